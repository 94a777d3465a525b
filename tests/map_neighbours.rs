//! Lanelet neighbours and lane-change permissions (Lanelet2 style) on HighwaySML, the generated
//! rings and Lanelet2's mapping_example.

mod common;

use smlworld::map::generate::{RingParams, ring_highway, ring_lane_tag};
use smlworld::map::{LaneletId, LaneletMap, Neighbours, RouteOptions};
use std::path::Path;

/// The lanelets of each ring lane, rightmost first, from the lane's tagged closed loop.
fn lanes(map: &LaneletMap, tags: &[String]) -> Vec<Vec<LaneletId>> {
    tags.iter().map(|t| map.closed_loop_tag(t, &RouteOptions::default()).unwrap().lanelets).collect()
}

/// Every lanelet of lane k has lane k+1's lanelet beside it on the left and lane k-1's on the right,
/// changes allowed; the outer lanes have no neighbour beyond the road edge.
fn assert_ring_neighbours(map: &LaneletMap, lanes: &[Vec<LaneletId>]) {
    let table = map.neighbours();
    let lane_of = |id: LaneletId| lanes.iter().position(|l| l.contains(&id));
    let mut checked = 0;
    for (k, lane) in lanes.iter().enumerate() {
        assert_eq!(lane.len(), lanes[0].len(), "lane {k}: same lanelet count as lane 0");
        for id in lane {
            let n: Neighbours = table[map.lanelet_index(*id).unwrap()];
            assert_eq!(n, map.neighbours_of(*id).unwrap());
            if k + 1 < lanes.len() {
                let left = n.left.unwrap_or_else(|| panic!("lane {k} lanelet {id}: no left neighbour"));
                assert_eq!(lane_of(left), Some(k + 1), "lane {k} lanelet {id}: left neighbour {left}");
                assert!(n.change_left, "lane {k} lanelet {id}: interior line must allow a change");
                // Beside means beside: the shared bound is this lanelet's left and the other's right.
                let other = map.lanelet(left).unwrap();
                assert_eq!(map.lanelet(*id).unwrap().left_nodes, other.right_nodes);
                let back = table[map.lanelet_index(left).unwrap()];
                assert_eq!(back.right, Some(*id), "left neighbour {left} of {id} has it on its right");
            } else {
                assert_eq!(n.left, None, "lane {k} lanelet {id}: the leftmost lane has no left neighbour");
                assert!(!n.change_left);
            }
            if k > 0 {
                let right = n.right.unwrap_or_else(|| panic!("lane {k} lanelet {id}: no right neighbour"));
                assert_eq!(lane_of(right), Some(k - 1), "lane {k} lanelet {id}: right neighbour {right}");
                assert!(n.change_right);
            } else {
                assert_eq!(n.right, None, "lane {k} lanelet {id}: the rightmost lane has no right neighbour");
                assert!(!n.change_right);
            }
            checked += 1;
        }
    }
    assert_eq!(checked, map.lanelets.len(), "every lanelet of the ring belongs to one lane");
}

#[test]
fn highway_sml_three_lanes_have_their_neighbours_on_every_lanelet() {
    let map = LaneletMap::load(&common::shared("sml2015/HighwaySML.xml")).unwrap();
    let tags: Vec<String> = ["right_lane_node", "center_lane_node", "left_lane_node"].map(String::from).to_vec();
    let lanes = lanes(&map, &tags);
    assert_eq!(lanes.iter().map(Vec::len).sum::<usize>(), 12);
    assert_ring_neighbours(&map, &lanes);
}

#[test]
fn generated_rings_have_neighbours_across_interior_lines_only() {
    for n_lanes in [1, 2, 3, 4] {
        for clockwise in [false, true] {
            let params = RingParams { lanes: n_lanes, clockwise, ..RingParams::default() };
            let map = LaneletMap::parse_str(&ring_highway(&params).unwrap(), Path::new("ring.osm")).unwrap();
            let tags: Vec<String> = (0..n_lanes).map(|k| ring_lane_tag(n_lanes, k)).collect();
            let lanes = lanes(&map, &tags);
            assert_ring_neighbours(&map, &lanes);
        }
    }
}

