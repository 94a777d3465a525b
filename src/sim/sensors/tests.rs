use super::errors::*;
#[cfg(target_arch = "x86_64")]
use super::kernel_avx2::*;
use super::kernel_scalar::*;
use super::keys::*;
use super::radar::*;
use super::readings::*;
use super::sight::*;
use super::*;
use crate::sim::grid::lists::*;
use crate::sim::grid::{Pass, within_reach};
use crate::sim::{Candidates, GridEntry, Parallelism, SimBuilder, SpatialGrid};
use crate::world::{Radar, SensorError, SensorErrors, SensorReadings, SimTime, VehicleId, VehicleState, Velodyne};
use glam::DVec2;
use std::f64::consts::TAU;

#[test]
fn shapes_summed_up_in_any_chunks_give_the_typical_range_of_all_of_them() {
    let shape = |radar: f64, velodyne: f64| Shape { radar, angle: 1.0, velodyne };
    let cases: Vec<Vec<Shape>> = vec![
        vec![shape(100.0, 50.0); 7],
        vec![shape(0.0, 0.0), shape(100.0, 50.0), shape(0.0, 0.0), shape(40.0, 100.0)],
        vec![shape(100.0, 50.0), shape(100.0, 50.0), shape(30.0, 20.0), shape(100.0, 0.0), shape(0.0, 70.0)],
        vec![shape(0.0, 0.0); 3],
        vec![shape(100.0, 50.0), shape(f64::INFINITY, 0.0), shape(100.0, 0.0)],
        vec![shape(100.0, 0.0), shape(100.0, 0.0), shape(30.0, 0.0), shape(30.0, 0.0), shape(0.0, 30.0)],
        vec![],
    ];
    for shapes in cases {
        let mut ranges: Vec<f64> = shapes.iter().map(Shape::range).filter(bounded).collect();
        let expected = typical_range(&mut ranges);
        let finite = shapes.iter().all(|s| s.range().is_finite());
        // Chunks of every size, and two chunks split at every place.
        let fixed = (1..=shapes.len().max(1)).map(|cut| shapes.chunks(cut).collect::<Vec<_>>());
        let split = (0..=shapes.len()).map(|k| vec![&shapes[..k], &shapes[k..]]);
        for chunks in fixed.chain(split) {
            let cut = chunks.iter().map(|c| c.len()).collect::<Vec<_>>();
            let mut summary = ShapeSummary::default();
            for chunk in chunks {
                let mut part = ShapeSummary::default();
                chunk.iter().for_each(|s| part.add(s));
                summary.then(&part);
                summary.then(&ShapeSummary::default());
            }
            assert_eq!(summary.finite, finite, "{shapes:?} in chunks of {cut:?}");
            if let Some(cell) = summary.typical() {
                assert_eq!(cell, expected, "{shapes:?} in chunks of {cut:?}");
            } else {
                assert!(ranges.iter().any(|r| *r != ranges[0]), "only mixed ranges leave it to the median");
            }
        }
    }
}

/// A vehicle `k` at (`x`, 0) facing east, standing still (no dynamics), with the default
/// radar and velodyne.
fn sensing_at(k: i32, x: f64) -> crate::world::VehicleSpec {
    use crate::world::{SensorSet, VehicleModel, VehicleSpec};
    let mut spec = VehicleSpec::new(VehicleId(k), VehicleState::new(DVec2::new(x, 0.0), 0.0, 0.0));
    spec.model = VehicleModel::None;
    let (radar, velodyne) = (Some(Radar::default()), Some(Velodyne::default()));
    spec.sensors = SensorSet { radar, velodyne, omniscient: false };
    spec
}

