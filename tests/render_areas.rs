//! Areas and lines by tag: patterns inside closed ways, no line on untagged ways.

mod render_support;

use std::path::Path;

use glam::DVec2;
use render_support::renderer;
use smlworld::map::LaneletMap;
use smlworld::render::{BirdseyeView, Environment, PatternKind, PatternSet};

/// Node (id, north, east) in units of 1e-4 degrees around 59 N 17 E (about 11 m north, 5.7 m east).
const NODES: [(i64, f64, f64); 13] = [
    (-1, 0.0, 0.0),
    (-2, -1.0, -4.0),
    (-3, -1.0, -1.0),
    (-4, 1.0, -1.0),
    (-5, 1.0, -4.0),
    (-6, -1.0, 1.0),
    (-7, -1.0, 4.0),
    (-8, 1.0, 4.0),
    (-9, 1.0, 1.0),
    (-10, -1.5, -4.0),
    (-11, -1.5, 4.0),
    (-12, 1.5, 0.5),
    (-13, 1.5, -0.5),
];

fn osm() -> String {
    let mut s = String::from("<?xml version='1.0' encoding='UTF-8'?>\n<osm version='0.6' generator='JOSM'>\n");
    for (id, n, e) in NODES {
        let tag = if id == -1 { "<tag k='origin' v='true' />" } else { "" };
        s += &format!("<node id='{id}' lat='{}' lon='{}'>{tag}</node>\n", 59.0 + n * 1e-4, 17.0 + e * 1e-4);
    }
    let way = |id: i64, nodes: &[i64], tags: &str| {
        let nds: String = nodes.iter().map(|n| format!("<nd ref='{n}' />")).collect();
        format!("<way id='{id}'>{nds}{tags}</way>\n")
    };
    s += &way(-20, &[-2, -3, -4, -5, -2], "<tag k='line_type' v='parking_lot' />");
    s += &way(-21, &[-6, -7, -8, -9, -6], "<tag k='region' v='pile_stuff' />");
    // An open way and a closed way without tags: neither draws anything.
    s += &way(-22, &[-10, -11], "");
    s += &way(-23, &[-12, -13, -1, -12], "");
    s += "</osm>\n";
    s
}

#[test]
fn closed_ways_get_their_pattern_and_untagged_ways_draw_nothing() {
    let map = LaneletMap::parse_str(&osm(), Path::new("areas.osm")).unwrap();
    let env = Environment::from_map(&map);
    assert_eq!(env.areas.len(), 2);
    assert!(env.lines.is_empty() && env.roads.is_empty());
    let view = BirdseyeView::centered_on_origin(400, 300, 8.0).unwrap();
    let mut r = renderer();
    let layer = r.environment_layer(&env, &view, &PatternSet::builtin()).unwrap();
    let img = r.read_environment(&layer).unwrap();
    let bare =
        Environment { background: PatternKind::Forest, areas: vec![], roads: vec![], fills: vec![], lines: vec![] };
    let bare_layer = r.environment_layer(&bare, &view, &PatternSet::builtin()).unwrap();
    let bare_img = r.read_environment(&bare_layer).unwrap();
    let centre = |way: i64| {
        let pts = &map.ways[&way].points;
        pts[..pts.len() - 1].iter().copied().sum::<DVec2>() / (pts.len() - 1) as f64
    };
    let at = |img: &image::RgbaImage, p: DVec2| {
        let px = view.world_to_pixel(p);
        *img.get_pixel(px.x as u32, px.y as u32)
    };
    let lot = at(&img, centre(-20));
    let mud = at(&img, centre(-21));
    // Areas come in way-id order: -21 (mud) before -20 (parking lot).
    assert_eq!(env.areas[0].pattern, PatternKind::Mud);
    assert_eq!(env.areas[1].pattern, PatternKind::ParkingLot);
    // Concrete is light grey; mud is brown (red > green > blue).
    assert!(lot[0] > 110 && lot[0].abs_diff(lot[2]) < 20, "parking lot pixel {lot:?}");
    assert!(mud[0] > mud[1] && mud[1] > mud[2], "mud pixel {mud:?}");
    // The untagged ways change no pixel: only the two areas differ from the bare forest.
    let changed_outside = img
        .enumerate_pixels()
        .filter(|(x, y, p)| {
            let w = view.pixel_to_world(DVec2::new(f64::from(*x) + 0.5, f64::from(*y) + 0.5));
            let in_area = |id: i64| {
                let pts = &map.ways[&id].points;
                let (lo, hi) = pts.iter().fold((DVec2::MAX, DVec2::MIN), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
                w.x > lo.x - 0.5 && w.y > lo.y - 0.5 && w.x < hi.x + 0.5 && w.y < hi.y + 0.5
            };
            *p != bare_img.get_pixel(*x, *y) && !in_area(-20) && !in_area(-21)
        })
        .count();
    assert_eq!(changed_outside, 0);
}
