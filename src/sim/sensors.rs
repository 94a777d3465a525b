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
    let half = 0.5 * angle;
    if half >= std::f64::consts::PI {
        return true;
    }
    let d = relative.length();
    if d == 0.0 {
        return false;
    }
    relative.dot(heading) >= d * half.cos()
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
    mut found: Local<Vec<(f64, Detection)>>,
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
    for (&id, state, radar, velodyne, omniscient, mut readings) in &mut sensing {
        found.clear();
        let heading = state.heading();
        let radar_range = radar.map_or(-1.0, |r| r.range);
        let velodyne_range = velodyne.map_or(-1.0, |v| v.range);
        let mut consider = |e: &GridEntry, d2: f64| {
            if e.id == id {
                return;
            }
            let seen = omniscient
                || d2 <= velodyne_range * velodyne_range
                || radar.is_some_and(|r| {
                    d2 <= radar_range * radar_range && in_radar_cone(e.position - state.position, heading, r.angle)
                });
            if seen {
                found.push((d2, Detection { id: e.id, position: e.position, velocity: e.velocity }));
            }
        };
        if omniscient {
            for e in grid.0.entries() {
                consider(e, e.position.distance_squared(state.position));
            }
        } else {
            grid.0.for_each_within(state.position, radar_range.max(velodyne_range), &mut consider);
        }
        found.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.id.cmp(&b.1.id)));
        readings.0.clear();
        readings.0.extend(found.iter().map(|&(_, d)| d));
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