#[test]
fn the_neighbour_lists_are_kept_while_the_vehicles_move_together_and_built_again_when_two_close_in() {
    let spec = sensing_at;
    let mut b = SimBuilder::new();
    b.add_plugin(SensorsPlugin);
    for k in 0..50 {
        b.spawn_vehicle(spec(k, 30.0 * f64::from(k))).expect("unique ids");
    }
    let mut sim = b.build();
    let builds = |sim: &crate::sim::Sim| sim.world().resource::<SensorGrid>().neighbours.lists.builds;
    let move_to = |sim: &mut crate::sim::Sim, x: f64| {
        let e = sim.entity(VehicleId(7)).expect("vehicle 7");
        *sim.world_mut().get_mut::<VehicleState>(e).expect("state") = VehicleState::new(DVec2::new(x, 0.0), 0.0, 0.0);
    };
    let move_all_by = |sim: &mut crate::sim::Sim, dx: f64| {
        for k in 0..50 {
            let e = sim.entity(VehicleId(k)).expect("vehicle");
            sim.world_mut().get_mut::<VehicleState>(e).expect("state").position.x += dx;
        }
    };
    sim.run_for(0.5);
    assert_eq!(builds(&sim), 1, "ten ticks, nobody moved: one build");
    // 100 m ranges: a 20 m skin, kept while no two neighbours closed in by 19.6 m.
    move_to(&mut sim, 210.0 + 9.0);
    sim.run_for(0.1);
    assert_eq!(builds(&sim), 1, "9 m is within half the skin");
    move_to(&mut sim, 210.0 + 19.0);
    sim.run_for(0.1);
    assert_eq!(builds(&sim), 1, "19 m closer to its neighbours: still under the skin");
    move_to(&mut sim, 210.0 + 21.0);
    sim.run_for(0.05);
    assert_eq!(builds(&sim), 2, "21 m is not");
    // Everyone 150 m on together (drift cells 480 m wide: up to 186 m), then 40 m more.
    move_all_by(&mut sim, 150.0);
    sim.run_for(0.1);
    assert_eq!(builds(&sim), 2, "everyone moved alike: the lists hold");
    move_all_by(&mut sim, 40.0);
    sim.run_for(0.05);
    assert_eq!(builds(&sim), 3, "190 m from where the lists were built: too far to tell");
    move_all_by(&mut sim, 1.0);
    move_to(&mut sim, f64::NAN);
    sim.run_for(0.05);
    assert_eq!(builds(&sim), 4, "a NaN position");
    move_to(&mut sim, 400.0);
    sim.run_for(0.05);
    assert_eq!(builds(&sim), 5, "and back");
    sim.spawn_vehicle(spec(50, -30.0)).expect("unique id");
    sim.run_for(0.05);
    assert_eq!(builds(&sim), 6, "a new vehicle");
    let e = sim.entity(VehicleId(3)).expect("vehicle 3");
    sim.world_mut().get_mut::<Velodyne>(e).expect("velodyne").range = 60.0;
    sim.run_for(0.05);
    assert_eq!(builds(&sim), 7, "a longer velodyne: a list reaches that far behind");
    sim.world_mut().get_mut::<Radar>(e).expect("radar").range = 150.0;
    sim.run_for(0.05);
    assert_eq!(builds(&sim), 8, "a longer radar");
    sim.run_for(0.2);
    assert_eq!(builds(&sim), 8);
    // Vehicle 20 turns: kept at 29° from its heading at the build, built again at 30.4°.
    let e = sim.entity(VehicleId(20)).expect("vehicle 20");
    let turn = |sim: &mut crate::sim::Sim, yaw: f64| {
        let mut state = sim.world_mut().get_mut::<VehicleState>(e).expect("state");
        *state = VehicleState::new(state.position, yaw, 0.0);
    };
    turn(&mut sim, 0.5);
    sim.run_for(0.05);
    assert_eq!(builds(&sim), 8, "turned 29°");
    turn(&mut sim, 0.53);
    sim.run_for(0.05);
    assert_eq!(builds(&sim), 9, "turned 30.4°");
    // Each list leaves out what lies behind beyond the velodyne (50 m) and its skin (20 m):
    // on a line of vehicles 30 m apart facing along it, two behind and four ahead (up to
    // 120 m), not the four behind up to 120 m.
    let grid = sim.world().resource::<SensorGrid>();
    let lists = &grid.neighbours.lists;
    let place = lists.ids.iter().position(|&id| id == VehicleId(10)).expect("vehicle 10 listed");
    let mut listed: Vec<i32> = lists.lists.of(place).iter().map(|&j| lists.ids[j as usize].0).collect();
    listed.sort_unstable();
    assert_eq!(listed, [8, 9, 11, 12, 13, 14]);
}

/// Sixty sensing vehicles 30 m apart in a row, on `threads` threads.
fn sixty_in_a_row(threads: usize) -> crate::sim::Sim {
    let mut b = SimBuilder::new();
    b.add_plugin(SensorsPlugin);
    b.insert_resource(Parallelism::split(threads));
    for k in 0..60 {
        b.spawn_vehicle(sensing_at(k, 30.0 * f64::from(k))).expect("unique ids");
    }
    b.build()
}

#[test]
fn a_sensor_changed_in_any_chunk_builds_the_lists_again_on_any_thread_count() {
    // The sensing pass over kept lists (or the shapes pass) tells whether this tick's
    // sensors are the build's, chunk by chunk: a change in the first, a middle or the last
    // chunk must be seen.
    for threads in [1, 2, 3] {
        for changed in [0, 31, 59] {
            let mut sim = sixty_in_a_row(threads);
            let builds = |sim: &crate::sim::Sim| sim.world().resource::<SensorGrid>().neighbours.lists.builds;
            sim.run_for(0.2);
            assert_eq!(builds(&sim), 1, "{threads} threads: nobody moved");
            let e = sim.entity(VehicleId(changed)).expect("vehicle");
            sim.world_mut().get_mut::<Radar>(e).expect("radar").range = 120.0;
            sim.run_for(0.05);
            assert_eq!(builds(&sim), 2, "{threads} threads, vehicle {changed}'s radar longer");
            sim.run_for(0.2);
            assert_eq!(builds(&sim), 2, "{threads} threads, vehicle {changed}: the same again");
            sim.world_mut().get_mut::<Velodyne>(e).expect("velodyne").range = 49.0;
            sim.run_for(0.05);
            assert_eq!(builds(&sim), 3, "{threads} threads, vehicle {changed}'s velodyne shorter");
        }
    }
}

