//! The parsed OpenDRIVE model: roads (reference line, lane offsets, lane sections, lanes,
//! links, speed records, signals) and junctions (connections, lane links, controllers,
//! priorities) and the file's controllers, read from the element tree with every problem tied
//! to its line and id.
//!
//! Elements this reader does not use (elevation, lateral profile, objects, user data, ...) are
//! gathered by name; each name gives one warning with its first line and count.

use std::collections::BTreeMap;
use std::path::Path as FsPath;

use glam::DVec2;

use super::geometry::{Cubic, Geometry, Shape};
use super::xml::Element;
use crate::map::error::{Location, MapError, MapWarning};

/// Longest road or geometry accepted \[m\]: sampling is proportional to length, so a typo such as
/// `length="1e12"` in a small file would otherwise ask for billions of points.
pub const MAX_LENGTH: f64 = 100_000.0;

/// A cubic polynomial record (`laneOffset`, `width`, `border`) starting at `s`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Poly {
    /// Start along the road \[m\] (absolute: a lane record's `sOffset` plus its section's `s`).
    pub s: f64,
    /// a, b, c, d of a + b ds + c ds² + d ds³.
    pub c: [f64; 4],
}

impl Poly {
    /// Value at `s` \[m\].
    pub fn value(&self, s: f64) -> f64 {
        let x = s - self.s;
        self.c[0] + x * (self.c[1] + x * (self.c[2] + x * self.c[3]))
    }

    /// |second derivative| at most, over [a, b] [1/m].
    pub fn max_second_derivative(&self, a: f64, b: f64) -> f64 {
        let dd = |s: f64| (2.0 * self.c[2] + 6.0 * self.c[3] * (s - self.s)).abs();
        dd(a).max(dd(b))
    }
}

/// The record of `list` in force at `s` (the last one starting at or before it; the first one
/// before all of them).
pub fn record_at(list: &[Poly], s: f64) -> Option<&Poly> {
    let k = list.partition_point(|p| p.s <= s + 1e-9);
    list.get(k.saturating_sub(1))
}

/// A `<roadMark>` record.
#[derive(Debug, Clone, PartialEq)]
pub struct RoadMark {
    /// Start along the road \[m\] (absolute).
    pub s: f64,
    /// `type`: `solid`, `broken`, `solid broken`, `curb`, `none`, ...
    pub kind: String,
    /// `color` (`standard` is white).
    pub color: String,
    /// `laneChange`: `increase`, `decrease`, `both`, `none`, if given.
    pub lane_change: Option<String>,
    /// `weight`: `standard` or `bold`.
    pub weight: String,
}

/// One lane of a lane section.
#[derive(Debug, Clone, PartialEq)]
pub struct Lane {
    /// Lane id: positive left of the reference line, negative right, 0 the centre lane.
    pub id: i32,
    /// `type` (`driving`, `sidewalk`, ...).
    pub kind: String,
    /// `width` records, in order.
    pub widths: Vec<Poly>,
    /// `border` records, in order (used where a lane has no `width`).
    pub borders: Vec<Poly>,
    /// Road marks of its outer border (the centre lane: of the reference line), in order.
    pub marks: Vec<RoadMark>,
    /// Lane id in the previous section (or the preceding road).
    pub predecessor: Option<i32>,
    /// Lane id in the next section (or the following road).
    pub successor: Option<i32>,
    /// Speed limit from a lane `<speed>` record [m/s].
    pub speed: Option<f64>,
    /// OpenDRIVE 1.7 `direction`: `standard`, `reversed` or `both`.
    pub direction: String,
    /// Line of the `<lane>` element.
    pub line: usize,
}

