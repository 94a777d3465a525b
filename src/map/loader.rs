//! Building a [`LaneletMap`] from an [`OsmDocument`]: projection, bound orientation, resampling,
//! centre lines, successors and the traffic rules that decide what a vehicle may drive.

use std::collections::BTreeMap;
use std::path::Path as FsPath;

use glam::DVec2;
use rayon::prelude::*;

use super::error::{Location, MapError, MapWarning};
use super::geometry_checks;
use super::graph::{GraphLanelet, RoutingGraph};
use super::lanelet::{KNOWN_LINE_TYPES, Lanelet, LaneletId, LaneletMap, MapNode, MapWay, RegulatoryElement, Tags};
use super::osm::{IdIndex, MemberType, OsmDocument, OsmNode, OsmObjects, OsmRelation, OsmWay, parse_objects};
use super::polyline::{polyline_length, resample_count};
use super::projection::Projector;

impl LaneletMap {
    /// Load a JOSM/OSM map (`.osm` or `.xml`), the road network of a CommonRoad scenario
    /// file (root element `<commonRoad>`, see [`super::commonroad`]), or an OpenDRIVE file
    /// (`.xodr`, or root element `<OpenDRIVE>`, see [`super::opendrive`]), or a SUMO network
    /// (root element `<net>`, `x.net.xml`, see [`super::sumo`]).
    pub fn load(path: &FsPath) -> Result<LaneletMap, MapError> {
        let text = std::fs::read_to_string(path).map_err(|source| MapError::Io { path: path.to_path_buf(), source })?;
        if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("xodr")) || super::opendrive::is_opendrive(&text) {
            return super::opendrive::parse_str(&text, path);
        }
        if super::commonroad::is_commonroad(&text) {
            return Ok(super::commonroad::CommonRoadScenario::parse_str(&text, path)?.map);
        }
        if super::sumo::is_sumo_net(&text) {
            return super::sumo::parse_str(&text, path);
        }
        let objects = parse_objects(&text, path)?;
        drop(text);
        build(objects)
    }

    /// Parse OSM XML text (or OpenDRIVE text, root element `<OpenDRIVE>`); `name` stands for
    /// the file in messages.
    pub fn parse_str(text: &str, name: &FsPath) -> Result<LaneletMap, MapError> {
        if super::opendrive::is_opendrive(text) {
            return super::opendrive::parse_str(text, name);
        }
        if super::sumo::is_sumo_net(text) {
            return super::sumo::parse_str(text, name);
        }
        build(parse_objects(text, name)?)
    }

    /// Build the lanelet map from a raw OSM document.
    pub fn from_osm(doc: &OsmDocument) -> Result<LaneletMap, MapError> {
        build(OsmObjects::from_document(doc))
    }
}

/// Node tag keys whose values are not names a user would route to (so not indexed by value).
const UNINDEXED_NODE_KEYS: [&str; 6] = ["origin", "ele", "x", "y", "local_x", "local_y"];

/// Lanelet `subtype`s that Lanelet2's vehicle traffic rules do not let a vehicle drive.
const NON_VEHICLE_SUBTYPES: [&str; 4] = ["crosswalk", "walkway", "bicycle_lane", "stairs"];

/// A way with what the lanelet stage needs beside it.
struct WayEntry {
    way: MapWay,
    /// Line of the way in the file.
    line: usize,
    /// Length of its polyline [m], computed once for all the lanelets that share the way.
    length: f64,
    /// Whether its repeats and self-crossings have been reported.
    checked: bool,
}

