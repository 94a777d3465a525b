//! The benchmark world: N vehicles on concentric three-lane ring roads at highway spacing, with
//! every module on (dynamics, radar + velodyne, wifi, network with one beacon per vehicle per
//! round, path following). Used by `smlworld bench` and the criterion benches.

use std::sync::Arc;

use bevy_ecs::prelude::{Query, Res};
use bevy_ecs::schedule::ScheduleLabel;
use glam::DVec2;

use crate::map::Path;
use crate::sim::{Phase, Rates, SimClock};
use crate::vehicles::{PathFollower, PathFollowing, PathFollowingPlugin};
use crate::world::{Channel, Mailbox, Radar, SensorSet, VehicleId, VehicleSpec, VehicleState, Velodyne};

use super::{SimBuilder, default_plugins};

/// Shape of the benchmark world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BenchWorld {
    /// Number of vehicles.
    pub vehicles: usize,
    /// Gap between consecutive vehicles of a lane [m] (2 s at 20 m/s).
    pub spacing: f64,
    /// Cruise speed [m/s].
    pub speed: f64,
    /// Radius of the innermost lane of each ring [m].
    pub ring_radius: f64,
    /// Lanes per ring.
    pub lanes: usize,
    /// Distance between lane centre lines [m].
    pub lane_width: f64,
    /// Centre-line resolution [points per metre].
    pub points_per_meter: f64,
}

impl Default for BenchWorld {
    fn default() -> Self {
        BenchWorld {
            vehicles: 1000,
            spacing: 40.0,
            speed: 20.0,
            ring_radius: 500.0,
            lanes: 3,
            lane_width: 3.5,
            points_per_meter: 0.5,
        }
    }
}

/// Schedule of the benchmark's beacons (one network message per vehicle per network round).
#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Beacons;

/// Queue one small network message (the vehicle's speed [m/s]) per vehicle.
pub fn send_beacons(clock: Res<SimClock>, mut vehicles: Query<(&VehicleState, &mut Mailbox)>) {
    for (state, mut mailbox) in &mut vehicles {
        mailbox.send(Channel::Network, clock.now, Arc::new(state.speed()));
    }
}

impl BenchWorld {
    /// Vehicles per ring (all lanes).
    pub fn per_ring(&self) -> usize {
        (0..self.lanes).map(|k| self.per_lane(k)).sum()
    }

    fn lane_radius(&self, lane: usize) -> f64 {
        self.ring_radius + lane as f64 * self.lane_width
    }

    fn per_lane(&self, lane: usize) -> usize {
        ((std::f64::consts::TAU * self.lane_radius(lane) / self.spacing).floor() as usize).max(1)
    }

    /// The lanes of ring `ring` (counter-clockwise closed loops), rings on a square grid with
    /// 200 m between neighbours.
    fn ring_lanes(&self, ring: usize, rings: usize) -> Vec<Arc<Path>> {
        let side = (rings as f64).sqrt().ceil().max(1.0) as usize;
        let pitch = 2.0 * self.lane_radius(self.lanes.saturating_sub(1)) + 200.0;
        let centre = DVec2::new((ring % side) as f64 * pitch, (ring / side) as f64 * pitch);
        (0..self.lanes)
            .map(|lane| {
                let r = self.lane_radius(lane);
                let n = ((std::f64::consts::TAU * r * self.points_per_meter).round() as usize).max(8);
                let points = (0..n)
                    .map(|i| centre + DVec2::from_angle(std::f64::consts::TAU * i as f64 / n as f64) * r)
                    .collect();
                Arc::new(Path::from_points(Vec::new(), points, true))
            })
            .collect()
    }

    /// A builder with every module on at the default rates and the vehicles spawned.
    pub fn builder(&self) -> SimBuilder {
        let rates = Rates::default();
        let mut b = SimBuilder::with_rates(rates);
        b.add_plugin(default_plugins).add_plugin(PathFollowingPlugin);
        b.add_module("beacons", Beacons, Phase::Control, rates.network);
        b.add_systems(Beacons, send_beacons);
        self.spawn(&mut b);
        b
    }

    /// Spawn the vehicles into `b` (ids −1, −2, ...).
    pub fn spawn(&self, b: &mut SimBuilder) {
        let rings = self.vehicles.div_ceil(self.per_ring().max(1));
        let params = PathFollowing { speed: self.speed, ..Default::default() };
        let sensors = SensorSet { radar: Some(Radar::default()), velodyne: Some(Velodyne::default()), omniscient: false };
        let mut next = 0usize;
        'rings: for ring in 0..rings {
            for (lane, path) in self.ring_lanes(ring, rings).into_iter().enumerate() {
                let count = self.per_lane(lane);
                for k in 0..count {
                    if next == self.vehicles {
                        break 'rings;
                    }
                    let s = path.length * k as f64 / count as f64;
                    let (p, heading) = path.sample(s);
                    let mut spec = VehicleSpec::new(VehicleId(-1 - next as i32), VehicleState::new(p, heading, self.speed));
                    spec.sensors = sensors;
                    spec.route = Some(Arc::clone(&path));
                    if let Ok(e) = b.spawn_vehicle(spec) {
                        b.world_mut().entity_mut(e).insert(PathFollower::starting_at(params, s));
                    }
                    next += 1;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use bevy_ecs::prelude::With;

    use super::*;
    use crate::sim::Parallelism;
    use crate::vehicles::PathFollower;
    use crate::world::{ControlCommand, SensorReadings};

    /// Everything the heavy systems write, per vehicle, in id order, as exact bits.
    fn fingerprint(parallelism: Parallelism) -> Vec<(i32, Vec<u64>)> {
        let mut b = BenchWorld { vehicles: 600, ..Default::default() }.builder();
        b.insert_resource(parallelism);
        let mut sim = b.build();
        sim.run_for(2.0);
        let world = sim.world_mut();
        let mut query = world.query_filtered::<(&VehicleId, &VehicleState, &ControlCommand, &SensorReadings, &PathFollower), With<Mailbox>>();
        let mut rows: Vec<(i32, Vec<u64>)> = query
            .iter(world)
            .map(|(id, s, c, r, f)| {
                let mut bits = vec![s.position.x, s.position.y, s.yaw, s.velocity.x, s.velocity.y, c.steering, c.speed, f.s];
                for d in &r.0 {
                    bits.extend([d.id.0 as f64, d.position.x, d.position.y, d.velocity.x, d.velocity.y]);
                }
                (id.0, bits.into_iter().map(f64::to_bits).collect())
            })
            .collect();
        rows.sort_by_key(|r| r.0);
        rows
    }

    #[test]
    fn results_do_not_depend_on_the_thread_count() {
        let single = fingerprint(Parallelism::single());
        assert_eq!(single.len(), 600);
        assert!(single.iter().any(|(_, bits)| bits.len() > 8), "some vehicle must detect others");
        for threads in [2, 3, 7] {
            let split = fingerprint(Parallelism { threads, min_vehicles: 0 });
            assert!(single == split, "{threads} threads changed the results");
        }
    }
}
