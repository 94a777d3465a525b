//! Generated maps: shipped files match the generator, parameters are checked, and the maps
//! round-trip through the loader with analytic counts, lengths and routes.

use std::f64::consts::{FRAC_PI_2, TAU};
use std::path::{Path, PathBuf};

use glam::DVec2;

use smlworld::map::generate::{
    self, GenerateError, GridParams, IntersectionParams, LaneDropParams, RingParams, grid_city, intersection,
    lane_drop, ring_highway,
};
use smlworld::map::generate::{Arm, grid_junction_tag, intersection_end_tag, intersection_start_tag, ring_lane_tag};
use smlworld::map::osm::parse_osm;
use smlworld::map::{LaneletMap, RouteOptions};

fn repo_file(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(name)
}

/// Compares two generated XML texts line by line; lat/lon may differ by `tol_deg` (the last
/// printed digit can flip between platforms whose libm rounds sin/cos differently).
fn assert_same_xml(expected: &str, actual: &str, what: &str) {
    const TOL_DEG: f64 = 2e-10;
    let (e_lines, a_lines): (Vec<&str>, Vec<&str>) = (expected.lines().collect(), actual.lines().collect());
    assert_eq!(e_lines.len(), a_lines.len(), "{what}: line count differs");
    for (i, (e, a)) in e_lines.iter().zip(&a_lines).enumerate() {
        if e == a {
            continue;
        }
        // Attribute values sit between single quotes: odd-numbered pieces of a split on '\''.
        let (ep, ap): (Vec<&str>, Vec<&str>) = (e.split('\'').collect(), a.split('\'').collect());
        let same = ep.len() == ap.len()
            && ep.iter().zip(&ap).enumerate().all(|(k, (x, y))| {
                x == y
                    || (k % 2 == 1
                        && matches!((x.parse::<f64>(), y.parse::<f64>()), (Ok(u), Ok(v)) if (u - v).abs() <= TOL_DEG))
            });
        assert!(same, "{what}: line {} differs:\n expected: {e}\n   actual: {a}", i + 1);
    }
}

#[test]
fn shipped_maps_are_what_the_generator_writes_with_default_parameters() {
    let cases: [(&str, String); 10] = [
        ("maps/highway_ring.osm", ring_highway(&RingParams::default()).expect("defaults are valid")),
        (
            "maps/two_lane_ring.osm",
            ring_highway(&RingParams { lanes: 2, radius: 150.0, ..RingParams::default() }).expect("valid"),
        ),
        (
            "maps/intersection3.osm",
            intersection(&IntersectionParams { arms: 3, ..IntersectionParams::default() }).expect("valid"),
        ),
        (
            "maps/intersection4.osm",
            intersection(&IntersectionParams { arms: 4, ..IntersectionParams::default() }).expect("valid"),
        ),
        ("maps/grid_3x3.osm", grid_city(&GridParams::default()).expect("defaults are valid")),
        (
            "maps/grid_5x5_lights.osm",
            grid_city(&GridParams {
                rows: 5,
                cols: 5,
                block: 100.0,
                lanes: 2,
                control: generate::JunctionMarks { traffic_lights: true, major: None },
                ..GridParams::default()
            })
            .expect("valid"),
        ),
        (
            "maps/intersection4_major.osm",
            intersection(&IntersectionParams {
                arm_length: 100.0,
                control: generate::JunctionMarks { traffic_lights: false, major: Some(generate::Axis::EastWest) },
                ..IntersectionParams::default()
            })
            .expect("valid"),
        ),
        (
            "maps/gcdc_intersection.osm",
            intersection(&IntersectionParams { arms: 3, arm_length: 150.0, ..IntersectionParams::default() })
                .expect("valid"),
        ),
        (
            "maps/emergency_ring.osm",
            ring_highway(&RingParams { radius: 250.0, ..RingParams::default() }).expect("valid"),
        ),
        (
            "maps/gcdc_merge.osm",
            generate::lane_drop(&generate::LaneDropParams {
                length: 2000.0,
                drop_at: 1600.0,
                ..generate::LaneDropParams::default()
            })
            .expect("valid"),
        ),
    ];
    for (file, generated) in cases {
        let shipped = std::fs::read_to_string(repo_file(file))
            .unwrap_or_else(|e| panic!("{file} must be shipped (see maps/README.md): {e}"));
        assert_same_xml(&shipped, &generated, file);
    }
}

