//! The student channel model (`examples/student_channel.rs`) compiled into this test: its
//! plugin registers `log_distance`, the scenario names it, its delivered share follows its
//! formula, and a misspelt key or model name is refused with the key named.

#[allow(dead_code)] // main() is the example's own entry point
#[path = "../examples/student_channel.rs"]
mod student;

use std::path::{Path, PathBuf};

use smlworld::prelude::*;
use smlworld::sim::Parallelism;
use smlworld::sim::channel::{ChannelModel, Draw, LinkState, Loss};
use smlworld::sim::channel_models::PluginLoss;

fn manifest() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn scenario_path() -> PathBuf {
    manifest().join("scenarios/student_channel.toml")
}

fn model() -> student::LogDistance {
    student::LogDistance {
        tx_power_dbm: 20.0,
        loss_at_1m_db: 40.0,
        exponent: 3.0,
        shadowing_sd_db: 4.0,
        sensitivity_dbm: -76.0,
    }
}

fn parse(text: &str) -> Result<Scenario, ScenarioError> {
    let mut b = SimBuilder::new();
    b.add_plugin(student::LogDistancePlugin);
    Scenario::parse_str_with(text, &scenario_path(), b.controllers())
}

#[test]
fn the_delivered_ratio_matches_the_formula_over_10000_draws() {
    let channel = ChannelModel { loss: Loss::Plugin(PluginLoss::new(model())), ..Default::default() };
    let n = 10_000u64;
    for distance in [30.0, 60.0, 90.0] {
        let delivered = (0..n)
            .filter(|&r| {
                let draw = Draw { seed: 3, stream: 1, sender: -1, receiver: -2, round: r, index: 0 };
                channel.deliver(&draw, r * 100_000, distance, 100.0, &mut LinkState::default()).is_some()
            })
            .count() as f64
            / n as f64;
        let p = model().delivery_ratio(distance);
        let sd = (p * (1.0 - p) / n as f64).sqrt();
        assert!((delivered - p).abs() <= 4.0 * sd + 1e-9, "{distance} m: delivered {delivered}, formula {p}");
    }
    // The three distances lie on the falling part of the curve, so the check can fail.
    assert!(model().delivery_ratio(30.0) > 0.99 && model().delivery_ratio(90.0) < 0.3);
    assert!((student::normal_cdf(1.0) - 0.841_344_746).abs() < 1e-6);
}

#[test]
fn the_example_scenario_runs_and_loses_far_beacons() {
    let mut b = SimBuilder::new();
    b.add_plugin(student::LogDistancePlugin);
    let scenario = Scenario::load_with(&scenario_path(), b.controllers()).expect("the registered model is accepted");
    let out = std::env::temp_dir().join(format!("smlworld-student-channel-{}", std::process::id()));
    let options = RunOptions { progress: false, ..RunOptions::default() }.out(&out).plugin(student::LogDistancePlugin);
    let summary = run_scenario(scenario, options).expect("run");
    let _ = std::fs::remove_dir_all(&out);
    let metrics = summary.metrics.expect("metrics");
    assert_eq!(metrics.collision_count, 0);
    let wifi = metrics.v2v.expect("v2v metrics").wifi;
    let share = wifi.delivered as f64 / wifi.sent as f64;
    assert!(wifi.sent > 1000 && share > 0.5 && share < 0.95, "wifi delivered {} of {}", wifi.delivered, wifi.sent);
}

#[test]
fn threads_do_not_change_a_run_with_the_plugin_model() {
    let run = |threads: usize| {
        let text = std::fs::read_to_string(scenario_path()).expect("shipped scenario");
        let mut b = SimBuilder::new();
        b.add_plugin(student::LogDistancePlugin);
        let scenario = Scenario::parse_str_with(&text, &scenario_path(), b.controllers()).expect("loads");
        scenario.assemble(&mut b).expect("assembles");
        b.insert_resource(Parallelism { threads, min_vehicles: 0 });
        let mut sim = b.build();
        sim.run_for(40.0);
        (sim.state_hash(), sim.world().resource::<V2vStats>().wifi_delivered)
    };
    assert_eq!(run(1), run(2));
}

#[test]
fn a_misspelt_key_or_model_is_refused_with_its_key() {
    let text = std::fs::read_to_string(scenario_path()).expect("shipped scenario");
    let misspelt = text.replace("shadowing_sd_db", "shadowing_sd");
    let e = parse(&misspelt).expect_err("misspelt key").to_string();
    assert!(e.contains("v2v.wifi.loss") && e.contains("shadowing_sd"), "{e}");
    let unknown = text.replace("\"log_distance\"", "\"log_distanse\"");
    let e = parse(&unknown).expect_err("unknown model").to_string();
    assert!(e.contains("v2v.wifi.loss.model") && e.contains("log_distanse"), "{e}");
    assert!(e.contains("log_distance") && e.contains("gilbert_elliott"), "the known models are listed: {e}");
    let bad = text.replace("exponent = 3.0", "exponent = -1.0");
    let e = parse(&bad).expect_err("negative exponent").to_string();
    assert!(e.contains("v2v.wifi.loss.exponent"), "{e}");
    // Without the plugin the model is unknown.
    let e = Scenario::parse_str(&text, &scenario_path()).expect_err("no plugin").to_string();
    assert!(e.contains("log_distance") && e.contains("register_channel_model"), "{e}");
    parse(&text).expect("the shipped scenario loads with the plugin");
}
