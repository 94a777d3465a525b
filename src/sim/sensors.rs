//! Simulated sensors: radar cone, velodyne circle and omniscient, over one spatial grid per tick.
//!
//! Every sensor tick the grid is rebuilt from all vehicles with cells as large as the typical
//! (median) sensor range, then each sensing vehicle scans only the cells its own range reaches:
//! its 3 x 3 neighbourhood when its range is typical, a wider square for the few with a longer
//! range, so a few long-range sensors cost only their own wider search, never a coarser grid for
//! everyone. O(N) for bounded ranges. An [`Omniscient`] vehicle scans everyone (O(N) per such
//! vehicle).

use bevy_ecs::prelude::{Has, Local, Mut, Query, Res, ResMut, Resource};
use glam::DVec2;

use super::{Plugin, SimBuilder};
use crate::world::{Detection, Omniscient, Radar, SensorReadings, VehicleId, VehicleState, Velodyne};

use bevy_ecs::schedule::IntoScheduleConfigs;

use super::parallel::recycle;
use super::{GridEntry, Parallelism, Sensors, SimSystems, SpatialGrid};

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
    /// That is dot >= |rel| cos(half), compared squared with the signs handled. Written without
    /// branches on the target (the sensor loop tests ~25 targets per vehicle and tick, and which
    /// ones are seen is unpredictable).
    fn contains(&self, relative: DVec2, d2: f64) -> bool {
        let dot = relative.dot(self.heading);
        let ahead = dot >= 0.0;
        let (dot2, limit) = (dot * dot, d2 * self.cos_half2);
        let inside = if self.cos_half >= 0.0 { ahead & (dot2 >= limit) } else { ahead | (dot2 <= limit) };
        self.everything | ((d2 != 0.0) & inside)
    }
}

/// The grid all sensors query, rebuilt every sensor tick.
#[derive(Resource, Debug, Default)]
pub struct SensorGrid(pub SpatialGrid);

/// Scratch buffers of one thread of [`sense_vehicles`], kept between ticks.
#[derive(Default)]
pub struct SenseScratch {
    /// Candidates around the current cell: (slot, position, id).
    around: Vec<(u32, DVec2, VehicleId)>,
    /// Detections of the current vehicle as sort keys, see [`detection_key`].
    found: Vec<u128>,
}

/// Cells each side a vehicle of sensor range `range` [m] must search on a grid of `cell` [m]:
/// a point within `range` of a vehicle lies at most `ceil(range / cell)` cells away.
fn reach(range: f64, cell: f64) -> i32 {
    ((range / cell).ceil() as i32).max(1)
}

/// Gather the candidates (slot, position, id) of the square of cells `reach` cells around
/// `centre`, or of the whole grid when that square has more cells than the grid has entries.
fn gather(grid: &SpatialGrid, centre: (i32, i32), reach: i32, around: &mut Vec<(u32, DVec2, VehicleId)>) {
    around.clear();
    let side = 2.0 * reach as f64 + 1.0;
    if side * side > grid.len() as f64 {
        around.extend((0..grid.len() as u32).map(|slot| {
            let e = grid.get(slot);
            (slot, e.position, e.id)
        }));
        return;
    }
    for dx in -reach..=reach {
        for dy in -reach..=reach {
            grid.for_each_in_cell((centre.0 + dx, centre.1 + dy), |slot, e| around.push((slot, e.position, e.id)));
        }
    }
}

/// One detection as an integer sort key: squared distance, then id, then grid slot (the slot
/// breaks no real tie: ids are unique). A non-negative f64's bits order like the number, and
/// flipping an i32's sign bit makes its unsigned order the signed one.
fn detection_key(d2: f64, id: VehicleId, slot: u32) -> u128 {
    ((d2.to_bits() as u128) << 64) | (((id.0 as u32 ^ 0x8000_0000) as u128) << 32) | slot as u128
}

/// What one vehicle's sensors see of the candidates (slot, position, id) around it.
struct Sight {
    id: VehicleId,
    position: DVec2,
    /// The radar cone (any cone without a radar: `radar_range2` < 0 then rules it out).
    cone: Cone,
    radar_range2: f64,
    velodyne_range2: f64,
    omniscient: bool,
}

impl Sight {
    fn new(
        id: VehicleId,
        state: &VehicleState,
        radar: Option<&Radar>,
        velodyne: Option<&Velodyne>,
        omniscient: bool,
    ) -> Sight {
        Sight {
            id,
            position: state.position,
            cone: radar.map_or(NO_CONE, |r| Cone::new(state.heading(), r.angle)),
            radar_range2: radar.map_or(-1.0, |r| r.range * r.range),
            velodyne_range2: velodyne.map_or(-1.0, |v| v.range * v.range),
            omniscient,
        }
    }

    /// Write the candidate's key at `found[n]`; returns `n + 1` if it is seen, else `n` (no
    /// branch on the outcome).
    fn consider(&self, slot: u32, position: DVec2, id: VehicleId, found: &mut [u128], n: usize) -> usize {
        let relative = position - self.position;
        let d2 = relative.length_squared();
        let seen = self.omniscient
            | (d2 <= self.velodyne_range2)
            | ((d2 <= self.radar_range2) & self.cone.contains(relative, d2));
        found[n] = detection_key(d2, id, slot);
        n + (seen & (id != self.id)) as usize
    }
}

