//! From the parsed model to a [`LaneletMap`]: lane borders sampled along each lane section,
//! one lanelet per lane, successors from the file's links, tags for the rest of the simulator.

use std::collections::BTreeMap;
use std::path::Path as FsPath;

use glam::DVec2;

use super::road::{Contact, Document, Lane, LaneSection, Road, RoadLink, RoadMark, record_at};
use super::xml::Element;
use crate::map::error::{Location, MapError, MapWarning};
use crate::map::lanelet::{Lanelet, LaneletId, LaneletMap, MapNode, MapWay, Tags};
use crate::map::polyline::polyline_length;
use crate::map::projection::Projector;

/// Largest distance between a sampled bound and the true lane border between two samples \[m\].
pub const CHORD_ERROR: f64 = 0.02;
/// Longest step between two samples, even on a straight road \[m\].
pub const MAX_STEP: f64 = 10.0;
/// Shortest step \[m\]: below it a border bends with a radius under 2 cm ([`CHORD_ERROR`] cannot
/// hold there anyway), and a wild curvature in a file must not ask for unbounded points.
pub const MIN_STEP: f64 = 0.05;

/// Lane sections shorter than this \[m\] are merged into a neighbouring section
/// (`merge_short_sections`): their lanelets' bounds would be shorter than the 1 cm an OSM
/// lanelet map accepts (the round trip through `map convert` would lose them), and no car
/// drives a lane 2 cm long.
pub const MIN_SECTION: f64 = 0.02;

/// Lane types a car may drive (OpenDRIVE 1.8 §11.7.3's types for motorised traffic).
pub const DRIVABLE: [&str; 7] = ["driving", "entry", "exit", "onRamp", "offRamp", "connectingRamp", "bidirectional"];

/// The lanelet `subtype` (drawn with its colour by the renderer) of an OpenDRIVE lane type.
fn subtype(kind: &str) -> Option<&'static str> {
    match kind {
        "sidewalk" | "walking" => Some("walkway"),
        "biking" => Some("bicycle_lane"),
        "parking" => Some("parking"),
        "bus" => Some("bus_lane"),
        "shoulder" => Some("shoulder"),
        _ => None,
    }
}

