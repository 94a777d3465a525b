//! What one vehicle's radar, velodyne and omniscient sensors see of candidates: the scalar
//! test of a candidate ([`Sight::key`]), the reference of the kernels.

use glam::DVec2;

use super::keys::{UNSEEN, detection_key, first};
use super::radar::{Cone, HalfCos, NO_CONE};
use crate::sim::Candidates;
use crate::sim::grid::{Pass, pack, vectorised};
use crate::world::{Radar, VehicleId, VehicleState, Velodyne};

/// What one vehicle's sensors see of the candidates (slot, position, id) around it.
pub(super) struct Sight {
    pub(super) id: VehicleId,
    pub(super) position: DVec2,
    /// The radar cone (any cone without a radar: `radar_range2` < 0 then rules it out).
    pub(super) cone: Cone,
    pub(super) radar_range2: f64,
    pub(super) velodyne_range2: f64,
    /// Whether the sensor is omniscient (bit 0, [`Sight::omniscient`]) and the cone's
    /// `everything` (bit 1) as one word, written whole, for [`Sight::key`]: the key pass reads
    /// them as a word, and a word read over two separate byte stores of the flags just made
    /// waited for those stores to leave the store buffer (perf: a seventh of the key pass's
    /// samples on that load).
    pub(super) flags: u32,
}

impl Sight {
    pub(super) fn new(
        id: VehicleId,
        state: &VehicleState,
        radar: Option<&Radar>,
        velodyne: Option<&Velodyne>,
        omniscient: bool,
        half_cos: &mut HalfCos,
    ) -> Sight {
        let cone = radar.map_or(NO_CONE, |r| Cone::with_cos(state.heading(), r.angle, half_cos.of(r.angle)));
        Sight {
            id,
            position: state.position,
            cone,
            radar_range2: radar.map_or(-1.0, |r| r.range * r.range),
            velodyne_range2: velodyne.map_or(-1.0, |v| v.range * v.range),
            flags: u32::from(omniscient) | (u32::from(cone.everything) << 1),
        }
    }

    /// Whether the sensor sees everyone ([`Omniscient`]).
    pub(super) fn omniscient(&self) -> bool {
        self.flags & 1 != 0
    }

    /// The detection keys of the candidates it sees (with which sensors reach each, see
    /// [`REACH`]), in candidate order, at the front of `found`; returns that front.
    ///
    /// Two passes: the first tests every candidate and writes its key, or [`UNSEEN`], without a
    /// branch on the candidate (which ones are seen is unpredictable), over the candidates'
    /// arrays, so the compiler turns it into vector code (four candidates an instruction where
    /// the processor has AVX2, chosen at run time; the same operations in the same order as
    /// the one-at-a-time code, so the same bits); the second packs the seen keys to the front.
    pub(super) fn consider_all<'f>(
        &self,
        around: &Candidates,
        keys: &mut Vec<u64>,
        found: &'f mut Vec<u64>,
    ) -> &'f mut [u64] {
        let n = around.len();
        let keys = first(keys, n);
        first(found, n);
        vectorised(KeysPass { sight: self, around, found: keys });
        let seen = pack(keys, found, UNSEEN);
        &mut found[..seen]
    }

    /// Each candidate's detection key, or [`UNSEEN`]: the first pass of [`Sight::consider_all`].
    /// The arithmetic is [`Cone::contains`]'s and `DVec2`'s (differences, then `x*x + y*y`),
    /// written on the coordinates.
    #[inline(always)]
    pub(super) fn keys(&self, around: &Candidates, found: &mut [u64]) {
        let candidates = around.xs.iter().zip(&around.ys).zip(&around.slots).zip(&around.ids);
        for (key, (((&x, &y), &slot), &other)) in found.iter_mut().zip(candidates) {
            *key = self.key(x, y, slot, other);
        }
    }

    /// The detection key of the candidate `other` at (`x`, `y`) [m] in slot `slot`, or
    /// [`UNSEEN`]: written without a branch on the candidate, so that [`Sight::keys`] turns
    /// into vector code, and shared with [`Sight::consider_listed`] so both give the same bits.
    #[inline(always)]
    pub(super) fn key(&self, x: f64, y: f64, slot: u32, other: VehicleId) -> u64 {
        let (p, h, cone) = (self.position, self.cone.heading, &self.cone);
        let acute = cone.cos_half >= 0.0;
        let (rx, ry) = (x - p.x, y - p.y);
        let d2 = rx * rx + ry * ry;
        let dot = rx * h.x + ry * h.y;
        let ahead = dot >= 0.0;
        let (dot2, limit) = (dot * dot, d2 * cone.cos_half2);
        let inside = (acute & ahead & (dot2 >= limit)) | (!acute & (ahead | (dot2 <= limit)));
        let (omniscient, everything) = (self.omniscient(), self.flags & 2 != 0);
        let in_cone = everything | ((d2 != 0.0) & inside);
        let radar = (d2 <= self.radar_range2) & in_cone;
        let velodyne = d2 <= self.velodyne_range2;
        let seen = (omniscient | velodyne | radar) & (other != self.id);
        let flags = (u32::from(radar) << 31) | (u32::from(velodyne) << 30);
        if seen { detection_key(d2, slot | flags) } else { UNSEEN }
    }
}

/// [`Sight::keys`] as a [`Pass`].
pub(super) struct KeysPass<'a> {
    pub(super) sight: &'a Sight,
    pub(super) around: &'a Candidates,
    pub(super) found: &'a mut [u64],
}

impl Pass for KeysPass<'_> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        self.sight.keys(self.around, self.found)
    }
}