/// The cone of a vehicle without a radar (never consulted: its radar range is negative).
const NO_CONE: Cone = Cone { heading: DVec2::ZERO, cos_half: 1.0, cos_half2: 1.0, everything: false };

/// Sort `found` nearest first (ties by id) and write it into `readings`.
fn write_readings(found: &mut [u128], grid: &SpatialGrid, readings: &mut SensorReadings) {
    found.sort_unstable();
    readings.0.clear();
    readings.0.extend(found.iter().map(|&key| {
        let e = grid.get(key as u32);
        Detection { id: e.id, position: e.position, velocity: e.velocity }
    }));
}

/// One sensing vehicle as the query hands it out.
type SensingItem<'a> =
    (&'a VehicleId, &'a VehicleState, Option<&'a Radar>, Option<&'a Velodyne>, bool, Mut<'a, SensorReadings>);

/// Fill the readings of a contiguous chunk of sensing vehicles from the (read-only) grid.
fn sense_chunk(grid: &SpatialGrid, chunk: &mut [SensingItem<'_>], s: &mut SenseScratch) {
    let mut gathered: Option<((i32, i32), i32)> = None;
    for (id, state, radar, velodyne, omniscient, readings) in chunk.iter_mut() {
        let sight = Sight::new(**id, state, *radar, *velodyne, *omniscient);
        let mut n = 0;
        if *omniscient {
            s.found.clear();
            s.found.resize(grid.len(), 0);
            for slot in 0..grid.len() as u32 {
                let e = grid.get(slot);
                n = sight.consider(slot, e.position, e.id, &mut s.found, n);
            }
        } else {
            let centre = grid.cell_of(state.position);
            let reach = reach(sensor_range(*radar, *velodyne), grid.cell_size());
            if gathered != Some((centre, reach)) {
                gather(grid, centre, reach, &mut s.around);
                gathered = Some((centre, reach));
            }
            s.found.clear();
            s.found.resize(s.around.len(), 0);
            for &(other, position, other_id) in &s.around {
                n = sight.consider(other, position, other_id, &mut s.found, n);
            }
        }
        s.found.truncate(n);
        write_readings(&mut s.found, grid, readings);
    }
}

/// Largest bounded range of a vehicle's sensors [m] (0 without radar and velodyne).
fn sensor_range(radar: Option<&Radar>, velodyne: Option<&Velodyne>) -> f64 {
    radar.map_or(0.0, |r| r.range).max(velodyne.map_or(0.0, |v| v.range))
}

/// Side of the sensor grid's cells [m]: the median of the sensing vehicles' positive ranges
/// (100 m when none has one). `ranges` is scratch space, reused between ticks.
fn typical_range(ranges: &mut [f64]) -> f64 {
    if ranges.is_empty() {
        return 100.0;
    }
    let middle = ranges.len() / 2;
    let (_, median, _) = ranges.select_nth_unstable_by(middle, f64::total_cmp);
    *median
}

/// Rebuild the sensor grid and fill every sensing vehicle's [`SensorReadings`], nearest first.
///
/// The grid's cells are as large as the median bounded range, so a typical vehicle sees only
/// vehicles of its own cell and the eight around it, and one of longer range searches as many
/// cells around it as its range reaches. Vehicles are visited in query order (spawn order,
/// which keeps each one's components in cache lines next to the previous one's); the candidates
/// around a cell are gathered into a small buffer and reused while consecutive vehicles share
/// that cell. The vehicles are cut into contiguous chunks over [`Parallelism::threads`]
/// threads; each vehicle's readings depend only on the grid and itself, so the split never
/// changes them.
#[allow(clippy::type_complexity)]
pub fn sense_vehicles(
    mut grid: ResMut<SensorGrid>,
    parallelism: Res<Parallelism>,
    everyone: Query<(&VehicleId, &VehicleState)>,
    mut sensing: Query<(
        &VehicleId,
        &VehicleState,
        Option<&Radar>,
        Option<&Velodyne>,
        Has<Omniscient>,
        &mut SensorReadings,
    )>,
    mut scratch: Local<Vec<SenseScratch>>,
    mut buffer: Local<Vec<SensingItem<'static>>>,
    mut ranges: Local<Vec<f64>>,
) {
    if sensing.is_empty() {
        return;
    }
    ranges.clear();
    ranges.extend(
        sensing
            .iter()
            .map(|(_, _, radar, velodyne, _, _)| sensor_range(radar, velodyne))
            .filter(|&r| r > 0.0 && r.is_finite()),
    );
    grid.0.rebuild(
        typical_range(&mut ranges),
        everyone.iter().map(|(&id, state)| GridEntry {
            position: state.position,
            velocity: state.velocity,
            id,
            index: 0,
        }),
    );
    let grid = &grid.0;
    let mut items: Vec<SensingItem<'_>> = recycle(std::mem::take(&mut *buffer));
    items.extend(sensing.iter_mut());
    parallelism.for_each_chunk(&mut items, &mut scratch, |chunk, s| sense_chunk(grid, chunk, s));
    *buffer = recycle(items);
}

/// Radar, velodyne and omniscient sensing in the [`Sensors`] schedule.
#[derive(Debug, Clone, Copy, Default)]
pub struct SensorsPlugin;

impl Plugin for SensorsPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.insert_resource(SensorGrid::default());
        sim.world_mut().init_resource::<Parallelism>();
        sim.add_systems(Sensors, sense_vehicles.in_set(SimSystems::Sense));
    }
}