/// The loading stages in order: projection and origin, then two halves that need nothing of
/// each other side by side on the thread pool (the nodes with their tag index; the ways, the
/// lanelets built on them, successors and the routing graph). Every stage is deterministic
/// and the halves write nothing shared, so the map is the same on any number of threads. The
/// objects are consumed: tags and node lists move into the map instead of being copied.
fn build(doc: OsmObjects) -> Result<LaneletMap, MapError> {
    let mut warnings = Vec::new();
    check_coordinates(&doc)?;
    let (projector, origin_node) = origin(&doc, &mut warnings)?;

    // Every node projected once, each on its own (so in parallel); the ways read the positions
    // by index, not through the node map.
    let positions: Vec<DVec2> =
        doc.nodes.par_iter().with_min_len(1 << 12).map(|n| projector.forward(n.lat, n.lon)).collect();
    let OsmObjects { source, nodes: osm_nodes, ways, relations, node_index } = doc;
    let ((nodes, tag_index), network) =
        rayon::join(|| node_map(osm_nodes, &positions), || network(&source, ways, relations, &positions, &node_index));
    let Network { ways, lanelets, index, graph, regulatory, warnings: network_warnings } = network?;
    warnings.extend(network_warnings);
    Ok(LaneletMap {
        projector,
        origin_node,
        nodes,
        ways,
        lanelets,
        tag_index,
        warnings,
        regulatory,
        signal_programs: BTreeMap::new(),
        junctions: Default::default(),
        index,
        graph,
    })
}

/// The node map (tags moved in) and the index of node tag values.
fn node_map(osm_nodes: Vec<OsmNode>, positions: &[DVec2]) -> (BTreeMap<i64, MapNode>, BTreeMap<String, Vec<i64>>) {
    let mut tag_index: BTreeMap<String, Vec<i64>> = BTreeMap::new();
    for n in &osm_nodes {
        for (k, v) in &n.tags {
            if !UNINDEXED_NODE_KEYS.contains(&k.as_str()) {
                tag_index.entry(v.clone()).or_default().push(n.id);
            }
        }
    }
    let nodes = osm_nodes
        .into_iter()
        .zip(positions)
        .map(|(n, &position)| (n.id, MapNode { id: n.id, lat: n.lat, lon: n.lon, position, tags: n.tags }))
        .collect();
    (nodes, tag_index)
}

/// What [`network`] builds.
struct Network {
    ways: BTreeMap<i64, MapWay>,
    lanelets: Vec<Lanelet>,
    index: BTreeMap<LaneletId, usize>,
    graph: RoutingGraph,
    regulatory: BTreeMap<i64, RegulatoryElement>,
    warnings: Vec<MapWarning>,
}

