//! Sensor geometry at the edges (cone angle, range), no self-detection, ordering, and the
//! spatial grid against a brute-force scan.

use smlworld::prelude::*;
use smlworld::sim::{Parallelism, SensorStats, in_radar_cone};
use smlworld::world::{SensorError, SensorErrors};

/// A sim with sensors only; vehicles have no dynamics so they stay where they are put.
fn world_of(vehicles: &[(i32, DVec2, f64, SensorSet)]) -> Sim {
    world_on(vehicles, 1)
}

/// [`world_of`], sensing split over `threads` threads however few the vehicles.
fn world_on(vehicles: &[(i32, DVec2, f64, SensorSet)], threads: usize) -> Sim {
    let mut b = SimBuilder::new();
    b.insert_resource(Parallelism { threads, min_vehicles: 0 });
    b.add_plugin(SensorsPlugin);
    for &(id, p, yaw, sensors) in vehicles {
        let mut spec = VehicleSpec::new(VehicleId(id), VehicleState::new(p, yaw, 0.0));
        spec.model = VehicleModel::None;
        spec.sensors = sensors;
        b.spawn_vehicle(spec).expect("unique ids");
    }
    let mut sim = b.build();
    sim.run_for(0.01); // one sensor tick, at t = 0
    sim
}

fn seen(sim: &Sim, id: i32) -> Vec<i32> {
    let e = sim.entity(VehicleId(id)).expect("vehicle exists");
    sim.world().get::<SensorReadings>(e).expect("has sensors").0.iter().map(|d| d.id.0).collect()
}

fn radar() -> SensorSet {
    SensorSet { radar: Some(Radar::default()), ..Default::default() }
}

const NONE: SensorSet = SensorSet { radar: None, velodyne: None, omniscient: false };

#[test]
fn radar_cone_edges_in_radians() {
    // Default cone: 60° full opening, so ±30° about the heading; observer heading 20°.
    let yaw = 20f64.to_radians();
    let at = |bearing_deg: f64, eps: f64, distance: f64| {
        let a = yaw + bearing_deg.to_radians() + eps;
        DVec2::new(a.cos(), a.sin()) * distance
    };
    let sim = world_of(&[
        (-1, DVec2::ZERO, yaw, radar()),
        (-2, at(30.0, -1e-6, 40.0), 0.0, NONE),
        (-3, at(30.0, 1e-6, 40.0), 0.0, NONE),
        (-4, at(-30.0, 1e-6, 45.0), 0.0, NONE),
        (-5, at(-30.0, -1e-6, 45.0), 0.0, NONE),
        // 40° off the heading: outside a 60° cone. (A degrees-vs-radians mix-up, as in 2015,
        // would not get this right.)
        (-6, at(40.0, 0.0, 40.0), 0.0, NONE),
    ]);
    assert_eq!(seen(&sim, -1), vec![-2, -4]);
}

#[test]
fn radar_range_is_inclusive_at_the_edge() {
    let sim = world_of(&[
        (-1, DVec2::ZERO, 0.0, radar()),
        (-2, DVec2::new(100.0, 0.0), 0.0, NONE),
        (-3, DVec2::new(100.0 + 1e-6, 1.0), 0.0, NONE),
        (-4, DVec2::new(100.0 - 1e-6, -1.0).normalize() * (100.0 - 1e-6), 0.0, NONE),
    ]);
    assert_eq!(seen(&sim, -1), vec![-4, -2]);
}

#[test]
fn radar_does_not_see_behind_but_velodyne_does() {
    let velodyne = SensorSet { velodyne: Some(Velodyne::default()), ..Default::default() };
    let sim = world_of(&[
        (-1, DVec2::ZERO, 0.0, radar()),
        (-2, DVec2::new(0.0, 100.0), 0.0, velodyne),
        (-3, DVec2::new(-10.0, 0.0), 0.0, NONE),
        (-4, DVec2::new(0.0, 150.0 - 1e-6), 0.0, NONE),
        (-5, DVec2::new(0.0, 51.0), 0.0, NONE),
        (-6, DVec2::new(50.0 + 1e-6, 100.0), 0.0, NONE),
        (-7, DVec2::new(0.0, 50.0 - 1e-6), 0.0, NONE),
    ]);
    assert_eq!(seen(&sim, -1), Vec::<i32>::new());
    assert_eq!(seen(&sim, -2), vec![-5, -4]);
}

