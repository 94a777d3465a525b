//! The candidates around a vehicle gathered from the grid, in arrays for the vector units.

use glam::DVec2;

use super::pass::{Pass, pack, vectorised};
use crate::world::VehicleId;

/// Candidates gathered from some cells of a grid, as arrays (structure of arrays): slot,
/// coordinates \[m\] and id of each, so a test of all of them against one sensor vectorises.
#[derive(Debug, Clone, Default)]
pub struct Candidates {
    /// Grid slot of each ([`SpatialGrid::get`](crate::sim::SpatialGrid::get)).
    pub slots: Vec<u32>,
    /// x \[m\].
    pub xs: Vec<f64>,
    /// y \[m\].
    pub ys: Vec<f64>,
    /// Vehicle id.
    pub ids: Vec<VehicleId>,
}

impl Candidates {
    /// Forget every candidate (the buffers stay).
    pub fn clear(&mut self) {
        self.slots.clear();
        self.xs.clear();
        self.ys.clear();
        self.ids.clear();
    }

    /// Number of candidates.
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    /// Whether there is none.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// The slots of the candidates within `radius` \[m\] of `p` (inclusive; the squared distance
    /// as [`DVec2::distance_squared`] computes it) but vehicle `exclude`, in candidate order,
    /// into `out`; `marks` is scratch. A branch-free pass over the arrays (vector code, AVX2
    /// where the processor has it, chosen at run time), then a pack.
    pub fn within(&self, p: DVec2, radius: f64, exclude: VehicleId, marks: &mut Vec<u32>, out: &mut Vec<u32>) {
        marks.clear();
        marks.resize(self.len(), 0);
        vectorised(MarkWithin { candidates: self, p, r2: radius * radius, exclude, marks });
        out.clear();
        out.resize(marks.len(), 0);
        let n = pack(marks, out, u32::MAX);
        out.truncate(n);
    }

    /// Each candidate's slot where it is within reach, else `u32::MAX` (no slot: grids hold
    /// fewer than 2³² entries).
    #[inline(always)]
    fn mark_within(&self, p: DVec2, r2: f64, exclude: VehicleId, marks: &mut [u32]) {
        let candidates = self.xs.iter().zip(&self.ys).zip(&self.slots).zip(&self.ids);
        for (mark, (((&x, &y), &slot), &id)) in marks.iter_mut().zip(candidates) {
            *mark = if within_reach(p, x, y, r2) & (id != exclude) { slot } else { u32::MAX };
        }
    }

    #[inline]
    pub(super) fn push(&mut self, slot: u32, x: f64, y: f64, id: VehicleId) {
        self.slots.push(slot);
        self.xs.push(x);
        self.ys.push(y);
        self.ids.push(id);
    }
}

/// Whether (`x`, `y`) lies within squared distance `r2` [m²] of `p` (inclusive), computed as
/// every range query computes it (differences, then x² + y²), so that a search through the
/// grid and one through neighbour lists agree at the edge bit for bit.
#[inline(always)]
pub(crate) fn within_reach(p: DVec2, x: f64, y: f64, r2: f64) -> bool {
    let (dx, dy) = (x - p.x, y - p.y);
    dx * dx + dy * dy <= r2
}

/// [`Candidates::mark_within`] as a [`Pass`].
struct MarkWithin<'a> {
    candidates: &'a Candidates,
    p: DVec2,
    r2: f64,
    exclude: VehicleId,
    marks: &'a mut [u32],
}

impl Pass for MarkWithin<'_> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        self.candidates.mark_within(self.p, self.r2, self.exclude, self.marks)
    }
}
