//! OpenDRIVE maps (issue 56): the shared esmini and CARLA files load, route and render;
//! lane geometry against closed forms; links, neighbours, left-hand traffic; bad files refused.

mod common;
mod render_support;

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::path::{Path, PathBuf};
use std::process::Command;

use glam::DVec2;
use render_support::data_dir;
use smlworld::map::opendrive::geometry::Shape;
use smlworld::map::opendrive::osm_out::MERGE_DISTANCE;
use smlworld::map::opendrive::{parse_document, parse_str};
use smlworld::map::{Lanelet, LaneletMap, RouteOptions};

fn opendrive_dir() -> PathBuf {
    data_dir().join("opendrive")
}

fn shared_files() -> Vec<PathBuf> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(opendrive_dir())
        .expect("the shared OpenDRIVE folder ../shared/data/opendrive")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "xodr"))
        .collect();
    files.sort();
    assert!(files.len() >= 16, "expected the 16 shared .xodr files, found {}", files.len());
    files
}

fn load(name: &str) -> LaneletMap {
    let path = opendrive_dir().join(name);
    LaneletMap::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn tag<'a>(l: &'a Lanelet, key: &str) -> &'a str {
    l.tags.get(key).map(String::as_str).unwrap_or_else(|| panic!("lanelet {} has no tag {key}", l.id))
}

/// The lanelet of road `road`, section `section`, lane `lane`.
fn lane<'a>(map: &'a LaneletMap, road: &str, section: usize, lane: i32) -> &'a Lanelet {
    map.lanelets
        .iter()
        .find(|l| {
            tag(l, "opendrive:road") == road
                && tag(l, "opendrive:section") == section.to_string()
                && tag(l, "opendrive:lane") == lane.to_string()
        })
        .unwrap_or_else(|| panic!("no lanelet for road {road} section {section} lane {lane}"))
}

fn parse(text: &str) -> Result<LaneletMap, smlworld::map::MapError> {
    parse_str(text, Path::new("test.xodr"))
}

#[test]
fn every_shared_file_loads_and_its_farthest_connected_lanelets_route() {
    for path in shared_files() {
        let map = LaneletMap::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let drivable: Vec<usize> = (0..map.lanelets.len()).filter(|&i| map.lanelets[i].routable).collect();
        assert!(!drivable.is_empty(), "{}: no drivable lanelet", path.display());
        for l in &map.lanelets {
            for key in ["opendrive:road", "opendrive:section", "opendrive:lane", "opendrive:type", "opendrive:junction"]
            {
                tag(l, key);
            }
            assert_eq!(l.left.len(), l.right.len());
            assert!(l.left.len() >= 2);
        }
        // Breadth-first search from every drivable lanelet; keep the farthest pair (by the
        // distance between their centre lines' middles) that connects.
        let index: BTreeMap<_, _> = map.lanelets.iter().enumerate().map(|(i, l)| (l.id, i)).collect();
        let middle = |i: usize| map.lanelets[i].centre[map.lanelets[i].centre.len() / 2];
        let mut best: Option<(f64, usize, usize)> = None;
        for &a in &drivable {
            let mut seen = vec![false; map.lanelets.len()];
            let mut queue = VecDeque::from([a]);
            seen[a] = true;
            while let Some(i) = queue.pop_front() {
                let d = middle(a).distance(middle(i));
                if best.is_none_or(|(bd, ..)| d > bd) {
                    best = Some((d, a, i));
                }
                for s in &map.lanelets[i].successors {
                    let j = index[s];
                    if map.lanelets[j].routable && !seen[j] {
                        seen[j] = true;
                        queue.push_back(j);
                    }
                }
            }
        }
        let (distance, a, b) = best.unwrap();
        let (from, to) = (map.lanelets[a].id, map.lanelets[b].id);
        let route = map
            .route_lanelets(from, to, &RouteOptions::default())
            .unwrap_or_else(|e| panic!("{}: no route {from} -> {to}: {e}", path.display()));
        assert!(route.lanelets.first() == Some(&from) && route.lanelets.last() == Some(&to));
        assert!(
            route.length + 1.0 >= distance * 0.5,
            "{}: route of {} m for {distance} m",
            path.display(),
            route.length
        );
    }
}

#[test]
fn every_shared_file_renders() {
    let out_dir = std::env::temp_dir().join(format!("smlworld-opendrive-render-{}", std::process::id()));
    std::fs::create_dir_all(&out_dir).unwrap();
    for path in shared_files() {
        let out = out_dir.join(path.file_stem().unwrap()).with_extension("png");
        let run = Command::new(env!("CARGO_BIN_EXE_smlworld"))
            .args(["map", "render"])
            .arg(&path)
            .arg("--out")
            .arg(&out)
            .args(["--width", "320", "--height", "240"])
            .output()
            .expect("runs smlworld");
        assert!(run.status.success(), "{}: {}", path.display(), String::from_utf8_lossy(&run.stderr));
        let img = image::open(&out).unwrap().to_rgba8();
        // Some asphalt: grey pixels (the background is green forest).
        let grey = img
            .pixels()
            .filter(|p| p[0].abs_diff(p[1]) < 12 && p[1].abs_diff(p[2]) < 12 && p[0] > 30 && p[0] < 170)
            .count();
        assert!(grey > 50, "{}: {grey} road pixels", path.display());
    }
    std::fs::remove_dir_all(&out_dir).ok();
}

/// `map render` of a shared file, 400 x 400 px centred on `center` [m] at `ppm` px/m.
fn render_at(name: &str, center: (f64, f64), ppm: f64) -> image::RgbaImage {
    let out = std::env::temp_dir().join(format!(
        "smlworld-opendrive-marks-{}-{name}-{}-{}.png",
        std::process::id(),
        center.0,
        center.1
    ));
    let run = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["map", "render"])
        .arg(opendrive_dir().join(name))
        .arg("--out")
        .arg(&out)
        .args(["--width", "400", "--height", "400", "--pixels-per-meter", &ppm.to_string()])
        .arg(format!("--center={},{}", center.0, center.1))
        .output()
        .expect("runs smlworld");
    assert!(run.status.success(), "{name}: {}", String::from_utf8_lossy(&run.stderr));
    let img = image::open(&out).unwrap().to_rgba8();
    std::fs::remove_file(&out).ok();
    std::fs::remove_file(out.with_extension("meta")).ok();
    img
}

