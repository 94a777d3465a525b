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
