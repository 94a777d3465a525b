//! Platooning: 0.5 s gaps, a speed dip at the leader that shrinks down the platoon with V2V
//! feed-forward and grows with radar-only ACC at the same gap, a hard stop without collision,
//! joining at the tail and leaving.

mod vehicles_support;

use smlworld::app::running::metrics::MetricsSummary;
use smlworld::prelude::*;
use smlworld::vehicles::{
    AccController, AdaptiveCruise, CruiseControl, CruiseController, PlatoonMember, Platooning, SpeedDip,
};
use vehicles_support::{builder, gap_x, spawn, straight, summary};

const LENGTH: f64 = 8.0;
const N: i32 = 5;

/// Five trucks at 20 m/s and 0.5 s gaps (leader -1, followers -2..-5); the leader dips as `dip`.
/// Followers are platoon members (`v2v`) or radar-only ACC at 0.5 s.
fn platoon(v2v: bool, dip: SpeedDip, road_length: f64) -> Sim {
    let road = straight(DVec2::ZERO, DVec2::new(road_length, 0.0));
    let mut b = builder(10.0);
    let p = Platooning::default();
    let speed = 20.0;
    let cruise = CruiseController::new(CruiseControl { dip: Some(dip), ..Default::default() });
    let mut s = 300.0;
    spawn(&mut b, -1, &road, s, speed, LENGTH, speed, (cruise, PlatoonMember::leader(p)));
    for k in 2..=N {
        s -= LENGTH + p.standstill + p.time_gap * speed;
        if v2v {
            spawn(&mut b, -k, &road, s, speed, LENGTH, speed + 5.0, PlatoonMember::follower(p));
        } else {
            let acc = AdaptiveCruise { time_gap: p.time_gap, ..Default::default() };
            spawn(&mut b, -k, &road, s, speed, LENGTH, speed + 5.0, AccController { params: acc });
        }
    }
    b.build()
}

/// Down to 15 m/s at 1 m/s² at t = 30 s, 5 s there, back up at 2 m/s².
fn dip() -> SpeedDip {
    SpeedDip { at: 30.0, speed: 15.0, deceleration: 1.0, hold: 5.0 }
}

/// Speed range (max − min) of every vehicle after the warm-up, leader first, from ground truth.
fn amplitudes(m: &MetricsSummary) -> Vec<f64> {
    assert_eq!(m.platoons.len(), 1, "one platoon: {:?}", m.platoons);
    m.platoons[0].speed_amplitudes.clone()
}

#[test]
fn platoon_keeps_half_second_gaps_and_a_leader_dip_shrinks_towards_the_tail() {
    let p = Platooning::default();
    let mut sim = platoon(true, dip(), 3000.0);
    sim.run_for(29.0);
    // Steady state before the dip: each gap is d₀ + 0.5 s · v within 10% of the time gap.
    for k in 2..=N {
        let v = sim.state(VehicleId(-k)).unwrap().speed();
        let gap = gap_x(&sim, -(k - 1), -k, LENGTH);
        let time_gap = (gap - p.standstill) / v;
        assert!((time_gap - 0.5).abs() <= 0.05, "follower {}: time gap {time_gap} s (gap {gap} m at {v} m/s)", -k);
        let member = sim.world().get::<PlatoonMember>(sim.entity(VehicleId(-k)).unwrap()).unwrap();
        assert_eq!((member.platoon, member.index), (Some(VehicleId(-1)), (k - 1) as u32), "membership from beacons");
    }
    sim.run_for(41.0);
    let m = summary(&sim);
    assert_eq!(m.collision_count, 0, "{:?}", m.collisions);
    let platoon = &m.platoons[0];
    assert_eq!(platoon.members, (1..=N).map(|k| VehicleId(-k)).collect::<Vec<_>>());
    let a = amplitudes(&m);
    // The leader's dip is 5 m/s; every follower's is smaller than the one ahead of it.
    assert!((a[0] - 5.0).abs() < 0.1, "leader dip {} m/s", a[0]);
    for w in a.windows(2) {
        assert!(w[1] < w[0], "disturbance grew down the platoon: {a:?}");
    }
    assert!(platoon.string_stable && platoon.amplification.is_some_and(|a| a < 1.0), "{platoon:?}");
    for f in &m.followers {
        assert!(f.min_gap > 0.5 * p.standstill, "follower {} came within {} m", f.id, f.min_gap);
    }
}

