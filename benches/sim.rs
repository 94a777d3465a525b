//! Criterion benches of each simulation module alone on the benchmark world (1,000 and 10,000
//! vehicles on a generated ring highway): dynamics, sensors (perfect, and with noise and
//! dropout), network, wifi (perfect, and with loss, delay and jitter), path following, and the
//! lane-change control stack (lane positions, index and MOBIL decisions, leaders, IDM); and the
//! spatial grid's rebuild (what sensing and every wifi round start with).
//! Run with `cargo bench --bench sim`; `smlworld bench` measures everything together.

use bevy_ecs::schedule::ScheduleLabel;
use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use smlworld::app::running::bench::{
    Beacons, BenchWorld, DEGRADED_WIFI, degraded_radar, send_beacons, send_wifi_beacons,
};
use smlworld::prelude::*;
use smlworld::sim::{GridEntry, Parallelism, SpatialGrid};

#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct WifiBeacons;

/// A sim of `n` bench vehicles with only the modules `plugin` adds.
fn sim_with(n: usize, plugin: impl Plugin) -> Sim {
    sim_of(BenchWorld { vehicles: n, ..Default::default() }, plugin)
}

/// A sim of `world`'s vehicles with only the modules `plugin` adds (and those `world` adds:
/// `lane_change` brings lane positions, the IDM and lane changes).
fn sim_of(world: BenchWorld, plugin: impl Plugin) -> Sim {
    let mut b = SimBuilder::new();
    b.add_plugin(plugin);
    world.spawn(&mut b).expect("the bench world builds");
    let mut sim = b.build();
    sim.run_for(1.0); // warm the buffers
    sim
}

/// One vehicle in a hundred (ids -100, -200, ...) gets a 500 m radar; the rest keep 100 m.
fn long_range_radars(mut sim: Sim) -> Sim {
    let world = sim.world_mut();
    let mut radars = world.query::<(&VehicleId, &mut Radar)>();
    for (id, mut radar) in radars.iter_mut(world) {
        if id.0 % 100 == 0 {
            radar.range = 500.0;
        }
    }
    sim.run_for(1.0); // warm the buffers of the long-range searches
    sim
}

/// Every vehicle's radar noisy and dropping detections, as `smlworld bench --degraded` has it.
fn noisy_radars(mut sim: Sim) -> Sim {
    let world = sim.world_mut();
    world.insert_resource(SimSeed(1));
    let mut vehicles = world.query::<bevy_ecs::entity::Entity>();
    let all: Vec<_> = vehicles.iter(world).collect();
    for e in all {
        world.entity_mut(e).insert(degraded_radar());
    }
    sim.run_for(1.0);
    sim
}

/// Builds the sim of one bench case.
type MakeSim = Box<dyn Fn() -> Sim>;

fn modules(c: &mut Criterion) {
    let mut group = c.benchmark_group("one sim second");
    group.sample_size(10);
    for n in [1_000usize, 10_000] {
        let cases: Vec<(&str, MakeSim)> = vec![
            ("dynamics 50 Hz", Box::new(move || sim_with(n, DynamicsPlugin))),
            ("sensors 20 Hz", Box::new(move || sim_with(n, SensorsPlugin))),
            ("sensors 20 Hz, 1% radar 500 m", Box::new(move || long_range_radars(sim_with(n, SensorsPlugin)))),
            (
                "network 1 Hz",
                Box::new(move || {
                    sim_with(n, |b: &mut SimBuilder| {
                        b.add_plugin(V2vPlugin::default());
                        b.add_module("beacons", Beacons, Phase::Control, 1.0);
                        b.add_systems(Beacons, send_beacons);
                    })
                }),
            ),
            (
                "wifi 10 Hz",
                Box::new(move || {
                    sim_with(n, |b: &mut SimBuilder| {
                        b.add_plugin(V2vPlugin::default());
                        b.add_module("wifi beacons", WifiBeacons, Phase::Control, 10.0);
                        b.add_systems(WifiBeacons, send_wifi_beacons);
                    })
                }),
            ),
            ("sensors 20 Hz, radar noise and dropout", Box::new(move || noisy_radars(sim_with(n, SensorsPlugin)))),
            (
                "wifi 10 Hz, 10 % loss, 10 ms delay, 5 ms jitter",
                Box::new(move || {
                    sim_with(n, |b: &mut SimBuilder| {
                        let range = V2vConfig::default().wifi_range;
                        b.add_plugin(V2vPlugin::default());
                        b.insert_resource(V2vConfig { wifi_range: range, wifi: DEGRADED_WIFI, ..V2vConfig::default() });
                        b.insert_resource(SimSeed(1));
                        b.add_module("wifi beacons", WifiBeacons, Phase::Control, 10.0);
                        b.add_systems(WifiBeacons, send_wifi_beacons);
                    })
                }),
            ),
            ("path following 20 Hz", Box::new(move || sim_with(n, PathFollowingPlugin))),
            (
                "lane changes 20 Hz: lane positions, MOBIL, leaders, IDM (with sensors, dynamics)",
                Box::new(move || {
                    let world = BenchWorld { vehicles: n, lane_change: true, ..Default::default() };
                    sim_of(world, |b: &mut SimBuilder| {
                        b.add_plugin(SensorsPlugin).add_plugin(DynamicsPlugin).add_plugin(PathFollowingPlugin);
                    })
                }),
            ),
        ];
        for (name, make) in cases {
            let mut sim = make();
            group.bench_with_input(BenchmarkId::new(name, n), &n, |b, _| b.iter(|| sim.run_for(1.0)));
        }
    }
    group.finish();
}

/// The grid rebuild alone: 10,000 vehicles in road order on a ring of 3 lanes (as the bench
/// spawns them), 100 m cells (the sensors' median range).
fn grid_rebuild(c: &mut Criterion) {
    let mut group = c.benchmark_group("spatial grid rebuild");
    let (n, lanes, radius) = (10_000usize, 3usize, 21_225.0);
    let entries: Vec<GridEntry> = (0..n)
        .map(|i| {
            let (j, k) = (i / lanes, i % lanes);
            let angle = std::f64::consts::TAU * j as f64 * lanes as f64 / n as f64;
            let r = radius + 3.5 * k as f64;
            GridEntry {
                position: DVec2::new(r * angle.cos(), r * angle.sin()),
                velocity: DVec2::new(-angle.sin(), angle.cos()) * 30.0,
                id: VehicleId(-1 - i as i32),
                index: i as u32,
            }
        })
        .collect();
    let mut grid = SpatialGrid::default();
    group.bench_function("10,000 vehicles", |b| b.iter(|| grid.rebuild(100.0, entries.iter().copied())));
    let two = Parallelism::split(2);
    group.bench_function("10,000 vehicles, 2 threads", |b| {
        b.iter(|| grid.rebuild_on(two, 100.0, entries.len(), |i| entries[i]))
    });
    group.finish();
}

criterion_group!(benches, modules, grid_rebuild);
criterion_main!(benches);
