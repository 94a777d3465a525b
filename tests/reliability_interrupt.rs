//! Ctrl-C and SIGTERM (issue 24): a run, replay or bench stopped by a signal writes what it ran
//! (complete files, `"interrupted": true`), names its output folder and exits 130 / 143; a second
//! signal aborts at once and leaves the folder's earlier outputs as they were. Tested by spawning
//! the binary and sending it real signals.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_smlworld"))
}

fn scratch(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Start a long headless run of the shipped highway scenario into `out`, and wait until its
/// trajectory log exists (the simulation is running).
fn start_run(out: &Path) -> Child {
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/highway.toml");
    let child = bin()
        .args(["run", scenario, "--duration", "1000000", "--out", out.to_str().unwrap()])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for(&out.join(".trajectories.csv.partial"));
    // Let it simulate a little.
    std::thread::sleep(Duration::from_millis(300));
    child
}

fn wait_for(path: &Path) {
    let start = Instant::now();
    while !path.exists() {
        assert!(start.elapsed() < Duration::from_secs(60), "{} never appeared", path.display());
        std::thread::sleep(Duration::from_millis(10));
    }
}

fn signal(child: &Child, signal: i32) {
    // SAFETY: kill(2) on our own child's pid.
    let rc = unsafe { libc::kill(child.id() as i32, signal) };
    assert_eq!(rc, 0, "kill failed");
}

/// Wait for the child (at most 60 s) and return its exit code and stderr.
fn finish(child: Child) -> (Option<i32>, String) {
    let start = Instant::now();
    let mut child = child;
    loop {
        if child.try_wait().unwrap().is_some() {
            break;
        }
        if start.elapsed() > Duration::from_secs(60) {
            let _ = child.kill();
            panic!("the process did not end within 60 s of the signal");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = child.wait_with_output().unwrap();
    (out.status.code(), String::from_utf8_lossy(&out.stderr).into_owned())
}

fn summary(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap()
}

fn check_interrupted_run(name: &str, sig: i32, code: i32) {
    let out = scratch(name);
    let child = start_run(&out);
    signal(&child, sig);
    let (status, err) = finish(child);
    assert_eq!(status, Some(code), "exit status after signal {sig}; stderr:\n{err}");
    assert!(!err.contains("panicked"), "{err}");
    let s = summary(&out);
    assert_eq!(s["interrupted"], true, "{s}");
    let reached = s["sim_seconds"].as_f64().unwrap();
    assert!(reached > 0.0 && reached < 1_000_000.0, "sim time reached {reached}");
    // The CSV is complete: a header, whole rows, and it ends with the state at the time reached.
    let csv = std::fs::read_to_string(out.join("trajectories.csv")).unwrap();
    assert!(csv.ends_with('\n'), "the last row is whole");
    let last_t: f64 = csv.lines().last().unwrap().split(',').next().unwrap().parse().unwrap();
    assert!((last_t - reached).abs() < 1e-3, "last row at {last_t} s, run reached {reached} s");
    let lines: Vec<&str> = err.lines().filter(|l| l.contains("interrupted")).collect();
    assert_eq!(lines.len(), 1, "one line about the interruption:\n{err}");
    assert!(lines[0].contains(out.to_str().unwrap()), "it names the output folder: {}", lines[0]);
    let names: Vec<String> =
        std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    assert!(names.iter().all(|n| !n.contains("partial")), "temporary files left: {names:?}");
}

#[test]
fn ctrl_c_stops_a_run_with_complete_outputs_and_exit_130() {
    check_interrupted_run("interrupt_sigint", libc::SIGINT, 130);
}

#[test]
fn sigterm_stops_a_run_with_complete_outputs_and_exit_143() {
    check_interrupted_run("interrupt_sigterm", libc::SIGTERM, 143);
}

#[test]
fn a_second_signal_aborts_at_once_and_keeps_the_earlier_outputs() {
    let out = scratch("interrupt_twice");
    std::fs::write(out.join("trajectories.csv"), "earlier run\n").unwrap();
    std::fs::write(out.join("summary.json"), "{\"earlier\": true}\n").unwrap();
    let child = start_run(&out);
    // Two signals back to back: both are pending before the run can look at the first, so the
    // handler of whichever the kernel delivers second ends the process (128 + that signal)
    // before anything is written or renamed.
    signal(&child, libc::SIGINT);
    signal(&child, libc::SIGTERM);
    let (status, err) = finish(child);
    assert!(matches!(status, Some(130 | 143)), "exit {status:?}; stderr:\n{err}");
    assert!(!err.contains("interrupted at"), "the run must not have written its outputs:\n{err}");
    assert_eq!(std::fs::read_to_string(out.join("trajectories.csv")).unwrap(), "earlier run\n");
    assert_eq!(std::fs::read_to_string(out.join("summary.json")).unwrap(), "{\"earlier\": true}\n");
}

#[test]
fn ctrl_c_stops_bench_with_the_figures_of_what_ran() {
    let child = bin()
        .args(["bench", "--vehicles", "200", "--duration", "1000000", "--threads", "1"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(1500));
    signal(&child, libc::SIGINT);
    let start = Instant::now();
    let out = child.wait_with_output().unwrap();
    assert!(start.elapsed() < Duration::from_secs(30), "bench took {:?} to stop", start.elapsed());
    assert_eq!(out.status.code(), Some(130), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["interrupted"], true, "{report}");
    let reached = report["sim_seconds"].as_f64().unwrap();
    assert!(reached > 0.0 && reached < 1_000_000.0, "{report}");
    assert!(report["real_time_factor"].as_f64().unwrap().is_finite(), "{report}");
}

#[test]
fn ctrl_c_stops_a_replay_and_keeps_the_gif_drawn_so_far() {
    // A short run to replay, then a replay to a slowly paced stream plus a GIF, stopped early.
    let dir = scratch("interrupt_replay");
    let out = dir.join("run");
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/highway.toml");
    let ok = bin().args(["run", scenario, "--duration", "20", "--out", out.to_str().unwrap()]).output().unwrap();
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));
    let gif = dir.join("replay.gif");
    let child = bin()
        .args(["replay", out.to_str().unwrap(), "--gif", gif.to_str().unwrap(), "--width", "64", "--height", "64"])
        .args(["--stream", "127.0.0.1:9", "--speed", "1"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_millis(2500));
    signal(&child, libc::SIGINT);
    let (status, err) = finish(child);
    assert_eq!(status, Some(130), "{err}");
    let bytes = std::fs::read(&gif).unwrap_or_else(|e| panic!("no GIF after the interrupt ({e}):\n{err}"));
    assert!(bytes.starts_with(b"GIF89a") && bytes.ends_with(&[0x3b]), "a whole GIF (header and trailer)");
}
