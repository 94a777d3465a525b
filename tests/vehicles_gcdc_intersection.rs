//! The GCDC 2016 cooperative intersection (issue 59, item 2): `scenarios/gcdc_intersection.toml`
//! run by the CLI with perfect and lossy wifi and with the plain right-of-way, the figures the
//! issue asks for, a participant whose radio dies (nobody crosses its path on a missing claim),
//! and bad `intersection` tables refused with the key.

use std::path::PathBuf;
use std::process::Command;

use serde_json::Value;
use smlworld::app::Scenario;
use smlworld::prelude::*;
use smlworld::vehicles::gcdc_intersection::Decision;
use smlworld::vehicles::{IntersectionNegotiator, PathFollower};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Run `smlworld run scenarios/gcdc_intersection.toml` with `--set` overrides; return summary.json.
fn run(tag: &str, sets: &[&str]) -> Value {
    let out = std::env::temp_dir().join(format!("smlworld-gcdc-x-{tag}-{}", std::process::id()));
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_smlworld"));
    cmd.arg("run").arg(root().join("scenarios/gcdc_intersection.toml")).arg("--out").arg(&out);
    for s in sets {
        cmd.arg("--set").arg(s);
    }
    let output = cmd.current_dir(root()).output().expect("the smlworld binary runs");
    assert!(output.status.success(), "{tag}: {}", String::from_utf8_lossy(&output.stderr));
    let text = std::fs::read_to_string(out.join("summary.json")).expect("summary.json written");
    let summary = serde_json::from_str(&text).expect("summary.json is JSON");
    let _ = std::fs::remove_dir_all(&out);
    summary
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("{v} is not a number"))
}

/// The vehicles of the scenario file, by arm: (id, platoon leader if a platoon member).
fn scenario_vehicles() -> Vec<(i64, String)> {
    let text = std::fs::read_to_string(root().join("scenarios/gcdc_intersection.toml")).unwrap();
    let file: toml::Value = toml::from_str(&text).unwrap();
    file["vehicles"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| (v["id"].as_integer().unwrap(), v["route"]["from"].as_str().unwrap().to_string()))
        .collect()
}

/// What the issue asks of `metrics.intersection`: every field there, no collision, everyone of
/// the scenario crossed, the order a permutation of them, gaps of at least 2 m.
fn assert_crossed(tag: &str, summary: &Value) -> f64 {
    let m = &summary["metrics"];
    let x = &m["intersection"];
    eprintln!("{tag}: {x}");
    for key in ["vehicles", "crossed", "order", "min_gap_m", "min_time_gap_s", "mean_delay_s", "platoon_splits"] {
        assert!(!x[key].is_null(), "{tag}: metrics.intersection.{key} missing: {x}");
    }
    assert_eq!(m["collision_count"], 0, "{tag}: {}", m["collisions"]);
    let vehicles = scenario_vehicles();
    assert_eq!(x["vehicles"].as_u64().unwrap() as usize, vehicles.len(), "{tag}: every vehicle takes part");
    assert_eq!(x["crossed"], x["vehicles"], "{tag}: everyone crosses: {x}");
    let mut order: Vec<i64> = x["order"].as_array().unwrap().iter().map(|v| v.as_i64().unwrap()).collect();
    order.sort_unstable();
    let mut ids: Vec<i64> = vehicles.iter().map(|v| v.0).collect();
    ids.sort_unstable();
    assert_eq!(order, ids, "{tag}: each vehicle enters once");
    assert!(f(&x["min_gap_m"]) >= 2.0, "{tag}: {x}");
    assert!(f(&x["min_time_gap_s"]) > 0.0, "{tag}: {x}");
    f(&x["mean_delay_s"])
}

#[test]
fn the_demand_has_three_vehicles_or_more_on_each_arm_and_platoons() {
    let vehicles = scenario_vehicles();
    for arm in ["west_start", "east_start", "south_start"] {
        let n = vehicles.iter().filter(|v| v.1 == arm).count();
        assert!(n >= 3, "{arm}: {n} vehicles");
    }
    let text = std::fs::read_to_string(root().join("scenarios/gcdc_intersection.toml")).unwrap();
    assert!(text.matches("role = \"follower\"").count() >= 2, "at least one platoon of three");
    assert!(text.contains("message = \"intersection_zone\""), "an RSU announces the zone");
}

