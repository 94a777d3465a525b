//! Raw OSM XML (as JOSM writes it) -> [`OsmDocument`]: nodes, ways, relations and tags, no semantics.
//!
//! A streaming quick-xml reader. JOSM conventions are honoured: single or double quotes, negative
//! ids for objects not yet uploaded, and objects with `action='delete'` or `visible='false'` are
//! dropped. Structural errors (broken XML, bad numbers, duplicate ids, a way naming a node that
//! is not in the file) are [`MapError`]s with file and line.

use std::collections::BTreeMap;
use std::path::{Path as FsPath, PathBuf};

use quick_xml::Reader;
use quick_xml::events::{BytesStart, Event};

use super::error::{Location, MapError};

/// Tags of an OSM object, key -> value.
pub type Tags = BTreeMap<String, String>;

/// An OSM node: a point on the globe.
#[derive(Debug, Clone, PartialEq)]
pub struct OsmNode {
    /// Node id (negative for objects JOSM has not uploaded).
    pub id: i64,
    /// Latitude [deg], -90..=90.
    pub lat: f64,
    /// Longitude [deg], -180..=180.
    pub lon: f64,
    /// Tags.
    pub tags: Tags,
    /// 1-based line of the element in the file.
    pub line: usize,
}

/// An OSM way: an ordered list of node ids.
#[derive(Debug, Clone, PartialEq)]
pub struct OsmWay {
    /// Way id.
    pub id: i64,
    /// Node ids in drawn order.
    pub nodes: Vec<i64>,
    /// Tags.
    pub tags: Tags,
    /// 1-based line of the element in the file.
    pub line: usize,
}

/// What a relation member refers to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum MemberType {
    /// A node.
    Node,
    /// A way.
    Way,
    /// Another relation.
    Relation,
}

/// One member of a relation.
#[derive(Debug, Clone, PartialEq)]
pub struct OsmMember {
    /// What kind of object `reference` names.
    pub kind: MemberType,
    /// Id of the member object.
    pub reference: i64,
    /// Role (`left`, `right`, `left_lane_marking`, `right_lane_marking`, `refers`, ...).
    pub role: String,
}

/// An OSM relation: members with roles, plus tags.
#[derive(Debug, Clone, PartialEq)]
pub struct OsmRelation {
    /// Relation id.
    pub id: i64,
    /// Members in file order.
    pub members: Vec<OsmMember>,
    /// Tags.
    pub tags: Tags,
    /// 1-based line of the element in the file.
    pub line: usize,
}

/// A whole OSM file, objects by id.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OsmDocument {
    /// File it was read from (`<memory>` for text).
    pub source: PathBuf,
    /// Nodes by id.
    pub nodes: BTreeMap<i64, OsmNode>,
    /// Ways by id.
    pub ways: BTreeMap<i64, OsmWay>,
    /// Relations by id.
    pub relations: BTreeMap<i64, OsmRelation>,
}

impl OsmDocument {
    /// Read and parse an `.osm` or `.xml` file.
    pub fn load(path: &FsPath) -> Result<OsmDocument, MapError> {
        let text = std::fs::read_to_string(path).map_err(|source| MapError::Io { path: path.to_path_buf(), source })?;
        parse_osm(&text, path)
    }

    /// Where object `line` of this document is, for messages.
    pub fn at(&self, line: usize) -> Location {
        Location { file: self.source.clone(), line }
    }
}

/// The object being read, between its start and end tags.
enum Open {
    Node(OsmNode),
    Way(OsmWay),
    Relation(OsmRelation),
    /// An element we drop (deleted / invisible) or do not know: children are ignored.
    Skipped,
}

/// Tracks 1-based line numbers from byte offsets, counting newlines incrementally.
struct LineCounter<'a> {
    bytes: &'a [u8],
    offset: usize,
    line: usize,
}

