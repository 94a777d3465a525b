//! Atomic outputs (issue 15): a run that fails part-way keeps the previous run's results intact
//! and leaves no temporary file; a run that succeeds leaves only its final files.

use std::path::Path;
use std::process::Command;

fn run(out: &Path, extra: &[&str]) -> (bool, String) {
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/highway.toml");
    let o = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["run", scenario, "--duration", "1", "--out", out.to_str().unwrap()])
        .args(extra)
        .output()
        .unwrap();
    (o.status.success(), String::from_utf8_lossy(&o.stderr).into_owned())
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

#[test]
fn a_run_failing_mid_way_keeps_the_previous_results() {
    let base = Path::new(env!("CARGO_TARGET_TMPDIR")).join("reliability_outputs_fail");
    let _ = std::fs::remove_dir_all(&base);
    let (out, frames) = (base.join("out"), base.join("frames"));
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("trajectories.csv"), "previous run\n").unwrap();
    std::fs::write(out.join("summary.json"), "{}\n").unwrap();
    // A folder where the third frame's file must go: writing that frame fails after the run has
    // started (and after the trajectory log was opened).
    std::fs::create_dir_all(frames.join("frame_000002.png")).unwrap();
    let (ok, err) = run(&out, &["--frames", frames.to_str().unwrap(), "--width", "64", "--height", "64"]);
    assert!(!ok, "the run should fail on the frame it cannot write:\n{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(std::fs::read_to_string(out.join("trajectories.csv")).unwrap(), "previous run\n");
    assert_eq!(std::fs::read_to_string(out.join("summary.json")).unwrap(), "{}\n");
    assert_eq!(names(&out), ["summary.json", "trajectories.csv"], "temporary files left behind");
}

#[test]
fn a_successful_run_leaves_only_its_final_files() {
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("reliability_outputs_ok");
    let _ = std::fs::remove_dir_all(&out);
    let (ok, err) = run(&out, &[]);
    assert!(ok, "{err}");
    assert_eq!(names(&out), ["summary.json", "trajectories.csv", "trips.csv"]);
    let csv = std::fs::read_to_string(out.join("trajectories.csv")).unwrap();
    assert!(csv.starts_with("t,id,x,y,yaw,vx,vy,lanelet,lane_offset\n") && csv.lines().count() > 12, "{csv}");
}