#[test]
fn xml_is_josm_style_with_unique_negative_ids_and_an_origin() {
    let text = intersection(&IntersectionParams::default()).expect("valid");
    assert!(text.starts_with("<?xml version='1.0' encoding='UTF-8'?>\n<osm version='0.6' generator='smlworld'>\n"));
    assert!(!text.contains('"'), "JOSM style uses single quotes only");
    let doc = parse_osm(&text, Path::new("intersection4.osm")).expect("generated XML parses");
    let mut ids: Vec<i64> = doc.nodes.keys().chain(doc.ways.keys()).chain(doc.relations.keys()).copied().collect();
    let total = ids.len();
    ids.sort_unstable();
    ids.dedup();
    assert_eq!(ids.len(), total, "ids are unique over nodes, ways and relations");
    assert!(ids.iter().all(|&id| id < 0), "new JOSM objects have negative ids");
    let origins: Vec<_> =
        doc.nodes.values().filter(|n| n.tags.get("origin").map(String::as_str) == Some("true")).collect();
    assert_eq!(origins.len(), 1);
    assert_eq!((origins[0].lat, origins[0].lon), (generate::ORIGIN_LAT, generate::ORIGIN_LON));
}

#[test]
fn both_bounds_of_every_lanelet_have_the_same_node_count_as_the_2015_loader_required() {
    let maps = [
        ("ring", ring_highway(&RingParams { lanes: 4, clockwise: true, ..RingParams::default() })),
        ("intersection3", intersection(&IntersectionParams { arms: 3, lanes: 2, ..IntersectionParams::default() })),
        ("grid", grid_city(&GridParams { rows: 2, cols: 3, lanes: 2, ..GridParams::default() })),
    ];
    for (name, text) in maps {
        let doc = parse_osm(&text.expect("valid"), Path::new(name)).expect("parses");
        assert!(!doc.relations.is_empty());
        for r in doc.relations.values() {
            let counts: Vec<(&str, usize)> =
                r.members.iter().map(|m| (m.role.as_str(), doc.ways[&m.reference].nodes.len())).collect();
            assert!(
                counts.len() == 2 && counts[0].0 == "left" && counts[1].0 == "right" && counts[0].1 == counts[1].1,
                "{name}: relation {}: {counts:?}",
                r.id
            );
        }
    }
}

#[test]
fn bad_parameters_are_errors_naming_the_parameter() {
    let name = |r: Result<String, GenerateError>| match r {
        Err(GenerateError::InvalidParameter { name, .. }) => name,
        other => panic!("expected InvalidParameter, got {other:?}"),
    };
    assert_eq!(name(ring_highway(&RingParams { lanes: 0, ..RingParams::default() })), "lanes");
    assert_eq!(name(ring_highway(&RingParams { radius: -1.0, ..RingParams::default() })), "radius");
    assert_eq!(name(ring_highway(&RingParams { lane_width: f64::NAN, ..RingParams::default() })), "lane_width");
    assert_eq!(name(ring_highway(&RingParams { node_spacing: 0.0, ..RingParams::default() })), "node_spacing");
    assert_eq!(name(intersection(&IntersectionParams { arms: 5, ..IntersectionParams::default() })), "arms");
    assert_eq!(
        name(intersection(&IntersectionParams { corner_radius: 0.0, ..IntersectionParams::default() })),
        "corner_radius"
    );
    assert_eq!(
        name(intersection(&IntersectionParams { arm_length: f64::INFINITY, ..IntersectionParams::default() })),
        "arm_length"
    );
    assert_eq!(name(grid_city(&GridParams { rows: 0, ..GridParams::default() })), "rows");
    // Junctions reach 3.5 + 6 = 9.5 m from their centre: blocks of 19 m leave no street.
    assert_eq!(name(grid_city(&GridParams { block: 19.0, ..GridParams::default() })), "block");
    assert!(grid_city(&GridParams { block: 19.5, ..GridParams::default() }).is_ok());
    // A road of a million kilometres at 2 m per node is a typo, refused at once (it used to run
    // until it had written gigabytes).
    let huge = LaneDropParams { length: 1e9, drop_at: 1.0, ..LaneDropParams::default() };
    assert_eq!(name(lane_drop(&huge)), "node_spacing");
}

