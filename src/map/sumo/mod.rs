//! SUMO road networks (`.net.xml`, root element `<net>`) -> a [`LaneletMap`], and SUMO demand
//! (`.rou.xml`, [`demand`]).
//!
//! What is read (SUMO's network format, eclipse-sumo/sumo
//! `docs/web/docs/Networks/SUMO_Road_Networks.md`):
//! - every `<lane>` of a normal `<edge>` becomes one lanelet: its bounds are the lane `shape`
//!   offset by half its `width` (3.2 m, SUMO's default, where none is given) to each side; lanes
//!   of one edge (`index` 0 the rightmost) share their border way, so they are left/right
//!   neighbours, and the border is dashed (a lane change allowed) unless the lanes' `changeLeft`
//!   / `changeRight` forbid passenger cars; `speed` [m/s] becomes the `speed_limit` tag [km/h];
//!   a lane whose `allow`/`disallow` closes it to `passenger` is kept and drawn but never routed;
//! - every `<connection>` from a normal lane becomes the successor link: with a `via`, the
//!   chain of internal lanes it passes (an internal lane may lead into another one, SUMO's
//!   internal junctions) is one lanelet of the junction (SUMO's internal lanes are what our
//!   junction links are), whose successor is the connection's `to` lane; without one (nets
//!   built with `--no-internal-links`) the `to` lane follows directly;
//! - right of way: each junction link lanelet carries `junction_control` from its
//!   `<junction type>` (`traffic_light*` -> `traffic_light`, `priority`, `priority_stop`,
//!   `zipper` and `unregulated` -> `priority`, `right_before_left`/`left_before_right` ->
//!   `right_before_left`, `allway_stop` -> `all_way_stop`), `priority=major|minor` from the
//!   connection `state` (`M`/`O` major; `m`, `s`, `w`, `o` minor), and its `<request>` row
//!   (`sumo:junction`, `sumo:link_index`: its place in the junction's `intLanes`,
//!   `sumo:response`), which [`crate::map::junctions`] uses to decide who yields at each conflict;
//! - traffic lights: a connection with `tl` and `linkIndex` tags its lanelet `traffic_light=yes`,
//!   `signal_program` and `signal_index`, and the `<tlLogic>` phases become the map's
//!   [`LaneletMap::signal_programs`], run by [`crate::vehicles::right_of_way`] in place of the
//!   default program. `actuated` and `delay_based` programs run with their phase `duration`s
//!   (a warning says so).
//!
//! - a turnaround (`dir="t"`) between lanes closer than two [`TURNAROUND_RADIUS`] (SUMO draws
//!   it as a half circle of half their distance, which a steered car cannot follow) is drawn
//!   as a driver takes it, into the junction and round (`turnaround_centre`, tag
//!   `sumo:shape=turnaround`); its crossings with the other links come from that shape, not
//!   from the file's `foes`, and it yields at those the file does not rank.
//!
//! Lanelets carry `sumo:lane` (the lane id; for a junction link, its first internal lane) and
//! `sumo:edge`; junction links also `sumo:from`, `sumo:to` (lane ids), `sumo:via` (all internal
//! lanes), `sumo:dir`, `sumo:state`. The first node of each lane's right bound carries the tag
//! value `start:LANE` and the last `end:LANE`, so a scenario can route from and to lanes.
//! Positions are the net's own (its `netOffset` already applied), in metres; the projection is
//! centred on lat/lon 0 (a `projParameter` is not read).
//!
//! Pedestrian `crossing` and `walkingarea` edges are left out (one warning); a connection to a
//! lane or edge the file does not define is a [`MapError::Sumo`] naming its line and ids.

pub mod demand;

use std::collections::BTreeMap;
use std::path::Path as FsPath;

use glam::DVec2;

use super::error::{Location, MapError, MapWarning};
use super::junctions::{MapSignalProgram, SignalPhase};
use super::lanelet::{Lanelet, LaneletId, LaneletMap, MapNode, MapWay, Tags};
use super::opendrive::xml::{Element, parse_root};
use super::polyline::{polyline_length, resample_count};
use super::projection::Projector;

/// SUMO's default lane width \[m\] (`netconvert --default.lanewidth`).
pub const DEFAULT_WIDTH: f64 = 3.2;

