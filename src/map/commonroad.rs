//! CommonRoad scenario XML (formats 2018b and 2020a) -> a [`LaneletMap`] plus the scenario's
//! dynamic obstacles and planning problems.
//!
//! CommonRoad is Cartesian: points are in metres, there is no projection (the map's projector
//! sits at lat/lon 0, 0 only so that every [`MapNode`] has some lat/lon). What is read:
//! - `<lanelet id>` with `<leftBound>`/`<rightBound>` of `<point><x/><y/></point>`s in driving
//!   direction and an optional `<lineMarking>` each; `<predecessor ref>`, `<successor ref>`;
//!   `<adjacentLeft ref drivingDir>`, `<adjacentRight ref drivingDir>`; `<laneletType>`.
//!   Lanelet ids are those of the file; successors are the file's successor lists plus the
//!   reverse of its predecessor lists (never derived from geometry).
//! - obstacles: 2020a `<dynamicObstacle>`; 2018b `<obstacle>` with `<role>dynamic</role>`
//!   (static ones are skipped). Each has a `<type>`, a `<shape>` (`<rectangle>` length and width;
//!   other shapes get a 1 m square with a warning), an `<initialState>` (2020a) and a
//!   `<trajectory>` of `<state>`s, each with `<position><point>`, `<orientation>`, `<time>` (an
//!   integer time step) and `<velocity>`; an interval value counts as its middle.
//! - `<planningProblem>`: its `<initialState>` and the position and time of its `<goalState>`s.
//!
//! Synthetic ids, so that the OSM-based tools work unchanged: the k-th point of lanelet L's left
//! bound is node `L * 100000 + k`, of its right bound node `L * 100000 + 50000 + k`; the bounds
//! are ways `2 L` (left) and `2 L + 1` (right), tagged `line_marking=<value>` and drawn like the
//! SML maps (`solid`/`broad_solid` as `line_type=exterior`, `dashed`/`broad_dashed` as
//! `interior`, other markings not drawn). The first right-bound node of lanelet L carries the tag
//! value `start_L` and the last one `end_L`, so `smlworld map route FILE.xml --from-tag start_1
//! --to-tag end_5` routes from the start of lanelet 1 to the end of lanelet 5.

use std::collections::BTreeMap;
use std::path::Path as FsPath;

use glam::DVec2;
use quick_xml::Reader;
use quick_xml::events::Event;

use super::error::{Location, MapError, MapWarning};
use super::graph::{GraphLanelet, RoutingGraph};
use super::lanelet::{Lanelet, LaneletId, LaneletMap, MapNode, MapWay, Tags};
use super::polyline::{polyline_length, resample_count};
use super::projection::Projector;

/// Node ids per lanelet: the lanelet id times this, plus the point index.
pub const NODE_IDS_PER_LANELET: i64 = 100_000;
/// Offset of right-bound node ids within a lanelet's range.
pub const RIGHT_BOUND_NODE_OFFSET: i64 = 50_000;

/// `laneletType` values on which Lanelet2-style vehicle rules forbid driving.
const NON_VEHICLE_TYPES: [&str; 3] = ["sidewalk", "crosswalk", "bicycleLane"];

/// One state of an obstacle or of a planning problem.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CommonRoadState {
    /// Integer time step (time = step * `timeStepSize`).
    pub time_step: i64,
    /// Position [m].
    pub position: DVec2,
    /// Heading, counter-clockwise from the x axis [rad].
    pub orientation: f64,
    /// Speed [m/s].
    pub velocity: f64,
}

/// A dynamic obstacle with its recorded trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct DynamicObstacle {
    /// Obstacle id as in the file.
    pub id: i64,
    /// `<type>` (`car`, `truck`, `pedestrian`, ...).
    pub kind: String,
    /// Length of its rectangle [m].
    pub length: f64,
    /// Width of its rectangle [m].
    pub width: f64,
    /// Initial state followed by the trajectory, in time-step order.
    pub states: Vec<CommonRoadState>,
}

