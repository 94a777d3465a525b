//! `app::Session` (what the Python package drives): overrides, stepping in chunks, commands that
//! win over controllers, checked arguments.

use std::path::Path;

use smlworld::app::running::session::{apply_override, load_scenario_with_overrides};
use smlworld::app::{Session, StateColumns, run_headless};

const PLATOON: &str = "scenarios/platoon_brake.toml";

#[test]
fn override_through_vehicles_sets_every_follower() {
    let s = load_scenario_with_overrides(
        Path::new(PLATOON),
        Some(11),
        &[("vehicles.controller.platoon.time_gap".into(), toml::Value::Float(0.9))],
    )
    .unwrap();
    assert_eq!(s.file.seed, 11);
    let text = std::fs::read_to_string(PLATOON).unwrap();
    let mut table: toml::Table = toml::from_str(&text).unwrap();
    apply_override(&mut table, "vehicles.controller.platoon.time_gap", toml::Value::Float(0.9)).unwrap();
    let gaps: Vec<f64> = table["vehicles"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|v| v["controller"].get("platoon")?.get("time_gap")?.as_float())
        .collect();
    assert_eq!(gaps, vec![0.9; 4]); // the four followers; the leader has no `platoon` table
    // A misspelt table is created on the way, then refused by the strict parser, naming it.
    let err = load_scenario_with_overrides(Path::new(PLATOON), None, &[("nosuch.key".into(), toml::Value::Integer(1))])
        .unwrap_err()
        .to_string();
    assert!(err.contains("nosuch"), "{err}");
}

#[test]
fn session_steps_in_chunks_like_one_headless_run() {
    let mut a = Session::from_scenario(Path::new(PLATOON), None, &[]).unwrap();
    for _ in 0..40 {
        a.step(0.05).unwrap();
    }
    let scenario = smlworld::app::Scenario::load(Path::new(PLATOON)).unwrap();
    let mut b = scenario.builder().unwrap().build();
    run_headless(&mut b, 2.0, 1.0, |_| {});
    assert_eq!(a.sim().state_hash(), b.state_hash());
}

#[test]
fn commands_win_over_the_controller_and_are_checked() {
    let mut s = Session::from_scenario(Path::new(PLATOON), None, &[]).unwrap();
    s.set_commands(&[-1], Some(&[-60_000.0]), None, None).unwrap();
    s.step(1.0).unwrap();
    let mut cols = StateColumns::default();
    s.states_into(&mut cols);
    let v = cols.vx[4].hypot(cols.vy[4]); // id -1 is last (sorted by id)
    assert_eq!(cols.id, vec![-5, -4, -3, -2, -1]);
    assert!(v < 12.0, "the leader should brake hard, speed {v}");
    s.clear_commands(&[-1]).unwrap();
    let e = s.set_commands(&[-1, -2], Some(&[0.0]), None, None).unwrap_err().to_string();
    assert!(e.contains("1 values for 2 ids"), "{e}");
    let e = s.set_commands(&[-1], None, Some(&[f64::NAN]), None).unwrap_err().to_string();
    assert!(e.contains("steering[0] (vehicle -1) is NaN"), "{e}");
    let e = s.readings(99).unwrap_err().to_string();
    assert!(e.contains("unknown vehicle id 99"), "{e}");
}

/// Issue 22 item 5: a leader driven from outside (Python's `set_commands`) tells its followers
/// (V2V beacons) the acceleration its commands give, so CACC followers brake with it: the
/// platoon_brake leader brakes at 6 m/s² to a stop from 10 s on (before its own dip at 30 s).
#[test]
fn followers_of_a_leader_braking_from_outside_brake_with_it() {
    let mut s = Session::from_scenario(Path::new(PLATOON), None, &[]).unwrap();
    s.step(10.0).unwrap();
    let (mass, drag) = (10_000.0, 500.0);
    let mut cols = StateColumns::default();
    while s.time() < 25.0 {
        s.states_into(&mut cols);
        let i = cols.id.iter().position(|&id| id == -1).unwrap();
        let v = cols.vx[i].hypot(cols.vy[i]);
        let throttle = if v > 0.3 { mass * -6.0 + drag * v } else { 0.0 };
        s.set_commands(&[-1], Some(&[throttle]), None, Some(&[0.0])).unwrap();
        s.step(0.05).unwrap();
    }
    s.states_into(&mut cols);
    let i = cols.id.iter().position(|&id| id == -1).unwrap();
    assert!(cols.vx[i].hypot(cols.vy[i]) < 0.5, "the leader stopped");
    let json = serde_json::to_value(s.summary()).unwrap();
    let m = &json["metrics"];
    assert_eq!(m["collision_count"], 0, "{}", m["collisions"]);
    let followers = m["followers"].as_array().unwrap();
    assert_eq!(followers.len(), 4);
    for f in followers {
        assert!(f["min_gap"].as_f64().unwrap() > 1.0, "{f}");
    }
}