/// A lane section: lanes from `s` to the next section (or the road's end).
#[derive(Debug, Clone, PartialEq)]
pub struct LaneSection {
    /// Start along the road \[m\].
    pub s: f64,
    /// End along the road \[m\].
    pub end: f64,
    /// Left lanes, from the centre out (1, 2, ...).
    pub left: Vec<Lane>,
    /// Right lanes, from the centre out (-1, -2, ...).
    pub right: Vec<Lane>,
    /// The centre lane (its road marks).
    pub centre: Option<Lane>,
    /// Line of the `<laneSection>` element.
    pub line: usize,
    /// Its index among the road's lane sections in the file (0-based, in order of `s`): what
    /// the `opendrive:section` tag and `ROAD:SECTION:LANE` name.
    pub index: usize,
}

impl LaneSection {
    /// The lane with this id (not the centre lane).
    pub fn lane(&self, id: i32) -> Option<&Lane> {
        let side = if id > 0 { &self.left } else { &self.right };
        side.iter().find(|l| l.id == id)
    }
}

/// Where a road link attaches on the other element.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Contact {
    /// Its start (s = 0).
    Start,
    /// Its end (s = length).
    End,
}

/// A road's `<predecessor>` or `<successor>`.
#[derive(Debug, Clone, PartialEq)]
pub enum RoadLink {
    /// Another road, at its start or end.
    Road {
        /// The road id.
        id: String,
        /// Where on it.
        contact: Contact,
        /// Line of the link element.
        line: usize,
    },
    /// A junction (its connections say which roads).
    Junction {
        /// The junction id.
        id: String,
    },
}

/// Which traffic a signal faces (its `orientation`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Facing {
    /// `+`: traffic driving along `s`.
    Along,
    /// `-`: traffic driving against `s`.
    Against,
    /// `none`: both ways.
    Both,
}

/// A road's `<signal>` or `<signalReference>` (a signal of another road that applies here too).
#[derive(Debug, Clone, PartialEq)]
pub struct Signal {
    /// `id` (of the referenced signal, for a `<signalReference>`).
    pub id: String,
    /// Position along the road \[m\].
    pub s: f64,
    /// Lateral position \[m\].
    pub t: f64,
    /// `orientation`.
    pub facing: Facing,
    /// `dynamic="yes"` (a light or a variable sign).
    pub dynamic: bool,
    /// `country` (`OpenDRIVE`, `DE`, ...; empty where not given).
    pub country: String,
    /// `type` (empty for a `<signalReference>` until the referenced signal is found).
    pub kind: String,
    /// `subtype`.
    pub subtype: String,
    /// `<validity fromLane toLane>` ranges (inclusive); empty: every lane it faces.
    pub validity: Vec<(i32, i32)>,
    /// Whether this is a `<signalReference>`.
    pub reference: bool,
    /// Line of the element.
    pub line: usize,
}

/// A top-level `<controller>`: signals that always show the same state (one signal group).
#[derive(Debug, Clone, PartialEq)]
pub struct Controller {
    /// `id`.
    pub id: String,
    /// `<control signalId>`s, in file order.
    pub signals: Vec<String>,
    /// Line of the element.
    pub line: usize,
}

/// One `<road>`.
#[derive(Debug, Clone, PartialEq)]
pub struct Road {
    /// `id`.
    pub id: String,
    /// `length` \[m\].
    pub length: f64,
    /// `junction` (`-1` outside junctions).
    pub junction: String,
    /// `rule="LHT"`: left-hand traffic.
    pub left_hand: bool,
    /// `<link><predecessor>`.
    pub predecessor: Option<RoadLink>,
    /// `<link><successor>`.
    pub successor: Option<RoadLink>,
    /// `<planView>` records, in order.
    pub geometries: Vec<Geometry>,
    /// `<laneOffset>` records, in order.
    pub lane_offsets: Vec<Poly>,
    /// Lane sections, in order.
    pub sections: Vec<LaneSection>,
    /// Road `<type>` speed records: (start \[m\], limit [m/s]).
    pub speeds: Vec<(f64, f64)>,
    /// `<signals>`: its signals and signal references, in file order.
    pub signals: Vec<Signal>,
    /// Where a lane section at the road's start (`start_lanes`) or end (`end_lanes`) was merged
    /// away (shorter than 2 cm): the file's lane ids there -> the lane ids of the section that
    /// took its place, for links from other roads and junctions. `None`: no merge, ids as is.
    pub start_lanes: Option<std::collections::BTreeMap<i32, i32>>,
    /// See `start_lanes`.
    pub end_lanes: Option<std::collections::BTreeMap<i32, i32>>,
    /// Line of the `<road>` element.
    pub line: usize,
}

