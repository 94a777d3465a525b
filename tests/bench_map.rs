//! `smlworld bench --routing MAP --routes N [--seed S]` and `bench --map-load MAP` (issue 25
//! item 3): JSON with `routes_per_second` and `mb_per_second`, pairs reproducible by seed, a
//! missing map an error naming it.

use std::path::PathBuf;
use std::process::Command;

use serde_json::Value;
use smlworld::map::generate::{GridParams, write_grid_city};

fn smlworld(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld")).args(args).output().expect("runs smlworld");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A 4 x 4 grid city in a temporary file (removed by the caller).
fn grid(name: &str) -> PathBuf {
    let path = std::env::temp_dir().join(format!("smlworld-bench-map-{name}-{}.osm", std::process::id()));
    let file = std::fs::File::create(&path).expect("temporary directory is writable");
    write_grid_city(&GridParams { rows: 4, cols: 4, ..GridParams::default() }, file).expect("valid grid");
    path
}

fn json(stdout: &str) -> Value {
    serde_json::from_str(stdout.trim()).unwrap_or_else(|e| panic!("bench prints one JSON object ({e}): {stdout}"))
}

#[test]
fn routing_bench_routes_random_pairs_reproducibly_and_reports_routes_per_second() {
    let map = grid("routing");
    let m = map.to_str().expect("utf-8 temp path");
    let run = |seed: &str| {
        let (ok, out, err) = smlworld(&["bench", "--routing", m, "--routes", "40", "--seed", seed]);
        assert!(ok, "bench --routing failed: {err}");
        json(&out)
    };
    let (a, b, c) = (run("3"), run("3"), run("4"));
    let _ = std::fs::remove_file(&map);
    assert_eq!(a["routes"], 40);
    let found = a["found"].as_u64().expect("found");
    assert_eq!(found + a["no_route"].as_u64().expect("no_route"), 40);
    // Every junction of the grid has every turn: nearly every pair is connected.
    assert!(found >= 36, "only {found} of 40 random pairs routed: {a}");
    assert!(a["routes_per_second"].as_f64().expect("routes_per_second") > 0.0);
    assert!(a["mean_points"].as_f64().expect("mean_points") > 2.0);
    // Same seed, same pairs (the same mean path size); another seed, other pairs.
    assert_eq!(a["mean_points"], b["mean_points"]);
    assert_ne!(a["mean_points"], c["mean_points"]);
}

#[test]
fn map_load_bench_reports_the_file_size_lanelets_and_rate() {
    let map = grid("load");
    let m = map.to_str().expect("utf-8 temp path");
    let text = std::fs::read_to_string(&map).expect("reads the grid");
    let (ok, out, err) = smlworld(&["bench", "--map-load", m]);
    let _ = std::fs::remove_file(&map);
    assert!(ok, "bench --map-load failed: {err}");
    let r = json(&out);
    assert_eq!(r["bytes"].as_u64(), Some(text.len() as u64));
    // Lanelets counted in the XML itself, not taken from our loader.
    let relations =
        text.matches("<tag k=\"type\" v=\"lanelet\"").count() + text.matches("<tag k='type' v='lanelet'").count();
    assert!(relations > 0, "the grid file names its lanelets");
    assert_eq!(r["lanelets"].as_u64(), Some(relations as u64));
    assert_eq!(r["runs"], 3);
    assert!(r["mb_per_second"].as_f64().expect("mb_per_second") > 0.0);
}

#[test]
fn a_missing_map_is_an_error_naming_it() {
    for flag in ["--routing", "--map-load"] {
        let (ok, out, err) = smlworld(&["bench", flag, "no/such/map.osm"]);
        assert!(!ok, "{flag} of a missing map succeeded: {out}");
        assert!(err.contains("no/such/map.osm"), "{flag}: the error does not name the file: {err}");
        assert!(!err.contains("panicked"), "{flag} panicked: {err}");
    }
}
