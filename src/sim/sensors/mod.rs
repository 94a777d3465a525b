//! Simulated sensors: radar cone, velodyne circle and omniscient, over one spatial grid per tick.
//!
//! Every sensor tick the grid is rebuilt from all vehicles with cells as large as the typical
//! (median) sensor range, then each sensing vehicle scans only the cells its own range reaches:
//! its 3 x 3 neighbourhood when its range is typical, a wider square for the few with a longer
//! range, so a few long-range sensors cost only their own wider search, never a coarser grid for
//! everyone. O(N) for bounded ranges. An [`Omniscient`](crate::world::Omniscient) vehicle scans everyone (O(N) per such
//! vehicle).
//!
//! Where every vehicle senses with a bounded range from one ECS table (the common case), the
//! grid is built only now and then, for Verlet neighbour lists (`NeighbourLists`): each
//! vehicle's list holds those within its range plus a skin, kept while no two neighbours have
//! closed in on each other by the skin (traffic moves together: seconds at a time), so most
//! ticks test a short list per vehicle and rebuild nothing. The readings are the grid scan's,
//! bit for bit.
//!
//! Imperfect sensors ([`SensorErrors`](crate::world::SensorErrors), issue 21) cost only their own vehicles: after the
//! candidates are found as above, occlusion compares each with the nearer ones found (a target
//! whose angular extent lies inside one nearer target's is hidden), dropout drops a detection
//! with its probability, and Gaussian noise moves range, bearing and velocity. Every draw is
//! counter-based ([`super::random`]), keyed by (seed, sensor, observer and target, tick): no
//! allocation, the same bits for any thread count; two hashes per noisy detection
//! (`SensorKeys`). The normals come from the ziggurat on 24 or 32 bits of a hash each
//! ([`super::random::normal_half`]: a multiplication each, mostly) and the bearing error's
//! rotation from a short polynomial, so noise costs no `ln` or `sin_cos` per detection.
//! [`SensorStats`] counts detections and the misses of each kind.
//!
//! The files: `tick` (the system), `scan` (one chunk of vehicles), `sight` (what one
//! vehicle sees of a candidate; the scalar reference) beside `kernel_scalar` and
//! `kernel_avx2` (neighbour lists, four at a time), `radar` (the cone), `keys`
//! (detection keys and their order), `readings` and `errors` (noise, dropout, occlusion),
//! and [`plugins`], the API of a student's sensor. The grid and the neighbour lists, which the
//! wifi round reads too, live in [`super::grid`].

use bevy_ecs::schedule::IntoScheduleConfigs;

use crate::sim::grid::lists::SensorGrid;
use crate::sim::{Parallelism, Plugin, Sensors, SimBuilder, SimSystems};

mod errors;
#[cfg(target_arch = "x86_64")]
mod kernel_avx2;
mod kernel_scalar;
mod keys;
pub mod plugins;
mod radar;
mod readings;
mod scan;
mod sight;
#[cfg(test)]
mod tests;
mod tick;

pub use keys::{OMNISCIENT, RADAR, VELODYNE};
pub use radar::{Cone, in_radar_cone};
pub use readings::SensorStats;
pub use tick::sense_vehicles;

/// Radar, velodyne and omniscient sensing in the [`Sensors`] schedule.
#[derive(Debug, Clone, Copy, Default)]
pub struct SensorsPlugin;

impl Plugin for SensorsPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.insert_resource(SensorGrid::default());
        sim.insert_resource(SensorStats::default());
        sim.world_mut().init_resource::<Parallelism>();
        sim.add_systems(Sensors, sense_vehicles.in_set(SimSystems::Sense));
    }
}