impl LineCounter<'_> {
    fn line_at(&mut self, offset: usize) -> usize {
        let offset = offset.min(self.bytes.len());
        if offset >= self.offset {
            self.line += self.bytes[self.offset..offset].iter().filter(|&&b| b == b'\n').count();
        } else {
            self.line = 1 + self.bytes[..offset].iter().filter(|&&b| b == b'\n').count();
        }
        self.offset = offset;
        self.line
    }
}

/// Parse OSM XML text; `source` names the file in messages.
pub fn parse_osm(text: &str, source: &FsPath) -> Result<OsmDocument, MapError> {
    if text.trim().is_empty() {
        return Err(MapError::Empty(source.to_path_buf()));
    }
    let mut doc = OsmDocument { source: source.to_path_buf(), ..Default::default() };
    let mut reader = Reader::from_str(text);
    reader.config_mut().trim_text(true);
    let mut lines = LineCounter { bytes: text.as_bytes(), offset: 0, line: 1 };
    let mut open: Option<Open> = None;
    // Where the open object started (line), for nesting messages.
    let mut open_line = 0;
    let mut saw_osm = false;
    // 0: before `<osm>`, 1: inside it, 2: after `</osm>`.
    let mut osm_state = 0u8;
    let structure = |line: usize, message: String| MapError::Structure {
        at: Location { file: source.to_path_buf(), line },
        message,
    };
    loop {
        let start = reader.buffer_position() as usize;
        let event = reader.read_event().map_err(|e| {
            let line = lines.line_at(reader.error_position() as usize);
            MapError::Xml { at: Location { file: source.to_path_buf(), line }, message: e.to_string() }
        })?;
        // The element starts at the first '<' after the previous event.
        let elem_offset = start + text[start..].find('<').unwrap_or(0);
        match event {
            Event::Start(ref e) | Event::Empty(ref e) if e.name().as_ref() == "osm" => {
                saw_osm = true;
                osm_state = if matches!(event, Event::Start(_)) { 1 } else { 2 };
            }
            Event::Start(ref e) | Event::Empty(ref e) => {
                let empty = matches!(event, Event::Empty(_));
                let at = Location { file: source.to_path_buf(), line: lines.line_at(elem_offset) };
                check_unique_attributes(e, &at)?;
                match e.name().as_ref() {
                    name @ ("node" | "way" | "relation") => {
                        let name = name.to_string();
                        if let Some(outer) = &open {
                            return Err(structure(
                                at.line,
                                format!(
                                    "<{name}> inside {} (opened on line {open_line}); an OSM object cannot hold another: close the outer one first",
                                    outer.describe()
                                ),
                            ));
                        }
                        if saw_osm && osm_state != 1 {
                            return Err(structure(
                                at.line,
                                format!("<{name}> after </osm>; objects must lie inside <osm>...</osm>"),
                            ));
                        }
                        let object = read_object(e, &at)?;
                        if empty {
                            finish(&mut doc, object)?;
                        } else {
                            open_line = at.line;
                            open = Some(object);
                        }
                    }
                    "tag" => {
                        let (k, v) = read_tag(e, &at)?;
                        match open.as_mut() {
                            Some(Open::Node(n)) => insert_tag(&mut n.tags, k, v),
                            Some(Open::Way(w)) => insert_tag(&mut w.tags, k, v),
                            Some(Open::Relation(r)) => insert_tag(&mut r.tags, k, v),
                            _ => {}
                        }
                    }
                    "nd" => {
                        if let Some(Open::Way(w)) = open.as_mut() {
                            let r = attr(e, "ref", &at)?;
                            w.nodes.push(parse_id(r.as_deref(), "way", &w.id.to_string(), "ref", &at)?);
                        }
                    }
                    "member" => {
                        if let Some(Open::Relation(r)) = open.as_mut() {
                            r.members.push(read_member(e, r.id, &at)?);
                        }
                    }
                    _ => {}
                }
            }
            Event::End(e) => {
                if matches!(e.name().as_ref(), "node" | "way" | "relation") {
                    if let Some(object) = open.take() {
                        finish(&mut doc, object)?;
                    }
                } else if e.name().as_ref() == "osm" {
                    osm_state = 2;
                }
            }
            Event::Eof => {
                if osm_state == 1 {
                    let line = lines.line_at(text.len());
                    let inside = open
                        .as_ref()
                        .map_or(String::new(), |o| format!(" (inside {}, line {open_line})", o.describe()));
                    return Err(structure(
                        line,
                        format!(
                            "the file ends before </osm>{inside}: it looks cut short; re-save it in JOSM or restore the whole file"
                        ),
                    ));
                }
                break;
            }
            _ => {}
        }
    }
    if !saw_osm {
        return Err(MapError::Xml {
            at: Location { file: source.to_path_buf(), line: 0 },
            message: "no <osm> root element; this is not an OSM/JOSM file".into(),
        });
    }
    check_way_nodes(&doc)?;
    Ok(doc)
}