impl DynamicObstacle {
    /// The state at `time_step`, if recorded.
    pub fn state_at(&self, time_step: i64) -> Option<&CommonRoadState> {
        self.states.binary_search_by_key(&time_step, |s| s.time_step).ok().map(|i| &self.states[i])
    }
}

/// Goal position of a planning problem.
#[derive(Debug, Clone, PartialEq)]
pub enum GoalShape {
    /// A rectangle of `length` x `width` [m] around `center`, turned by `orientation` [rad].
    Rectangle {
        /// Centre [m].
        center: DVec2,
        /// Along its orientation [m].
        length: f64,
        /// Across [m].
        width: f64,
        /// Heading of its length axis [rad].
        orientation: f64,
    },
    /// A circle.
    Circle {
        /// Centre [m].
        center: DVec2,
        /// Radius [m].
        radius: f64,
    },
    /// A polygon (any orientation).
    Polygon {
        /// Corners [m].
        points: Vec<DVec2>,
    },
    /// Any point of these lanelets.
    Lanelets {
        /// Lanelet ids.
        ids: Vec<i64>,
    },
}

impl GoalShape {
    /// Whether `p` [m] lies in the goal shape (lanelets: inside one of their polygons).
    pub fn contains(&self, p: DVec2, map: &LaneletMap) -> bool {
        match self {
            GoalShape::Rectangle { center, length, width, orientation } => {
                let d = p - *center;
                let (s, c) = orientation.sin_cos();
                let along = d.x * c + d.y * s;
                let across = -d.x * s + d.y * c;
                along.abs() <= length / 2.0 && across.abs() <= width / 2.0
            }
            GoalShape::Circle { center, radius } => p.distance(*center) <= *radius,
            GoalShape::Polygon { points } => point_in_polygon(p, points),
            GoalShape::Lanelets { ids } => {
                ids.iter().filter_map(|id| map.lanelet(LaneletId(*id))).any(|l| point_in_polygon(p, &l.polygon()))
            }
        }
    }
}

fn point_in_polygon(p: DVec2, poly: &[DVec2]) -> bool {
    let mut inside = false;
    let n = poly.len();
    for i in 0..n {
        let (a, b) = (poly[i], poly[(i + 1) % n]);
        if (a.y > p.y) != (b.y > p.y) && p.x < a.x + (p.y - a.y) / (b.y - a.y) * (b.x - a.x) {
            inside = !inside;
        }
    }
    inside
}

/// One goal state: where (any of `shapes`, or anywhere when empty) and when.
#[derive(Debug, Clone, PartialEq)]
pub struct GoalState {
    /// Goal positions; empty means any position.
    pub shapes: Vec<GoalShape>,
    /// Earliest time step.
    pub time_start: i64,
    /// Latest time step.
    pub time_end: i64,
}

/// A planning problem: an ego vehicle's initial state and goal.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanningProblem {
    /// Id as in the file.
    pub id: i64,
    /// Initial state of the ego vehicle.
    pub initial_state: CommonRoadState,
    /// Goal states (reaching any one solves the problem).
    pub goals: Vec<GoalState>,
}

/// A CommonRoad scenario file: its lanelet map, obstacles and planning problems.
#[derive(Debug, Clone)]
pub struct CommonRoadScenario {
    /// `commonRoadVersion` of the file (`2018b`, `2020a`, ...).
    pub version: String,
    /// Time step [s] (`timeStepSize`).
    pub time_step_size: f64,
    /// The road network.
    pub map: LaneletMap,
    /// Dynamic obstacles, sorted by id.
    pub obstacles: Vec<DynamicObstacle>,
    /// Planning problems, sorted by id.
    pub planning_problems: Vec<PlanningProblem>,
}

/// Whether `text` is a CommonRoad file (its root element is `<commonRoad>`).
pub fn is_commonroad(text: &str) -> bool {
    let mut reader = Reader::from_str(text);
    loop {
        match reader.read_event() {
            Ok(Event::Start(e) | Event::Empty(e)) => return e.name().as_ref() == "commonRoad",
            Ok(Event::Eof) | Err(_) => return false,
            Ok(_) => {}
        }
    }
}

