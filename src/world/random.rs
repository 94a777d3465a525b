//! Counter-based randomness: every draw is a pure function of (seed, stream, index, draw), a
//! SplitMix64 hash of the four (Steele, Lea, Flood 2014, "Fast splittable pseudorandom number
//! generators"), so no global generator exists and nothing depends on thread count or system
//! order; a draw allocates nothing.
//!
//! Besides single draws: [`binomial`] (how many of n independent trials succeed, from one
//! uniform) and [`OrderedSample`] (which k of n positions, in increasing order, one draw per
//! position), with which a lossy channel decides a whole round for one receiver in O(1) and
//! leaves the positions to whoever reads them (see `sim::v2v`). The module sits in `world`
//! because the V2V in-boxes draw those positions while they are iterated.

/// SplitMix64's finaliser: a bijective mix of 64 bits.
pub fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A uniform number in [0, 1) keyed by `(seed, stream, index, draw)`.
pub fn uniform(seed: u64, stream: u64, index: u64, draw: u64) -> f64 {
    let h = mix(mix(mix(mix(seed) ^ stream) ^ index) ^ draw);
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// The first three rounds of [`uniform`]'s hash: with [`uniform_at`],
/// `uniform(seed, stream, index, draw) == uniform_at(key(seed, stream, index), draw)`, so many
/// draws of one counter cost one mix each.
pub fn key(seed: u64, stream: u64, index: u64) -> u64 {
    mix(mix(mix(seed) ^ stream) ^ index)
}

/// Draw `draw` of the counter `key` ([`key`]): uniform in [0, 1).
pub fn uniform_at(key: u64, draw: u64) -> f64 {
    (mix(key ^ draw) >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// ln(n!): summed exactly below 30, else Stirling's series to n⁻⁵ (error below 1e-13).
fn ln_factorial(n: u32) -> f64 {
    if n < 30 {
        return (2..=n).map(|k| f64::from(k).ln()).sum();
    }
    let x = f64::from(n);
    let x2 = x * x;
    x * x.ln() - x
        + 0.5 * (std::f64::consts::TAU * x).ln()
        + (1.0 / 12.0 - (1.0 / 360.0 - 1.0 / (1260.0 * x2)) / x2) / x
}

/// A Binomial(`n`, `p`) number (successes among `n` independent trials of probability `p`)
/// from one uniform `u` in [0, 1), by inversion from the mode: the mode's probability from
/// log-factorials, then its neighbours by the pmf's ratios, alternately below and above, until
/// `u` is used up. Expected O(√(n p (1 − p))) steps, no allocation; exact up to rounding
/// (a `u` in the last ~1e-12 of the mass that rounding leaves over gives the mode).
pub fn binomial(n: u32, p: f64, u: f64) -> u32 {
    if n == 0 || p <= 0.0 {
        return 0;
    }
    if p >= 1.0 {
        return n;
    }
    let q = 1.0 - p;
    let mode = ((f64::from(n) + 1.0) * p).floor().min(f64::from(n)) as u32;
    let ln_mode = ln_factorial(n) - ln_factorial(mode) - ln_factorial(n - mode)
        + f64::from(mode) * p.ln()
        + f64::from(n - mode) * q.ln();
    let f_mode = ln_mode.exp();
    let mut u = u;
    if u < f_mode {
        return mode;
    }
    u -= f_mode;
    let (down, up) = (q / p, p / q);
    let (mut lo, mut hi, mut f_lo, mut f_hi) = (mode, mode, f_mode, f_mode);
    loop {
        let mut moved = false;
        if lo > 0 && f_lo > 0.0 {
            f_lo *= f64::from(lo) / f64::from(n - lo + 1) * down;
            lo -= 1;
            moved = true;
            if u < f_lo {
                return lo;
            }
            u -= f_lo;
        }
        if hi < n && f_hi > 0.0 {
            f_hi *= f64::from(n - hi) / f64::from(hi + 1) * up;
            hi += 1;
            moved = true;
            if u < f_hi {
                return hi;
            }
            u -= f_hi;
        }
        if !moved {
            return mode;
        }
    }
}

/// A uniformly random `k`-subset of the positions `0..n`, yielded in increasing order by
/// sequential random sampling (Vitter 1984, "Faster methods for random sampling", Algorithm A):
/// each position costs one counter-based draw ([`uniform_at`] of `key`, draws 1, 2, ...; draw 0
/// is left to the caller, e.g. for the [`binomial`] that chose `k`) and O(skip) arithmetic.
/// Copy it to replay the same positions; it allocates nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OrderedSample {
    key: u64,
    /// Positions still to yield.
    left: u32,
    /// Positions not yet decided, from `at` on.
    pool: u32,
    /// First position not yet decided.
    at: u32,
    /// Next draw number.
    draw: u64,
}

impl OrderedSample {
    /// `k` of the positions `0..n` (`k <= n`), drawn from counter `key`.
    pub fn new(key: u64, k: u32, n: u32) -> OrderedSample {
        OrderedSample { key, left: k.min(n), pool: n, at: 0, draw: 1 }
    }

    /// Positions still to yield.
    pub fn remaining(&self) -> u32 {
        self.left
    }

    /// An empty sample (yields nothing).
    pub fn empty() -> OrderedSample {
        OrderedSample::new(0, 0, 0)
    }
}

impl Iterator for OrderedSample {
    type Item = u32;

    fn next(&mut self) -> Option<u32> {
        if self.left == 0 {
            return None;
        }
        let v = uniform_at(self.key, self.draw);
        self.draw += 1;
        // The skip S before the next chosen position: P(S > s) = Π_{j=0..s} (N - n - j) / (N - j)
        // for N positions left and n to choose; S is the first s where that falls to v or below.
        let mut skip = 0u32;
        let mut top = f64::from(self.pool - self.left);
        let mut left = f64::from(self.pool);
        let mut quot = top / left;
        while quot > v {
            skip += 1;
            top -= 1.0;
            left -= 1.0;
            quot *= top / left;
        }
        let position = self.at + skip;
        self.at = position + 1;
        self.pool -= skip + 1;
        self.left -= 1;
        Some(position)
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        (self.left as usize, Some(self.left as usize))
    }
}

/// A counter-based stream of 64-bit words: word `m` of `key` is a hash of (key, m), so a
/// consumer that needs a varying number of words (a rejection sampler) stays a pure function
/// of its key. Two words of state, no allocation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Words {
    key: u64,
    next: u64,
}

impl Words {
    /// The words of counter `key`, from word 0.
    pub fn new(key: u64) -> Words {
        Words { key, next: 0 }
    }

    /// The next 64 random bits.
    #[inline]
    pub fn bits(&mut self) -> u64 {
        let b = mix(self.key ^ self.next);
        self.next += 1;
        b
    }

    /// The next uniform number in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.bits() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// A standard normal number by the ziggurat method ([`normal`]).
    #[inline]
    pub fn normal(&mut self) -> f64 {
        normal(self)
    }
}

/// A standard normal number from the 32 random bits `h` by the ziggurat of [`normal`]: the
/// layer from the low 8 bits, a uniform in [-1, 1) of 2⁻²³ resolution from the other 24. In
/// 98.5 % of the draws that is all (a multiplication, no further hash); a draw outside its
/// layer's rectangle (the tail, a wedge, or another try) goes on with the full words of
/// `Words` at key `mix(more)` from word `part << 32` (cold), so a caller that takes several
/// normals from the halves of a few words gives each its own `part` and they never share a
/// continuation word. A caller with counter-based words (REFERENCE "Channels":
/// reproducibility) stays a pure function of its keys.
#[inline(always)]
pub fn normal_half(h: u32, more: u64, part: u64) -> f64 {
    let z = ziggurat();
    let (u, i) = half_draw(h);
    if u.abs() < z.r[i] {
        return u * z.x[i];
    }
    normal_half_outside(z, u, i, more, part)
}

/// [`normal_half`] when the half fell outside its layer's rectangle.
#[cold]
#[inline(never)]
fn normal_half_outside(z: &Ziggurat, u: f64, i: usize, more: u64, part: u64) -> f64 {
    let mut words = Words { key: mix(more), next: part << 32 };
    normal_outside(&mut words, z, u, i)
}

/// 32 random bits as the ziggurat's uniform in [-1, 1) (24 bits) and layer (8 bits).
#[inline]
fn half_draw(h: u32) -> (f64, usize) {
    (f64::from(h >> 8) * (1.0 / (1u64 << 23) as f64) - 1.0, (h & 0xff) as usize)
}

/// Layers of the ziggurat, its rightmost layer edge `R` and the area `V` of every layer
/// (Marsaglia and Tsang 2000, "The ziggurat method for generating random variables", 256
/// layers; the construction is Doornik's 2005 ZIGNOR). 256 rather than 128 layers: a draw
/// falls outside its layer's rectangle (a mispredicted branch, often an `exp`) about half as
/// often, 1.5 % of the draws rather than 2.8 %, for 4 KiB of tables.
const ZIG_LAYERS: usize = 256;
const ZIG_R: f64 = 3.654_152_885_361_009;
const ZIG_V: f64 = 4.928_673_233_99e-3;

/// The ziggurat's layer edges `x` and their ratios `r[i] = x[i + 1] / x[i]`.
struct Ziggurat {
    x: [f64; ZIG_LAYERS + 1],
    r: [f64; ZIG_LAYERS],
}

/// The tables, computed once per process (no allocation: two arrays in a static).
fn ziggurat() -> &'static Ziggurat {
    static TABLES: std::sync::OnceLock<Ziggurat> = std::sync::OnceLock::new();
    TABLES.get_or_init(|| {
        let mut x = [0.0; ZIG_LAYERS + 1];
        let mut f = (-0.5 * ZIG_R * ZIG_R).exp();
        x[0] = ZIG_V / f;
        x[1] = ZIG_R;
        for i in 2..ZIG_LAYERS {
            x[i] = (-2.0 * (ZIG_V / x[i - 1] + f).ln()).sqrt();
            f = (-0.5 * x[i] * x[i]).exp();
        }
        let mut r = [0.0; ZIG_LAYERS];
        for i in 0..ZIG_LAYERS {
            r[i] = x[i + 1] / x[i];
        }
        Ziggurat { x, r }
    })
}

