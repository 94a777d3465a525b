//! Building a [`LaneletMap`] from an [`OsmDocument`]: projection, bound orientation, resampling,
//! centre lines, successors and the traffic rules that decide what a vehicle may drive.

use std::collections::BTreeMap;
use std::path::Path as FsPath;

use glam::DVec2;

use super::error::{MapError, MapWarning};
use super::geometry_checks;
use super::graph::{GraphLanelet, RoutingGraph};
use super::lanelet::{KNOWN_LINE_TYPES, Lanelet, LaneletId, LaneletMap, MapNode, MapWay, Tags};
use super::osm::{MemberType, OsmDocument, OsmRelation};
use super::polyline::{polyline_length, resample_count};
use super::projection::Projector;

impl LaneletMap {
    /// Load a JOSM/OSM map (`.osm` or `.xml`), or the road network of a CommonRoad scenario
    /// file (root element `<commonRoad>`, see [`super::commonroad`]).
    pub fn load(path: &FsPath) -> Result<LaneletMap, MapError> {
        let text = std::fs::read_to_string(path).map_err(|source| MapError::Io { path: path.to_path_buf(), source })?;
        if super::commonroad::is_commonroad(&text) {
            return Ok(super::commonroad::CommonRoadScenario::parse_str(&text, path)?.map);
        }
        let doc = super::osm::parse_osm(&text, path)?;
        LaneletMap::from_osm(&doc)
    }

    /// Parse OSM XML text; `name` stands for the file in messages.
    pub fn parse_str(text: &str, name: &FsPath) -> Result<LaneletMap, MapError> {
        let doc = super::osm::parse_osm(text, name)?;
        LaneletMap::from_osm(&doc)
    }

    /// Build the lanelet map from a raw OSM document.
    pub fn from_osm(doc: &OsmDocument) -> Result<LaneletMap, MapError> {
        build(doc)
    }
}

/// Node tag keys whose values are not names a user would route to (so not indexed by value).
const UNINDEXED_NODE_KEYS: [&str; 6] = ["origin", "ele", "x", "y", "local_x", "local_y"];

/// Lanelet `subtype`s that Lanelet2's vehicle traffic rules do not let a vehicle drive.
const NON_VEHICLE_SUBTYPES: [&str; 4] = ["crosswalk", "walkway", "bicycle_lane", "stairs"];

/// The loading stages in order (projection and origin, nodes and their tag index, ways,
/// lanelets, successors, routing graph); one function of about 85 lines because each stage
/// reads the previous one's locals and the order is the point.
fn build(doc: &OsmDocument) -> Result<LaneletMap, MapError> {
    let mut warnings = Vec::new();
    let warn = |warnings: &mut Vec<MapWarning>, line: usize, message: String| {
        warnings.push(MapWarning { at: doc.at(line).to_string(), message });
    };

    check_coordinates(doc)?;
    let (projector, origin_node) = origin(doc, &mut warnings)?;

    let mut nodes = BTreeMap::new();
    let mut tag_index: BTreeMap<String, Vec<i64>> = BTreeMap::new();
    for n in doc.nodes.values() {
        for (k, v) in &n.tags {
            if !UNINDEXED_NODE_KEYS.contains(&k.as_str()) {
                tag_index.entry(v.clone()).or_default().push(n.id);
            }
        }
        let position = projector.forward(n.lat, n.lon);
        nodes.insert(n.id, MapNode { id: n.id, lat: n.lat, lon: n.lon, position, tags: n.tags.clone() });
    }

    let mut ways = BTreeMap::new();
    for w in doc.ways.values() {
        // osm::parse_osm has already checked that every node exists.
        let points = w.nodes.iter().map(|id| nodes[id].position).collect();
        if let Some(t) = w.tags.get("line_type").filter(|t| !KNOWN_LINE_TYPES.contains(&t.as_str())) {
            warn(
                &mut warnings,
                w.line,
                format!(
                    "way {}: unknown line_type `{t}` (known: {}); drawn as an untagged way",
                    w.id,
                    KNOWN_LINE_TYPES.join(", ")
                ),
            );
        }
        ways.insert(w.id, MapWay { id: w.id, nodes: w.nodes.clone(), points, tags: w.tags.clone() });
    }

    let mut lanelets = Vec::new();
    let mut checked_ways = std::collections::BTreeSet::new();
    for r in doc.relations.values() {
        match r.tags.get("type").map(String::as_str) {
            Some("lanelet") => {
                if let Some(l) = lanelet(doc, r, &ways, &mut checked_ways, &mut warnings)? {
                    lanelets.push(l);
                }
            }
            Some(_) => {}
            None if r.members.is_empty() => {
                warn(&mut warnings, r.line, format!("relation {} has no members and no type tag; skipped", r.id))
            }
            None => warn(
                &mut warnings,
                r.line,
                format!(
                    "relation {} has no `type` tag; kept in the file but not used (tag it type=lanelet to drive on it)",
                    r.id
                ),
            ),
        }
    }
    link_successors(&mut lanelets);
    let index = lanelets.iter().enumerate().map(|(i, l)| (l.id, i)).collect();
    let mut map = LaneletMap {
        projector,
        origin_node,
        nodes,
        ways,
        lanelets,
        tag_index,
        warnings,
        index,
        graph: Default::default(),
    };
    let graph_lanelets: Vec<GraphLanelet<'_>> = map.lanelets.iter().map(Lanelet::graph_view).collect();
    map.graph = RoutingGraph::new(&graph_lanelets);
    Ok(map)
}

