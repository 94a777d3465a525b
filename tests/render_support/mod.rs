//! Shared helpers of the renderer tests: the adapter, the shared test data, snapshot comparison.

#![allow(dead_code)] // each test crate uses a different subset of these helpers

use std::path::{Path, PathBuf};

use image::{Rgba, RgbaImage};
use smlworld::render::Renderer;

/// The renderer, or a failure that says how to get an adapter: these tests never skip.
pub fn renderer() -> Renderer {
    match Renderer::new() {
        Ok(r) => r,
        Err(e) => panic!(
            "renderer tests need a graphics adapter and must not be skipped: {e}\n\
             (CI installs one in .ci/run; locally run `apt-get install -y libvulkan1 mesa-vulkan-drivers`)"
        ),
    }
}

/// The shared external test data (`../shared/data` beside the crate, else `/work/shared/data`).
pub fn data_dir() -> PathBuf {
    let beside = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    if beside.is_dir() {
        return beside;
    }
    let fallback = PathBuf::from("/work/shared/data");
    assert!(
        fallback.is_dir(),
        "test data not found at {} nor {}: these tests need the shared maps (see the README)",
        beside.display(),
        fallback.display()
    );
    fallback
}

/// How far a rendering may drift from its reference.
#[derive(Debug, Clone, Copy)]
pub struct Tolerance {
    /// A pixel counts as different when any channel differs by more than this (0..255).
    pub channel: u8,
    /// The test fails when more than this fraction of all pixels differ.
    pub fraction: f64,
}

/// The tolerance of all screenshot tests, and why. The references are made with Mesa's lavapipe,
/// which is deterministic for one Mesa/LLVM version (CI installs the same Debian package as the
/// machine that made them). Another version, or a real GPU, may round triangle edges, texture
/// filtering and blending slightly differently: that moves a channel by a few levels or flips
/// single pixels along edges. So a channel may move by 8, and 0.1 % of the pixels (about 2,000 of
/// a 1080p image, a one-pixel seam along a few road edges) may differ more. Anything meaningful
/// changes more: recolouring only the thin yellow edge lines of the highway changes 0.4 %.
pub const TOLERANCE: Tolerance = Tolerance { channel: 8, fraction: 0.001 };

fn snapshot_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/snapshots")
}

/// Compare `image` with `tests/snapshots/<name>.png`. With `UPDATE_SNAPSHOTS=1` the reference is
/// (re)written instead. On a mismatch or a missing reference the test fails and leaves
/// `<name>.new.png` (this rendering) and, when there is a reference, `<name>.diff.png` (differing
/// pixels in red over a faded reference) beside it.
pub fn check_snapshot(name: &str, image: &RgbaImage, tol: Tolerance) {
    let dir = snapshot_dir();
    let reference = dir.join(format!("{name}.png"));
    let new_path = dir.join(format!("{name}.new.png"));
    let diff_path = dir.join(format!("{name}.diff.png"));
    if std::env::var("UPDATE_SNAPSHOTS").is_ok_and(|v| v == "1") {
        image.save(&reference).expect("write the reference image");
        let _ = std::fs::remove_file(&new_path);
        let _ = std::fs::remove_file(&diff_path);
        return;
    }
    if !reference.exists() {
        image.save(&new_path).expect("write the new image");
        panic!(
            "reference {} is missing; this rendering is in {}. Look at it, then run with UPDATE_SNAPSHOTS=1 to accept it",
            reference.display(),
            new_path.display()
        );
    }
    let expected = image::open(&reference).expect("read the reference image").to_rgba8();
    if expected.dimensions() != image.dimensions() {
        image.save(&new_path).expect("write the new image");
        panic!(
            "{name}: size {:?} differs from the reference's {:?}; see {}",
            image.dimensions(),
            expected.dimensions(),
            new_path.display()
        );
    }
    let mut diff = RgbaImage::new(image.width(), image.height());
    let mut bad = 0usize;
    let mut worst = 0u8;
    for (x, y, e) in expected.enumerate_pixels() {
        let a = image.get_pixel(x, y);
        let d = (0..4).map(|c| a[c].abs_diff(e[c])).max().unwrap_or(0);
        worst = worst.max(d);
        if d > tol.channel {
            bad += 1;
            diff.put_pixel(x, y, Rgba([255, 0, 0, 255]));
        } else {
            let l = ((u16::from(e[0]) + u16::from(e[1]) + u16::from(e[2])) / 6) as u8;
            diff.put_pixel(x, y, Rgba([l, l, l, 255]));
        }
    }
    let fraction = bad as f64 / f64::from(image.width() * image.height());
    if fraction > tol.fraction {
        image.save(&new_path).expect("write the new image");
        diff.save(&diff_path).expect("write the diff image");
        panic!(
            "{name}: {bad} pixels ({:.3} %) differ by more than {} (worst {worst}); allowed {:.3} %. \
             See {} and {}; if the change is intended, rerun with UPDATE_SNAPSHOTS=1",
            100.0 * fraction,
            tol.channel,
            100.0 * tol.fraction,
            new_path.display(),
            diff_path.display()
        );
    }
    let _ = std::fs::remove_file(&new_path);
    let _ = std::fs::remove_file(&diff_path);
}

/// Whether a pixel is close to a colour (each channel within `tol`).
pub fn near(p: &Rgba<u8>, c: [u8; 3], tol: u8) -> bool {
    (0..3).all(|i| p[i].abs_diff(c[i]) <= tol)
}
