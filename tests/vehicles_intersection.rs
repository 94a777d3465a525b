//! Intersection negotiation over V2V on two straight roads crossing at the origin: with crossing
//! claims nobody collides whatever the arrival times; without them the same traffic collides.

mod vehicles_support;

use smlworld::prelude::*;
use smlworld::vehicles::{AccController, AdaptiveCruise, Crossing, CrossingNegotiator, zone_span};
use vehicles_support::{builder, spawn, straight, summary};

const LENGTH: f64 = 4.12;

/// Two cars eastbound (from x = −100) and two northbound (from y = −100) at 10 m/s, the first of
/// each pair `east` and `north` metres from the start; `negotiate` adds crossing claims.
fn crossing(east: f64, north: f64, negotiate: bool) -> Sim {
    let eastbound = straight(DVec2::new(-100.0, 0.0), DVec2::new(100.0, 0.0));
    let northbound = straight(DVec2::new(0.0, -100.0), DVec2::new(0.0, 100.0));
    let mut b = builder(0.0);
    let acc = AccController { params: AdaptiveCruise::default() };
    let zone = Crossing { center: [0.0, 0.0], radius: 6.0, ..Default::default() };
    for (id, road, s) in [
        (-1, &eastbound, east),
        (-2, &eastbound, east - 25.0),
        (-3, &northbound, north),
        (-4, &northbound, north - 25.0),
    ] {
        if negotiate {
            spawn(&mut b, id, road, s, 10.0, LENGTH, 10.0, (acc, CrossingNegotiator::new(zone)));
        } else {
            spawn(&mut b, id, road, s, 10.0, LENGTH, 10.0, acc);
        }
    }
    b.build()
}

#[test]
fn the_zone_span_is_where_the_route_enters_and_leaves_the_disc() {
    let road = straight(DVec2::new(-100.0, 0.0), DVec2::new(100.0, 0.0));
    let (entry, exit) = zone_span(&road, DVec2::ZERO, 6.0).expect("the road crosses the disc");
    assert!((entry - 94.0).abs() <= 0.5 && (exit - 106.0).abs() <= 0.5, "entry {entry} m, exit {exit} m");
    assert_eq!(zone_span(&road, DVec2::new(0.0, 50.0), 6.0), None);
}

#[test]
fn same_arrival_times_collide_without_negotiation() {
    let mut sim = crossing(40.0, 40.0, false);
    sim.run_for(20.0);
    assert!(summary(&sim).collision_count > 0, "both pairs reach the crossing together: they must collide");
}

#[test]
fn negotiated_crossing_has_no_collision_and_everyone_passes() {
    // Arrival offsets from simultaneous to one car length apart, either road first.
    for (east, north) in [(40.0, 40.0), (40.0, 38.0), (38.0, 40.0), (40.0, 35.0), (45.0, 40.0), (20.0, 40.0)] {
        let mut sim = crossing(east, north, true);
        sim.run_for(40.0);
        let m = summary(&sim);
        assert_eq!(m.collision_count, 0, "start {east}/{north}: {:?}", m.collisions);
        for id in [-1, -2] {
            assert!(sim.state(VehicleId(id)).unwrap().position.x > 10.0, "start {east}/{north}: {id} crossed");
        }
        for id in [-3, -4] {
            assert!(sim.state(VehicleId(id)).unwrap().position.y > 10.0, "start {east}/{north}: {id} crossed");
        }
        let passed =
            |id: i32| sim.world().get::<CrossingNegotiator>(sim.entity(VehicleId(id)).unwrap()).unwrap().passed;
        assert!((-4..=-1).all(passed), "start {east}/{north}: every claim ended");
    }
}