#[test]
fn no_self_detection_and_omniscient_sees_everyone_else_nearest_first() {
    let all = SensorSet { radar: Some(Radar::default()), velodyne: Some(Velodyne::default()), omniscient: true };
    let sim = world_of(&[
        (3, DVec2::new(5.0, 0.0), 0.0, all),
        (-7, DVec2::new(10_000.0, 0.0), 0.0, NONE),
        (-8, DVec2::new(5.0, 2.0), 0.0, NONE),
        (-9, DVec2::new(-20.0, 0.0), 0.0, NONE),
        // Co-located with the observer: seen by the velodyne, not confused with itself.
        (-10, DVec2::new(5.0, 0.0), 0.0, NONE),
    ]);
    assert_eq!(seen(&sim, 3), vec![-10, -8, -9, -7]);
}

#[test]
fn readings_carry_position_and_velocity_of_the_target() {
    let mut b = SimBuilder::new();
    b.add_plugin(SensorsPlugin);
    let mut observer = VehicleSpec::new(VehicleId(-1), VehicleState::new(DVec2::ZERO, 0.0, 0.0));
    observer.sensors = radar();
    observer.model = VehicleModel::None;
    b.spawn_vehicle(observer).unwrap();
    let mut target = VehicleSpec::new(VehicleId(-2), VehicleState::new(DVec2::new(30.0, 1.0), 0.5, 7.0));
    target.model = VehicleModel::None;
    b.spawn_vehicle(target).unwrap();
    let mut sim = b.build();
    sim.run_for(0.01);
    let e = sim.entity(VehicleId(-1)).unwrap();
    let readings = &sim.world().get::<SensorReadings>(e).unwrap().0;
    assert_eq!(readings.len(), 1);
    assert_eq!(readings[0].position, DVec2::new(30.0, 1.0));
    assert!((readings[0].velocity - DVec2::new(0.5f64.cos(), 0.5f64.sin()) * 7.0).length() < 1e-12);
}

#[test]
fn cone_test_in_radians() {
    let h = DVec2::X;
    let third = std::f64::consts::FRAC_PI_3;
    assert!(in_radar_cone(DVec2::from_angle(0.5 * third - 1e-9), h, third));
    assert!(!in_radar_cone(DVec2::from_angle(0.5 * third + 1e-9), h, third));
    assert!(in_radar_cone(-DVec2::X, h, std::f64::consts::TAU));
    assert!(!in_radar_cone(DVec2::ZERO, h, third));
}

/// A deterministic pseudo-random sequence in [0, 1).
fn lcg(state: &mut u64) -> f64 {
    *state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    (*state >> 11) as f64 / (1u64 << 53) as f64
}

#[test]
fn grid_sensing_matches_brute_force() {
    let mut rng = 7u64;
    let mut vehicles = Vec::new();
    for i in 0..400 {
        let p = DVec2::new(lcg(&mut rng) * 800.0 - 400.0, lcg(&mut rng) * 800.0 - 400.0);
        let yaw = lcg(&mut rng) * std::f64::consts::TAU;
        let sensors = match i % 3 {
            0 => SensorSet { radar: Some(Radar { angle: 1.0, range: 80.0 }), ..Default::default() },
            1 => SensorSet { velodyne: Some(Velodyne { range: 35.0 }), ..Default::default() },
            _ => SensorSet { radar: Some(Radar::default()), velodyne: Some(Velodyne::default()), omniscient: false },
        };
        vehicles.push((-1 - i, p, yaw, sensors));
    }
    assert_matches_brute_force(&vehicles);
}

