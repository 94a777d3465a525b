//! Simulated sensors: radar cone, velodyne circle and omniscient, over one spatial grid per tick.
//!
//! Every sensor tick the grid is rebuilt from all vehicles with cells as large as the largest
//! bounded sensor range, then each sensing vehicle scans only its neighbouring cells: O(N) for
//! bounded ranges. An [`Omniscient`] vehicle scans everyone (O(N) per such vehicle).

use bevy_ecs::prelude::{Has, Local, Query, ResMut, Resource};
use glam::DVec2;

use crate::app::{Plugin, SimBuilder};
use crate::world::{Detection, Omniscient, Radar, SensorReadings, VehicleId, VehicleState, Velodyne};

use super::{GridEntry, Sensors, SpatialGrid};

/// Whether a target at offset `relative` [m] from the sensor lies inside a radar cone facing
/// `heading` (a unit vector) with full opening angle `angle` [rad] (edges inclusive).
///
/// Every angle here is in radians. The 2015 Python code compared an angle in degrees with one in
/// radians in this test, so its radar cone was not the configured one; this one is.
pub fn in_radar_cone(relative: DVec2, heading: DVec2, angle: f64) -> bool {
    Cone::new(heading, angle).contains(relative, relative.length_squared())
}

/// A radar cone prepared for many tests: no trigonometry or square root per target.
#[derive(Debug, Clone, Copy)]
struct Cone {
    heading: DVec2,
    /// cos of the half opening angle, and its square.
    cos_half: f64,
    cos_half2: f64,
    everything: bool,
}

impl Cone {
    fn new(heading: DVec2, angle: f64) -> Cone {
        let half = 0.5 * angle;
        let cos_half = half.cos();
        Cone { heading, cos_half, cos_half2: cos_half * cos_half, everything: half >= std::f64::consts::PI }
    }

    /// `relative` at squared distance `d2`: is its angle to the heading at most the half angle?
    /// That is dot >= |rel| cos(half), compared squared with the signs handled.
    fn contains(&self, relative: DVec2, d2: f64) -> bool {
        if self.everything {
            return true;
        }
        if d2 == 0.0 {
            return false;
        }
        let dot = relative.dot(self.heading);
        if self.cos_half >= 0.0 {
            dot >= 0.0 && dot * dot >= d2 * self.cos_half2
        } else {
            dot >= 0.0 || dot * dot <= d2 * self.cos_half2
        }
    }
}

/// The grid all sensors query, rebuilt every sensor tick.
#[derive(Resource, Debug, Default)]
pub struct SensorGrid(pub SpatialGrid);

/// Rebuild the sensor grid and fill every sensing vehicle's [`SensorReadings`], nearest first.
#[allow(clippy::type_complexity)]
pub fn sense_vehicles(
    mut grid: ResMut<SensorGrid>,
    everyone: Query<(&VehicleId, &VehicleState)>,
    mut sensing: Query<(&VehicleId, &VehicleState, Option<&Radar>, Option<&Velodyne>, Has<Omniscient>, &mut SensorReadings)>,
    mut found: Local<Vec<(u64, VehicleId, u32)>>,
) {
    let mut cell: f64 = 0.0;
    for (_, _, radar, velodyne, _, _) in &sensing {
        cell = cell.max(radar.map_or(0.0, |r| r.range)).max(velodyne.map_or(0.0, |v| v.range));
    }
    if sensing.is_empty() {
        return;
    }
    grid.0.rebuild(
        if cell > 0.0 { cell } else { 100.0 },
        everyone.iter().map(|(&id, s)| GridEntry { position: s.position, velocity: s.velocity, id, index: 0 }),
    );
    let grid = &grid.0;
    for (&id, state, radar, velodyne, omniscient, mut readings) in &mut sensing {
        found.clear();
        let cone = radar.map(|r| Cone::new(state.heading(), r.angle));
        let radar_range2 = radar.map_or(-1.0, |r| r.range * r.range);
        let velodyne_range2 = velodyne.map_or(-1.0, |v| v.range * v.range);
        let mut consider = |slot: u32, e: &GridEntry, d2: f64| {
            if e.id == id {
                return;
            }
            let seen = omniscient
                || d2 <= velodyne_range2
                || (d2 <= radar_range2 && cone.is_some_and(|c| c.contains(e.position - state.position, d2)));
            if seen {
                // A non-negative f64's bits order like the number: integer sort keys.
                found.push((d2.to_bits(), e.id, slot));
            }
        };
        if omniscient {
            for slot in 0..grid.len() as u32 {
                let e = grid.get(slot);
                consider(slot, e, e.position.distance_squared(state.position));
            }
        } else {
            let range = radar.map_or(0.0, |r| r.range).max(velodyne.map_or(0.0, |v| v.range));
            grid.for_each_within(state.position, range, &mut consider);
        }
        found.sort_unstable_by_key(|&(d2, id, _)| (d2, id));
        readings.0.clear();
        readings.0.extend(found.iter().map(|&(_, _, slot)| {
            let e = grid.get(slot);
            Detection { id: e.id, position: e.position, velocity: e.velocity }
        }));
    }
}

/// Radar, velodyne and omniscient sensing in the [`Sensors`] schedule.
#[derive(Debug, Clone, Copy, Default)]
pub struct SensorsPlugin;

impl Plugin for SensorsPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.insert_resource(SensorGrid::default());
        sim.add_systems(Sensors, sense_vehicles);
    }
}
