//! The road module on real maps nobody here drew: the 2015 SML maps and Lanelet2's example.

mod common;

use smlworld::map::{LaneletId, LaneletMap, RouteOptions};

fn highway() -> LaneletMap {
    LaneletMap::load(&common::shared("sml2015/HighwaySML.xml")).expect("HighwaySML.xml loads")
}

#[test]
fn highway_counts_origin_and_successors() {
    let map = highway();
    assert_eq!(map.nodes.len(), 273);
    assert_eq!(map.ways.len(), 16);
    assert_eq!(map.lanelets.len(), 12);
    assert_eq!(map.successor_pairs(), 12);
    assert_eq!(map.origin_node, Some(-552));
    let origin = &map.nodes[&-552];
    assert!(origin.position.length() < 1e-9, "origin node projects to (0, 0), got {}", origin.position);
    // Every lanelet of the ring has exactly one successor: the next quarter of its lane.
    for l in &map.lanelets {
        assert_eq!(l.successors.len(), 1, "lanelet {} successors {:?}", l.id, l.successors);
    }
    assert!(map.warnings.is_empty(), "{:?}", map.warnings);
}

#[test]
fn highway_tags_addressable_by_value() {
    let map = highway();
    assert_eq!(map.nodes_with_tag("left_lane_node").unwrap(), &[-414]);
    assert_eq!(map.nodes_with_tag("center_lane_node").unwrap(), &[-272]);
    assert_eq!(map.nodes_with_tag("right_lane_node").unwrap(), &[-142]);
    assert!(map.nodes_with_tag("true").is_err(), "origin=true is not a destination");
}

#[test]
fn highway_closed_loops_have_the_original_lengths() {
    let map = highway();
    let opts = RouteOptions::default();
    for (tag, expected) in [("right_lane_node", 374.4), ("center_lane_node", 349.2), ("left_lane_node", 324.0)] {
        let path = map.closed_loop_tag(tag, &opts).unwrap();
        assert!(path.closed);
        assert_eq!(path.lanelets.len(), 4, "{tag}: a lane is four lanelets");
        assert!((path.length - expected).abs() < 0.5, "{tag}: loop length {} expected {expected}", path.length);
        // Equal spacing at 5 points per metre.
        let spacing = path.spacing();
        assert!((spacing - 0.2).abs() < 0.01, "{tag}: spacing {spacing}");
        // The loop starts at the tagged node.
        let node = map.nodes[&map.nodes_with_tag(tag).unwrap()[0]].position;
        assert!(
            path.points[0].distance(node) < 2.5,
            "{tag}: loop starts {} m from its node",
            path.points[0].distance(node)
        );
    }
}

#[test]
fn highway_loops_run_counter_clockwise() {
    let map = highway();
    let path = map.closed_loop_tag("right_lane_node", &RouteOptions::default()).unwrap();
    let pts = &path.points;
    let area: f64 = (0..pts.len()).map(|i| pts[i].perp_dot(pts[(i + 1) % pts.len()])).sum::<f64>() / 2.0;
    assert!(area > 0.0, "the SML highway is driven counter-clockwise (signed area {area})");
}

#[test]
fn highway_routes_between_lanes_are_not_possible_but_along_a_lane_are() {
    let map = highway();
    // No lane changes in the lanelet graph: right lane to left lane has no route.
    let err = map.route_tags("right_lane_node", "left_lane_node", &RouteOptions::default()).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("right_lane_node") && msg.contains("left_lane_node"), "{msg}");
    // Along the right lane from its tagged node to a node half-way round.
    let lane = map.closed_loop_tag("right_lane_node", &RouteOptions::default()).unwrap();
    let l = map.lanelet(lane.lanelets[2]).unwrap();
    let target = l.right_nodes[0];
    let route = map.route(-142, target, &RouteOptions::default()).unwrap();
    assert!(!route.closed);
    assert!(route.length > 100.0 && route.length < lane.length, "{}", route.length);
}

#[test]
fn adjacency_matrix_matches_successors() {
    let map = highway();
    let m = map.adjacency_matrix();
    assert_eq!(m.len(), 12);
    let finite = m.iter().flatten().filter(|&&v| v < 1e10).count();
    assert_eq!(finite, 12);
    for (i, l) in map.lanelets.iter().enumerate() {
        let j = map.lanelet_index(l.successors[0]).unwrap();
        assert_eq!(m[i][j], l.length);
    }
}

#[test]
fn intersection_and_templates_load() {
    let map = LaneletMap::load(&common::shared("sml2015/Intersection3Way.xml")).unwrap();
    assert_eq!(map.nodes.len(), 124);
    assert_eq!(map.ways.len(), 18);
    assert_eq!(map.lanelets.len(), 12);
    assert!(map.nodes_with_tag("bottom_start").is_ok());

    let templates = LaneletMap::load(&common::shared("sml2015/RoadTemplates.xml")).unwrap();
    let empty = templates.warnings.iter().filter(|w| w.message.contains("no members")).count();
    assert_eq!(empty, 84, "RoadTemplates.xml has 84 relations without members: {:#?}", &templates.warnings[..3]);
    assert_eq!(templates.lanelets.len(), 28);
}

