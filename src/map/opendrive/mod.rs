//! OpenDRIVE (`.xodr`, ASAM OpenDRIVE 1.4-1.8) -> a [`LaneletMap`].
//!
//! What is read:
//! - the reference line of every road (`planView`: `line`, `arc`, `spiral`, `poly3`,
//!   `paramPoly3` with `pRange` `arcLength` or `normalized`; see [`geometry`]);
//! - `laneOffset`, lane sections, lane `width` polynomials (`border` where a lane has no
//!   `width`), left and right lanes, `rule="LHT"` (left-hand traffic: left lanes run along `s`);
//! - each lane of each lane section becomes one lanelet, its bounds sampled along `s` so that
//!   the chord error of every border is at most 2 cm ([`build::CHORD_ERROR`]), with tags
//!   `opendrive:road`, `opendrive:section` (0-based index in the road), `opendrive:lane`,
//!   `opendrive:type` and `opendrive:junction` (`-1` outside junctions); lane types `driving`,
//!   `entry`, `exit`, `onRamp`, `offRamp`, `connectingRamp` and `bidirectional` are routable, the
//!   others (sidewalk, shoulder, border, parking, median ...) are kept and drawn but never
//!   routed through;
//! - lane sections shorter than [`MIN_SECTION`] (CARLA's files have hundreds, down to 0.1 µm)
//!   are merged into the section before them (the first one into the one after it), their lane
//!   links carried over, so no lanelet has a bound of next to no length;
//! - lanelet successors from lane `predecessor`/`successor` links between lane sections, road
//!   links with `contactPoint`, and junction `connection`/`laneLink`s (never from geometry);
//! - neighbours: adjacent lanes share one border way (same node ids), so the map's
//!   [`LaneletMap::neighbours`] finds them; the way carries the `roadMark` as a Lanelet2 line
//!   (`broken` -> `dashed`, `solid`, `solid broken` -> one way, `laneChange` deciding where given);
//! - `speed` records (lane, else road `type`) as the `speed_limit` tag [km/h]; left-hand roads
//!   carry `driving_side=left`;
//! - road `<signal>`s and `<signalReference>`s, top-level `<controller>`s and the junctions'
//!   `<controller>` and `<priority>` elements, as what [`crate::map::junctions`] reads
//!   ([`signals`]): traffic lights on the connecting lanelets their lanes enter, one signal group
//!   per controller, with a fixed-time program per junction
//!   ([`LaneletMap::signal_programs`]); stop, yield and priority signs and `<priority high low>`
//!   as `priority=minor|major`. A junction that names controllers none of whose lights face a
//!   lane entering it gets `traffic_light=yes` on its lanelets (the default program);
//! - `header/geoReference` `+lat_0`/`+lon_0` as the projection origin; local metres (origin 0, 0)
//!   when there is none.
//!
//! The first and last node of each lanelet's right bound carry the tag values
//! `start:ROAD:SECTION:LANE` and `end:ROAD:SECTION:LANE` ([`lane_tag`]), so `map route
//! --from-lane ROAD:LANE --to-lane ROAD:LANE` and a scenario's `{ road = "5", lane = -1 }` reach them.
//!
//! [`osm_out::write_osm`] writes the built map as Lanelet2 OSM (`smlworld map convert`).
//!
//! Everything else (elevation, lateral profile, objects, user data, road mark line details, ...)
//! gives one warning per element name with its first line, and each signal type that means
//! nothing here (pedestrian lights, crosswalks, speed limit signs, ...) one warning per type. Missing `planView`,
//! an unknown geometry, a negative length or a link to a missing road or junction are
//! [`MapError::OpenDrive`] errors naming the line and id.
//!
//! No crate was used for parsing: the package lists this project may install from showed no
//! Rust OpenDRIVE crate (only Python ones: `pyxodr`, ...), and errors and warnings here must name
//! the file's line, which quick-xml gives us; the tree in `xml` is the same small reader the
//! CommonRoad module uses.

mod build;
pub mod geometry;
pub mod osm_out;
pub mod road;
pub mod signals;
pub(crate) mod xml;

use std::path::Path as FsPath;

pub use build::{CHORD_ERROR, DRIVABLE, MAX_STEP, MIN_SECTION, MIN_STEP};

use super::error::MapError;
use super::lanelet::LaneletMap;

/// Whether `text` is an OpenDRIVE file (its root element is `<OpenDRIVE>`).
pub fn is_opendrive(text: &str) -> bool {
    let mut reader = quick_xml::Reader::from_str(text);
    loop {
        match reader.read_event() {
            Ok(quick_xml::events::Event::Start(e) | quick_xml::events::Event::Empty(e)) => {
                return e.name().as_ref() == "OpenDRIVE";
            }
            Ok(quick_xml::events::Event::Eof) | Err(_) => return false,
            Ok(_) => {}
        }
    }
}

/// Parse OpenDRIVE text into a lanelet map; `source` names the file in messages.
pub fn parse_str(text: &str, source: &FsPath) -> Result<LaneletMap, MapError> {
    let root = xml::parse_tree(text, source)?;
    let mut reader = road::Reader::new(source);
    let mut doc = reader.document(&root)?;
    build::merge_short_sections(&mut doc);
    build::build(&doc, &root, source, reader.warnings())
}

/// Parse OpenDRIVE text into the model (roads, lane sections, junctions) without building
/// lanelets: for tests and tools that need the file's own numbers.
pub fn parse_document(text: &str, source: &FsPath) -> Result<road::Document, MapError> {
    let root = xml::parse_tree(text, source)?;
    road::Reader::new(source).document(&root)
}

/// The node tag value at the start (or, with `end`, the end) of the lanelet of lane `lane` in
/// lane section `section` (0-based) of road `road`: what `map route --from-lane` and a
/// scenario's `{ road, lane }` route to.
pub fn lane_tag(road: &str, section: usize, lane: i32, end: bool) -> String {
    format!("{}:{road}:{section}:{lane}", if end { "end" } else { "start" })
}

/// Parse `ROAD:LANE` or `ROAD:SECTION:LANE` (section 0-based; without it the road's first lane
/// section) into the node tag value of the lane's start (or end).
pub fn lane_spec_tag(spec: &str, end: bool) -> Result<String, MapError> {
    let bad = || {
        MapError::InvalidOption(format!(
            "lane `{spec}`: expected ROAD:LANE or ROAD:SECTION:LANE (an OpenDRIVE road id, a lane section index from 0, a lane id such as -1)"
        ))
    };
    let parts: Vec<&str> = spec.split(':').collect();
    let (road, section, lane) = match parts.as_slice() {
        [road, lane] => (*road, "0", *lane),
        [road, section, lane] => (*road, *section, *lane),
        _ => return Err(bad()),
    };
    let section: usize = section.trim().parse().map_err(|_| bad())?;
    let lane: i32 = lane.trim().parse().map_err(|_| bad())?;
    if road.trim().is_empty() || lane == 0 {
        return Err(bad());
    }
    Ok(lane_tag(road.trim(), section, lane, end))
}