#[test]
fn cli_writes_the_same_map_and_rejects_flags_of_other_kinds() {
    let dir = std::env::temp_dir();
    let out = dir.join(format!("smlworld-test-generate-{}.osm", std::process::id()));
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["map", "generate", "ring", "--lanes", "2", "--radius", "20", "--clockwise", "--out"])
        .arg(&out)
        .output()
        .expect("binary runs");
    assert!(status.status.success(), "stderr: {}", String::from_utf8_lossy(&status.stderr));
    let written = std::fs::read_to_string(&out).expect("CLI wrote the map");
    let _ = std::fs::remove_file(&out);
    let expected =
        ring_highway(&RingParams { lanes: 2, radius: 20.0, clockwise: true, ..RingParams::default() }).expect("valid");
    assert_eq!(written, expected);

    let bad = std::process::Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["map", "generate", "intersection4", "--radius", "20", "--out"])
        .arg(&out)
        .output()
        .expect("binary runs");
    assert!(!bad.status.success());
    let stderr = String::from_utf8_lossy(&bad.stderr);
    assert!(stderr.contains("--radius") && !stderr.contains("panicked"), "stderr: {stderr}");
    assert!(!out.exists(), "no file is left behind on error");
}

#[test]
fn lat_lon_project_back_onto_the_ring_circles_to_a_tenth_of_a_millimetre() {
    let p = RingParams { lanes: 2, radius: 400.0, lane_width: 3.0, node_spacing: 5.0, ..RingParams::default() };
    let doc = parse_osm(&ring_highway(&p).expect("valid"), Path::new("ring.osm")).expect("parses");
    let projector = smlworld::map::Projector::new(generate::ORIGIN_LAT, generate::ORIGIN_LON);
    let radii = [400.0, 403.0, 406.0];
    let mut on_circle = [0usize; 3];
    for node in doc.nodes.values().filter(|n| !n.tags.contains_key("origin")) {
        let r = projector.forward(node.lat, node.lon).length();
        let b = radii.iter().position(|&rb| (r - rb).abs() < 1e-4);
        let b = b.unwrap_or_else(|| panic!("node {} at radius {r} m is on no boundary circle", node.id));
        on_circle[b] += 1;
    }
    // Same node count on every boundary: 4 quarters of ceil(pi/2 * 406 / 5) = 128 segments.
    assert_eq!(on_circle, [512, 512, 512]);
}

// ---------------------------------------------------------------------------------------------
// Round trips through the loader.

fn load(text: &str, name: &str) -> LaneletMap {
    let map = LaneletMap::parse_str(text, Path::new(name)).unwrap_or_else(|e| panic!("{name} must load: {e}"));
    assert!(map.warnings.is_empty(), "{name} loads without warnings: {:?}", map.warnings);
    map
}

fn count_line_type(map: &LaneletMap, line_type: &str) -> usize {
    map.ways.values().filter(|w| w.tags.get("line_type").map(String::as_str) == Some(line_type)).count()
}

/// Twice the signed area of a polyline [m^2]: positive when it turns counter-clockwise.
fn signed_area2(points: &[DVec2]) -> f64 {
    points.windows(2).map(|w| w[0].perp_dot(w[1])).sum()
}

fn rel_err(actual: f64, expected: f64) -> f64 {
    (actual - expected).abs() / expected
}