/// Whether `text` is a SUMO network (its root element is `<net>`).
pub fn is_sumo_net(text: &str) -> bool {
    let mut reader = quick_xml::Reader::from_str(text);
    loop {
        match reader.read_event() {
            Ok(quick_xml::events::Event::Start(e) | quick_xml::events::Event::Empty(e)) => {
                return e.name().as_ref() == "net";
            }
            Ok(quick_xml::events::Event::Eof) | Err(_) => return false,
            Ok(_) => {}
        }
    }
}

/// Whether vehicle class `passenger` may use a lane or edge with these `allow`/`disallow`
/// lists (SUMO's vehicle permissions: `allow` wins where both are given; `all` names every
/// class).
pub fn passenger_allowed(allow: Option<&str>, disallow: Option<&str>) -> bool {
    let names = |list: &str| list.split_whitespace().any(|c| c == "passenger" || c == "all");
    match (allow, disallow) {
        (Some(a), _) => names(a),
        (None, Some(d)) => !names(d),
        (None, None) => true,
    }
}

/// One lane of the file.
struct SumoLane {
    id: String,
    index: usize,
    speed: f64,
    width: f64,
    shape: Vec<DVec2>,
    passenger: bool,
    change_left: bool,
    change_right: bool,
    line: usize,
}

/// One edge with its lanes by index.
struct SumoEdge {
    id: String,
    internal: bool,
    lanes: Vec<SumoLane>,
}

/// One `<connection>`.
struct SumoConnection<'a> {
    from: &'a str,
    to: &'a str,
    from_lane: usize,
    to_lane: usize,
    via: Option<&'a str>,
    el: &'a Element,
}

/// Reading context: the file for messages.
struct Cx<'a> {
    source: &'a FsPath,
}

impl Cx<'_> {
    fn at(&self, line: usize) -> Location {
        Location { file: self.source.to_path_buf(), line }
    }

    fn err(&self, el: &Element, message: String) -> MapError {
        MapError::Sumo { at: self.at(el.line), message }
    }

    fn attr<'e>(&self, el: &'e Element, name: &str) -> Result<&'e str, MapError> {
        el.attr(name).ok_or_else(|| {
            self.err(el, format!("<{}> {}: attribute `{name}` is missing", el.name, el.attr("id").unwrap_or("")))
        })
    }

    fn num(&self, el: &Element, name: &str) -> Result<Option<f64>, MapError> {
        match el.attr(name) {
            None => Ok(None),
            Some(v) => v.trim().parse::<f64>().ok().filter(|x| x.is_finite()).map(Some).ok_or_else(|| {
                self.err(el, format!("<{}> {}: `{name}` = `{v}` is not a number", el.name, el.attr("id").unwrap_or("")))
            }),
        }
    }

    fn index(&self, el: &Element, name: &str) -> Result<usize, MapError> {
        let v = self.attr(el, name)?;
        v.trim()
            .parse::<usize>()
            .map_err(|_| self.err(el, format!("<{}>: `{name}` = `{v}` is not a lane index (0, 1, ...)", el.name)))
    }

    /// A `shape` ("x,y x,y ..." or with z), consecutive repeats dropped.
    fn shape(&self, el: &Element, text: &str) -> Result<Vec<DVec2>, MapError> {
        let mut out: Vec<DVec2> = Vec::new();
        for pair in text.split_whitespace() {
            let mut it = pair.split(',').map(|v| v.trim().parse::<f64>());
            let (Some(Ok(x)), Some(Ok(y))) = (it.next(), it.next()) else {
                return Err(self.err(
                    el,
                    format!("<{}> {}: shape point `{pair}` is not `x,y`", el.name, el.attr("id").unwrap_or("")),
                ));
            };
            let p = DVec2::new(x, y);
            if out.last().is_none_or(|q| q.distance(p) > 1e-6) {
                out.push(p);
            }
        }
        Ok(out)
    }
}

/// The polyline `points` moved sideways by `d` \[m\] (positive: to the left of its direction),
/// each vertex along the mitre of its two segments (the mitre stretch capped at 1/0.3).
pub fn offset_polyline(points: &[DVec2], d: f64) -> Vec<DVec2> {
    let n = points.len();
    if n < 2 {
        return points.to_vec();
    }
    let normal = |a: DVec2, b: DVec2| (b - a).normalize_or_zero().perp();
    (0..n)
        .map(|i| {
            let na = if i > 0 { normal(points[i - 1], points[i]) } else { normal(points[0], points[1]) };
            let nb = if i + 1 < n { normal(points[i], points[i + 1]) } else { na };
            let m = (na + nb).normalize_or_zero();
            let m = if m == DVec2::ZERO { na } else { m };
            let stretch = 1.0 / m.dot(na).max(0.3);
            points[i] + m * d * stretch
        })
        .collect()
}

