//! Quiet ends (issue 15): a printing subcommand whose stdout is closed early (`| head`) ends
//! without a panic or backtrace.

use std::io::Read;
use std::process::{Command, Stdio};

#[test]
fn map_info_on_a_closed_pipe_does_not_panic() {
    let map = concat!(env!("CARGO_MANIFEST_DIR"), "/maps/highway_ring.osm");
    let mut child = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["map", "info", map])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Close the read end before the map is loaded: every line printed meets a closed pipe.
    drop(child.stdout.take());
    let status = child.wait().unwrap();
    let mut err = String::new();
    child.stderr.take().unwrap().read_to_string(&mut err).unwrap();
    assert!(!err.contains("panicked"), "panicked on a closed stdout:\n{err}");
    assert_ne!(status.code(), Some(101), "exit code 101 (a panic):\n{err}");
}

/// Issue 22 item 9: off-screen rendering without a Wayland session (no `XDG_RUNTIME_DIR`, as on
/// CI) prints no `error:` line for what is no error (Mesa's device-select layer used to print
/// `error: XDG_RUNTIME_DIR is invalid or not set in the environment.` twice per GIF run).
#[test]
fn rendering_without_a_wayland_session_prints_no_error_lines() {
    let dir = std::env::temp_dir().join(format!("smlworld-quiet-render-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let gif = dir.join("run.gif");
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["run", "scenarios/highway.toml", "--duration", "0.3", "--gif"])
        .arg(&gif)
        .arg("--out")
        .arg(&dir)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("NODEVICE_SELECT")
        .env_remove("RUST_LOG")
        .output()
        .unwrap();
    let wrote = gif.is_file();
    let _ = std::fs::remove_dir_all(&dir);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success() && wrote, "the GIF run failed:\n{err}");
    assert!(!err.contains("XDG_RUNTIME_DIR"), "{err}");
    assert!(!err.to_lowercase().contains("error"), "an error line in a run that succeeded:\n{err}");
}