/// Lanes drawn by OpenDRIVE type and road marks as the file paints them (pixel rows: y [m] at
/// 200 - 20 y px for 20 px/m).
#[test]
fn render_draws_lane_types_and_the_files_road_marks() {
    let yellow = |p: &image::Rgba<u8>| p[0] > 180 && p[1] > 140 && p[2] < 110;
    let white = |p: &image::Rgba<u8>| p[0] > 200 && p[1] > 200 && p[2] > 190;
    // Town01 road 4 runs east along y = -131.41 m: a broken yellow centre line, 4 m driving
    // lanes, 0.3 m shoulders with a curb, 4 m sidewalks (y -127.1 to -123.1: row 74).
    let img = render_at("Town01.xodr", (200.0, -131.41), 20.0);
    let row: Vec<_> = (0..400).map(|x| *img.get_pixel(x, 200)).collect();
    let painted = row.iter().filter(|p| yellow(p)).count();
    assert!(painted > 100 && painted < 300, "a broken yellow centre line: {painted} of 400 px yellow");
    assert!(row.iter().all(|p| !white(p)), "no white paint on the centre line");
    let sidewalk = img.get_pixel(200, 74);
    let lane = img.get_pixel(200, 140);
    assert!(sidewalk[0] > 150 && sidewalk[0] > sidewalk[2] + 25, "sidewalk tint: {sidewalk:?}");
    assert!(lane[0].abs_diff(lane[2]) < 15 && lane[0] < 140, "asphalt: {lane:?}");
    // straight_500m: shoulders 3.07-4.75 m (row 122) brown over the asphalt, borders beyond
    // (row 45) darker than the driving lane (row 170).
    let img = render_at("straight_500m.xodr", (250.0, 0.0), 20.0);
    let (shoulder, border, driving) = (img.get_pixel(200, 122), img.get_pixel(200, 45), img.get_pixel(200, 170));
    assert!(shoulder[0] > shoulder[2] + 15, "shoulder tint {shoulder:?} (driving {driving:?})");
    assert!(
        u32::from(border[0]) + u32::from(border[1]) + 30 < u32::from(driving[0]) + u32::from(driving[1]),
        "border {border:?} darker than driving {driving:?}"
    );
    // straight_500m_roadmarks: the centre line changes along s, laneChange="both" throughout:
    // solid from 50 to 100 m (every pixel of row 200 painted), double solid from 100 to 200 m
    // (at 40 px/m two lines 0.24 m apart: rows 196 and 204 white, row 200 between them not).
    let img = render_at("straight_500m_roadmarks.xodr", (75.0, 0.0), 20.0);
    let solid = (0..400).filter(|&x| white(img.get_pixel(x, 200))).count();
    assert_eq!(solid, 400, "a solid line from 50 to 100 m");
    let img = render_at("straight_500m_roadmarks.xodr", (150.0, 0.0), 40.0);
    for x in [50, 200, 350] {
        let column: Vec<bool> = (190..211).map(|y| white(img.get_pixel(x, y))).collect();
        assert!(column[6] && column[14] && !column[10], "two solid lines at x = {x}: {column:?}");
    }
}

/// Analytic lane lengths: a lane whose centre lies at lateral offset t_c (the sum of the widths
/// inside it plus half its own, signed: + left) runs Σ_g L_g (1 - κ_g t_c) over the reference
/// line's geometries (L_g the length, κ_g the curvature: 0 for lines, 1/R for arcs): a lane
/// at t_c on an arc of radius R turning left has radius R - t_c and turns by L_g / R.
#[test]
fn driving_lane_lengths_match_the_analytic_lengths() {
    for name in ["straight_500m.xodr", "curve_r100.xodr", "circle_300m.xodr"] {
        let path = opendrive_dir().join(name);
        let text = std::fs::read_to_string(&path).unwrap();
        let doc = parse_document(&text, &path).unwrap();
        let map = load(name);
        let mut checked = 0;
        for road in &doc.roads {
            assert!(road.lane_offsets.iter().all(|o| o.c == [0.0; 4]), "{name}: the formula assumes no lane offset");
            for (si, section) in road.sections.iter().enumerate() {
                for side in [&section.left, &section.right] {
                    let mut inner = 0.0;
                    for l in side.iter() {
                        assert_eq!(l.widths.len(), 1, "{name}: the formula assumes constant widths");
                        let w = l.widths[0].c;
                        assert_eq!(&w[1..], &[0.0; 3]);
                        let t_c = f64::from(l.id.signum()) * (inner + 0.5 * w[0]);
                        inner += w[0];
                        if l.kind != "driving" {
                            continue;
                        }
                        let expected: f64 = road
                            .geometries
                            .iter()
                            .map(|g| {
                                let kappa = match g.shape {
                                    Shape::Line => 0.0,
                                    Shape::Arc { curvature } => curvature,
                                    _ => panic!("{name}: only lines and arcs expected"),
                                };
                                g.length * (1.0 - kappa * t_c)
                            })
                            .sum();
                        let got = lane(&map, &road.id, si, l.id).length;
                        assert!(
                            (got - expected).abs() <= 1e-3 * expected,
                            "{name} lane {}: {got} m, analytic {expected} m",
                            l.id
                        );
                        checked += 1;
                    }
                }
            }
        }
        assert!(checked >= 2, "{name}: {checked} driving lanes checked");
    }
}

/// Bound points on the arc of curve_r100 (from (500, 0), heading 0, curvature 0.01: centre
/// (500, 100)) lie on circles about that centre, and the middle of every chord strays at most
/// 2 cm from its circle.
#[test]
fn bounds_on_an_arc_keep_the_chord_error_under_2_cm() {
    let map = load("curve_r100.xodr");
    let centre = DVec2::new(500.0, 100.0);
    let mut chords = 0;
    for l in &map.lanelets {
        for bound in [&l.left, &l.right] {
            for w in bound.windows(2) {
                let on_arc = |p: DVec2| p.x > 500.0 + 1e-6 && p.y < 100.0 - 1e-6;
                if !(on_arc(w[0]) && on_arc(w[1])) {
                    continue;
                }
                let (r0, r1) = (w[0].distance(centre), w[1].distance(centre));
                assert!((r0 - r1).abs() < 1e-6, "bound points off a circle: {r0} vs {r1}");
                let sagitta = r0 - ((w[0] + w[1]) * 0.5).distance(centre);
                assert!(sagitta <= 0.02 + 1e-9, "chord error {sagitta} m");
                chords += 1;
            }
        }
    }
    assert!(chords > 50, "{chords} chords on the arc");
}

/// Successive drivable lanelets (across lane sections, road links and junctions) start where
/// their predecessor ends: both bounds within 1 cm. (Lanes that are never driven are left out:
/// multi_intersections links a 20 m wide filler lane of type `none` to a narrower one.)
#[test]
fn bounds_are_continuous_across_sections_and_links() {
    for path in shared_files() {
        let map = LaneletMap::load(&path).unwrap();
        let mut links = 0;
        for l in map.lanelets.iter().filter(|l| l.routable) {
            for s in &l.successors {
                let n = map.lanelet(*s).unwrap();
                if !n.routable {
                    continue;
                }
                let (end_l, end_r) = (*l.left.last().unwrap(), *l.right.last().unwrap());
                let gap = if end_l.distance(end_r) < 0.01 {
                    // A lane that merges by narrowing to no width ends on its successor's start line.
                    segment_distance(end_l, n.left[0], n.right[0])
                } else if n.left[0].distance(n.right[0]) < 0.01 {
                    // A lane that opens from no width starts on its predecessor's end line.
                    segment_distance(n.left[0], end_l, end_r)
                } else {
                    end_l.distance(n.left[0]).max(end_r.distance(n.right[0]))
                };
                assert!(
                    gap <= 0.01,
                    "{}: lanelet {} (road {} lane {}) -> {} (road {} lane {}): gap {gap} m",
                    path.display(),
                    l.id,
                    tag(l, "opendrive:road"),
                    tag(l, "opendrive:lane"),
                    n.id,
                    tag(n, "opendrive:road"),
                    tag(n, "opendrive:lane")
                );
                links += 1;
            }
        }
        let name = path.file_name().unwrap().to_string_lossy();
        if ["Town01.xodr", "Town04.xodr", "multi_lanesections.xodr", "fabriksgatan.xodr"].contains(&name.as_ref()) {
            assert!(links > 0, "{name}: no successor links");
        }
    }
}

