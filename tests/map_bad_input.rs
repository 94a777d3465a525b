//! Bad map input: each broken file gives a clear error naming the file, the line and the id;
//! recoverable problems load with warnings. Nothing panics.

use std::path::{Path, PathBuf};

use smlworld::map::{LaneletMap, MapError};

fn bad(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/bad_maps").join(name)
}

/// Load `name` expecting an error whose message contains every one of `needles`.
fn expect_error(name: &str, needles: &[&str]) -> MapError {
    let err = LaneletMap::load(&bad(name)).expect_err(name);
    let msg = err.to_string();
    assert!(msg.contains(name), "{name}: the message names the file: {msg}");
    for n in needles {
        assert!(msg.contains(n), "{name}: expected {n:?} in: {msg}");
    }
    err
}

#[test]
fn malformed_xml_names_the_line() {
    let e = expect_error("broken_xml.osm", &["malformed XML", "broken_xml.osm:4"]);
    assert!(matches!(e, MapError::Xml { .. }));
    let e = expect_error("mismatched_end.osm", &["malformed XML", "mismatched_end.osm:5"]);
    assert!(matches!(e, MapError::Xml { .. }));
}

#[test]
fn way_with_a_missing_node() {
    let e = expect_error("missing_node.osm", &["missing_node.osm:9", "way -11", "node -99"]);
    assert!(matches!(e, MapError::MissingNode { way: -11, node: -99, .. }));
}

#[test]
fn lanelet_with_a_missing_way() {
    let e = expect_error("missing_way.osm", &["missing_way.osm:9", "lanelet -20", "way -77", "`left`"]);
    assert!(matches!(e, MapError::MissingWay { lanelet: -20, way: -77, .. }));
}

#[test]
fn bad_coordinates() {
    expect_error("bad_lat.osm", &["bad_lat.osm:4", "node -2", "`lat`", "fifty-nine", "not a number"]);
    expect_error("lon_out_of_range.osm", &["lon_out_of_range.osm:4", "node -2", "`lon`", "181.5", "-180..=180"]);
    expect_error("missing_lat.osm", &["missing_lat.osm:3", "node -1", "`lat`", "missing"]);
}

#[test]
fn duplicate_ids() {
    let e = expect_error("duplicate_node.osm", &["duplicate_node.osm:5", "duplicate node id -1", "line 3"]);
    assert!(matches!(e, MapError::DuplicateId { id: -1, first_line: 3, .. }));
    expect_error("duplicate_way.osm", &["duplicate_way.osm:9", "duplicate way id -10", "line 5"]);
}

#[test]
fn empty_and_foreign_files() {
    let e = expect_error("empty.osm", &["empty"]);
    assert!(matches!(e, MapError::Empty(_)));
    expect_error("not_osm.xml", &["no <osm> root"]);
    let e = LaneletMap::load(&bad("does_not_exist.osm")).unwrap_err();
    assert!(matches!(e, MapError::Io { .. }) && e.to_string().contains("does_not_exist.osm"), "{e}");
}

#[test]
fn bad_ids_and_references() {
    expect_error("bad_id.osm", &["bad_id.osm:3", "`id`", "\"n1\"", "integer"]);
    expect_error("bad_nd_ref.osm", &["bad_nd_ref.osm:6", "way -10", "`ref`", "\"1.5\""]);
    expect_error(
        "bad_member_type.osm",
        &["bad_member_type.osm:5", "relation -20", "`type`", "\"area\"", "node, way, relation"],
    );
    expect_error("tag_without_key.osm", &["tag_without_key.osm:4", "`k`", "missing"]);
}

#[test]
fn recoverable_problems_are_warnings() {
    let map = LaneletMap::load(&bad("warnings.osm")).expect("loads despite the warnings");
    assert_eq!(map.lanelets.len(), 1, "only the complete lanelet -22 remains");
    let text: Vec<String> = map.warnings.iter().map(ToString::to_string).collect();
    let has = |needle: &str| text.iter().any(|w| w.contains(needle));
    assert!(has("lanelet -20 has no members"), "{text:#?}");
    assert!(has("lanelet -21 has no left bound"), "{text:#?}");
    assert!(has("relation -23 has no `type` tag"), "{text:#?}");
    assert!(text.iter().all(|w| w.contains("warnings.osm:")), "warnings name file and line: {text:#?}");
    assert!(has("way -11: unknown line_type `rainbow`"), "{text:#?}");
    assert_eq!(map.warnings.len(), 4);
}