#[test]
fn kept_lists_sense_in_one_pass_and_a_tick_thrown_away_counts_its_detections_once() {
    // Lists kept for `ONE_PASS_AFTER` ticks are then kept in one pass; a tick that finds them
    // no longer hold (a vehicle closed in by the skin, a radar changed) throws that pass
    // away and senses again over lists built anew: its detections count once, as many as
    // the readings hold. Right after a build, the two-pass path.
    for threads in [1, 2, 3] {
        let mut sim = sixty_in_a_row(threads);
        let counts = |sim: &crate::sim::Sim| {
            let lists = &sim.world().resource::<SensorGrid>().neighbours.lists;
            (lists.builds, lists.kept_in_one_pass, lists.thrown_away)
        };
        let detections = |sim: &mut crate::sim::Sim| {
            let counted = sim.world().resource::<SensorStats>().detections;
            let world = sim.world_mut();
            let read: usize = world.query::<&SensorReadings>().iter(world).map(|r| r.0.len()).sum();
            (counted, read as u64)
        };
        sim.run_for(0.05);
        assert_eq!(counts(&sim), (1, 0, 0), "{threads} threads: the first tick builds");
        let (mut last, read) = detections(&mut sim);
        assert_eq!(last, read, "{threads} threads: the first tick");
        for step in 0..30 {
            match step {
                12 => {
                    let e = sim.entity(VehicleId(7)).expect("vehicle 7");
                    sim.world_mut().get_mut::<VehicleState>(e).expect("state").position.x += 21.0;
                }
                24 => {
                    let e = sim.entity(VehicleId(40)).expect("vehicle 40");
                    sim.world_mut().get_mut::<Radar>(e).expect("radar").range = 120.0;
                }
                _ => {}
            }
            sim.run_for(0.05);
            let (counted, read) = detections(&mut sim);
            assert_eq!(counted - last, read, "{threads} threads, step {step}");
            last = counted;
        }
        // Ticks 0-7 after each build on two passes, then one (steps 8-11 and 21-23), the
        // passes of steps 12 and 24 thrown away for builds.
        assert_eq!(counts(&sim), (3, 7, 2), "{threads} threads: builds, kept in one pass, thrown away");
    }
}

#[test]
fn at_the_instant_the_sensors_tested_the_lists_the_wifi_round_takes_them_without_testing_again() {
    let mut b = SimBuilder::new();
    b.add_plugin(SensorsPlugin);
    for k in 0..50 {
        b.spawn_vehicle(sensing_at(k, 30.0 * f64::from(k))).expect("unique ids");
    }
    let mut sim = b.build();
    sim.run_for(0.12);
    let mut query = sim.world_mut().query::<(&VehicleId, &VehicleState)>();
    let (ids, mut states): (Vec<VehicleId>, Vec<VehicleState>) =
        query.iter(sim.world()).map(|(id, state)| (*id, *state)).unzip();
    let grid = sim.world().resource::<SensorGrid>();
    let tested = grid.neighbours.lists.held_at.expect("the sensors tested the lists");
    let later = SimTime(tested.0 + 1);
    let mut scratch = DriftScratch::default();
    let mut within = |ids: &[VehicleId], states: &[VehicleState], now| {
        grid.lists_within(ids, states, 10.0, (Parallelism::single(), now), &mut scratch).is_some()
    };
    assert!(within(&ids, &states, tested), "as the sensors left them");
    assert!(within(&ids, &states, later), "nobody moved: they hold at any instant");
    // Vehicle 7 25 m on (more than the 20 m skin): at the sensors' instant the states are
    // the ones they tested (only the dynamics moves vehicles, after every other module), so
    // no drift test; at any other instant the drift test finds the lists stale.
    states[7].position.x += 25.0;
    assert!(within(&ids, &states, tested), "the sensors' instant: taken without a test");
    assert!(!within(&ids, &states, later), "another instant: tested, and stale");
    let mut swapped = ids.clone();
    swapped.swap(3, 4);
    assert!(!within(&swapped, &states, tested), "other vehicles than the build's");
    assert!(!within(&ids[1..], &states[1..], tested), "fewer vehicles than the build's");
}

