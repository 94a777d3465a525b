//! Detection keys: a detection as a sortable integer (distance, grid slot, which sensors
//! reached it), their order, and the targets a key's slot names.

use glam::DVec2;

use crate::sim::grid::lists::Everyone;
use crate::sim::{GridEntry, SpatialGrid};

/// One detection as an integer sort key: the squared distance rounded to an f32 (a
/// non-negative float's bits order like the number, and rounding keeps the order but for
/// ties), then `low` (the grid slot and which sensors reach it, see [`REACH`]). Eight bytes
/// sort faster than the sixteen of the exact distance with the id; [`sort_nearest_first`]
/// puts the rare ties of the rounded distance in exact order.
pub(super) fn detection_key(d2: f64, low: u32) -> u64 {
    (u64::from((d2 as f32).to_bits()) << 32) | u64::from(low)
}

/// Sort detection keys nearest first, ties by id: as by the exact squared distance from `from`
/// and then the id. The keys hold the distance rounded to an f32, so detections whose
/// distances round alike (within about 1e-7 of each other, or equal) are put in exact order
/// among themselves afterwards, from their grid entries.
pub(super) fn sort_nearest_first(found: &mut [u64], grid: &impl Targets, from: DVec2) {
    found.sort_unstable();
    let mut k = 0;
    while k + 1 < found.len() {
        let rounded = found[k] >> 32;
        if found[k + 1] >> 32 != rounded {
            k += 1;
            continue;
        }
        let mut end = k + 2;
        while end < found.len() && found[end] >> 32 == rounded {
            end += 1;
        }
        found[k..end].sort_unstable_by_key(|&key| {
            let e = grid.target(key as u32 & !REACH);
            ((e.position - from).length_squared().to_bits(), e.id.0)
        });
        k = end;
    }
}

/// The first `n` items of `buffer`, grown to hold them if it is shorter. A sensor tick's
/// buffers only grow (no zero-filling per vehicle) and are used up to the length.
pub(super) fn first<T: Copy + Default>(buffer: &mut Vec<T>, n: usize) -> &mut [T] {
    if buffer.len() < n {
        buffer.resize(n, T::default());
    }
    &mut buffer[..n]
}
/// Where the readings find a target by the slot its detection key holds: the grid's entry, or
/// (with neighbour lists, [`NeighbourLists`]) the vehicle at that place of the query.
pub(super) trait Targets: Sync {
    fn target(&self, slot: u32) -> GridEntry;
}

impl Targets for SpatialGrid {
    #[inline]
    fn target(&self, slot: u32) -> GridEntry {
        *self.get(slot)
    }
}
impl Targets for Everyone<'_> {
    #[inline]
    fn target(&self, slot: u32) -> GridEntry {
        let (id, state) = (self.ids[slot as usize], &self.states[slot as usize]);
        GridEntry { position: state.position, velocity: state.velocity, id, index: slot }
    }
}
/// What [`Sight::keys`] writes for a candidate not seen: no detection key is all ones (a key's
/// high word is the f32 bits of a squared distance, never all ones; its low word is a slot
/// below 2³⁰ with the reach bits, which an unseen candidate would not have set).
pub(super) const UNSEEN: u64 = u64::MAX;

/// The low word of a detection key: the grid slot in the low 30 bits (grids hold fewer than
/// 2³⁰ vehicles), bit 31 set when the radar reaches the target, bit 30 when the velodyne does,
/// so the imperfect sensors need not test range and cone again.
pub(super) const REACH: u32 = 0b11 << 30;
pub(super) const RADAR_REACH: u32 = 1 << 31;
pub(super) const VELODYNE_REACH: u32 = 1 << 30;

/// The name of the radar's detections ([`Detection::sensor`](crate::world::Detection::sensor)).
pub const RADAR: &str = "radar";
/// The name of the velodyne's detections.
pub const VELODYNE: &str = "velodyne";
/// The name of an omniscient sensor's detections.
pub const OMNISCIENT: &str = "omniscient";

/// Which built-in sensor a detection with key low word `low` is named after: the radar where it
/// reaches the target, else the velodyne where it does, else the omniscient sensor (by the two
/// reach bits, one table look-up).
#[inline]
pub(super) fn reached_by(low: u32) -> &'static str {
    const BY_REACH: [&str; 4] = [OMNISCIENT, VELODYNE, RADAR, RADAR];
    BY_REACH[(low >> 30) as usize]
}