/// Merges every lane section shorter than [`MIN_SECTION`] into the one before it (the first
/// section into the one after it), carrying the short section's lane links over: a lane linked
/// into the short section links on to where that section's lane links. A neighbour with the same
/// lane ids runs on over the short section's stretch; one with other lanes does not (the
/// stretch, under [`MIN_SECTION`], is left out). Either way no lanelet of the short section is
/// built, so the map and its `map convert` round trip have the same lanelets (an OSM lanelet of
/// bounds under 1 cm is skipped by the loader). A road of one section keeps it, however short.
pub(crate) fn merge_short_sections(doc: &mut Document) {
    // Composes an earlier id map (file id -> id) with a step (id -> new id).
    fn compose(old: Option<BTreeMap<i32, i32>>, step: BTreeMap<i32, i32>) -> Option<BTreeMap<i32, i32>> {
        Some(match old {
            None => step,
            Some(m) => m.into_iter().filter_map(|(o, g)| step.get(&g).map(|n| (o, *n))).collect(),
        })
    }
    for road in &mut doc.roads {
        let mut k = 0;
        while k < road.sections.len() {
            let short = road.sections[k].end - road.sections[k].s < MIN_SECTION;
            if !short || road.sections.len() < 2 {
                k += 1;
                continue;
            }
            // A neighbour with the same lanes takes over the short section's stretch of road.
            // Where the lanes differ the short section may move a lane sideways (Town04 road 688:
            // its 1.7 µm first section holds lane -6 where the next section's lane offset puts
            // lane -2; running that section back over it moved lane -2 by 14 m), so the section
            // is dropped and its stretch left out: a gap of its length (under MIN_SECTION; the
            // four in Town04 are 2 to 23 µm) between the lanes it joined.
            let ids = |x: &LaneSection| x.left.iter().chain(&x.right).map(|l| l.id).collect::<Vec<_>>();
            let neighbour = if k > 0 { k - 1 } else { k + 1 };
            let same = road.sections.get(neighbour).is_some_and(|n| ids(n) == ids(&road.sections[k]));
            let gone = road.sections.remove(k);
            let last = k == road.sections.len();
            if k > 0 {
                // The section before runs on to the short one's end (same lanes); its lanes link
                // past it.
                let prev = &mut road.sections[k - 1];
                if same {
                    prev.end = gone.end;
                }
                let mut step = BTreeMap::new();
                for lane in prev.left.iter_mut().chain(&mut prev.right) {
                    let via = lane
                        .successor
                        .and_then(|id| gone.lane(id))
                        .or_else(|| gone.left.iter().chain(&gone.right).find(|g| g.predecessor == Some(lane.id)));
                    if let Some(g) = via {
                        step.insert(g.id, lane.id);
                    }
                    lane.successor = via.and_then(|g| g.successor);
                }
                if last {
                    road.end_lanes = compose(road.end_lanes.take(), step);
                }
                if let Some(next) = road.sections.get_mut(k) {
                    for lane in next.left.iter_mut().chain(&mut next.right) {
                        if let Some(id) = lane.predecessor {
                            lane.predecessor = gone.lane(id).and_then(|g| g.predecessor);
                        }
                    }
                }
            } else {
                // The first section: the next one starts at the road's start instead (same lanes).
                let next = &mut road.sections[0];
                if same {
                    next.s = gone.s;
                }
                let mut step = BTreeMap::new();
                for lane in next.left.iter_mut().chain(&mut next.right) {
                    let via = lane
                        .predecessor
                        .and_then(|id| gone.lane(id))
                        .or_else(|| gone.left.iter().chain(&gone.right).find(|g| g.successor == Some(lane.id)));
                    if let Some(g) = via {
                        step.insert(g.id, lane.id);
                    }
                    lane.predecessor = via.and_then(|g| g.predecessor);
                }
                road.start_lanes = compose(road.start_lanes.take(), step);
            }
        }
    }
}

/// The lane id, in the sections built, of lane `id` that the file names at the `end` of `road`
/// (`None` where a merged-away section's lane leads nowhere).
fn lane_at(road: &Road, end: End, id: i32) -> Option<i32> {
    let map = if end == End::Start { &road.start_lanes } else { &road.end_lanes };
    match map {
        None => Some(id),
        Some(m) => m.get(&id).copied(),
    }
}

/// One lanelet's place in the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
struct LaneKey {
    road: usize,
    section: usize,
    lane: i32,
}

/// Where a lanelet meets another: its start or its end along `s`.
type End = Contact;

/// A lanelet being built: whether it runs along `s` (false: against it).
struct Built {
    along: bool,
}

/// Samples of one lane section: `s` values and, per border (index 0 the centre, then left
/// borders 1.. and right borders 1..), the node ids.
struct SectionNodes {
    left: Vec<Vec<i64>>,
    right: Vec<Vec<i64>>,
    centre: Vec<i64>,
}