/// A lane shape with at least two points (a lone point gets a 1 cm stub along x, so the
/// lanelet has a direction).
fn two_points(mut shape: Vec<DVec2>) -> Vec<DVec2> {
    match shape.len() {
        0 => vec![DVec2::ZERO, DVec2::new(0.01, 0.0)],
        1 => {
            shape.push(shape[0] + DVec2::new(0.01, 0.0));
            shape
        }
        _ => shape,
    }
}

/// Builds nodes and ways with fresh ids.
struct Ids {
    nodes: BTreeMap<i64, MapNode>,
    ways: BTreeMap<i64, MapWay>,
    next_node: i64,
    next_way: i64,
    projector: Projector,
}

impl Ids {
    fn way(&mut self, points: Vec<DVec2>, tags: Tags) -> (i64, Vec<i64>) {
        let ids: Vec<i64> = (0..points.len() as i64).map(|k| self.next_node + k).collect();
        self.next_node += points.len() as i64;
        for (&id, &p) in ids.iter().zip(&points) {
            let (lat, lon) = self.projector.reverse(p);
            self.nodes.insert(id, MapNode { id, lat, lon, position: p, tags: Tags::new() });
        }
        let id = self.next_way;
        self.next_way += 1;
        self.ways.insert(id, MapWay { id, nodes: ids.clone(), points, tags });
        (id, ids)
    }
}

/// Lanelet2 line tags of a lane border: `subtype` from which changes it allows (`along` its
/// drawn direction: from the right lane to the left one, and back).
fn border_tags(right_to_left: bool, left_to_right: bool) -> Tags {
    let mut tags = Tags::new();
    tags.insert("type".into(), "line_thin".into());
    let sub = match (right_to_left, left_to_right) {
        (true, true) => "dashed",
        (true, false) => "solid_dashed",
        (false, true) => "dashed_solid",
        (false, false) => "solid",
    };
    tags.insert("subtype".into(), sub.into());
    tags
}

/// A lanelet from its bounds (node ids and points, in driving direction).
fn lanelet(
    id: i64,
    left: (i64, Vec<i64>, Vec<DVec2>),
    right: (i64, Vec<i64>, Vec<DVec2>),
    tags: Tags,
    routable: bool,
) -> Lanelet {
    let centre: Vec<DVec2> = left.2.iter().zip(&right.2).map(|(l, r)| (*l + *r) * 0.5).collect();
    Lanelet {
        id: LaneletId(id),
        left_way: left.0,
        right_way: right.0,
        left_nodes: left.1,
        right_nodes: right.1,
        left: left.2,
        right: right.2,
        length: polyline_length(&centre),
        centre,
        successors: Vec::new(),
        routable,
        bidirectional: false,
        tags,
    }
}

/// Speed [m/s] as a `speed_limit` tag value [km/h].
fn kmh(v: f64) -> String {
    format!("{}", (v * 3.6 * 1000.0).round() / 1000.0)
}

/// The control a `<junction type>` states, as the `junction_control` tag value.
fn control_of(kind: &str) -> Option<&'static str> {
    match kind {
        "traffic_light" | "traffic_light_unregulated" | "traffic_light_right_on_red" => Some("traffic_light"),
        "priority" | "priority_stop" | "zipper" | "unregulated" => Some("priority"),
        "right_before_left" | "left_before_right" => Some("right_before_left"),
        "allway_stop" => Some("all_way_stop"),
        _ => None,
    }
}

