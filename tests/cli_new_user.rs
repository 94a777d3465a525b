//! Defects a new user met running the command line (issue 10): each cause said once, colour only
//! on a terminal, a GIF never written under another extension.

use std::process::Command;

fn smlworld(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env_remove("RUST_LOG")
        .output()
        .expect("runs smlworld");
    (out.status.success(), String::from_utf8_lossy(&out.stderr).into())
}

#[test]
fn a_missing_file_is_reported_once() {
    let (ok, stderr) = smlworld(&["map", "info", "/nonexistent/smlworld-issue10.osm"]);
    assert!(!ok);
    assert_eq!(stderr.matches("os error 2").count(), 1, "{stderr}");
    assert_eq!(stderr.matches("No such file or directory").count(), 1, "{stderr}");
}

#[test]
fn logs_to_a_pipe_carry_no_colour_codes() {
    let out = std::env::temp_dir().join(format!("smlworld-nocolour-{}", std::process::id()));
    let (ok, stderr) =
        smlworld(&["run", "scenarios/highway.toml", "--duration", "0.2", "--out", out.to_str().unwrap()]);
    let _ = std::fs::remove_dir_all(&out);
    assert!(ok, "{stderr}");
    assert!(stderr.contains("INFO"), "the run logs something: {stderr}");
    assert!(!stderr.contains('\u{1b}'), "ANSI escape in piped stderr: {stderr:?}");
}

#[test]
fn gif_under_another_extension_is_refused() {
    let dir = std::env::temp_dir().join(format!("smlworld-gifext-{}", std::process::id()));
    let png = dir.join("x.png");
    let (ok, stderr) = smlworld(&[
        "run",
        "scenarios/highway.toml",
        "--duration",
        "0.2",
        "--out",
        dir.to_str().unwrap(),
        "--gif",
        png.to_str().unwrap(),
    ]);
    let written = png.exists();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(!ok, "GIF data under a .png name must be refused");
    assert!(stderr.contains("--gif") && stderr.contains(".gif") && stderr.contains("x.png"), "{stderr}");
    assert!(!written, "nothing written under the .png name");
}

/// Issue 22 item 7: the closing line says how many collisions there were (no escape codes in a
/// pipe). Vehicle -2 stands still 93.6 m ahead of -1, which drives at 10 m/s into it.
#[test]
fn the_closing_line_counts_collisions() {
    let out = std::env::temp_dir().join(format!("smlworld-collisions-line-{}", std::process::id()));
    let o = out.to_str().unwrap();
    let (ok, clean) = smlworld(&["run", "scenarios/highway.toml", "--duration", "1", "--out", o]);
    assert!(ok, "{clean}");
    let closing = |stderr: &str| stderr.lines().find(|l| l.contains("sim s in")).map(str::to_string);
    let line = closing(&clean).expect("a closing line");
    assert!(line.contains(", collisions 0,"), "{line}");
    let (ok, crash) = smlworld(&[
        "run",
        "scenarios/highway.toml",
        "--duration",
        "15",
        "--out",
        o,
        "--set",
        "vehicles.1.speed=0.0",
        "--set",
        "vehicles.1.controller.speed=0.0",
    ]);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let _ = std::fs::remove_dir_all(&out);
    assert!(ok, "{crash}");
    let n = summary["metrics"]["collision_count"].as_u64().unwrap();
    assert!(n >= 1, "-1 runs into the standing -2");
    let line = closing(&crash).expect("a closing line");
    assert!(line.contains(&format!(", collisions {n},")), "{line}");
    assert!(!line.contains('\u{1b}'), "{line:?}");
    assert!(summary["metrics"]["collided"].get("-1").is_some() && summary["metrics"]["collided"].get("-2").is_some());
}