#[test]
fn a_few_long_range_sensors_see_as_far_as_their_range_on_a_fine_grid() {
    // Typical 30 m velodynes make 30 m cells; every 25th vehicle has a 500 m radar (17 cells
    // each way) and one a 5 km velodyne (more cells than vehicles: it scans everyone).
    let mut rng = 13u64;
    let mut vehicles = Vec::new();
    for i in 0..500 {
        let p = DVec2::new(lcg(&mut rng) * 1600.0 - 800.0, lcg(&mut rng) * 1600.0 - 800.0);
        let yaw = lcg(&mut rng) * std::f64::consts::TAU;
        let sensors = match i {
            7 => SensorSet { velodyne: Some(Velodyne { range: 5000.0 }), ..Default::default() },
            _ if i % 25 == 0 => SensorSet { radar: Some(Radar { angle: 1.0, range: 500.0 }), ..Default::default() },
            _ => SensorSet { velodyne: Some(Velodyne { range: 30.0 }), ..Default::default() },
        };
        vehicles.push((-1 - i, p, yaw, sensors));
    }
    let sim = world_of(&vehicles);
    let far = seen(&sim, -1);
    assert!(far.len() > 10, "the 500 m radar of vehicle -1 sees only {far:?}");
    assert_eq!(seen(&sim, -8).len(), 499, "the 5 km velodyne sees everyone");
    assert_matches_brute_force(&vehicles);
}

#[test]
fn moving_vehicles_are_seen_as_a_brute_force_scan_sees_them_tick_after_tick() {
    // On one thread, and on three (the lists built in three chunks and joined).
    for threads in [1, 3] {
        moving_vehicles_against_a_scan(threads);
    }
}

fn moving_vehicles_against_a_scan(threads: usize) {
    // 300 vehicles on a 700 m square, each at its own speed (0 to 40 m/s, some turning); now and
    // then one jumps 150 m (a lab bridge's correction) and one gets a much longer or shorter range. Sensing keeps
    // neighbour lists between ticks while nobody has moved far: every tick's readings must
    // still be those of a scan over everyone.
    let mut rng = 29u64;
    let mut vehicles = Vec::new();
    let mut motion = Vec::new();
    for i in 0..300 {
        let p = DVec2::new(lcg(&mut rng) * 700.0 - 350.0, lcg(&mut rng) * 700.0 - 350.0);
        let yaw = lcg(&mut rng) * std::f64::consts::TAU;
        // Every vehicle a radar and a velodyne (one ECS table, where the lists are used), of
        // ranges that differ.
        let (radar, velodyne) = match i % 3 {
            0 => (Radar { angle: 1.0, range: 80.0 }, Velodyne { range: 10.0 }),
            1 => (Radar { angle: 0.5, range: 0.0 }, Velodyne { range: 35.0 }),
            _ => (Radar::default(), Velodyne::default()),
        };
        let sensors = SensorSet { radar: Some(radar), velodyne: Some(velodyne), omniscient: false };
        vehicles.push((-1 - i, p, yaw, sensors));
        // Speed [m/s] and turn rate [rad/s].
        motion.push((lcg(&mut rng) * 40.0, if i % 4 == 0 { lcg(&mut rng) - 0.5 } else { 0.0 }));
    }
    let mut sim = world_on(&vehicles, threads);
    assert_sim_matches_brute_force(&sim, &vehicles);
    let dt = 0.05; // one sensor tick at 20 Hz
    for tick in 1..80 {
        for (k, ((_, p, yaw, sensors), (speed, turn))) in vehicles.iter_mut().zip(&motion).enumerate() {
            *yaw += turn * dt;
            *p += DVec2::from_angle(*yaw) * speed * dt;
            if tick % 25 == 0 && k % 50 == 0 {
                *p += DVec2::new(150.0, -40.0);
            }
            if tick % 10 == 3 && k % 37 == 0 {
                // A much longer range (or a shorter one); the same sensors (the same ECS table).
                let range = if tick % 20 == 3 { 150.0 } else { 20.0 };
                match (&mut sensors.velodyne, &mut sensors.radar) {
                    (Some(velodyne), _) if k % 2 == 0 => velodyne.range = range,
                    (_, Some(radar)) => radar.range = range,
                    _ => unreachable!("every vehicle has both sensors"),
                }
            }
        }
        for &(id, p, yaw, sensors) in &vehicles {
            let e = sim.entity(VehicleId(id)).expect("vehicle exists");
            let mut entity = sim.world_mut().entity_mut(e);
            *entity.get_mut::<VehicleState>().expect("has a state") = VehicleState::new(p, yaw, 0.0);
            if let Some(velodyne) = sensors.velodyne {
                *entity.get_mut::<Velodyne>().expect("has a velodyne") = velodyne;
            }
            if let Some(radar) = sensors.radar {
                *entity.get_mut::<Radar>().expect("has a radar") = radar;
            }
        }
        sim.run_for(dt);
        assert_sim_matches_brute_force(&sim, &vehicles);
    }
}

