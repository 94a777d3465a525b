//! Cruise control step and dip responses, the collision geometry, time to collision, and
//! scenario errors for bad controller settings.

mod vehicles_support;

use std::path::Path as FsPath;

use smlworld::app::Scenario;
use smlworld::app::running::metrics::rectangles_overlap;
use smlworld::prelude::*;
use smlworld::vehicles::{CruiseControl, CruiseController, SpeedDip, time_to_collision};
use vehicles_support::{builder, spawn, straight};

fn cruising(from: f64, cruise: f64, dip: Option<SpeedDip>) -> Sim {
    let road = straight(DVec2::ZERO, DVec2::new(5000.0, 0.0));
    let mut b = builder(0.0);
    spawn(
        &mut b,
        -1,
        &road,
        10.0,
        from,
        4.12,
        cruise,
        CruiseController::new(CruiseControl { dip, ..Default::default() }),
    );
    b.build()
}

#[test]
fn cruise_control_reaches_and_holds_the_set_speed() {
    // From rest the reference ramps at 2 m/s²: 20 m/s after 10 s, then held.
    let mut sim = cruising(0.0, 20.0, None);
    sim.run_for(5.0);
    let v = sim.state(VehicleId(-1)).unwrap().speed();
    assert!((v - 10.0).abs() < 0.5, "half way up the 2 m/s² ramp: {v} m/s");
    sim.run_for(15.0);
    let v = sim.state(VehicleId(-1)).unwrap().speed();
    assert!((v - 20.0).abs() < 0.05, "holds 20 m/s: {v}");
}

#[test]
fn a_scripted_dip_brakes_at_its_deceleration_and_comes_back() {
    let dip = SpeedDip { at: 5.0, speed: 10.0, deceleration: 2.0, hold: 3.0 };
    let mut sim = cruising(20.0, 20.0, Some(dip));
    sim.run_for(7.5);
    let v = sim.state(VehicleId(-1)).unwrap().speed();
    assert!((v - 15.0).abs() < 0.3, "20 − 2·2.5 = 15 m/s, got {v}");
    sim.run_for(3.5);
    let v = sim.state(VehicleId(-1)).unwrap().speed();
    assert!((v - 10.0).abs() < 0.3, "holding 10 m/s, got {v}");
    sim.run_for(15.0);
    let v = sim.state(VehicleId(-1)).unwrap().speed();
    assert!((v - 20.0).abs() < 0.1, "back at 20 m/s, got {v}");
}

#[test]
fn rectangles_overlap_by_separating_axes() {
    let car = VehicleSize { length: 4.0, width: 2.0 };
    // Nose to tail along x: they touch when centres are 4 m apart.
    assert!(rectangles_overlap(DVec2::ZERO, 0.0, &car, DVec2::new(3.99, 0.0), 0.0, &car));
    assert!(!rectangles_overlap(DVec2::ZERO, 0.0, &car, DVec2::new(4.01, 0.0), 0.0, &car));
    // Side by side: 2 m.
    assert!(!rectangles_overlap(DVec2::ZERO, 0.0, &car, DVec2::new(0.0, 2.01), 0.0, &car));
    // A car turned 90° in front: its half width (1 m) plus our half length (2 m).
    let turned = std::f64::consts::FRAC_PI_2;
    assert!(rectangles_overlap(DVec2::ZERO, 0.0, &car, DVec2::new(2.99, 0.0), turned, &car));
    assert!(!rectangles_overlap(DVec2::ZERO, 0.0, &car, DVec2::new(3.01, 0.0), turned, &car));
    // Corner to corner at 45°: a diamond's tip reaches √(2² + 1²)·cos(45° − atan(1/2)) ≈ 2.12 m.
    let tip = (5.0f64).sqrt() * (std::f64::consts::FRAC_PI_4 - 0.5f64.atan()).cos();
    assert!(rectangles_overlap(
        DVec2::ZERO,
        0.0,
        &car,
        DVec2::new(2.0 + tip - 0.01, 0.0),
        std::f64::consts::FRAC_PI_4,
        &car
    ));
    assert!(!rectangles_overlap(
        DVec2::ZERO,
        0.0,
        &car,
        DVec2::new(2.0 + tip + 0.01, 0.0),
        std::f64::consts::FRAC_PI_4,
        &car
    ));
}

#[test]
fn time_to_collision_is_gap_over_closing_speed() {
    assert_eq!(time_to_collision(30.0, 10.0), 3.0);
    assert_eq!(time_to_collision(30.0, 0.0), f64::INFINITY);
    assert_eq!(time_to_collision(30.0, -2.0), f64::INFINITY);
    assert_eq!(time_to_collision(-0.1, 5.0), 0.0);
}

fn scenario_error(controller: &str) -> String {
    let text = format!("[[vehicles]]\nid = -1\nroute = {{ loop = \"ring\" }}\ncontroller = {controller}\n");
    match Scenario::parse_str(&text, FsPath::new("/nowhere/bad.toml")) {
        Ok(_) => panic!("accepted a bad controller: {controller}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bad_controller_settings_name_the_key() {
    let e = scenario_error("{ type = \"acc\", acc = { time_gap = -1.0 } }");
    assert!(e.contains("vehicles[0] (id -1).controller.acc.time_gap") && e.contains("zero or more"), "{e}");
    let e = scenario_error("{ type = \"platoon\", role = \"follower\", platoon = { beacon_timeout = 0.0 } }");
    assert!(e.contains("controller.platoon.beacon_timeout") && e.contains("positive"), "{e}");
    let e = scenario_error("{ type = \"platoon\", role = \"follower\", fallback = { time_gap = -1.0 } }");
    assert!(e.contains("controller.fallback.time_gap"), "{e}");
    let both = "platoon = { beacon_timeout = 0.5 }, fallback = { beacon_timeout = 0.3 }";
    let e = scenario_error(&format!("{{ type = \"platoon\", role = \"follower\", {both} }}"));
    assert!(e.contains("controller.platoon.beacon_timeout") && e.contains("fallback.beacon_timeout"), "{e}");
    let e = scenario_error("{ type = \"acc\", acc = { time_gapp = 1.0 } }");
    assert!(e.contains("time_gapp") && e.contains("time_gap"), "unknown key named, allowed ones listed: {e}");
    let e = scenario_error("{ type = \"platoon\", role = \"boss\" }");
    assert!(e.contains("boss") && e.contains("leader") && e.contains("follower"), "{e}");
    let e = scenario_error("{ type = \"adaptive\" }");
    assert!(e.contains("adaptive") && e.contains("acc") && e.contains("platoon"), "{e}");
    let text = "[[vehicles]]\nid = -1\ncontroller = { type = \"cruise_control\" }\n";
    let e = Scenario::parse_str(text, FsPath::new("/nowhere/bad.toml")).expect_err("no route").to_string();
    assert!(e.contains("controller") && e.contains("route"), "{e}");
}
