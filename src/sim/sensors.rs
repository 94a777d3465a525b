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

/// Scratch buffers of [`sense_vehicles`], kept between ticks.
#[derive(Default)]
pub struct SenseScratch {
    /// Candidates around the current cell: (slot, position).
    around: Vec<(u32, DVec2)>,
    /// Detections of the current vehicle: (squared distance bits, id, slot).
    found: Vec<(u64, VehicleId, u32)>,
}

/// What one vehicle's sensors see of the candidates (slot, position) around it, into `found`.
struct Sight {
    id: VehicleId,
    position: DVec2,
    cone: Option<Cone>,
    radar_range2: f64,
    velodyne_range2: f64,
    omniscient: bool,
}

impl Sight {
    fn new(id: VehicleId, state: &VehicleState, radar: Option<&Radar>, velodyne: Option<&Velodyne>, omniscient: bool) -> Sight {
        Sight {
            id,
            position: state.position,
            cone: radar.map(|r| Cone::new(state.heading(), r.angle)),
            radar_range2: radar.map_or(-1.0, |r| r.range * r.range),
            velodyne_range2: velodyne.map_or(-1.0, |v| v.range * v.range),
            omniscient,
        }
    }

    fn consider(&self, slot: u32, position: DVec2, grid: &SpatialGrid, found: &mut Vec<(u64, VehicleId, u32)>) {
        let relative = position - self.position;
        let d2 = relative.length_squared();
        let seen = self.omniscient
            || d2 <= self.velodyne_range2
            || (d2 <= self.radar_range2 && self.cone.is_some_and(|c| c.contains(relative, d2)));
        if seen {
            let id = grid.get(slot).id;
            if id != self.id {
                // A non-negative f64's bits order like the number: integer sort keys.
                found.push((d2.to_bits(), id, slot));
            }
        }
    }
}

/// Sort `found` nearest first (ties by id) and write it into `readings`.
fn write_readings(found: &mut [(u64, VehicleId, u32)], grid: &SpatialGrid, readings: &mut SensorReadings) {
    found.sort_unstable_by_key(|&(d2, id, _)| (d2, id));
    readings.0.clear();
    readings.0.extend(found.iter().map(|&(_, _, slot)| {
        let e = grid.get(slot);
        Detection { id: e.id, position: e.position, velocity: e.velocity }
    }));
}

/// Rebuild the sensor grid and fill every sensing vehicle's [`SensorReadings`], nearest first.
///
/// The grid's cells are as large as the largest bounded range, so a vehicle sees only vehicles
/// of its own cell and the eight around it. Vehicles are visited in query order (spawn order,
/// which keeps each one's components in cache lines next to the previous one's); the candidates
/// around a cell are gathered into a small buffer and reused while consecutive vehicles share
/// that cell.
#[allow(clippy::type_complexity)]
pub fn sense_vehicles(
    mut grid: ResMut<SensorGrid>,
    everyone: Query<(&VehicleId, &VehicleState)>,
    mut sensing: Query<(&VehicleId, &VehicleState, Option<&Radar>, Option<&Velodyne>, Has<Omniscient>, &mut SensorReadings)>,
    mut scratch: Local<SenseScratch>,
) {
    let mut cell: f64 = 0.0;
    for (_, _, radar, velodyne, _, _) in &sensing {
        cell = cell.max(radar.map_or(0.0, |r| r.range)).max(velodyne.map_or(0.0, |v| v.range));
    }
    if sensing.is_empty() {
        return;
    }
    let s = &mut *scratch;
    grid.0.rebuild(
        if cell > 0.0 { cell } else { 100.0 },
        everyone.iter().map(|(&id, state)| GridEntry { position: state.position, velocity: state.velocity, id, index: 0 }),
    );
    let grid = &grid.0;
    let mut gathered: Option<(i32, i32)> = None;
    for (&id, state, radar, velodyne, omniscient, mut readings) in &mut sensing {
        let sight = Sight::new(id, state, radar, velodyne, omniscient);
        s.found.clear();
        if omniscient {
            for slot in 0..grid.len() as u32 {
                sight.consider(slot, grid.get(slot).position, grid, &mut s.found);
            }
        } else {
            let (cx, cy) = grid.cell_of(state.position);
            if gathered != Some((cx, cy)) {
                s.around.clear();
                for dx in -1..=1 {
                    for dy in -1..=1 {
                        grid.for_each_in_cell((cx + dx, cy + dy), |slot, e| s.around.push((slot, e.position)));
                    }
                }
                gathered = Some((cx, cy));
            }
            for &(other, position) in &s.around {
                sight.consider(other, position, grid, &mut s.found);
            }
        }
        write_readings(&mut s.found, grid, &mut readings);
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
