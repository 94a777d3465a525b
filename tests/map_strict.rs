//! Maps that used to load silently with a wrong result (issue 24): each now gives an error, or a
//! warning naming the lanelet, way or node. The small maps are written here; the cut-short and
//! typo cases are made in memory from the original HighwaySML map in `../shared/data`.

use std::path::Path;

use smlworld::map::{LaneletMap, MapError};

const NODES: &str = r#"  <node id="-1" lat="59.0" lon="17.0" />
  <node id="-2" lat="59.0" lon="17.001" />
  <node id="-3" lat="59.00003" lon="17.0" />
  <node id="-4" lat="59.00003" lon="17.001" />
"#;
const WAYS: &str = r#"  <way id="-10">
    <nd ref="-1" />
    <nd ref="-2" />
  </way>
  <way id="-11">
    <nd ref="-3" />
    <nd ref="-4" />
  </way>
"#;
const LANELET: &str = r#"  <relation id="-20">
    <member type="way" ref="-10" role="right" />
    <member type="way" ref="-11" role="left" />
    <tag k="type" v="lanelet" />
  </relation>
"#;

fn osm(body: &str) -> String {
    format!("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<osm version=\"0.6\" generator=\"JOSM\">\n{body}</osm>\n")
}

fn load(text: &str) -> Result<LaneletMap, MapError> {
    LaneletMap::parse_str(text, Path::new("test.osm"))
}

fn error(text: &str, needles: &[&str]) -> String {
    let e = load(text).expect_err("must not load").to_string();
    for n in needles {
        assert!(e.contains(n), "expected {n:?} in: {e}");
    }
    e
}

fn warnings(text: &str) -> Vec<String> {
    load(text).expect("loads").warnings.iter().map(ToString::to_string).collect()
}

#[test]
fn the_template_itself_loads_without_a_word() {
    let map = load(&osm(&format!("{NODES}{WAYS}{LANELET}"))).unwrap();
    assert_eq!(map.lanelets.len(), 1);
    assert!(map.warnings.is_empty(), "{:?}", map.warnings);
}

#[test]
fn a_file_cut_at_a_line_boundary_is_an_error() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/sml2015/HighwaySML.xml");
    let text = std::fs::read_to_string(&path).expect("../shared/data/sml2015/HighwaySML.xml");
    // `head -n 668`: 9 of 12 lanelets and no `</osm>`.
    let cut: String = text.lines().take(668).map(|l| format!("{l}\n")).collect();
    error(&cut, &["test.osm:", "ends before </osm>", "cut short"]);
    let small: String = osm(&format!("{NODES}{WAYS}{LANELET}")).replace("</osm>\n", "");
    error(&small, &["ends before </osm>"]);
}

#[test]
fn a_node_nested_in_a_node_and_a_way_in_a_relation_are_errors() {
    let nested = NODES.replace(
        "<node id=\"-1\" lat=\"59.0\" lon=\"17.0\" />",
        "<node id=\"-1\" lat=\"59.0\" lon=\"17.0\">\n    <node id=\"-5\" lat=\"60.0\" lon=\"18.0\" />\n  </node>",
    );
    error(&osm(&format!("{nested}{WAYS}{LANELET}")), &["test.osm:4", "<node> inside node -1", "line 3"]);
    let way_in_relation = LANELET
        .replace("<tag k=\"type\"", "<way id=\"-12\">\n      <nd ref=\"-1\" />\n    </way>\n    <tag k=\"type\"");
    error(&osm(&format!("{NODES}{WAYS}{way_in_relation}")), &["<way> inside relation -20"]);
}

#[test]
fn an_object_after_the_end_of_osm_is_an_error() {
    let text = osm(&format!("{NODES}{WAYS}{LANELET}")) + "<node id=\"-9\" lat=\"59.0\" lon=\"17.0\" />\n";
    error(&text, &["<node> after </osm>"]);
}

#[test]
fn an_attribute_given_twice_is_an_error() {
    let twice = NODES.replace("<node id=\"-2\" lat=\"59.0\"", "<node id=\"-2\" lat=\"59.0\" lat=\"60.0\"");
    error(&osm(&format!("{twice}{WAYS}{LANELET}")), &["test.osm:4", "lat", "once"]);
}

