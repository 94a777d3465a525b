//! One chunk of sensing vehicles: candidates from the grid or a neighbour list, their keys,
//! and the readings written.

use glam::DVec2;

use super::errors::{Draws, Footprint};
use super::kernel_avx2::listed_keys_avx2;
use super::kernel_scalar::{ListKeysPass, gather_positions, near_of};
use super::keys::{Targets, UNSEEN, detection_key, first};
use super::radar::HalfCos;
use super::readings::{
    SensorStats, radar_errors_only, write_imperfect_readings, write_radar_error_readings, write_readings,
};
use super::sight::Sight;
use crate::sim::grid::lists::{DriftPart, Everyone, Lists, NEAR_MASK_BITS, Reach, Shape};
use crate::sim::grid::{pack, vectorised};
use crate::sim::{Candidates, SpatialGrid};
use crate::world::{Radar, SensorErrors, SensorReadings, VehicleId, VehicleState, Velodyne};

/// Scratch buffers of one thread of [`sense_vehicles`], kept between ticks.
/// On cache lines of its own (see [`crate::sim::parallel::Padded`]).
#[derive(Default)]
#[repr(align(128))]
pub struct SenseScratch {
    /// Candidates around the current cell.
    pub(super) around: Candidates,
    /// Every candidate's key (or [`UNSEEN`]), then the detections of the current vehicle as
    /// sort keys, see [`detection_key`].
    pub(super) keys: Vec<u64>,
    pub(super) found: Vec<u64>,
    /// A neighbour list's coordinates [m] and keys where the processor has no AVX2
    /// ([`Sight::consider_listed`]).
    pub(super) xs: Vec<f64>,
    pub(super) ys: Vec<f64>,
    pub(super) list_keys: Vec<u64>,
    /// A neighbour list's build: which candidates lie within reach, and scratch for finding them.
    pub(super) marks: Vec<u32>,
    pub(super) slots: Vec<u32>,
    /// The lists this thread built this tick (its chunk's, from vehicle `built_from` on), one
    /// after the other, and where each ends.
    pub(super) built: Vec<u32>,
    pub(super) built_ends: Vec<u32>,
    pub(super) built_from: Option<usize>,
    /// Angular extents of the targets found so far nearer than the current one (occlusion).
    pub(super) extents: Vec<(f64, f64, f64)>,
    /// Counts of this thread's vehicles this tick.
    pub(super) stats: SensorStats,
    pub(super) half_cos: HalfCos,
    /// With kept lists ([`sense_with_kept_lists`]): this chunk's displacements since the build
    /// and whether its vehicles' sensors are the build's.
    pub(super) drift: DriftPart,
    pub(super) shapes_held: bool,
}

/// Cells each side a vehicle of sensor range `range` [m] must search on a grid of `cell` [m]:
/// a point within `range` of a vehicle lies at most `ceil(range / cell)` cells away.
pub(super) fn reach(range: f64, cell: f64) -> i32 {
    ((range / cell).ceil() as i32).max(1)
}

/// Which candidates [`SenseScratch::around`] holds: those of the square of cells `reach` cells
/// around a cell, or the whole grid's.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Gathered {
    Square((i32, i32), i32),
    All,
}

/// Gather the candidates of the square of cells `reach` cells around `centre`, or of the whole
/// grid when that square has more cells than the grid has entries; returns which.
pub(super) fn gather(grid: &SpatialGrid, centre: (i32, i32), reach: i32, around: &mut Candidates) -> Gathered {
    around.clear();
    let side = 2.0 * reach as f64 + 1.0;
    if side * side > grid.len() as f64 {
        grid.gather_all(around);
        return Gathered::All;
    }
    grid.gather_cells(centre.0 - reach..=centre.0 + reach, centre.1 - reach..=centre.1 + reach, around);
    Gathered::Square(centre, reach)
}

/// Gather into `around` the candidates of the cells that `range` [m] reaches around `p`, unless
/// it holds them already (`gathered` says what it holds: consecutive vehicles mostly share a
/// cell).
pub(super) fn gather_within(
    grid: &SpatialGrid,
    p: DVec2,
    range: f64,
    gathered: &mut Option<Gathered>,
    around: &mut Candidates,
) {
    let centre = grid.cell_of(p);
    let reach = reach(range, grid.cell_size());
    if gathered.is_none_or(|g| g != Gathered::Square(centre, reach) && g != Gathered::All) {
        *gathered = Some(gather(grid, centre, reach, around));
    }
}