#[test]
fn ring_round_trips_with_analytic_counts_lengths_successors_and_loops() {
    let opts = RouteOptions::default();
    for lanes in [1, 2, 3, 5] {
        for clockwise in [false, true] {
            let p = RingParams { lanes, radius: 30.0, lane_width: 3.5, clockwise, node_spacing: 1.5 };
            let what = format!("ring lanes={lanes} clockwise={clockwise}");
            let map = load(&ring_highway(&p).expect("valid"), &what);
            // Documented node rule: the same count on every boundary, spacing <= 1.5 m outside.
            let r_outer = p.radius + lanes as f64 * p.lane_width;
            let n = (FRAC_PI_2 * r_outer / p.node_spacing).ceil() as usize;
            assert!((FRAC_PI_2 * r_outer / n as f64) <= p.node_spacing, "{what}");
            assert_eq!(map.nodes.len(), 1 + 4 * n * (lanes + 1), "{what}: nodes");
            assert_eq!(map.ways.len(), 4 * (lanes + 1), "{what}: ways");
            assert_eq!(count_line_type(&map, "exterior"), 8, "{what}");
            assert_eq!(count_line_type(&map, "interior"), 4 * (lanes - 1), "{what}");
            assert_eq!(map.lanelets.len(), 4 * lanes, "{what}: lanelets");
            assert_eq!(map.successor_pairs(), 4 * lanes, "{what}: successor pairs");
            let sign = if clockwise { -1.0 } else { 1.0 };
            for l in &map.lanelets {
                // Which lane: the centre line stays at one radius, radius + (m + 0.5) w.
                let r_mid = l.centre[l.centre.len() / 2].length();
                let m = ((r_mid - p.radius) / p.lane_width - 0.5).round();
                let r_c = p.radius + (m + 0.5) * p.lane_width;
                for c in &l.centre {
                    assert!((c.length() - r_c).abs() < 0.01, "{what}: lanelet {} centre off its circle", l.id);
                }
                assert!(rel_err(l.length, FRAC_PI_2 * r_c) < 1e-3, "{what}: lanelet {} length {}", l.id, l.length);
                assert!(sign * signed_area2(&l.centre) > 0.0, "{what}: lanelet {} runs the wrong way", l.id);
                // One successor: the next quarter of the same lane, starting where this one ends.
                assert_eq!(l.successors.len(), 1, "{what}: lanelet {}", l.id);
                let next = map.lanelet(l.successors[0]).expect("successor exists");
                let (end, start) = (l.centre[l.centre.len() - 1], next.centre[0]);
                assert!(end.distance(start) < 1e-6, "{what}: {} -> {} not joined", l.id, next.id);
            }
            for k in 0..lanes {
                let m = if clockwise { k } else { lanes - 1 - k };
                let r_c = p.radius + (m as f64 + 0.5) * p.lane_width;
                let tag = ring_lane_tag(lanes, k);
                let path = map.closed_loop_tag(&tag, &opts).unwrap_or_else(|e| panic!("{what}: loop {tag}: {e}"));
                assert!(
                    rel_err(path.length, TAU * r_c) < 0.005,
                    "{what}: loop {tag} is {} m, 2 pi R = {} m",
                    path.length,
                    TAU * r_c
                );
                assert!(sign * signed_area2(&path.points) > 0.0, "{what}: loop {tag} runs the wrong way");
            }
        }
    }
}

#[test]
fn shipped_ring_has_highwaysml_tags_and_loop_lengths() {
    let map = LaneletMap::load(&repo_file("maps/highway_ring.osm")).expect("shipped ring loads");
    let opts = RouteOptions::default();
    // Documented in maps/README.md: inner edge 50 m, lanes 4 m, right lane outermost.
    for (tag, r_c) in [("right_lane_node", 60.0), ("center_lane_node", 56.0), ("left_lane_node", 52.0)] {
        let path = map.closed_loop_tag(tag, &opts).unwrap_or_else(|e| panic!("loop {tag}: {e}"));
        assert!(rel_err(path.length, TAU * r_c) < 0.005, "{tag}: {} m", path.length);
    }
    let origin = &map.nodes[&map.origin_node.expect("origin node")];
    assert!(origin.position.length() < 1e-6);
}