/// Distance from `p` to the segment from `a` to `b` [m].
fn segment_distance(p: DVec2, a: DVec2, b: DVec2) -> f64 {
    let ab = b - a;
    let t = if ab.length_squared() > 0.0 { ((p - a).dot(ab) / ab.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
    p.distance(a + ab * t)
}

/// A straight road along x with one right lane whose width is a cubic and a lane offset.
const WIDTH_FILE: &str = r#"<?xml version="1.0"?>
<OpenDRIVE>
  <header revMajor="1" revMinor="6"/>
  <road id="7" length="100" junction="-1">
    <planView>
      <geometry s="0" x="10" y="20" hdg="0" length="100"><line/></geometry>
    </planView>
    <lanes>
      <laneOffset s="0" a="0.5" b="0" c="0" d="0"/>
      <laneSection s="0">
        <center><lane id="0" type="none"/></center>
        <right>
          <lane id="-1" type="driving">
            <width sOffset="0" a="3" b="0.01" c="0.0004" d="-0.000002"/>
            <speed max="50" unit="km/h"/>
          </lane>
          <lane id="-2" type="sidewalk"><width sOffset="0" a="2" b="0" c="0" d="0"/></lane>
        </right>
      </laneSection>
    </lanes>
  </road>
</OpenDRIVE>"#;

#[test]
fn width_polynomials_and_lane_offset_shape_the_bounds() {
    let map = parse(WIDTH_FILE).unwrap();
    let width = |s: f64| 3.0 + 0.01 * s + 0.0004 * s * s - 0.000002 * s * s * s;
    let l = lane(&map, "7", 0, -1);
    assert_eq!(tag(l, "opendrive:type"), "driving");
    assert_eq!(tag(l, "speed_limit"), "50");
    assert!(l.routable);
    for (left, right) in l.left.iter().zip(&l.right) {
        let s = left.x - 10.0;
        assert!((left.y - 20.5).abs() < 1e-9, "left bound follows the lane offset 0.5 m");
        assert!((right.x - left.x).abs() < 1e-9);
        assert!((left.y - right.y - width(s)).abs() < 1e-9, "width at s = {s}");
    }
    let walk = lane(&map, "7", 0, -2);
    assert!(!walk.routable, "a sidewalk is kept but not routed through");
    assert_eq!(tag(walk, "subtype"), "walkway");
    assert_eq!(walk.left, l.right, "neighbouring lanes share their border");
    assert!((map.lanelets.iter().map(|l| l.length).fold(0.0, f64::max) - 100.0).abs() < 0.1);
}

#[test]
fn left_hand_traffic_drives_the_left_lanes_along_the_reference_line() {
    for (name, along_lane, against_lane) in [("e6mini.xodr", -1, 1), ("e6mini-lht.xodr", 1, -1)] {
        let path = opendrive_dir().join(name);
        let doc = parse_document(&std::fs::read_to_string(&path).unwrap(), &path).unwrap();
        let road = &doc.roads[0];
        let map = load(name);
        let start = road.reference(0.0).0;
        let a = lane(&map, &road.id, 0, along_lane);
        let b = lane(&map, &road.id, 0, against_lane);
        assert!(a.centre[0].distance(start) < 20.0, "{name}: lane {along_lane} starts at s = 0");
        assert!(b.centre.last().unwrap().distance(start) < 20.0, "{name}: lane {against_lane} ends at s = 0");
        // Driving direction: the left bound is on the left of the centre line.
        for l in [a, b] {
            let d = l.centre[1] - l.centre[0];
            let to_left = l.left[0] - l.centre[0];
            assert!(d.perp_dot(to_left) > 0.0, "{name}: lanelet {} left bound on its left", l.id);
        }
        assert_eq!(a.tags.get("driving_side").map(String::as_str), (name == "e6mini-lht.xodr").then_some("left"));
    }
}

/// Three lanes on the right of a straight road with the marks between them.
fn marks_file(mark_12: &str, mark_23: &str) -> String {
    format!(
        r#"<OpenDRIVE><header/>
  <road id="1" length="50" junction="-1">
    <planView><geometry s="0" x="0" y="0" hdg="0" length="50"><line/></geometry></planView>
    <lanes><laneSection s="0">
      <center><lane id="0" type="none"><roadMark sOffset="0" type="solid"/></lane></center>
      <right>
        <lane id="-1" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/>{mark_12}</lane>
        <lane id="-2" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/>{mark_23}</lane>
        <lane id="-3" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>
      </right>
    </laneSection></lanes>
  </road>
</OpenDRIVE>"#
    )
}

#[test]
fn road_marks_decide_lane_changes() {
    let changes = |m12: &str, m23: &str| {
        let map = parse(&marks_file(m12, m23)).unwrap();
        let n = map.neighbours();
        let at = |lane_id: i32| n[map.lanelet_index(lane(&map, "1", 0, lane_id).id).unwrap()];
        let (l1, l2, l3) = (at(-1), at(-2), at(-3));
        assert_eq!(l1.right, Some(lane(&map, "1", 0, -2).id));
        assert_eq!(l3.left, Some(lane(&map, "1", 0, -2).id));
        // (from -1 to -2, from -2 to -1, from -2 to -3, from -3 to -2)
        (l1.change_right, l2.change_left, l2.change_right, l3.change_left)
    };
    let broken = r#"<roadMark sOffset="0" type="broken"/>"#;
    let solid = r#"<roadMark sOffset="0" type="solid"/>"#;
    assert_eq!(changes(broken, solid), (true, true, false, false));
    // `solid broken` reads from the centre outwards: solid on the inner (-1) side, broken on the
    // outer side, so only the outer lane may cross.
    let solid_broken = r#"<roadMark sOffset="0" type="solid broken"/>"#;
    let broken_solid = r#"<roadMark sOffset="0" type="broken solid"/>"#;
    assert_eq!(changes(solid_broken, broken_solid), (false, true, true, false));
    // laneChange overrides the paint.
    let solid_both = r#"<roadMark sOffset="0" type="solid" laneChange="both"/>"#;
    let broken_none = r#"<roadMark sOffset="0" type="broken" laneChange="none"/>"#;
    assert_eq!(changes(solid_both, broken_none), (true, true, false, false));
    // `increase`: towards higher lane ids only (from -2 to -1 across the first line).
    let increase = r#"<roadMark sOffset="0" type="solid" laneChange="increase"/>"#;
    let decrease = r#"<roadMark sOffset="0" type="solid" laneChange="decrease"/>"#;
    assert_eq!(changes(increase, decrease), (false, true, true, false));
}

/// Road 1 runs east and ends where road 2 also ends (`contactPoint="end"`): road 2 runs back
/// west, so lane -1 of road 1 continues on lane 1 of road 2 (driven against road 2's s). A
/// second lane section on road 1 links lanes by id.
const LINK_FILE: &str = r#"<OpenDRIVE><header/>
  <road id="1" length="40" junction="-1">
    <link><successor elementType="road" elementId="2" contactPoint="end"/></link>
    <planView><geometry s="0" x="0" y="0" hdg="0" length="40"><line/></geometry></planView>
    <lanes>
      <laneSection s="0">
        <center><lane id="0" type="none"/></center>
        <right><lane id="-1" type="driving"><link><successor id="-1"/></link><width sOffset="0" a="3" b="0" c="0" d="0"/></lane></right>
      </laneSection>
      <laneSection s="25">
        <center><lane id="0" type="none"/></center>
        <right><lane id="-1" type="driving"><link><predecessor id="-1"/><successor id="1"/></link><width sOffset="0" a="3" b="0" c="0" d="0"/></lane></right>
      </laneSection>
    </lanes>
  </road>
  <road id="2" length="30" junction="-1">
    <link><successor elementType="road" elementId="1" contactPoint="end"/></link>
    <planView><geometry s="0" x="70" y="0" hdg="3.141592653589793" length="30"><line/></geometry></planView>
    <lanes><laneSection s="0">
      <center><lane id="0" type="none"/></center>
      <left><lane id="1" type="driving"><link><successor id="-1"/></link><width sOffset="0" a="3" b="0" c="0" d="0"/></lane></left>
    </laneSection></lanes>
  </road>
</OpenDRIVE>"#;

#[test]
fn lane_links_follow_sections_and_contact_points() {
    let map = parse(LINK_FILE).unwrap();
    let (a, b, c) = (lane(&map, "1", 0, -1), lane(&map, "1", 1, -1), lane(&map, "2", 0, 1));
    assert_eq!(a.successors, vec![b.id]);
    assert_eq!(b.successors, vec![c.id]);
    assert!(c.successors.is_empty());
    // Lane 1 of road 2 runs against road 2's s: from x = 40 to x = 70.
    assert!((c.centre[0].x - 40.0).abs() < 1e-9 && (c.centre.last().unwrap().x - 70.0).abs() < 1e-9);
    let route = map.route_lanelets(a.id, c.id, &RouteOptions::default()).unwrap();
    assert!((route.length - 70.0).abs() < 0.5, "route {} m", route.length);
}

/// Town04 road 688 (a junction's connecting road): a first section 1.7 µm long holds lanes
/// -1 to -6 (only -6 driving), then the lane offset jumps 14 m and section 1 holds lanes -1 and
/// -2, lane -6 linking into -2. The short section is dropped, not run over by section 1 (which
/// moved lane -2 by 14 m): lane -2 is the road's first lanelet, where lane -6 was, and the lane
/// of road 39 that led into -6 leads into it with no gap.
#[test]
fn a_micrometre_section_whose_lanes_move_is_dropped_and_its_links_pass_through() {
    let map = load("Town04.xodr");
    let road: Vec<&Lanelet> = map.lanelets.iter().filter(|l| tag(l, "opendrive:road") == "688").collect();
    let mut lanes: Vec<(&str, &str)> =
        road.iter().map(|l| (tag(l, "opendrive:section"), tag(l, "opendrive:lane"))).collect();
    lanes.sort();
    // Section tags keep the file's numbering: section 0 is gone.
    assert_eq!(lanes, [("1", "-1"), ("1", "-2")], "road 688's lanelets");
    let l2 = lane(&map, "688", 1, -2);
    assert!(l2.routable && l2.length > 9.0);
    let before: Vec<&Lanelet> = map.lanelets.iter().filter(|l| l.successors.contains(&l2.id)).collect();
    assert!(!before.is_empty(), "a lane leads into road 688 lane -2");
    for p in before {
        let gap = p.right.last().unwrap().distance(l2.right[0]).max(p.left.last().unwrap().distance(l2.left[0]));
        assert!(
            gap < 0.001,
            "road {} lane {} -> 688 -2: gap {gap} m",
            tag(p, "opendrive:road"),
            tag(p, "opendrive:lane")
        );
    }
}

/// Town04's highway loop crosses itself on a bridge: roads 39 and 47, both outside any
/// junction, cross in the plane. OpenDRIVE joins roads that meet at grade in a junction, so
/// the crossing is on two levels: no junction (and no yielding) there, and the pair is listed
/// as levels apart (vehicles on them neither touch nor lead each other: before, platoon cars
/// stopped for the cars below and five collisions were counted on the bridge).
#[test]
fn roads_crossing_outside_junctions_lie_on_different_levels() {
    let map = load("Town04.xodr");
    let junctions = map.junctions();
    let on = |road: &str| -> Vec<usize> {
        (0..map.lanelets.len())
            .filter(|&i| tag(&map.lanelets[i], "opendrive:road") == road && map.lanelets[i].routable)
            .collect()
    };
    let (upper, lower) = (on("39"), on("47"));
    let apart =
        upper.iter().flat_map(|&a| lower.iter().map(move |&b| (a, b))).filter(|&(a, b)| junctions.levels_apart(a, b));
    assert!(apart.count() >= 4, "the driving lanes of roads 39 and 47 cross on two levels");
    for i in upper.iter().chain(&lower) {
        assert!(
            junctions.of_lanelet(map.lanelets[*i].id).is_none(),
            "lanelet {} is in no junction",
            map.lanelets[*i].id
        );
    }
    // Lanelets of one junction still conflict: fabriksgatan has its junction and nothing apart.
    let town = load("fabriksgatan.xodr");
    let j = town.junctions();
    assert!(!j.list.is_empty() && !j.any_levels_apart());
}

#[test]
fn carla_geo_reference_sets_the_origin() {
    let map = load("Town04.xodr");
    assert_eq!((map.projector.origin_lat, map.projector.origin_lon), (49.0, 8.0));
    let n = map.nodes.values().next().unwrap();
    let back = map.projector.forward(n.lat, n.lon);
    assert!(back.distance(n.position) < 1e-3);
}

#[test]
fn junction_connections_link_incoming_and_connecting_roads() {
    let path = opendrive_dir().join("fabriksgatan.xodr");
    let doc = parse_document(&std::fs::read_to_string(&path).unwrap(), &path).unwrap();
    let map = load("fabriksgatan.xodr");
    let mut checked = 0;
    for j in &doc.junctions {
        for c in &j.connections {
            for &(from, to) in &c.lane_links {
                let (a, b) = (lane_end(&map, &c.incoming, from, &doc), lane_end(&map, &c.connecting, to, &doc));
                let (Some(a), Some(b)) = (a, b) else { continue };
                if !(a.routable && b.routable) {
                    continue;
                }
                assert!(
                    a.successors.contains(&b.id) || b.successors.contains(&a.id),
                    "junction {}: lane {from} of road {} and lane {to} of road {} not linked",
                    j.id,
                    c.incoming,
                    c.connecting
                );
                assert_eq!(tag(b, "opendrive:junction"), j.id);
                checked += 1;
            }
        }
    }
    assert!(checked > 4, "{checked} lane links checked");
}

/// A lanelet of `lane` on `road` in any section (first match).
fn lane_end<'a>(
    map: &'a LaneletMap,
    road: &str,
    lane_id: i32,
    _doc: &smlworld::map::opendrive::road::Document,
) -> Option<&'a Lanelet> {
    map.lanelets.iter().find(|l| tag(l, "opendrive:road") == road && tag(l, "opendrive:lane") == lane_id.to_string())
}