/// A standard normal number from `words` by the ziggurat method (Marsaglia and Tsang 2000, in
/// Doornik's 2005 form): one word (a layer from 8 bits, a uniform from 53 others) and a
/// multiplication in 98.5 % of the draws, no transcendental function; the wedges and the tail
/// take more words and `exp`/`ln`. Exact in distribution (unlike Box-Muller on 32-bit halves,
/// it has the full tail) and several times faster than a `ln`, `sqrt` and `sin_cos` per pair.
#[inline]
pub fn normal(words: &mut Words) -> f64 {
    let z = ziggurat();
    let (u, i) = ziggurat_draw(words);
    if u.abs() < z.r[i] {
        return u * z.x[i];
    }
    normal_outside(words, z, u, i)
}

/// One word as the ziggurat's uniform in (-1, 1) and layer.
#[inline]
fn ziggurat_draw(words: &mut Words) -> (f64, usize) {
    let bits = words.bits();
    (2.0 * ((bits >> 11) as f64 * (1.0 / (1u64 << 53) as f64)) - 1.0, (bits & 0xff) as usize)
}

/// [`normal`] when its first draw fell outside its layer's rectangle: the tail, a wedge, or
/// another try.
#[cold]
fn normal_outside(words: &mut Words, z: &Ziggurat, mut u: f64, mut i: usize) -> f64 {
    loop {
        if i == 0 {
            // The tail beyond R (Marsaglia 1964).
            loop {
                let x = (1.0 - words.uniform()).ln() / ZIG_R;
                let y = (1.0 - words.uniform()).ln();
                if -2.0 * y >= x * x {
                    return if u < 0.0 { x - ZIG_R } else { ZIG_R - x };
                }
            }
        }
        let x = u * z.x[i];
        let f0 = (-0.5 * (z.x[i] * z.x[i] - x * x)).exp();
        let f1 = (-0.5 * (z.x[i + 1] * z.x[i + 1] - x * x)).exp();
        if f1 + words.uniform() * (f0 - f1) < 1.0 {
            return x;
        }
        (u, i) = ziggurat_draw(words);
        if u.abs() < z.r[i] {
            return u * z.x[i];
        }
    }
}

