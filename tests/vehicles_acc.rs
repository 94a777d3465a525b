//! ACC on radar: steady time gap behind a constant-speed leader, no collision when the leader
//! brakes at 6 m/s² from 25 m/s, and emergency braking before a stopped vehicle.

mod vehicles_support;

use smlworld::prelude::*;
use smlworld::vehicles::{
    AccController, AdaptiveCruise, CruiseControl, CruiseController, EmergencyBrake, EmergencyBraking, SpeedDip,
};
use vehicles_support::{builder, gap_x, spawn, straight, summary};

const LENGTH: f64 = 4.12;

/// Leader -1 at `speed` under cruise control (with `dip`), follower -2 `start_gap` [m] behind
/// at the same speed with cruise speed `cruise` [m/s] and `follower` components.
fn two_cars(
    speed: f64,
    dip: Option<SpeedDip>,
    start_gap: f64,
    cruise: f64,
    follower: impl bevy_ecs::prelude::Bundle,
) -> Sim {
    let road = straight(DVec2::ZERO, DVec2::new(4000.0, 0.0));
    let mut b = builder(5.0);
    let lead_s = 200.0;
    spawn(
        &mut b,
        -1,
        &road,
        lead_s,
        speed,
        LENGTH,
        speed,
        CruiseController::new(CruiseControl { dip, ..Default::default() }),
    );
    spawn(&mut b, -2, &road, lead_s - LENGTH - start_gap, speed, LENGTH, cruise, follower);
    b.build()
}

#[test]
fn acc_holds_the_time_gap_within_ten_percent_behind_a_constant_speed_leader() {
    let acc = AdaptiveCruise::default();
    // Start 60 m behind (far from the 2 + 1.5·20 = 32 m wanted), follower faster when alone.
    let mut sim = two_cars(20.0, None, 60.0, 25.0, AccController { params: acc });
    sim.run_for(60.0);
    for _ in 0..20 {
        sim.run_for(0.5);
        let v = sim.state(VehicleId(-2)).unwrap().speed();
        let gap = gap_x(&sim, -1, -2, LENGTH);
        assert!((v - 20.0).abs() < 0.2, "follower speed {v} m/s, leader drives 20 m/s");
        // Time gap on top of the standstill distance: (gap − d₀) / v = h within 10%.
        let time_gap = (gap - acc.standstill) / v;
        assert!((time_gap - 1.5).abs() <= 0.15, "time gap {time_gap} s (gap {gap} m at {v} m/s), wanted 1.5 s ± 10%");
        // Headway gap / v within 10% too (1.5 + 2/20 = 1.6 s).
        assert!((gap / v - 1.5).abs() <= 0.15, "headway {} s", gap / v);
    }
    let m = summary(&sim);
    assert_eq!(m.collision_count, 0);
    let f = m.followers.iter().find(|f| f.id == VehicleId(-2)).expect("the follower is measured");
    assert_eq!(f.leader, VehicleId(-1));
    assert!(f.min_gap > 20.0, "min gap {}", f.min_gap);
}

/// Leader brakes at 6 m/s² from 25 m/s to a stop at t = 20 s.
fn hard_brake() -> Option<SpeedDip> {
    Some(SpeedDip { at: 20.0, speed: 0.0, deceleration: 6.0, hold: f64::INFINITY })
}

#[test]
fn acc_does_not_collide_with_a_leader_braking_at_six_mps2_from_25() {
    let acc = AdaptiveCruise::default();
    let mut sim = two_cars(25.0, hard_brake(), acc.desired_gap(25.0), 30.0, AccController { params: acc });
    sim.run_for(22.0);
    // The leader really brakes at 6 m/s²: 25 − 6·2 = 13 m/s two seconds in.
    let v_lead = sim.state(VehicleId(-1)).unwrap().speed();
    assert!((v_lead - 13.0).abs() < 0.6, "leader at {v_lead} m/s 2 s into a 6 m/s² stop from 25 m/s");
    sim.run_for(18.0);
    assert_eq!(sim.state(VehicleId(-1)).unwrap().speed(), 0.0, "leader stopped");
    assert!(sim.state(VehicleId(-2)).unwrap().speed() < 0.05, "follower stopped");
    let m = summary(&sim);
    assert_eq!(m.collision_count, 0, "collisions: {:?}", m.collisions);
    let gap = gap_x(&sim, -1, -2, LENGTH);
    assert!(gap > 0.5 && gap < acc.standstill + 1.0, "stopped {gap} m behind (standstill distance 2 m)");
}

#[test]
fn plain_cruise_control_does_collide_there_so_the_collision_metric_works() {
    let mut sim = two_cars(25.0, hard_brake(), 39.5, 25.0, CruiseController::new(CruiseControl::default()));
    sim.run_for(30.0);
    let m = summary(&sim);
    assert_eq!(m.collision_count, 1, "one contact episode: {:?}", m.collisions);
    let c = m.collisions[0];
    assert_eq!((c.a, c.b), (VehicleId(-2), VehicleId(-1)));
    // Leader stops 25²/12 = 52 m after 20 s; the follower covers 39.5 + 52 m at 25 m/s by 23.7 s.
    assert!(c.t > 22.0 && c.t < 24.5, "collision at {} s", c.t);
}

#[test]
fn emergency_braking_stops_a_cruising_car_before_a_stopped_one() {
    let road = straight(DVec2::ZERO, DVec2::new(1000.0, 0.0));
    let mut b = builder(0.0);
    // A stopped car (no controller, no model) at 300 m; a car cruising at 15 m/s from 100 m.
    let mut spec = VehicleSpec::new(VehicleId(-1), VehicleState::new(DVec2::new(300.0, 0.0), 0.0, 0.0));
    spec.model = VehicleModel::None;
    b.spawn_vehicle(spec).unwrap();
    let emergency = EmergencyBraking::default();
    spawn(
        &mut b,
        -2,
        &road,
        100.0,
        15.0,
        LENGTH,
        15.0,
        (CruiseController::new(CruiseControl::default()), EmergencyBrake::new(emergency)),
    );
    let mut sim = b.build();
    sim.run_for(30.0);
    let m = summary(&sim);
    assert_eq!(m.collision_count, 0, "collisions: {:?}", m.collisions);
    let s = sim.state(VehicleId(-2)).unwrap();
    assert!(s.speed() < 0.05, "stopped, not at {} m/s", s.speed());
    // Braking at 9 m/s² from 15 m/s takes 12.5 m; triggered at TTC 1.5 s (22.5 m) it stops ~10 m short.
    let gap = 300.0 - s.position.x - LENGTH;
    assert!(gap > 2.0 && gap < 22.5, "stopped {gap} m short");
    let brake = sim.world().get::<EmergencyBrake>(sim.entity(VehicleId(-2)).unwrap()).unwrap();
    assert!(brake.triggered >= 1);
}