fn refused(text: &str, expect: &[&str]) {
    let err = parse(text).expect_err("the file must be refused").to_string();
    for e in expect {
        assert!(err.contains(e), "error {err:?} lacks {e:?}");
    }
}

#[test]
fn malformed_files_are_refused_with_line_and_id() {
    let road = |body: &str, extra: &str| {
        format!(
            "<OpenDRIVE>\n<header/>\n<road id=\"9\" length=\"10\" junction=\"-1\">\n{extra}{body}\n<lanes><laneSection s=\"0\"><center><lane id=\"0\"/></center></laneSection></lanes>\n</road>\n</OpenDRIVE>"
        )
    };
    let plan = |g: &str| {
        format!("<planView>\n<geometry s=\"0\" x=\"0\" y=\"0\" hdg=\"0\" length=\"10\">{g}</geometry>\n</planView>")
    };
    refused(&road("", ""), &["test.xodr:3", "road 9", "planView"]);
    refused(&road(&plan("<clothoid/>"), ""), &["test.xodr:5", "road 9", "unknown geometry <clothoid>"]);
    refused(
        &road(
            "<planView>\n<geometry s=\"0\" x=\"0\" y=\"0\" hdg=\"0\" length=\"-4\"><line/></geometry>\n</planView>",
            "",
        ),
        &["test.xodr:5", "road 9", "negative length"],
    );
    refused(
        &road(&plan("<line/>"), "").replace("length=\"10\" junction", "length=\"-10\" junction"),
        &["test.xodr:3", "road 9", "negative length"],
    );
    refused(
        &road(
            &plan("<line/>"),
            "<link><successor elementType=\"road\" elementId=\"77\" contactPoint=\"start\"/></link>\n",
        ),
        &["test.xodr:4", "road 9", "road 77"],
    );
    refused(&road(&plan("<arc curvature=\"x\"/>"), ""), &["test.xodr:5", "road 9", "curvature"]);
    refused("<osm></osm>", &["OpenDRIVE"]);
    // A huge length in a small file is refused, not sampled into billions of points.
    refused(
        &road(&plan("<line/>"), "").replace("length=\"10\" junction", "length=\"1e12\" junction"),
        &["test.xodr:3", "road 9", "beyond"],
    );
}