#[test]
fn a_list_holds_all_around_the_velodyne_or_the_wifi_range_and_the_widened_radar_cone_ahead() {
    let shape = Shape { radar: 100.0, angle: std::f64::consts::FRAC_PI_3, velodyne: 50.0 };
    let east = DVec2::X;
    let holds = |reach: &Reach, x: f64, y: f64| reach.holds(DVec2::new(x, y), x * x + y * y);
    let reach = Reach::new(&shape, east, 0.0, 20.0);
    assert!(holds(&reach, -70.0, 0.0) && !holds(&reach, -70.1, 0.0), "behind: velodyne and skin");
    assert!(holds(&reach, 0.0, 69.9) && !holds(&reach, 0.0, 80.0), "beside");
    // Ahead at 100 m: half the cone (30°), the turn (30°), asin(20 / 100) = 11.5°.
    let at = |deg: f64| DVec2::from_angle(deg.to_radians()) * 100.0;
    assert!(holds(&reach, at(71.0).x, at(71.0).y) && !holds(&reach, at(72.0).x, at(72.0).y));
    assert!(holds(&reach, at(-71.0).x, at(-71.0).y) && !holds(&reach, at(-72.0).x, at(-72.0).y));
    // A radar of 150°: 75° + 30° + 11.5°.
    let wide = Shape { angle: 150f64.to_radians(), ..shape };
    let reach_wide = Reach::new(&wide, east, 0.0, 20.0);
    assert!(holds(&reach_wide, at(116.0).x, at(116.0).y) && !holds(&reach_wide, at(117.0).x, at(117.0).y));
    // With the wifi at 60 m, 80 m all around; a wifi range beyond the sensors' adds nothing.
    let reach = Reach::new(&shape, east, 60.0, 20.0);
    assert!(holds(&reach, -80.0, 0.0) && !holds(&reach, -80.1, 0.0));
    assert_eq!(shape.around(500.0), 100.0);
    // Without a radar, the velodyne's circle; with a NaN angle (which sees all ahead), all.
    let no_radar = Shape { radar: 0.0, angle: 1.0, velodyne: 50.0 };
    assert!(!holds(&Reach::new(&no_radar, east, 0.0, 20.0), 80.0, 0.0));
    let nan = Shape { angle: f64::NAN, ..shape };
    assert!(holds(&Reach::new(&nan, east, 0.0, 20.0), -100.0, 10.0));
}

#[test]
fn the_typical_range_is_the_median_whether_or_not_all_ranges_agree() {
    assert_eq!(typical_range(&mut []), 100.0);
    assert_eq!(typical_range(&mut [80.0; 5]), 80.0);
    assert_eq!(typical_range(&mut [50.0, 100.0, 100.0]), 100.0);
    assert_eq!(typical_range(&mut [100.0, 50.0, 50.0, 200.0, 30.0]), 50.0);
    // One differing range among many equal ones: still the median, not the first.
    let mut ranges = vec![100.0; 9];
    ranges.extend([20.0; 10]);
    assert_eq!(typical_range(&mut ranges), 20.0);
}

#[test]
fn pair_draws_are_keyed_by_seed_sensor_pair_and_tick() {
    let (a, b) = (VehicleId(-3), VehicleId(7));
    let first = |seed, stream, now, observer, target| SensorKeys::new(seed, stream, now).pair(observer, target).first;
    let base = first(42, RADAR_STREAM, 1_500_000, a, b);
    assert_eq!(base, first(42, RADAR_STREAM, 1_500_000, a, b));
    for other in [
        first(43, RADAR_STREAM, 1_500_000, a, b),
        first(42, VELODYNE_STREAM, 1_500_000, a, b),
        first(42, RADAR_STREAM, 1_550_000, a, b),
        first(42, RADAR_STREAM, 1_500_000, b, a),
        first(42, RADAR_STREAM, 1_500_000, a, VehicleId(8)),
    ] {
        assert_ne!(base, other);
    }
    let d = Draws::new(42, 1_500_000);
    assert_eq!(d.radar.pair(a, b).first, base);
    assert_eq!(d.velodyne.pair(a, b).first, first(42, VELODYNE_STREAM, 1_500_000, a, b));
}

#[test]
fn pair_draws_drop_their_share_and_give_independent_standard_normals() {
    // Many (observer, target) pairs over a few ticks, as a bench run draws them.
    let (dropout, mut dropped, mut n) = (0.02, 0u32, 0u32);
    let mut normals: Vec<[f64; 4]> = Vec::new();
    for tick in 0..20u64 {
        let keys = SensorKeys::new(1, RADAR_STREAM, tick * 50_000);
        for observer in 0..100 {
            for target in 0..100 {
                let pair = keys.pair(VehicleId(-1 - observer), VehicleId(-1 - target));
                n += 1;
                if pair.kept(dropout) {
                    normals.push(pair.normals());
                } else {
                    dropped += 1;
                }
            }
        }
    }
    let share = f64::from(dropped) / f64::from(n);
    let sd = (dropout * (1.0 - dropout) / f64::from(n)).sqrt();
    assert!((share - dropout).abs() < 4.0 * sd, "dropout share {share} of {n}");
    let m = normals.len() as f64;
    for k in 0..4 {
        let mean = normals.iter().map(|x| x[k]).sum::<f64>() / m;
        let var = normals.iter().map(|x| x[k] * x[k]).sum::<f64>() / m;
        assert!(mean.abs() < 4.0 / m.sqrt(), "normal {k}: mean {mean}");
        assert!((var - 1.0).abs() < 0.02, "normal {k}: variance {var}");
        let beyond = normals.iter().filter(|x| x[k].abs() > 2.0).count() as f64 / m;
        assert!((beyond - 0.0455).abs() < 0.003, "normal {k}: P(|X| > 2) {beyond}");
        for j in 0..k {
            let c = normals.iter().map(|x| x[j] * x[k]).sum::<f64>() / m;
            assert!(c.abs() < 4.0 / m.sqrt(), "normals {j} and {k} correlate: {c}");
        }
    }
}

