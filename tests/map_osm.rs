//! The raw OSM reader: JOSM conventions, ids beyond 2^53, dropped objects.

use std::path::Path;

use smlworld::map::LaneletMap;
use smlworld::map::osm::{MemberType, parse_osm};

const JOSM: &str = r#"<?xml version='1.0' encoding='UTF-8'?>
<osm version='0.6' upload='true' generator='JOSM'>
  <node id='-1' action='modify' visible='true' lat='59.0' lon='17.0'>
    <tag k='destination' v='a &amp; b' />
  </node>
  <node id="9007199254740993" lat="59.0001" lon="17.0001" />
  <node id='-3' action='delete' visible='true' lat='59.0002' lon='17.0' />
  <node id='-4' visible='false' lat='59.0003' lon='17.0' />
  <way id='-10' action='modify' visible='true'>
    <nd ref='-1' />
    <nd ref='9007199254740993' />
    <tag k='line_type' v='exterior' />
  </way>
  <way id='-11' action='delete'>
    <nd ref='-3' />
  </way>
  <relation id='-20'>
    <member type='way' ref='-10' role='right_lane_marking' />
    <member type='node' ref='-1' role='refers' />
    <tag k='type' v='lanelet' />
    <tag k='truck_lane' v='true' />
  </relation>
</osm>
"#;

#[test]
fn josm_conventions() {
    let doc = parse_osm(JOSM, Path::new("josm.osm")).unwrap();
    assert_eq!(doc.nodes.len(), 2, "deleted and invisible nodes are dropped");
    assert_eq!(doc.ways.len(), 1, "the deleted way is dropped");
    assert_eq!(doc.nodes[&-1].tags["destination"], "a & b", "entities are unescaped");
    assert_eq!(doc.nodes[&-1].line, 3);
    // 2^53 + 1 is not representable as f64: parsed as i64 it stays exact.
    assert!(doc.nodes.contains_key(&9_007_199_254_740_993));
    assert_eq!(doc.ways[&-10].nodes, vec![-1, 9_007_199_254_740_993]);
    let r = &doc.relations[&-20];
    assert_eq!(r.members.len(), 2);
    assert_eq!(r.members[1].kind, MemberType::Node);
    assert_eq!(r.members[0].role, "right_lane_marking");
    assert_eq!(r.tags["truck_lane"], "true");
}

#[test]
fn xml_and_osm_extensions_both_load() {
    let dir = std::env::temp_dir().join(format!("smlworld-osm-ext-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for name in ["map.xml", "map.osm"] {
        let p = dir.join(name);
        std::fs::write(&p, JOSM).unwrap();
        let map = LaneletMap::load(&p).unwrap();
        assert_eq!(map.nodes.len(), 2, "{name}");
        // The one lanelet lacks a left bound: a warning, not an error; its tags are kept in the file.
        assert!(map.lanelets.is_empty());
        assert_eq!(map.warnings.len(), 1, "{:?}", map.warnings);
        assert_eq!(map.ways[&-10].line_type(), Some("exterior"));
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn origin_defaults_to_the_mean_of_all_nodes() {
    let text = r#"<osm version='0.6'>
  <node id='1' lat='10.0' lon='20.0' />
  <node id='2' lat='10.002' lon='20.002' />
</osm>"#;
    let map = LaneletMap::parse_str(text, Path::new("mean.osm")).unwrap();
    assert_eq!(map.origin_node, None);
    let (a, b) = (map.nodes[&1].position, map.nodes[&2].position);
    assert!((a + b).length() < 0.01, "the two nodes are symmetric about the mean origin: {a} {b}");
    assert!((map.projector.origin_lat - 10.001).abs() < 1e-12);
}