/// Builds the map.
pub(crate) fn build(
    doc: &Document,
    root: &Element,
    source: &FsPath,
    mut warnings: Vec<MapWarning>,
) -> Result<LaneletMap, MapError> {
    let at = |line: usize| Location { file: source.to_path_buf(), line };
    let mut road_index: BTreeMap<&str, usize> = BTreeMap::new();
    for (k, r) in doc.roads.iter().enumerate() {
        if let Some(first) = road_index.insert(r.id.as_str(), k) {
            return Err(MapError::OpenDrive {
                at: at(r.line),
                message: format!("duplicate road id {} (first defined on line {})", r.id, doc.roads[first].line),
            });
        }
    }
    let junction_index: BTreeMap<&str, usize> =
        doc.junctions.iter().enumerate().map(|(k, j)| (j.id.as_str(), k)).collect();
    // Links to roads and junctions that do not exist are errors: the file is inconsistent.
    for r in &doc.roads {
        for link in [&r.predecessor, &r.successor].into_iter().flatten() {
            match link {
                RoadLink::Road { id, line, .. } if !road_index.contains_key(id.as_str()) => {
                    return Err(MapError::OpenDrive {
                        at: at(*line),
                        message: format!("road {} links to road {id}, which is not in the file", r.id),
                    });
                }
                RoadLink::Junction { id } if !junction_index.contains_key(id.as_str()) => {
                    return Err(MapError::OpenDrive {
                        at: at(r.line),
                        message: format!("road {} links to junction {id}, which is not in the file", r.id),
                    });
                }
                _ => {}
            }
        }
    }
    for j in &doc.junctions {
        for c in &j.connections {
            for road in [&c.incoming, &c.connecting] {
                if !road_index.contains_key(road.as_str()) {
                    return Err(MapError::OpenDrive {
                        at: at(c.line),
                        message: format!("junction {}: connection names road {road}, which is not in the file", j.id),
                    });
                }
            }
        }
    }

    let projector = match doc.origin {
        Some((lat, lon)) => Projector::new(lat, lon),
        None => Projector::new(0.0, 0.0),
    };
    let mut nodes: BTreeMap<i64, MapNode> = BTreeMap::new();
    let mut ways: BTreeMap<i64, MapWay> = BTreeMap::new();
    let mut lanelets: Vec<Lanelet> = Vec::new();
    let mut built: Vec<Built> = Vec::new();
    let mut by_key: BTreeMap<LaneKey, usize> = BTreeMap::new();
    let mut next_node: i64 = 1;
    let mut next_way: i64 = 1;
    let mut tag_index: BTreeMap<String, Vec<i64>> = BTreeMap::new();

    for (ri, road) in doc.roads.iter().enumerate() {
        for (si, section) in road.sections.iter().enumerate() {
            let samples = sample_section(road, section);
            let mut new_way = |points: Vec<DVec2>, tags: Tags, nodes: &mut BTreeMap<i64, MapNode>| -> (i64, Vec<i64>) {
                let ids: Vec<i64> = (0..points.len() as i64).map(|k| next_node + k).collect();
                next_node += points.len() as i64;
                for (&id, &p) in ids.iter().zip(&points) {
                    let (lat, lon) = projector.reverse(p);
                    nodes.insert(id, MapNode { id, lat, lon, position: p, tags: Tags::new() });
                }
                let id = next_way;
                next_way += 1;
                ways.insert(id, MapWay { id, nodes: ids.clone(), points, tags });
                (id, ids)
            };
            let centre_points = samples.border(section, 0);
            let (centre_way, centre_nodes) = new_way(
                centre_points,
                mark_tags(section.centre.as_ref().map(|c| c.marks.as_slice()), Side::Centre, section.s, &samples.s),
                &mut nodes,
            );
            let mut sn = SectionNodes { left: vec![], right: vec![], centre: centre_nodes };
            let mut way_ids = BTreeMap::new();
            way_ids.insert(0i32, centre_way);
            for lane in section.left.iter().chain(&section.right) {
                let side = if lane.id > 0 { Side::Left } else { Side::Right };
                let pts = samples.border(section, lane.id);
                let (w, ids) = new_way(pts, mark_tags(Some(&lane.marks), side, section.s, &samples.s), &mut nodes);
                way_ids.insert(lane.id, w);
                let list = if lane.id > 0 { &mut sn.left } else { &mut sn.right };
                list.push(ids);
            }
            // Lanes from the leftmost to the rightmost, so lanelet ids read across the road.
            for lane in section.left.iter().rev().chain(&section.right) {
                let k = lane.id.unsigned_abs() as usize;
                let (inner_nodes, inner_way) = if k == 1 {
                    (&sn.centre, way_ids[&0])
                } else {
                    let side = if lane.id > 0 { &sn.left } else { &sn.right };
                    (&side[k - 2], way_ids[&(lane.id - lane.id.signum())])
                };
                let outer_nodes = if lane.id > 0 { &sn.left[k - 1] } else { &sn.right[k - 1] };
                let outer_way = way_ids[&lane.id];
                // Borders by t: the higher one is on the left when driving along s.
                let ((hi_nodes, hi_way), (lo_nodes, lo_way)) = if lane.id > 0 {
                    ((outer_nodes, outer_way), (inner_nodes, inner_way))
                } else {
                    ((inner_nodes, inner_way), (outer_nodes, outer_way))
                };
                let rht_along = lane.id < 0;
                let mut along = if road.left_hand { !rht_along } else { rht_along };
                if lane.direction == "reversed" {
                    along = !along;
                }
                let (mut left_nodes, left_way, mut right_nodes, right_way) = if along {
                    (hi_nodes.clone(), hi_way, lo_nodes.clone(), lo_way)
                } else {
                    (lo_nodes.clone(), lo_way, hi_nodes.clone(), hi_way)
                };
                if !along {
                    left_nodes.reverse();
                    right_nodes.reverse();
                }
                let pos = |ids: &[i64]| ids.iter().map(|id| nodes[id].position).collect::<Vec<_>>();
                let (left, right) = (pos(&left_nodes), pos(&right_nodes));
                let centre: Vec<DVec2> = left.iter().zip(&right).map(|(l, r)| (*l + *r) * 0.5).collect();
                let id = LaneletId(lanelets.len() as i64 + 1);
                for (node, key, value) in [
                    (right_nodes[0], "opendrive:start", super::lane_tag(&road.id, section.index, lane.id, false)),
                    (
                        right_nodes[right_nodes.len() - 1],
                        "opendrive:end",
                        super::lane_tag(&road.id, section.index, lane.id, true),
                    ),
                ] {
                    if let Some(n) = nodes.get_mut(&node) {
                        n.tags.insert(key.into(), value.clone());
                    }
                    tag_index.entry(value).or_default().push(node);
                }
                let mut tags = Tags::new();
                tags.insert("type".into(), "lanelet".into());
                tags.insert("opendrive:road".into(), road.id.clone());
                tags.insert("opendrive:section".into(), section.index.to_string());
                tags.insert("opendrive:lane".into(), lane.id.to_string());
                tags.insert("opendrive:type".into(), lane.kind.clone());
                tags.insert("opendrive:junction".into(), road.junction.clone());
                if let Some(st) = subtype(&lane.kind) {
                    tags.insert("subtype".into(), st.into());
                }
                if road.left_hand {
                    tags.insert("driving_side".into(), "left".into());
                }
                if let Some(v) = lane.speed.or_else(|| road_speed(road, section.s)) {
                    tags.insert("speed_limit".into(), format!("{}", (v * 3.6 * 1000.0).round() / 1000.0));
                }
                if lane.direction == "both" || lane.kind == "bidirectional" {
                    tags.insert("opendrive:bidirectional".into(), "yes".into());
                }
                let length = polyline_length(&centre);
                by_key.insert(LaneKey { road: ri, section: si, lane: lane.id }, lanelets.len());
                built.push(Built { along });
                lanelets.push(Lanelet {
                    id,
                    left_way,
                    right_way,
                    left_nodes,
                    right_nodes,
                    left,
                    right,
                    centre,
                    length,
                    successors: Vec::new(),
                    routable: DRIVABLE.contains(&lane.kind.as_str()),
                    bidirectional: false,
                    tags,
                });
            }
        }
    }

    // Contacts: pairs of (lanelet, which end along s) that the file joins.
    let mut contacts: Vec<((usize, End), (usize, End))> = Vec::new();
    let missing_lane = |warnings: &mut Vec<MapWarning>, line: usize, message: String| {
        warnings.push(MapWarning { at: at(line).to_string(), message });
    };
    for (ri, road) in doc.roads.iter().enumerate() {
        let last = road.sections.len() - 1;
        // Inside the road, section by section.
        for si in 0..last {
            let (a, b) = (&road.sections[si], &road.sections[si + 1]);
            for lane in a.left.iter().chain(&a.right) {
                if let Some(next) = lane.successor {
                    match (
                        by_key.get(&LaneKey { road: ri, section: si, lane: lane.id }),
                        by_key.get(&LaneKey { road: ri, section: si + 1, lane: next }),
                    ) {
                        (Some(&x), Some(&y)) => contacts.push(((x, End::End), (y, End::Start))),
                        _ => missing_lane(
                            &mut warnings,
                            lane.line,
                            format!(
                                "road {} lane {}: successor lane {next} is not in the next lane section; link ignored",
                                road.id, lane.id
                            ),
                        ),
                    }
                }
            }
            for lane in b.left.iter().chain(&b.right) {
                if let Some(prev) = lane.predecessor {
                    match (
                        by_key.get(&LaneKey { road: ri, section: si + 1, lane: lane.id }),
                        by_key.get(&LaneKey { road: ri, section: si, lane: prev }),
                    ) {
                        (Some(&y), Some(&x)) => contacts.push(((x, End::End), (y, End::Start))),
                        _ => missing_lane(
                            &mut warnings,
                            lane.line,
                            format!(
                                "road {} lane {}: predecessor lane {prev} is not in the previous lane section; link ignored",
                                road.id, lane.id
                            ),
                        ),
                    }
                }
            }
        }
        // To other roads.
        for (link, section, end, pick) in [
            (&road.predecessor, 0, End::Start, Lane::predecessor_of as fn(&Lane) -> Option<i32>),
            (&road.successor, last, End::End, Lane::successor_of),
        ] {
            let Some(RoadLink::Road { id, contact, .. }) = link else { continue };
            let oi = road_index[id.as_str()];
            let other = &doc.roads[oi];
            let osec = if *contact == Contact::Start { 0 } else { other.sections.len() - 1 };
            for lane in road.sections[section].left.iter().chain(&road.sections[section].right) {
                let Some(to) = pick(lane) else { continue };
                let Some(to) = lane_at(other, *contact, to) else { continue };
                match (
                    by_key.get(&LaneKey { road: ri, section, lane: lane.id }),
                    by_key.get(&LaneKey { road: oi, section: osec, lane: to }),
                ) {
                    (Some(&x), Some(&y)) => contacts.push(((x, end), (y, *contact))),
                    _ => missing_lane(
                        &mut warnings,
                        lane.line,
                        format!(
                            "road {} lane {}: linked lane {to} is not on road {id}; link ignored",
                            road.id, lane.id
                        ),
                    ),
                }
            }
        }
    }
    for j in &doc.junctions {
        for c in &j.connections {
            let (ii, ci) = (road_index[c.incoming.as_str()], road_index[c.connecting.as_str()]);
            let (incoming, connecting) = (&doc.roads[ii], &doc.roads[ci]);
            // Which end of the incoming road touches the junction.
            let ends_here = |link: &Option<RoadLink>| matches!(link, Some(RoadLink::Junction { id }) if *id == j.id);
            let inc_end = match (ends_here(&incoming.predecessor), ends_here(&incoming.successor)) {
                (true, false) => End::Start,
                (false, true) => End::End,
                _ => {
                    // Not linked (or linked at both ends): the end nearer the connecting road's contact.
                    let target =
                        connecting.reference(if c.contact == Contact::Start { 0.0 } else { connecting.length }).0;
                    let d0 = incoming.reference(0.0).0.distance(target);
                    let d1 = incoming.reference(incoming.length).0.distance(target);
                    if d0 <= d1 { End::Start } else { End::End }
                }
            };
            let isec = if inc_end == End::Start { 0 } else { incoming.sections.len() - 1 };
            let csec = if c.contact == Contact::Start { 0 } else { connecting.sections.len() - 1 };
            for &(from, to) in &c.lane_links {
                let (Some(from), Some(to)) = (lane_at(incoming, inc_end, from), lane_at(connecting, c.contact, to))
                else {
                    continue;
                };
                match (
                    by_key.get(&LaneKey { road: ii, section: isec, lane: from }),
                    by_key.get(&LaneKey { road: ci, section: csec, lane: to }),
                ) {
                    (Some(&x), Some(&y)) => contacts.push(((x, inc_end), (y, c.contact))),
                    _ => missing_lane(
                        &mut warnings,
                        c.line,
                        format!(
                            "junction {}: lane link {from} -> {to} names a lane missing on road {} or {}; ignored",
                            j.id, c.incoming, c.connecting
                        ),
                    ),
                }
            }
        }
    }
    // A lanelet along s leaves at its end and enters at its start; against s the other way.
    let exits = |i: usize, e: End| (e == End::End) == built[i].along;
    let mut successors: Vec<Vec<usize>> = vec![Vec::new(); lanelets.len()];
    for ((a, ea), (b, eb)) in contacts {
        // A lanelet joined to itself end to start (a ring road such as circle_300m: road 1 is
        // its own predecessor and successor) follows itself; the same end twice is no link.
        if a == b && ea == eb {
            continue;
        }
        if exits(a, ea) && !exits(b, eb) && !successors[a].contains(&b) {
            successors[a].push(b);
        }
        if exits(b, eb) && !exits(a, ea) && !successors[b].contains(&a) {
            successors[b].push(a);
        }
    }
    for (l, next) in lanelets.iter_mut().zip(&mut successors) {
        next.sort_unstable();
        l.successors = next.iter().map(|&k| LaneletId(k as i64 + 1)).collect();
    }

    // Signals, controllers and junction priorities: lights and right of way on the links.
    let along: Vec<bool> = built.iter().map(|b| b.along).collect();
    let lane_of = |road: usize, section: usize, lane: i32| by_key.get(&LaneKey { road, section, lane }).copied();
    let programs = super::signals::apply(doc, &lane_of, &along, &mut lanelets, source, &mut warnings);

    if doc.roads.is_empty() {
        warnings.push(MapWarning {
            at: at(root.line).to_string(),
            message: "the file has no <road>: nothing to drive on".into(),
        });
    }
    let mut map = LaneletMap::from_parts(projector, nodes, ways, lanelets, tag_index, warnings);
    map.signal_programs = programs;
    Ok(map)
}