/// A grid of `n` vehicles scattered around the origin and a sensing vehicle at the origin
/// facing +x with a radar and a velodyne: its candidates as `Sight::consider` keys.
fn scene(n: u32) -> (SpatialGrid, Sight, Vec<u64>) {
    let mut grid = SpatialGrid::default();
    let entries = (0..n).map(|k| {
        let a = f64::from(k) * 2.399_963; // golden angle: spread in every direction
        let r = 3.0 + f64::from(k % 37) * 3.1;
        GridEntry {
            position: DVec2::new(r * a.cos(), r * a.sin()),
            velocity: DVec2::new(f64::from(k % 5), -1.0),
            id: VehicleId(k as i32 + 1),
            index: k,
        }
    });
    grid.rebuild(100.0, entries);
    let state = VehicleState::new(DVec2::ZERO, 0.0, 10.0);
    let radar = Some(&Radar::default());
    let sight = Sight::new(VehicleId(-1), &state, radar, Some(&Velodyne::default()), false, &mut HalfCos::default());
    let (mut around, mut found) = (Candidates::default(), Vec::new());
    grid.gather_all(&mut around);
    let seen = sight.consider_all(&around, &mut Vec::new(), &mut found).len();
    found.truncate(seen);
    (grid, sight, found)
}

#[test]
fn listed_keys_four_at_a_time_are_the_keys_of_the_three_passes() {
    // Neighbours all around at 0 m (on top of the sensor) to 130 m, one at NaN; lists of
    // every length to 70 (every remainder of four, past the near mask's 64 bits) in an
    // order that jumps about the states; an acute radar cone, one wider than a half turn,
    // one all around, none; with and without a velodyne.
    let p = DVec2::new(12.5, -3.25);
    let states: Vec<VehicleState> = (0..101)
        .map(|k| {
            let (a, r) = (k as f64 * 2.399_963, (k % 29) as f64 * 4.7);
            let q = if k == 50 { DVec2::new(f64::NAN, 1.0) } else { p + DVec2::new(r * a.cos(), r * a.sin()) };
            VehicleState::new(q, 0.0, 1.0)
        })
        .collect();
    let state = VehicleState::new(p, 0.7, 10.0);
    let radars = [
        Some(Radar::default()),
        Some(Radar { angle: 4.0, range: 80.0 }),
        Some(Radar { angle: TAU, range: 60.0 }),
        None,
    ];
    let (mut lengths_compared, mut reach_seen) = (0, 0u32);
    for radar in &radars {
        for velodyne in [Some(Velodyne::default()), None] {
            let sight =
                Sight::new(VehicleId(-1), &state, radar.as_ref(), velodyne.as_ref(), false, &mut HalfCos::default());
            for n in 0..=70 {
                let list: Vec<u32> = (0..n).map(|k| ((k * 37 + 11) % 101) as u32).collect();
                // The three passes, one neighbour at a time.
                let (mut xs, mut ys, mut keys) = (vec![0.0; n], vec![0.0; n], vec![0; n]);
                gather_positions(&states, &list, &mut xs, &mut ys);
                ListKeysPass { sight: &sight, xs: &xs, ys: &ys, slots: &list, keys: &mut keys }.run();
                let want: Vec<u64> = keys.iter().copied().filter(|&k| k != UNSEEN).collect();
                let want_near = near_of(&xs, &ys, (p, 900.0));
                reach_seen |= want.iter().fold(0, |r, &k| r | k as u32 & REACH);
                #[cfg(target_arch = "x86_64")]
                if std::arch::is_x86_feature_detected!("avx2") {
                    for r2 in [None, Some(900.0)] {
                        let mut found = vec![0; n.next_multiple_of(4)];
                        // SAFETY: the processor has AVX2, checked just above.
                        let (seen, near) = unsafe { listed_keys_avx2(&sight, &states, &list, r2, &mut found) };
                        assert_eq!(found[..seen], want[..], "{n} neighbours, radar {radar:?}, velodyne {velodyne:?}");
                        assert_eq!(near, if r2.is_some() { want_near } else { 0 }, "{n} neighbours' near mask");
                    }
                    lengths_compared += 1;
                }
                if n == 70 {
                    // Some seen, some not (none without a sensor).
                    let blind = radar.is_none() && velodyne.is_none();
                    assert!(blind == want.is_empty() && want.len() < n, "{} of {n} seen", want.len());
                }
            }
        }
    }
    // Both reach bits turned up; every case compared where the processor has AVX2.
    assert_eq!(reach_seen, REACH);
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        assert_eq!(lengths_compared, 4 * 2 * 71);
    }
}

