//! Lanelet map: lanelets with bounds in metres, centre lines, lengths, successors and all tags.

use std::collections::BTreeMap;

use glam::DVec2;

use super::error::MapWarning;
use super::graph::{GraphLanelet, RoutingGraph};
use super::projection::Projector;

/// Id of a lanelet: the id of its `type=lanelet` relation in the OSM file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize)]
pub struct LaneletId(pub i64);

impl std::fmt::Display for LaneletId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// `line_type` values the SML maps use: lines (`exterior` yellow, `interior` white) and areas.
/// Any other value loads with a warning and is drawn as an untagged way.
pub const KNOWN_LINE_TYPES: [&str; 7] =
    ["exterior", "interior", "free_space", "parking_lot", "pile_stuff", "mud", "iron"];

/// Tags of an OSM object, key -> value, in key order.
pub type Tags = BTreeMap<String, String>;

/// A node projected to local metres.
#[derive(Debug, Clone, PartialEq)]
pub struct MapNode {
    /// OSM node id (negative for objects JOSM has not uploaded).
    pub id: i64,
    /// Latitude \[deg\].
    pub lat: f64,
    /// Longitude \[deg\].
    pub lon: f64,
    /// Local position \[m\], x east, y north, relative to the map origin.
    pub position: DVec2,
    /// All tags of the node.
    pub tags: Tags,
}

/// A way (polyline) projected to local metres: lane markings, road borders, areas.
#[derive(Debug, Clone, PartialEq)]
pub struct MapWay {
    /// OSM way id.
    pub id: i64,
    /// Node ids in drawn order.
    pub nodes: Vec<i64>,
    /// Node positions \[m\] in drawn order.
    pub points: Vec<DVec2>,
    /// All tags of the way (`line_type`, `region`, `type`, `subtype`, ...).
    pub tags: Tags,
}

impl MapWay {
    /// A closed way (first node = last node, at least 4 refs) describes an area.
    pub fn is_closed(&self) -> bool {
        self.nodes.len() >= 4 && self.nodes.first() == self.nodes.last()
    }

    /// The way's `line_type` tag, else its `region` tag (the SML maps use both for areas).
    pub fn line_type(&self) -> Option<&str> {
        self.tags.get("line_type").or_else(|| self.tags.get("region")).map(String::as_str)
    }
}

/// One lanelet: a drivable lane segment between a left and a right bound.
///
/// All geometry is in the driving direction: `left[k]` and `right[k]` are paired points (after
/// resampling bounds with different node counts), `centre[k]` is their midpoint.
#[derive(Debug, Clone, PartialEq)]
pub struct Lanelet {
    /// Relation id.
    pub id: LaneletId,
    /// Way id of the left bound.
    pub left_way: i64,
    /// Way id of the right bound.
    pub right_way: i64,
    /// Node ids of the left bound, in driving direction (as drawn, or reversed).
    pub left_nodes: Vec<i64>,
    /// Node ids of the right bound, in driving direction.
    pub right_nodes: Vec<i64>,
    /// Left bound \[m\], in driving direction, same length as `right` and `centre`.
    pub left: Vec<DVec2>,
    /// Right bound \[m\], in driving direction.
    pub right: Vec<DVec2>,
    /// Centre line \[m\]: midpoints of the paired bounds.
    pub centre: Vec<DVec2>,
    /// Length of the centre line \[m\].
    pub length: f64,
    /// Lanelets that follow this one in its driving direction.
    pub successors: Vec<LaneletId>,
    /// Whether a vehicle may drive here (Lanelet2 traffic rules: not a crosswalk, walkway, ...).
    pub routable: bool,
    /// `one_way=no`: vehicles may also drive it against its direction.
    pub bidirectional: bool,
    /// All tags of the relation (`type`, `subtype`, `truck_lane`, ...).
    pub tags: Tags,
}

impl Lanelet {
    /// What the routing graph needs of this lanelet.
    pub(crate) fn graph_view(&self) -> GraphLanelet<'_> {
        GraphLanelet {
            routable: self.routable,
            bidirectional: self.bidirectional,
            right_nodes: &self.right_nodes,
            left_nodes: &self.left_nodes,
            length: self.length,
            centre_ends: (
                self.centre.first().copied().unwrap_or_default(),
                self.centre.last().copied().unwrap_or_default(),
            ),
        }
    }

    /// Its speed limit [m/s], from the `speed_limit` tag in km/h as Lanelet2 writes it
    /// (`"100"` or `"100 km/h"`; the OpenDRIVE and SUMO readers write it so); `None` without
    /// one or when it does not read as a positive number.
    pub fn speed_limit(&self) -> Option<f64> {
        let v: f64 = self.tags.get("speed_limit")?.trim().trim_end_matches("km/h").trim().parse().ok()?;
        (v > 0.0 && v.is_finite()).then_some(v / 3.6)
    }

    /// Polygon of the lanelet: left bound followed by the reversed right bound.
    pub fn polygon(&self) -> Vec<DVec2> {
        self.left.iter().chain(self.right.iter().rev()).copied().collect()
    }
}

