//! The student API: a controller registered by a plugin is named in a scenario like a built-in
//! one, `examples/student_controller.rs` runs `scenarios/student.toml` through `run_scenario`,
//! and a controller written the documented way (an acceleration demand) brakes on both models.

use std::path::{Path, PathBuf};
use std::process::Command;

use smlworld::prelude::*;

fn manifest() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The example binary `cargo test` builds beside the test binaries (target/<profile>/examples).
fn example_binary() -> PathBuf {
    let exe = std::env::current_exe().expect("test binary path");
    let profile = exe.parent().and_then(Path::parent).expect("target/<profile>/deps/<test>");
    profile.join("examples").join("student_controller")
}

fn fresh_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("smlworld-student-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// The student scenario with its map path made absolute and the gap set to `gap` [m].
fn student_scenario_with_gap(dir: &Path, gap: f64) -> PathBuf {
    let text = std::fs::read_to_string(manifest().join("scenarios/student.toml")).expect("shipped scenario");
    let map = manifest().join("maps/highway_ring.osm");
    let text = text
        .replace("\"../maps/highway_ring.osm\"", &format!("{:?}", map.display().to_string()))
        .replace("gap = 25.0", &format!("gap = {gap:.1}"));
    std::fs::create_dir_all(dir).expect("temp dir");
    let path = dir.join("student.toml");
    std::fs::write(&path, text).expect("write scenario");
    path
}

/// Run the example on `scenario` into `out`; returns the follower statistics of vehicle -2.
fn run_example(scenario: &Path, out: &Path) -> serde_json::Value {
    let output = Command::new(example_binary()).arg(scenario).arg(out).output().expect("run the example");
    assert!(output.status.success(), "example failed: {}", String::from_utf8_lossy(&output.stderr));
    assert!(out.join("trajectories.csv").is_file(), "trajectories.csv written");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).expect("summary.json")).expect("json");
    assert_eq!(summary["metrics"]["collision_count"], 0, "{summary}");
    let followers = summary["metrics"]["followers"].as_array().expect("followers");
    followers.iter().find(|f| f["id"] == -2).cloned().expect("vehicle -2 follows")
}

#[test]
fn the_example_runs_the_student_scenario_and_keeps_the_gap_it_is_given() {
    let dir = fresh_dir("gap");
    for gap in [25.0, 40.0] {
        let scenario = student_scenario_with_gap(&dir.join(format!("gap{gap}")), gap);
        let stats = run_example(&scenario, &dir.join(format!("out{gap}")));
        let min_gap = stats["min_gap"].as_f64().expect("min_gap");
        // The leader brakes at 3 m/s² from 14 to 6 m/s: a spring-damper on the gap gives way by
        // at most a few metres and never closes in much beyond that.
        assert!(min_gap > gap - 6.0 && min_gap < gap + 3.0, "gap {gap} m asked, smallest gap {min_gap} m");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_default_example_run_writes_both_outputs() {
    let out = fresh_dir("default");
    let output = Command::new(example_binary())
        .current_dir(manifest())
        .arg("scenarios/student.toml")
        .arg(&out)
        .output()
        .expect("run the example");
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert!(out.join("trajectories.csv").is_file() && out.join("summary.json").is_file());
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn without_the_plugin_the_scenario_names_an_unknown_controller() {
    let out = fresh_dir("noplugin");
    let output = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .current_dir(manifest())
        .args(["run", "scenarios/student.toml", "--out"])
        .arg(&out)
        .output()
        .expect("run smlworld");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "accepted an unregistered controller");
    assert!(
        stderr.contains("vehicles[1] (id -2).controller.type")
            && stderr.contains("my_cautious")
            && stderr.contains("acc")
            && stderr.contains("platoon"),
        "the error names the key, the unknown name and the known ones: {stderr}"
    );
    assert!(!out.exists(), "a run that cannot start writes nothing");
}

/// A controller written the documented way: after `from` [s] it asks for `accel` [m/s²].
#[derive(Component, serde::Deserialize, Clone, Copy)]
#[serde(deny_unknown_fields)]
struct Brake {
    from: f64,
    accel: f64,
}

impl ScenarioController for Brake {
    fn cruise_speed(&self) -> Option<f64> {
        Some(14.0)
    }
    fn attach(&self, vehicle: &mut EntityWorldMut<'_>) {
        vehicle.insert(*self);
    }
}

fn demand_braking(clock: Res<SimClock>, mut vehicles: Query<(&Brake, &mut Longitudinal)>) {
    for (b, mut lon) in &mut vehicles {
        if clock.now.as_secs() >= b.from {
            lon.accel = b.accel;
        }
    }
}

fn brake_plugin(sim: &mut SimBuilder) {
    sim.register_controller::<Brake>("brake");
    sim.add_systems(Control, demand_braking.in_set(LongitudinalSystems::Demand));
}

fn speed_after_braking(model: &str) -> f64 {
    let text = format!(
        "map = \"../maps/highway_ring.osm\"\n[[vehicles]]\nid = -1\nmodel = {{ type = \"{model}\" }}\n\
         route = {{ loop = \"right_lane_node\" }}\nspeed = 14.0\ncontroller = {{ type = \"brake\", from = 2.0, accel = -2.0 }}\n"
    );
    let mut b = SimBuilder::new();
    b.add_plugin(brake_plugin);
    let scenario = Scenario::parse_str_with(&text, &manifest().join("scenarios/brake.toml"), b.controllers())
        .expect("registered controller accepted");
    scenario.assemble(&mut b).expect("assembled");
    let mut sim = b.build();
    sim.run_for(6.0);
    sim.state(VehicleId(-1)).expect("vehicle").speed()
}

#[test]
fn a_demand_brakes_on_both_vehicle_models() {
    // 14 m/s, then -2 m/s² from 2 s to 6 s: about 6 m/s on either model.
    for model in ["kinematic", "acceleration"] {
        let v = speed_after_braking(model);
        assert!((v - 6.0).abs() < 0.6, "{model} model: {v} m/s after braking");
    }
}

#[test]
fn registering_a_built_in_or_taken_name_is_refused() {
    let mut registry = ControllerRegistry::default();
    assert!(registry.register::<Brake>("acc").is_err(), "built-in name");
    registry.register::<Brake>("brake").expect("fresh name");
    assert!(registry.register::<Brake>("brake").is_err(), "taken name");
}

#[test]
fn bad_parameters_of_a_registered_controller_name_the_key() {
    let text = "map = \"../maps/highway_ring.osm\"\n[[vehicles]]\nid = -1\nroute = { loop = \"right_lane_node\" }\n\
                controller = { type = \"brake\", from = 2.0, acel = -2.0 }\n";
    let mut b = SimBuilder::new();
    b.add_plugin(brake_plugin);
    let e = Scenario::parse_str_with(text, &manifest().join("scenarios/brake.toml"), b.controllers())
        .expect_err("unknown key")
        .to_string();
    assert!(e.contains("vehicles[0] (id -1).controller") && e.contains("acel"), "{e}");
}
