//! Loaded maps pinned bit for bit: a digest of everything the loader builds (nodes, ways,
//! lanelets, tag index, warnings, the raw OSM document), of what the routing graph answers
//! (routable nodes, neighbours, routes) and of every bad map's error message, over the real maps,
//! the generated ones and the hand-made ones in `tests/bad_maps`. A faster loader must load
//! the same maps: the digests were taken with the loader before issue 25's speed-up.
//!
//! Debug formatting prints every `f64` as its shortest round-trip decimal, so two maps with the
//! same digest have the same bits. On a mismatch the test prints every digest it computed, to
//! be pasted here only when a change of the loaded map is meant.

mod common;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use smlworld::map::generate::{
    GridParams, IntersectionParams, LaneDropParams, RingParams, grid_city, intersection, lane_drop, ring_highway,
};
use smlworld::map::osm::parse_osm;
use smlworld::map::{LaneletMap, Place, RouteOptions, RouteSearch};

/// FNV-1a (64 bit) over formatted text: a digest without a dependency.
struct Fnv(u64);

impl std::fmt::Write for Fnv {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        for &b in s.as_bytes() {
            self.0 = (self.0 ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
        }
        Ok(())
    }
}

fn digest(write: impl FnOnce(&mut Fnv) -> std::fmt::Result) -> u64 {
    let mut h = Fnv(0xcbf2_9ce4_8422_2325);
    write(&mut h).expect("formatting into a hash cannot fail");
    h.0
}

/// The loaded map's public contents and what its routing graph answers.
fn map_digest(map: &LaneletMap) -> u64 {
    digest(|h| {
        write!(h, "{:?}{:?}{:?}", map.projector, map.origin_node, map.nodes)?;
        write!(h, "{:?}{:?}{:?}{:?}", map.ways, map.lanelets, map.tag_index, map.warnings)?;
        let nodes = map.routable_nodes();
        write!(h, "{nodes:?}{:?}", map.neighbours())?;
        // Up to 40 pairs spread over the routable nodes, both searches.
        let opts = RouteOptions::default();
        let step = (nodes.len() / 7).max(1);
        let picks: Vec<i64> = nodes.iter().step_by(step).copied().collect();
        for (k, &from) in picks.iter().enumerate() {
            for &to in picks.iter().skip(k + 1).take(3) {
                for search in [RouteSearch::AStar, RouteSearch::Dijkstra] {
                    let route = map.route_places_with(&Place::Node(from), &Place::Node(to), &opts, search);
                    write!(h, "{from}->{to}:{:?}", route.map(|p| (p.lanelets, p.length, p.points.len())))?;
                }
            }
        }
        Ok(())
    })
}

fn bad_maps() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/bad_maps");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&dir).expect("tests/bad_maps").map(|e| e.unwrap().path()).collect();
    files.sort();
    files
}