/// Southern and northern limits of UTM [deg]: beyond them the projection is not defined (polar
/// maps need UPS).
const UTM_LATITUDES: (f64, f64) = (-80.0, 84.0);

/// Every node within UTM's latitudes, and the map not spread over the antimeridian (a map with
/// nodes at +179.9 and -179.9 degrees would be projected 40,000 km wide).
fn check_coordinates(doc: &OsmDocument) -> Result<(), MapError> {
    let bad =
        |n: &super::osm::OsmNode, message: String| MapError::Coordinates { at: doc.at(n.line), node: n.id, message };
    if let Some(n) = doc.nodes.values().find(|n| n.lat < UTM_LATITUDES.0 || n.lat > UTM_LATITUDES.1) {
        return Err(bad(
            n,
            format!(
                "latitude {} is outside UTM's range ({}..={} degrees); such a map cannot be projected (a typo in `lat`?)",
                n.lat, UTM_LATITUDES.0, UTM_LATITUDES.1
            ),
        ));
    }
    let west = doc.nodes.values().min_by(|a, b| a.lon.total_cmp(&b.lon));
    let east = doc.nodes.values().max_by(|a, b| a.lon.total_cmp(&b.lon));
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
fn origin(doc: &OsmDocument, warnings: &mut Vec<MapWarning>) -> Result<(Projector, Option<i64>), MapError> {
    let mut tagged: Vec<_> =
        doc.nodes.values().filter(|n| n.tags.get("origin").map(String::as_str) == Some("true")).collect();
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
    let lat = doc.nodes.values().map(|n| n.lat).sum::<f64>() / n;
    let lon = doc.nodes.values().map(|n| n.lon).sum::<f64>() / n;
    Ok((Projector::new(lat, lon), None))
}

/// The left and right bound ways of lanelet relation `r` (either role convention), or `None`
/// (with a warning) when it has no members or lacks a usable bound.
fn bound_ways<'a>(
    doc: &OsmDocument,
    r: &OsmRelation,
    ways: &'a BTreeMap<i64, MapWay>,
    warn: &mut dyn FnMut(String),
) -> Result<Option<(&'a MapWay, &'a MapWay)>, MapError> {
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
        let way = ways.get(&m.reference).ok_or_else(|| MapError::MissingWay {
            at: doc.at(r.line),
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
        if b.nodes.len() < 2 {
            warn(format!("lanelet {}: bound way {} has fewer than 2 nodes; lanelet skipped", r.id, b.id));
            return Ok(None);
        }
    }

    Ok(Some((left, right)))
}

/// One lanelet from its relation, or `None` (with a warning) when it cannot be used.
/// `checked_ways` holds the bound ways already checked for repeats and self-crossings (each is
/// reported once, on its own line, however many lanelets share it).
fn lanelet(
    doc: &OsmDocument,
    r: &OsmRelation,
    ways: &BTreeMap<i64, MapWay>,
    checked_ways: &mut std::collections::BTreeSet<i64>,
    warnings: &mut Vec<MapWarning>,
) -> Result<Option<Lanelet>, MapError> {
    let at = doc.at(r.line).to_string();
    let mut warn = |message: String| warnings.push(MapWarning { at: at.clone(), message });
    let Some((left, right)) = bound_ways(doc, r, ways, &mut warn)? else { return Ok(None) };
    for way in [left, right] {
        if checked_ways.insert(way.id) {
            let way_at = doc.ways.get(&way.id).map_or_else(|| at.clone(), |w| doc.at(w.line).to_string());
            for message in geometry_checks::way_problems(way) {
                warnings.push(MapWarning { at: way_at.clone(), message });
            }
        }
    }
    let mut warn = |message: String| warnings.push(MapWarning { at: at.clone(), message });
    if let Some(message) = geometry_checks::unusable(r.id, left, right) {
        warn(message);
        return Ok(None);
    }
    if let Some(message) = geometry_checks::length_mismatch(r.id, left, right) {
        warn(message);
    }

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
    let tags: Tags = r.tags.clone();
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
/// really is on the left of the driving direction.
fn signed_area(left: &[DVec2], right: &[DVec2]) -> f64 {
    let ring: Vec<DVec2> = left.iter().chain(right.iter().rev()).copied().collect();
    let mut area = 0.0;
    for i in 0..ring.len() {
        let a = ring[i];
        let b = ring[(i + 1) % ring.len()];
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
/// Lanelet2 both decide it.
fn link_successors(lanelets: &mut [Lanelet]) {
    let mut by_start: BTreeMap<(i64, i64), Vec<LaneletId>> = BTreeMap::new();
    for l in lanelets.iter() {
        by_start.entry((l.right_nodes[0], l.left_nodes[0])).or_default().push(l.id);
    }
    for l in lanelets.iter_mut() {
        let end = (l.right_nodes[l.right_nodes.len() - 1], l.left_nodes[l.left_nodes.len() - 1]);
        if let Some(next) = by_start.get(&end) {
            l.successors = next.iter().copied().filter(|&id| id != l.id).collect();
        }
    }
}