#[test]
fn traffic_driving_together_is_seen_as_a_brute_force_scan_sees_it_tick_after_tick() {
    // The neighbour lists are kept while vehicles move alike (their displacements since the
    // build differ by less than the skin), not only while each stays near where it was: here for
    // seconds at a time, over which vehicles at different speeds close in on and pass each other.
    for threads in [1, 3] {
        traffic_against_a_scan(threads);
    }
}

fn traffic_against_a_scan(threads: usize) {
    // 240 vehicles on four lanes of a 2 km road heading east at 25 m/s, each up to 6 m/s faster
    // or slower and some weaving a little; 60 more 4 km away heading north at 30 m/s, apart
    // from them (drift cells that do not touch), one of which brakes hard; now and then a
    // vehicle jumps back 30 m.
    let mut rng = 41u64;
    let mut vehicles = Vec::new();
    let mut motion = Vec::new();
    for i in 0..300 {
        let (p, yaw, speed) = if i < 240 {
            let p = DVec2::new(lcg(&mut rng) * 2000.0, 3.5 * f64::from(i % 4));
            (p, 0.0, 25.0 + 12.0 * (lcg(&mut rng) - 0.5))
        } else {
            let p = DVec2::new(4000.0 + 3.5 * f64::from(i % 3), lcg(&mut rng) * 1500.0);
            (p, std::f64::consts::FRAC_PI_2, 30.0)
        };
        let sensors =
            SensorSet { radar: Some(Radar::default()), velodyne: Some(Velodyne::default()), omniscient: false };
        vehicles.push((-1 - i, p, yaw, sensors));
        motion.push((speed, if i % 7 == 0 { 0.05 } else { 0.0 }));
    }
    let mut sim = world_on(&vehicles, threads);
    assert_sim_matches_brute_force(&sim, &vehicles);
    let dt = 0.05;
    for tick in 1..200 {
        for (k, ((_, p, yaw, _), (speed, weave))) in vehicles.iter_mut().zip(&mut motion).enumerate() {
            let heading = *yaw + *weave * (f64::from(tick) * 0.3).sin();
            *p += DVec2::from_angle(heading) * *speed * dt;
            if k == 250 {
                *speed = (*speed - 8.0 * dt).max(0.0);
            }
            if tick % 60 == 0 && k % 40 == 3 {
                p.x -= 30.0;
            }
        }
        place(&mut sim, &vehicles);
        sim.run_for(dt);
        assert_sim_matches_brute_force(&sim, &vehicles);
    }
}

#[test]
fn a_vehicle_turning_round_sees_what_was_behind_it() {
    // A neighbour list leaves out what lies behind beyond the velodyne; a vehicle that turns
    // round (here 10° a tick, in place, among a line of vehicles 30 m apart) must see it.
    let sensors = SensorSet { radar: Some(Radar::default()), velodyne: Some(Velodyne::default()), omniscient: false };
    let mut vehicles: Vec<(i32, DVec2, f64, SensorSet)> =
        (0..15).map(|k| (-1 - k, DVec2::new(30.0 * f64::from(k), 0.0), 0.0, sensors)).collect();
    let mut sim = world_on(&vehicles, 1);
    for tick in 1..=36 {
        vehicles[7].2 = f64::from(tick) * 10f64.to_radians();
        place(&mut sim, &vehicles[7..8]);
        sim.run_for(0.05);
        assert_sim_matches_brute_force(&sim, &vehicles);
    }
}

