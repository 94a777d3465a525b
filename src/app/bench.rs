//! The benchmark world: N vehicles on a generated three-lane ring highway
//! ([`crate::map::generate::ring_highway`]) whose radius grows with N so the spacing stays at
//! highway gaps, with every module on (dynamics, radar + velodyne, wifi, network with one beacon
//! per vehicle per round, path following). Used by `smlworld bench` and the criterion benches.

use std::sync::Arc;

use bevy_ecs::prelude::{Query, Res};
use bevy_ecs::schedule::{IntoScheduleConfigs, ScheduleLabel};

use crate::map::generate::{GenerateError, RingParams, ring_highway, ring_lane_tag};
use crate::map::{LaneletMap, MapError, Path, RouteOptions};
use crate::sim::{Control, Rates, SimClock, SimSystems};
use crate::vehicles::{PathFollower, PathFollowing, PathFollowingPlugin};
use crate::world::{Channel, Mailbox, Radar, SensorSet, SimTime, VehicleId, VehicleSpec, VehicleState, Velodyne};

use super::{SimBuilder, default_plugins};

/// Why the benchmark world could not be built (the generated map did not load: a bug).
#[derive(Debug, thiserror::Error)]
pub enum BenchError {
    /// The ring highway generator refused the parameters.
    #[error("generating the benchmark ring highway: {0}")]
    Generate(#[from] GenerateError),
    /// The generated map did not load or had no loop through a lane's tagged node.
    #[error("loading the generated benchmark ring highway: {0}")]
    Map(#[from] MapError),
}

/// Shape of the benchmark world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BenchWorld {
    /// Number of vehicles.
    pub vehicles: usize,
    /// Gap between consecutive vehicles of a lane [m] (2 s at 20 m/s).
    pub spacing: f64,
    /// Cruise speed [m/s].
    pub speed: f64,
    /// Smallest radius of the ring's inner edge [m]; the ring grows beyond it to give every
    /// vehicle `spacing` metres of lane.
    pub ring_radius: f64,
    /// Lanes of the ring.
    pub lanes: usize,
    /// Lane width [m].
    pub lane_width: f64,
    /// Centre-line resolution [points per metre].
    pub points_per_meter: f64,
    /// Largest distance between the generated map's boundary and a true circle [m]: sets the
    /// map's node spacing (coarser for bigger rings, so the map stays small).
    pub chord_error: f64,
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
            chord_error: 0.1,
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
    /// The generated ring: inner edge radius [m] large enough for every vehicle to have about
    /// `spacing` metres of lane, and the node spacing [m] that keeps the chord error.
    pub fn ring(&self) -> RingParams {
        let lanes = self.lanes.max(1);
        let per_lane = self.vehicles.div_ceil(lanes) as f64;
        let radius = (per_lane * self.spacing / std::f64::consts::TAU).max(self.ring_radius);
        let outer = radius + lanes as f64 * self.lane_width;
        // A chord of length c on a circle of radius R strays c² / (8 R) from it.
        let node_spacing = (8.0 * outer * self.chord_error).sqrt().max(1.0);
        RingParams { lanes, radius, lane_width: self.lane_width, clockwise: false, node_spacing }
    }

    /// The closed loops of the generated ring's lanes, rightmost first.
    pub fn lanes(&self) -> Result<Vec<Arc<Path>>, BenchError> {
        let ring = self.ring();
        let xml = ring_highway(&ring)?;
        let map = LaneletMap::parse_str(&xml, std::path::Path::new("generated bench ring"))?;
        let options = RouteOptions { points_per_meter: self.points_per_meter };
        (0..ring.lanes).map(|k| Ok(Arc::new(map.closed_loop_tag(&ring_lane_tag(ring.lanes, k), &options)?))).collect()
    }

    /// A builder with every module on at the default rates and the vehicles spawned.
    pub fn builder(&self) -> Result<SimBuilder, BenchError> {
        let rates = Rates::default();
        let mut b = SimBuilder::with_rates(rates);
        b.add_plugin(default_plugins).add_plugin(PathFollowingPlugin);
        // Beacons go out from the controllers' own schedule at the network rate: a module of
        // their own in the control phase would hold the V2V in-boxes until it ran.
        let period = SimTime::from_secs(1.0 / rates.network).0.max(1);
        b.add_systems(
            Control,
            send_beacons.in_set(SimSystems::Control).run_if(move |clock: Res<SimClock>| clock.now.0 % period == 0),
        );
        self.spawn(&mut b)?;
        Ok(b)
    }

    /// Spawn the vehicles into `b` (ids −1, −2, ...), evenly spread over the lanes and along
    /// each lane, lane after lane.
    pub fn spawn(&self, b: &mut SimBuilder) -> Result<(), BenchError> {
        let lanes = self.lanes()?;
        let params = PathFollowing { speed: self.speed, ..Default::default() };
        let sensors =
            SensorSet { radar: Some(Radar::default()), velodyne: Some(Velodyne::default()), omniscient: false };
        let mut next = 0usize;
        for (k, path) in lanes.iter().enumerate() {
            // Lane k gets an equal share, the first lanes one more when N does not divide.
            let count = self.vehicles / lanes.len() + usize::from(k < self.vehicles % lanes.len());
            for j in 0..count {
                let s = path.length * j as f64 / count as f64;
                let (p, heading) = path.sample(s);
                let mut spec = VehicleSpec::new(VehicleId(-1 - next as i32), VehicleState::new(p, heading, self.speed));
                spec.sensors = sensors;
                spec.route = Some(Arc::clone(path));
                if let Ok(e) = b.spawn_vehicle(spec) {
                    b.world_mut().entity_mut(e).insert(PathFollower::starting_at(params, s));
                }
                next += 1;
            }
        }
        Ok(())
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
        let mut b = BenchWorld { vehicles: 600, ..Default::default() }.builder().expect("the bench world builds");
        b.insert_resource(parallelism);
        let mut sim = b.build();
        sim.run_for(2.0);
        let world = sim.world_mut();
        let mut query = world.query_filtered::<(&VehicleId, &VehicleState, &ControlCommand, &SensorReadings, &PathFollower), With<Mailbox>>();
        let mut rows: Vec<(i32, Vec<u64>)> = query
            .iter(world)
            .map(|(id, s, c, r, f)| {
                let mut bits =
                    vec![s.position.x, s.position.y, s.yaw, s.velocity.x, s.velocity.y, c.steering, c.speed, f.s];
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
    fn the_ring_grows_to_give_every_vehicle_its_gap() {
        // 10,000 vehicles per lane around an inner edge of radius 10,000 * 40 m / 2π: each lane
        // is 2π (R + (k + 1/2) 3.5 m) long, i.e. 40 m per vehicle plus at most 2π 8.75 m / 10,000.
        let world = BenchWorld { vehicles: 30_000, ..Default::default() };
        let lanes = world.lanes().expect("the bench world builds");
        assert_eq!(lanes.len(), 3);
        for path in &lanes {
            assert!(path.closed);
            let gap = path.length / 10_000.0;
            assert!((gap - 40.0).abs() < 0.02, "{gap} m per vehicle");
        }
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