#[test]
fn the_gather_marks_the_neighbours_within_the_wifi_range_as_within_reach_tests_them() {
    // Neighbours inside, outside and exactly on the circle (a 3-4-5 offset at r = 5 m:
    // d² = 25 = r² exactly, inclusive), a NaN one (never within), lists of every length up
    // to 64 (all bits of the mask) in an order that jumps about the states.
    let p = DVec2::new(100.25, -40.5);
    let offsets = [(3.0, 4.0), (-3.0, 4.0), (1.0, 1.0), (4.0, 3.1), (0.0, -5.0), (6.0, 0.0), (f64::NAN, 0.0)];
    let states: Vec<VehicleState> = (0..97)
        .map(|k| {
            let (dx, dy) = offsets[k % offsets.len()];
            VehicleState::new(p + DVec2::new(dx, dy) * (1.0 + (k / 50) as f64 * 1e-9), 0.0, 1.0)
        })
        .collect();
    let r2 = 25.0;
    let ids: Vec<VehicleId> = (0..97).map(VehicleId).collect();
    let everyone = Everyone { ids: &ids, states: &states };
    let sight = Sight::new(VehicleId(-1), &VehicleState::new(p, 0.0, 1.0), None, None, false, &mut HalfCos::default());
    let mut bits_seen = 0u64;
    for n in 0..=64 {
        let slots: Vec<u32> = (0..n).map(|k| ((k * 31 + 5) % 97) as u32).collect();
        let want = slots.iter().enumerate().fold(0u64, |m, (k, &j)| {
            m | u64::from(within_reach(p, states[j as usize].position.x, states[j as usize].position.y, r2)) << k
        });
        let mut near = u64::MAX;
        let mut buffers = (Vec::new(), Vec::new(), Vec::new());
        sight.consider_listed(
            &slots,
            everyone,
            (&mut buffers.0, &mut buffers.1, &mut buffers.2),
            Some((r2, &mut near)),
            &mut Vec::new(),
        );
        assert_eq!(near, want, "{n} neighbours");
        let (mut xs, mut ys) = (vec![0.0; n], vec![0.0; n]);
        gather_positions(&states, &slots, &mut xs, &mut ys);
        assert_eq!(near_of(&xs, &ys, (p, r2)), want, "{n} neighbours, one at a time");
        bits_seen |= near;
    }
    // Both kinds at every length, up to the mask's last bit.
    assert!((20..44).contains(&bits_seen.count_ones()) && bits_seen >> 63 == 1, "{bits_seen:#x}");
}

#[test]
fn a_neighbour_list_is_seen_as_the_grid_scan_sees_it_in_vector_and_scalar_code() {
    let n = 400;
    let (grid, sight, found) = scene(n);
    // Everyone at their places (a list names vehicles by place), the list all of them.
    let (ids, states): (Vec<_>, Vec<_>) =
        (0..n).map(|slot| grid.get(slot)).map(|e| (e.id, VehicleState::new(e.position, 0.0, 0.0))).unzip();
    let everyone = Everyone { ids: &ids, states: &states };
    let list: Vec<u32> = (0..n).rev().collect();
    let mut buffers = (Vec::new(), Vec::new(), Vec::new());
    let mut listed = Vec::new();
    let listed =
        sight.consider_listed(&list, everyone, (&mut buffers.0, &mut buffers.1, &mut buffers.2), None, &mut listed);
    // The same targets, distances and reach bits as the grid scan's keys.
    let named = |keys: &[u64], id_of: &dyn Fn(u32) -> VehicleId| {
        let mut named: Vec<_> = keys.iter().map(|&k| (id_of(k as u32 & !REACH).0, k >> 32, k as u32 & REACH)).collect();
        named.sort_unstable();
        named
    };
    let from_list = named(listed, &|place| ids[place as usize]);
    assert_eq!(from_list, named(&found, &|slot| grid.get(slot).id));
    assert!(from_list.len() > 50 && from_list.len() < n as usize, "{} of {n} seen", from_list.len());
    // The key pass gives the same bits compiled as it is and with AVX2.
    let (mut xs, mut ys) = (vec![0.0; n as usize], vec![0.0; n as usize]);
    gather_positions(&states, &list, &mut xs, &mut ys);
    let (xs, ys) = (&xs[..], &ys[..]);
    let (mut plain, mut wide) = (vec![0; n as usize], vec![0; n as usize]);
    ListKeysPass { sight: &sight, xs, ys, slots: &list, keys: &mut plain }.run();
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the processor has AVX2, checked just above.
        unsafe { crate::sim::grid::with_avx2(ListKeysPass { sight: &sight, xs, ys, slots: &list, keys: &mut wide }) };
        assert_eq!(plain, wide);
    }
    assert_eq!(plain.iter().filter(|&&k| k != UNSEEN).count(), from_list.len());
}

