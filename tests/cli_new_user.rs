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
