//! The built-in ground patterns: present, square, seamless when tiled, and distinct from each other.

use smlworld::render::{PATTERN_SIZE, PatternKind, PatternSet};

/// Mean absolute difference between two pixel columns (or rows) of a tile, over all channels.
fn mean_diff(img: &image::RgbaImage, a: (u32, u32), b: (u32, u32), vertical: bool) -> f64 {
    let n = PATTERN_SIZE;
    let sum: u64 = (0..n)
        .map(|k| {
            let (pa, pb) = if vertical {
                (img.get_pixel(a.0, k), img.get_pixel(b.0, k))
            } else {
                (img.get_pixel(k, a.1), img.get_pixel(k, b.1))
            };
            (0..3).map(|c| u64::from(pa[c].abs_diff(pb[c]))).sum::<u64>()
        })
        .sum();
    sum as f64 / f64::from(3 * n)
}

#[test]
fn built_in_patterns_tile_without_visible_seams() {
    let set = PatternSet::builtin();
    let last = PATTERN_SIZE - 1;
    for kind in PatternKind::ALL {
        let p = set.get(kind);
        assert_eq!(p.image.dimensions(), (PATTERN_SIZE, PATTERN_SIZE), "{kind:?}");
        assert!(p.tile_meters > 0.0);
        // Across the wrap (last column next to the first) the picture changes no more than
        // between neighbouring columns inside the tile, plus a small allowance.
        for vertical in [true, false] {
            let seam = mean_diff(&p.image, (last, last), (0, 0), vertical);
            let inside: f64 =
                (1..PATTERN_SIZE).map(|k| mean_diff(&p.image, (k - 1, k - 1), (k, k), vertical)).sum::<f64>()
                    / f64::from(last);
            assert!(
                seam <= 1.5 * inside + 2.0,
                "{kind:?}: seam difference {seam:.1} vs {inside:.1} inside ({})",
                if vertical { "left/right" } else { "top/bottom" }
            );
        }
    }
}

#[test]
fn built_in_patterns_are_distinct() {
    let set = PatternSet::builtin();
    let mean = |kind: PatternKind| {
        let img = &set.get(kind).image;
        let mut m = [0f64; 3];
        for p in img.pixels() {
            for c in 0..3 {
                m[c] += f64::from(p[c]);
            }
        }
        m.map(|v| v / f64::from(PATTERN_SIZE * PATTERN_SIZE))
    };
    let kinds = PatternKind::ALL;
    for (i, a) in kinds.iter().enumerate() {
        for b in &kinds[i + 1..] {
            let (ma, mb) = (mean(*a), mean(*b));
            let d: f64 = (0..3).map(|c| (ma[c] - mb[c]).abs()).sum();
            assert!(d > 15.0, "{a:?} and {b:?} look alike: mean colours {ma:?} vs {mb:?}");
        }
    }
    // The forest is green, the road grey.
    let (f, r) = (mean(PatternKind::Forest), mean(PatternKind::Road));
    assert!(f[1] > f[0] + 10.0 && f[1] > f[2] + 10.0, "forest {f:?}");
    assert!((r[0] - r[1]).abs() < 5.0 && (r[2] - r[1]).abs() < 8.0, "road {r:?}");
}
