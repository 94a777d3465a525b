//! Writes the built-in ground patterns (`assets/patterns/*.png`) from procedural noise.
//!
//! Run `cargo run --example make_patterns [OUT_DIR]` (default `assets/patterns`). Every pattern is
//! seamless (noise on a lattice that wraps at the tile size) and deterministic, so rerunning the
//! generator reproduces the committed files bit for bit.

use image::{Rgb, RgbImage};

/// Tile side [px]; the renderer scales each tile to a size in metres.
const SIZE: u32 = 256;

/// Deterministic hash of a lattice point (wrapped at `period`) to 0..1.
fn hash(x: i64, y: i64, period: i64, seed: u64) -> f64 {
    let (x, y) = (x.rem_euclid(period) as u64, y.rem_euclid(period) as u64);
    let mut h = seed ^ x.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ y.wrapping_mul(0xC2B2_AE3D_27D4_EB4F);
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    h = h.wrapping_mul(0xC4CE_B9FE_1A85_EC53);
    h ^= h >> 33;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Smooth value noise with `cells` lattice cells across the tile (tileable), 0..1.
fn value_noise(px: f64, py: f64, cells: i64, seed: u64) -> f64 {
    value_noise_xy(px, py, cells, cells, seed)
}

/// Value noise with `cx` cells across and `cy` cells down (tileable; unequal counts streak it).
fn value_noise_xy(px: f64, py: f64, cx: i64, cy: i64, seed: u64) -> f64 {
    let fx = px / f64::from(SIZE) * cx as f64;
    let fy = py / f64::from(SIZE) * cy as f64;
    let (x0, y0) = (fx.floor() as i64, fy.floor() as i64);
    let (tx, ty) = (fx - fx.floor(), fy - fy.floor());
    let s = |t: f64| t * t * (3.0 - 2.0 * t);
    let (sx, sy) = (s(tx), s(ty));
    let h = |x: i64, y: i64| hash(x.rem_euclid(cx), y.rem_euclid(cy), cx.max(cy), seed);
    let (a, b, c, d) = (h(x0, y0), h(x0 + 1, y0), h(x0, y0 + 1), h(x0 + 1, y0 + 1));
    let top = a + (b - a) * sx;
    let bottom = c + (d - c) * sx;
    top + (bottom - top) * sy
}

/// Fractal noise: `octaves` octaves starting at `cells` cells, 0..1.
fn fbm(px: f64, py: f64, cells: i64, octaves: u32, seed: u64) -> f64 {
    let (mut sum, mut amp, mut norm, mut c) = (0.0, 1.0, 0.0, cells);
    for o in 0..octaves {
        sum += amp * value_noise(px, py, c, seed.wrapping_add(u64::from(o) * 101));
        norm += amp;
        amp *= 0.5;
        c *= 2;
    }
    sum / norm
}

fn mix(a: [f64; 3], b: [f64; 3], t: f64) -> [f64; 3] {
    let t = t.clamp(0.0, 1.0);
    [a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, a[2] + (b[2] - a[2]) * t]
}

fn scale(c: [f64; 3], k: f64) -> [f64; 3] {
    [c[0] * k, c[1] * k, c[2] * k]
}

fn to_rgb(c: [f64; 3]) -> Rgb<u8> {
    Rgb([
        c[0].round().clamp(0.0, 255.0) as u8,
        c[1].round().clamp(0.0, 255.0) as u8,
        c[2].round().clamp(0.0, 255.0) as u8,
    ])
}

fn tile(f: impl Fn(f64, f64) -> [f64; 3]) -> RgbImage {
    RgbImage::from_fn(SIZE, SIZE, |x, y| to_rgb(f(f64::from(x) + 0.5, f64::from(y) + 0.5)))
}

/// Wrapped offset between two points on the torus of the tile [px].
fn wrapped(d: f64) -> f64 {
    let s = f64::from(SIZE);
    d - s * (d / s).round()
}

/// Forest seen from above: overlapping tree crowns, lit from the upper left, on a dark floor.
fn forest() -> RgbImage {
    let mut crowns = Vec::new();
    for i in 0..70u64 {
        let x = hash(i as i64, 1, 1 << 30, 11) * f64::from(SIZE);
        let y = hash(i as i64, 2, 1 << 30, 11) * f64::from(SIZE);
        let r = 13.0 + 15.0 * hash(i as i64, 3, 1 << 30, 11);
        let hue = hash(i as i64, 4, 1 << 30, 11);
        crowns.push((x, y, r, hue));
    }
    tile(|px, py| {
        let floor = fbm(px, py, 8, 3, 5);
        let mut c = mix([22.0, 38.0, 20.0], [40.0, 52.0, 28.0], floor);
        // Later crowns cover earlier ones: the top-most crown containing the pixel wins.
        for &(x, y, r, hue) in &crowns {
            let (dx, dy) = (wrapped(px - x), wrapped(py - y));
            let rr = (dx * dx + dy * dy).sqrt();
            let ragged = r * (0.85 + 0.3 * value_noise(px, py, 32, 7));
            if rr < ragged {
                let base = mix([38.0, 92.0, 34.0], [72.0, 110.0, 40.0], hue);
                let base = mix(base, [28.0, 70.0, 42.0], if hue > 0.8 { 0.8 } else { 0.0 });
                // Light from the upper left: brighter where the crown faces it, darker at the rim.
                let light = 1.0 + 0.35 * (-(dx + dy) / (1.414 * r)).clamp(-1.0, 1.0);
                let rim = 1.0 - 0.45 * (rr / ragged).powi(3);
                let leaves = 0.8 + 0.4 * fbm(px, py, 64, 2, 13);
                c = scale(base, light * rim * leaves);
            }
        }
        c
    })
}

/// Asphalt: dark grey with fine grain, a few lighter stones and faint large-scale wear.
fn road() -> RgbImage {
    tile(|px, py| {
        let grain = value_noise(px, py, 128, 21);
        let wear = fbm(px, py, 4, 3, 22);
        let stone = if hash(px as i64, py as i64, i64::from(SIZE), 23) > 0.985 { 18.0 } else { 0.0 };
        let g = 72.0 + 18.0 * grain + 14.0 * wear + stone;
        [g, g, g + 4.0]
    })
}

/// Mud and piled material: brown, lumpy, with darker wet patches.
fn mud() -> RgbImage {
    tile(|px, py| {
        let n = fbm(px, py, 8, 5, 31);
        let wet = (fbm(px, py, 4, 3, 32) - 0.55).max(0.0) * 3.0;
        let c = mix([96.0, 72.0, 48.0], [140.0, 108.0, 72.0], n);
        mix(c, [60.0, 44.0, 32.0], wet)
    })
}

/// Diamond plate steel: a grey base with raised diagonal lugs catching the light.
fn iron() -> RgbImage {
    tile(|px, py| {
        let brushed = value_noise_xy(px, py, 128, 8, 41);
        let mut c = scale([128.0, 132.0, 138.0], 0.9 + 0.15 * brushed);
        let cell = 32.0;
        let (u, v) = (px.rem_euclid(cell) - cell / 2.0, py.rem_euclid(cell) - cell / 2.0);
        let (a, b) = ((u + v) / 1.414, (u - v) / 1.414);
        let alt = ((px / cell).floor() + (py / cell).floor()) as i64 % 2 == 0;
        let (along, across) = if alt { (a, b) } else { (b, a) };
        if along.abs() < 10.0 && across.abs() < 2.2 {
            c = scale(c, if across < 0.0 { 1.25 } else { 0.75 });
        }
        c
    })
}

/// Parking lot: light concrete slabs with dark joints every quarter tile.
fn parking_lot() -> RgbImage {
    tile(|px, py| {
        let n = fbm(px, py, 16, 3, 51);
        let mut c = mix([150.0, 150.0, 146.0], [172.0, 171.0, 165.0], n);
        let slab = 64.0;
        // Joints in the middle of each slab period, so none sits on the tile border.
        if (px.rem_euclid(slab) - 32.0).abs() < 0.75 || (py.rem_euclid(slab) - 32.0).abs() < 0.75 {
            c = scale(c, 0.7);
        }
        c
    })
}

/// Free space: dry grass and gravel, lighter than the forest.
fn free_space() -> RgbImage {
    tile(|px, py| {
        let n = fbm(px, py, 8, 4, 61);
        let blades = value_noise_xy(px, py, 128, 32, 62);
        let c = mix([118.0, 128.0, 70.0], [160.0, 158.0, 96.0], n);
        scale(c, 0.9 + 0.2 * blades)
    })
}

fn main() -> anyhow::Result<()> {
    let out = std::env::args().nth(1).unwrap_or_else(|| "assets/patterns".into());
    std::fs::create_dir_all(&out)?;
    type Maker = fn() -> RgbImage;
    let patterns: [(&str, Maker); 6] = [
        ("forest", forest),
        ("road", road),
        ("mud", mud),
        ("iron", iron),
        ("parking_lot", parking_lot),
        ("free_space", free_space),
    ];
    for (name, make) in patterns {
        let path = std::path::Path::new(&out).join(format!("{name}.png"));
        make().save(&path)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