#[test]
fn radar_only_acc_at_half_a_second_amplifies_the_same_dip() {
    let mut sim = platoon(false, dip(), 3000.0);
    sim.run_for(70.0);
    let m = summary(&sim);
    // Radar-only vehicles are not platoon members: measure their speeds from the followers' list.
    assert!(m.platoons.iter().all(|p| p.members.len() == 1), "only the leader claims a platoon");
    let leader = amplitudes(&m)[0];
    assert!((leader - 5.0).abs() < 0.1, "leader dip {leader} m/s");
    let tail = speed_range_after(&mut platoon(false, dip(), 3000.0), VehicleId(-N), 10.0, 70.0);
    assert!(
        tail > leader * 1.1,
        "radar-only ACC at 0.5 s should amplify the dip: tail {tail} m/s vs leader {leader} m/s"
    );
}

/// Range of vehicle `id`'s speed between `from` and `to` [s], sampled every 0.1 s.
fn speed_range_after(sim: &mut Sim, id: VehicleId, from: f64, to: f64) -> f64 {
    sim.run_for(from);
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    while sim.now().as_secs() < to {
        sim.run_for(0.1);
        let v = sim.state(id).unwrap().speed();
        lo = lo.min(v);
        hi = hi.max(v);
    }
    hi - lo
}

#[test]
fn platoon_stops_without_collision_when_the_leader_brakes_at_six_mps2() {
    let stop = SpeedDip { at: 30.0, speed: 0.0, deceleration: 6.0, hold: f64::INFINITY };
    let mut sim = platoon(true, stop, 3000.0);
    sim.run_for(60.0);
    let m = summary(&sim);
    assert_eq!(m.collision_count, 0, "{:?}", m.collisions);
    for f in &m.followers {
        assert!(f.min_gap > 1.0, "follower {} came within {} m", f.id, f.min_gap);
    }
    for k in 1..=N {
        let v = sim.state(VehicleId(-k)).unwrap().speed();
        assert!(
            v < 0.1,
            "vehicle {} stopped, not at {v} m/s; gaps {:?}",
            -k,
            (2..=N).map(|j| gap_x(&sim, -(j - 1), -j, LENGTH)).collect::<Vec<_>>()
        );
    }
}

#[test]
fn a_vehicle_joins_at_the_tail_and_a_member_leaves() {
    let road = straight(DVec2::ZERO, DVec2::new(5000.0, 0.0));
    let mut b = builder(0.0);
    let p = Platooning::default();
    let speed = 20.0;
    let spacing = LENGTH + p.standstill + p.time_gap * speed;
    let leader = (CruiseController::new(CruiseControl::default()), PlatoonMember::leader(p));
    spawn(&mut b, -1, &road, 400.0, speed, LENGTH, speed, leader);
    spawn(&mut b, -2, &road, 400.0 - spacing, speed, LENGTH, 25.0, PlatoonMember::follower(p));
    spawn(&mut b, -3, &road, 400.0 - 2.0 * spacing, speed, LENGTH, 25.0, PlatoonMember::follower(p));
    // 90 m behind the tail: out of wifi range (50 m), in radar range (100 m).
    spawn(&mut b, -4, &road, 400.0 - 2.0 * spacing - 90.0, speed, LENGTH, 25.0, PlatoonMember::follower(p));
    let mut sim = b.build();
    let member = |sim: &Sim, id: i32| *sim.world().get::<PlatoonMember>(sim.entity(VehicleId(id)).unwrap()).unwrap();
    sim.run_for(1.0);
    assert_eq!(member(&sim, -4).platoon, None, "too far to hear the tail");
    sim.run_for(59.0);
    let joined = member(&sim, -4);
    assert_eq!((joined.platoon, joined.index), (Some(VehicleId(-1)), 3), "joined at the tail");
    let gap = gap_x(&sim, -3, -4, LENGTH);
    let v = sim.state(VehicleId(-4)).unwrap().speed();
    assert!(((gap - p.standstill) / v - p.time_gap).abs() < 0.05, "closed to the platoon gap: {gap} m at {v} m/s");

    let leaving = sim.entity(VehicleId(-2)).unwrap();
    sim.world_mut().get_mut::<PlatoonMember>(leaving).unwrap().leave();
    sim.run_for(30.0);
    assert_eq!(member(&sim, -2).platoon, None, "left");
    assert_eq!(member(&sim, -3).platoon, None, "the platoon ends in front of the vehicle that left");
    assert_eq!(member(&sim, -1).platoon, Some(VehicleId(-1)));
    // Having left, -2 keeps the ACC gap of 1.5 s.
    let gap = gap_x(&sim, -1, -2, LENGTH);
    let v = sim.state(VehicleId(-2)).unwrap().speed();
    assert!(((gap - p.standstill) / v - p.acc_time_gap).abs() < 0.15, "ACC gap after leaving: {gap} m at {v} m/s");
    assert_eq!(summary(&sim).collision_count, 0);
}