#[test]
fn exterior_line_forbids_the_change_but_keeps_the_neighbour() {
    // Retag the centre/left boundary of a generated 3-lane ring as exterior: still neighbours
    // (they share a bound), but no change across it either way.
    let text = ring_highway(&RingParams::default()).unwrap();
    let map = LaneletMap::parse_str(&text, Path::new("ring.osm")).unwrap();
    let tags: Vec<String> = (0..3).map(|k| ring_lane_tag(3, k)).collect();
    let lanes = lanes(&map, &tags);
    let centre = map.lanelet(lanes[1][0]).unwrap();
    let mut ways: Vec<i64> = lanes[1].iter().map(|id| map.lanelet(*id).unwrap().left_way).collect();
    ways.sort();
    ways.dedup();
    assert!(ways.contains(&centre.left_way));
    let mut edited = String::new();
    let mut inside = false;
    for line in text.lines() {
        if let Some(rest) = line.trim_start().strip_prefix("<way id='") {
            let id: i64 = rest.split('\'').next().unwrap().parse().unwrap();
            inside = ways.contains(&id);
        }
        if inside && line.contains("'interior'") {
            edited.push_str(&line.replace("'interior'", "'exterior'"));
        } else {
            edited.push_str(line);
        }
        edited.push('\n');
    }
    let map = LaneletMap::parse_str(&edited, Path::new("ring.osm")).unwrap();
    let n = map.neighbours_of(lanes[1][0]).unwrap();
    assert!(n.left.is_some() && !n.change_left, "{n:?}");
    assert!(n.right.is_some() && n.change_right, "the other interior line still allows: {n:?}");
    let left = map.neighbours_of(n.left.unwrap()).unwrap();
    assert!(left.right == Some(lanes[1][0]) && !left.change_right, "{left:?}");
}

#[test]
fn lanelet2_example_changes_only_across_dashed_or_virtual_lines() {
    let map = LaneletMap::load(&common::shared("lanelet2/mapping_example.osm")).unwrap();
    let table = map.neighbours();
    let (mut dashed, mut solid, mut one_way, mut changes) = (0, 0, 0, 0);
    for (i, l) in map.lanelets.iter().enumerate() {
        let n = table[i];
        if let Some(left) = n.left {
            let other = map.lanelet(left).unwrap();
            assert_eq!(l.left_nodes, other.right_nodes, "{} and {left} share a bound", l.id);
            let tags = &map.ways[&l.left_way].tags;
            let subtype = tags.get("subtype").map(String::as_str);
            let virtual_line = tags.get("type").map(String::as_str) == Some("virtual");
            match subtype {
                // A virtual line (no paint, inside intersections) is crossed like a dashed one.
                Some("dashed") | None if subtype.is_some() || virtual_line => {
                    dashed += 1;
                    assert!(n.change_left && table[map.lanelet_index(left).unwrap()].change_right);
                }
                // Solid, or a painted line whose pattern the map does not say.
                Some("solid" | "solid_solid") | None => {
                    solid += 1;
                    assert!(!n.change_left, "{}: change across {subtype:?} line", l.id);
                    assert!(!table[map.lanelet_index(left).unwrap()].change_right);
                }
                // Lanelet2: `solid_dashed` is solid on the left of the way as drawn, dashed on its
                // right, so only the lanelet on the way's right may cross it (to the left).
                Some(kind @ ("solid_dashed" | "dashed_solid")) => {
                    one_way += 1;
                    let along = map.ways[&l.left_way].nodes == l.left_nodes;
                    let l_on_ways_right = along;
                    let expect_left = (kind == "solid_dashed") == l_on_ways_right;
                    assert_eq!(n.change_left, expect_left, "{}: {kind} along={along}", l.id);
                    assert_eq!(table[map.lanelet_index(left).unwrap()].change_right, !expect_left);
                }
                other => panic!("unexpected shared line subtype {other:?}: way {} {tags:?}", l.left_way),
            }
        }
        changes += n.change_left as usize + n.change_right as usize;
        // No neighbour across a lanelet's own road edge.
        assert!(n.left.is_none() || n.left != n.right);
    }
    eprintln!("mapping_example: {dashed} dashed, {solid} solid, {one_way} one-way shared bounds");
    assert!(dashed > 0 && solid > 0, "the example has both kinds of shared line ({dashed} dashed, {solid} solid)");
    assert_eq!(changes, 2 * dashed + one_way, "every allowed change crosses a dashed or virtual line, both ways");
    // Brute force: same-direction pairs sharing a bound, counted independently of the table.
    let mut pairs = 0;
    for a in map.lanelets.iter().filter(|l| l.routable) {
        for b in map.lanelets.iter().filter(|l| l.routable) {
            if a.id != b.id && a.left_nodes == b.right_nodes {
                pairs += 1;
            }
        }
    }
    assert_eq!(pairs, dashed + solid + one_way, "every same-direction shared bound is found");
}
