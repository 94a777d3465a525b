//! Counter-based randomness: every draw is a pure function of (seed, stream, index, draw), a
//! SplitMix64 hash of the four (Steele, Lea, Flood 2014, "Fast splittable pseudorandom number
//! generators"), so no global generator exists and nothing depends on thread count or system
//! order; a draw allocates nothing.

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
}