impl Open {
    /// `way -10` for messages.
    fn describe(&self) -> String {
        match self {
            Open::Node(n) => format!("node {}", n.id),
            Open::Way(w) => format!("way {}", w.id),
            Open::Relation(r) => format!("relation {}", r.id),
            Open::Skipped => "a skipped element".into(),
        }
    }
}

/// XML forbids an attribute twice on one element; quick-xml only checks it when asked, and
/// [`attr`] stops at the first match, so `<node id="1" lat="1" lat="2">` would load silently.
fn check_unique_attributes(e: &BytesStart, at: &Location) -> Result<(), MapError> {
    let mut seen: Vec<&str> = Vec::new();
    for a in e.attributes().with_checks(false) {
        let a = a.map_err(|err| MapError::Xml { at: at.clone(), message: err.to_string() })?;
        let key = a.key.into_inner();
        if seen.contains(&key) {
            let id = attr(e, "id", at)?.map_or(String::new(), |id| format!(" {id}"));
            return Err(MapError::Structure {
                at: at.clone(),
                message: format!(
                    "{}{id}: attribute `{key}` given twice; an attribute may appear once per element (which value is meant?)",
                    e.name().as_ref()
                ),
            });
        }
        seen.push(key);
    }
    Ok(())
}

/// `<tag>` keys are unique per object in OSM; the last one wins like in JOSM.
fn insert_tag(tags: &mut Tags, k: String, v: String) {
    tags.insert(k, v);
}

fn check_way_nodes(doc: &OsmDocument) -> Result<(), MapError> {
    for way in doc.ways.values() {
        if let Some(&missing) = way.nodes.iter().find(|n| !doc.nodes.contains_key(n)) {
            return Err(MapError::MissingNode { at: doc.at(way.line), way: way.id, node: missing });
        }
    }
    Ok(())
}

fn attr(e: &BytesStart, name: &str, at: &Location) -> Result<Option<String>, MapError> {
    for a in e.attributes().with_checks(false) {
        let a = a.map_err(|err| MapError::Xml { at: at.clone(), message: err.to_string() })?;
        if a.key.as_ref() == name {
            let v = a
                .normalized_value(quick_xml::XmlVersion::Implicit1_0)
                .map_err(|err| MapError::Xml { at: at.clone(), message: err.to_string() })?;
            return Ok(Some(v.into_owned()));
        }
    }
    Ok(None)
}

fn parse_id(
    value: Option<&str>,
    element: &'static str,
    id: &str,
    attribute: &'static str,
    at: &Location,
) -> Result<i64, MapError> {
    let bad =
        |problem: String| MapError::BadAttribute { at: at.clone(), element, id: id.to_string(), attribute, problem };
    let value = value.ok_or_else(|| bad("is missing".into()))?;
    value.trim().parse::<i64>().map_err(|_| bad(format!("= {value:?} is not an integer id (64-bit, may be negative)")))
}