#[test]
fn a_vehicle_turning_towards_one_closing_in_from_the_side_sees_it() {
    // The radar cone's edge turns with the vehicle (here 29°, kept under the 30° that rebuilds
    // the lists) while the other, 80 m off at 62° from the heading, beyond the velodyne, moves
    // 15 m across towards it (under the skin): both together bring it into the cone, so its
    // list must have held it from the start.
    let sensors = SensorSet { radar: Some(Radar::default()), velodyne: Some(Velodyne::default()), omniscient: false };
    let side = DVec2::from_angle(62f64.to_radians()) * 80.0;
    let mut vehicles = vec![(-1, DVec2::ZERO, 0.0, sensors), (-2, side, 0.0, sensors)];
    let mut sim = world_on(&vehicles, 1);
    assert_sim_matches_brute_force(&sim, &vehicles);
    vehicles[0].2 = 29f64.to_radians();
    vehicles[1].1 += DVec2::new(62f64.to_radians().sin(), -62f64.to_radians().cos()) * 15.0;
    place(&mut sim, &vehicles);
    sim.run_for(0.05);
    assert_eq!(seen(&sim, -1), [-2], "now in the cone");
    assert_sim_matches_brute_force(&sim, &vehicles);
}

#[test]
fn a_group_that_drives_far_together_is_seen_where_it_arrives() {
    // Two groups 1 km apart with empty road between: the first jumps 150 m east every tick,
    // all alike (so none closes in on another of its own group), until it reaches the second.
    // Lists kept because the group moved together would miss the second group on arrival: how
    // far a vehicle may move before they are built again is bounded too.
    let sensors = SensorSet { radar: Some(Radar::default()), velodyne: Some(Velodyne::default()), omniscient: false };
    let mut vehicles: Vec<(i32, DVec2, f64, SensorSet)> = (0..10)
        .map(|k| {
            let x = if k < 5 { 10.0 * f64::from(k) } else { 950.0 + 10.0 * f64::from(k) };
            (-1 - k, DVec2::new(x, 0.0), 0.0, sensors)
        })
        .collect();
    let mut sim = world_on(&vehicles, 1);
    for _ in 0..6 {
        for v in vehicles.iter_mut().take(5) {
            v.1.x += 150.0;
        }
        place(&mut sim, &vehicles);
        sim.run_for(0.05);
        assert_sim_matches_brute_force(&sim, &vehicles);
    }
    assert!(seen(&sim, -1).len() >= 5, "the first group reached the second: {:?}", seen(&sim, -1));
}

/// Put each of `vehicles` where it now is, heading its way, at rest (sensing needs no speed).
fn place(sim: &mut Sim, vehicles: &[(i32, DVec2, f64, SensorSet)]) {
    for &(id, p, yaw, _) in vehicles {
        let e = sim.entity(VehicleId(id)).expect("vehicle exists");
        *sim.world_mut().get_mut::<VehicleState>(e).expect("has a state") = VehicleState::new(p, yaw, 0.0);
    }
}

/// Every vehicle's readings are those of a brute-force scan over all others, nearest first.
fn assert_matches_brute_force(vehicles: &[(i32, DVec2, f64, SensorSet)]) {
    assert_sim_matches_brute_force(&world_of(vehicles), vehicles);
}

/// Every vehicle's readings in `sim` are those of a brute-force scan over `vehicles` (where
/// they are now, with the sensors they carry now), nearest first.
fn assert_sim_matches_brute_force(sim: &Sim, vehicles: &[(i32, DVec2, f64, SensorSet)]) {
    for &(id, p, yaw, sensors) in vehicles {
        let mut expected: Vec<(f64, i32)> = vehicles
            .iter()
            .filter(|o| o.0 != id)
            .filter(|o| {
                let rel = o.1 - p;
                let d = rel.length();
                sensors.velodyne.is_some_and(|v| d <= v.range)
                    || sensors.radar.is_some_and(|r| {
                        let bearing = (rel.y.atan2(rel.x) - yaw + std::f64::consts::PI)
                            .rem_euclid(std::f64::consts::TAU)
                            - std::f64::consts::PI;
                        d <= r.range && bearing.abs() <= 0.5 * r.angle
                    })
            })
            .map(|o| (o.1.distance(p), o.0))
            .collect();
        expected.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let expected: Vec<i32> = expected.into_iter().map(|x| x.1).collect();
        assert_eq!(seen(sim, id), expected, "vehicle {id} at {}", sim.now().as_secs());
    }
}