/// Uniform draws in [0, 1) from `seed`, one after another ([`uniform`] at consecutive
/// indices): test data for the four-wide passes' tests.
#[cfg(test)]
pub(crate) fn draws(seed: u64) -> impl FnMut() -> f64 {
    let mut index = 0;
    move || {
        index += 1;
        uniform(seed, 0, index, 0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_are_reproducible_and_differ_by_every_key() {
        let a = uniform(1, 2, 3, 4);
        assert_eq!(a, uniform(1, 2, 3, 4));
        for other in [uniform(2, 2, 3, 4), uniform(1, 3, 3, 4), uniform(1, 2, 4, 4), uniform(1, 2, 3, 5)] {
            assert_ne!(a, other);
        }
        let mean = (0..10_000).map(|i| uniform(7, 0, i, 0)).sum::<f64>() / 10_000.0;
        assert!((mean - 0.5).abs() < 0.02, "{mean}");
        assert!((0..10_000).all(|i| (0.0..1.0).contains(&uniform(7, 1, i, 0))));
    }

    #[test]
    fn keyed_draws_are_the_plain_draws() {
        for (seed, stream, index, draw) in [(1, 2, 3, 4), (0, 0, 0, 0), (u64::MAX, 7, 9, 1 << 40)] {
            assert_eq!(uniform(seed, stream, index, draw), uniform_at(key(seed, stream, index), draw));
        }
    }

    #[test]
    fn ln_factorial_is_continuous_at_the_switch_to_stirling() {
        let exact = |n: u32| (2..=n).map(|k| f64::from(k).ln()).sum::<f64>();
        for n in [30, 31, 100, 1000] {
            assert!((ln_factorial(n) - exact(n)).abs() < 1e-9 * exact(n), "n {n}");
        }
    }

    /// Binomial pmf, directly.
    fn pmf(n: u32, p: f64, k: u32) -> f64 {
        let c = (0..k).map(|j| f64::from(n - j) / f64::from(j + 1)).product::<f64>();
        c * p.powi(k as i32) * (1.0 - p).powi((n - k) as i32)
    }

    #[test]
    fn binomial_has_the_binomial_distribution() {
        // Small n: every value's frequency against its pmf.
        for (n, p) in [(5, 0.3), (12, 0.1), (40, 0.5), (3, 0.95)] {
            let draws = 200_000;
            let mut counts = vec![0u32; n as usize + 1];
            for i in 0..draws {
                counts[binomial(n, p, uniform(3, 9, i, 0)) as usize] += 1;
            }
            for (k, &c) in counts.iter().enumerate() {
                let f = f64::from(c) / draws as f64;
                assert!((f - pmf(n, p, k as u32)).abs() < 0.005, "n {n} p {p} k {k}: {f} vs {}", pmf(n, p, k as u32));
            }
        }
        // Large n: mean and variance.
        for (n, p) in [(10_000u32, 0.1), (9_999, 0.5), (5_000, 0.001)] {
            let draws = 20_000;
            let xs: Vec<f64> = (0..draws).map(|i| f64::from(binomial(n, p, uniform(4, 1, i, 0)))).collect();
            let mean = xs.iter().sum::<f64>() / draws as f64;
            let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / draws as f64;
            let (m, v) = (f64::from(n) * p, f64::from(n) * p * (1.0 - p));
            assert!((mean - m).abs() < 4.0 * (v / draws as f64).sqrt(), "n {n} p {p}: mean {mean} vs {m}");
            assert!((var - v).abs() < 0.05 * v, "n {n} p {p}: variance {var} vs {v}");
        }
        assert_eq!(binomial(0, 0.5, 0.3), 0);
        assert_eq!(binomial(10, 0.0, 0.3), 0);
        assert_eq!(binomial(10, 1.0, 0.3), 10);
        // The search order is 5, 4, 6, 3, 7, 2, 8, 1, 9, 0, 10: the top 0.1 % of u is the last, 10.
        assert_eq!(binomial(10, 0.5, 0.9995), 10);
        assert_eq!(binomial(10, 0.5, 0.9985), 0);
    }

    #[test]
    fn ordered_sample_is_a_uniform_subset_in_order() {
        let (k, n) = (30u32, 100u32);
        let mut hits = vec![0u32; n as usize];
        let samples = 20_000;
        for i in 0..samples {
            let positions: Vec<u32> = OrderedSample::new(key(5, 6, i), k, n).collect();
            assert_eq!(positions.len(), k as usize);
            assert!(positions.windows(2).all(|w| w[0] < w[1]), "{positions:?}");
            assert!(positions.iter().all(|&p| p < n));
            for p in positions {
                hits[p as usize] += 1;
            }
        }
        let expected = f64::from(k) / f64::from(n);
        for (p, &h) in hits.iter().enumerate() {
            let f = f64::from(h) / samples as f64;
            assert!((f - expected).abs() < 0.02, "position {p} chosen {f} of the time, not {expected}");
        }
        assert_eq!(OrderedSample::new(1, 5, 5).collect::<Vec<_>>(), vec![0, 1, 2, 3, 4]);
        assert_eq!(OrderedSample::new(1, 0, 5).count(), 0);
        let a: Vec<u32> = OrderedSample::new(key(1, 2, 3), 10, 1000).collect();
        let b: Vec<u32> = OrderedSample::new(key(2, 2, 3), 10, 1000).collect();
        assert_ne!(a, b, "keys differ, positions do not");
    }

    /// Mean, variance, the CDF at a few points and the tail share of `xs` are the standard
    /// normal's.
    fn assert_standard_normal(xs: &[f64], what: &str) {
        let n = xs.len() as f64;
        let points = [-3.0, -2.0, -1.0, 0.0, 0.5, 1.5, 3.0];
        // Φ at those points.
        let phi = [0.001_349_9, 0.022_750_1, 0.158_655_3, 0.5, 0.691_462_5, 0.933_192_8, 0.998_650_1];
        let mean = xs.iter().sum::<f64>() / n;
        let var = xs.iter().map(|x| x * x).sum::<f64>() / n;
        assert!(mean.abs() < 0.005, "{what}: mean {mean}");
        assert!((var - 1.0).abs() < 0.01, "{what}: variance {var}");
        for (&p, &x) in phi.iter().zip(&points) {
            let f = xs.iter().filter(|&&v| v < x).count() as f64 / n;
            assert!((f - p).abs() < 4.0 * (p * (1.0 - p) / n).sqrt() + 1e-4, "{what}: P(X < {x}) {f}, not {p}");
        }
        // P(|X| > R) = 2.58e-4 beyond the ziggurat's last layer edge: the tail is drawn, not cut.
        let tail = xs.iter().filter(|v| v.abs() > ZIG_R).count() as f64 / n;
        assert!((tail - 2.58e-4).abs() < 8e-5, "{what}: tail share {tail}");
    }

    #[test]
    fn ziggurat_normals_have_the_normal_distribution() {
        let draws = 1_000_000;
        let single: Vec<f64> = (0..draws).map(|i| Words::new(key(11, 12, i)).normal()).collect();
        assert_standard_normal(&single, "normal");
        // Each 32-bit half on its own, continuing (1.5 % of the draws) from its own key and part.
        let halves: Vec<f64> = (0..draws)
            .flat_map(|i| {
                let (w, more) = (mix(key(17, 12, i)), key(17, 13, i));
                [normal_half((w >> 32) as u32, more, 0), normal_half(w as u32, more, 1)]
            })
            .collect();
        assert_standard_normal(&halves, "halves");
        let correlation = halves.chunks(2).map(|p| p[0] * p[1]).sum::<f64>() / draws as f64;
        assert!(correlation.abs() < 0.005, "the two halves of a word correlate: {correlation}");
        // A half in the base layer outside its rectangle: drawn from the tail, by continuation.
        let tail = (0..1u32 << 16).find(|&h| {
            let (u, i) = half_draw(h);
            i == 0 && u.abs() >= ziggurat().r[0]
        });
        let h = tail.expect("some half falls into the tail");
        assert_ne!(normal_half(h, 5, 0), normal_half(h, 5, 1), "two parts share their continuation");
        // Pure functions of the key.
        assert_eq!(normal_half(h, 5, 0), normal_half(h, 5, 0));
        assert_eq!(Words::new(key(1, 2, 3)).normal(), Words::new(key(1, 2, 3)).normal());
    }
}