/// Centre-line length through a junction [m] from the arm `from` to the arm `to` for a lane whose
/// centre is `t` [m] from the road centre line, junction edge `d0` [m] from the centre.
fn turn_length(from: Arm, to: Arm, d0: f64, t: f64) -> f64 {
    let (a, b) = (-from.direction(), to.direction());
    if a.dot(b) > 0.5 {
        2.0 * d0
    } else if a.perp_dot(b) > 0.0 {
        FRAC_PI_2 * (d0 + t)
    } else {
        FRAC_PI_2 * (d0 - t)
    }
}

#[test]
fn intersections_round_trip_and_route_every_legal_turn_but_no_u_turn() {
    let opts = RouteOptions::default();
    for arms in [3, 4] {
        for lanes in [1, 2] {
            let p = IntersectionParams { arms, lanes, ..IntersectionParams::default() };
            let what = format!("intersection arms={arms} lanes={lanes}");
            let map = load(&intersection(&p).expect("valid"), &what);
            let turns = arms * (arms - 1) * lanes;
            assert_eq!(map.lanelets.len(), 2 * arms * lanes + turns, "{what}: lanelets");
            assert_eq!(map.ways.len(), arms * (2 * lanes + 1) + arms * (arms - 1) * (lanes + 1), "{what}: ways");
            assert_eq!(map.successor_pairs(), 2 * turns, "{what}: successor pairs");
            let d0 = lanes as f64 * p.lane_width + p.corner_radius;
            // Nodes: origin, both ends and the inner nodes of every arm boundary, plus the inner
            // nodes of the lanes + 1 bounds of each turn, spaced by the longest bound: 2 d0
            // straight, a quarter circle of radius d0 right, of d0 + lanes w left.
            let arm_list = Arm::of_intersection(arms);
            let segments = |len: f64| (len / p.node_spacing).ceil() as usize;
            let bounds = 2 * lanes + 1;
            let mut nodes = 1 + arms * bounds * (2 + segments(p.arm_length) - 1);
            for &from in arm_list {
                for &to in arm_list.iter().filter(|&&to| to != from) {
                    let (a, b) = (-from.direction(), to.direction());
                    let longest = if a.dot(b) > 0.5 {
                        2.0 * d0
                    } else if a.perp_dot(b) > 0.0 {
                        FRAC_PI_2 * (d0 + lanes as f64 * p.lane_width)
                    } else {
                        FRAC_PI_2 * d0
                    };
                    nodes += (lanes + 1) * (segments(longest) - 1);
                }
            }
            assert_eq!(map.nodes.len(), nodes, "{what}: nodes");
            for l in map.lanelets.iter().filter(|l| map.ways[&l.right_way].line_type().is_some()) {
                assert!((l.length - p.arm_length).abs() < 1e-4, "{what}: arm lanelet {} is {} m", l.id, l.length);
            }
            // Rightmost lane: centre (lanes - 0.5) lane widths from the road centre line.
            let t = (lanes as f64 - 0.5) * p.lane_width;
            for &from in arm_list {
                for &to in arm_list {
                    let (start, end) = (intersection_start_tag(from), intersection_end_tag(to));
                    let route = map.route_tags(&start, &end, &opts);
                    if from == to {
                        assert!(route.is_err(), "{what}: U-turn {start} -> {end} must not be routable");
                        continue;
                    }
                    let path = route.unwrap_or_else(|e| panic!("{what}: {start} -> {end}: {e}"));
                    let expected = 2.0 * p.arm_length + turn_length(from, to, d0, t);
                    assert!(
                        rel_err(path.length, expected) < 0.005,
                        "{what}: {start} -> {end} is {} m, expected {expected} m",
                        path.length
                    );
                    assert_eq!(path.lanelets.len(), 3, "{what}: {start} -> {end}: in, turn, out");
                }
            }
        }
    }
}

