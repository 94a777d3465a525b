//! Every numeric flag goes through one range check (issue 24 item 4): NaN, negative and huge
//! values are refused by the parser, before any work, with exit code 2 and the flag named.

use std::process::Command;

const SCENARIO: &str = "scenarios/platoon_brake.toml";
const MAP: &str = "maps/highway_ring.osm";

/// `(arguments before the flag, flag)` for every numeric flag of every subcommand.
fn flags() -> Vec<(Vec<&'static str>, &'static str)> {
    let mut v = Vec::new();
    for f in ["--vehicles", "--duration", "--threads", "--soak"] {
        v.push((vec!["bench"], f));
    }
    v.push((vec!["bench", "--soak", "10"], "--sample-every"));
    for f in ["--duration", "--log-rate", "--frame-rate", "--width", "--height", "--threads"] {
        v.push((vec!["run", SCENARIO], f));
    }
    v.push((vec!["run", SCENARIO, "--realtime"], "--speed"));
    for f in ["--speed", "--frame-rate", "--width", "--height"] {
        v.push((vec!["replay", "out"], f));
    }
    for f in ["--width", "--height", "--pixels-per-meter", "--duration", "--frame-rate"] {
        v.push((vec!["view"], f));
    }
    v.push((vec!["map", "route", MAP, "--from", "1", "--to", "2"], "--points-per-meter"));
    v.push((vec!["map", "route", MAP, "--from", "1", "--to", "2", "--lane-changes"], "--lane-change-penalty"));
    v.push((vec!["map", "loop", MAP, "--node", "1"], "--points-per-meter"));
    for f in ["--width", "--height", "--pixels-per-meter"] {
        v.push((vec!["map", "render", MAP, "--out", "/tmp/never-written.png"], f));
    }
    for f in [
        "--lanes",
        "--lane-width",
        "--node-spacing",
        "--radius",
        "--arm-length",
        "--corner-radius",
        "--rows",
        "--cols",
        "--block",
        "--length",
        "--drop-at",
    ] {
        v.push((vec!["map", "generate", "ring", "--out", "/tmp/never-written.osm"], f));
    }
    for f in ["--bodies", "--rate"] {
        v.push((vec!["mock-mocap", "--port", "0"], f));
    }
    v
}

#[test]
fn nan_negative_and_huge_values_are_refused_naming_the_flag() {
    let mut failures = Vec::new();
    for (before, flag) in flags() {
        for bad in ["nan", "-1", "1e300", "inf"] {
            let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
                .current_dir(env!("CARGO_MANIFEST_DIR"))
                .args(&before)
                .arg(format!("{flag}={bad}"))
                .output()
                .expect("run smlworld");
            let stderr = String::from_utf8_lossy(&out.stderr);
            if out.status.code() != Some(2) || !stderr.contains(flag) || stderr.contains("panicked") {
                failures.push(format!("{before:?} {flag}={bad}: exit {:?}: {}", out.status.code(), stderr.trim()));
            }
        }
    }
    assert!(failures.is_empty(), "{} accepted or unnamed:\n{}", failures.len(), failures.join("\n"));
}

/// `--center X,Y` of `map render` and `view` goes through the same range check: each coordinate
/// finite and at most 1e9 m from the origin (negative coordinates are points like any other).
#[test]
fn a_center_out_of_range_is_refused_naming_the_flag() {
    let commands: [Vec<&str>; 2] = [
        vec!["map", "render", MAP, "--out", "/tmp/never-written.png", "--pixels-per-meter", "2"],
        vec!["view", "--duration", "0.01"],
    ];
    let mut failures = Vec::new();
    for before in &commands {
        for bad in ["nan,0", "0,nan", "1e300,0", "0,-1e300", "inf,0", "0,-inf", "1e10,0", "3", "x,y", "1,2,3"] {
            let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
                .current_dir(env!("CARGO_MANIFEST_DIR"))
                .args(before)
                .arg(format!("--center={bad}"))
                .output()
                .expect("run smlworld");
            let stderr = String::from_utf8_lossy(&out.stderr);
            if out.status.code() != Some(2) || !stderr.contains("--center") || stderr.contains("panicked") {
                failures.push(format!("{before:?} --center={bad}: exit {:?}: {}", out.status.code(), stderr.trim()));
            }
        }
    }
    assert!(failures.is_empty(), "{} accepted or unnamed:\n{}", failures.len(), failures.join("\n"));
    // A point with negative coordinates passes the parser (the map file is what fails here).
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["map", "render", "/nonexistent.osm", "--out", "/tmp/never-written.png"])
        .args(["--pixels-per-meter", "2", "--center=-12.5,-3"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("nonexistent.osm") && !stderr.contains("--center"), "{stderr}");
}