#[test]
fn everyone_crosses_without_collisions_with_perfect_and_lossy_wifi() {
    let perfect = run("perfect", &[]);
    assert_crossed("perfect wifi", &perfect);
    assert_eq!(perfect["metrics"]["intersection"]["platoon_splits"], 0, "the platoons stay together");
    let lossy = run("loss", &["v2v.wifi.loss=0.2"]);
    assert_crossed("wifi loss 0.2", &lossy);
    let wifi = &lossy["metrics"]["v2v"]["wifi"];
    let (sent, lost) = (wifi["sent"].as_u64().unwrap(), wifi["lost"].as_u64().unwrap());
    assert!(lost as f64 > 0.15 * sent as f64, "the lossy run lost about a fifth: {wifi}");
}

#[test]
fn the_plain_right_of_way_handles_the_same_demand_and_both_delays_are_measured() {
    let plain = run("plain", &["vehicles.*.controller.intersection.negotiate=false"]);
    let m = &plain["metrics"];
    assert_eq!(m["collision_count"], 0, "{}", m["collisions"]);
    let x = &m["intersection"];
    assert_eq!(x["crossed"], x["vehicles"], "{x}");
    let v2v = run("v2v", &[]);
    // A different rule: a different order (the junction is right before left, the V2V order is
    // first come), both with a positive delay.
    assert_ne!(x["order"], v2v["metrics"]["intersection"]["order"]);
    assert!(f(&x["mean_delay_s"]) > 0.0 && f(&v2v["metrics"]["intersection"]["mean_delay_s"]) > 0.0);
}

/// A participant whose radio dies after everyone has heard it: nobody whose link meets its link
/// enters the zone on the guess that it is gone (missing claims mean stop), while it drives on.
#[test]
fn nobody_crosses_the_path_of_a_participant_whose_messages_stop() {
    let scenario = Scenario::load(&root().join("scenarios/gcdc_intersection.toml")).expect("the scenario loads");
    let mut sim = scenario.builder().expect("the scenario builds").build();
    sim.run_for(3.0);
    let silent = VehicleId(-1);
    let entity = sim.entity(silent).expect("vehicle -1 exists");
    sim.world_mut().entity_mut(entity).remove::<Mailbox>();
    sim.run_for(37.0);
    let world = sim.world_mut();
    let silent_link = {
        let neg = world.get::<IntersectionNegotiator>(entity).unwrap();
        neg.zone.as_ref().unwrap().links[0].0
    };
    assert!(sim.state(silent).unwrap().position.x > 20.0, "the silent vehicle drove through");
    let network = sim.world().resource::<smlworld::vehicles::JunctionNetwork>();
    let conflicting = |link: u32| network.links[link as usize].conflicts.iter().any(|c| c.foe == silent_link);
    let (mut stopped, mut missing) = (0, 0);
    let world = sim.world();
    let mut query = world.try_query::<(&VehicleId, &PathFollower, &IntersectionNegotiator)>().unwrap();
    for (id, follower, neg) in query.iter(world) {
        let zone = neg.zone.as_ref().expect("everyone heard the RSU");
        if *id == silent || !conflicting(zone.links[0].0) {
            continue;
        }
        assert!(follower.s + 2.1 < zone.entry, "{id} entered the path of a participant it no longer hears");
        assert!(neg.decision.is_some_and(|d| d != Decision::Go), "{id}: {:?}", neg.decision);
        missing += usize::from(neg.decision == Some(Decision::Missing(silent)));
        stopped += 1;
    }
    assert!(stopped >= 5, "the vehicles on the links that meet the silent one's: {stopped}");
    // The first of them in the agreed order waits for the silent one's claim; the others queue
    // or yield to vehicles before them (a vehicle names the first reason it finds).
    assert!(missing >= 1, "nobody waits for the silent vehicle's claim");
}

#[test]
fn bad_intersection_tables_are_refused_with_the_key() {
    let base = std::fs::read_to_string(root().join("scenarios/gcdc_intersection.toml")).unwrap();
    let dir = std::env::temp_dir().join(format!("smlworld-gcdc-x-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cases = [
        ("intersection = {}", "intersection = { deceleration = -1.0 }", "intersection.deceleration"),
        ("intersection = {}", "intersection = { stopmargin = 2.0 }", "stopmargin"),
        ("message = \"intersection_zone\"", "message = \"crossroads\"", "crossroads"),
    ];
    for (from, to, expect) in cases {
        let text = base.replacen(from, to, 1).replace("../maps/", &format!("{}/maps/", root().display()));
        let path = dir.join("bad.toml");
        std::fs::write(&path, text).unwrap();
        let err = Scenario::load(&path).and_then(|s| s.builder().map(|_| ())).err();
        let message = err.map(|e| e.to_string()).unwrap_or_default();
        assert!(message.contains(expect), "{to}: {message}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