#[test]
fn grid_counts_follow_the_formulas_and_far_corners_are_routable() {
    let opts = RouteOptions::default();
    for (rows, cols, lanes) in [(1, 1, 1), (1, 3, 1), (2, 2, 2), (3, 4, 1)] {
        let p = GridParams { rows, cols, lanes, ..GridParams::default() };
        let what = format!("grid {rows}x{cols} lanes={lanes}");
        let map = load(&grid_city(&p).expect("valid"), &what);
        let streets = rows * (cols + 1) + cols * (rows + 1);
        // Sum over junctions of arms (arms - 1): corners 2, border junctions 6, inner 12.
        let turn_pairs = 4 * 2 + 6 * (2 * (rows - 1) + 2 * (cols - 1)) + 12 * (rows - 1) * (cols - 1);
        let turns = lanes * turn_pairs;
        assert_eq!(map.lanelets.len(), 2 * lanes * streets + turns, "{what}: lanelets");
        assert_eq!(map.ways.len(), (2 * lanes + 1) * streets + (lanes + 1) * turn_pairs, "{what}: ways");
        assert_eq!(map.successor_pairs(), 2 * turns, "{what}: successor pairs");
        let virtual_ways = map.ways.values().filter(|w| w.tags.get("type").map(String::as_str) == Some("virtual"));
        assert_eq!(virtual_ways.count(), (lanes + 1) * turn_pairs, "{what}");
        let d0 = lanes as f64 * p.lane_width + p.corner_radius;
        let street = p.block - 2.0 * d0;
        let mut street_lanelets = 0;
        for l in &map.lanelets {
            assert!(!l.successors.is_empty(), "{what}: lanelet {} is a dead end", l.id);
            let right = &map.ways[&l.right_way];
            if right.line_type().is_some() {
                street_lanelets += 1;
                // 1e-10 deg in the file is about 1e-5 m.
                assert!((l.length - street).abs() < 1e-4, "{what}: street lanelet {} is {} m", l.id, l.length);
            }
        }
        assert_eq!(street_lanelets, 2 * lanes * streets, "{what}");

        // Corner to opposite corner: at least rows + cols streets and junction passes, at most
        // the L-shaped route (straight through all but two junctions, two left turns).
        let t = (lanes as f64 - 0.5) * p.lane_width;
        let (start, end) = (grid_junction_tag(0, 0, Arm::East), grid_junction_tag(rows, cols, Arm::West));
        let path = map.route_tags(&start, &end, &opts).unwrap_or_else(|e| panic!("{what}: {start} -> {end}: {e}"));
        let hops = (rows + cols) as f64;
        let lower = hops * (street + FRAC_PI_2 * (d0 - t));
        let upper = hops * street + (hops - 2.0) * 2.0 * d0 + 2.0 * FRAC_PI_2 * (d0 + t);
        assert!(
            path.length > lower * 0.995 && path.length < upper * 1.005,
            "{what}: {start} -> {end} is {} m, outside [{lower}, {upper}]",
            path.length
        );
        let start_node = map.tag_index[&start][0];
        let first = path.points[0];
        assert!(
            (first.distance(map.nodes[&start_node].position) - p.lane_width / 2.0).abs() < 0.05,
            "{what}: route starts on the lane centre beside {start}"
        );
    }
}

#[test]
fn grid_writer_scales_to_tens_of_thousands_of_lanelets() {
    let (rows, cols) = (40, 40);
    let stats =
        generate::write_grid_city(&GridParams { rows, cols, ..GridParams::default() }, std::io::sink()).expect("valid");
    let streets = rows * (cols + 1) + cols * (rows + 1);
    let turns = 4 * 2 + 6 * (2 * (rows - 1) + 2 * (cols - 1)) + 12 * (rows - 1) * (cols - 1);
    assert_eq!(stats.lanelets, 2 * streets + turns);
    assert!(stats.lanelets > 20_000 && stats.bytes > 20_000_000, "{stats:?}");
}
