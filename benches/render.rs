//! Frame time of the bird's-eye renderer at 1920x1080 with 1,000 and 10,000 vehicles.
//!
//! The environment layer (HighwaySML at 5 px/m) is drawn once outside the timed loop; each
//! iteration builds the instance lists, draws all vehicles with their ids (every tenth with a
//! radar cone) and reads the frame back into a reused `RgbaImage`, as a frame writer would.
//! Run: `cargo bench --bench render`.

use std::path::{Path, PathBuf};

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use glam::DVec2;
use smlworld::map::LaneletMap;
use smlworld::render::{BirdseyeView, Environment, PatternSet, RadarCone, Renderer, VehicleSprite};

fn data_dir() -> PathBuf {
    let beside = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data");
    if beside.is_dir() { beside } else { PathBuf::from("/work/shared/data") }
}

/// `n` vehicles on a jittered grid over the view, deterministic headings and classes.
fn sprites(n: usize, view: &BirdseyeView) -> Vec<VehicleSprite> {
    let (min, max) = view.world_rect();
    let cols = (n as f64 * (max.x - min.x) / (max.y - min.y)).sqrt().ceil() as usize;
    let rows = n.div_ceil(cols);
    let classes = ["Truck", "Car", "Bus"];
    (0..n)
        .map(|i| {
            let (c, r) = (i % cols, i / cols);
            let p = DVec2::new(
                min.x + (max.x - min.x) * (c as f64 + 0.5) / cols as f64,
                min.y + (max.y - min.y) * (r as f64 + 0.5) / rows as f64,
            );
            let id = if i % 2 == 0 { i as i32 } else { -(i as i32) };
            let mut s = VehicleSprite::new(id, p, i as f64 * 0.7, 4.5, 1.9, classes[i % 3]);
            if i % 10 == 0 {
                s.overlays.radar = Some(RadarCone { range: 10.0, angle: 0.8 });
            }
            s
        })
        .collect()
}

fn bench_frames(c: &mut Criterion) {
    let map_path = data_dir().join("sml2015/HighwaySML.xml");
    let map = LaneletMap::load(&map_path).unwrap_or_else(|e| panic!("{}: {e}", map_path.display()));
    let mut renderer = Renderer::new().unwrap_or_else(|e| panic!("{e}"));
    eprintln!("adapter: {}", renderer.adapter_name());
    let view = BirdseyeView::centered_on_origin(1920, 1080, 5.0).expect("valid view");
    let layer = renderer
        .environment_layer(&Environment::from_map(&map), &view, &PatternSet::builtin())
        .expect("environment layer");
    let mut image = image::RgbaImage::new(1, 1);
    let mut group = c.benchmark_group("render_frame_1920x1080");
    group.sample_size(20);
    for n in [1_000usize, 10_000] {
        let sprites = sprites(n, &view);
        group.bench_with_input(BenchmarkId::from_parameter(n), &sprites, |b, s| {
            b.iter(|| renderer.render_frame_into(&layer, s, &mut image).expect("frame"))
        });
    }
    group.finish();
}

criterion_group!(benches, bench_frames);
criterion_main!(benches);