/// Parse a SUMO network; `source` names the file in messages.
pub fn parse_str(text: &str, source: &FsPath) -> Result<LaneletMap, MapError> {
    let cx = Cx { source };
    let root = parse_root(text, source)?.filter(|r| r.name == "net").ok_or_else(|| MapError::Sumo {
        at: cx.at(0),
        message: "no <net> root element; this is not a SUMO network (.net.xml)".into(),
    })?;
    let mut warnings: Vec<MapWarning> = Vec::new();
    let mut skipped_pedestrian = 0usize;
    let mut first_pedestrian = 0usize;
    let mut edges: Vec<SumoEdge> = Vec::new();
    let mut edge_index: BTreeMap<&str, usize> = BTreeMap::new();
    let mut unknown: BTreeMap<&str, usize> = BTreeMap::new();
    for el in &root.children {
        match el.name.as_str() {
            "edge" => {
                let id = cx.attr(el, "id")?;
                let function = el.attr("function").unwrap_or("normal");
                if matches!(function, "crossing" | "walkingarea") {
                    skipped_pedestrian += 1;
                    if first_pedestrian == 0 {
                        first_pedestrian = el.line;
                    }
                    continue;
                }
                let (edge_allow, edge_disallow) = (el.attr("allow"), el.attr("disallow"));
                let mut lanes = Vec::new();
                for l in el.children("lane") {
                    let lane_id = cx.attr(l, "id")?;
                    let shape = cx.shape(l, cx.attr(l, "shape")?)?;
                    let (allow, disallow) = match (l.attr("allow"), l.attr("disallow")) {
                        (None, None) => (edge_allow, edge_disallow),
                        other => other,
                    };
                    let forbids = |k: &str| l.attr(k).is_some_and(|v| !passenger_allowed(None, Some(v)));
                    lanes.push(SumoLane {
                        id: lane_id.to_string(),
                        index: cx.index(l, "index")?,
                        speed: cx.num(l, "speed")?.unwrap_or(13.89),
                        width: cx.num(l, "width")?.filter(|w| *w > 0.0).unwrap_or(DEFAULT_WIDTH),
                        shape: two_points(shape),
                        passenger: passenger_allowed(allow, disallow),
                        change_left: !forbids("changeLeft"),
                        change_right: !forbids("changeRight"),
                        line: l.line,
                    });
                }
                lanes.sort_by_key(|l| l.index);
                for (k, l) in lanes.iter().enumerate() {
                    if l.index != k {
                        return Err(MapError::Sumo {
                            at: cx.at(l.line),
                            message: format!(
                                "edge {id}: lane {} has index {} but the edge's lane indices must run 0, 1, ... without gaps",
                                l.id, l.index
                            ),
                        });
                    }
                }
                if let Some(first) = edge_index.insert(id, edges.len()) {
                    return Err(cx.err(el, format!("duplicate edge id {id} (first defined as edge #{first})")));
                }
                edges.push(SumoEdge { id: id.to_string(), internal: function == "internal", lanes });
            }
            "location" | "junction" | "connection" | "tlLogic" | "type" | "roundabout" | "param" | "neigh"
            | "prohibition" => {}
            other => {
                unknown.entry(other).or_insert(el.line);
            }
        }
    }
    if skipped_pedestrian > 0 {
        warnings.push(MapWarning {
            at: cx.at(first_pedestrian).to_string(),
            message: format!(
                "{skipped_pedestrian} pedestrian crossing/walkingarea edge(s) left out (only vehicle lanes are read)"
            ),
        });
    }
    for (name, line) in unknown {
        warnings.push(MapWarning { at: cx.at(line).to_string(), message: format!("<{name}> is not read; ignored") });
    }

    let mut ids = Ids {
        nodes: BTreeMap::new(),
        ways: BTreeMap::new(),
        next_node: 1,
        next_way: 1,
        projector: Projector::new(0.0, 0.0),
    };
    let mut tag_index: BTreeMap<String, Vec<i64>> = BTreeMap::new();
    let mut lanelets: Vec<Lanelet> = Vec::new();
    // Lanelet index of every normal lane, by lane id.
    let mut lane_lanelet: BTreeMap<&str, usize> = BTreeMap::new();
    for e in edges.iter().filter(|e| !e.internal) {
        let n = e.lanes.len();
        if n == 0 {
            continue;
        }
        // Borders 0 (right of lane 0) ..= n (left of lane n - 1), all in driving direction.
        let count = e.lanes.iter().map(|l| l.shape.len()).max().unwrap_or(2);
        let shapes: Vec<Vec<DVec2>> = e
            .lanes
            .iter()
            .map(|l| if l.shape.len() == count { l.shape.clone() } else { resample_count(&l.shape, count) })
            .collect();
        let mut borders: Vec<(i64, Vec<i64>, Vec<DVec2>)> = Vec::with_capacity(n + 1);
        for k in 0..=n {
            let (points, tags) = if k == 0 {
                (offset_polyline(&shapes[0], -0.5 * e.lanes[0].width), border_tags(false, false))
            } else if k == n {
                (offset_polyline(&shapes[n - 1], 0.5 * e.lanes[n - 1].width), border_tags(false, false))
            } else {
                let a = offset_polyline(&shapes[k - 1], 0.5 * e.lanes[k - 1].width);
                let b = offset_polyline(&shapes[k], -0.5 * e.lanes[k].width);
                let mid = a.iter().zip(&b).map(|(p, q)| (*p + *q) * 0.5).collect();
                (mid, border_tags(e.lanes[k - 1].change_left, e.lanes[k].change_right))
            };
            let (way, nodes) = ids.way(points.clone(), tags);
            borders.push((way, nodes, points));
        }
        for (k, l) in e.lanes.iter().enumerate() {
            let id = lanelets.len() as i64 + 1;
            let mut tags = Tags::new();
            tags.insert("type".into(), "lanelet".into());
            tags.insert("subtype".into(), "road".into());
            tags.insert("sumo:lane".into(), l.id.clone());
            tags.insert("sumo:edge".into(), e.id.clone());
            tags.insert("sumo:index".into(), k.to_string());
            tags.insert("speed_limit".into(), kmh(l.speed));
            if !l.passenger {
                tags.insert("participant:vehicle:car".into(), "no".into());
            }
            let right = borders[k].clone();
            let left = borders[k + 1].clone();
            for (node, value) in
                [(right.1[0], format!("start:{}", l.id)), (right.1[right.1.len() - 1], format!("end:{}", l.id))]
            {
                if let Some(nd) = ids.nodes.get_mut(&node) {
                    nd.tags.insert("sumo".into(), value.clone());
                }
                tag_index.entry(value).or_default().push(node);
            }
            lane_lanelet.insert(l.id.as_str(), lanelets.len());
            lanelets.push(lanelet(id, left, right, tags, l.passenger));
        }
    }

    // Junctions: type and request row of every internal lane, tlLogic programs.
    type Request<'a> = (&'a str, &'a str);
    let mut link_of: BTreeMap<&str, (&str, usize, Option<Request<'_>>, &str)> = BTreeMap::new();
    for j in root.children("junction") {
        let jid = cx.attr(j, "id")?;
        let kind = j.attr("type").unwrap_or("");
        let requests: BTreeMap<usize, Request<'_>> = j
            .children("request")
            .filter_map(|r| Some((r.attr("index")?.trim().parse().ok()?, (r.attr("response")?, r.attr("foes")?))))
            .collect();
        for (k, lane) in j.attr("intLanes").unwrap_or("").split_whitespace().enumerate() {
            link_of.insert(lane, (jid, k, requests.get(&k).copied(), kind));
        }
    }
    let mut signal_programs: BTreeMap<String, MapSignalProgram> = BTreeMap::new();
    for t in root.children("tlLogic") {
        let id = cx.attr(t, "id")?;
        if signal_programs.contains_key(id) {
            warnings.push(MapWarning {
                at: cx.at(t.line).to_string(),
                message: format!(
                    "tlLogic {id}: another program ({}) for this light; the last one in the file is run, as SUMO does",
                    t.attr("programID").unwrap_or("?")
                ),
            });
        }
        let kind = t.attr("type").unwrap_or("static");
        if kind != "static" {
            warnings.push(MapWarning {
                at: cx.at(t.line).to_string(),
                message: format!("tlLogic {id}: a `{kind}` program runs as a fixed-time one with its phase durations (detectors are not simulated)"),
            });
        }
        let mut phases = Vec::new();
        for p in t.children("phase") {
            let duration = cx.num(p, "duration")?.unwrap_or(0.0);
            if duration <= 0.0 {
                return Err(cx.err(p, format!("tlLogic {id}: phase duration must be above 0 s")));
            }
            phases.push(SignalPhase { state: cx.attr(p, "state")?.to_string(), duration });
        }
        if phases.is_empty() {
            return Err(cx.err(t, format!("tlLogic {id} has no <phase>")));
        }
        signal_programs
            .insert(id.to_string(), MapSignalProgram { phases, offset: cx.num(t, "offset")?.unwrap_or(0.0) });
    }

    let lane_of = |edge: &str, index: usize, el: &Element, role: &str| -> Result<&SumoLane, MapError> {
        let e = edge_index
            .get(edge)
            .map(|&k| &edges[k])
            .ok_or_else(|| cx.err(el, format!("connection {}: {role} edge {edge} is not in the file", describe(el))))?;
        e.lanes.get(index).ok_or_else(|| {
            cx.err(
                el,
                format!(
                    "connection {}: {role} lane {index} of edge {edge} is not in the file (the edge has {} lane(s))",
                    describe(el),
                    e.lanes.len()
                ),
            )
        })
    };
    let internal_lanes: BTreeMap<&str, &SumoLane> =
        edges.iter().filter(|e| e.internal).flat_map(|e| e.lanes.iter()).map(|l| (l.id.as_str(), l)).collect();
    let internal_lane = |id: &str, el: &Element| -> Result<&SumoLane, MapError> {
        internal_lanes
            .get(id)
            .copied()
            .ok_or_else(|| cx.err(el, format!("connection {}: via lane {id} is not in the file", describe(el))))
    };
    let mut connections: Vec<SumoConnection<'_>> = Vec::new();
    // Where each internal lane leads: (next internal lane, or the normal lane it ends on).
    let mut internal_next: BTreeMap<String, (Option<&str>, &Element)> = BTreeMap::new();
    for c in root.children("connection") {
        let from = cx.attr(c, "from")?;
        let to = cx.attr(c, "to")?;
        let (from_lane, to_lane) = (cx.index(c, "fromLane")?, cx.index(c, "toLane")?);
        let from_internal = from.starts_with(':');
        if let Some(k) = edge_index.get(from) {
            if edges[*k].internal || from_internal {
                let lane = lane_of(from, from_lane, c, "from")?;
                lane_of(to, to_lane, c, "to")?;
                internal_next.insert(lane.id.clone(), (c.attr("via"), c));
                continue;
            }
        } else if from_internal {
            // An internal edge left out (pedestrian) or missing: nothing drives it.
            continue;
        }
        connections.push(SumoConnection { from, to, from_lane, to_lane, via: c.attr("via"), el: c });
    }
    let mut successors: Vec<Vec<usize>> = vec![Vec::new(); lanelets.len()];
    for c in &connections {
        let from_l = lane_of(c.from, c.from_lane, c.el, "from")?;
        let to_l = lane_of(c.to, c.to_lane, c.el, "to")?;
        if edge_index.get(c.to).is_some_and(|&k| edges[k].internal) {
            return Err(cx.err(c.el, format!("connection {}: `to` edge {} is an internal edge", describe(c.el), c.to)));
        }
        let (Some(&a), Some(&b)) = (lane_lanelet.get(from_l.id.as_str()), lane_lanelet.get(to_l.id.as_str())) else {
            continue;
        };
        let Some(first_via) = c.via else {
            if !successors[a].contains(&b) {
                successors[a].push(b);
            }
            continue;
        };
        // The chain of internal lanes, to the normal lane.
        let mut chain: Vec<&SumoLane> = vec![internal_lane(first_via, c.el)?];
        while let Some((Some(next), el)) = internal_next.get(chain[chain.len() - 1].id.as_str()) {
            if chain.len() > 16 || chain.iter().any(|l| l.id == *next) {
                return Err(cx.err(el, format!("connection {}: internal lanes loop at {next}", describe(el))));
            }
            chain.push(internal_lane(next, el)?);
        }
        let mut centre: Vec<DVec2> = Vec::new();
        for l in &chain {
            for &p in &l.shape {
                if centre.last().is_none_or(|q| q.distance(p) > 1e-6) {
                    centre.push(p);
                }
            }
        }
        let mut centre = two_points(centre);
        let mut redrawn = false;
        if c.el.attr("dir") == Some("t")
            && let [.., q, p] = from_l.shape[..]
            && let Some(drawn) = turnaround_centre(centre[0], (p - q).normalize_or_zero(), centre[centre.len() - 1])
        {
            centre = drawn;
            redrawn = true;
        }
        let width = chain[0].width;
        let lp = offset_polyline(&centre, 0.5 * width);
        let rp = offset_polyline(&centre, -0.5 * width);
        let virtual_line = || {
            let mut t = Tags::new();
            t.insert("type".into(), "virtual".into());
            t
        };
        let (lw, ln) = ids.way(lp.clone(), virtual_line());
        let (rw, rn) = ids.way(rp.clone(), virtual_line());
        let mut tags = Tags::new();
        tags.insert("type".into(), "lanelet".into());
        tags.insert("subtype".into(), "road".into());
        tags.insert("sumo:lane".into(), chain[0].id.clone());
        tags.insert(
            "sumo:edge".into(),
            chain[0].id.rsplit_once('_').map_or(chain[0].id.clone(), |(e, _)| e.to_string()),
        );
        tags.insert("sumo:function".into(), "internal".into());
        if redrawn {
            tags.insert("sumo:shape".into(), "turnaround".into());
        }
        tags.insert("sumo:from".into(), from_l.id.clone());
        tags.insert("sumo:to".into(), to_l.id.clone());
        if chain.len() > 1 {
            tags.insert("sumo:via".into(), chain.iter().map(|l| l.id.as_str()).collect::<Vec<_>>().join(" "));
        }
        tags.insert("speed_limit".into(), kmh(chain[0].speed));
        for key in ["dir", "state"] {
            if let Some(v) = c.el.attr(key) {
                tags.insert(format!("sumo:{key}"), v.to_string());
            }
        }
        if let Some((junction, k, response, kind)) = link_of.get(first_via) {
            tags.insert("sumo:junction".into(), junction.to_string());
            tags.insert("sumo:link_index".into(), k.to_string());
            if let Some((response, foes)) = response {
                tags.insert("sumo:response".into(), response.to_string());
                tags.insert("sumo:foes".into(), foes.to_string());
            }
            if let Some(control) = control_of(kind) {
                tags.insert("junction_control".into(), control.into());
            }
        }
        // At a light the state is the one shown while it is off; the program decides.
        match c.el.attr("state").filter(|_| c.el.attr("tl").is_none()) {
            Some("M" | "O") => {
                tags.insert("priority".into(), "major".into());
            }
            Some("m" | "s" | "w" | "o") => {
                tags.insert("priority".into(), "minor".into());
            }
            _ => {}
        }
        if let (Some(tl), Some(k)) = (c.el.attr("tl"), c.el.attr("linkIndex")) {
            if !signal_programs.contains_key(tl) {
                return Err(cx.err(
                    c.el,
                    format!("connection {}: traffic light {tl} has no <tlLogic> in the file", describe(c.el)),
                ));
            }
            tags.insert("traffic_light".into(), "yes".into());
            tags.insert("signal_program".into(), tl.to_string());
            tags.insert("signal_index".into(), k.trim().to_string());
        }
        let routable = from_l.passenger && to_l.passenger && chain.iter().all(|l| l.passenger);
        if !routable {
            tags.insert("participant:vehicle:car".into(), "no".into());
        }
        let k = lanelets.len();
        lanelets.push(lanelet(k as i64 + 1, (lw, ln, lp), (rw, rn, rp), tags, routable));
        successors.push(vec![b]);
        successors[a].push(k);
    }
    for (l, next) in lanelets.iter_mut().zip(&successors) {
        l.successors = next.iter().map(|&k| LaneletId(k as i64 + 1)).collect();
    }
    if lanelets.is_empty() {
        warnings.push(MapWarning {
            at: cx.at(root.line).to_string(),
            message: "the network has no vehicle lane: nothing to drive on".into(),
        });
    }
    let Ids { nodes, ways, projector, .. } = ids;
    let mut map = LaneletMap::from_parts(projector, nodes, ways, lanelets, tag_index, warnings);
    map.signal_programs = signal_programs;
    Ok(map)
}

/// Radius \[m\] of the turnaround drawn in place of a SUMO U-turn too tight to drive: above the
/// 5.1 m a default vehicle turns at full lock (wheelbase 2.8 m, steering 0.5 rad,
/// [`crate::world::KinematicUnicycle`]), so pure pursuit follows it.
pub const TURNAROUND_RADIUS: f64 = 5.5;

/// A drivable centre line for a U-turn from `p0` (heading `u`, a unit vector) to `p1` (heading
/// back), or `None` where SUMO's own shape is wide enough (the lanes at least two
/// [`TURNAROUND_RADIUS`] apart). SUMO draws a turnaround between the two inner lanes of a road
/// as a half circle of half the lanes' distance (1.6 m on a road without a median): a car
/// cannot drive it, and SUMO, which moves vehicles along lanes without steering, does not need
/// to. Ours steer, so the link becomes what a driver does on such a road: on into the junction,
/// a half circle of [`TURNAROUND_RADIUS`] that carries on by θ, and a reverse curve of θ back
/// into the target lane (cos θ = d / 2R for lanes d apart). Its crossings with the junction's
/// other links are found from this shape ([`crate::map::junctions`]).
fn turnaround_centre(p0: DVec2, u: DVec2, p1: DVec2) -> Option<Vec<DVec2>> {
    let r = TURNAROUND_RADIUS;
    let n = u.perp();
    let rel = p1 - p0;
    let (along, across) = (rel.dot(u), rel.dot(n));
    if !(along.is_finite() && across.is_finite()) || across.abs() >= 2.0 * r || across.abs() < 1e-6 {
        return None;
    }
    // Local frame: x along u, y towards the side the turn goes to.
    let side = across.signum();
    let theta = (across.abs() / (2.0 * r)).acos();
    let a = (along + 2.0 * r * theta.sin()).max(0.0);
    let to_world = |x: f64, y: f64| p0 + u * x + n * (side * y);
    let mut out = vec![p0];
    if a > 0.5 {
        out.push(to_world(a, 0.0));
    }
    // Points about every 0.5 m along each arc.
    let arc = |out: &mut Vec<DVec2>, centre: (f64, f64), from: f64, sweep: f64, radius_sign: f64| {
        let steps = ((sweep.abs() * r) / 0.5).ceil().max(1.0) as usize;
        for k in 1..=steps {
            let phi = from + sweep * k as f64 / steps as f64;
            out.push(to_world(centre.0 + r * phi.sin() * radius_sign, centre.1 - r * phi.cos() * radius_sign));
        }
    };
    // Left (towards +y) arc about (a, r) through π + θ, from φ = 0.
    arc(&mut out, (a, r), 0.0, std::f64::consts::PI + theta, 1.0);
    // Right arc about (a − 2r sin θ, r + 2r cos θ) back through θ.
    let c2 = (a - 2.0 * r * theta.sin(), r + 2.0 * r * theta.cos());
    arc(&mut out, c2, std::f64::consts::PI + theta, -theta, -1.0);
    if let Some(last) = out.last_mut() {
        *last = p1;
    }
    Some(out)
}

/// `from F_0 -> T_1` of a connection element, for messages.
fn describe(el: &Element) -> String {
    format!(
        "from {} lane {} to {} lane {}",
        el.attr("from").unwrap_or("?"),
        el.attr("fromLane").unwrap_or("?"),
        el.attr("to").unwrap_or("?"),
        el.attr("toLane").unwrap_or("?")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn permissions_follow_allow_then_disallow() {
        assert!(passenger_allowed(None, None));
        assert!(!passenger_allowed(Some("pedestrian"), None));
        assert!(passenger_allowed(Some("bus passenger"), Some("passenger")));
        assert!(!passenger_allowed(None, Some("all")));
        assert!(passenger_allowed(None, Some("pedestrian bicycle")));
    }

    #[test]
    fn a_tight_turnaround_is_redrawn_as_a_drivable_loop_from_lane_to_lane() {
        // netgenerate's turnaround between the inner lanes of a 2+2 road: 3.2 m apart.
        let (p0, u, p1) = (DVec2::new(198.4, 210.4), DVec2::new(0.0, -1.0), DVec2::new(201.6, 210.4));
        let c = turnaround_centre(p0, u, p1).expect("3.2 m apart is too tight to drive");
        assert_eq!((c[0], c[c.len() - 1]), (p0, p1));
        // Leaves along the lane and arrives heading back.
        assert!((c[1] - c[0]).normalize().dot(u) > 0.999);
        assert!((c[c.len() - 1] - c[c.len() - 2]).normalize().dot(-u) > 0.99);
        // No bend tighter than the radius: three points a few metres apart on a circle of at
        // least TURNAROUND_RADIUS.
        for w in c.windows(3) {
            let (a, b, d) = (w[0], w[1], w[2]);
            let area2 = (b - a).perp_dot(d - a).abs();
            let denom = a.distance(b) * b.distance(d) * a.distance(d);
            if denom > 1e-9 {
                assert!(denom / (2.0 * area2) > TURNAROUND_RADIUS - 0.05, "bend of radius {}", denom / (2.0 * area2));
            }
        }
        // It turns towards the target lane (left here) and stays within two radii of the line.
        assert!(c.iter().all(|p| p.x >= 198.4 - 1e-9 && p.x <= 198.4 + 2.0 * TURNAROUND_RADIUS + 1e-9));
        // Lanes two radii apart or more keep SUMO's shape.
        assert!(turnaround_centre(p0, u, p0 + DVec2::new(2.0 * TURNAROUND_RADIUS, 0.0)).is_none());
    }

    #[test]
    fn an_offset_straight_line_moves_by_the_offset() {
        let p = offset_polyline(&[DVec2::ZERO, DVec2::new(10.0, 0.0)], 1.6);
        assert!((p[0] - DVec2::new(0.0, 1.6)).length() < 1e-12);
        assert!((p[1] - DVec2::new(10.0, 1.6)).length() < 1e-12);
        // A right-angle corner keeps both legs 1 m away: the vertex moves by √2.
        let q = offset_polyline(&[DVec2::ZERO, DVec2::new(10.0, 0.0), DVec2::new(10.0, 10.0)], 1.0);
        assert!((q[1] - DVec2::new(9.0, 1.0)).length() < 1e-9);
    }
}
