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
    let rows_at_end = csv.lines().filter(|l| l.starts_with("4,")).count();
    let rows_at_start = csv.lines().filter(|l| l.starts_with("0,")).count();
    assert!(rows_at_start > 0, "rows at t = 0 written `0,`: {}", &csv[..csv.len().min(300)]);
    assert_eq!(rows_at_end, rows_at_start, "one final row per vehicle, logged once");
    // The README: every number with the precision of its unit, trailing zeros dropped (issue 61:
    // `t` was written `0.100000`).
    assert!(csv.lines().any(|l| l.starts_with("0.1,")), "t = 0.1 s written `0.1`");
    for line in csv.lines().skip(1) {
        let t = line.split(',').next().unwrap();
        assert!(!(t.contains('.') && t.ends_with('0')), "trailing zero in t: {line}");
    }
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

/// Run `scenario` for `duration` [s]; returns summary.json's text.
fn run_summary(scenario: &str, duration: f64, name: &str) -> String {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = std::env::temp_dir().join(format!("smlworld-run-summary-{name}-{}", std::process::id()));
    let options = RunOptions { progress: false, duration: Some(duration), ..RunOptions::default() }.out(&out);
    run_scenario(manifest.join(scenario).as_path(), options).expect("run");
    let text = std::fs::read_to_string(out.join("summary.json")).unwrap();
    let _ = std::fs::remove_dir_all(&out);
    text
}

/// The decimals of every number in a JSON text (digits after a `.` that follows a digit).
fn decimals(text: &str) -> Vec<usize> {
    let b = text.as_bytes();
    (1..b.len())
        .filter(|&i| b[i] == b'.' && b[i - 1].is_ascii_digit())
        .map(|i| b[i + 1..].iter().take_while(|c| c.is_ascii_digit()).count())
        .collect()
}

/// Issue 61: summary.json held `0.09999999999999999` and `4.3999999999999995`; every figure is
/// rounded to its unit's precision as the CSV's are (times 1 µs, lengths 1 mm).
#[test]
fn summary_json_figures_are_rounded_to_their_unit() {
    for (scenario, name) in [("scenarios/highway.toml", "highway"), ("scenarios/platoon_brake.toml", "platoon")] {
        let text = run_summary(scenario, 20.0, name);
        let most = decimals(&text).into_iter().max().unwrap_or(0);
        assert!(most <= 6, "{scenario}: a number with {most} decimals in {text}");
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        let distances = v["max_distance_to_centre_line"].as_object().unwrap();
        assert!(!distances.is_empty());
        for d in distances.values() {
            let d = d.to_string();
            assert!(decimals(&d).into_iter().all(|n| n <= 3), "{scenario}: a distance of {d} m is not in mm");
        }
    }
}

/// Issue 61: the lane-drop run said "0 vehicles ... max distance to centre line 0.000 m" after 73
/// vehicles drove (`max_distance_to_centre_line` was `{}`): every vehicle that drove is reported.
#[test]
fn lane_drop_summary_reports_every_vehicle_that_drove() {
    let text = run_summary("scenarios/lane_drop.toml", 300.0, "lane-drop");
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let inserted = v["metrics"]["traffic"]["inserted"].as_u64().unwrap();
    assert!(inserted > 50, "{text}");
    let distances = v["max_distance_to_centre_line"].as_object().unwrap();
    let (removed, present) = (v["metrics"]["traffic"]["removed"].as_u64().unwrap(), v["vehicles"].as_u64().unwrap());
    assert_eq!(distances.len() as u64, removed + present, "one entry per vehicle that drove: {text}");
    let worst = distances.values().filter_map(serde_json::Value::as_f64).fold(0.0, f64::max);
    assert!(worst > 0.01, "lane changes move vehicles off the centre line: largest {worst} m");
}

/// Issue 61: the closing line names the vehicles inserted and still present.
#[test]
fn closing_line_names_inserted_and_present_vehicles() {
    let out = std::env::temp_dir().join(format!("smlworld-closing-line-{}", std::process::id()));
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["run", "scenarios/lane_drop.toml", "--out", out.to_str().unwrap()])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("runs smlworld");
    let _ = std::fs::remove_dir_all(&out);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    assert!(stderr.contains("traffic vehicles inserted, 0 vehicles still present"), "{stderr}");
    assert!(!stderr.contains("max distance to centre line 0.000 m"), "{stderr}");
}