#[test]
fn the_radar_only_loop_reads_what_the_general_one_reads() {
    let (grid, sight, found) = scene(400);
    assert!(found.len() > 50, "{} candidates seen", found.len());
    for (dropout, range_sd) in [(0.3, 0.5), (0.0, 0.5), (0.3, 0.0), (0.0, 0.0)] {
        let radar = SensorError { range_sd, bearing_sd: 0.02, speed_sd: 0.3, dropout, occlusion: false };
        let errors = SensorErrors { radar, ..Default::default() };
        assert!(radar_errors_only(&errors));
        for tick in [0, 50_000, 1_000_000] {
            let draws = Draws::new(7, tick);
            let (mut general, mut fast) = (SensorReadings::default(), SensorReadings::default());
            let (mut general_stats, mut fast_stats) = (SensorStats::default(), SensorStats::default());
            let mut extents = Vec::new();
            let (mut a, mut b) = (found.clone(), found.clone());
            write_imperfect_readings(
                &sight,
                &errors,
                draws,
                &[],
                &grid,
                &mut a,
                &mut extents,
                &mut general_stats,
                &mut general,
            );
            write_radar_error_readings(&sight, &errors.radar, draws, &grid, &mut b, &mut fast_stats, &mut fast);
            let bits = |r: &SensorReadings| -> Vec<(i32, [u64; 4])> {
                r.0.iter()
                    .map(|d| (d.id.0, [d.position.x, d.position.y, d.velocity.x, d.velocity.y].map(f64::to_bits)))
                    .collect()
            };
            assert_eq!(bits(&general), bits(&fast), "dropout {dropout}, range sd {range_sd}, tick {tick}");
            assert_eq!(general_stats, fast_stats);
            if dropout > 0.0 {
                assert!(fast_stats.missed_by_dropout > 0, "dropout {dropout} missed nothing");
            }
        }
    }
}

/// Targets `entries` (position, id) in a grid of `cell` [m], all seen by a velodyne of
/// `range` [m] at the origin: their readings come by the exact squared distance, then id.
fn assert_seen_nearest_first(entries: &[(DVec2, i32)], cell: f64, range: f64) {
    let mut grid = SpatialGrid::default();
    grid.rebuild(
        cell,
        entries.iter().enumerate().map(|(i, &(position, id))| GridEntry {
            position,
            velocity: DVec2::ZERO,
            id: VehicleId(id),
            index: i as u32,
        }),
    );
    let state = VehicleState::new(DVec2::ZERO, 0.0, 0.0);
    let velodyne = Velodyne { range };
    let sight = Sight::new(VehicleId(-1), &state, None, Some(&velodyne), false, &mut HalfCos::default());
    let (mut around, mut found) = (Candidates::default(), Vec::new());
    grid.gather_all(&mut around);
    let n = sight.consider_all(&around, &mut Vec::new(), &mut found).len();
    found.truncate(n);
    assert_eq!((n, found.len()), (entries.len(), n));
    let mut readings = SensorReadings::default();
    write_readings(&mut found, &grid, DVec2::ZERO, &mut readings);
    let mut want: Vec<(u64, i32)> = entries.iter().map(|&(p, id)| (p.length_squared().to_bits(), id)).collect();
    want.sort_unstable();
    let got: Vec<i32> = readings.0.iter().map(|d| d.id.0).collect();
    assert_eq!(got, want.iter().map(|w| w.1).collect::<Vec<_>>());
}

#[test]
fn detections_come_nearest_first_by_the_exact_distance_then_id_even_where_an_f32_ties() {
    // Targets at 20 m + k * 1e-9 m (distinct doubles, one f32 squared distance), and pairs
    // at exactly equal distances with ids in both orders, slots shuffled by the grid.
    let mut entries = Vec::new();
    for k in 0..12u32 {
        let r = 20.0 + f64::from((k * 7) % 12) * 1e-9;
        let a = f64::from(k) * 0.5;
        entries.push((DVec2::new(r * a.cos(), r * a.sin()), 100 - k as i32));
    }
    for (k, id) in [(0, 7), (1, 3), (2, 9), (3, 1)] {
        let a = 1.0 + f64::from(k) * std::f64::consts::FRAC_PI_2;
        // Exactly 30 m: 30 (cos, sin) rounded may differ by an ulp, so mirror one point.
        let p = DVec2::new(30.0 * a.cos(), 30.0 * a.sin());
        entries.push((p, id));
        entries.push((-p, id + 200));
    }
    assert_seen_nearest_first(&entries, 100.0, 50.0);
    // The f32 keys did tie: the first twelve share one rounded distance.
    let rounded: std::collections::HashSet<u32> =
        entries[..12].iter().map(|(p, _)| (p.length_squared() as f32).to_bits()).collect();
    assert_eq!(rounded.len(), 1);
    let exact: std::collections::HashSet<u64> =
        entries[..12].iter().map(|(p, _)| p.length_squared().to_bits()).collect();
    assert!(exact.len() > 6, "only {} distinct distances", exact.len());
}