impl Road {
    /// Reference-line position \[m\] and heading \[rad\] at `s` \[m\].
    pub fn reference(&self, s: f64) -> (DVec2, f64) {
        self.reference_at(s, s)
    }

    /// Reference-line position and heading at `s` on the geometry in force at `pick` (so a
    /// point where two geometries meet can be read at the end of the first).
    pub fn reference_at(&self, s: f64, pick: f64) -> (DVec2, f64) {
        let k = self.geometries.partition_point(|g| g.s <= pick + 1e-9).saturating_sub(1);
        let g = &self.geometries[k];
        g.eval(s - g.s)
    }

    /// Lane offset at `s` \[m\].
    pub fn offset(&self, s: f64) -> f64 {
        record_at(&self.lane_offsets, s).map_or(0.0, |p| p.value(s))
    }

    /// The geometry records that overlap [a, b].
    pub fn geometries_in(&self, a: f64, b: f64) -> impl Iterator<Item = &Geometry> {
        self.geometries.iter().filter(move |g| g.s < b - 1e-9 && g.s + g.length > a + 1e-9)
    }
}

/// A junction `<connection>`.
#[derive(Debug, Clone, PartialEq)]
pub struct Connection {
    /// `incomingRoad`.
    pub incoming: String,
    /// `connectingRoad`.
    pub connecting: String,
    /// `contactPoint` on the connecting road.
    pub contact: Contact,
    /// `<laneLink from to>` pairs.
    pub lane_links: Vec<(i32, i32)>,
    /// Line of the element.
    pub line: usize,
}

/// A `<junction>`.
#[derive(Debug, Clone, PartialEq)]
pub struct Junction {
    /// `id`.
    pub id: String,
    /// Its connections.
    pub connections: Vec<Connection>,
    /// Whether it names a `<controller>` (signals control it).
    pub controlled: bool,
    /// Its `<controller id sequence>`s: (controller id, `sequence` if given), in file order.
    pub controllers: Vec<(String, Option<i64>)>,
    /// Its `<priority high low>`s: (connecting road with priority, connecting road that yields,
    /// line).
    pub priorities: Vec<(String, String, usize)>,
    /// Line of the element.
    pub line: usize,
}

/// A whole parsed file.
#[derive(Debug, Clone, PartialEq)]
pub struct Document {
    /// `header/geoReference` origin (lat, lon) \[deg\], if it gives `+lat_0` and `+lon_0`.
    pub origin: Option<(f64, f64)>,
    /// Roads in file order.
    pub roads: Vec<Road>,
    /// Junctions in file order.
    pub junctions: Vec<Junction>,
    /// Top-level `<controller>`s in file order.
    pub controllers: Vec<Controller>,
}

/// Reads elements into the model, collecting unsupported elements by name.
pub(crate) struct Reader<'a> {
    source: &'a FsPath,
    /// Element path -> (count, first line).
    unsupported: BTreeMap<String, (usize, usize)>,
    /// Other warnings, in file order.
    notes: Vec<MapWarning>,
}

