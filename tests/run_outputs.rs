//! What `smlworld run` writes, checked as a user reads it (issue 10): the trajectory CSV.

use std::path::Path;

use smlworld::prelude::*;

fn run_csv(scenario: &str, duration: f64, name: &str) -> String {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = std::env::temp_dir().join(format!("smlworld-run-outputs-{name}-{}", std::process::id()));
    let options = RunOptions { progress: false, duration: Some(duration), ..RunOptions::default() }.out(&out);
    run_scenario(manifest.join(scenario).as_path(), options).expect("run");
    let csv = std::fs::read_to_string(out.join("trajectories.csv")).unwrap();
    let _ = std::fs::remove_dir_all(&out);
    csv
}

/// The intersection scenario stops vehicles at 3.9 s (speed 0 at a heading of -90°: vx = -0).
#[test]
fn csv_has_no_negative_zero_and_ends_with_the_final_state() {
    let csv = run_csv("scenarios/intersection.toml", 4.0, "final");
    for (n, line) in csv.lines().enumerate() {
        assert!(!line.split(',').any(|f| f == "-0"), "line {}: `-0` in {line}", n + 1);
    }
    let last_t: f64 = csv.lines().last().unwrap().split(',').next().unwrap().parse().unwrap();
    assert_eq!(last_t, 4.0, "a 4 s run logs its final state at t = 4");
    let rows_at_end = csv.lines().filter(|l| l.starts_with("4.000000,")).count();
    let rows_at_start = csv.lines().filter(|l| l.starts_with("0.000000,")).count();
    assert_eq!(rows_at_end, rows_at_start, "one final row per vehicle, logged once");
}

/// Issue 22 item 13: numbers carry the precision of their unit (1 mm, 1e-5 rad, 1 mm/s), not 17
/// digits of float noise, so a long run's CSV stays small.
#[test]
fn csv_numbers_have_the_precision_of_their_unit() {
    let csv = run_csv("scenarios/highway.toml", 20.0, "precision");
    let decimals = |f: &str| f.split_once('.').map_or(0, |(_, d)| d.len());
    let mut rows = 0;
    for line in csv.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        for (i, most) in [(2, 3), (3, 3), (4, 5), (5, 3), (6, 3)] {
            assert!(decimals(f[i]) <= most, "column {i} of `{line}` has more than {most} decimals");
            assert!(f[i].parse::<f64>().is_ok_and(f64::is_finite), "`{}` in `{line}`", f[i]);
        }
        rows += 1;
    }
    assert!(rows > 100, "{rows} rows");
    let bytes_per_row = csv.len() as f64 / rows as f64;
    // t (11) + id (3) + 5 numbers of at most ~9 characters + 6 separators and a newline.
    assert!(bytes_per_row < 60.0, "{bytes_per_row:.1} bytes per row");
}