impl Lane {
    fn predecessor_of(&self) -> Option<i32> {
        self.predecessor
    }

    fn successor_of(&self) -> Option<i32> {
        self.successor
    }
}

/// The road `<type>` speed limit in force at `s` [m/s].
fn road_speed(road: &Road, s: f64) -> Option<f64> {
    road.speeds.iter().rev().find(|(start, _)| *start <= s + 1e-9).or(road.speeds.first()).map(|&(_, v)| v)
}

/// Which border a road mark lies on, for reading combined marks (`solid broken`): lanes read
/// from the centre outwards, the centre lane from left to right (OpenDRIVE 1.8 §11.8.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Side {
    Left,
    Centre,
    Right,
}

/// How a road mark is painted on a border way drawn along `s`: the Lanelet2 line `type` and
/// `subtype` (`dashed`, `solid`, `solid_solid`, `solid_dashed`/`dashed_solid` as read along the
/// way: the first part on its left), `line_thick` for `weight="bold"`.
fn paint(mark: &RoadMark, side: Side) -> (&'static str, Option<String>) {
    let part = |p: &str| match p {
        "solid" => Some("solid"),
        "broken" | "botts dots" => Some("dashed"),
        _ => None,
    };
    let line = if mark.weight == "bold" { "line_thick" } else { "line_thin" };
    let parts: Vec<&str> = mark.kind.split_whitespace().collect();
    match parts.as_slice() {
        ["none"] => ("virtual", None),
        ["curb"] => ("curbstone", None),
        ["grass"] | ["edge"] => ("road_border", None),
        [one] => (line, part(one).map(str::to_string)),
        [first, second] => {
            // (way's left part, way's right part), the way drawn along s (+t on its left).
            let (l, r) = if side == Side::Left { (second, first) } else { (first, second) };
            match (part(l), part(r)) {
                (Some("solid"), Some("solid")) => (line, Some("solid_solid".into())),
                (Some("dashed"), Some("dashed")) => (line, Some("dashed".into())),
                (Some(a), Some(b)) => (line, Some(format!("{a}_{b}"))),
                _ => (line, None),
            }
        }
        _ => (line, None),
    }
}