#[test]
fn a_follower_whose_beacons_stop_falls_back_to_acc_and_returns_when_they_come_back() {
    use smlworld::sim::channel::Loss;
    let road = straight(DVec2::ZERO, DVec2::new(5000.0, 0.0));
    let mut b = builder(0.0);
    let p = Platooning::default();
    let speed = 20.0;
    let spacing = LENGTH + p.standstill + p.time_gap * speed;
    let leader = (CruiseController::new(CruiseControl::default()), PlatoonMember::leader(p));
    spawn(&mut b, -1, &road, 400.0, speed, LENGTH, speed, leader);
    spawn(&mut b, -2, &road, 400.0 - spacing, speed, LENGTH, 25.0, PlatoonMember::follower(p));
    spawn(&mut b, -3, &road, 400.0 - 2.0 * spacing, speed, LENGTH, 25.0, PlatoonMember::follower(p));
    let mut sim = b.build();
    let member = |sim: &Sim, id: i32| *sim.world().get::<PlatoonMember>(sim.entity(VehicleId(id)).unwrap()).unwrap();
    let time_gap = |sim: &Sim, ahead: i32, behind: i32| {
        (gap_x(sim, ahead, behind, LENGTH) - p.standstill) / sim.state(VehicleId(behind)).unwrap().speed()
    };
    sim.run_for(10.0);
    assert!(!member(&sim, -2).degraded);
    assert!((time_gap(&sim, -1, -2) - p.time_gap).abs() < 0.05);

    // Every wifi reception lost from the round at 10 s on: the newest beacon heard was sent at
    // 9.85 s; the followers fall back once it is older than 3 wifi intervals (0.3 s).
    sim.world_mut().resource_mut::<V2vConfig>().wifi.loss = Loss::Constant(1.0);
    sim.run_for(0.11);
    let m = member(&sim, -2);
    assert!(!m.degraded && m.beacon_age.unwrap() <= 0.3, "fell back early: beacon age {:?}", m.beacon_age);
    sim.run_for(0.1);
    let m = member(&sim, -2);
    assert!(m.degraded && m.beacon_age.unwrap() > 0.3, "no fallback: beacon age {:?}", m.beacon_age);
    assert_eq!((m.platoon, m.index), (Some(VehicleId(-1)), 1), "a degraded follower keeps its place");
    sim.run_for(40.0);
    assert!(member(&sim, -3).degraded);
    let fallback = member(&sim, -2).fallback.time_gap;
    assert!((time_gap(&sim, -1, -2) - fallback).abs() < 0.1, "ACC at the fallback gap: {}", time_gap(&sim, -1, -2));

    sim.world_mut().resource_mut::<V2vConfig>().wifi.loss = Loss::Constant(0.0);
    sim.run_for(40.0);
    assert!(!member(&sim, -2).degraded && !member(&sim, -3).degraded, "beacons back, fallback over");
    assert!((time_gap(&sim, -1, -2) - p.time_gap).abs() < 0.05, "back to the platoon gap");
    let m = summary(&sim);
    assert_eq!(m.collision_count, 0);
    let f = m.followers.iter().find(|f| f.id == VehicleId(-2)).unwrap();
    assert!((f.degraded_s - 40.2).abs() < 0.15, "{}", f.degraded_s);
}