/// One phase of a signal program: a state (one character per link) held for `duration` \[s\].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SignalPhase {
    /// One character per link in link order: `G` green with priority, `g` green yielding, `y`
    /// yellow, `r` red.
    pub state: String,
    /// How long it is held \[s\].
    pub duration: f64,
}

/// A signal program stated by the map file (a SUMO `<tlLogic>`): phases whose states have one
/// character per signal index (the `signal_index` tag of the links it controls).
#[derive(Debug, Clone, PartialEq)]
pub struct MapSignalProgram {
    /// The phases in file order.
    pub phases: Vec<SignalPhase>,
    /// Cycle shift \[s\].
    pub offset: f64,
}

/// A loaded lanelet map: everything the simulator, router and renderer need, in metres.
#[derive(Debug, Clone)]
pub struct LaneletMap {
    /// Projection between lat/lon and local metres.
    pub projector: Projector,
    /// Id of the node tagged `origin=true`, if any (else the origin is the mean of all nodes).
    pub origin_node: Option<i64>,
    /// All nodes by id.
    pub nodes: BTreeMap<i64, MapNode>,
    /// All ways by id.
    pub ways: BTreeMap<i64, MapWay>,
    /// Lanelets, sorted by id.
    pub lanelets: Vec<Lanelet>,
    /// Node tag value -> ids of the nodes carrying it (`destination=left_lane_node` -> `left_lane_node`).
    pub tag_index: BTreeMap<String, Vec<i64>>,
    /// Recoverable problems found while loading.
    pub warnings: Vec<MapWarning>,
    /// Regulatory elements (Lanelet2 `type=regulatory_element` relations: traffic lights,
    /// right of way, speed limits, ...), by relation id; empty for formats without them.
    pub regulatory: BTreeMap<i64, RegulatoryElement>,
    /// Signal programs the map file gives (SUMO `<tlLogic>`), by program id; a junction link
    /// lanelet names its program and its character in the states with the tags
    /// `signal_program` and `signal_index` (`junctions::map_program`).
    pub signal_programs: BTreeMap<String, MapSignalProgram>,
    /// The junctions under the default rules, found on first use ([`LaneletMap::junctions`]);
    /// held type-erased so this data module does not import the junction logic built on it.
    pub(crate) junctions: std::sync::OnceLock<std::sync::Arc<dyn std::any::Any + Send + Sync>>,
    pub(crate) index: BTreeMap<LaneletId, usize>,
    pub(crate) graph: RoutingGraph,
}

/// A Lanelet2 regulatory element: what it is (`subtype`), the lanelets it names by role
/// (`right_of_way`, `yield`) and the lanelets that refer to it (their `regulatory_element`
/// members), so the junction rules can read who has right of way and which lanes a light controls.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RegulatoryElement {
    /// Relation id.
    pub id: i64,
    /// `subtype` tag (`traffic_light`, `right_of_way`, `traffic_sign`, `all_way_stop`, ...).
    pub subtype: String,
    /// All tags of the relation.
    pub tags: Tags,
    /// Lanelet members with their role (`right_of_way`, `yield`, ...), in file order.
    pub lanelet_roles: Vec<(LaneletId, String)>,
    /// Way members with their role (`refers`, `ref_line`, ...), in file order.
    pub way_roles: Vec<(i64, String)>,
    /// Lanelets that carry this element as a `regulatory_element` member, in id order.
    pub lanelets: Vec<LaneletId>,
}

impl LaneletMap {
    /// A map from lanelets whose successors the source file states (CommonRoad, OpenDRIVE,
    /// SUMO): the id index and the routing graph are built here from each lanelet's
    /// `successors` (successors naming no lanelet are dropped from the graph). No origin node,
    /// no regulatory elements and no signal programs; set those fields after where a format has them.
    pub fn from_parts(
        projector: Projector,
        nodes: BTreeMap<i64, MapNode>,
        ways: BTreeMap<i64, MapWay>,
        lanelets: Vec<Lanelet>,
        tag_index: BTreeMap<String, Vec<i64>>,
        warnings: Vec<MapWarning>,
    ) -> LaneletMap {
        let index: BTreeMap<LaneletId, usize> = lanelets.iter().enumerate().map(|(i, l)| (l.id, i)).collect();
        let explicit: Vec<Vec<usize>> =
            lanelets.iter().map(|l| l.successors.iter().filter_map(|s| index.get(s).copied()).collect()).collect();
        let graph_lanelets: Vec<GraphLanelet<'_>> = lanelets.iter().map(Lanelet::graph_view).collect();
        let graph = RoutingGraph::with_successors(&graph_lanelets, &explicit);
        drop(graph_lanelets);
        LaneletMap {
            projector,
            origin_node: None,
            nodes,
            ways,
            lanelets,
            tag_index,
            warnings,
            regulatory: BTreeMap::new(),
            signal_programs: BTreeMap::new(),
            junctions: Default::default(),
            index,
            graph,
        }
    }

    /// The lanelet with this id.
    pub fn lanelet(&self, id: LaneletId) -> Option<&Lanelet> {
        self.index.get(&id).map(|&i| &self.lanelets[i])
    }

    /// Index of the lanelet with this id in [`LaneletMap::lanelets`].
    pub fn lanelet_index(&self, id: LaneletId) -> Option<usize> {
        self.index.get(&id).copied()
    }
}