/// Tags of a border way (drawn along `s`) from the road mark in force at the section's start:
/// Lanelet2 `type`/`subtype` so the neighbour rules read it like any Lanelet2 line (`dashed`
/// allows a change both ways, `solid` none, `solid_dashed`/`dashed_solid` one way as read along
/// the way), with a `laneChange` attribute deciding the `subtype` where given; the file's own
/// values stay in `opendrive:road_mark`, `opendrive:color` and `opendrive:lane_change`, and
/// `opendrive:marks` lists every mark painted along the way ([`mark_pieces`]) for the renderer.
fn mark_tags(marks: Option<&[RoadMark]>, side: Side, s: f64, s_values: &[f64]) -> Tags {
    let mut tags = Tags::new();
    let Some(mark) = marks.and_then(|m| m.iter().rev().find(|m| m.s <= s + 1e-9).or(m.first())) else {
        return tags;
    };
    tags.insert("opendrive:road_mark".into(), mark.kind.clone());
    tags.insert("opendrive:color".into(), mark.color.clone());
    let (kind, mut sub) = paint(mark, side);
    if let Some(change) = &mark.lane_change {
        tags.insert("opendrive:lane_change".into(), change.clone());
        // Lane ids rise to the left of the way: `increase` crosses from its right to its left.
        let by_rule = match change.as_str() {
            "both" => Some("dashed"),
            "none" => Some("solid"),
            "increase" => Some("solid_dashed"),
            "decrease" => Some("dashed_solid"),
            _ => None,
        };
        if let Some(r) = by_rule {
            sub = Some(r.into());
        }
    }
    tags.insert("type".into(), kind.into());
    if let Some(s) = sub {
        tags.insert("subtype".into(), s);
    }
    if let Some(pieces) = marks.map(|m| mark_pieces(m, side, s_values)).filter(|p| !p.is_empty()) {
        tags.insert("opendrive:marks".into(), pieces);
    }
    tags
}

