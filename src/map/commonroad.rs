//! CommonRoad scenario XML (formats 2018b and 2020a) -> a [`LaneletMap`] plus the scenario's
//! obstacles and planning problems.
//!
//! CommonRoad is Cartesian: points are in metres, there is no projection (the map's projector
//! sits at lat/lon 0, 0 only so that every [`MapNode`] has some lat/lon). What is read:
//! - `<lanelet id>` with `<leftBound>`/`<rightBound>` of `<point><x/><y/></point>`s in driving
//!   direction and an optional `<lineMarking>` each; `<predecessor ref>`, `<successor ref>`;
//!   `<adjacentLeft ref drivingDir>`, `<adjacentRight ref drivingDir>`; `<laneletType>`.
//!   Lanelet ids are those of the file; successors are the file's successor lists plus the
//!   reverse of its predecessor lists (never derived from geometry). A file without lanelets
//!   loads with a warning when it has obstacles (commonroad-io reads such files too).
//! - dynamic obstacles: 2020a `<dynamicObstacle>`; 2018b `<obstacle>` with `<role>dynamic</role>`.
//!   Each has a `<type>`, a `<shape>` (a `<rectangle>`'s length and width; a circle, polygon or
//!   several shapes count as the rectangle around them, with a warning), an `<initialState>` and
//!   a `<trajectory>` of `<state>`s, each with a `<position>`, `<orientation>`, `<time>` (an
//!   integer time step) and `<velocity>`; an interval value counts as its middle. A position is a
//!   `<point>` or a shape (`<rectangle>`, `<circle>`, `<polygon>`, or several of them: an
//!   uncertain position), read at the shape's centre (a polygon's centre is the mean of its
//!   corners; several shapes: the mean of their centres). A trajectory state at the initial
//!   state's time step that repeats it is dropped (2018b files do that); `<occupancySet>`s and
//!   signal states are not read.
//! - static obstacles: 2020a `<staticObstacle>`; 2018b `<obstacle>` with `<role>static</role>`:
//!   `<type>`, `<shape>` (one or more rectangles, circles, polygons in the obstacle's frame) and
//!   `<initialState>` (where that frame is). They never move. See [`StaticObstacle`].
//! - environment obstacles (2020a `<environmentObstacle>`, e.g. `building`): `<type>` and
//!   `<shape>` in map coordinates. Phantom obstacles are not read.
//! - `<planningProblem>`: its `<initialState>` and the position and time of its `<goalState>`s.
//!
//! Synthetic ids, so that the OSM-based tools work unchanged: the k-th point of lanelet L's left
//! bound is node `L * 100000 + k`, of its right bound node `L * 100000 + 50000 + k`; the bounds
//! are ways `2 L` (left) and `2 L + 1` (right), tagged `line_marking=<value>` and drawn like the
//! SML maps (`solid`/`broad_solid` as `line_type=exterior`, `dashed`/`broad_dashed` as
//! `interior`, other markings not drawn). The first right-bound node of lanelet L carries the tag
//! value `start_L` and the last one `end_L`, so `smlworld map route FILE.xml --from-tag start_1
//! --to-tag end_5` routes from the start of lanelet 1 to the end of lanelet 5. The outline of
//! every static and environment obstacle shape is a closed way tagged `obstacle=<type>`,
//! `obstacle_role=static|environment` and `obstacle_id=<id>`, so maps draw them; these ways and
//! their nodes have negative ids (-1, -2, ... in file order).

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path as FsPath;

use glam::DVec2;
use quick_xml::Reader;
use quick_xml::events::Event;

use super::error::{Location, MapError, MapWarning};
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
    /// Position \[m\].
    pub position: DVec2,
    /// Heading, counter-clockwise from the x axis \[rad\].
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
    /// Length of its rectangle \[m\].
    pub length: f64,
    /// Width of its rectangle \[m\].
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

