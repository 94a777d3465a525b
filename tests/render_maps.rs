//! Environment images of real maps: screenshots against references and direct geometry checks.

mod render_support;

use std::f64::consts::PI;

use glam::DVec2;
use image::RgbaImage;
use render_support::{TOLERANCE, check_snapshot, data_dir, renderer};
use smlworld::map::LaneletMap;
use smlworld::render::{BirdseyeView, Environment, PatternSet, RadarCone, VehicleSprite};

fn load(rel: &str) -> LaneletMap {
    let path = data_dir().join(rel);
    LaneletMap::load(&path).unwrap_or_else(|e| panic!("loading {}: {e}", path.display()))
}

fn environment(map: &LaneletMap, view: &BirdseyeView) -> RgbaImage {
    let mut r = renderer();
    let layer = r.environment_layer(&Environment::from_map(map), view, &PatternSet::builtin()).unwrap();
    r.read_environment(&layer).unwrap()
}

/// Asphalt is grey: channels within a few levels of each other (the road tile is (g, g, g+4)).
fn is_road(p: &image::Rgba<u8>) -> bool {
    let (mn, mx) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
    mx - mn <= 10 && mx > 30 && mx < 160
}

/// The forest is green: green clearly above red and blue.
fn is_forest(p: &image::Rgba<u8>) -> bool {
    p[1] > p[0].saturating_add(8) && p[1] > p[2].saturating_add(8)
}

fn pixel(view: &BirdseyeView, img: &RgbaImage, p: DVec2) -> Option<image::Rgba<u8>> {
    let px = view.world_to_pixel(p);
    (px.x >= 0.0 && px.y >= 0.0 && px.x < f64::from(img.width()) && px.y < f64::from(img.height()))
        .then(|| *img.get_pixel(px.x as u32, px.y as u32))
}

/// The point at `fraction` of a polyline's length.
fn along(line: &[DVec2], fraction: f64) -> DVec2 {
    let total: f64 = line.windows(2).map(|w| w[0].distance(w[1])).sum();
    let mut left = fraction * total;
    for w in line.windows(2) {
        let d = w[0].distance(w[1]);
        if left <= d && d > 0.0 {
            return w[0].lerp(w[1], left / d);
        }
        left -= d;
    }
    line[line.len() - 1]
}

/// Distance from `p` to the segment `a`-`b` [m].
fn segment_distance(p: DVec2, a: DVec2, b: DVec2) -> f64 {
    let ab = b - a;
    let t = if ab.length_squared() > 0.0 { ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
    p.distance(a + ab * t)
}

#[test]
fn highway_environment_at_the_original_view_matches_the_reference() {
    let map = load("sml2015/HighwaySML.xml");
    let view = BirdseyeView::centered_on_origin(1920, 1080, 5.0).unwrap();
    let img = environment(&map, &view);
    check_snapshot("highway_sml_1920x1080_5ppm", &img, TOLERANCE);
}

#[test]
fn shipped_intersection_fitted_to_the_map_matches_the_reference() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("maps/intersection4.osm");
    let map = LaneletMap::load(&path).unwrap_or_else(|e| panic!("loading {}: {e}", path.display()));
    let view = BirdseyeView::fit_map(960, 540, &map).unwrap();
    let img = environment(&map, &view);
    check_snapshot("intersection4_fit_960x540", &img, TOLERANCE);
}

#[test]
fn projector_view_of_the_highway_matches_the_reference() {
    let map = load("sml2015/HighwaySML.xml");
    // A 60 x 40 m floor rectangle over the loop's east curve on a 1024 x 768 projector: the
    // pixels are not square on the floor (aspect 1.125).
    let view = BirdseyeView::projector(1024, 768, 30.0, 90.0, -5.0, 35.0).unwrap();
    assert!((view.aspect - 1.125).abs() < 1e-12);
    let mut r = renderer();
    let layer = r.environment_layer(&Environment::from_map(&map), &view, &PatternSet::builtin()).unwrap();
    // A truck on the centre line nearest to (70, 15) m, heading along it.
    let target = DVec2::new(70.0, 15.0);
    let (p, yaw) = map
        .lanelets
        .iter()
        .flat_map(|l| l.centre.windows(2).map(|w| (w[0], (w[1] - w[0]).to_angle())))
        .min_by(|a, b| a.0.distance(target).total_cmp(&b.0.distance(target)))
        .unwrap();
    let mut truck = VehicleSprite::new(4, p, yaw, 8.0, 2.5, "Truck");
    truck.real = true;
    truck.overlays.radar = Some(RadarCone { range: 15.0, angle: PI / 4.0 });
    let img = r.render_frame(&layer, &[truck]).unwrap();
    // The rectangle's corners are the image's corners.
    assert_eq!(view.world_to_pixel(DVec2::new(30.0, 35.0)), DVec2::ZERO);
    check_snapshot("projector_highway_1024x768", &img, TOLERANCE);
}