/// The road marks painted along a border way whose nodes lie at `s_values`: `;`-separated
/// pieces `NODE TYPE SUBTYPE COLOR`, each from node index NODE (0-based along the way) to the
/// next piece's, TYPE and SUBTYPE as [`paint`] gives them (`-`: none) and COLOR the file's
/// `color` (`standard` is white). Marks start at samples (they are breaks of the sampling).
fn mark_pieces(marks: &[RoadMark], side: Side, s_values: &[f64]) -> String {
    let (Some(&first), Some(&last)) = (s_values.first(), s_values.last()) else { return String::new() };
    let mut pieces: Vec<(usize, String)> = Vec::new();
    for (k, m) in marks.iter().enumerate() {
        let next = marks.get(k + 1).map_or(f64::INFINITY, |n| n.s);
        if next <= first + 1e-6 || m.s >= last - 1e-6 {
            continue;
        }
        let node = s_values.iter().position(|&v| v >= m.s - 1e-6).unwrap_or(0);
        let (kind, sub) = paint(m, side);
        let piece = format!("{node} {kind} {} {}", sub.as_deref().unwrap_or("-"), m.color.replace(' ', "_"));
        if pieces.last().is_some_and(|(n, _)| *n == node) {
            pieces.pop();
        }
        pieces.push((node, piece));
    }
    pieces.into_iter().map(|(_, p)| p).collect::<Vec<_>>().join(";")
}