/// A static obstacle (parked vehicle, road boundary, construction zone, ...): it never moves.
/// For collisions and sensors it is one oriented rectangle around all its shapes (its length
/// axis along the state's orientation plus, for a single polygon, the polygon's longest edge,
/// so a rectangle given as a polygon keeps its size); maps draw each shape's outline.
#[derive(Debug, Clone, PartialEq)]
pub struct StaticObstacle {
    /// Obstacle id as in the file.
    pub id: i64,
    /// `<type>` (`parkedVehicle`, `roadBoundary`, `constructionZone`, `building`, ...).
    pub kind: String,
    /// Centre of the rectangle around its shapes \[m\].
    pub position: DVec2,
    /// Heading of that rectangle's length axis \[rad\].
    pub orientation: f64,
    /// Length of that rectangle \[m\].
    pub length: f64,
    /// Width of that rectangle \[m\].
    pub width: f64,
    /// Outline of each shape in map coordinates \[m\] (circles as 24-gons).
    pub outlines: Vec<Vec<DVec2>>,
}

/// An environment obstacle (2020a `<environmentObstacle>`: `building`, `pillar`, ...), drawn only.
#[derive(Debug, Clone, PartialEq)]
pub struct EnvironmentObstacle {
    /// Obstacle id as in the file.
    pub id: i64,
    /// `<type>`.
    pub kind: String,
    /// Outline of each shape in map coordinates \[m\].
    pub outlines: Vec<Vec<DVec2>>,
}

/// Goal position of a planning problem, or one shape of an obstacle or of an uncertain position.
#[derive(Debug, Clone, PartialEq)]
pub enum GoalShape {
    /// A rectangle of `length` x `width` \[m\] around `center`, turned by `orientation` \[rad\].
    Rectangle {
        /// Centre \[m\].
        center: DVec2,
        /// Along its orientation \[m\].
        length: f64,
        /// Across \[m\].
        width: f64,
        /// Heading of its length axis \[rad\].
        orientation: f64,
    },
    /// A circle.
    Circle {
        /// Centre \[m\].
        center: DVec2,
        /// Radius \[m\].
        radius: f64,
    },
    /// A polygon (any orientation).
    Polygon {
        /// Corners \[m\].
        points: Vec<DVec2>,
    },
    /// Any point of these lanelets.
    Lanelets {
        /// Lanelet ids.
        ids: Vec<i64>,
    },
}

/// Sides of the polygon that stands for a circle in outlines.
const CIRCLE_SIDES: usize = 24;

impl GoalShape {
    /// The shape's centre \[m\]: a rectangle's or circle's centre, the mean of a polygon's corners
    /// (a closing point that repeats the first is not counted twice); `None` for lanelets.
    pub fn centre(&self) -> Option<DVec2> {
        match self {
            GoalShape::Rectangle { center, .. } | GoalShape::Circle { center, .. } => Some(*center),
            GoalShape::Polygon { points } => {
                let corners = open_ring(points);
                (!corners.is_empty()).then(|| corners.iter().copied().sum::<DVec2>() / corners.len() as f64)
            }
            GoalShape::Lanelets { .. } => None,
        }
    }

    /// The outline \[m\], counter-clockwise for rectangles and circles (a circle as a
    /// 24-gon), a polygon's corners as given without a repeated closing point; empty for lanelets.
    pub fn outline(&self) -> Vec<DVec2> {
        match self {
            GoalShape::Rectangle { center, length, width, orientation } => {
                let (along, across) = (DVec2::from_angle(*orientation), DVec2::from_angle(*orientation).perp());
                [(1.0, -1.0), (1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0)]
                    .map(|(a, c)| *center + along * (a * length / 2.0) + across * (c * width / 2.0))
                    .to_vec()
            }
            GoalShape::Circle { center, radius } => (0..CIRCLE_SIDES)
                .map(|k| *center + DVec2::from_angle(std::f64::consts::TAU * k as f64 / CIRCLE_SIDES as f64) * *radius)
                .collect(),
            GoalShape::Polygon { points } => open_ring(points).to_vec(),
            GoalShape::Lanelets { .. } => Vec::new(),
        }
    }