impl Sight {
    /// The detection keys of the neighbours `list` (places in `everyone`) it sees, in list
    /// order, at the front of `found`; returns that front.
    ///
    /// Where the processor has AVX2, one pass four neighbours at a time
    /// ([`listed_keys_avx2`]: gather, keys and packing in registers). Else three passes: the
    /// neighbours' coordinates into arrays ([`gather_positions`]), every neighbour's key (or
    /// [`UNSEEN`], [`ListKeysPass`]), then the seen keys packed to the front. Both give the
    /// same keys in the same order (the same operations on each neighbour).
    ///
    /// With `near` (a squared range [m²] and a mask, for lists of at most 64), bit k of the mask
    /// is set when the k-th neighbour lies within that range ([`within_reach`]).
    pub(super) fn consider_listed<'f>(
        &self,
        list: &[u32],
        everyone: Everyone<'_>,
        (xs, ys, keys): (&mut Vec<f64>, &mut Vec<f64>, &mut Vec<u64>),
        near: Option<(f64, &mut u64)>,
        found: &'f mut Vec<u64>,
    ) -> &'f mut [u64] {
        let n = list.len();
        let near = near.filter(|_| n <= NEAR_MASK_BITS);
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // Room for the last group's four keys, stored whole.
            let room = first(found, n.next_multiple_of(4));
            let r2 = near.as_ref().map(|(r2, _)| *r2);
            // SAFETY: the processor has AVX2, checked just above.
            let (seen, mask) = unsafe { listed_keys_avx2(self, everyone.states, list, r2, room) };
            if let Some((_, m)) = near {
                *m = mask;
            }
            return &mut room[..seen];
        }
        let (xs, ys, keys) = (first(xs, n), first(ys, n), first(keys, n));
        first(found, n);
        gather_positions(everyone.states, list, xs, ys);
        if let Some((r2, mask)) = near {
            *mask = near_of(xs, ys, (self.position, r2));
        }
        vectorised(ListKeysPass { sight: self, xs, ys, slots: list, keys });
        let seen = pack(keys, found, UNSEEN);
        &mut found[..seen]
    }
}
/// One ECS table of sensing vehicles as bevy's contiguous access hands it out: a slice of each
/// component (of the optional ones when the table has them), whether the table's vehicles are
/// omniscient, and the readings to write.
#[derive(Clone, Copy)]
pub(super) struct SensingTable<'a> {
    pub(super) ids: &'a [VehicleId],
    pub(super) states: &'a [VehicleState],
    pub(super) radars: Option<&'a [Radar]>,
    pub(super) velodynes: Option<&'a [Velodyne]>,
    pub(super) omniscient: bool,
    pub(super) errors: Option<&'a [SensorErrors]>,
}

/// What every chunk reads: the grid, the footprints of its entries (filled only when some
/// sensor has occlusion on) and the tick's draws.
#[derive(Clone, Copy)]
pub(super) struct SenseInput<'a> {
    pub(super) grid: &'a SpatialGrid,
    pub(super) footprints: &'a [Footprint],
    pub(super) draws: Draws,
}

/// Fill the readings of a contiguous chunk of sensing vehicles (items `start..` of `table`)
/// from the (read-only) grid.
pub(super) fn sense_chunk(
    input: SenseInput<'_>,
    table: SensingTable<'_>,
    start: usize,
    chunk: &mut [SensorReadings],
    s: &mut SenseScratch,
) {
    let grid = input.grid;
    let mut gathered: Option<Gathered> = None;
    let omniscient = table.omniscient;
    for (k, readings) in chunk.iter_mut().enumerate() {
        let i = start + k;
        let (id, state) = (&table.ids[i], &table.states[i]);
        let (radar, velodyne) = (table.radars.map(|r| &r[i]), table.velodynes.map(|v| &v[i]));
        let errors = table.errors.map(|e| &e[i]);
        let sight = Sight::new(*id, state, radar, velodyne, omniscient, &mut s.half_cos);
        if omniscient {
            if gathered != Some(Gathered::All) {
                s.around.clear();
                grid.gather_all(&mut s.around);
                gathered = Some(Gathered::All);
            }
        } else {
            gather_within(grid, state.position, Shape::of(radar, velodyne).range(), &mut gathered, &mut s.around);
        }
        let found = sight.consider_all(&s.around, &mut s.keys, &mut s.found);
        write_found(&sight, errors, input, grid, found, (&mut s.extents, &mut s.stats), readings);
    }
}