/// A parsed XML element (CommonRoad files are small and nested: a tree is simplest).
#[derive(Debug, Default)]
struct Element {
    name: String,
    attrs: Vec<(String, String)>,
    text: String,
    children: Vec<Element>,
    line: usize,
}

impl Element {
    fn attr(&self, name: &str) -> Option<&str> {
        self.attrs.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
    }

    fn child(&self, name: &str) -> Option<&Element> {
        self.children.iter().find(|c| c.name == name)
    }

    fn children<'a>(&'a self, name: &'a str) -> impl Iterator<Item = &'a Element> + 'a {
        self.children.iter().filter(move |c| c.name == name)
    }
}

fn parse_tree(text: &str, source: &FsPath) -> Result<Element, MapError> {
    let mut reader = Reader::from_str(text);
    reader.config_mut().trim_text(true);
    let bytes = text.as_bytes();
    let (mut line, mut counted) = (1usize, 0usize);
    let mut line_at = |offset: usize| {
        let offset = offset.min(bytes.len());
        if offset > counted {
            line += bytes[counted..offset].iter().filter(|&&b| b == b'\n').count();
            counted = offset;
        }
        line
    };
    let mut stack: Vec<Element> = vec![Element::default()];
    loop {
        let start = reader.buffer_position() as usize;
        let event = reader.read_event().map_err(|e| MapError::Xml {
            at: Location { file: source.to_path_buf(), line: line_at(reader.error_position() as usize) },
            message: e.to_string(),
        })?;
        let elem_line = line_at(start + text[start..].find('<').unwrap_or(0));
        match event {
            Event::Start(ref e) | Event::Empty(ref e) => {
                let mut el = Element { name: e.name().as_ref().to_string(), line: elem_line, ..Default::default() };
                for a in e.attributes().with_checks(false) {
                    let a = a.map_err(|err| MapError::Xml {
                        at: Location { file: source.to_path_buf(), line: elem_line },
                        message: err.to_string(),
                    })?;
                    let v = a.normalized_value(quick_xml::XmlVersion::Implicit1_0).map_err(|err| MapError::Xml {
                        at: Location { file: source.to_path_buf(), line: elem_line },
                        message: err.to_string(),
                    })?;
                    el.attrs.push((a.key.as_ref().to_string(), v.into_owned()));
                }
                if matches!(event, Event::Empty(_)) {
                    if let Some(parent) = stack.last_mut() {
                        parent.children.push(el);
                    }
                } else {
                    stack.push(el);
                }
            }
            Event::Text(t) => {
                if let Some(top) = stack.last_mut() {
                    top.text.push_str(&t.xml10_content());
                }
            }
            Event::End(_) => {
                if stack.len() > 1 {
                    let el = stack.pop().unwrap_or_default();
                    if let Some(parent) = stack.last_mut() {
                        parent.children.push(el);
                    }
                }
            }
            Event::Eof => break,
            _ => {}
        }
    }
    let mut root = stack.swap_remove(0);
    root.children.pop().filter(|r| r.name == "commonRoad").ok_or_else(|| MapError::Xml {
        at: Location { file: source.to_path_buf(), line: 0 },
        message: "no <commonRoad> root element; this is not a CommonRoad scenario file".into(),
    })
}

/// Builds errors at a file's lines.
struct Ctx<'a> {
    source: &'a FsPath,
}

