//! Lanelet2's mapping_example drawn as it is tagged: line types (`solid`, `dashed`, double lines,
//! curbstones, stop lines; `virtual` not drawn), zebra crossings and tinted lanelet subtypes.
//! Expected counts come from a plain scan of the OSM text, not from the loader.

mod render_support;

use render_support::{data_dir, renderer};
use smlworld::map::LaneletMap;
use smlworld::render::{BirdseyeView, Environment, LineStyle, PatternSet};

fn path() -> std::path::PathBuf {
    data_dir().join("lanelet2/mapping_example.osm")
}

/// `(type, subtype)` of every element named `element` (`way`, `relation`) in the OSM text.
fn scan(element: &str) -> Vec<(String, Option<String>)> {
    let text = std::fs::read_to_string(path()).unwrap();
    let tag = |body: &str, key: &str| {
        let k = format!("k='{key}' v='");
        body.find(&k).map(|i| body[i + k.len()..].split('\'').next().unwrap_or("").to_string())
    };
    text.split(&format!("<{element} "))
        .skip(1)
        .map(|chunk| {
            let body = &chunk[..chunk.find(&format!("</{element}>")).unwrap_or(chunk.len())];
            (tag(body, "type").unwrap_or_default(), tag(body, "subtype"))
        })
        .collect()
}

fn ways_of(kind: &str) -> usize {
    scan("way").iter().filter(|(t, _)| t == kind).count()
}

#[test]
fn line_types_become_lines_as_tagged() {
    let map = LaneletMap::load(&path()).unwrap();
    let env = Environment::from_map(&map);
    let count = |style: LineStyle| env.lines.iter().filter(|l| l.style == style).count();

    assert!(ways_of("stop_line") > 0);
    assert_eq!(count(LineStyle::STOP_LINE), ways_of("stop_line"));
    assert_eq!(count(LineStyle::KERB), ways_of("curbstone") + ways_of("road_border"));

    // Painted lines: one per solid or dashed way, two per double line; dashed halves counted.
    let ways = scan("way");
    let painted: Vec<&Option<String>> =
        ways.iter().filter(|(t, _)| t == "line_thin" || t == "line_thick").map(|(_, s)| s).collect();
    let is = |s: &Option<String>, v: &str| s.as_deref() == Some(v);
    let doubles =
        painted.iter().filter(|s| ["solid_solid", "solid_dashed", "dashed_solid"].iter().any(|v| is(s, v))).count();
    assert!(doubles > 0, "mapping_example has solid_dashed and dashed_solid lines");
    let dashed_expected =
        painted.iter().filter(|s| ["dashed", "solid_dashed", "dashed_solid"].iter().any(|v| is(s, v))).count();
    let lane_styles = [LineStyle::THIN_SOLID, LineStyle::THIN_DASHED]
        .into_iter()
        .flat_map(|s| [s, s.widened(2.0)])
        .collect::<Vec<_>>();
    let lane_lines: Vec<_> = env.lines.iter().filter(|l| lane_styles.contains(&l.style)).collect();
    assert_eq!(lane_lines.len(), painted.len() + doubles);
    assert_eq!(lane_lines.iter().filter(|l| l.style.dash == Some(6.0)).count(), dashed_expected);

    // A double line is two parallel lines, one line width to each side of the way.
    let double = map.ways.values().find(|w| w.tags.get("subtype").is_some_and(|s| s == "solid_dashed")).unwrap();
    let a = double.points[0];
    let mut offsets: Vec<f64> = lane_lines
        .iter()
        .filter(|l| l.points.len() == double.points.len() && l.points[0].distance(a) < 0.5)
        .map(|l| l.points[0].distance(a))
        .collect();
    offsets.sort_by(f64::total_cmp);
    assert_eq!(offsets.len(), 2, "{offsets:?}");
    let thick = double.tags.get("type").is_some_and(|t| t == "line_thick");
    let width = LineStyle::THIN_SOLID.width * if thick { 2.0 } else { 1.0 };
    assert!(offsets.iter().all(|d| (d - width).abs() < 1e-6), "{offsets:?}");

    // Virtual line strings draw nothing.
    let virtuals: Vec<_> = map.ways.values().filter(|w| w.tags.get("type").is_some_and(|t| t == "virtual")).collect();
    assert_eq!(virtuals.len(), ways_of("virtual"));
    assert!(!virtuals.is_empty());
    for w in virtuals {
        assert!(!env.lines.iter().any(|l| l.points == w.points), "virtual way {} is drawn", w.id);
    }

    // Crosswalk lanelets are striped (white dashes as wide as the crossing); walkways, bicycle
    // lanes and parking lanelets are tinted.
    let lanelets = scan("relation");
    let subtype = |v: &str| lanelets.iter().filter(|(t, s)| t == "lanelet" && is(s, v)).count();
    let stripes = env.lines.iter().filter(|l| l.style.dash == Some(1.0) && l.style.width > 1.0).count();
    assert!(subtype("crosswalk") > 0);
    assert_eq!(stripes, subtype("crosswalk"));
    assert_eq!(env.fills.len(), subtype("walkway") + subtype("bicycle_lane") + subtype("parking"));
}

