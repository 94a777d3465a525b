//! `smlworld bench --render WxH` (issue 25 item 2): the simulation bench's JSON gains
//! `render_ms_per_frame` (the median of the timed frames) and `render` (every frame, the size,
//! the adapter); a malformed size is refused naming the expected form.

use std::process::Command;

use serde_json::Value;

fn smlworld(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld")).args(args).output().expect("runs smlworld");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn render_bench_adds_the_frame_time_beside_the_real_time_factor() {
    let (ok, out, err) = smlworld(&["bench", "--vehicles", "300", "--duration", "1", "--render", "320x180"]);
    assert!(ok, "bench --render failed: {err}");
    let r: Value = serde_json::from_str(out.trim()).unwrap_or_else(|e| panic!("one JSON object ({e}): {out}"));
    assert!(r["real_time_factor"].as_f64().is_some_and(|f| f > 0.0), "{r}");
    let render = &r["render"];
    assert_eq!((render["width"].as_u64(), render["height"].as_u64()), (Some(320), Some(180)));
    assert_eq!(render["vehicles"], 300);
    let frames: Vec<f64> =
        render["frame_ms"].as_array().expect("frame_ms").iter().map(|v| v.as_f64().expect("ms")).collect();
    assert_eq!(frames.len(), 10);
    assert!(frames.iter().all(|&ms| ms > 0.0 && ms.is_finite()), "{frames:?}");
    // The reported figure is the median of the frames listed.
    let mut sorted = frames.clone();
    sorted.sort_by(f64::total_cmp);
    assert_eq!(r["render_ms_per_frame"].as_f64(), Some(sorted[5]));
    assert!(!render["adapter"].as_str().unwrap_or("").is_empty());
}

#[test]
fn a_bad_render_size_is_refused_with_the_expected_form() {
    for bad in ["1920", "0x100", "axb"] {
        let (ok, _, err) = smlworld(&["bench", "--vehicles", "10", "--render", bad]);
        assert!(!ok, "--render {bad} accepted");
        assert!(err.contains("--render"), "{bad}: {err}");
        assert!(!err.contains("panicked"), "{bad}: {err}");
    }
}
