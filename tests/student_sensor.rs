//! The student sensor (`examples/student_sensor.rs`) compiled into this test: its plugin
//! registers `camera`; its detections equal a brute-force O(N²) reference, its noise does not
//! depend on the thread count, a misspelt key is refused, and the example scenario runs.

#[allow(dead_code)] // main() is the example's own entry point
#[path = "../examples/student_sensor.rs"]
mod student;

use std::path::{Path, PathBuf};

use smlworld::prelude::*;
use smlworld::sim::Parallelism;
use smlworld::sim::random::uniform;
use smlworld::sim::sensor_plugins::attach_sensor;

fn scenario_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/student_sensor.toml")
}

fn parse(text: &str) -> Result<Scenario, ScenarioError> {
    let mut b = SimBuilder::new();
    b.add_plugin(student::CameraPlugin);
    Scenario::parse_str_with(text, &scenario_path(), b.controllers())
}

/// 200 parked vehicles at random places and headings in a 300 m square, each with a camera
/// (`occlusion` as given, no noise), after one sensor tick; and their states.
fn parked_cameras(occlusion: bool) -> (Sim, Vec<(VehicleId, VehicleState)>) {
    let mut b = SimBuilder::new();
    b.add_plugin(default_plugins).add_plugin(student::CameraPlugin);
    let camera = student::Camera { fov_deg: 100.0, range: 60.0, occlusion, range_sd: 0.0, dropout: 0.0 };
    for i in 0..200u64 {
        let p = DVec2::new(300.0 * uniform(1, 1, i, 0), 300.0 * uniform(1, 1, i, 1));
        let yaw = std::f64::consts::TAU * uniform(1, 1, i, 2);
        let e = b.spawn_vehicle(VehicleSpec::new(VehicleId(-1 - i as i32), VehicleState::new(p, yaw, 0.0))).unwrap();
        attach_sensor(&mut b.world_mut().entity_mut(e), "camera", camera);
    }
    let mut sim = b.build();
    sim.run_for(0.01);
    let states = sim.states();
    (sim, states)
}

fn camera_ids(sim: &Sim, id: VehicleId) -> Vec<VehicleId> {
    let readings = sim.world().get::<SensorReadings>(sim.entity(id).unwrap()).unwrap();
    readings.of("camera").map(|d| d.id).collect()
}

#[test]
fn detections_equal_a_brute_force_reference_on_200_random_vehicles() {
    let (sim, states) = parked_cameras(false);
    let (fov, range) = (100f64.to_radians(), 60.0);
    let mut total = 0;
    for (id, me) in &states {
        // O(N²): every other vehicle, nearest first (ties by id), inside range and cone.
        let mut expected: Vec<(f64, VehicleId)> = states
            .iter()
            .filter(|(other, s)| {
                let rel = s.position - me.position;
                other != id
                    && rel.length() <= range
                    && smlworld::sim::in_radar_cone(rel, DVec2::from_angle(me.yaw), fov)
            })
            .map(|(other, s)| (s.position.distance_squared(me.position), *other))
            .collect();
        expected.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let expected: Vec<VehicleId> = expected.into_iter().map(|(_, id)| id).collect();
        total += expected.len();
        assert_eq!(camera_ids(&sim, *id), expected, "vehicle {id}");
    }
    assert!(total > 200, "the reference saw {total} vehicles in all: too few to test anything");
    // Occlusion hides some of them and adds none.
    let (occluded, _) = parked_cameras(true);
    let mut hidden = 0;
    for (id, _) in &states {
        let (all, seen) = (camera_ids(&sim, *id), camera_ids(&occluded, *id));
        assert!(seen.iter().all(|s| all.contains(s)), "vehicle {id}: occlusion added a detection");
        hidden += all.len() - seen.len();
    }
    assert!(hidden > 0, "no vehicle hidden among 200");
}

/// The example scenario with `threads`, after 20 s: every camera detection's bits and the
/// camera's counts.
fn noisy_run(threads: usize) -> (Vec<(i32, u64, u64)>, String) {
    let text = std::fs::read_to_string(scenario_path()).unwrap();
    let mut b = SimBuilder::new();
    b.add_plugin(student::CameraPlugin);
    let scenario = Scenario::parse_str_with(&text, &scenario_path(), b.controllers()).expect("loads");
    scenario.assemble(&mut b).expect("assembles");
    b.insert_resource(Parallelism { threads, min_vehicles: 0 });
    let mut sim = b.build();
    let mut bits = Vec::new();
    for _ in 0..40 {
        sim.run_for(0.5);
        let readings = sim.world().get::<SensorReadings>(sim.entity(VehicleId(-4)).unwrap()).unwrap();
        bits.extend(readings.of("camera").map(|d| (d.id.0, d.position.x.to_bits(), d.position.y.to_bits())));
    }
    let stats = sim.world().resource::<smlworld::sim::PluginSensorStats>();
    (bits, format!("{:?}", stats.0))
}

#[test]
fn camera_noise_is_the_same_on_1_and_2_threads() {
    let (one, stats_one) = noisy_run(1);
    let (two, stats_two) = noisy_run(2);
    assert!(!one.is_empty(), "the camera saw nothing");
    assert_eq!(one, two, "1 vs 2 threads");
    assert_eq!(stats_one, stats_two);
}

#[test]
fn a_misspelt_key_or_unknown_sensor_is_refused_with_its_key() {
    let text = std::fs::read_to_string(scenario_path()).unwrap();
    let e = parse(&text.replace("fov_deg", "fov_degs")).expect_err("misspelt").to_string();
    assert!(e.contains("sensors.camera") && e.contains("fov_degs"), "{e}");
    let e = parse(&text.replace("camera =", "camra =")).expect_err("unknown sensor").to_string();
    assert!(e.contains("sensors.camra") && e.contains("camera"), "the known ones are listed: {e}");
    let e = parse(&text.replace("fov_deg = 90.0", "fov_deg = 400.0")).expect_err("too wide").to_string();
    assert!(e.contains("sensors.camera.fov_deg") && e.contains("400"), "{e}");
    let e = Scenario::parse_str(&text, &scenario_path()).expect_err("no plugin").to_string();
    assert!(e.contains("camera") && e.contains("register_sensor"), "{e}");
    parse(&text).expect("the shipped scenario loads with the plugin");
}

#[test]
fn the_example_scenario_runs_and_its_camera_counts_show_in_the_summary() {
    let mut b = SimBuilder::new();
    b.add_plugin(student::CameraPlugin);
    let scenario = Scenario::load_with(&scenario_path(), b.controllers()).expect("loads");
    let out = std::env::temp_dir().join(format!("smlworld-student-sensor-{}", std::process::id()));
    let options = RunOptions { progress: false, ..RunOptions::default() }.out(&out).plugin(student::CameraPlugin);
    let summary = run_scenario(scenario, options).expect("run");
    let json = std::fs::read_to_string(out.join("summary.json")).expect("summary.json");
    let _ = std::fs::remove_dir_all(&out);
    let sensors = summary.metrics.expect("metrics").sensors.expect("sensor metrics");
    let camera = sensors.by_sensor.get("camera").expect("the camera's counts");
    assert!(camera.detections > 100, "{camera:?}");
    assert!(camera.missed_by_occlusion > 0 && camera.missed_by_dropout > 0, "{camera:?}");
    assert!(json.contains("\"by_sensor\""), "summary.json has the breakdown");
}