#[test]
fn stop_lines_and_crossings_show_in_the_image() {
    let map = LaneletMap::load(&path()).unwrap();
    let env = Environment::from_map(&map);
    let mut r = renderer();
    let bright = |c: image::Rgba<u8>| c.0.iter().take(3).all(|&v| v > 200);

    // Road lanelets are asphalt: grey, channels within a few levels (the road tile is (g, g, g+4)).
    let road = map.lanelets.iter().filter(|l| l.tags.get("subtype").is_some_and(|s| s == "road")).nth(10).unwrap();
    let view = BirdseyeView::new(200, 200, 20.0, road.centre[road.centre.len() / 2]).unwrap();
    let layer = r.environment_layer(&env, &view, &PatternSet::builtin()).unwrap();
    let c = r.read_environment(&layer).unwrap().get_pixel(100, 100).0;
    let (lo, hi) = (c[0].min(c[1]).min(c[2]), c[0].max(c[1]).max(c[2]));
    assert!(hi - lo <= 10 && hi > 30 && hi < 160, "road lanelet {} pixel {c:?}", road.id);

    // The middle of the first stop line, at 20 px/m: white paint.
    let stop = map.ways.values().find(|w| w.tags.get("type").is_some_and(|t| t == "stop_line")).unwrap();
    let mid = stop.points[0].lerp(stop.points[stop.points.len() - 1], 0.5);
    let view = BirdseyeView::new(200, 200, 20.0, mid).unwrap();
    let layer = r.environment_layer(&env, &view, &PatternSet::builtin()).unwrap();
    let img = r.read_environment(&layer).unwrap();
    assert!(bright(*img.get_pixel(100, 100)), "stop line pixel {:?}", img.get_pixel(100, 100));

    // Along a crossing's centre line: white stripes and asphalt between them.
    let crossing = map.lanelets.iter().find(|l| l.tags.get("subtype").is_some_and(|s| s == "crosswalk")).unwrap();
    let c = crossing.centre[crossing.centre.len() / 2];
    let view = BirdseyeView::new(200, 200, 20.0, c).unwrap();
    let layer = r.environment_layer(&env, &view, &PatternSet::builtin()).unwrap();
    let img = r.read_environment(&layer).unwrap();
    let (a, b) = (crossing.centre[0], crossing.centre[crossing.centre.len() - 1]);
    let dir = (b - a).normalize_or_zero();
    let samples: Vec<bool> = (-30..=30)
        .filter_map(|k| {
            let p = view.world_to_pixel(c + dir * (f64::from(k) * 0.05));
            (p.x >= 0.0 && p.y >= 0.0 && p.x < 200.0 && p.y < 200.0)
                .then(|| bright(*img.get_pixel(p.x as u32, p.y as u32)))
        })
        .collect();
    let white = samples.iter().filter(|w| **w).count();
    assert!(
        white >= 10 && samples.len() - white >= 10,
        "{white} white of {} samples across the stripes",
        samples.len()
    );
}