impl Ctx<'_> {
    fn err(&self, el: &Element, message: String) -> MapError {
        MapError::CommonRoad { at: Location { file: self.source.to_path_buf(), line: el.line }, message }
    }

    fn at(&self, el: &Element) -> String {
        Location { file: self.source.to_path_buf(), line: el.line }.to_string()
    }

    fn id(&self, el: &Element) -> Result<i64, MapError> {
        let v = el.attr("id").ok_or_else(|| self.err(el, format!("<{}> has no `id` attribute", el.name)))?;
        v.trim().parse().map_err(|_| self.err(el, format!("<{}> id {v:?} is not an integer", el.name)))
    }

    fn reference(&self, el: &Element) -> Result<i64, MapError> {
        let v = el.attr("ref").ok_or_else(|| self.err(el, format!("<{}> has no `ref` attribute", el.name)))?;
        v.trim().parse().map_err(|_| self.err(el, format!("<{}> ref {v:?} is not an integer", el.name)))
    }

    fn number(&self, el: &Element) -> Result<f64, MapError> {
        el.text
            .trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| self.err(el, format!("<{}> {:?} is not a finite number", el.name, el.text.trim())))
    }

    fn field(&self, parent: &Element, name: &str) -> Result<f64, MapError> {
        let el = parent.child(name).ok_or_else(|| self.err(parent, format!("<{}> has no <{name}>", parent.name)))?;
        self.number(el)
    }

    fn point(&self, el: &Element) -> Result<DVec2, MapError> {
        Ok(DVec2::new(self.field(el, "x")?, self.field(el, "y")?))
    }

    /// `<exact>v</exact>` or `<intervalStart>a</intervalStart><intervalEnd>b</intervalEnd>`
    /// (the middle).
    fn value(&self, el: &Element) -> Result<f64, MapError> {
        if let Some(exact) = el.child("exact") {
            return self.number(exact);
        }
        match (el.child("intervalStart"), el.child("intervalEnd")) {
            (Some(a), Some(b)) => Ok((self.number(a)? + self.number(b)?) / 2.0),
            _ => Err(self.err(el, format!("<{}> has neither <exact> nor <intervalStart>/<intervalEnd>", el.name))),
        }
    }

    fn interval(&self, el: &Element) -> Result<(f64, f64), MapError> {
        if let Some(exact) = el.child("exact") {
            let v = self.number(exact)?;
            return Ok((v, v));
        }
        match (el.child("intervalStart"), el.child("intervalEnd")) {
            (Some(a), Some(b)) => Ok((self.number(a)?, self.number(b)?)),
            _ => Err(self.err(el, format!("<{}> has neither <exact> nor <intervalStart>/<intervalEnd>", el.name))),
        }
    }

    fn state(&self, el: &Element) -> Result<CommonRoadState, MapError> {
        let need = |name: &str| el.child(name).ok_or_else(|| self.err(el, format!("<{}> has no <{name}>", el.name)));
        let pos = need("position")?;
        let point = pos.child("point").ok_or_else(|| {
            self.err(pos, "<position> has no <point> (shapes as positions are only read in goal states)".into())
        })?;
        let time = self.value(need("time")?)?;
        if time.fract() != 0.0 {
            return Err(self.err(el, format!("<time> {time} is not an integer time step")));
        }
        Ok(CommonRoadState {
            time_step: time as i64,
            position: self.point(point)?,
            orientation: el.child("orientation").map(|o| self.value(o)).transpose()?.unwrap_or(0.0),
            velocity: el.child("velocity").map(|v| self.value(v)).transpose()?.unwrap_or(0.0),
        })
    }

    fn bound(&self, el: &Element) -> Result<(Vec<DVec2>, Option<String>), MapError> {
        let points = el.children("point").map(|p| self.point(p)).collect::<Result<Vec<_>, _>>()?;
        if points.len() < 2 {
            return Err(self.err(el, format!("<{}> has {} points; a bound needs at least 2", el.name, points.len())));
        }
        Ok((points, el.child("lineMarking").map(|m| m.text.trim().to_string())))
    }
}

impl CommonRoadScenario {
    /// Read a CommonRoad scenario file.
    pub fn load(path: &FsPath) -> Result<CommonRoadScenario, MapError> {
        let text = std::fs::read_to_string(path).map_err(|source| MapError::Io { path: path.to_path_buf(), source })?;
        CommonRoadScenario::parse_str(&text, path)
    }