#[test]
fn truncated_and_mangled_files_never_panic() {
    let text = std::fs::read_to_string(opendrive_dir().join("fabriksgatan.xodr")).unwrap();
    let n = text.len();
    for k in 1..60 {
        let cut = (n * k / 60..n).find(|&i| text.is_char_boundary(i)).unwrap_or(n);
        let _ = parse(&text[..cut]);
        let mangled = text.replacen("length=", "length=\"-1\" x=", k);
        let _ = parse(&mangled);
    }
}

#[test]
fn unsupported_elements_warn_once_per_name_with_a_line() {
    let map = load("fabriksgatan.xodr");
    let names: Vec<&str> = map.warnings.iter().filter_map(|w| w.message.split('<').nth(1)?.split('>').next()).collect();
    let mut unique = names.clone();
    unique.sort();
    unique.dedup();
    assert_eq!(names.len(), unique.len(), "one warning per element name: {names:?}");
    assert!(
        names.iter().any(|n| n.ends_with("/signals") || n.ends_with("/objects") || n.ends_with("/elevationProfile")),
        "{names:?}"
    );
    assert!(map.warnings.iter().all(|w| w.at.contains("fabriksgatan.xodr:")));
}

fn smlworld(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld")).args(args).output().expect("runs smlworld");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn map_route_takes_opendrive_lanes() {
    let file = opendrive_dir().join("multi_lanesections.xodr");
    let file = file.to_str().unwrap();
    let map = load("multi_lanesections.xodr");
    // From the first section's lane -1 to the last section's lane -1, through every section.
    let last = map
        .lanelets
        .iter()
        .filter(|l| tag(l, "opendrive:road") == "0")
        .map(|l| tag(l, "opendrive:section").parse::<usize>().unwrap())
        .max()
        .unwrap();
    let (a, b) = (lane(&map, "0", 0, -1), lane(&map, "0", last, -1));
    let (ok, out, err) =
        smlworld(&["map", "route", file, "--from-lane", "0:-1", "--to-lane", &format!("0:{last}:-1"), "--json"]);
    assert!(ok, "{err}");
    let json: serde_json::Value = serde_json::from_str(&out).unwrap();
    let lanelets: Vec<i64> = json["lanelets"].as_array().unwrap().iter().map(|v| v.as_i64().unwrap()).collect();
    assert_eq!(lanelets.first(), Some(&a.id.0));
    assert_eq!(lanelets.last(), Some(&b.id.0));
    assert_eq!(lanelets.len(), last + 1, "one lanelet per lane section: {lanelets:?}");
    let (ok, _, err) = smlworld(&["map", "route", file, "--from-lane", "0:x", "--to-lane", "0:-1"]);
    assert!(!ok && err.contains("ROAD:LANE"), "{err}");
    let (ok, _, err) = smlworld(&["map", "route", file, "--from-lane", "99:-1", "--to-lane", "0:-1"]);
    assert!(!ok && err.contains("start:99:0:-1"), "{err}");
}