impl<'a> Reader<'a> {
    pub(crate) fn new(source: &'a FsPath) -> Reader<'a> {
        Reader { source, unsupported: BTreeMap::new(), notes: Vec::new() }
    }

    fn at(&self, line: usize) -> Location {
        Location { file: self.source.to_path_buf(), line }
    }

    /// An OpenDRIVE error at `el`.
    pub(crate) fn err(&self, el: &Element, message: String) -> MapError {
        MapError::OpenDrive { at: self.at(el.line), message }
    }

    /// Note every child of `el` whose name is not in `known`, as `parent/child`.
    fn others(&mut self, el: &Element, known: &[&str]) {
        for c in &el.children {
            if !known.contains(&c.name.as_str()) {
                let entry = self.unsupported.entry(format!("{}/{}", el.name, c.name)).or_insert((0, c.line));
                entry.0 += 1;
            }
        }
    }

    /// One warning per unsupported element name, then the other warnings.
    pub(crate) fn warnings(&self) -> Vec<MapWarning> {
        self.unsupported
            .iter()
            .map(|(name, &(count, line))| MapWarning {
                at: self.at(line).to_string(),
                message: format!(
                    "OpenDRIVE element <{name}> is not supported ({count} in the file, the first here); ignored"
                ),
            })
            .chain(self.notes.iter().cloned())
            .collect()
    }

    fn number(&self, el: &Element, name: &str, what: &str) -> Result<f64, MapError> {
        let v =
            el.attr(name).ok_or_else(|| self.err(el, format!("{what}: <{}> has no `{name}` attribute", el.name)))?;
        let x: f64 = v
            .trim()
            .parse()
            .map_err(|_| self.err(el, format!("{what}: <{}> `{name}` = {v:?} is not a number", el.name)))?;
        if !x.is_finite() {
            return Err(self.err(el, format!("{what}: <{}> `{name}` = {v:?} is not finite", el.name)));
        }
        Ok(x)
    }

    fn number_or(&self, el: &Element, name: &str, default: f64, what: &str) -> Result<f64, MapError> {
        if el.attr(name).is_some() { self.number(el, name, what) } else { Ok(default) }
    }

    fn coefficients(&self, el: &Element, names: [&str; 4], what: &str) -> Result<[f64; 4], MapError> {
        let mut c = [0.0; 4];
        for (k, n) in names.iter().enumerate() {
            c[k] = self.number_or(el, n, 0.0, what)?;
        }
        Ok(c)
    }

    fn integer(&self, el: &Element, name: &str, what: &str) -> Result<i32, MapError> {
        let v =
            el.attr(name).ok_or_else(|| self.err(el, format!("{what}: <{}> has no `{name}` attribute", el.name)))?;
        v.trim().parse().map_err(|_| self.err(el, format!("{what}: <{}> `{name}` = {v:?} is not an integer", el.name)))
    }

    fn contact(&self, el: &Element, what: &str) -> Result<Contact, MapError> {
        match el.attr("contactPoint").map(str::trim) {
            Some("start") => Ok(Contact::Start),
            Some("end") => Ok(Contact::End),
            Some(other) => Err(self.err(el, format!("{what}: contactPoint {other:?} is neither `start` nor `end`"))),
            None => Err(self.err(el, format!("{what}: <{}> has no `contactPoint`", el.name))),
        }
    }

    /// The whole document.
    pub(crate) fn document(&mut self, root: &Element) -> Result<Document, MapError> {
        self.others(root, &["header", "road", "junction", "controller"]);
        let origin = match root.child("header") {
            Some(h) => {
                self.others(h, &["geoReference"]);
                h.child("geoReference").and_then(|g| geo_origin(&g.text))
            }
            None => None,
        };
        let mut controllers = Vec::new();
        for c in root.children("controller") {
            self.others(c, &["control"]);
            let id = c
                .attr("id")
                .ok_or_else(|| self.err(c, "<controller> has no `id` attribute".into()))?
                .trim()
                .to_string();
            let mut signals = Vec::new();
            for k in c.children("control") {
                let sid = k
                    .attr("signalId")
                    .ok_or_else(|| self.err(k, format!("controller {id}: <control> has no `signalId` attribute")))?;
                signals.push(sid.trim().to_string());
            }
            controllers.push(Controller { id, signals, line: c.line });
        }
        let roads = root.children("road").map(|r| self.road(r)).collect::<Result<Vec<_>, _>>()?;
        let junctions = root.children("junction").map(|j| self.junction(j)).collect::<Result<Vec<_>, _>>()?;
        Ok(Document { origin, roads, junctions, controllers })
    }

    fn road(&mut self, el: &Element) -> Result<Road, MapError> {
        let id = el.attr("id").ok_or_else(|| self.err(el, "<road> has no `id` attribute".into()))?.trim().to_string();
        let what = format!("road {id}");
        let length = self.number(el, "length", &what)?;
        if length < 0.0 {
            return Err(self.err(el, format!("{what}: negative length {length}")));
        }
        if length > MAX_LENGTH {
            return Err(self.err(el, format!("{what}: length {length} m is beyond {MAX_LENGTH} m; split the road")));
        }
        self.others(el, &["link", "planView", "lanes", "type", "signals"]);
        let junction = el.attr("junction").unwrap_or("-1").trim().to_string();
        let left_hand = el.attr("rule").map(str::trim) == Some("LHT");
        let (mut predecessor, mut successor) = (None, None);
        if let Some(link) = el.child("link") {
            self.others(link, &["predecessor", "successor"]);
            for (name, slot) in [("predecessor", &mut predecessor), ("successor", &mut successor)] {
                if let Some(l) = link.child(name) {
                    *slot = Some(self.road_link(l, &what)?);
                }
            }
        }
        let plan = el.child("planView").ok_or_else(|| self.err(el, format!("{what} has no <planView>")))?;
        self.others(plan, &["geometry"]);
        let mut geometries = Vec::new();
        for g in plan.children("geometry") {
            geometries.push(self.geometry(g, &what)?);
        }
        if geometries.is_empty() {
            return Err(self.err(plan, format!("{what}: <planView> has no <geometry>")));
        }
        geometries.sort_by(|a, b| a.s.total_cmp(&b.s));
        let mut speeds = Vec::new();
        for t in el.children("type") {
            self.others(t, &["speed"]);
            if let Some(sp) = t.child("speed")
                && let Some(v) = self.speed(sp, &what)?
            {
                speeds.push((self.number_or(t, "s", 0.0, &what)?, v));
            }
        }
        let lanes = el.child("lanes").ok_or_else(|| self.err(el, format!("{what} has no <lanes>")))?;
        self.others(lanes, &["laneOffset", "laneSection"]);
        let mut lane_offsets = Vec::new();
        for o in lanes.children("laneOffset") {
            lane_offsets.push(Poly {
                s: self.number_or(o, "s", 0.0, &what)?,
                c: self.coefficients(o, ["a", "b", "c", "d"], &what)?,
            });
        }
        lane_offsets.sort_by(|a, b| a.s.total_cmp(&b.s));
        let mut sections = Vec::new();
        for sec in lanes.children("laneSection") {
            sections.push(self.section(sec, &what)?);
        }
        if sections.is_empty() {
            return Err(self.err(lanes, format!("{what}: <lanes> has no <laneSection>")));
        }
        sections.sort_by(|a, b| a.s.total_cmp(&b.s));
        for k in 0..sections.len() {
            sections[k].index = k;
            sections[k].end = if k + 1 < sections.len() { sections[k + 1].s } else { length };
            if sections[k].end < sections[k].s {
                return Err(MapError::OpenDrive {
                    at: self.at(sections[k].line),
                    message: format!(
                        "{what}: lane section at s = {} starts after the road's end {length}",
                        sections[k].s
                    ),
                });
            }
        }
        let mut signals = Vec::new();
        for list in el.children("signals") {
            self.others(list, &["signal", "signalReference"]);
            for sig in &list.children {
                if sig.name == "signal" || sig.name == "signalReference" {
                    signals.push(self.signal(sig, &what)?);
                }
            }
        }
        Ok(Road {
            id,
            length,
            junction,
            left_hand,
            predecessor,
            successor,
            geometries,
            lane_offsets,
            sections,
            speeds,
            signals,
            start_lanes: None,
            end_lanes: None,
            line: el.line,
        })
    }

    /// A `<signal>` or `<signalReference>` (OpenDRIVE 1.8 §14: `s`, `t`, `orientation`,
    /// `dynamic`, `country`, `type`, `subtype`, `<validity>`).
    fn signal(&mut self, el: &Element, what: &str) -> Result<Signal, MapError> {
        let reference = el.name == "signalReference";
        let id = el
            .attr("id")
            .ok_or_else(|| self.err(el, format!("{what}: <{}> has no `id` attribute", el.name)))?
            .trim()
            .to_string();
        let what = format!("{what} signal {id}");
        self.others(el, &["validity"]);
        let facing = match el.attr("orientation").map(str::trim) {
            Some("+") => Facing::Along,
            Some("-") => Facing::Against,
            Some("none") | None => Facing::Both,
            Some(other) => {
                self.notes.push(MapWarning {
                    at: self.at(el.line).to_string(),
                    message: format!(
                        "{what}: orientation {other:?} is none of `+`, `-`, `none`; taken as `none` (both ways)"
                    ),
                });
                Facing::Both
            }
        };
        let mut validity = Vec::new();
        for v in el.children("validity") {
            validity.push((self.integer(v, "fromLane", &what)?, self.integer(v, "toLane", &what)?));
        }
        let text = |name: &str| el.attr(name).unwrap_or("").trim().to_string();
        Ok(Signal {
            s: self.number_or(el, "s", 0.0, &what)?,
            t: self.number_or(el, "t", 0.0, &what)?,
            id,
            facing,
            dynamic: el.attr("dynamic").map(str::trim) == Some("yes"),
            country: text("country"),
            kind: if reference { String::new() } else { text("type") },
            subtype: text("subtype"),
            validity,
            reference,
            line: el.line,
        })
    }

    fn road_link(&mut self, el: &Element, what: &str) -> Result<RoadLink, MapError> {
        let id =
            el.attr("elementId").ok_or_else(|| self.err(el, format!("{what}: <{}> has no `elementId`", el.name)))?;
        match el.attr("elementType").map(str::trim).unwrap_or("road") {
            "road" => Ok(RoadLink::Road { id: id.trim().to_string(), contact: self.contact(el, what)?, line: el.line }),
            "junction" => Ok(RoadLink::Junction { id: id.trim().to_string() }),
            other => Err(self.err(el, format!("{what}: elementType {other:?} is neither `road` nor `junction`"))),
        }
    }

    fn geometry(&mut self, el: &Element, what: &str) -> Result<Geometry, MapError> {
        let s = self.number(el, "s", what)?;
        let start = DVec2::new(self.number(el, "x", what)?, self.number(el, "y", what)?);
        let hdg = self.number(el, "hdg", what)?;
        let length = self.number(el, "length", what)?;
        if length < 0.0 {
            return Err(self.err(el, format!("{what}: geometry at s = {s} has negative length {length}")));
        }
        if length > MAX_LENGTH || s.abs() > MAX_LENGTH {
            return Err(
                self.err(el, format!("{what}: geometry at s = {s} of length {length} m lies beyond {MAX_LENGTH} m"))
            );
        }
        let Some(shape_el) = el.children.first() else {
            return Err(self
                .err(el, format!("{what}: geometry at s = {s} has no shape (line, arc, spiral, poly3, paramPoly3)")));
        };
        self.others(el, &["line", "arc", "spiral", "poly3", "paramPoly3"]);
        let shape = match shape_el.name.as_str() {
            "line" => Shape::Line,
            "arc" => Shape::Arc { curvature: self.number(shape_el, "curvature", what)? },
            "spiral" => Shape::Spiral {
                start: self.number(shape_el, "curvStart", what)?,
                end: self.number(shape_el, "curvEnd", what)?,
            },
            "poly3" => Shape::Cubic(Cubic::poly3(self.coefficients(shape_el, ["a", "b", "c", "d"], what)?, length)),
            "paramPoly3" => {
                let u = self.coefficients(shape_el, ["aU", "bU", "cU", "dU"], what)?;
                let v = self.coefficients(shape_el, ["aV", "bV", "cV", "dV"], what)?;
                let p_end = match shape_el.attr("pRange").map(str::trim).unwrap_or("normalized") {
                    "arcLength" => length,
                    "normalized" => 1.0,
                    other => {
                        return Err(self.err(
                            shape_el,
                            format!("{what}: pRange {other:?} is neither `arcLength` nor `normalized`"),
                        ));
                    }
                };
                Shape::Cubic(Cubic::param(u, v, p_end, length))
            }
            other => {
                return Err(self.err(
                    shape_el,
                    format!(
                        "{what}: unknown geometry <{other}> at s = {s} (known: line, arc, spiral, poly3, paramPoly3)"
                    ),
                ));
            }
        };
        Ok(Geometry { s, start, hdg, length, shape })
    }

    /// A `<speed max unit>` in m/s, `None` for `no limit`/`undefined`.
    fn speed(&self, el: &Element, what: &str) -> Result<Option<f64>, MapError> {
        let Some(max) = el.attr("max").map(str::trim) else { return Ok(None) };
        if max == "no limit" || max == "undefined" {
            return Ok(None);
        }
        let v: f64 = max.parse().map_err(|_| self.err(el, format!("{what}: speed max {max:?} is not a number")))?;
        let factor = match el.attr("unit").map(str::trim).unwrap_or("m/s") {
            "m/s" => 1.0,
            "km/h" => 1.0 / 3.6,
            "mph" => 0.447_04,
            other => return Err(self.err(el, format!("{what}: speed unit {other:?} is not m/s, km/h or mph"))),
        };
        Ok(Some(v * factor))
    }

    fn section(&mut self, el: &Element, what: &str) -> Result<LaneSection, MapError> {
        let s = self.number_or(el, "s", 0.0, what)?;
        self.others(el, &["left", "center", "right"]);
        let mut section =
            LaneSection { s, end: s, left: Vec::new(), right: Vec::new(), centre: None, line: el.line, index: 0 };
        for side in ["left", "center", "right"] {
            let Some(side_el) = el.child(side) else { continue };
            self.others(side_el, &["lane"]);
            for l in side_el.children("lane") {
                let lane = self.lane(l, s, what)?;
                let ok = match side {
                    "left" => lane.id > 0,
                    "right" => lane.id < 0,
                    _ => lane.id == 0,
                };
                if !ok {
                    return Err(self.err(l, format!("{what}: lane {} does not belong in <{side}>", lane.id)));
                }
                match side {
                    "left" => section.left.push(lane),
                    "right" => section.right.push(lane),
                    _ => section.centre = Some(lane),
                }
            }
        }
        section.left.sort_by_key(|l| l.id);
        section.right.sort_by_key(|l| -l.id);
        for side in [&section.left, &section.right] {
            for (k, lane) in side.iter().enumerate() {
                if lane.id.unsigned_abs() as usize != k + 1 {
                    return Err(MapError::OpenDrive {
                        at: self.at(lane.line),
                        message: format!(
                            "{what}: lane ids of the section at s = {s} are not 1, 2, ... from the centre out (lane {})",
                            lane.id
                        ),
                    });
                }
            }
        }
        Ok(section)
    }

    fn lane(&mut self, el: &Element, section_s: f64, what: &str) -> Result<Lane, MapError> {
        let id = self.integer(el, "id", what)?;
        let what = format!("{what} lane {id}");
        self.others(el, &["link", "width", "border", "roadMark", "speed"]);
        let mut lane = Lane {
            id,
            kind: el.attr("type").unwrap_or("none").trim().to_string(),
            widths: Vec::new(),
            borders: Vec::new(),
            marks: Vec::new(),
            predecessor: None,
            successor: None,
            speed: None,
            direction: el.attr("direction").unwrap_or("standard").trim().to_string(),
            line: el.line,
        };
        if let Some(link) = el.child("link") {
            self.others(link, &["predecessor", "successor"]);
            if let Some(p) = link.child("predecessor") {
                lane.predecessor = Some(self.integer(p, "id", &what)?);
            }
            if let Some(p) = link.child("successor") {
                lane.successor = Some(self.integer(p, "id", &what)?);
            }
        }
        for (name, list) in [("width", &mut lane.widths), ("border", &mut lane.borders)] {
            for w in el.children(name) {
                let s = section_s + self.number_or(w, "sOffset", 0.0, &what)?;
                list.push(Poly { s, c: self.coefficients(w, ["a", "b", "c", "d"], &what)? });
            }
            list.sort_by(|a, b| a.s.total_cmp(&b.s));
        }
        for m in el.children("roadMark") {
            self.others(m, &[]);
            lane.marks.push(RoadMark {
                s: section_s + self.number_or(m, "sOffset", 0.0, &what)?,
                kind: m.attr("type").unwrap_or("none").trim().to_string(),
                color: m.attr("color").unwrap_or("standard").trim().to_string(),
                lane_change: m.attr("laneChange").map(|v| v.trim().to_string()),
                weight: m.attr("weight").unwrap_or("standard").trim().to_string(),
            });
        }
        lane.marks.sort_by(|a, b| a.s.total_cmp(&b.s));
        if let Some(sp) = el.child("speed") {
            lane.speed = self.speed(sp, &what)?;
        }
        Ok(lane)
    }

    fn junction(&mut self, el: &Element) -> Result<Junction, MapError> {
        let id =
            el.attr("id").ok_or_else(|| self.err(el, "<junction> has no `id` attribute".into()))?.trim().to_string();
        let what = format!("junction {id}");
        self.others(el, &["connection", "controller", "priority"]);
        let mut connections = Vec::new();
        for c in el.children("connection") {
            self.others(c, &["laneLink"]);
            // A direct junction (OpenDRIVE 1.7) names `linkedRoad` instead of `connectingRoad`.
            let field = |names: &[&str]| {
                names
                    .iter()
                    .find_map(|n| c.attr(n))
                    .map(|v| v.trim().to_string())
                    .ok_or_else(|| self.err(c, format!("{what}: <connection> has no `{}`", names[0])))
            };
            let mut lane_links = Vec::new();
            for l in c.children("laneLink") {
                lane_links.push((self.integer(l, "from", &what)?, self.integer(l, "to", &what)?));
            }
            connections.push(Connection {
                incoming: field(&["incomingRoad"])?,
                connecting: field(&["connectingRoad", "linkedRoad"])?,
                contact: self.contact(c, &what)?,
                lane_links,
                line: c.line,
            });
        }
        let mut controllers = Vec::new();
        for c in el.children("controller") {
            let cid = c
                .attr("id")
                .ok_or_else(|| self.err(c, format!("{what}: <controller> has no `id` attribute")))?
                .trim()
                .to_string();
            let sequence = match c.attr("sequence") {
                Some(_) => Some(self.integer(c, "sequence", &what)? as i64),
                None => None,
            };
            controllers.push((cid, sequence));
        }
        let mut priorities = Vec::new();
        for p in el.children("priority") {
            let road = |name: &str| {
                p.attr(name)
                    .map(|v| v.trim().to_string())
                    .ok_or_else(|| self.err(p, format!("{what}: <priority> has no `{name}` attribute")))
            };
            priorities.push((road("high")?, road("low")?, p.line));
        }
        Ok(Junction { id, connections, controlled: !controllers.is_empty(), controllers, priorities, line: el.line })
    }
}

/// The origin (lat, lon) \[deg\] of a `geoReference` PROJ string's `+lat_0` and `+lon_0`.
pub fn geo_origin(proj: &str) -> Option<(f64, f64)> {
    let value = |key: &str| {
        proj.split_whitespace().find_map(|w| w.strip_prefix(key)).and_then(|v| v.trim().parse::<f64>().ok())
    };
    match (value("+lat_0="), value("+lon_0=")) {
        (Some(lat), Some(lon)) if lat.is_finite() && lon.is_finite() && lat.abs() < 84.0 => Some((lat, lon)),
        _ => None,
    }
}