    /// Parse CommonRoad XML text; `source` names the file in messages.
    pub fn parse_str(text: &str, source: &FsPath) -> Result<CommonRoadScenario, MapError> {
        if text.trim().is_empty() {
            return Err(MapError::Empty(source.to_path_buf()));
        }
        let root = parse_tree(text, source)?;
        let cx = Ctx { source };
        let version = root.attr("commonRoadVersion").unwrap_or("").to_string();
        let time_step_size = match root.attr("timeStepSize") {
            Some(v) => v
                .trim()
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite() && *v > 0.0)
                .ok_or_else(|| cx.err(&root, format!("timeStepSize {v:?} must be a positive number of seconds")))?,
            None => return Err(cx.err(&root, "<commonRoad> has no `timeStepSize` attribute".into())),
        };
        let mut warnings = Vec::new();
        let map = build_map(&root, &cx, &mut warnings)?;
        let mut obstacles = Vec::new();
        for el in root.children.iter().filter(|c| c.name == "dynamicObstacle" || c.name == "obstacle") {
            if el.name == "obstacle" && el.child("role").map(|r| r.text.trim()) != Some("dynamic") {
                continue;
            }
            obstacles.push(obstacle(el, &cx, &mut warnings)?);
        }
        obstacles.sort_by_key(|o| o.id);
        let mut planning_problems = Vec::new();
        for el in root.children("planningProblem") {
            planning_problems.push(planning_problem(el, &cx)?);
        }
        planning_problems.sort_by_key(|p| p.id);
        let mut map = map;
        map.warnings.extend(warnings);
        Ok(CommonRoadScenario { version, time_step_size, map, obstacles, planning_problems })
    }
}

fn obstacle(el: &Element, cx: &Ctx, warnings: &mut Vec<MapWarning>) -> Result<DynamicObstacle, MapError> {
    let id = cx.id(el)?;
    let kind = el.child("type").map(|t| t.text.trim().to_string()).unwrap_or_else(|| "unknown".into());
    let (mut length, mut width) = (1.0, 1.0);
    match el.child("shape").and_then(|s| s.child("rectangle")) {
        Some(r) => (length, width) = (cx.field(r, "length")?, cx.field(r, "width")?),
        None => warnings.push(MapWarning {
            at: cx.at(el),
            message: format!("obstacle {id}: no <shape><rectangle>; drawn and checked as a 1 m x 1 m square"),
        }),
    }
    let mut states = Vec::new();
    if let Some(s) = el.child("initialState") {
        states.push(cx.state(s)?);
    }
    if let Some(t) = el.child("trajectory") {
        for s in t.children("state") {
            states.push(cx.state(s)?);
        }
    }
    if states.is_empty() {
        return Err(cx.err(el, format!("obstacle {id} has no <initialState> and no <trajectory> states")));
    }
    states.sort_by_key(|s| s.time_step);
    if let Some(w) = states.windows(2).find(|w| w[0].time_step == w[1].time_step) {
        return Err(cx.err(el, format!("obstacle {id} has two states at time step {}", w[0].time_step)));
    }
    Ok(DynamicObstacle { id, kind, length, width, states })
}

fn planning_problem(el: &Element, cx: &Ctx) -> Result<PlanningProblem, MapError> {
    let id = cx.id(el)?;
    let initial =
        el.child("initialState").ok_or_else(|| cx.err(el, format!("planning problem {id} has no <initialState>")))?;
    let initial_state = cx.state(initial)?;
    let mut goals = Vec::new();
    for g in el.children("goalState") {
        let (time_start, time_end) = match g.child("time") {
            Some(t) => {
                let (a, b) = cx.interval(t)?;
                (a as i64, b as i64)
            }
            None => (0, i64::MAX),
        };
        let mut shapes = Vec::new();
        if let Some(pos) = g.child("position") {
            for s in &pos.children {
                shapes.push(match s.name.as_str() {
                    "rectangle" => GoalShape::Rectangle {
                        center: cx
                            .point(s.child("center").ok_or_else(|| cx.err(s, "<rectangle> has no <center>".into()))?)?,
                        length: cx.field(s, "length")?,
                        width: cx.field(s, "width")?,
                        orientation: s.child("orientation").map(|o| cx.number(o)).transpose()?.unwrap_or(0.0),
                    },
                    "circle" => GoalShape::Circle {
                        center: cx
                            .point(s.child("center").ok_or_else(|| cx.err(s, "<circle> has no <center>".into()))?)?,
                        radius: cx.field(s, "radius")?,
                    },
                    "polygon" => GoalShape::Polygon {
                        points: s.children("point").map(|p| cx.point(p)).collect::<Result<_, _>>()?,
                    },
                    "lanelet" => GoalShape::Lanelets { ids: vec![cx.reference(s)?] },
                    "point" => GoalShape::Circle { center: cx.point(s)?, radius: 0.0 },
                    other => {
                        return Err(cx.err(
                            s,
                            format!("goal position <{other}> (allowed: rectangle, circle, polygon, lanelet, point)"),
                        ));
                    }
                });
            }
        }
        goals.push(GoalState { shapes, time_start, time_end });
    }
    Ok(PlanningProblem { id, initial_state, goals })
}

