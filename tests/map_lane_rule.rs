//! Which lanelets a start or end node selects (issue 10): the 2015 rule (seed §3.3.2) takes the
//! lanelets whose right bound holds the node; only a node on no right bound falls back to the
//! lanelets whose left bound holds it, and the result says so.

use std::path::Path;

use smlworld::map::{LaneletId, LaneletMap, Place, RouteOptions};

/// Two parallel one-lanelet lanes driven east, 100 m long: lanelet -20 (right lane, bounds R | M)
/// and -21 (left lane, bounds M | L). M is the right lane's left bound and the left lane's right
/// bound; `left_end` lies only on L, the left lane's left bound.
const TWO_LANES: &str = r#"<?xml version='1.0' encoding='UTF-8'?>
<osm version='0.6' generator='JOSM'>
  <node id='-1' lat='59.0' lon='17.0' />
  <node id='-2' lat='59.0' lon='17.001744' />
  <node id='-3' lat='59.0000315' lon='17.0'><tag k='destination' v='mid_start' /></node>
  <node id='-4' lat='59.0000315' lon='17.001744'><tag k='destination' v='mid_end' /></node>
  <node id='-5' lat='59.000063' lon='17.0' />
  <node id='-6' lat='59.000063' lon='17.001744'><tag k='destination' v='left_end' /></node>
  <way id='-10'><nd ref='-1' /><nd ref='-2' /></way>
  <way id='-11'><nd ref='-3' /><nd ref='-4' /></way>
  <way id='-12'><nd ref='-5' /><nd ref='-6' /></way>
  <relation id='-21'>
    <member type='way' ref='-11' role='right' />
    <member type='way' ref='-12' role='left' />
    <tag k='type' v='lanelet' />
  </relation>
  <relation id='-20'>
    <member type='way' ref='-10' role='right' />
    <member type='way' ref='-11' role='left' />
    <tag k='type' v='lanelet' />
  </relation>
</osm>
"#;

fn two_lanes() -> LaneletMap {
    LaneletMap::parse_str(TWO_LANES, Path::new("two_lanes.osm")).expect("the two-lane map loads")
}

#[test]
fn a_node_on_a_shared_marking_selects_the_lane_on_its_left() {
    let map = two_lanes();
    assert_eq!(map.lanelets.len(), 2, "{:?}", map.warnings);
    let r = map
        .route_places_routed(&Place::Tag("mid_start".into()), &Place::Tag("mid_end".into()), &RouteOptions::default())
        .unwrap();
    assert_eq!(r.path.lanelets, vec![LaneletId(-21)], "M is the right bound of the left lane only");
    assert_eq!((r.from_node, r.to_node), (-3, -4));
    assert!(r.note.is_none(), "{:?}", r.note);
    // The path is the left lane's centre line, between M and L.
    let y = r.path.points[r.path.points.len() / 2].y;
    let (m, l) = (map.nodes[&-3].position.y, map.nodes[&-5].position.y);
    assert!(y > m + 0.1 && y < l - 0.1, "path at y = {y} m is not between M ({m}) and L ({l})");
}

#[test]
fn a_node_on_no_right_bound_falls_back_to_the_left_bound_and_says_so() {
    let map = two_lanes();
    let r = map
        .route_places_routed(&Place::Tag("mid_start".into()), &Place::Tag("left_end".into()), &RouteOptions::default())
        .unwrap();
    assert_eq!(r.path.lanelets, vec![LaneletId(-21)]);
    assert_eq!(r.to_node, -6);
    let note = r.note.expect("a fallback is reported");
    assert!(note.contains("node -6") && note.contains("-21") && note.contains("left bound"), "{note}");
}
