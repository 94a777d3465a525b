//! Generated maps: shipped files match the generator, parameters are checked, and the maps
//! round-trip through the loader with analytic counts, lengths and routes.

use std::path::{Path, PathBuf};

use smlworld::map::generate::{
    self, grid_city, intersection, ring_highway, GenerateError, GridParams, IntersectionParams, RingParams,
};
use smlworld::map::osm::parse_osm;

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
    let cases: [(&str, String); 4] = [
        ("maps/highway_ring.osm", ring_highway(&RingParams::default()).expect("defaults are valid")),
        (
            "maps/intersection3.osm",
            intersection(&IntersectionParams { arms: 3, ..IntersectionParams::default() }).expect("valid"),
        ),
        (
            "maps/intersection4.osm",
            intersection(&IntersectionParams { arms: 4, ..IntersectionParams::default() }).expect("valid"),
        ),
        ("maps/grid_3x3.osm", grid_city(&GridParams::default()).expect("defaults are valid")),
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
    let origins: Vec<_> = doc.nodes.values().filter(|n| n.tags.get("origin").map(String::as_str) == Some("true")).collect();
    assert_eq!(origins.len(), 1);
    assert_eq!((origins[0].lat, origins[0].lon), (generate::ORIGIN_LAT, generate::ORIGIN_LON));
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
    assert_eq!(name(intersection(&IntersectionParams { arm_length: f64::INFINITY, ..IntersectionParams::default() })), "arm_length");
    assert_eq!(name(grid_city(&GridParams { rows: 0, ..GridParams::default() })), "rows");
    // Junctions reach 3.5 + 6 = 9.5 m from their centre: blocks of 19 m leave no street.
    assert_eq!(name(grid_city(&GridParams { block: 19.0, ..GridParams::default() })), "block");
    assert!(grid_city(&GridParams { block: 19.5, ..GridParams::default() }).is_ok());
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