/// A sim with sensors only, vehicles `(id, position, yaw, size, sensors, errors)`, one sensor tick.
fn world_with_errors(vehicles: &[(i32, DVec2, f64, VehicleSize, SensorSet, SensorErrors)], seed: u64) -> Sim {
    let mut b = SimBuilder::new();
    b.add_plugin(SensorsPlugin);
    b.insert_resource(SimSeed(seed));
    for &(id, p, yaw, size, sensors, errors) in vehicles {
        let mut spec = VehicleSpec::new(VehicleId(id), VehicleState::new(p, yaw, 0.0));
        spec.model = VehicleModel::None;
        spec.size = size;
        spec.sensors = sensors;
        spec.sensor_errors = errors;
        b.spawn_vehicle(spec).expect("unique ids");
    }
    let mut sim = b.build();
    sim.run_for(0.01);
    sim
}

#[test]
fn a_car_hidden_behind_a_truck_is_not_seen_by_an_occluding_radar() {
    let car = VehicleSize { length: 4.12, width: 1.7 };
    let truck = VehicleSize { length: 12.0, width: 2.5 };
    let occluding = SensorErrors { radar: SensorError { occlusion: true, ..Default::default() }, ..Default::default() };
    let scene = |errors| {
        world_with_errors(
            &[
                (-1, DVec2::ZERO, 0.0, car, radar(), errors),
                (-2, DVec2::new(20.0, 0.0), 0.0, truck, NONE, SensorErrors::default()),
                // Straight behind the truck: hidden.
                (-3, DVec2::new(45.0, 0.0), 0.0, car, NONE, SensorErrors::default()),
                // Beside the truck's shadow, in the next lane: seen.
                (-4, DVec2::new(45.0, 3.5), 0.0, car, NONE, SensorErrors::default()),
            ],
            1,
        )
    };
    assert_eq!(seen(&scene(SensorErrors::default()), -1), vec![-2, -3, -4], "without occlusion all are seen");
    let sim = scene(occluding);
    assert_eq!(seen(&sim, -1), vec![-2, -4], "the car behind the truck is hidden");
    let stats = *sim.world().resource::<SensorStats>();
    assert_eq!((stats.detections, stats.missed_by_occlusion, stats.missed_by_dropout), (2, 1, 0));
}

#[test]
fn dropout_misses_its_share_and_noise_has_its_spread() {
    let size = VehicleSize::default();
    let noisy =
        SensorError { range_sd: 0.2, bearing_sd: 0.5f64.to_radians(), speed_sd: 0.1, dropout: 0.3, occlusion: false };
    let errors = SensorErrors { velodyne: noisy, ..Default::default() };
    let velodyne = SensorSet { velodyne: Some(Velodyne { range: 1000.0 }), ..Default::default() };
    // One observer, 400 targets on a circle of 30 m.
    let mut vehicles = vec![(-1, DVec2::ZERO, 0.0, size, velodyne, errors)];
    for k in 0..400 {
        let a = k as f64 * std::f64::consts::TAU / 400.0;
        vehicles.push((-2 - k, DVec2::from_angle(a) * 30.0, 0.0, size, NONE, SensorErrors::default()));
    }
    let sim = world_with_errors(&vehicles, 7);
    let e = sim.entity(VehicleId(-1)).unwrap();
    let readings = &sim.world().get::<SensorReadings>(e).unwrap().0;
    let stats = *sim.world().resource::<SensorStats>();
    assert_eq!(stats.detections + stats.missed_by_dropout, 400);
    assert_eq!(stats.detections, readings.len() as u64);
    let share = stats.missed_by_dropout as f64 / 400.0;
    assert!((share - 0.3).abs() < 0.07, "dropout share {share}");
    let n = readings.len() as f64;
    let sd = |values: Vec<f64>| (values.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
    let range_sd = sd(readings.iter().map(|d| d.position.length() - 30.0).collect());
    let speed_sd = sd(readings.iter().map(|d| d.velocity.x).collect());
    assert!((range_sd - 0.2).abs() < 0.04, "range sd {range_sd}");
    assert!((speed_sd - 0.1).abs() < 0.02, "speed sd {speed_sd}");
}
