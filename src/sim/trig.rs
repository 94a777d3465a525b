//! Trigonometry of the small angles the hot loops meet every tick, by Taylor polynomials where
//! they are below rounding, else by the library: a one-step turn, the steering of a vehicle on
//! a gentle curve (a 10,000-vehicle ring steers about 1e-4 rad). Each agrees with the library
//! to within an ulp or so; the library call (not inlined, 8 ns or more) was several percent of
//! the benchmark.

/// Below this magnitude [rad] the polynomials are used: their first omitted terms are under
/// 1e-20 of the result, far below a double's rounding.
const SMALL: f64 = 1e-2;

/// sin and cos of `a` \[rad\].
#[inline]
pub fn small_sin_cos(a: f64) -> (f64, f64) {
    if is_small(a) { sin_cos_polynomial(a) } else { a.sin_cos() }
}

/// Whether `a` is small enough for the polynomials (`SMALL`).
#[inline(always)]
pub fn is_small(a: f64) -> bool {
    a.abs() < SMALL
}

/// [`small_sin_cos`]'s polynomials, for `a` that [`is_small`] (also in vector code: the same
/// operations, so the same bits).
#[inline(always)]
pub fn sin_cos_polynomial(a: f64) -> (f64, f64) {
    let a2 = a * a;
    let sin = a * (1.0 - a2 / 6.0 * (1.0 - a2 / 20.0 * (1.0 - a2 / 42.0)));
    let cos = 1.0 - a2 / 2.0 * (1.0 - a2 / 12.0 * (1.0 - a2 / 30.0 * (1.0 - a2 / 56.0)));
    (sin, cos)
}

/// tan of `a` \[rad\]: a + a³/3 + 2a⁵/15 + 17a⁷/315 + 62a⁹/2835 when small.
#[inline]
pub fn small_tan(a: f64) -> f64 {
    if is_small(a) { tan_polynomial(a) } else { a.tan() }
}

/// [`small_tan`]'s polynomial, for `a` that [`is_small`].
#[inline(always)]
pub fn tan_polynomial(a: f64) -> f64 {
    let a2 = a * a;
    a + a * a2 * (1.0 / 3.0 + a2 * (2.0 / 15.0 + a2 * (17.0 / 315.0 + a2 * (62.0 / 2835.0))))
}

/// atan of `x`: x − x³/3 + x⁵/5 − x⁷/7 + x⁹/9 when small.
#[inline]
pub fn small_atan(x: f64) -> f64 {
    if is_small(x) { atan_polynomial(x) } else { x.atan() }
}

/// [`small_atan`]'s polynomial, for `x` that [`is_small`].
#[inline(always)]
pub fn atan_polynomial(x: f64) -> f64 {
    let x2 = x * x;
    // The leading x stays a factor, so atan(−0) is −0.
    x * (1.0 - x2 * (1.0 / 3.0 - x2 * (1.0 / 5.0 - x2 * (1.0 / 7.0 - x2 * (1.0 / 9.0)))))
}

/// ⌊x⌋ as an i32 (saturating, NaN to 0, as `x.floor() as i32`) without the library's `floor`,
/// which this target calls out of line (no SSE4.1 rounding instruction in baseline x86-64).
#[inline]
pub fn floor_i32(x: f64) -> i32 {
    let t = x as i32;
    t.saturating_sub(i32::from((t as f64) > x))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Arguments across and around the polynomials' range, both signs.
    fn arguments() -> impl Iterator<Item = f64> {
        (0..20_000).flat_map(|k| {
            let x = 1.2e-2 * (k as f64 / 20_000.0).powi(3) + 1e-300 * k as f64;
            [x, -x]
        })
    }

    fn ulps(a: f64, b: f64) -> u64 {
        (a.to_bits() as i64 - b.to_bits() as i64).unsigned_abs()
    }

    #[test]
    fn small_angle_functions_agree_with_the_library_to_an_ulp() {
        for x in arguments() {
            let (s, c) = small_sin_cos(x);
            let (ls, lc) = x.sin_cos();
            assert!(ulps(s, ls) <= 1 && ulps(c, lc) <= 1, "sin_cos({x}): ({s}, {c}), library ({ls}, {lc})");
            assert!(ulps(small_tan(x), x.tan()) <= 1, "tan({x}): {}, library {}", small_tan(x), x.tan());
            assert!(ulps(small_atan(x), x.atan()) <= 1, "atan({x}): {}, library {}", small_atan(x), x.atan());
        }
        for x in [0.5, -3.0, 1e3, f64::NAN, f64::INFINITY] {
            assert_eq!(small_tan(x).to_bits(), x.tan().to_bits());
            assert_eq!(small_atan(x).to_bits(), x.atan().to_bits());
        }
    }

    #[test]
    fn floor_i32_is_floor_as_i32() {
        let mut xs = vec![0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 2.999_999, -2.999_999, 1e-300, -1e-300, 1e300, -1e300];
        xs.extend([f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 2_147_483_647.5, -2_147_483_648.5, -2_147_483_648.0]);
        xs.extend((0..4000).map(|k| (k as f64 - 2000.0) * 0.37));
        for x in xs {
            assert_eq!(floor_i32(x), x.floor() as i32, "floor of {x}");
        }
    }
}