#[test]
fn inbox_returns_every_message_since_the_last_call() {
    let mut s = Session::from_scenario(Path::new(PLATOON), None, &[]).unwrap();
    assert!(s.inbox(-2, "wifi").unwrap().is_empty(), "nothing sent yet");
    // One message per wifi round (10 Hz) for 5 rounds, read once at the end: a V2V in-box holds
    // only the rounds since the last control tick, the session keeps all of them.
    for k in 0..5u8 {
        s.send(-1, "wifi", vec![k]).unwrap();
        s.step(0.1).unwrap();
    }
    let got = s.inbox(-2, "wifi").unwrap();
    assert_eq!(got, (0..5u8).map(|k| (-1, vec![k])).collect::<Vec<_>>());
    assert!(s.inbox(-2, "wifi").unwrap().is_empty(), "read twice");
    s.send(-1, "wifi", vec![9]).unwrap();
    s.step(0.1).unwrap();
    assert_eq!(s.inbox(-2, "wifi").unwrap(), vec![(-1, vec![9])]);
    assert!(s.inbox(-2, "network").unwrap().is_empty());
    assert!(s.inbox(-2, "radio").is_err());
}

/// Issue 22 item 12: `inbox()` keeps at most `INBOX_CAPACITY` unread messages per vehicle and
/// channel; past it the oldest are dropped first, so the newest are the ones returned.
#[test]
fn inbox_keeps_the_newest_messages_when_more_than_its_bound_wait() {
    use smlworld::app::running::session::INBOX_CAPACITY;
    let mut s = Session::from_scenario(Path::new(PLATOON), None, &[]).unwrap();
    assert!(s.inbox(-2, "wifi").unwrap().is_empty(), "from now on every message is kept until read");
    // 10 over the bound, in three wifi rounds (10 Hz), numbered in the order they were sent.
    let total = INBOX_CAPACITY as u32 + 10;
    let rounds = [0..4_000, 4_000..8_000, 8_000..total];
    for r in rounds {
        for k in r {
            s.send(-1, "wifi", k.to_le_bytes().to_vec()).unwrap();
        }
        s.step(0.1).unwrap();
    }
    let got = s.inbox(-2, "wifi").unwrap();
    assert_eq!(got.len(), INBOX_CAPACITY, "the bound");
    let numbers: Vec<u32> = got
        .iter()
        .map(|(sender, b)| {
            assert_eq!(*sender, -1);
            u32::from_le_bytes(b.as_slice().try_into().unwrap())
        })
        .collect();
    // The 10 oldest dropped, the rest in the order sent (compared in short: 10,000 numbers).
    assert_eq!((numbers[0], numbers[numbers.len() - 1]), (10, total - 1), "first and last kept");
    assert!(numbers.windows(2).all(|w| w[1] == w[0] + 1), "in order, none missing");
    assert!(s.inbox(-2, "wifi").unwrap().is_empty(), "read once");
    // Below the bound again, nothing is dropped.
    s.send(-1, "wifi", vec![7]).unwrap();
    s.step(0.1).unwrap();
    assert_eq!(s.inbox(-2, "wifi").unwrap(), vec![(-1, vec![7])]);
}

#[test]
fn stopping_the_metrics_changes_no_trajectory() {
    // The merge environment's scenario: IDM traffic with lane changes on the lane-drop map.
    let path = Path::new("python/smlworld/data/highway_merge.toml");
    let mut with = Session::from_scenario(path, Some(5), &[]).unwrap();
    let mut without = Session::from_scenario(path, Some(5), &[]).unwrap();
    without.stop_metrics();
    for _ in 0..30 {
        with.step(0.5).unwrap();
        without.step(0.5).unwrap();
        assert_eq!(with.sim().state_hash(), without.sim().state_hash(), "t = {} s", with.time());
    }
    let followers = |s: &Session| s.summary().metrics.map_or(0, |m| m.followers.len());
    assert!(followers(&with) > 0, "the recorded run has follower statistics");
    assert_eq!(followers(&without), 0, "nothing is recorded after stop_metrics");
}