#[test]
fn a_lanelet_bounded_twice_by_one_way_or_by_one_point_is_skipped_with_a_warning() {
    let same = LANELET.replace("ref=\"-11\" role=\"left\"", "ref=\"-10\" role=\"left\"");
    let w = warnings(&osm(&format!("{NODES}{WAYS}{same}")));
    assert!(w.iter().any(|w| w.contains("lanelet -20") && w.contains("same way -10")), "{w:?}");

    let point = WAYS.replace("<nd ref=\"-4\" />", "<nd ref=\"-3\" />");
    let map = load(&osm(&format!("{NODES}{point}{LANELET}"))).unwrap();
    assert!(map.lanelets.is_empty(), "a lanelet with a zero-length bound is not driven");
    let w: Vec<String> = map.warnings.iter().map(ToString::to_string).collect();
    assert!(w.iter().any(|w| w.contains("way -11") && w.contains("zero length")), "{w:?}");
    assert!(w.iter().any(|w| w.contains("way -11 repeats node -3")), "{w:?}");
}

#[test]
fn a_bound_crossing_itself_is_a_warning_naming_the_way_and_node() {
    let nodes = format!(
        "{NODES}  <node id=\"-5\" lat=\"59.00006\" lon=\"17.0005\" />\n  <node id=\"-6\" lat=\"58.99994\" lon=\"17.0005\" />\n"
    );
    // -3 -> -4 -> -6 -> -5: the last segment crosses the first.
    let ways = WAYS.replace(
        "<nd ref=\"-4\" />\n  </way>",
        "<nd ref=\"-4\" />\n    <nd ref=\"-6\" />\n    <nd ref=\"-5\" />\n  </way>",
    );
    let w = warnings(&osm(&format!("{nodes}{ways}{LANELET}")));
    assert!(w.iter().any(|w| w.contains("way -11 crosses itself near node -6")), "{w:?}");
}

#[test]
fn a_latitude_typo_is_named_by_its_node() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/sml2015/HighwaySML.xml");
    let text = std::fs::read_to_string(&path).expect("../shared/data/sml2015/HighwaySML.xml");
    let clean = load(&text).unwrap();
    assert!(clean.warnings.is_empty(), "{:?}", clean.warnings);
    // A bound node of a lanelet with its latitude mistyped by 0.9 degrees (~100 km).
    let lanelet = &clean.lanelets[0];
    let victim = lanelet.right_nodes[lanelet.right_nodes.len() / 2];
    let node = clean.nodes[&victim].clone();
    let lat = format!("{}", node.lat);
    let needle = format!("id='{victim}'");
    let line = text.lines().find(|l| l.contains(&needle) && l.contains("<node")).expect("the node's line");
    let (start, _) = line.split_once("lat='").expect("lat attribute");
    let old_lat: String = line[start.len() + 5..].chars().take_while(|c| *c != '\'').collect();
    assert!((old_lat.parse::<f64>().unwrap() - node.lat).abs() < 1e-9, "{old_lat} vs {lat}");
    let typo = text.replacen(line, &line.replace(&format!("lat='{old_lat}'"), &format!("lat='{}'", node.lat + 0.9)), 1);
    let w = warnings(&typo);
    assert!(w.iter().any(|w| w.contains(&format!("node {victim} lies")) && w.contains("misplaced")), "{w:?}");
}

#[test]
fn polar_latitudes_and_the_antimeridian_are_errors_naming_the_node() {
    let polar = NODES.replace("lat=\"59.00003\" lon=\"17.001\"", "lat=\"85.5\" lon=\"17.001\"");
    error(&osm(&format!("{polar}{WAYS}{LANELET}")), &["node -4", "85.5", "UTM"]);
    let across = NODES.replace("lon=\"17.0\"", "lon=\"179.9999\"").replace("lon=\"17.001\"", "lon=\"-179.9999\"");
    error(&osm(&format!("{across}{WAYS}{LANELET}")), &["antimeridian", "node"]);
}

#[test]
fn an_origin_at_180_degrees_east_keeps_lengths() {
    // The lanelet ends at exactly 180 degrees east, the origin tagged there.
    let nodes = NODES.replace("lon=\"17.0\"", "lon=\"179.999\"").replace("lon=\"17.001\"", "lon=\"180.0\"").replace(
        "<node id=\"-2\" lat=\"59.0\" lon=\"180.0\" />",
        "<node id=\"-2\" lat=\"59.0\" lon=\"180.0\">\n    <tag k=\"origin\" v=\"true\" />\n  </node>",
    );
    let map = load(&osm(&format!("{nodes}{WAYS}{LANELET}"))).unwrap();
    assert_eq!(map.projector.zone, 60);
    // 0.001 degrees of longitude at 59 N: 57.4 m.
    let expected = 0.001_f64.to_radians() * 6_378_137.0 * 59f64.to_radians().cos();
    assert!((map.lanelets[0].length - expected).abs() < 0.5, "{} vs {expected}", map.lanelets[0].length);
}