#[test]
fn scenario_routes_name_opendrive_lanes() {
    let dir = std::env::temp_dir().join(format!("smlworld-opendrive-scenario-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let map = opendrive_dir().join("multi_lanesections.xodr");
    let scenario = dir.join("lanes.toml");
    std::fs::write(
        &scenario,
        format!(
            r#"seed = 1
duration = 8.0
map = {map:?}

[[vehicles]]
id = -1
class = "car"
model = {{ type = "acceleration" }}
route = {{ from = {{ road = "0", lane = -1 }}, to = {{ road = 0, section = 2, lane = -1 }} }}
start = {{ offset = 5.0 }}
speed = 10.0
controller = {{ type = "cruise_control", speed = 10.0 }}
"#
        ),
    )
    .unwrap();
    let out = dir.join("out");
    let (ok, _, err) = smlworld(&["run", scenario.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(ok, "{err}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["metrics"]["collision_count"], 0);
    std::fs::remove_dir_all(&dir).ok();
}

/// scenarios/town04_platoon.toml: a CACC platoon of 8 on Town04's highway loop with background
/// traffic on random trips over the highway, 10 simulated minutes without a collision, every
/// follower kept a gap. The background cars (ids from -1000 down) really drive random trips:
/// many trips of many lengths end, the cars are seen on lanes of both directions, and never
/// off the highway (a lanelet of 65 mph, or a junction's link between two).
#[test]
fn town04_platoon_runs_ten_minutes_without_collision() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let out = std::env::temp_dir().join(format!("smlworld-town04-platoon-{}", std::process::id()));
    let (ok, _, err) = smlworld(&[
        "run",
        root.join("scenarios/town04_platoon.toml").to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let trajectories = std::fs::read_to_string(out.join("trajectories.csv")).unwrap();
    let trips = std::fs::read_to_string(out.join("trips.csv")).unwrap();
    std::fs::remove_dir_all(&out).ok();
    let m = &summary["metrics"];
    assert_eq!(m["collision_count"], 0, "collisions: {}", m["collisions"]);
    let followers = m["followers"].as_array().unwrap();
    // Followers -2 ... -8 behind leader -1 (on the loop the leader is measured too, behind -8).
    let platoon: Vec<&serde_json::Value> =
        followers.iter().filter(|f| (-8..=-2).contains(&f["id"].as_i64().unwrap())).collect();
    assert_eq!(platoon.len(), 7, "7 platoon followers measured");
    for f in platoon {
        assert!(f["min_gap"].as_f64().unwrap() > 1.0, "follower {} came within {} m", f["id"], f["min_gap"]);
    }
    // Trips of the background cars that ended (at their destination, where the next began):
    // many, and of many lengths (one loop route would give one length).
    let mut lengths = std::collections::BTreeSet::new();
    for line in trips.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f[0].parse::<i64>().unwrap() <= -1000 && !f[2].is_empty() {
            lengths.insert(f[3].to_string());
        }
    }
    assert!(lengths.len() >= 20, "background trips that ended, by length: {lengths:?}");
    // Where they drove: lanes of both signs (both carriageways), on the highway only.
    let map = load("Town04.xodr");
    let highway = |l: &Lanelet| l.speed_limit().is_some_and(|v| v >= 25.0) || tag(l, "opendrive:junction") != "-1";
    let (mut lanes, mut roads, mut off) = (std::collections::BTreeSet::new(), std::collections::BTreeSet::new(), 0);
    for line in trajectories.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let (Ok(id), Ok(lanelet)) = (f[1].parse::<i64>(), f[7].parse::<i64>()) else { continue };
        if id > -1000 {
            continue;
        }
        let l = map.lanelet(smlworld::map::LaneletId(lanelet)).expect("a lanelet of the map");
        if !highway(l) {
            off += 1;
        }
        lanes.insert(tag(l, "opendrive:lane").parse::<i32>().unwrap());
        roads.insert(tag(l, "opendrive:road").to_string());
    }
    assert_eq!(off, 0, "background rows off the highway");
    assert!(lanes.iter().any(|&k| k > 0) && lanes.iter().any(|&k| k < 0), "lanes driven: {lanes:?}");
    assert!(lanes.len() >= 4 && roads.len() >= 20, "lanes {lanes:?}, roads {roads:?}");
}

/// highway_example_with_merge_and_split: lane 3 of road 1 ends (the on-ramp merges), so from
/// the ramp (road 8) to road 0 there is no route in lane, and the route with lane changes
/// changes lanes exactly where the neighbours' shared border lets it.
#[test]
fn the_merge_needs_a_lane_change_and_the_road_marks_allow_one() {
    use smlworld::map::{LaneChangeOptions, MapError, Place};
    let map = load("highway_example_with_merge_and_split.xodr");
    let from = Place::Tag("start:8:0:1".into());
    let to = Place::Tag("end:0:0:1".into());
    assert!(matches!(map.route_places(&from, &to, &RouteOptions::default()), Err(MapError::NoRoute { .. })));
    let route = map.route_with_lane_changes(&from, &to, &LaneChangeOptions::default()).unwrap();
    assert!(!route.lane_changes.is_empty());
    let n = map.neighbours();
    for c in &route.lane_changes {
        let nb = n[map.lanelet_index(c.from).unwrap()];
        assert!((nb.left == Some(c.to) && nb.change_left) || (nb.right == Some(c.to) && nb.change_right));
        let (a, b) = (map.lanelet(c.from).unwrap(), map.lanelet(c.to).unwrap());
        assert_eq!(tag(a, "opendrive:road"), tag(b, "opendrive:road"), "a change stays on its road");
    }
}

/// A lanelet's place in the OpenDRIVE file: (road, section, lane), as its tags give it.
fn lane_key(l: &Lanelet) -> (String, String, String) {
    (
        tag(l, "opendrive:road").to_string(),
        tag(l, "opendrive:section").to_string(),
        tag(l, "opendrive:lane").to_string(),
    )
}

/// Every lanelet's key, length and successors' keys.
/// A lanelet's OpenDRIVE road, section and lane.
type LaneKey = (String, String, String);

fn by_lane_key(map: &LaneletMap) -> BTreeMap<LaneKey, (f64, Vec<LaneKey>)> {
    let key_of: BTreeMap<_, _> = map.lanelets.iter().map(|l| (l.id, lane_key(l))).collect();
    map.lanelets
        .iter()
        .map(|l| {
            let mut next: Vec<_> = l.successors.iter().map(|id| key_of[id].clone()).collect();
            next.sort();
            (lane_key(l), (l.length, next))
        })
        .collect()
}

#[test]
fn map_convert_writes_osm_that_loads_back_with_the_same_lanelets() {
    let dir = std::env::temp_dir().join(format!("smlworld-opendrive-convert-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // Every shared file: the same lanelets and the same successors come back. Town01 lost 4
    // lanelets of lane sections under a centimetre (the OSM loader skips zero-length bounds) and
    // files without geoReference (origin 0, 0) came back off the globe before the reader merged
    // short sections and the projection kept one false northing across the equator.
    let mut totals = (0, 0);
    for path in shared_files() {
        let name = path.file_name().unwrap().to_str().unwrap();
        let out = dir.join(name.replace(".xodr", ".osm"));
        let input = opendrive_dir().join(name);
        let (ok, stdout, stderr) =
            smlworld(&["map", "convert", input.to_str().unwrap(), "--out", out.to_str().unwrap()]);
        assert!(ok, "{name}: {stdout}{stderr}");
        // Links whose bounds lie apart are reported, not joined (none in these files).
        let unjoined: usize = stderr
            .lines()
            .find(|l| l.contains("not joined"))
            .and_then(|l| l.split("WARN ").nth(1)?.split_whitespace().next()?.parse().ok())
            .unwrap_or(0);
        let text = std::fs::read_to_string(&out).unwrap();
        assert!(!smlworld::map::opendrive::is_opendrive(&text));
        let xodr = load(name);
        let osm = LaneletMap::load(&out).unwrap_or_else(|e| panic!("{name}: the OSM map loads: {e}"));
        // The origin: one node tagged origin=true, at the file's origin.
        assert_eq!(osm.origin_node, Some(-1), "{name}");
        assert!((osm.projector.origin_lat - xodr.projector.origin_lat).abs() < 1e-9, "{name}");
        assert!((osm.projector.origin_lon - xodr.projector.origin_lon).abs() < 1e-9, "{name}");
        // Lane sections under 2 cm are merged into a neighbour (Town04: 22 lanelets of four first
        // sections 2 to 23 µm long whose lanes move sideways were built, then skipped by the OSM
        // loader for bounds under 1 cm): no lanelet of no length is left, and every lanelet comes
        // back, once.
        let len = |p: &[DVec2]| p.windows(2).map(|w| w[0].distance(w[1])).sum::<f64>();
        let tiny: Vec<LaneKey> =
            xodr.lanelets.iter().filter(|l| len(&l.left).min(len(&l.right)) < 0.01).map(lane_key).collect();
        assert!(tiny.is_empty(), "{name}: lanelets of no length {tiny:?}");
        assert_eq!(osm.lanelets.len(), xodr.lanelets.len(), "{name}: lanelet count");
        let (a, b) = (by_lane_key(&xodr), by_lane_key(&osm));
        assert_eq!(a.len(), xodr.lanelets.len(), "{name}: one lanelet per (road, section, lane)");
        assert_eq!(b.len(), osm.lanelets.len(), "{name}: one OSM lanelet per (road, section, lane)");
        // An OSM lanelet map links lanelets by shared nodes: a link whose bounds lie apart in the
        // file (soderleden's lane -3 ending into lane -2: 3.5 m; 2 in multi_intersections)
        // cannot come back, and is reported. Every other link does.
        let ends = |key: &LaneKey| {
            let l = xodr.lanelets.iter().find(|l| lane_key(l) == *key).unwrap();
            (l.left[0], l.right[0], l.left[l.left.len() - 1], l.right[l.right.len() - 1])
        };
        let (mut links, mut lost) = (0, 0);
        for (key, (len, next)) in &a {
            let (len2, next2) = b.get(key).unwrap_or_else(|| panic!("{name}: lanelet {key:?} is missing"));
            assert!((len - len2).abs() <= 0.01, "{name} {key:?}: length {len} -> {len2}");
            assert!(next2.iter().all(|n| next.contains(n)), "{name} {key:?}: successors {next:?} -> {next2:?}");
            for n in next.iter().filter(|n| !next2.contains(n)) {
                let ((_, _, l, r), (l2, r2, _, _)) = (ends(key), ends(n));
                let gap = l.distance(l2).max(r.distance(r2));
                assert!(gap > MERGE_DISTANCE, "{name} {key:?} -> {n:?}: lost, with bounds {gap} m apart");
                lost += 1;
            }
            links += next.len();
        }
        assert_eq!(lost, unjoined, "{name}: successors lost are exactly the links reported");
        let expected = match name {
            "multi_intersections.xodr" => 2,
            "soderleden.xodr" => 1,
            _ => 0,
        };
        assert_eq!(unjoined, expected, "{name}: links not joined");
        totals.0 += xodr.lanelets.len();
        totals.1 += links - lost;
        // Positions survive the lat/lon round trip, routability and neighbours' lines too.
        for l in &xodr.lanelets {
            let l2 = osm.lanelets.iter().find(|m| lane_key(m) == lane_key(l)).unwrap();
            assert_eq!(l.routable, l2.routable, "{name} {:?}", lane_key(l));
            let (p, q) = (l.centre[l.centre.len() / 2], l2.centre[l2.centre.len() / 2]);
            assert!(p.distance(q) < 0.01, "{name} {:?}: centre {p} -> {q}", lane_key(l));
        }
        // A lane named in the file is still a place a route can start.
        let start = osm.tag_index.keys().filter(|k| k.starts_with("start:")).count();
        assert!(start >= xodr.lanelets.len(), "{name}: every lanelet's start tag survives");
    }
    // Town01 302 lanelets and 266 links, Town04 1326 and 1116, ...: all of them.
    assert!(totals.0 > 1800 && totals.1 > 1500, "lanelets and links compared: {totals:?}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn map_convert_refuses_to_overwrite_its_input_and_non_opendrive_files() {
    let dir = std::env::temp_dir().join(format!("smlworld-opendrive-convert-refuse-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let copy = dir.join("straight.xodr");
    std::fs::copy(opendrive_dir().join("straight_500m.xodr"), &copy).unwrap();
    let before = std::fs::read(&copy).unwrap();
    let c = copy.to_str().unwrap();
    let (ok, _, stderr) = smlworld(&["map", "convert", c, "--out", c]);
    assert!(!ok && stderr.contains("refusing to overwrite"), "{stderr}");
    // The same file by another path.
    let other = dir.join(".").join("straight.xodr");
    let (ok, _, stderr) = smlworld(&["map", "convert", c, "--out", other.to_str().unwrap()]);
    assert!(!ok && stderr.contains("refusing to overwrite"), "{stderr}");
    assert_eq!(std::fs::read(&copy).unwrap(), before, "the input is untouched");
    // An OSM map is not converted, and the target is not created.
    let osm = Path::new(env!("CARGO_MANIFEST_DIR")).join("maps/lane_drop.osm");
    let target = dir.join("out.osm");
    let (ok, _, stderr) = smlworld(&["map", "convert", osm.to_str().unwrap(), "--out", target.to_str().unwrap()]);
    assert!(!ok && stderr.contains("not an OpenDRIVE file"), "{stderr}");
    assert!(!target.exists());
    // A broken file: an error naming it, no panic, no output.
    let bad = dir.join("bad.xodr");
    std::fs::write(&bad, "<OpenDRIVE><header/><road id='1' length='10'><lanes/></road></OpenDRIVE>").unwrap();
    let (ok, _, stderr) = smlworld(&["map", "convert", bad.to_str().unwrap(), "--out", target.to_str().unwrap()]);
    assert!(!ok && stderr.contains("bad.xodr") && !stderr.contains("panicked"), "{stderr}");
    assert!(!target.exists());
    std::fs::remove_dir_all(&dir).ok();
}

/// scenarios/opendrive_merge.toml: the on-ramp's lane ends on road 1, so every ramp vehicle
/// (ids from -2000 down) makes a mandatory change into the main road and still arrives at the
/// end of road 0; no collision. (Before scenario routes could use lane changes the ramp route
/// was "no route"; before traffic let a vehicle mid-change leave at its route's end, vehicles
/// stood past the end of road 0 and 21 collisions followed.)
#[test]
fn opendrive_merge_scenario_merges_the_ramp_without_collision() {
    let scenario = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/opendrive_merge.toml");
    let out = std::env::temp_dir().join(format!("smlworld-opendrive-merge-{}", std::process::id()));
    let (ok, _, err) = smlworld(&["run", scenario.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(ok, "{err}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let m = &summary["metrics"];
    assert_eq!(m["collision_count"], 0, "{}", m["collisions"]);
    let inserted = m["traffic"]["inserted"].as_u64().unwrap();
    assert!(inserted >= 40, "{inserted} vehicles");
    assert_eq!(m["trips"]["arrived"].as_u64(), Some(inserted), "every vehicle arrived: {}", m["trips"]);
    assert_eq!(m["traffic"]["removed"].as_u64(), Some(inserted), "none left standing: {}", m["traffic"]);
    // Each ramp vehicle changed lanes (mandatory, not aborted) and its last position is at the
    // end of road 0 lane 1.
    let map = load("highway_example_with_merge_and_split.xodr");
    let goal = map.nodes[&map.tag_index["end:0:0:1"][0]].position;
    let mut last: BTreeMap<i64, DVec2> = BTreeMap::new();
    let text = std::fs::read_to_string(out.join("trajectories.csv")).unwrap();
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let id: i64 = f[1].parse().unwrap();
        last.insert(id, DVec2::new(f[2].parse().unwrap(), f[3].parse().unwrap()));
    }
    let ramp: Vec<i64> = last.keys().copied().filter(|&id| id <= -2000).collect();
    assert!(ramp.len() >= 10, "ramp vehicles: {ramp:?}");
    let changes = m["lane_changes"].as_array().unwrap();
    for id in &ramp {
        let merged =
            changes.iter().any(|c| c["id"].as_i64() == Some(*id) && c["kind"] == "mandatory" && c["aborted"] == false);
        assert!(merged, "ramp vehicle {id} made no mandatory change");
        assert!(last[id].distance(goal) < 10.0, "ramp vehicle {id} ended at {} (goal {goal})", last[id]);
    }
    std::fs::remove_dir_all(&out).ok();
}

/// multi_intersections' lights, counted by hand from the file (23 `<controller>`s, each also
/// named by one of the five `<junction>`s, and 127 `<signal>`s): its 34 signals of type 1000001
/// (the three-light signal) stand at s = 0 of the 16 roads that enter the five junctions, facing
/// (orientation `-`) the left lanes, which drive into the junction there. Their controllers:
/// junction 146: 1 (roads 202 and 209) and 2 (196, 197); 148: 6 (217), 7 (222), 10 (227); 150:
/// 12 (235, 242), 13 (229, 230); 152: 17 (256), 18 (261), 21 (266); 154: 23 (270), 24 (275),
/// 27 (280). The other 11 controllers hold its 34 pedestrian lights (type 1000002, valid for
/// lane 0 only). So five signalised junctions with 2, 3, 2, 3 and 3 signal groups, and the lanes
/// of one controller's roads get green together.
#[test]
fn multi_intersections_lights_are_its_signals_grouped_by_controller() {
    use smlworld::map::junctions::{JunctionControl, map_program};
    let map = load("multi_intersections.xodr");
    let junctions = map.junctions();
    let mut found: BTreeMap<String, BTreeSet<BTreeSet<String>>> = BTreeMap::new();
    for j in junctions.list.iter().filter(|j| j.control == JunctionControl::TrafficLight) {
        let (program, _) = map_program(&map, j).unwrap_or_else(|| panic!("junction {} runs the file's program", j.id));
        let of = |l: smlworld::map::LaneletId, key: &str| tag(map.lanelet(l).unwrap(), key).to_string();
        let odr: BTreeSet<String> = j.links.iter().map(|l| of(l.lanelet, "opendrive:junction")).collect();
        assert_eq!(odr.len(), 1, "junction {}: links of one OpenDRIVE junction: {odr:?}", j.id);
        // A signal group: the links green (G, or the yielding g) in one phase, by the roads they
        // come from. Every link is lit in some phase, and none in every phase.
        let green = |state: &str, k: usize| matches!(state.as_bytes()[k], b'G' | b'g');
        for k in 0..j.links.len() {
            let lit = program.iter().filter(|p| green(&p.state, k)).count();
            assert!(lit > 0 && lit < program.len(), "junction {} link {k}: green in {lit} phases", j.id);
        }
        let groups: BTreeSet<BTreeSet<String>> = program
            .iter()
            .map(|p| {
                (0..j.links.len())
                    .filter(|&k| green(&p.state, k))
                    .map(|k| of(j.links[k].from.expect("a link is entered from a road"), "opendrive:road"))
                    .collect::<BTreeSet<String>>()
            })
            .filter(|g| !g.is_empty())
            .collect();
        found.insert(odr.into_iter().next().unwrap(), groups);
    }
    let expect = |groups: &[&[&str]]| -> BTreeSet<BTreeSet<String>> {
        groups.iter().map(|g| g.iter().map(|r| r.to_string()).collect()).collect()
    };
    let expected: BTreeMap<String, BTreeSet<BTreeSet<String>>> = [
        ("146", expect(&[&["202", "209"], &["196", "197"]])),
        ("148", expect(&[&["217"], &["222"], &["227"]])),
        ("150", expect(&[&["235", "242"], &["229", "230"]])),
        ("152", expect(&[&["256"], &["261"], &["266"]])),
        ("154", expect(&[&["270"], &["275"], &["280"]])),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    assert_eq!(found, expected);
    let counts: Vec<usize> = found.values().map(BTreeSet::len).collect();
    assert_eq!(counts, [2, 3, 2, 3, 3]);
    // `map info --json` says so.
    let file = opendrive_dir().join("multi_intersections.xodr");
    let (ok, stdout, stderr) = smlworld(&["map", "info", file.to_str().unwrap(), "--json"]);
    assert!(ok, "{stderr}");
    let info: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    let lit = info["junctions"].as_array().unwrap().iter().filter(|j| j["control"] == "traffic_light").count();
    assert_eq!(lit, 5, "{}", info["junctions"]);
    // Signal types that mean nothing here warn once per type, with the first line: pedestrian
    // lights (1000002, first on line 151) and crosswalks (1000003, line 148), stop lines (294,
    // line 161), speed limit signs (274) and road arrows (-1); lights and the priority (306) and
    // yield (205) signs do not.
    let warned = |kind: &str| {
        map.warnings.iter().filter(|w| w.message.contains(&format!("signal type \"{kind}\""))).collect::<Vec<_>>()
    };
    for (kind, line) in
        [("1000002", Some(151)), ("1000003", Some(148)), ("294", Some(161)), ("274", None), ("-1", None)]
    {
        let w = warned(kind);
        assert_eq!(w.len(), 1, "type {kind}: {w:?}");
        if let Some(line) = line {
            assert!(w[0].at.ends_with(&format!("multi_intersections.xodr:{line}")), "{}", w[0]);
        }
    }
    for kind in ["1000001", "306", "205"] {
        assert!(warned(kind).is_empty(), "type {kind} is read: {:?}", warned(kind));
    }
}

/// Random traffic through multi_intersections' five signalised junctions for 10 minutes
/// (`scenarios/opendrive_lights.toml`): no collision, and no vehicle enters a junction on red
/// (seen from the vehicles' lanelets and the lights, as for the generated junction).
#[test]
fn opendrive_lights_scenario_keeps_red_and_collides_nowhere() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let scenario = smlworld::app::Scenario::load(&root.join("scenarios/opendrive_lights.toml")).expect("loads");
    let mut sim = scenario.builder().expect("builds").build();
    let seen = common::red_entries(&mut sim, 600.0);
    assert!(seen.red_steps > 0, "the lights showed red");
    assert!(seen.entries >= 150, "only {} junction entries in 10 minutes", seen.entries);
    assert_eq!(seen.on_red, 0, "{} of {} entries on red: {:?}", seen.on_red, seen.entries, seen.first_reds);
    let metrics = sim.world().resource::<smlworld::app::running::metrics::Metrics>();
    assert!(metrics.collisions.is_empty(), "collisions: {:?}", metrics.collisions);
}

/// The same town with `on_arrival = "new_trip"`: a trip that ends at a stop line goes on along
/// its next trip, and that trip is drawn while the vehicle can still stop for the light (on its
/// destination lanelet), not when it stands at the line at speed. Before, 8 of 277 entries were
/// on red: a vehicle drove its route's last metres unaware of the light and the next trip began
/// inside the junction's reach.
#[test]
fn new_trips_at_a_stop_line_are_drawn_in_time_to_stop_for_red() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let path = root.join("scenarios/opendrive_lights.toml");
    let text = std::fs::read_to_string(&path)
        .expect("reads")
        .replace("lane_change = false", "lane_change = false\non_arrival = \"new_trip\"\nuntil = 200.0");
    let scenario = smlworld::app::Scenario::parse_str(&text, &path).expect("parses");
    let mut sim = scenario.builder().expect("builds").build();
    let seen = common::red_entries(&mut sim, 600.0);
    let finished = &sim.world().resource::<smlworld::app::running::trips::TripLog>().finished;
    assert!(finished.len() >= 100, "only {} trips ended", finished.len());
    // Each trip ended where it was to (its route's length driven), after it began.
    for r in finished {
        let travel = r.travel_time().expect("arrived");
        assert!(travel > 0.0 && r.trip.route_length > 0.0, "{r:?}");
    }
    assert!(seen.entries >= 150, "only {} junction entries in 10 minutes", seen.entries);
    assert_eq!(seen.on_red, 0, "{} of {} entries on red: {:?}", seen.on_red, seen.entries, seen.first_reds);
    let metrics = sim.world().resource::<smlworld::app::running::metrics::Metrics>();
    assert!(metrics.collisions.is_empty(), "collisions: {:?}", metrics.collisions);
}

/// circle_300m is one road that is its own predecessor and successor (an arc of curvature
/// 0.0209439510 1/m, radius R = 47.746 m, over its 300 m): each driving lane is one lanelet
/// that follows itself, so `map loop` drives round it, on the `.xodr` and on its OSM conversion
/// alike. Lane -1 (3.07 m wide, outside the reference line on this left-turning circle) has its
/// centre at R + 1.535 m: the loop is 2π (R + 1.535) = 309.64 m long. Before, the reader dropped
/// the link of a lanelet to itself and `map loop` found no route.
#[test]
fn circle_300m_is_a_ring_that_map_loop_drives_round() {
    let map = load("circle_300m.xodr");
    let ring = lane(&map, "1", 0, -1);
    assert_eq!(ring.successors, vec![ring.id], "lane -1 follows itself");
    let radius = 1.0 / 20.9439510e-3 + 3.07 / 2.0;
    let expected = std::f64::consts::TAU * radius;
    let dir = std::env::temp_dir().join(format!("smlworld-opendrive-ring-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let osm = dir.join("circle.osm");
    let xodr = opendrive_dir().join("circle_300m.xodr");
    let (ok, out, err) = smlworld(&["map", "convert", xodr.to_str().unwrap(), "--out", osm.to_str().unwrap()]);
    assert!(ok, "{out}{err}");
    for file in [&xodr, &osm] {
        let (ok, out, err) = smlworld(&["map", "loop", file.to_str().unwrap(), "--tag", "start:1:0:-1", "--json"]);
        assert!(ok, "{}: {err}", file.display());
        let path: serde_json::Value = serde_json::from_str(&out).unwrap();
        let length = path["length_m"].as_f64().unwrap();
        assert!(
            (length - expected).abs() / expected < 1e-3,
            "{}: loop of {length} m, not {expected} m",
            file.display()
        );
        assert_eq!(path["lanelets"].as_array().map(Vec::len), Some(1), "{}: {}", file.display(), path["lanelets"]);
    }
    let back = LaneletMap::load(&osm).unwrap();
    let ring = back.lanelets.iter().find(|l| tag(l, "opendrive:lane") == "-1").unwrap();
    assert_eq!(ring.successors, vec![ring.id], "the OSM lanelet follows itself too");
    std::fs::remove_dir_all(&dir).ok();
}

/// Town04's road 841 (in junction 804) starts with lane sections of 0.1, 0.5 and 0.2 m: its
/// lanelets there lie within 0.8 m of road 40's end, and lane -2 of road 40 "crossed" its own
/// continuation 0.6 m before its end, a junction of one lane (a platoon leader braked there for
/// the car ahead of it, and its follower ran into it: town04_platoon with seed 2, t = 435 s).
/// A lanelet and those that follow it through less than 2 m of lanelets meet at a joint: no
/// conflict, in any shared file.
#[test]
fn a_lane_never_conflicts_with_its_own_continuation() {
    for path in shared_files() {
        let name = path.file_name().unwrap().to_str().unwrap();
        let map = load(name);
        let index = |id| map.lanelet_index(id).unwrap();
        // Lanelets reached from `from` through successors whose lengths before them sum under 2 m.
        let follows = |from: usize, to: usize| {
            let mut todo = vec![(from, 0.0)];
            let mut seen = BTreeSet::new();
            while let Some((k, before)) = todo.pop() {
                for next in &map.lanelets[k].successors {
                    let j = index(*next);
                    if j == to {
                        return true;
                    }
                    let through = before + map.lanelets[j].length;
                    if seen.insert(j) && through < 2.0 {
                        todo.push((j, through));
                    }
                }
            }
            false
        };
        for j in &map.junctions().list {
            for c in &j.conflicts {
                let (a, b) = (index(c.a), index(c.b));
                assert!(!follows(a, b) && !follows(b, a), "{name}: junction {} pairs {} and {}", j.id, c.a, c.b);
            }
        }
        if name == "Town04.xodr" {
            let lane_40 = lane(&map, "40", 0, -2);
            assert!(map.junctions().of_lanelet(lane_40.id).is_none(), "road 40 lane -2 is in no junction");
        }
    }
}