/// Every digest, as `name digest` lines.
fn digests() -> Vec<(String, u64)> {
    let mut out = Vec::new();
    for rel in [
        "sml2015/HighwaySML.xml",
        "sml2015/Intersection3Way.xml",
        "sml2015/RoadTemplates.xml",
        "lanelet2/mapping_example.osm",
    ] {
        // Parsed under the relative name: messages and warnings name the file, and the shared
        // data lies in another folder on another machine.
        let text = std::fs::read_to_string(common::shared(rel)).expect("readable");
        let map = LaneletMap::parse_str(&text, Path::new(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"));
        out.push((rel.to_string(), map_digest(&map)));
        let doc = parse_osm(&text, Path::new(rel)).expect("parses");
        out.push((format!("{rel} (osm)"), digest(|h| write!(h, "{doc:?}"))));
    }
    let generated = [
        ("grid", grid_city(&GridParams::default())),
        ("grid 8x8", grid_city(&GridParams { rows: 8, cols: 8, ..GridParams::default() })),
        // The map of `smlworld bench --routing` and `--map-load` (35 MB, read in two halves).
        ("grid 32x32", grid_city(&GridParams { rows: 32, cols: 32, ..GridParams::default() })),
        ("grid 2 lanes", grid_city(&GridParams { rows: 2, cols: 4, lanes: 2, ..GridParams::default() })),
        ("ring", ring_highway(&RingParams::default())),
        ("intersection", intersection(&IntersectionParams::default())),
        ("lane drop", lane_drop(&LaneDropParams::default())),
    ];
    for (name, text) in generated {
        let text = text.expect("valid parameters");
        let map = LaneletMap::parse_str(&text, Path::new(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        out.push((name.to_string(), map_digest(&map)));
    }
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/bad_maps");
    for path in bad_maps() {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        // Loaded from the file (the path the loader reads); the checkout's folder left out of
        // the messages.
        let d = match LaneletMap::load(&path) {
            Ok(_) => {
                let text = std::fs::read_to_string(&path).expect("readable");
                map_digest(&LaneletMap::parse_str(&text, Path::new(&name)).expect("loads from text too"))
            }
            Err(e) => digest(|h| write!(h, "{}", e.to_string().replace(&format!("{}/", dir.display()), ""))),
        };
        out.push((format!("bad_maps/{name}"), d));
    }
    out
}

const EXPECTED: &[(&str, u64)] = &[
    ("sml2015/HighwaySML.xml", 0x45b13af526b3cd11),
    ("sml2015/HighwaySML.xml (osm)", 0x399bba6a93b6850c),
    ("sml2015/Intersection3Way.xml", 0x542d8b67617b0974),
    ("sml2015/Intersection3Way.xml (osm)", 0x5d33b233b6c2f292),
    ("sml2015/RoadTemplates.xml", 0x2cb5d871f9852f05),
    ("sml2015/RoadTemplates.xml (osm)", 0xaeb1021a2196cf22),
    ("lanelet2/mapping_example.osm", 0xb6893693e5c77465),
    ("lanelet2/mapping_example.osm (osm)", 0xb736d84953f4ddd8),
    ("grid", 0x2ad4c1c5702083e1),
    ("grid 8x8", 0xa5ef5fad541bc863),
    ("grid 32x32", 0xde1b15dc38bf5acb),
    ("grid 2 lanes", 0x8993c982ff050726),
    ("ring", 0x8a7f82c69ccf027f),
    ("intersection", 0x13cc079ea76dded6),
    ("lane drop", 0xc863409c5202321a),
    ("bad_maps/bad_id.osm", 0x2a8f6d320f34d7eb),
    ("bad_maps/bad_lat.osm", 0xc54bb06792f00c9c),
    ("bad_maps/bad_member_type.osm", 0xd77074b74d6ec7cc),
    ("bad_maps/bad_nd_ref.osm", 0x91d6b7172d6ea866),
    ("bad_maps/broken_xml.osm", 0x70ece2b6bf3a8b9d),
    ("bad_maps/duplicate_node.osm", 0x668d8c50ac9b3a43),
    ("bad_maps/duplicate_way.osm", 0x1db04304d41ff557),
    ("bad_maps/empty.osm", 0xdc1212f1d43d9d9f),
    ("bad_maps/lon_out_of_range.osm", 0x0fbde4a3311fc692),
    ("bad_maps/mismatched_end.osm", 0xdd7a65e1a34611e8),
    ("bad_maps/missing_lat.osm", 0xee72c1ee5e006468),
    ("bad_maps/missing_node.osm", 0x750e34f7c62c6ce6),
    ("bad_maps/missing_way.osm", 0x8cefc9012e153c4f),
    ("bad_maps/not_osm.xml", 0x45336f50e65540ae),
    ("bad_maps/tag_without_key.osm", 0x382913cbd23ab106),
    ("bad_maps/warnings.osm", 0x539a6dc5e48b77bc),
];

#[test]
fn loaded_maps_match_their_digests() {
    let got = digests();
    let listing: String = got.iter().map(|(name, d)| format!("    (\"{name}\", {d:#018x}),\n")).collect();
    let expected: Vec<(String, u64)> = EXPECTED.iter().map(|&(n, d)| (n.to_string(), d)).collect();
    let differ: Vec<&str> = got.iter().zip(&expected).filter(|(g, e)| g != e).map(|(g, _)| g.0.as_str()).collect();
    assert!(
        got.len() == expected.len() && differ.is_empty(),
        "loaded maps differ from their digests ({differ:?}); all digests now:\n{listing}"
    );
}
