//! `smlworld run --seed/--threads/--set` (issue 19 item 4): dotted overrides with indices and `*`,
//! checked like the file; the same seed gives the same bytes for any thread count.

use std::path::{Path, PathBuf};
use std::process::Command;

use smlworld::app::running::scenario::{apply_override, parse_override};
use smlworld::app::running::session::load_scenario_with_overrides;

fn smlworld(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .env_remove("RUST_LOG")
        .output()
        .expect("runs smlworld");
    (out.status.success(), String::from_utf8_lossy(&out.stderr).into())
}

fn temp(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("smlworld-overrides-{name}-{}", std::process::id()))
}

fn table(text: &str) -> toml::Table {
    toml::from_str(text).unwrap()
}

#[test]
fn star_index_and_created_tables() {
    let mut t = table("[[vehicles]]\nid = -1\n[[vehicles]]\nid = -2\nlane_change = { politeness = 0.1 }\n");
    apply_override(&mut t, "vehicles.*.lane_change.politeness", toml::Value::Float(0.5)).unwrap();
    let pol: Vec<f64> =
        t["vehicles"].as_array().unwrap().iter().map(|v| v["lane_change"]["politeness"].as_float().unwrap()).collect();
    assert_eq!(pol, vec![0.5, 0.5], "`*` sets every element, creating `lane_change` in the first");

    apply_override(&mut t, "vehicles.1.speed", toml::Value::Float(7.0)).unwrap();
    assert!(t["vehicles"][0].get("speed").is_none(), "index 1 leaves element 0 alone");
    assert_eq!(t["vehicles"][1]["speed"].as_float(), Some(7.0));

    apply_override(&mut t, "v2v.wifi.loss", toml::Value::Float(0.1)).unwrap();
    assert_eq!(t["v2v"]["wifi"]["loss"].as_float(), Some(0.1), "missing tables on the way are created");

    let e = apply_override(&mut t, "vehicles.5.speed", toml::Value::Float(1.0)).unwrap_err();
    assert!(e.contains("vehicles") && e.contains("2 elements") && e.contains('5'), "{e}");
    let e = apply_override(&mut t, "traffic.*.count", toml::Value::Integer(80)).unwrap_err();
    assert!(e.contains("no array `traffic`"), "{e}");
    let e = apply_override(&mut t, "v2v.*.loss", toml::Value::Float(0.1)).unwrap_err();
    assert!(e.contains("`v2v` is a table"), "{e}");
    let e = apply_override(&mut t, "vehicles.0.id.x", toml::Value::Float(0.1)).unwrap_err();
    assert!(e.contains("`vehicles.0.id` is an integer, not a table"), "{e}");
}

#[test]
fn values_are_toml_and_bare_words_strings() {
    assert_eq!(parse_override("traffic.0.count=80").unwrap(), ("traffic.0.count".into(), toml::Value::Integer(80)));
    assert_eq!(parse_override("a.b = 0.5").unwrap().1, toml::Value::Float(0.5));
    assert_eq!(parse_override("a=true").unwrap().1, toml::Value::Boolean(true));
    assert_eq!(parse_override("class=truck").unwrap().1, toml::Value::String("truck".into()));
    assert_eq!(parse_override("class=\"bus\"").unwrap().1, toml::Value::String("bus".into()));
    let v = parse_override("controller={ type = \"acc\", speed = 20.0 }").unwrap().1;
    assert_eq!(v["type"].as_str(), Some("acc"));
    assert!(parse_override("novalue").unwrap_err().contains("KEY=VALUE"));
    assert!(parse_override("a..b=1").unwrap_err().contains("dotted"));
    assert!(parse_override("a=[1,").unwrap_err().contains("not TOML"));
}

#[test]
fn a_misspelt_override_gets_the_file_error_naming_the_key() {
    let e = load_scenario_with_overrides(
        Path::new("scenarios/platoon_brake.toml"),
        None,
        &[("vehicles.*.speedd".into(), toml::Value::Float(3.0))],
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("speedd") && e.contains("platoon_brake.toml"), "{e}");

    let out = temp("typo");
    let (ok, stderr) = smlworld(&[
        "run",
        "scenarios/platoon_brake.toml",
        "--duration",
        "0.2",
        "--out",
        out.to_str().unwrap(),
        "--set",
        "v2v.wifi_rnage=40",
    ]);
    let _ = std::fs::remove_dir_all(&out);
    assert!(!ok, "a misspelt key must stop the run");
    assert!(stderr.contains("wifi_rnage") && stderr.contains("unknown field"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

/// Issue 60 §4: `--set 'vehicles.*.sped=12.0'` reported "line 19 ... line numbers count in the
/// rewritten scenario", a file nobody sees; the error names the `--set` argument instead (the
/// first one after which the file no longer parses), with the parser's reason.
#[test]
fn a_bad_override_is_named_by_its_set_argument_not_a_line_of_the_rewritten_file() {
    let e = load_scenario_with_overrides(
        Path::new("scenarios/platoon_brake.toml"),
        None,
        &[("seed".into(), toml::Value::Integer(3)), ("vehicles.*.sped".into(), toml::Value::Float(12.0))],
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("--set vehicles.*.sped=12.0") && e.contains("unknown field `sped`"), "{e}");
    assert!(!e.contains("rewritten") && !e.contains("line "), "{e}");
}

/// summary.json without the fields that measure the wall clock.
fn summary_without_wall_clock(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json")).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let o = v.as_object_mut().unwrap();
    assert!(o.remove("wall_seconds").is_some() && o.remove("real_time_factor").is_some(), "{text}");
    v
}

#[test]
fn same_seed_same_bytes_for_any_thread_count() {
    for scenario in ["scenarios/platoon_brake.toml", "scenarios/highway.toml"] {
        let runs: Vec<(PathBuf, Vec<u8>, serde_json::Value)> = ["1", "2"]
            .iter()
            .map(|threads| {
                let out = temp(&format!("threads{threads}"));
                let (ok, stderr) = smlworld(&[
                    "run",
                    scenario,
                    "--duration",
                    "8",
                    "--seed",
                    "42",
                    "--threads",
                    threads,
                    "--set",
                    "vehicles.0.speed=9.0",
                    "--out",
                    out.to_str().unwrap(),
                ]);
                assert!(ok, "{scenario} --threads {threads}: {stderr}");
                let csv = std::fs::read(out.join("trajectories.csv")).unwrap();
                let summary = summary_without_wall_clock(&out);
                (out, csv, summary)
            })
            .collect();
        for (out, _, _) in &runs {
            let _ = std::fs::remove_dir_all(out);
        }
        assert_eq!(runs[0].2["seed"], 42, "--seed replaces the scenario seed");
        assert!(runs[0].1.len() > 1000, "{scenario}: the run logged trajectories");
        assert!(runs[0].1 == runs[1].1, "{scenario}: trajectories.csv differs between --threads 1 and 2");
        assert_eq!(runs[0].2, runs[1].2, "{scenario}: summary.json differs between --threads 1 and 2");
    }
}

#[test]
fn zero_threads_is_refused() {
    let (ok, stderr) = smlworld(&["run", "scenarios/highway.toml", "--duration", "0.2", "--threads", "0"]);
    assert!(!ok);
    assert!(stderr.contains("--threads") && stderr.contains("1..=1024"), "{stderr}");
}