#[test]
fn runs_of_tied_distances_of_any_length_and_place_come_in_exact_order() {
    // Groups of targets whose squared distances round to one f32 (radius r + k * 1e-9 m,
    // and mirrored pairs at exactly equal distances), of 1 to 150 targets, so that runs
    // start and end at and across the 64-key windows of the tie search; ids descending
    // within a group, so the exact order is not the order they were made in.
    let mut entries = Vec::new();
    let mut id = 10_000;
    let sizes = [1usize, 2, 3, 61, 1, 64, 2, 65, 1, 1, 150, 2, 4];
    for (g, size) in sizes.into_iter().enumerate() {
        let r = 10.0 + g as f64 * 7.0;
        for k in 0..size {
            let a = k as f64 * 0.37 + g as f64;
            let p = if k % 3 == 2 {
                // Mirror the one before: exactly the same distance, another id.
                -entries.last().map(|&(p, _): &(DVec2, i32)| p).expect("k > 0")
            } else {
                let r = r + ((k * 5) % 7) as f64 * 1e-9;
                DVec2::new(r * a.cos(), r * a.sin())
            };
            entries.push((p, id));
            id -= 1;
        }
    }
    assert_seen_nearest_first(&entries, 50.0, 1000.0);
    // The groups did tie in the f32 keys (each rounds to one value).
    let mut start = 0;
    for size in sizes {
        let group = &entries[start..start + size];
        let rounded: std::collections::HashSet<u32> =
            group.iter().map(|(p, _)| (p.length_squared() as f32).to_bits()).collect();
        assert_eq!(rounded.len(), 1, "the group of {size} at {start} rounds to one f32");
        start += size;
    }
}

/// One candidate's key as the sensors decided before their test was vectorised (one at a
/// time, through `Cone::contains` and `DVec2`), `None` when not seen.
fn one_key(sight: &Sight, slot: u32, position: DVec2, id: VehicleId) -> Option<u64> {
    let relative = position - sight.position;
    let d2 = relative.length_squared();
    let radar = (d2 <= sight.radar_range2) && sight.cone.contains(relative, d2);
    let velodyne = d2 <= sight.velodyne_range2;
    let flags = (u32::from(radar) << 31) | (u32::from(velodyne) << 30);
    ((sight.omniscient() || velodyne || radar) && id != sight.id).then(|| detection_key(d2, slot | flags))
}

#[test]
fn the_vectorised_candidate_test_keeps_what_the_one_at_a_time_test_keeps() {
    let (grid, _, _) = scene(500);
    let mut around = Candidates::default();
    grid.gather_all(&mut around);
    // Sensors at a target's spot (distance 0), facing every way, with acute, obtuse, full and
    // no radar cones, with and without a velodyne, omniscient or not.
    let radars = [
        None,
        Some(Radar::default()),
        Some(Radar { range: 60.0, angle: 4.0 }),
        Some(Radar { range: 80.0, angle: TAU }),
    ];
    let mut seen_any = [false; 2];
    for (k, (&radar, velodyne)) in radars.iter().zip([None, Some(Velodyne { range: 30.0 })]).cycle().take(8).enumerate()
    {
        for (j, omniscient) in [false, true].into_iter().enumerate() {
            let at = grid.get((k * 37 % grid.len()) as u32).position;
            let state = VehicleState::new(at, k as f64 * 0.9 - 3.0, 5.0);
            let sight = Sight::new(
                VehicleId(k as i32),
                &state,
                radar.as_ref(),
                velodyne.as_ref(),
                omniscient,
                &mut HalfCos::default(),
            );
            let want: Vec<u64> = (0..around.len())
                .filter_map(|c| one_key(&sight, around.slots[c], DVec2::new(around.xs[c], around.ys[c]), around.ids[c]))
                .collect();
            // Buffers longer than needed from an earlier vehicle: only the seen part counts.
            let (mut keys, mut got) = (vec![7; around.len() + 3], vec![9; around.len() + 5]);
            let seen = sight.consider_all(&around, &mut keys, &mut got);
            assert_eq!(seen, &want[..], "sensor {k}, omniscient {omniscient}");
            // Both compilations of the first pass, whichever the processor runs.
            let mut plain = vec![0; around.len()];
            sight.keys(&around, &mut plain);
            #[cfg(target_arch = "x86_64")]
            if std::arch::is_x86_feature_detected!("avx2") {
                let mut wide = vec![0; around.len()];
                // SAFETY: checked just above.
                unsafe { crate::sim::grid::with_avx2(KeysPass { sight: &sight, around: &around, found: &mut wide }) };
                assert_eq!(wide, plain);
            }
            assert_eq!(plain.iter().filter(|&&k| k != UNSEEN).count(), want.len());
            seen_any[j] |= !want.is_empty() && want.len() < around.len() - 1;
        }
    }
    assert!(seen_any[0], "no sensor saw some but not all");
}

#[test]
fn the_remembered_half_cosine_follows_the_angle_asked() {
    let mut half = HalfCos::default();
    for angle in [1.0, 1.0, 0.5, 1.0, std::f64::consts::TAU, 0.5] {
        assert_eq!(half.of(angle).to_bits(), (0.5 * angle).cos().to_bits(), "angle {angle}");
    }
}

#[test]
fn small_rotation_is_the_rotation() {
    for k in -2000..=2000 {
        let a = f64::from(k) * 1e-4; // -0.2 ..= 0.2 rad, both sides of the switch
        let (r, exact) = (small_rotation(a), DVec2::from_angle(a));
        assert!((r - exact).abs().max_element() < 1e-15, "angle {a}: {r} vs {exact}");
    }
}
