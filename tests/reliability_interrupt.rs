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

/// Start `bench` with `args`, wait `after`, send `sig`; the process must end within 30 s with
/// exit status `code` and one JSON report on stdout marked `"interrupted": true`.
fn interrupted_bench(args: &[&str], after: Duration, sig: i32, code: i32) -> serde_json::Value {
    let child = bin().arg("bench").args(args).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    std::thread::sleep(after);
    signal(&child, sig);
    let start = Instant::now();
    let out = child.wait_with_output().unwrap();
    assert!(start.elapsed() < Duration::from_secs(30), "bench took {:?} to stop", start.elapsed());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(code), "exit status after signal {sig}; stderr:\n{err}");
    assert!(!err.contains("panicked"), "{err}");
    let report: serde_json::Value = serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("one whole JSON report on stdout ({e}): {}", String::from_utf8_lossy(&out.stdout)));
    assert_eq!(report["interrupted"], true, "{report}");
    report
}

#[test]
fn ctrl_c_stops_bench_with_the_figures_of_what_ran() {
    let args = ["--vehicles", "200", "--duration", "1000000", "--threads", "1"];
    let report = interrupted_bench(&args, Duration::from_millis(1500), libc::SIGINT, 130);
    let reached = report["sim_seconds"].as_f64().unwrap();
    assert!(reached > 0.0 && reached < 1_000_000.0, "{report}");
    assert!(report["real_time_factor"].as_f64().unwrap().is_finite(), "{report}");
}

#[test]
fn sigterm_stops_bench_with_the_figures_of_what_ran_and_exit_143() {
    let args = ["--vehicles", "200", "--duration", "1000000", "--threads", "1"];
    let report = interrupted_bench(&args, Duration::from_millis(1500), libc::SIGTERM, 143);
    let reached = report["sim_seconds"].as_f64().unwrap();
    assert!(reached > 0.0 && reached < 1_000_000.0, "{report}");
    assert!(report["real_time_factor"].as_f64().unwrap().is_finite(), "{report}");
}

#[test]
fn ctrl_c_stops_a_soak_with_the_samples_taken_and_exit_130() {
    let args = ["--soak", "30", "--sample-every", "0.5", "--vehicles", "200", "--threads", "1"];
    let report = interrupted_bench(&args, Duration::from_millis(2500), libc::SIGINT, 130);
    let samples = report["samples"].as_array().expect("samples");
    assert!(samples.len() >= 2, "the samples taken before the signal: {report}");
    let last_wall = samples.last().unwrap()["wall_s"].as_f64().unwrap();
    assert!(last_wall < 20.0, "stopped early, not after the 30 s: last sample at {last_wall} s wall");
    assert!(samples.iter().all(|s| s["rss_mb"].as_f64().unwrap() > 1.0), "{report}");
}

/// A short run to replay, then a replay to a slowly paced stream plus a GIF, stopped by `sig`
/// once it has drawn a frame: the GIF drawn so far is whole and the exit status is `code`.
fn interrupted_replay(name: &str, sig: i32, code: i32) {
    let dir = scratch(name);
    let out = dir.join("run");
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/highway.toml");
    let ok = bin().args(["run", scenario, "--duration", "20", "--out", out.to_str().unwrap()]).output().unwrap();
    assert!(ok.status.success(), "{}", String::from_utf8_lossy(&ok.stderr));
    let gif = dir.join("replay.gif");
    let frames = dir.join("frames");
    let child = bin()
        .args(["replay", out.to_str().unwrap(), "--gif", gif.to_str().unwrap(), "--width", "64", "--height", "64"])
        .args(["--frames", frames.to_str().unwrap()])
        .args(["--stream", "127.0.0.1:9", "--speed", "1"])
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Signalled once it has drawn a frame (its start, the renderer's, may take seconds on a
    // loaded machine: a fixed 2.5 s sometimes caught it before the first frame), plus 1 s.
    let started = std::time::Instant::now();
    let drawn = || std::fs::read_dir(&frames).is_ok_and(|mut d| d.next().is_some());
    while !drawn() && started.elapsed() < Duration::from_secs(60) {
        std::thread::sleep(Duration::from_millis(50));
    }
    std::thread::sleep(Duration::from_millis(1000));
    signal(&child, sig);
    let (status, err) = finish(child);
    assert_eq!(status, Some(code), "exit status after signal {sig}; stderr:\n{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(err.contains("interrupted"), "it says it was interrupted:\n{err}");
    let bytes = std::fs::read(&gif).unwrap_or_else(|e| panic!("no GIF after the interrupt ({e}):\n{err}"));
    assert!(bytes.starts_with(b"GIF89a") && bytes.ends_with(&[0x3b]), "a whole GIF (header and trailer)");
    // The frames written so far are whole PNGs, with no temporary file beside them.
    let names: Vec<String> =
        std::fs::read_dir(&frames).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    assert!(!names.is_empty() && names.len() < 200, "some frames, not all 20 s of them: {}", names.len());
    for n in &names {
        assert!(n.starts_with("frame_") && n.ends_with(".png"), "unexpected file {n}");
        let png = std::fs::read(frames.join(n)).unwrap();
        assert!(png.starts_with(b"\x89PNG") && png.ends_with(b"IEND\xaeB`\x82"), "{n} is a whole PNG");
    }
    let left: Vec<String> =
        std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    assert!(left.iter().all(|n| !n.contains("partial")), "temporary files left: {left:?}");
}

#[test]
fn ctrl_c_stops_a_replay_and_keeps_the_gif_drawn_so_far() {
    interrupted_replay("interrupt_replay", libc::SIGINT, 130);
}

#[test]
fn sigterm_stops_a_replay_with_complete_outputs_and_exit_143() {
    interrupted_replay("interrupt_replay_term", libc::SIGTERM, 143);
}