/// The sampled reference line of a section: `s` values with position, heading and lane offset.
struct Samples {
    s: Vec<f64>,
    /// Where the records in force are looked up: the middle of the sample's interval between
    /// record starts, so a sample on a record start belongs to the interval it closes (a lane
    /// section's last sample uses the section's own records, not the next section's).
    pick: Vec<f64>,
    points: Vec<DVec2>,
    normals: Vec<DVec2>,
    offsets: Vec<f64>,
}

impl Samples {
    /// The points of border `id` (0 the centre lane, k > 0 the outer border of left lane k,
    /// k < 0 of right lane -k), in order of `s`.
    fn border(&self, section: &LaneSection, id: i32) -> Vec<DVec2> {
        (0..self.s.len())
            .map(|k| self.points[k] + self.normals[k] * border_t(section, id, self.s[k], self.pick[k], self.offsets[k]))
            .collect()
    }
}

/// Lateral position `t` [m] of border `id` at `s` with the records in force at `pick`, given
/// the lane offset there.
fn border_t(section: &LaneSection, id: i32, s: f64, pick: f64, offset: f64) -> f64 {
    if id == 0 {
        return offset;
    }
    let side = if id > 0 { &section.left } else { &section.right };
    let sign = f64::from(id.signum());
    let mut t = offset;
    for lane in side.iter().take(id.unsigned_abs() as usize) {
        if let Some(w) = record_at(&lane.widths, pick) {
            t += sign * w.value(s);
        } else if let Some(b) = record_at(&lane.borders, pick) {
            // A `border` gives the lane's outer border from the centre lane directly.
            t = offset + sign * b.value(s);
        }
    }
    t
}