/// Ways (in metres), lanelets, successors and the routing graph, with their warnings in order.
fn network(
    source: &FsPath,
    osm_ways: Vec<OsmWay>,
    relations: Vec<OsmRelation>,
    positions: &[DVec2],
    node_index: &IdIndex,
) -> Result<Network, MapError> {
    let mut warnings = Vec::new();
    let at = |line: usize| Location { file: source.to_path_buf(), line };
    let mut ways = Vec::with_capacity(osm_ways.len());
    for w in osm_ways {
        // osm::parse_objects has already checked that every node exists.
        let points: Vec<DVec2> = w
            .nodes
            .iter()
            .map(|&id| positions[node_index.get(id).expect("osm::parse_objects checked every way node")])
            .collect();
        if let Some(t) = w.tags.get("line_type").filter(|t| !KNOWN_LINE_TYPES.contains(&t.as_str())) {
            warnings.push(MapWarning {
                at: at(w.line).to_string(),
                message: format!(
                    "way {}: unknown line_type `{t}` (known: {}); drawn as an untagged way",
                    w.id,
                    KNOWN_LINE_TYPES.join(", ")
                ),
            });
        }
        let length = polyline_length(&points);
        ways.push(WayEntry {
            way: MapWay { id: w.id, nodes: w.nodes, points, tags: w.tags },
            line: w.line,
            length,
            checked: false,
        });
    }

    let way_index = IdIndex::new(ways.iter().map(|w| w.way.id));
    let mut lanelets = Vec::new();
    let mut regulatory: BTreeMap<i64, RegulatoryElement> = BTreeMap::new();
    let mut refers_to: Vec<(i64, LaneletId)> = Vec::new();
    for r in relations {
        match r.tags.get("type").map(String::as_str) {
            Some("lanelet") => {
                let id = LaneletId(r.id);
                let refs: Vec<i64> = r
                    .members
                    .iter()
                    .filter(|m| m.kind == MemberType::Relation && m.role == "regulatory_element")
                    .map(|m| m.reference)
                    .collect();
                if let Some(l) = lanelet(&at, r, &mut ways, &way_index, &mut warnings)? {
                    lanelets.push(l);
                    refers_to.extend(refs.into_iter().map(|re| (re, id)));
                }
            }
            Some("regulatory_element") => {
                let mut re = RegulatoryElement {
                    id: r.id,
                    subtype: r.tags.get("subtype").cloned().unwrap_or_default(),
                    ..RegulatoryElement::default()
                };
                for m in &r.members {
                    match m.kind {
                        MemberType::Relation => re.lanelet_roles.push((LaneletId(m.reference), m.role.clone())),
                        MemberType::Way => re.way_roles.push((m.reference, m.role.clone())),
                        MemberType::Node => {}
                    }
                }
                re.tags = r.tags;
                regulatory.insert(re.id, re);
            }
            Some(_) => {}
            None if r.members.is_empty() => warnings.push(MapWarning {
                at: at(r.line).to_string(),
                message: format!("relation {} has no members and no type tag; skipped", r.id),
            }),
            None => warnings.push(MapWarning {
                at: at(r.line).to_string(),
                message: format!(
                    "relation {} has no `type` tag; kept in the file but not used (tag it type=lanelet to drive on it)",
                    r.id
                ),
            }),
        }
    }
    link_successors(&mut lanelets);
    refers_to.sort();
    for (re, lanelet) in refers_to {
        match regulatory.get_mut(&re) {
            Some(r) => r.lanelets.push(lanelet),
            None => warnings.push(MapWarning {
                at: source.display().to_string(),
                message: format!(
                    "lanelet {lanelet} names regulatory element {re}, which the file does not hold; ignored"
                ),
            }),
        }
    }
    let index = lanelets.iter().enumerate().map(|(i, l)| (l.id, i)).collect();
    let (ways, graph) = rayon::join(
        || ways.into_iter().map(|w| (w.way.id, w.way)).collect(),
        || RoutingGraph::new(&lanelets.iter().map(Lanelet::graph_view).collect::<Vec<GraphLanelet<'_>>>()),
    );
    Ok(Network { ways, lanelets, index, graph, regulatory, warnings })
}

/// Southern and northern limits of UTM [deg]: beyond them the projection is not defined (polar
/// maps need UPS).
const UTM_LATITUDES: (f64, f64) = (-80.0, 84.0);

/// Every node within UTM's latitudes, and the map not spread over the antimeridian (a map with
/// nodes at +179.9 and -179.9 degrees would be projected 40,000 km wide).
fn check_coordinates(doc: &OsmObjects) -> Result<(), MapError> {
    let bad = |n: &OsmNode, message: String| MapError::Coordinates { at: doc.at(n.line), node: n.id, message };
    if let Some(n) = doc.nodes.iter().find(|n| n.lat < UTM_LATITUDES.0 || n.lat > UTM_LATITUDES.1) {
        return Err(bad(
            n,
            format!(
                "latitude {} is outside UTM's range ({}..={} degrees); such a map cannot be projected (a typo in `lat`?)",
                n.lat, UTM_LATITUDES.0, UTM_LATITUDES.1
            ),
        ));
    }
    let west = doc.nodes.iter().min_by(|a, b| a.lon.total_cmp(&b.lon));
    let east = doc.nodes.iter().max_by(|a, b| a.lon.total_cmp(&b.lon));
    if let (Some(w), Some(e)) = (west, east)
        && e.lon - w.lon > 180.0
    {
        return Err(bad(
            e,
            format!(
                "longitude {} and node {}'s {} are more than 180 degrees apart: the map crosses the antimeridian (or a `lon` has a typo), which one UTM zone cannot draw; split the map or move it",
                e.lon, w.id, w.lon
            ),
        ));
    }
    Ok(())
}

/// The origin: the node tagged `origin=true`, else the mean of all nodes.
fn origin(doc: &OsmObjects, warnings: &mut Vec<MapWarning>) -> Result<(Projector, Option<i64>), MapError> {
    let mut tagged: Vec<_> =
        doc.nodes.iter().filter(|n| n.tags.get("origin").map(String::as_str) == Some("true")).collect();
    tagged.sort_by_key(|n| n.line);
    if let Some(first) = tagged.first() {
        if tagged.len() > 1 {
            warnings.push(MapWarning {
                at: doc.at(tagged[1].line).to_string(),
                message: format!(
                    "{} nodes are tagged origin=true; using node {} (line {}), the first in the file",
                    tagged.len(),
                    first.id,
                    first.line
                ),
            });
        }
        return Ok((Projector::new(first.lat, first.lon), Some(first.id)));
    }
    if doc.nodes.is_empty() {
        return Err(MapError::Empty(doc.source.clone()));
    }
    let n = doc.nodes.len() as f64;
    let lat = doc.nodes.iter().map(|n| n.lat).sum::<f64>() / n;
    let lon = doc.nodes.iter().map(|n| n.lon).sum::<f64>() / n;
    Ok((Projector::new(lat, lon), None))
}

/// The left and right bound ways of lanelet relation `r` (either role convention), as
/// positions in `ways`, or `None` (with a warning) when it has no members or lacks a usable bound.
fn bound_ways(
    at: &dyn Fn(usize) -> Location,
    r: &OsmRelation,
    ways: &[WayEntry],
    way_index: &IdIndex,
    warn: &mut dyn FnMut(String),
) -> Result<Option<(usize, usize)>, MapError> {
    if r.members.is_empty() {
        warn(format!("lanelet {} has no members; skipped", r.id));
        return Ok(None);
    }
    let mut left = None;
    let mut right = None;
    for m in &r.members {
        let side = match m.role.as_str() {
            "left" | "left_lane_marking" => &mut left,
            "right" | "right_lane_marking" => &mut right,
            _ => continue,
        };
        if m.kind != MemberType::Way {
            warn(format!("lanelet {}: member {} with role `{}` is not a way; ignored", r.id, m.reference, m.role));
            continue;
        }
        let way = way_index.get(m.reference).ok_or_else(|| MapError::MissingWay {
            at: at(r.line),
            lanelet: r.id,
            way: m.reference,
            role: m.role.clone(),
        })?;
        if side.is_some() {
            warn(format!("lanelet {} has two `{}` bounds; using the first", r.id, m.role));
            continue;
        }
        *side = Some(way);
    }
    let (Some(left), Some(right)) = (left, right) else {
        let missing = if left.is_none() { "left" } else { "right" };
        warn(format!(
            "lanelet {} has no {missing} bound (role `{missing}` or `{missing}_lane_marking`); skipped",
            r.id
        ));
        return Ok(None);
    };
    for b in [left, right] {
        if ways[b].way.nodes.len() < 2 {
            warn(format!("lanelet {}: bound way {} has fewer than 2 nodes; lanelet skipped", r.id, ways[b].way.id));
            return Ok(None);
        }
    }

    Ok(Some((left, right)))
}

/// One lanelet from its relation, or `None` (with a warning) when it cannot be used. A bound
/// way's repeats and self-crossings are reported once, on its own line, however many lanelets
/// share it.
fn lanelet(
    at: &dyn Fn(usize) -> Location,
    r: OsmRelation,
    ways: &mut [WayEntry],
    way_index: &IdIndex,
    warnings: &mut Vec<MapWarning>,
) -> Result<Option<Lanelet>, MapError> {
    // The relation's place, formatted only when there is something to say.
    let mut relation_at: Option<String> = None;
    let mut warn = |warnings: &mut Vec<MapWarning>, message: String| {
        let at = relation_at.get_or_insert_with(|| at(r.line).to_string()).clone();
        warnings.push(MapWarning { at, message });
    };
    let Some((li, ri)) = bound_ways(at, &r, ways, way_index, &mut |m| warn(warnings, m))? else {
        return Ok(None);
    };
    for k in [li, ri] {
        let entry = &mut ways[k];
        if !entry.checked {
            entry.checked = true;
            let problems = geometry_checks::way_problems(&entry.way);
            if !problems.is_empty() {
                let way_at = at(entry.line).to_string();
                warnings.extend(problems.into_iter().map(|message| MapWarning { at: way_at.clone(), message }));
            }
        }
    }
    let (left, right) = (&ways[li], &ways[ri]);
    if let Some(message) = geometry_checks::unusable(r.id, (&left.way, left.length), (&right.way, right.length)) {
        warn(warnings, message);
        return Ok(None);
    }
    if let Some(message) = geometry_checks::length_mismatch(r.id, (&left.way, left.length), (&right.way, right.length))
    {
        warn(warnings, message);
    }
    let (left, right) = (&left.way, &right.way);

    let mut right_nodes = right.nodes.clone();
    let mut right_pts = right.points.clone();
    let mut left_nodes = left.nodes.clone();
    let mut left_pts = left.points.clone();
    // Pair the left bound's ends with the right bound's ends (the SML maps draw it backwards).
    let (l0, l1, r0, r1) = (left_pts[0], left_pts[left_pts.len() - 1], right_pts[0], right_pts[right_pts.len() - 1]);
    if l0.distance(r0) + l1.distance(r1) > l1.distance(r0) + l0.distance(r1) {
        left_nodes.reverse();
        left_pts.reverse();
    }
    // Lanelet2 maps: the roles say which side, not which way. If the left bound lies on the right
    // of the right bound's drawn direction, the lanelet runs the other way.
    if signed_area(&left_pts, &right_pts) > 0.0 {
        left_nodes.reverse();
        left_pts.reverse();
        right_nodes.reverse();
        right_pts.reverse();
    }
    if left_pts.len() != right_pts.len() {
        let n = left_pts.len().max(right_pts.len());
        left_pts = resample_count(&left_pts, n);
        right_pts = resample_count(&right_pts, n);
    }
    let centre: Vec<DVec2> = left_pts.iter().zip(&right_pts).map(|(l, r)| (*l + *r) * 0.5).collect();
    let length = polyline_length(&centre);
    let tags: Tags = r.tags;
    Ok(Some(Lanelet {
        id: LaneletId(r.id),
        left_way: left.id,
        right_way: right.id,
        left_nodes,
        right_nodes,
        left: left_pts,
        right: right_pts,
        centre,
        length,
        successors: Vec::new(),
        routable: vehicle_may_drive(&tags),
        bidirectional: tags.get("one_way").map(String::as_str) == Some("no"),
        tags,
    }))
}

/// Shoelace area of the polygon left bound + reversed right bound: negative when the left bound
/// really is on the left of the driving direction. Walks the ring in place (no copy of it).
fn signed_area(left: &[DVec2], right: &[DVec2]) -> f64 {
    let n = left.len() + right.len();
    let ring = |i: usize| if i < left.len() { left[i] } else { right[right.len() - 1 - (i - left.len())] };
    let mut area = 0.0;
    for i in 0..n {
        let a = ring(i);
        let b = ring((i + 1) % n);
        area += a.x * b.y - b.x * a.y;
    }
    area * 0.5
}

/// Lanelet2's vehicle traffic rules: a `participant:vehicle:car` or `participant:vehicle` tag
/// overrides the default of the `subtype`, as in Lanelet2's `GenericTrafficRules`.
fn vehicle_may_drive(tags: &Tags) -> bool {
    for key in ["participant:vehicle:car", "participant:vehicle"] {
        if let Some(v) = tags.get(key) {
            return v == "yes";
        }
    }
    !tags.get("subtype").is_some_and(|s| NON_VEHICLE_SUBTYPES.contains(&s.as_str()))
}

/// j follows i when j's bounds start where i's bounds end (right and left), as the 2015 code and
/// Lanelet2 both decide it; a ring lanelet whose bounds end where they start follows itself
/// (an OpenDRIVE ring road converted to OSM). The starts are one sorted list (lanelets come in id order, so each
/// start's lanelets stay in id order), not a map of lists.
fn link_successors(lanelets: &mut [Lanelet]) {
    let mut by_start: Vec<((i64, i64), LaneletId)> =
        lanelets.iter().map(|l| ((l.right_nodes[0], l.left_nodes[0]), l.id)).collect();
    by_start.sort_unstable();
    for l in lanelets.iter_mut() {
        let end = (l.right_nodes[l.right_nodes.len() - 1], l.left_nodes[l.left_nodes.len() - 1]);
        let from = by_start.partition_point(|(start, _)| *start < end);
        let next = by_start[from..].iter().take_while(|(start, _)| *start == end);
        l.successors = next.map(|&(_, id)| id).collect();
    }
}