#[test]
fn lanelet_centres_are_road_and_far_off_road_is_forest() {
    let shipped = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("maps/intersection4.osm");
    let paths = [data_dir().join("sml2015/HighwaySML.xml"), data_dir().join("sml2015/Intersection3Way.xml"), shipped];
    for path in &paths {
        let rel = path.display();
        let map = LaneletMap::load(path).unwrap_or_else(|e| panic!("loading {rel}: {e}"));
        let view = BirdseyeView::fit_map(960, 540, &map).unwrap();
        let img = environment(&map, &view);
        let mut checked = 0;
        for l in &map.lanelets {
            // Midway between the bounds, away from the painted lines on them and from the ends.
            for f in [0.25, 0.5, 0.75] {
                let Some(p) = pixel(&view, &img, along(&l.centre, f)) else { continue };
                assert!(is_road(&p), "{rel}: lanelet {} centre at {f} of its length is {p:?}, not road", l.id);
                checked += 1;
            }
        }
        assert!(checked >= 3 * map.lanelets.len() / 2, "{rel}: only {checked} centre points inside the image");
        // Pixels more than 6 m from every lanelet bound are background.
        let segments: Vec<(DVec2, DVec2)> = map
            .lanelets
            .iter()
            .flat_map(|l| l.left.windows(2).chain(l.right.windows(2)).map(|w| (w[0], w[1])))
            .collect();
        let mut off_road = 0;
        for y in (5..540).step_by(40) {
            for x in (5..960).step_by(40) {
                let w = view.pixel_to_world(DVec2::new(f64::from(x) + 0.5, f64::from(y) + 0.5));
                if segments.iter().all(|&(a, b)| segment_distance(w, a, b) > 6.0) {
                    let p = img.get_pixel(x, y);
                    // Tree crowns and the floor between them are both green-dominant or dark.
                    assert!(is_forest(p) || p[0].max(p[1]).max(p[2]) < 60, "{rel}: off-road pixel ({x}, {y}) is {p:?}");
                    off_road += 1;
                }
            }
        }
        assert!(off_road > 50, "{rel}: only {off_road} off-road samples");
    }
}

#[test]
fn highway_image_is_not_blank_and_shows_both_line_colours() {
    let map = load("sml2015/HighwaySML.xml");
    let view = BirdseyeView::centered_on_origin(1920, 1080, 5.0).unwrap();
    let img = environment(&map, &view);
    let mut colours = std::collections::BTreeSet::new();
    let (mut yellow, mut white) = (0, 0);
    for p in img.pixels() {
        colours.insert([p[0], p[1], p[2]]);
        yellow += usize::from(p[0] > 180 && p[1] > 140 && p[2] < 90);
        white += usize::from(p[0] > 200 && p[1] > 200 && p[2] > 200);
    }
    assert!(colours.len() > 1000, "only {} colours", colours.len());
    // 8 exterior ways around a ~350 m loop at >= 1.5 px width: thousands of yellow pixels.
    assert!(yellow > 1000, "{yellow} yellow pixels");
    assert!(white > 500, "{white} white pixels");
}

#[test]
fn a_user_pattern_directory_replaces_the_road() {
    let map = load("sml2015/HighwaySML.xml");
    let view = BirdseyeView::centered_on_origin(480, 270, 2.0).unwrap();
    let dir = std::env::temp_dir().join(format!("smlworld-patterns-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    RgbaImage::from_pixel(64, 64, image::Rgba([255, 0, 255, 255])).save(dir.join("road.png")).unwrap();
    let patterns = PatternSet::from_dir(&dir).unwrap();
    let mut r = renderer();
    let layer = r.environment_layer(&Environment::from_map(&map), &view, &patterns).unwrap();
    let img = r.read_environment(&layer).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    let l = &map.lanelets[0];
    let p = pixel(&view, &img, l.centre[l.centre.len() / 2]).unwrap();
    // Magenta, darkened at most by the anti-tiling brightness modulation of a flat tile (none).
    assert_eq!([p[0], p[1], p[2]], [255, 0, 255], "road pixel {p:?}");
    assert!(PatternSet::from_dir(std::path::Path::new("/nonexistent/patterns")).is_err());
}

#[test]
fn cli_writes_png_bmp_and_the_original_meta_file() {
    let dir = std::env::temp_dir().join(format!("smlworld-render-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let map = data_dir().join("sml2015/HighwaySML.xml");
    for ext in ["png", "bmp"] {
        let out = dir.join(format!("h.{ext}"));
        let status = std::process::Command::new(env!("CARGO_BIN_EXE_smlworld"))
            .args(["map", "render"])
            .arg(&map)
            .arg("--out")
            .arg(&out)
            .args(["--pixels-per-meter", "5"])
            .status()
            .unwrap();
        assert!(status.success(), "smlworld map render --out {} failed", out.display());
        let img = image::open(&out).unwrap();
        assert_eq!((img.width(), img.height()), (1920, 1080));
        // The same bytes as the 2015 tool's own HighwaySML.meta.
        let meta = std::fs::read(dir.join("h.meta")).unwrap();
        let original = std::fs::read(data_dir().join("sml2015/HighwaySML.meta")).unwrap();
        assert_eq!(String::from_utf8_lossy(&meta), String::from_utf8_lossy(&original));
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