/// Write what `sight` sees of the targets `found` (detection keys of `targets`' slots) into
/// `readings`, through the errors of its sensors if it has some, counting into `stats`.
pub(super) fn write_found(
    sight: &Sight,
    errors: Option<&SensorErrors>,
    input: SenseInput<'_>,
    targets: &impl Targets,
    found: &mut [u64],
    (extents, stats): (&mut Vec<(f64, f64, f64)>, &mut SensorStats),
    readings: &mut SensorReadings,
) {
    match errors {
        Some(errors) if radar_errors_only(errors) => {
            write_radar_error_readings(sight, &errors.radar, input.draws, targets, found, stats, readings)
        }
        Some(errors) => write_imperfect_readings(
            sight,
            errors,
            input.draws,
            input.footprints,
            targets,
            found,
            extents,
            stats,
            readings,
        ),
        None => {
            stats.detections += found.len() as u64;
            write_readings(found, targets, sight.position, readings);
        }
    }
}
/// Where a sensor tick finds the neighbour lists: built this tick over the grid with the skin
/// [m] and the wifi range `floor` [m] ([`Reach`]; each chunk into its thread's
/// [`SenseScratch::built`], joined after the tick), or kept.
#[derive(Clone, Copy)]
pub(super) enum Listing<'a> {
    Build { skin: f64, floor: f64 },
    Kept(&'a Lists),
}

/// Fill the readings of a contiguous chunk of sensing vehicles (items `start..` of `table`,
/// which is every vehicle, `everyone`) from their neighbour lists; with `near_r2` [m²], also
/// note in `near` which neighbours on each list lie that close ([`Sight::consider_listed`]).
pub(super) fn sense_listed(
    input: SenseInput<'_>,
    table: SensingTable<'_>,
    everyone: Everyone<'_>,
    (listing, near_r2): (Listing<'_>, Option<f64>),
    (start, chunk, near): (usize, &mut [SensorReadings], &mut [u64]),
    s: &mut SenseScratch,
) {
    let grid = input.grid;
    let mut gathered: Option<Gathered> = None;
    s.built.clear();
    s.built_ends.clear();
    s.built_from = matches!(listing, Listing::Build { .. }).then_some(start);
    for (k, readings) in chunk.iter_mut().enumerate() {
        let i = start + k;
        let (id, state) = (table.ids[i], &table.states[i]);
        let (radar, velodyne) = (table.radars.map(|r| &r[i]), table.velodynes.map(|v| &v[i]));
        let list = match listing {
            Listing::Kept(lists) => lists.of(i),
            Listing::Build { skin, floor } => {
                let shape = Shape::of(radar, velodyne);
                let radius = shape.range() + skin;
                gather_within(grid, state.position, radius, &mut gathered, &mut s.around);
                s.around.within(state.position, radius, id, &mut s.marks, &mut s.slots);
                let reach = Reach::new(&shape, state.heading(), floor, skin);
                s.keys.clear();
                s.keys.extend(s.slots.iter().filter_map(|&slot| {
                    let e = grid.get(slot);
                    let relative = e.position - state.position;
                    let d2 = relative.length_squared();
                    reach.holds(relative, d2).then(|| detection_key(d2, e.index))
                }));
                s.keys.sort_unstable();
                let begin = s.built.len();
                s.built.extend(s.keys.iter().map(|&key| key as u32));
                s.built_ends.push(s.built.len() as u32);
                &s.built[begin..]
            }
        };
        let sight = Sight::new(id, state, radar, velodyne, false, &mut s.half_cos);
        // (A list longer than a mask is left to the wifi round: its mask stays 0.)
        let near = near_r2.map(|r2| {
            near[k] = 0;
            (r2, &mut near[k])
        });
        let found = sight.consider_listed(list, everyone, (&mut s.xs, &mut s.ys, &mut s.list_keys), near, &mut s.found);
        let errors = table.errors.map(|e| &e[i]);
        write_found(&sight, errors, input, &everyone, found, (&mut s.extents, &mut s.stats), readings);
    }
}