    /// Whether `p` \[m\] lies in the goal shape (lanelets: inside one of their polygons).
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

/// `points` without a last point that repeats the first.
fn open_ring(points: &[DVec2]) -> &[DVec2] {
    match points {
        [first, .., last] if points.len() > 1 && first == last => &points[..points.len() - 1],
        _ => points,
    }
}

/// The rectangle around `points` whose length axis has heading `angle` [rad]: its centre [m],
/// length (along `angle`) and width [m].
fn box_around(points: &[DVec2], angle: f64) -> (DVec2, f64, f64) {
    let (along, across) = (DVec2::from_angle(angle), DVec2::from_angle(angle).perp());
    let (mut lo, mut hi) = (DVec2::splat(f64::INFINITY), DVec2::splat(f64::NEG_INFINITY));
    for p in points {
        let q = DVec2::new(p.dot(along), p.dot(across));
        (lo, hi) = (lo.min(q), hi.max(q));
    }
    let mid = (lo + hi) / 2.0;
    (along * mid.x + across * mid.y, hi.x - lo.x, hi.y - lo.y)
}

/// Heading of the longest edge of a closed outline [rad] (0 for fewer than two points).
fn longest_edge_heading(outline: &[DVec2]) -> f64 {
    let n = outline.len();
    (0..n)
        .map(|i| outline[(i + 1) % n] - outline[i])
        .max_by(|a, b| a.length_squared().total_cmp(&b.length_squared()))
        .filter(|d| d.length_squared() > 0.0)
        .map_or(0.0, |d| d.y.atan2(d.x))
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
    /// Time step \[s\] (`timeStepSize`).
    pub time_step_size: f64,
    /// The road network.
    pub map: LaneletMap,
    /// Dynamic obstacles, sorted by id.
    pub obstacles: Vec<DynamicObstacle>,
    /// Static obstacles, sorted by id.
    pub static_obstacles: Vec<StaticObstacle>,
    /// Environment obstacles (buildings, ...), sorted by id.
    pub environment_obstacles: Vec<EnvironmentObstacle>,
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
            Event::End(_) if stack.len() > 1 => {
                let el = stack.pop().unwrap_or_default();
                if let Some(parent) = stack.last_mut() {
                    parent.children.push(el);
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
        let position = self.position(need("position")?)?;
        let time = self.value(need("time")?)?;
        if time.fract() != 0.0 {
            return Err(self.err(el, format!("<time> {time} is not an integer time step")));
        }
        Ok(CommonRoadState {
            time_step: time as i64,
            position,
            orientation: el.child("orientation").map(|o| self.value(o)).transpose()?.unwrap_or(0.0),
            velocity: el.child("velocity").map(|v| self.value(v)).transpose()?.unwrap_or(0.0),
        })
    }

    /// A state's `<position>`: a `<point>`, or the centre of its shape (several shapes: the mean
    /// of their centres).
    fn position(&self, pos: &Element) -> Result<DVec2, MapError> {
        if let Some(p) = pos.child("point") {
            return self.point(p);
        }
        let mut centres = Vec::new();
        for s in &pos.children {
            let shape = self.shape(s)?;
            centres.push(shape.centre().ok_or_else(|| {
                self.err(s, format!("a <{}> position has no centre; states need a point or a shape", s.name))
            })?);
        }
        if centres.is_empty() {
            return Err(self.err(pos, "<position> has no <point>, <rectangle>, <circle> or <polygon>".into()));
        }
        Ok(centres.iter().copied().sum::<DVec2>() / centres.len() as f64)
    }

    /// One shape: `<rectangle>` (length, width, optional orientation and centre), `<circle>`
    /// (radius, optional centre), `<polygon>` (at least 3 points) or `<lanelet ref>`.
    fn shape(&self, s: &Element) -> Result<GoalShape, MapError> {
        let center = |s: &Element| s.child("center").map_or(Ok(DVec2::ZERO), |c| self.point(c));
        let positive = |name: &str| {
            let v = self.field(s, name)?;
            if v > 0.0 { Ok(v) } else { Err(self.err(s, format!("<{}> {name} {v} must be positive", s.name))) }
        };
        Ok(match s.name.as_str() {
            "rectangle" => GoalShape::Rectangle {
                center: center(s)?,
                length: positive("length")?,
                width: positive("width")?,
                orientation: s.child("orientation").map(|o| self.number(o)).transpose()?.unwrap_or(0.0),
            },
            "circle" => GoalShape::Circle { center: center(s)?, radius: positive("radius")? },
            "polygon" => {
                let points: Vec<DVec2> = s.children("point").map(|p| self.point(p)).collect::<Result<_, _>>()?;
                if open_ring(&points).len() < 3 {
                    return Err(
                        self.err(s, format!("<polygon> has {} points; a polygon needs at least 3", points.len()))
                    );
                }
                GoalShape::Polygon { points }
            }
            "lanelet" => GoalShape::Lanelets { ids: vec![self.reference(s)?] },
            "point" => GoalShape::Circle { center: self.point(s)?, radius: 0.0 },
            other => {
                return Err(self
                    .err(s, format!("unknown shape <{other}> (allowed: rectangle, circle, polygon, lanelet, point)")));
            }
        })
    }

    /// Every shape under `<shape>` of `el`; an error when there is none.
    fn shapes(&self, el: &Element) -> Result<Vec<GoalShape>, MapError> {
        let shape = el.child("shape").ok_or_else(|| self.err(el, format!("<{}> has no <shape>", el.name)))?;
        let shapes = shape.children.iter().map(|s| self.shape(s)).collect::<Result<Vec<_>, _>>()?;
        // A <lanelet> or <point> (a circle of radius 0) has no area: not an obstacle's shape.
        let no_area = |s: &GoalShape| match s {
            GoalShape::Lanelets { .. } => true,
            GoalShape::Circle { radius, .. } => *radius <= 0.0,
            _ => false,
        };
        if shapes.is_empty() || shapes.iter().any(no_area) {
            return Err(self.err(shape, "<shape> needs one or more <rectangle>, <circle> or <polygon>".into()));
        }
        Ok(shapes)
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
        let (mut obstacles, mut static_obstacles, mut environment_obstacles) = (Vec::new(), Vec::new(), Vec::new());
        for el in &root.children {
            let role = el.child("role").map(|r| r.text.trim());
            match (el.name.as_str(), role) {
                ("dynamicObstacle", _) | ("obstacle", Some("dynamic")) => {
                    obstacles.push(obstacle(el, &cx, &mut warnings)?);
                }
                ("staticObstacle", _) | ("obstacle", Some("static")) => {
                    static_obstacles.push(static_obstacle(el, &cx)?)
                }
                ("environmentObstacle", _) => environment_obstacles.push(environment_obstacle(el, &cx)?),
                ("obstacle", role) => {
                    return Err(cx.err(
                        el,
                        format!(
                            "obstacle {}: <role> {role:?} is neither `dynamic` nor `static`",
                            el.attr("id").unwrap_or("?")
                        ),
                    ));
                }
                _ => {}
            }
        }
        if map.lanelets.is_empty()
            && obstacles.is_empty()
            && static_obstacles.is_empty()
            && environment_obstacles.is_empty()
        {
            return Err(cx.err(&root, "the scenario has no <lanelet> and no obstacle; nothing to load".into()));
        }
        obstacles.sort_by_key(|o| o.id);
        static_obstacles.sort_by_key(|o| o.id);
        environment_obstacles.sort_by_key(|o| o.id);
        let mut planning_problems = Vec::new();
        for el in root.children("planningProblem") {
            planning_problems.push(planning_problem(el, &cx)?);
        }
        planning_problems.sort_by_key(|p| p.id);
        let mut map = map;
        map.warnings.extend(warnings);
        add_obstacle_ways(&mut map, &static_obstacles, &environment_obstacles);
        Ok(CommonRoadScenario {
            version,
            time_step_size,
            map,
            obstacles,
            static_obstacles,
            environment_obstacles,
            planning_problems,
        })
    }
}

/// `e` with `what` (an obstacle named by id) in front of its message.
fn about(e: MapError, what: &str) -> MapError {
    match e {
        MapError::CommonRoad { at, message } => MapError::CommonRoad { at, message: format!("{what}: {message}") },
        other => other,
    }
}

fn kind_of(el: &Element) -> String {
    el.child("type").map(|t| t.text.trim().to_string()).unwrap_or_else(|| "unknown".into())
}

fn obstacle(el: &Element, cx: &Ctx, warnings: &mut Vec<MapWarning>) -> Result<DynamicObstacle, MapError> {
    let id = cx.id(el)?;
    let what = format!("obstacle {id}");
    let kind = kind_of(el);
    let shapes = cx.shapes(el).map_err(|e| about(e, &what))?;
    let (length, width) = match shapes.as_slice() {
        [GoalShape::Rectangle { length, width, .. }] => (*length, *width),
        _ => {
            let outline: Vec<DVec2> = shapes.iter().flat_map(GoalShape::outline).collect();
            let (_, length, width) = box_around(&outline, 0.0);
            warnings.push(MapWarning {
                at: cx.at(el),
                message: format!(
                    "{what}: its shape is not one rectangle; drawn and checked as the {length:.2} m x {width:.2} m rectangle around it"
                ),
            });
            (length, width)
        }
    };
    let mut states = Vec::new();
    if let Some(s) = el.child("initialState") {
        states.push(cx.state(s).map_err(|e| about(e, &what))?);
    }
    if let Some(t) = el.child("trajectory") {
        for s in t.children("state") {
            let state = cx.state(s).map_err(|e| about(e, &what))?;
            // 2018b trajectories may repeat the initial state.
            if states.first().is_some_and(|first: &CommonRoadState| {
                first.time_step == state.time_step && first.position == state.position
            }) {
                continue;
            }
            states.push(state);
        }
    }
    if states.is_empty() {
        return Err(cx.err(el, format!("{what} has no <initialState> and no <trajectory> states")));
    }
    states.sort_by_key(|s| s.time_step);
    if let Some(w) = states.windows(2).find(|w| w[0].time_step == w[1].time_step) {
        return Err(cx.err(el, format!("{what} has two different states at time step {}", w[0].time_step)));
    }
    Ok(DynamicObstacle { id, kind, length, width, states })
}

fn static_obstacle(el: &Element, cx: &Ctx) -> Result<StaticObstacle, MapError> {
    let id = cx.id(el)?;
    let what = format!("static obstacle {id}");
    let shapes = cx.shapes(el).map_err(|e| about(e, &what))?;
    let initial = el.child("initialState").ok_or_else(|| cx.err(el, format!("{what} has no <initialState>")))?;
    let state = cx.state(initial).map_err(|e| about(e, &what))?;
    let frame = |p: DVec2| state.position + DVec2::from_angle(state.orientation).rotate(p);
    let outlines: Vec<Vec<DVec2>> = shapes.iter().map(|s| s.outline().into_iter().map(frame).collect()).collect();
    let local = match shapes.as_slice() {
        [GoalShape::Rectangle { orientation, .. }] => *orientation,
        [GoalShape::Polygon { points }] => longest_edge_heading(open_ring(points)),
        _ => 0.0,
    };
    let orientation = state.orientation + local;
    let all: Vec<DVec2> = outlines.iter().flatten().copied().collect();
    let (position, length, width) = box_around(&all, orientation);
    Ok(StaticObstacle { id, kind: kind_of(el), position, orientation, length, width, outlines })
}

fn environment_obstacle(el: &Element, cx: &Ctx) -> Result<EnvironmentObstacle, MapError> {
    let id = cx.id(el)?;
    let shapes = cx.shapes(el).map_err(|e| about(e, &format!("environment obstacle {id}")))?;
    Ok(EnvironmentObstacle { id, kind: kind_of(el), outlines: shapes.iter().map(GoalShape::outline).collect() })
}

/// Each obstacle shape as a closed way (see the module docs), ids -1, -2, ... in file order.
fn add_obstacle_ways(map: &mut LaneletMap, statics: &[StaticObstacle], environment: &[EnvironmentObstacle]) {
    let shapes = statics
        .iter()
        .flat_map(|o| o.outlines.iter().map(move |l| (o.id, &o.kind, "static", l)))
        .chain(environment.iter().flat_map(|o| o.outlines.iter().map(move |l| (o.id, &o.kind, "environment", l))));
    let (mut next_way, mut next_node) = (-1i64, -1i64);
    for (id, kind, role, outline) in shapes {
        let mut points = outline.clone();
        points.extend(outline.first().copied());
        let mut nodes: Vec<i64> = Vec::with_capacity(points.len());
        for &p in outline {
            let (lat, lon) = map.projector.reverse(p);
            map.nodes.insert(next_node, MapNode { id: next_node, lat, lon, position: p, tags: Tags::new() });
            nodes.push(next_node);
            next_node -= 1;
        }
        nodes.extend(nodes.first().copied());
        let mut tags = Tags::new();
        tags.insert("obstacle".into(), kind.clone());
        tags.insert("obstacle_role".into(), role.into());
        tags.insert("obstacle_id".into(), id.to_string());
        map.ways.insert(next_way, MapWay { id: next_way, nodes, points, tags });
        next_way -= 1;
    }
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
                shapes.push(cx.shape(s).map_err(|e| about(e, &format!("planning problem {id}, goal position")))?);
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
        if !(0..i64::MAX / (2 * NODE_IDS_PER_LANELET)).contains(&id) {
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
        warnings.push(MapWarning {
            at: cx.at(root),
            message: "the scenario has no <lanelet>: nothing to drive on (obstacles only)".into(),
        });
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

    // Traffic lights and signs by id, for the lanelets that refer to them: a light makes the
    // junction the lanelet leads into signalled, a stop or yield sign makes its arm minor, a
    // priority-road sign major ([`super::junctions`] reads the tags up to 30 m upstream).
    let lights: BTreeSet<i64> = root.children("trafficLight").filter_map(|t| cx.id(t).ok()).collect();
    let mut signs: BTreeMap<i64, Vec<String>> = BTreeMap::new();
    for sign in root.children("trafficSign") {
        let Ok(id) = cx.id(sign) else { continue };
        let ids = sign
            .children("trafficSignElement")
            .filter_map(|e| e.child("trafficSignID"))
            .map(|t| t.text.trim().to_string())
            .collect();
        signs.insert(id, ids);
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
        let light_refs: Vec<i64> =
            r.el.children("trafficLightRef").map(|t| cx.reference(t)).collect::<Result<_, _>>()?;
        for &light in &light_refs {
            if !lights.contains(&light) {
                warnings.push(MapWarning {
                    at: cx.at(r.el),
                    message: format!("lanelet {}: trafficLightRef {light} is not in the file; ignored", r.id),
                });
            }
        }
        let light_refs: Vec<String> =
            light_refs.into_iter().filter(|l| lights.contains(l)).map(|l| l.to_string()).collect();
        if !light_refs.is_empty() {
            tags.insert("traffic_light".into(), "yes".into());
            tags.insert("commonroad:traffic_light".into(), light_refs.join(";"));
        }
        let mut sign_ids = Vec::new();
        for t in r.el.children("trafficSignRef") {
            let sign = cx.reference(t)?;
            match signs.get(&sign) {
                Some(ids) => sign_ids.extend(ids.iter().cloned()),
                None => warnings.push(MapWarning {
                    at: cx.at(t),
                    message: format!("lanelet {}: trafficSignRef {sign} is not in the file; ignored", r.id),
                }),
            }
        }
        if let Some(priority) = super::junctions::sign_priority(&sign_ids) {
            tags.insert("priority".into(), priority.into());
        }
        if !sign_ids.is_empty() {
            tags.insert("commonroad:traffic_sign".into(), sign_ids.join(";"));
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
    Ok(LaneletMap::from_parts(projector, nodes, ways, lanelets, tag_index, Vec::new()))
}
