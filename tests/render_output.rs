//! Output files: frames as PNG/BMP, animated GIFs, numbered frame paths, bad paths.

mod render_support;

use glam::DVec2;
use render_support::renderer;
use smlworld::render::{
    BirdseyeView, Environment, PatternKind, PatternSet, VehicleSprite, frame_path, write_gif, write_image,
};

fn temp_dir(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("smlworld-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn a_moving_vehicle_becomes_an_animated_gif_with_one_frame_per_image() {
    let mut r = renderer();
    let view = BirdseyeView::centered_on_origin(160, 120, 4.0).unwrap();
    let env =
        Environment { background: PatternKind::FreeSpace, areas: vec![], roads: vec![], fills: vec![], lines: vec![] };
    let layer = r.environment_layer(&env, &view, &PatternSet::builtin()).unwrap();
    let frames: Vec<_> = (0..4)
        .map(|k| {
            let v = VehicleSprite::new(-1, DVec2::new(-10.0 + 5.0 * f64::from(k), 0.0), 0.0, 4.5, 2.0, "Car");
            r.render_frame(&layer, &[v]).unwrap()
        })
        .collect();
    // Consecutive frames differ: the vehicle moved.
    assert!(frames.windows(2).all(|w| w[0] != w[1]));
    let dir = temp_dir("gif");
    let gif = dir.join("run.gif");
    write_gif(&gif, &frames, 10.0).unwrap();
    let decoder =
        image::codecs::gif::GifDecoder::new(std::io::BufReader::new(std::fs::File::open(&gif).unwrap())).unwrap();
    let decoded = image::AnimationDecoder::into_frames(decoder).collect_frames().unwrap();
    assert_eq!(decoded.len(), 4);
    // 10 Hz = 100 ms per frame.
    assert_eq!(decoded[0].delay().numer_denom_ms(), (100, 1));
    assert_eq!(decoded[0].buffer().dimensions(), (160, 120));
    assert!(write_gif(&gif, &frames, 0.0).is_err());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn frames_are_numbered_in_order_and_bad_extensions_are_errors() {
    let dir = std::path::Path::new("out");
    assert_eq!(frame_path(dir, 7), dir.join("frame_000007.png"));
    assert!(frame_path(dir, 9) < frame_path(dir, 10));
    let img = image::RgbaImage::new(2, 2);
    let err = write_image(std::path::Path::new("/tmp/x.jpeg"), &img).unwrap_err();
    assert!(err.to_string().contains(".png or .bmp"), "{err}");
    // A folder that cannot be made (its parent is a plain file) is an error naming the path, for
    // every user (root included, who may create `/nonexistent-dir`).
    let blocker = std::env::temp_dir().join(format!("smlworld-render-blocker-{}", std::process::id()));
    std::fs::write(&blocker, b"a file, not a folder").unwrap();
    let bad = blocker.join("x.png");
    let err = write_image(&bad, &img).unwrap_err();
    assert!(err.to_string().contains(&bad.display().to_string()), "{err}");
    std::fs::remove_file(&blocker).unwrap();
}
