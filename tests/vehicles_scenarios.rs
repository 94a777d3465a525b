//! Every demo scenario runs with `smlworld run scenarios/X.toml` and writes its metrics into
//! summary.json: no collision anywhere, followers measured, platoons string stable where the
//! scenario says so.

use std::path::PathBuf;
use std::process::Command;

use serde_json::Value;
use smlworld::app::Scenario;

/// Run `smlworld run scenarios/<name>.toml` into a fresh folder; return summary.json.
fn run(name: &str) -> Value {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let scenario = root.join("scenarios").join(format!("{name}.toml"));
    let out = std::env::temp_dir().join(format!("smlworld-test-{name}-{}", std::process::id()));
    let output = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .arg("run")
        .arg(&scenario)
        .arg("--out")
        .arg(&out)
        .current_dir(&root)
        .output()
        .expect("the smlworld binary runs");
    assert!(
        output.status.success(),
        "smlworld run {} failed (its maps come from maps/, written by `smlworld map generate`):\n{}",
        scenario.display(),
        String::from_utf8_lossy(&output.stderr)
    );
    let text = std::fs::read_to_string(out.join("summary.json")).expect("summary.json written");
    let _ = std::fs::remove_dir_all(&out);
    serde_json::from_str(&text).expect("summary.json is JSON")
}

/// The `metrics` object, checked for the fields every summary must have and for no collision.
fn metrics_without_collision(summary: &Value) -> &Value {
    let m = &summary["metrics"];
    for key in ["warmup", "collision_count", "collisions", "followers", "platoons"] {
        assert!(!m[key].is_null(), "summary.json metrics lack `{key}`: {m}");
    }
    assert_eq!(m["collision_count"], 0, "collisions: {}", m["collisions"]);
    m
}

fn followers(m: &Value) -> &Vec<Value> {
    m["followers"].as_array().expect("followers is a list")
}

#[test]
fn acc_highway_runs_without_collision_and_keeps_time_gaps() {
    let summary = run("acc_highway");
    let m = metrics_without_collision(&summary);
    let f = followers(m);
    assert_eq!(f.len(), 7, "3 ACC cars on the right lane, 4 on the centre lane: {f:?}");
    for follower in f {
        let min_gap = follower["min_gap"].as_f64().expect("min_gap");
        assert!(min_gap > 1.0, "follower {} came within {min_gap} m", follower["id"]);
        let mean = follower["mean_time_gap"].as_f64().expect("moving followers have a mean time gap");
        assert!(mean > 1.5 && mean < 2.5, "ACC at 1.5 s + 2 m: mean time gap {mean} s for {}", follower["id"]);
    }
}

#[test]
fn platoon_brake_runs_without_collision_and_is_string_stable() {
    let summary = run("platoon_brake");
    let m = metrics_without_collision(&summary);
    assert_eq!(followers(m).len(), 4);
    let platoons = m["platoons"].as_array().expect("platoons is a list");
    assert_eq!(platoons.len(), 1, "{platoons:?}");
    let p = &platoons[0];
    assert_eq!(p["members"].as_array().map(Vec::len), Some(5), "5 trucks: {p}");
    assert_eq!(p["string_stable"], true, "{p}");
    // The leader stops from 15 m/s: its speed range is 15 m/s; nobody's is larger.
    let amplitudes: Vec<f64> = p["speed_amplitudes"].as_array().unwrap().iter().filter_map(Value::as_f64).collect();
    assert!((amplitudes[0] - 15.0).abs() < 0.1, "{amplitudes:?}");
}

#[test]
fn platoon_merge_runs_without_collision_and_the_platoon_stays_together() {
    let summary = run("platoon_merge");
    let m = metrics_without_collision(&summary);
    let platoons = m["platoons"].as_array().expect("platoons is a list");
    assert_eq!(platoons[0]["members"].as_array().map(Vec::len), Some(3), "{platoons:?}");
}

#[test]
fn intersection_runs_without_collision() {
    let summary = run("intersection");
    let m = metrics_without_collision(&summary);
    assert!(!followers(m).is_empty(), "vehicles queue behind each other at the junction");
    assert_eq!(summary["vehicles"], 8);
}

#[test]
fn platoon_scenarios_are_deterministic() {
    // Beacons, claims and membership make no run-to-run difference: same scenario, same states.
    for name in ["platoon_merge", "platoon_brake"] {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("scenarios").join(format!("{name}.toml"));
        let scenario = Scenario::load(&path).expect("the demo scenario loads");
        let hash = || {
            let mut sim = scenario.builder().expect("builds").build();
            sim.run_for(35.0);
            sim.state_hash()
        };
        assert_eq!(hash(), hash(), "{name}");
    }
}