fn parse_coordinate(
    value: Option<&str>,
    id: i64,
    attribute: &'static str,
    limit: f64,
    at: &Location,
) -> Result<f64, MapError> {
    let bad = |problem: String| MapError::BadAttribute {
        at: at.clone(),
        element: "node",
        id: id.to_string(),
        attribute,
        problem,
    };
    let value = value.ok_or_else(|| bad("is missing".into()))?;
    let v: f64 = value.trim().parse().map_err(|_| bad(format!("= {value:?} is not a number in degrees")))?;
    if !v.is_finite() || v.abs() > limit {
        return Err(bad(format!("= {value} is out of range; allowed -{limit}..={limit} degrees")));
    }
    Ok(v)
}

fn read_object(e: &BytesStart, at: &Location) -> Result<Open, MapError> {
    let element: &'static str = match e.name().as_ref() {
        "node" => "node",
        "way" => "way",
        _ => "relation",
    };
    let action = attr(e, "action", at)?;
    let visible = attr(e, "visible", at)?;
    if action.as_deref() == Some("delete") || visible.as_deref() == Some("false") {
        return Ok(Open::Skipped);
    }
    let id = parse_id(attr(e, "id", at)?.as_deref(), element, "?", "id", at)?;
    let line = at.line;
    Ok(match element {
        "node" => {
            let lat = parse_coordinate(attr(e, "lat", at)?.as_deref(), id, "lat", 90.0, at)?;
            let lon = parse_coordinate(attr(e, "lon", at)?.as_deref(), id, "lon", 180.0, at)?;
            Open::Node(OsmNode { id, lat, lon, tags: Tags::new(), line })
        }
        "way" => Open::Way(OsmWay { id, nodes: Vec::new(), tags: Tags::new(), line }),
        _ => Open::Relation(OsmRelation { id, members: Vec::new(), tags: Tags::new(), line }),
    })
}

fn read_tag(e: &BytesStart, at: &Location) -> Result<(String, String), MapError> {
    let k = attr(e, "k", at)?.ok_or_else(|| MapError::BadAttribute {
        at: at.clone(),
        element: "tag",
        id: "?".into(),
        attribute: "k",
        problem: "is missing; every <tag> needs k and v".into(),
    })?;
    let v = attr(e, "v", at)?.unwrap_or_default();
    Ok((k, v))
}

fn read_member(e: &BytesStart, relation: i64, at: &Location) -> Result<OsmMember, MapError> {
    let id = relation.to_string();
    let kind = match attr(e, "type", at)?.as_deref() {
        Some("node") => MemberType::Node,
        Some("way") => MemberType::Way,
        Some("relation") => MemberType::Relation,
        other => {
            return Err(MapError::BadAttribute {
                at: at.clone(),
                element: "relation",
                id,
                attribute: "type",
                problem: format!("= {other:?}; allowed: node, way, relation"),
            });
        }
    };
    let reference = parse_id(attr(e, "ref", at)?.as_deref(), "relation", &id, "ref", at)?;
    let role = attr(e, "role", at)?.unwrap_or_default();
    Ok(OsmMember { kind, reference, role })
}

fn finish(doc: &mut OsmDocument, object: Open) -> Result<(), MapError> {
    let duplicate = |element, id, line, first_line| MapError::DuplicateId { at: doc.at(line), element, id, first_line };
    match object {
        Open::Node(n) => {
            if let Some(first) = doc.nodes.get(&n.id) {
                return Err(duplicate("node", n.id, n.line, first.line));
            }
            doc.nodes.insert(n.id, n);
        }
        Open::Way(w) => {
            if let Some(first) = doc.ways.get(&w.id) {
                return Err(duplicate("way", w.id, w.line, first.line));
            }
            doc.ways.insert(w.id, w);
        }
        Open::Relation(r) => {
            if let Some(first) = doc.relations.get(&r.id) {
                return Err(duplicate("relation", r.id, r.line, first.line));
            }
            doc.relations.insert(r.id, r);
        }
        Open::Skipped => {}
    }
    Ok(())
}