#[test]
fn lanelet2_example_loads_all_lanelets_resampled() {
    let map = LaneletMap::load(&common::shared("lanelet2/mapping_example.osm")).unwrap();
    assert_eq!(map.lanelets.len(), 371);
    let mut unequal = 0;
    for l in &map.lanelets {
        assert_eq!(l.left.len(), l.right.len(), "lanelet {}", l.id);
        assert_eq!(l.centre.len(), l.left.len());
        if l.left_nodes.len() != l.right_nodes.len() {
            unequal += 1;
        }
        // The left bound lies on the left of the driving direction.
        let d = l.centre[l.centre.len() - 1] - l.centre[0];
        let mid = l.centre.len() / 2;
        assert!(d.perp_dot(l.left[mid] - l.right[mid]) > 0.0, "lanelet {}: left bound on the right", l.id);
    }
    assert!(unequal > 100, "most Lanelet2 lanelets have bounds of different node counts ({unequal})");
    let crosswalks = map.lanelets.iter().filter(|l| l.tags.get("subtype").map(String::as_str) == Some("crosswalk"));
    for c in crosswalks {
        assert!(!c.routable, "crosswalk {} must not be routable for vehicles", c.id);
    }
    // Route between two lanelets far apart (ids found by searching the map for the longest
    // shortest route between right-bound nodes; they lie on opposite sides of the map). Issue 10
    // changed the start from lanelet 45258: under the 2015 right-bound rule its first node no
    // longer selects the opposite lane whose left bound holds it.
    let a = map.lanelet(LaneletId(45256)).unwrap();
    let b = map.lanelet(LaneletId(45566)).unwrap();
    let (from, to) = (a.right_nodes[0], b.right_nodes[b.right_nodes.len() - 1]);
    let route = map.route(from, to, &RouteOptions::default()).unwrap();
    let (p, q) = (map.nodes[&from].position, map.nodes[&to].position);
    assert!(p.distance(q) > 200.0, "the ends are far apart ({} m)", p.distance(q));
    assert!(route.length >= p.distance(q), "a route cannot be shorter than the straight line");
    assert!(route.lanelets.len() >= 10, "{} lanelets", route.lanelets.len());
    // A node lies on several lanelets: the route starts and ends on ones whose bounds hold it.
    let holds = |id: LaneletId, node: i64| {
        let l = map.lanelet(id).unwrap();
        l.left_nodes.contains(&node) || l.right_nodes.contains(&node)
    };
    assert!(holds(route.lanelets[0], from) && holds(*route.lanelets.last().unwrap(), to));
    let (d0, d1) = (route.points[0].distance(p), route.points[route.points.len() - 1].distance(q));
    // The node is on a bound and the path on the centre line: about half a lane width apart.
    let widest = |id: LaneletId| {
        let l = map.lanelet(id).unwrap();
        l.left.iter().zip(&l.right).map(|(a, b)| a.distance(*b)).fold(0.0, f64::max)
    };
    let (w0, w1) = (widest(route.lanelets[0]), widest(*route.lanelets.last().unwrap()));
    assert!(d0 <= w0 && d1 <= w1, "route ends {d0} m and {d1} m from its nodes (lane widths {w0}, {w1})");
    for w in route.lanelets.windows(2) {
        let l = map.lanelet(w[0]).unwrap();
        assert!(
            l.successors.contains(&w[1]) || l.bidirectional || map.lanelet(w[1]).unwrap().bidirectional,
            "{} -> {}",
            w[0],
            w[1]
        );
    }
    for p in route.points.windows(2) {
        assert!(p[0].distance(p[1]) < 0.5, "gap in the route");
    }
}

/// Issue 10: the 2015 rule (seed §3.3.2) picks the lanelets whose RIGHT bound holds the node, so
/// `map loop --tag T` and `map route --from-tag T --to-tag T` drive the same lane, and a route from
/// the right lane's node to the centre lane's node does not stay inside the right lane.
#[test]
fn highway_tags_select_the_lane_whose_right_bound_holds_the_node() {
    let map = highway();
    let opts = RouteOptions::default();
    for tag in ["right_lane_node", "center_lane_node", "left_lane_node"] {
        let node = map.nodes_with_tag(tag).unwrap()[0];
        let lp = map.closed_loop_tag(tag, &opts).unwrap();
        let rt = map.route_tags(tag, tag, &opts).unwrap();
        let loop_lane: std::collections::BTreeSet<_> = lp.lanelets.iter().collect();
        for id in &rt.lanelets {
            assert!(loop_lane.contains(id), "{tag}: route lanelet {id} is not in the loop's lane {:?}", lp.lanelets);
        }
        for id in lp.lanelets.iter().chain(&rt.lanelets) {
            let l = map.lanelet(*id).unwrap();
            assert!(
                !l.left_nodes.contains(&node) || l.right_nodes.contains(&node),
                "{tag}: lanelet {id} has node {node} only on its left bound"
            );
        }
    }
    // Right lane to centre lane: no lane change in the graph, so no route (2015: no route either),
    // never a 0.25 m hop inside the right lane.
    assert!(map.route_tags("right_lane_node", "center_lane_node", &opts).is_err());
}