/// Parsed `<lanelet>` before ids are linked.
struct RawLanelet<'a> {
    el: &'a Element,
    id: i64,
    left: Vec<DVec2>,
    right: Vec<DVec2>,
    left_marking: Option<String>,
    right_marking: Option<String>,
}

fn build_map(root: &Element, cx: &Ctx, warnings: &mut Vec<MapWarning>) -> Result<LaneletMap, MapError> {
    let mut raw = Vec::new();
    let mut first_line: BTreeMap<i64, usize> = BTreeMap::new();
    for el in root.children("lanelet") {
        let id = cx.id(el)?;
        if id < 0 || id >= i64::MAX / (2 * NODE_IDS_PER_LANELET) {
            return Err(cx.err(el, format!("lanelet id {id} must be in 0..{}", i64::MAX / (2 * NODE_IDS_PER_LANELET))));
        }
        if let Some(first) = first_line.insert(id, el.line) {
            return Err(cx.err(el, format!("duplicate lanelet id {id} (first defined on line {first})")));
        }
        let side = |name: &str| {
            el.child(name).ok_or_else(|| cx.err(el, format!("lanelet {id} has no <{name}>"))).and_then(|b| cx.bound(b))
        };
        let (left, left_marking) = side("leftBound")?;
        let (right, right_marking) = side("rightBound")?;
        if left.len().max(right.len()) as i64 >= RIGHT_BOUND_NODE_OFFSET {
            return Err(cx.err(el, format!("lanelet {id}: a bound has more than {RIGHT_BOUND_NODE_OFFSET} points")));
        }
        raw.push(RawLanelet { el, id, left, right, left_marking, right_marking });
    }
    if raw.is_empty() {
        return Err(cx.err(root, "the scenario has no <lanelet>; nothing to drive on".into()));
    }
    raw.sort_by_key(|r| r.id);
    let index: BTreeMap<LaneletId, usize> = raw.iter().enumerate().map(|(i, r)| (LaneletId(r.id), i)).collect();

    // Successors: the file's successor lists plus reversed predecessor lists.
    let mut successors: Vec<Vec<LaneletId>> = vec![Vec::new(); raw.len()];
    for (i, r) in raw.iter().enumerate() {
        for (kind, list) in [("successor", true), ("predecessor", false)] {
            for s in r.el.children(kind) {
                let other = cx.reference(s)?;
                let Some(&j) = index.get(&LaneletId(other)) else {
                    warnings.push(MapWarning {
                        at: cx.at(s),
                        message: format!("lanelet {}: {kind} {other} is not in the file; ignored", r.id),
                    });
                    continue;
                };
                let (from, to) = if list { (i, j) } else { (j, i) };
                let to_id = LaneletId(raw[to].id);
                if from != to && !successors[from].contains(&to_id) {
                    successors[from].push(to_id);
                }
            }
        }
    }

    let projector = Projector::new(0.0, 0.0);
    let mut nodes = BTreeMap::new();
    let mut ways = BTreeMap::new();
    let mut tag_index: BTreeMap<String, Vec<i64>> = BTreeMap::new();
    let mut lanelets = Vec::with_capacity(raw.len());
    for (i, r) in raw.iter().enumerate() {
        let base = r.id * NODE_IDS_PER_LANELET;
        let mut bound_nodes = |points: &[DVec2], offset: i64| -> Vec<i64> {
            (0..points.len())
                .map(|k| {
                    let id = base + offset + k as i64;
                    let (lat, lon) = projector.reverse(points[k]);
                    nodes.insert(id, MapNode { id, lat, lon, position: points[k], tags: Tags::new() });
                    id
                })
                .collect()
        };
        let left_nodes = bound_nodes(&r.left, 0);
        let right_nodes = bound_nodes(&r.right, RIGHT_BOUND_NODE_OFFSET);
        for (node, value) in
            [(right_nodes[0], format!("start_{}", r.id)), (right_nodes[right_nodes.len() - 1], format!("end_{}", r.id))]
        {
            if let Some(n) = nodes.get_mut(&node) {
                n.tags.insert("commonroad".into(), value.clone());
            }
            tag_index.entry(value).or_default().push(node);
        }
        for (way_id, node_ids, points, marking) in [
            (2 * r.id, &left_nodes, &r.left, &r.left_marking),
            (2 * r.id + 1, &right_nodes, &r.right, &r.right_marking),
        ] {
            let mut tags = Tags::new();
            if let Some(m) = marking {
                tags.insert("line_marking".into(), m.clone());
                let line_type = match m.as_str() {
                    "solid" | "broad_solid" => Some("exterior"),
                    "dashed" | "broad_dashed" => Some("interior"),
                    _ => None,
                };
                if let Some(t) = line_type {
                    tags.insert("line_type".into(), t.into());
                }
            }
            ways.insert(way_id, MapWay { id: way_id, nodes: node_ids.clone(), points: points.clone(), tags });
        }
        let mut tags = Tags::new();
        tags.insert("type".into(), "lanelet".into());
        let types: Vec<String> = r.el.children("laneletType").map(|t| t.text.trim().to_string()).collect();
        if !types.is_empty() {
            tags.insert("lanelet_type".into(), types.join(";"));
        }
        for (name, key) in [("adjacentLeft", "adjacent_left"), ("adjacentRight", "adjacent_right")] {
            if let Some(a) = r.el.child(name) {
                tags.insert(key.into(), cx.reference(a)?.to_string());
                if let Some(d) = a.attr("drivingDir") {
                    tags.insert(format!("{key}_driving_dir"), d.to_string());
                }
            }
        }
        let not_for_vehicles = !types.is_empty() && types.iter().all(|t| NON_VEHICLE_TYPES.contains(&t.as_str()));
        let (mut left, mut right) = (r.left.clone(), r.right.clone());
        if left.len() != right.len() {
            let n = left.len().max(right.len());
            left = resample_count(&left, n);
            right = resample_count(&right, n);
        }
        let centre: Vec<DVec2> = left.iter().zip(&right).map(|(l, r)| (*l + *r) * 0.5).collect();
        lanelets.push(Lanelet {
            id: LaneletId(r.id),
            left_way: 2 * r.id,
            right_way: 2 * r.id + 1,
            left_nodes,
            right_nodes,
            length: polyline_length(&centre),
            left,
            right,
            centre,
            successors: std::mem::take(&mut successors[i]),
            routable: !not_for_vehicles,
            bidirectional: false,
            tags,
        });
    }
    let graph_lanelets: Vec<GraphLanelet<'_>> = lanelets
        .iter()
        .map(|l| GraphLanelet {
            routable: l.routable,
            bidirectional: false,
            right_nodes: &l.right_nodes,
            left_nodes: &l.left_nodes,
            length: l.length,
            centre_ends: (l.centre.first().copied().unwrap_or_default(), l.centre.last().copied().unwrap_or_default()),
        })
        .collect();
    let explicit: Vec<Vec<usize>> =
        lanelets.iter().map(|l| l.successors.iter().filter_map(|s| index.get(s).copied()).collect()).collect();
    let graph = RoutingGraph::with_successors(&graph_lanelets, &explicit);
    Ok(LaneletMap {
        projector,
        origin_node: None,
        nodes,
        ways,
        lanelets,
        tag_index,
        warnings: Vec::new(),
        index,
        graph,
    })
}
