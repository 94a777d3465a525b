//! The neighbour-list kernel in scalar code (where the processor has no AVX2): the reference
//! the AVX2 kernel ([`super::kernel_avx2`]) is tested against.

use glam::DVec2;

use super::sight::Sight;
use crate::sim::grid::lists::NEAR_MASK_BITS;
use crate::sim::grid::{Pass, within_reach};
use crate::world::{VehicleId, VehicleState};

/// The coordinates of the vehicles at places `slots` of `states` into `xs` and `ys`: the first
/// pass of [`Sight::consider_listed`] where the processor has no AVX2.
#[inline]
pub(super) fn gather_positions(states: &[VehicleState], slots: &[u32], xs: &mut [f64], ys: &mut [f64]) {
    for ((x, y), &j) in xs.iter_mut().zip(ys.iter_mut()).zip(slots) {
        let p = states[j as usize].position;
        (*x, *y) = (p.x, p.y);
    }
}

/// The `near` of [`Sight::consider_listed`] for neighbours at (`xs`, `ys`): bit k for the k-th
/// (of at most 64) within `r2` [m²] of `p`.
pub(super) fn near_of(xs: &[f64], ys: &[f64], (p, r2): (DVec2, f64)) -> u64 {
    xs.iter()
        .zip(ys)
        .take(NEAR_MASK_BITS)
        .enumerate()
        .fold(0, |mask, (k, (&x, &y))| mask | u64::from(within_reach(p, x, y, r2)) << k)
}
/// The keys of a neighbour list's vehicles at (`xs`, `ys`): the second pass of
/// [`Sight::consider_listed`] where the processor has no AVX2, [`Sight::key`] on each (and the
/// reference [`listed_keys_avx2`] is tested against).
pub(super) struct ListKeysPass<'a> {
    pub(super) sight: &'a Sight,
    pub(super) xs: &'a [f64],
    pub(super) ys: &'a [f64],
    pub(super) slots: &'a [u32],
    pub(super) keys: &'a mut [u64],
}

impl Pass for ListKeysPass<'_> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        // A list never holds its own vehicle (`Candidates::within` leaves its id out when the
        // list is built), so no neighbour's id is read: an id that differs from ours stands in.
        let other = VehicleId(!self.sight.id.0);
        let neighbours = self.xs.iter().zip(self.ys).zip(self.slots);
        for (key, ((&x, &y), &slot)) in self.keys.iter_mut().zip(neighbours) {
            *key = self.sight.key(x, y, slot, other);
        }
    }
}
