//! The neighbour-list kernel in AVX2 registers, four neighbours at a time; the same keys as
//! the scalar kernel ([`super::kernel_scalar`]).

use glam::DVec2;

use super::keys::{RADAR_REACH, VELODYNE_REACH};
use super::sight::Sight;
use crate::sim::grid::lists::NEAR_MASK_BITS;
use crate::world::VehicleState;

/// [`Sight::consider_listed`] in AVX2 registers, four neighbours at a time: each four's
/// coordinates loaded from `states`, their detection keys worked out as [`Sight::key`] works
/// them out (the same subtractions, products, sums and comparisons, no fused multiply-add, so
/// the same bits; NaN compares as there), and the seen ones stored to the front of `found`
/// (which must hold `slots.len()` rounded up to four) in list order, by a permutation
/// ([`PACK_FOUR`]). Returns how many were seen and, with `near_r2`, which of the first 64 lie
/// within it ([`within_reach`]: the same squared distance).
///
/// It replaced three passes (coordinates into arrays, keys into an array, packing) and
/// their loop set-ups, alias checks and one-at-a-time remainders, for lists of about 14.
///
/// # Safety
/// Only on a processor with AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
pub(super) unsafe fn listed_keys_avx2(
    sight: &Sight,
    states: &[VehicleState],
    slots: &[u32],
    near_r2: Option<f64>,
    found: &mut [u64],
) -> (usize, u64) {
    use std::arch::x86_64::{
        _CMP_GE_OQ, _CMP_LE_OQ, _CMP_NEQ_UQ, _mm_castps_si128, _mm_loadu_pd, _mm_loadu_si128, _mm_set_epi32,
        _mm256_add_pd, _mm256_and_pd, _mm256_and_si256, _mm256_castpd_si256, _mm256_cmp_pd, _mm256_cvtepu32_epi64,
        _mm256_cvtpd_ps, _mm256_loadu_si256, _mm256_movemask_pd, _mm256_mul_pd, _mm256_or_pd, _mm256_or_si256,
        _mm256_permutevar8x32_epi32, _mm256_set_m128d, _mm256_set1_epi64x, _mm256_set1_pd, _mm256_slli_epi64,
        _mm256_storeu_si256, _mm256_sub_pd, _mm256_unpackhi_pd, _mm256_unpacklo_pd,
    };
    let n = slots.len();
    assert!(found.len() >= n.next_multiple_of(4), "room for whole groups of four");
    let (p, cone) = (sight.position, &sight.cone);
    let (px, py) = (_mm256_set1_pd(p.x), _mm256_set1_pd(p.y));
    let (hx, hy) = (_mm256_set1_pd(cone.heading.x), _mm256_set1_pd(cone.heading.y));
    let cos_half2 = _mm256_set1_pd(cone.cos_half2);
    let (radar2, velodyne2) = (_mm256_set1_pd(sight.radar_range2), _mm256_set1_pd(sight.velodyne_range2));
    let near2 = _mm256_set1_pd(near_r2.unwrap_or(f64::NEG_INFINITY));
    let zero = _mm256_set1_pd(0.0);
    let acute = cone.cos_half >= 0.0;
    // Whole-lane masks for `everything` and `omniscient` (all ones or none).
    let lanes = |on: bool| _mm256_set1_pd(f64::from_bits(if on { u64::MAX } else { 0 }));
    let (everything, omniscient) = (lanes(sight.flags & 2 != 0), lanes(sight.omniscient()));
    let (radar_bit, velodyne_bit) =
        (_mm256_set1_epi64x(i64::from(RADAR_REACH)), _mm256_set1_epi64x(i64::from(VELODYNE_REACH)));
    let (mut seen, mut near) = (0usize, 0u64);
    for g in (0..n).step_by(4) {
        // The group's four places (as an array and in a register); past the list's end, the
        // last one again (masked out by `valid`). Where the list holds four more, the register
        // is loaded from the list itself (a load of an array just written place by place would
        // wait for those stores to leave the store buffer).
        let (four, places, valid): ([u32; 4], _, u32) = match slots.get(g..g + 4) {
            Some(whole @ &[a, b, c, d]) => {
                // SAFETY: `whole` is four u32s (16 bytes); the load needs no alignment.
                ([a, b, c, d], unsafe { _mm_loadu_si128(whole.as_ptr().cast()) }, 0b1111)
            }
            _ => {
                let four: [u32; 4] = std::array::from_fn(|l| slots[(g + l).min(n - 1)]);
                let places = _mm_set_epi32(four[3] as i32, four[2] as i32, four[1] as i32, four[0] as i32);
                (four, places, (1 << (n - g)) - 1)
            }
        };
        // (x, y) of vehicle j: a `DVec2` is two f64 side by side (`#[repr(C)]`, x first).
        let at = |l: usize| {
            let q: &DVec2 = &states[four[l] as usize].position;
            // SAFETY: `q` points at two initialised f64s (x, then y); the load needs no alignment.
            unsafe { _mm_loadu_pd(std::ptr::from_ref(q).cast::<f64>()) }
        };
        // (x0, y0, x2, y2) and (x1, y1, x3, y3), then their even and odd lanes interleaved.
        let (even, odd) = (_mm256_set_m128d(at(2), at(0)), _mm256_set_m128d(at(3), at(1)));
        let (x, y) = (_mm256_unpacklo_pd(even, odd), _mm256_unpackhi_pd(even, odd));
        // `Sight::key`, lane by lane.
        let (rx, ry) = (_mm256_sub_pd(x, px), _mm256_sub_pd(y, py));
        let d2 = _mm256_add_pd(_mm256_mul_pd(rx, rx), _mm256_mul_pd(ry, ry));
        let dot = _mm256_add_pd(_mm256_mul_pd(rx, hx), _mm256_mul_pd(ry, hy));
        let ahead = _mm256_cmp_pd::<_CMP_GE_OQ>(dot, zero);
        let (dot2, limit) = (_mm256_mul_pd(dot, dot), _mm256_mul_pd(d2, cos_half2));
        let inside = if acute {
            _mm256_and_pd(ahead, _mm256_cmp_pd::<_CMP_GE_OQ>(dot2, limit))
        } else {
            _mm256_or_pd(ahead, _mm256_cmp_pd::<_CMP_LE_OQ>(dot2, limit))
        };
        let in_cone = _mm256_or_pd(everything, _mm256_and_pd(_mm256_cmp_pd::<_CMP_NEQ_UQ>(d2, zero), inside));
        let radar = _mm256_and_pd(_mm256_cmp_pd::<_CMP_LE_OQ>(d2, radar2), in_cone);
        let velodyne = _mm256_cmp_pd::<_CMP_LE_OQ>(d2, velodyne2);
        let visible = _mm256_or_pd(omniscient, _mm256_or_pd(velodyne, radar));
        let kept = (_mm256_movemask_pd(visible) as u32 & valid) as usize;
        if near_r2.is_some() && g < NEAR_MASK_BITS {
            let within = _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_LE_OQ>(d2, near2)) as u32 & valid;
            near |= u64::from(within) << g;
        }
        // Keys: the f32 bits of d² high, the place and the reach bits low (`detection_key`).
        let high = _mm256_slli_epi64::<32>(_mm256_cvtepu32_epi64(_mm_castps_si128(_mm256_cvtpd_ps(d2))));
        let places = _mm256_cvtepu32_epi64(places);
        let reach = _mm256_or_si256(
            _mm256_and_si256(_mm256_castpd_si256(radar), radar_bit),
            _mm256_and_si256(_mm256_castpd_si256(velodyne), velodyne_bit),
        );
        let keys = _mm256_or_si256(high, _mm256_or_si256(places, reach));
        // SAFETY: `PACK_FOUR[kept]` is eight i32s (32 bytes); the load needs no alignment.
        let order = unsafe { _mm256_loadu_si256(PACK_FOUR[kept].as_ptr().cast()) };
        // SAFETY: `seen` <= `g` and `g + 4` <= `found.len()` (asserted): four u64s in bounds.
        unsafe { _mm256_storeu_si256(found.as_mut_ptr().add(seen).cast(), _mm256_permutevar8x32_epi32(keys, order)) };
        seen += kept.count_ones() as usize;
    }
    (seen, near)
}

/// For each set of four lanes kept (bit l for lane l), the 32-bit halves of those 64-bit lanes
/// moved to the front in order: the permutation [`listed_keys_avx2`] packs a group's seen keys
/// with (the rest of the lanes repeat lane 0, never read).
#[cfg(target_arch = "x86_64")]
pub(super) const PACK_FOUR: [[i32; 8]; 16] = {
    let mut table = [[0; 8]; 16];
    let mut kept = 0;
    while kept < 16 {
        let mut at = 0;
        let mut lane = 0;
        while lane < 4 {
            if kept & (1 << lane) != 0 {
                table[kept][2 * at] = 2 * lane;
                table[kept][2 * at + 1] = 2 * lane + 1;
                at += 1;
            }
            lane += 1;
        }
        kept += 1;
    }
    table
};