/// The `s` values at which a section is sampled: every record start (geometry, lane offset,
/// width) is a sample, and between them the step keeps the chord error of every border under
/// [`CHORD_ERROR`]: a border at lateral offset t of a reference line with curvature κ curves
/// by κ / (1 - κ t), plus the second derivative of t itself (lane offset and widths); a chord
/// of length h on curvature k strays k h² / 8 from the curve.
fn sample_section(road: &Road, section: &LaneSection) -> Samples {
    let (a, b) = (section.s, section.end.max(section.s));
    let mut breaks = vec![a, b];
    let inside = |s: f64| s > a + 1e-6 && s < b - 1e-6;
    breaks.extend(road.geometries.iter().map(|g| g.s).filter(|&s| inside(s)));
    breaks.extend(road.lane_offsets.iter().map(|p| p.s).filter(|&s| inside(s)));
    for lane in section.left.iter().chain(&section.right) {
        breaks.extend(lane.widths.iter().chain(&lane.borders).map(|p| p.s).filter(|&s| inside(s)));
        breaks.extend(lane.marks.iter().map(|m| m.s).filter(|&s| inside(s)));
    }
    if let Some(c) = &section.centre {
        breaks.extend(c.marks.iter().map(|m| m.s).filter(|&s| inside(s)));
    }
    breaks.sort_by(f64::total_cmp);
    breaks.dedup_by(|x, y| (*x - *y).abs() < 1e-6);
    if breaks.len() < 2 {
        // A section of (next to) no length still gets its two ends.
        breaks.push(b);
    }
    let mut s_values = vec![(a, 0.5 * (breaks[0] + breaks[1]))];
    for w in breaks.windows(2) {
        let (s0, s1) = (w[0], w[1]);
        let kappa = road.geometries_in(s0, s1).map(|g| g.max_curvature()).fold(0.0, f64::max);
        let mid = 0.5 * (s0 + s1);
        let mut t_max: f64 = 0.0;
        let mut bend = record_at(&road.lane_offsets, mid).map_or(0.0, |p| p.max_second_derivative(s0, s1));
        for lane in section.left.iter().chain(&section.right) {
            let rec = record_at(&lane.widths, mid).or_else(|| record_at(&lane.borders, mid));
            if let Some(p) = rec {
                bend += p.max_second_derivative(s0, s1);
                t_max += p.value(s0).abs().max(p.value(s1).abs());
            }
        }
        t_max += road.offset(s0).abs().max(road.offset(s1).abs());
        let curvature = kappa / (1.0 - kappa * t_max).max(0.2) + bend;
        let step =
            if curvature > 0.0 { (8.0 * CHORD_ERROR / curvature).sqrt().clamp(MIN_STEP, MAX_STEP) } else { MAX_STEP };
        let n = ((s1 - s0) / step).ceil().max(1.0) as usize;
        for k in 1..=n {
            s_values.push((s0 + (s1 - s0) * k as f64 / n as f64, mid));
        }
    }
    let mut out = Samples {
        s: Vec::with_capacity(s_values.len()),
        pick: Vec::with_capacity(s_values.len()),
        points: Vec::with_capacity(s_values.len()),
        normals: Vec::with_capacity(s_values.len()),
        offsets: Vec::with_capacity(s_values.len()),
    };
    for (s, pick) in s_values {
        let (p, h) = road.reference_at(s, pick);
        out.s.push(s);
        out.pick.push(pick);
        out.points.push(p);
        out.normals.push(DVec2::new(-h.sin(), h.cos()));
        out.offsets.push(record_at(&road.lane_offsets, pick).map_or(0.0, |o| o.value(s)));
    }
    out
}
