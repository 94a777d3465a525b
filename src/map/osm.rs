//! Raw OSM XML (as JOSM writes it) -> [`OsmDocument`]: nodes, ways, relations and tags, no semantics.
//!
//! A streaming quick-xml reader. JOSM conventions are honoured: single or double quotes, negative
//! ids for objects not yet uploaded, and objects with `action='delete'` or `visible='false'` are
//! dropped. Structural errors (broken XML, bad numbers, duplicate ids, a way naming a node that
//! is not in the file) are [`MapError`]s with file and line.

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::{Path as FsPath, PathBuf};

use quick_xml::Reader;
use quick_xml::events::attributes::Attribute;
use quick_xml::events::{BytesStart, Event};

use super::error::{Location, MapError};

/// Tags of an OSM object, key -> value.
pub type Tags = BTreeMap<String, String>;

/// An OSM node: a point on the globe.
#[derive(Debug, Clone, PartialEq)]
pub struct OsmNode {
    /// Node id (negative for objects JOSM has not uploaded).
    pub id: i64,
    /// Latitude \[deg\], -90..=90.
    pub lat: f64,
    /// Longitude \[deg\], -180..=180.
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

/// The objects of one file, each kind sorted by id, as the loader reads them: vectors and an
/// index by id instead of a map per kind (what [`OsmDocument`] gives), which costs the loader
/// a tree insert and a tree walk per node.
#[derive(Debug, Clone)]
pub(crate) struct OsmObjects {
    /// File it was read from (`<memory>` for text).
    pub(crate) source: PathBuf,
    /// Nodes by rising id.
    pub(crate) nodes: Vec<OsmNode>,
    /// Ways by rising id; every node they name is in `nodes`.
    pub(crate) ways: Vec<OsmWay>,
    /// Relations by rising id.
    pub(crate) relations: Vec<OsmRelation>,
    /// Node id -> position in `nodes`.
    pub(crate) node_index: IdIndex,
}

impl OsmObjects {
    /// The objects of a document (copied).
    pub(crate) fn from_document(doc: &OsmDocument) -> OsmObjects {
        let nodes: Vec<OsmNode> = doc.nodes.values().cloned().collect();
        let node_index = IdIndex::new(nodes.iter().map(|n| n.id));
        OsmObjects {
            source: doc.source.clone(),
            nodes,
            ways: doc.ways.values().cloned().collect(),
            relations: doc.relations.values().cloned().collect(),
            node_index,
        }
    }

    /// Where object `line` of this file is, for messages.
    pub(crate) fn at(&self, line: usize) -> Location {
        Location { file: self.source.clone(), line }
    }
}

/// Position of an id among rising ids, found without a tree: a table when the ids lie close
/// together (JOSM's -1, -2, ...; our generators), else a binary search.
#[derive(Debug, Clone)]
pub(crate) enum IdIndex {
    /// `slots[id - first]` is the position of `id`, or [`IdIndex::NONE`].
    Dense { first: i64, slots: Vec<u32> },
    /// The ids themselves, rising.
    Sparse(Vec<i64>),
}

impl IdIndex {
    const NONE: u32 = u32::MAX;

    /// The index of `ids`, which rise strictly.
    pub(crate) fn new(ids: impl ExactSizeIterator<Item = i64> + DoubleEndedIterator + Clone) -> IdIndex {
        let n = ids.len();
        let (Some(first), Some(last)) = (ids.clone().next(), ids.clone().next_back()) else {
            return IdIndex::Sparse(Vec::new());
        };
        // At most a quarter of the table empty (and positions fit a u32): else search.
        let span = i128::from(last) - i128::from(first) + 1;
        if span <= (n as i128) * 4 / 3 + 16 && n < IdIndex::NONE as usize {
            let mut slots = vec![IdIndex::NONE; span as usize];
            for (k, id) in ids.enumerate() {
                slots[(id - first) as usize] = k as u32;
            }
            IdIndex::Dense { first, slots }
        } else {
            IdIndex::Sparse(ids.collect())
        }
    }

    /// Position of `id`, if there is one.
    pub(crate) fn get(&self, id: i64) -> Option<usize> {
        match self {
            IdIndex::Dense { first, slots } => {
                let k = id.checked_sub(*first).and_then(|d| usize::try_from(d).ok())?;
                slots.get(k).filter(|&&s| s != IdIndex::NONE).map(|&s| s as usize)
            }
            IdIndex::Sparse(ids) => ids.binary_search(&id).ok(),
        }
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

/// What the duplicate check needs of an object.
trait Object {
    fn id(&self) -> i64;
    fn line(&self) -> usize;
}

impl Object for OsmNode {
    fn id(&self) -> i64 {
        self.id
    }
    fn line(&self) -> usize {
        self.line
    }
}

impl Object for OsmWay {
    fn id(&self) -> i64 {
        self.id
    }
    fn line(&self) -> usize {
        self.line
    }
}

impl Object for OsmRelation {
    fn id(&self) -> i64 {
        self.id
    }
    fn line(&self) -> usize {
        self.line
    }
}

/// Objects of one kind in file order, checked for a repeated id as each comes (so the first
/// repeat in the file is the one reported, whatever follows it). While the ids only rise or
/// only fall, as JOSM and our generators write them, a repeat is found by a binary search
/// when the order breaks and no map of ids is kept; after that, one is.
struct Collected<T> {
    items: Vec<T>,
    order: IdOrder,
}

enum IdOrder {
    /// Fewer than two objects so far.
    Unknown,
    Rising,
    Falling,
    /// Id -> line of every object so far.
    Mixed(BTreeMap<i64, usize>),
    /// Two halves joined, in no order: only to be sorted.
    Joined,
}

impl<T: Object> Collected<T> {
    fn with_capacity(capacity: usize) -> Self {
        Collected { items: Vec::with_capacity(capacity), order: IdOrder::Unknown }
    }

    /// Add `item`, or give the line of the earlier object with its id.
    fn push(&mut self, item: T) -> Result<(), usize> {
        let id = item.id();
        let Some(last) = self.items.last().map(Object::id) else {
            self.items.push(item);
            return Ok(());
        };
        match &mut self.order {
            IdOrder::Unknown if id > last => self.order = IdOrder::Rising,
            IdOrder::Unknown if id < last => self.order = IdOrder::Falling,
            IdOrder::Rising if id > last => {}
            IdOrder::Falling if id < last => {}
            IdOrder::Mixed(lines) => {
                if let Some(&first) = lines.get(&id) {
                    return Err(first);
                }
                lines.insert(id, item.line());
            }
            IdOrder::Unknown | IdOrder::Rising | IdOrder::Falling | IdOrder::Joined => {
                if let Some(first) = self.line_of(id) {
                    return Err(first);
                }
                let mut lines: BTreeMap<i64, usize> = self.items.iter().map(|o| (o.id(), o.line())).collect();
                lines.insert(id, item.line());
                self.order = IdOrder::Mixed(lines);
            }
        }
        self.items.push(item);
        Ok(())
    }

    /// The objects by rising id.
    fn into_sorted(self) -> Vec<T> {
        let mut items = self.items;
        match self.order {
            IdOrder::Falling => items.reverse(),
            IdOrder::Mixed(_) | IdOrder::Joined => items.sort_unstable_by_key(Object::id),
            IdOrder::Unknown | IdOrder::Rising => {}
        }
        items
    }

    /// The line of the object with `id`, if there is one.
    fn line_of(&self, id: i64) -> Option<usize> {
        let (first, last) = (self.items.first()?.id(), self.items.last()?.id());
        let found = match &self.order {
            IdOrder::Rising if id < first || id > last => return None,
            IdOrder::Falling if id > first || id < last => return None,
            IdOrder::Rising => self.items.binary_search_by(|o| o.id().cmp(&id)).ok(),
            IdOrder::Falling => self.items.binary_search_by(|o| id.cmp(&o.id())).ok(),
            IdOrder::Mixed(lines) => return lines.get(&id).copied(),
            IdOrder::Unknown | IdOrder::Joined => self.items.iter().position(|o| o.id() == id),
        };
        found.map(|k| self.items[k].line())
    }

    /// These objects followed by `later` (no id in both), for [`Collected::into_sorted`] only.
    fn join(self, later: Collected<T>) -> Collected<T> {
        let (Some(last), Some(next)) = (self.items.last().map(Object::id), later.items.first().map(Object::id)) else {
            return if self.items.is_empty() { later } else { self };
        };
        let rising = |o: &IdOrder| matches!(o, IdOrder::Unknown | IdOrder::Rising);
        let falling = |o: &IdOrder| matches!(o, IdOrder::Unknown | IdOrder::Falling);
        let order = if rising(&self.order) && rising(&later.order) && last < next {
            IdOrder::Rising
        } else if falling(&self.order) && falling(&later.order) && last > next {
            IdOrder::Falling
        } else {
            IdOrder::Joined
        };
        let mut items = self.items;
        items.extend(later.items);
        Collected { items, order }
    }
}

/// Objects of the file being read.
struct Objects {
    nodes: Collected<OsmNode>,
    ways: Collected<OsmWay>,
    relations: Collected<OsmRelation>,
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
            self.line += count_newlines(&self.bytes[self.offset..offset]);
        } else {
            self.line = 1 + count_newlines(&self.bytes[..offset]);
        }
        self.offset = offset;
        self.line
    }
}

/// Newlines in `bytes`.
fn count_newlines(bytes: &[u8]) -> usize {
    count_byte(bytes, b'\n')
}

/// How often `byte` is in `bytes`, eight bytes at a time: a byte-by-byte count of the newlines
/// cost a tenth of parsing.
fn count_byte(bytes: &[u8], byte: u8) -> usize {
    const LOW7: u64 = 0x7f7f_7f7f_7f7f_7f7f;
    const ONES: u64 = 0x0101_0101_0101_0101;
    let mut words = bytes.chunks_exact(8);
    let mut n = 0;
    for w in &mut words {
        let x = u64::from_le_bytes([w[0], w[1], w[2], w[3], w[4], w[5], w[6], w[7]]) ^ (ONES * u64::from(byte));
        // The high bit of each byte that was `byte` (now 0), exactly: no carry crosses a byte.
        let zero = !(((x & LOW7) + LOW7) | x | LOW7);
        n += ((zero >> 7).wrapping_mul(ONES) >> 56) as usize;
    }
    n + words.remainder().iter().filter(|&&b| b == byte).count()
}

/// Where an element is, made into a [`Location`] only for a message (not once per element).
#[derive(Clone, Copy)]
struct At<'a> {
    file: &'a FsPath,
    line: usize,
}

impl At<'_> {
    fn location(self) -> Location {
        Location { file: self.file.to_path_buf(), line: self.line }
    }
}

/// Parse OSM XML text; `source` names the file in messages.
pub fn parse_osm(text: &str, source: &FsPath) -> Result<OsmDocument, MapError> {
    let objects = parse_objects(text, source)?;
    Ok(OsmDocument {
        source: objects.source,
        nodes: objects.nodes.into_iter().map(|n| (n.id, n)).collect(),
        ways: objects.ways.into_iter().map(|w| (w.id, w)).collect(),
        relations: objects.relations.into_iter().map(|r| (r.id, r)).collect(),
    })
}

/// Files from this size [bytes] on are read as two halves at once, each on its own thread.
const PARALLEL_BYTES: usize = 4 << 20;

/// Parse OSM XML text into its objects sorted by id; `source` names the file in messages.
///
/// A big file is read in two halves side by side: the second from the first object line after
/// the middle (read as if `<osm>` had just opened there), the first up to that line. The halves
/// are only joined when the first reader reaches that line between objects, directly inside
/// `<osm>` (not inside a comment, an object or another element); otherwise the first reader
/// reads on to the end alone, as a small file is read. Joined, the errors are the ones a
/// single reader gives: the first half's first, then an object of the second half that repeats
/// an id of the first half, then the second half's own.
pub(crate) fn parse_objects(text: &str, source: &FsPath) -> Result<OsmObjects, MapError> {
    parse_objects_split(text, source, PARALLEL_BYTES)
}

/// [`parse_objects`], reading files of `parallel_bytes` or more in two halves.
fn parse_objects_split(text: &str, source: &FsPath, parallel_bytes: usize) -> Result<OsmObjects, MapError> {
    if text.trim().is_empty() {
        return Err(MapError::Empty(source.to_path_buf()));
    }
    let whole = || read_part(text, source, LineCounter { bytes: text.as_bytes(), offset: 0, line: 1 }, None);
    let Some(split) = (text.len() >= parallel_bytes).then(|| object_line_after(text, balanced_middle(text))).flatten()
    else {
        return finish_objects(whole()?, source);
    };
    let (first, second) = rayon::join(
        || read_part(text, source, LineCounter { bytes: text.as_bytes(), offset: 0, line: 1 }, Some(split)),
        || {
            let rest = format!("<osm>{}", &text[split..]);
            // "<osm>" holds no newline: offsets in `rest` count the same lines.
            let line = 1 + count_newlines(&text.as_bytes()[..split]);
            read_part(&rest, source, LineCounter { bytes: rest.as_bytes(), offset: 0, line }, None)
        },
    );
    let first = first?;
    if !first.stopped {
        return finish_objects(first, source);
    }
    let second = match second {
        Ok(part) => part,
        Err(e) => {
            let PartError { objects, order, error } = *e;
            return Err(repeat_across(&first.objects, &objects, &order, source).unwrap_or(error));
        }
    };
    if let Some(repeat) = repeat_across(&first.objects, &second.objects, &second.order, source) {
        return Err(repeat);
    }
    let objects = Objects {
        nodes: first.objects.nodes.join(second.objects.nodes),
        ways: first.objects.ways.join(second.objects.ways),
        relations: first.objects.relations.join(second.objects.relations),
    };
    finish_objects(Part { objects, order: Vec::new(), saw_osm: true, stopped: false }, source)
}

/// Where about half the reading work of `text` lies before: the work of a stretch taken as its
/// bytes plus 64 for each element in it (a way's `<nd>`s make more elements per byte than the
/// nodes before them, and the middle byte left the second half half as much again to do),
/// counted on every fourth block of 16 KiB.
fn balanced_middle(text: &str) -> usize {
    const BLOCK: usize = 1 << 14;
    let weights: Vec<usize> =
        text.as_bytes().chunks(BLOCK).step_by(4).map(|b| b.len() + 64 * count_byte(b, b'<')).collect();
    let total: usize = weights.iter().sum();
    let mut sum = 0;
    for (k, w) in weights.iter().enumerate() {
        sum += w;
        if 2 * sum >= total {
            return ((4 * k + 2) * BLOCK).min(text.len() / 8 * 7);
        }
    }
    text.len() / 2
}

/// The offset of the first line after `from` that opens a node, way or relation, if one comes
/// within a megabyte.
fn object_line_after(text: &str, from: usize) -> Option<usize> {
    let bytes = text.as_bytes();
    let mut at = from;
    while at < (from + (1 << 20)).min(bytes.len()) {
        let newline = at + bytes[at..].iter().position(|&b| b == b'\n')?;
        let line_start = newline + 1;
        let indent = bytes[line_start..].iter().take_while(|&&b| b == b' ' || b == b'\t').count();
        let tag = &bytes[line_start + indent..];
        for name in [&b"<node"[..], b"<way", b"<relation"] {
            if tag.starts_with(name) && tag.get(name.len()).is_some_and(|b| b" \t\r\n/>".contains(b)) {
                return Some(line_start + indent);
            }
        }
        at = line_start;
    }
    None
}

/// Which kind of object finished, in file order (to find the first repeat across halves).
#[derive(Clone, Copy)]
enum Kind {
    Node,
    Way,
    Relation,
}

/// What one reader read.
struct Part {
    objects: Objects,
    /// The kind of every object in `objects`, in file order.
    order: Vec<Kind>,
    saw_osm: bool,
    /// Whether it stopped at the given offset (else it read to the end).
    stopped: bool,
}

/// A reader's error, with the objects it had read before it.
struct PartError {
    objects: Objects,
    order: Vec<Kind>,
    error: MapError,
}

impl From<Box<PartError>> for MapError {
    fn from(e: Box<PartError>) -> MapError {
        e.error
    }
}

/// The first object of `second` (in file order) whose id an object of the same kind in `first`
/// has, as the error a single reader would give for it.
fn repeat_across(first: &Objects, second: &Objects, order: &[Kind], source: &FsPath) -> Option<MapError> {
    let (mut n, mut w, mut r) = (0, 0, 0);
    for kind in order {
        let (element, id, line, earlier) = match kind {
            Kind::Node => {
                let o = &second.nodes.items[n];
                n += 1;
                ("node", o.id, o.line, first.nodes.line_of(o.id))
            }
            Kind::Way => {
                let o = &second.ways.items[w];
                w += 1;
                ("way", o.id, o.line, first.ways.line_of(o.id))
            }
            Kind::Relation => {
                let o = &second.relations.items[r];
                r += 1;
                ("relation", o.id, o.line, first.relations.line_of(o.id))
            }
        };
        if let Some(first_line) = earlier {
            return Some(MapError::DuplicateId {
                at: Location { file: source.to_path_buf(), line },
                element,
                id,
                first_line,
            });
        }
    }
    None
}

/// The objects of a whole file, sorted, with the checks that need them all.
fn finish_objects(part: Part, source: &FsPath) -> Result<OsmObjects, MapError> {
    if !part.saw_osm {
        return Err(MapError::Xml {
            at: Location { file: source.to_path_buf(), line: 0 },
            message: "no <osm> root element; this is not an OSM/JOSM file".into(),
        });
    }
    let nodes = part.objects.nodes.into_sorted();
    let node_index = IdIndex::new(nodes.iter().map(|n| n.id));
    let doc = OsmObjects {
        source: source.to_path_buf(),
        nodes,
        ways: part.objects.ways.into_sorted(),
        relations: part.objects.relations.into_sorted(),
        node_index,
    };
    check_way_nodes(&doc)?;
    Ok(doc)
}

/// Read `text` (from its start, its lines counted by `lines`) to its end, or up to `stop_at`
/// when the reader gets there between objects directly inside `<osm>`.
fn read_part(
    text: &str,
    source: &FsPath,
    mut lines: LineCounter,
    stop_at: Option<usize>,
) -> Result<Part, Box<PartError>> {
    // Room for the nodes of a typical file (100 bytes or more each): no copies while they come.
    let mut objects = Objects {
        nodes: Collected::with_capacity(stop_at.unwrap_or(text.len()) / 80),
        ways: Collected::with_capacity(0),
        relations: Collected::with_capacity(0),
    };
    let mut order = Vec::new();
    match read_events(text, source, &mut lines, stop_at, &mut objects, &mut order) {
        Ok((saw_osm, stopped)) => Ok(Part { objects, order, saw_osm, stopped }),
        Err(error) => Err(Box::new(PartError { objects, order, error })),
    }
}

/// The event loop of [`read_part`]: gives whether it saw `<osm>` and whether it stopped at
/// `stop_at`.
fn read_events(
    text: &str,
    source: &FsPath,
    lines: &mut LineCounter,
    stop_at: Option<usize>,
    objects: &mut Objects,
    order: &mut Vec<Kind>,
) -> Result<(bool, bool), MapError> {
    let mut reader = Reader::from_str(text);
    reader.config_mut().trim_text(true);
    let mut open: Option<Open> = None;
    // Where the open object started (line), for nesting messages.
    let mut open_line = 0;
    let mut saw_osm = false;
    // 0: before `<osm>`, 1: inside it, 2: after `</osm>`.
    let mut osm_state = 0u8;
    // Elements open, `<osm>` included.
    let mut depth = 0usize;
    let structure = |line: usize, message: String| MapError::Structure {
        at: Location { file: source.to_path_buf(), line },
        message,
    };
    loop {
        let start = reader.buffer_position() as usize;
        if let Some(stop) = stop_at
            && start <= stop
            && open.is_none()
            && depth == 1
            && osm_state == 1
            && text.as_bytes()[start..stop].iter().all(|b| b" \t\r\n".contains(b))
        {
            return Ok((saw_osm, true));
        }
        let event = reader.read_event().map_err(|e| {
            let line = lines.line_at(reader.error_position() as usize);
            MapError::Xml { at: Location { file: source.to_path_buf(), line }, message: e.to_string() }
        })?;
        // The element starts at the first '<' after the previous event.
        let elem_offset = start + text.as_bytes()[start..].iter().position(|&b| b == b'<').unwrap_or(0);
        match &event {
            Event::Start(_) => depth += 1,
            Event::End(_) => depth = depth.saturating_sub(1),
            _ => {}
        }
        match event {
            Event::Start(ref e) | Event::Empty(ref e) if e.name().as_ref() == "osm" => {
                saw_osm = true;
                osm_state = if matches!(event, Event::Start(_)) { 1 } else { 2 };
            }
            Event::Start(ref e) | Event::Empty(ref e) => {
                let empty = matches!(event, Event::Empty(_));
                let at = At { file: source, line: lines.line_at(elem_offset) };
                match e.name().as_ref() {
                    name @ ("node" | "way" | "relation") => {
                        let [action, visible, id, lat, lon] =
                            read_attributes(e, ["action", "visible", "id", "lat", "lon"], at)?;
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
                        let object = read_object(name, [action, visible, id, lat, lon], at)?;
                        if empty {
                            finish(objects, order, object, source)?;
                        } else {
                            open_line = at.line;
                            open = Some(object);
                        }
                    }
                    "tag" => {
                        let [k, v] = read_attributes(e, ["k", "v"], at)?;
                        let (k, v) = read_tag(k, v, at)?;
                        match open.as_mut() {
                            Some(Open::Node(n)) => insert_tag(&mut n.tags, k, v),
                            Some(Open::Way(w)) => insert_tag(&mut w.tags, k, v),
                            Some(Open::Relation(r)) => insert_tag(&mut r.tags, k, v),
                            _ => {}
                        }
                    }
                    "nd" => {
                        let [r] = read_attributes(e, ["ref"], at)?;
                        if let Some(Open::Way(w)) = open.as_mut() {
                            let r = value(&r, at)?;
                            w.nodes.push(parse_id(r.as_deref(), "way", w.id, "ref", at)?);
                        }
                    }
                    "member" => {
                        let [kind, reference, role] = read_attributes(e, ["type", "ref", "role"], at)?;
                        if let Some(Open::Relation(r)) = open.as_mut() {
                            r.members.push(read_member([kind, reference, role], r.id, at)?);
                        }
                    }
                    _ => {
                        read_attributes(e, [], at)?;
                    }
                }
            }
            Event::End(e) => {
                if matches!(e.name().as_ref(), "node" | "way" | "relation") {
                    if let Some(object) = open.take() {
                        finish(objects, order, object, source)?;
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
    Ok((saw_osm, false))
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

/// The attributes `names` of element `e`, read in one pass over them: quick-xml's syntax checks,
/// then XML's rule of one attribute per name (quick-xml only checks it when asked, and a lookup
/// stops at the first match, so `<node id="1" lat="1" lat="2">` would load silently). Values
/// are left raw: [`value`] normalises one when it is used, so its errors come in the order of
/// use, and a value without `&` or line breaks is borrowed, not copied.
fn read_attributes<'e, const N: usize>(
    e: &'e BytesStart,
    names: [&str; N],
    at: At,
) -> Result<[Option<Attribute<'e>>; N], MapError> {
    let mut found: [Option<Attribute<'e>>; N] = std::array::from_fn(|_| None);
    // Keys seen so far: on the stack for the few an OSM element has.
    let mut seen: [&str; 8] = [""; 8];
    let mut more_seen: Vec<&str> = Vec::new();
    for (count, a) in e.attributes().with_checks(false).enumerate() {
        let a = a.map_err(|err| MapError::Xml { at: at.location(), message: err.to_string() })?;
        let key = a.key.into_inner();
        if seen[..count.min(seen.len())].contains(&key) || more_seen.contains(&key) {
            let id = attr(e, "id", at)?.map_or(String::new(), |id| format!(" {id}"));
            return Err(MapError::Structure {
                at: at.location(),
                message: format!(
                    "{}{id}: attribute `{key}` given twice; an attribute may appear once per element (which value is meant?)",
                    e.name().as_ref()
                ),
            });
        }
        match seen.get_mut(count) {
            Some(slot) => *slot = key,
            None => more_seen.push(key),
        }
        if let Some(k) = names.iter().position(|&n| n == key) {
            found[k] = Some(a);
        }
    }
    Ok(found)
}

/// The normalised value of an attribute read by [`read_attributes`] (XML 1.0: entities
/// replaced, tabs and line breaks made spaces).
fn value<'e>(a: &Option<Attribute<'e>>, at: At) -> Result<Option<Cow<'e, str>>, MapError> {
    let Some(a) = a else { return Ok(None) };
    // What normalisation changes; without any, quick-xml gives the raw value back as it is.
    if !a.value.bytes().any(|b| matches!(b, b'&' | b'\t' | b'\r' | b'\n')) {
        return Ok(Some(a.value.clone()));
    }
    a.normalized_value(quick_xml::XmlVersion::Implicit1_0)
        .map(Some)
        .map_err(|err| MapError::Xml { at: at.location(), message: err.to_string() })
}

/// `<tag>` keys are unique per object in OSM; the last one wins like in JOSM.
fn insert_tag(tags: &mut Tags, k: String, v: String) {
    tags.insert(k, v);
}

fn check_way_nodes(doc: &OsmObjects) -> Result<(), MapError> {
    for way in &doc.ways {
        if let Some(&missing) = way.nodes.iter().find(|&&n| doc.node_index.get(n).is_none()) {
            return Err(MapError::MissingNode { at: doc.at(way.line), way: way.id, node: missing });
        }
    }
    Ok(())
}

/// The first attribute `name` of `e`, normalised (for the rare messages that name an element's id).
fn attr(e: &BytesStart, name: &str, at: At) -> Result<Option<String>, MapError> {
    for a in e.attributes().with_checks(false) {
        let a = a.map_err(|err| MapError::Xml { at: at.location(), message: err.to_string() })?;
        if a.key.as_ref() == name {
            let v = a
                .normalized_value(quick_xml::XmlVersion::Implicit1_0)
                .map_err(|err| MapError::Xml { at: at.location(), message: err.to_string() })?;
            return Ok(Some(v.into_owned()));
        }
    }
    Ok(None)
}

/// An integer id; `id` names the element in messages (`?` while its own id is read).
fn parse_id(
    value: Option<&str>,
    element: &'static str,
    id: impl std::fmt::Display,
    attribute: &'static str,
    at: At,
) -> Result<i64, MapError> {
    let bad =
        |problem: String| MapError::BadAttribute { at: at.location(), element, id: id.to_string(), attribute, problem };
    let value = value.ok_or_else(|| bad("is missing".into()))?;
    value.trim().parse::<i64>().map_err(|_| bad(format!("= {value:?} is not an integer id (64-bit, may be negative)")))
}

fn parse_coordinate(
    value: Option<&str>,
    id: i64,
    attribute: &'static str,
    limit: f64,
    at: At,
) -> Result<f64, MapError> {
    let bad = |problem: String| MapError::BadAttribute {
        at: at.location(),
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

/// A node, way or relation from its attributes `action`, `visible`, `id`, `lat`, `lon`.
fn read_object(name: &str, attributes: [Option<Attribute>; 5], at: At) -> Result<Open, MapError> {
    let element: &'static str = match name {
        "node" => "node",
        "way" => "way",
        _ => "relation",
    };
    let [action, visible, id, lat, lon] = attributes;
    let action = value(&action, at)?;
    let visible = value(&visible, at)?;
    if action.as_deref() == Some("delete") || visible.as_deref() == Some("false") {
        return Ok(Open::Skipped);
    }
    let id = parse_id(value(&id, at)?.as_deref(), element, "?", "id", at)?;
    let line = at.line;
    Ok(match element {
        "node" => {
            let lat = parse_coordinate(value(&lat, at)?.as_deref(), id, "lat", 90.0, at)?;
            let lon = parse_coordinate(value(&lon, at)?.as_deref(), id, "lon", 180.0, at)?;
            Open::Node(OsmNode { id, lat, lon, tags: Tags::new(), line })
        }
        "way" => Open::Way(OsmWay { id, nodes: Vec::new(), tags: Tags::new(), line }),
        _ => Open::Relation(OsmRelation { id, members: Vec::new(), tags: Tags::new(), line }),
    })
}

fn read_tag(k: Option<Attribute>, v: Option<Attribute>, at: At) -> Result<(String, String), MapError> {
    let k = value(&k, at)?.ok_or_else(|| MapError::BadAttribute {
        at: at.location(),
        element: "tag",
        id: "?".into(),
        attribute: "k",
        problem: "is missing; every <tag> needs k and v".into(),
    })?;
    let v = value(&v, at)?.unwrap_or_default();
    Ok((k.into_owned(), v.into_owned()))
}

/// A member from its attributes `type`, `ref`, `role`.
fn read_member(attributes: [Option<Attribute>; 3], relation: i64, at: At) -> Result<OsmMember, MapError> {
    let [kind, reference, role] = attributes;
    let kind = match value(&kind, at)?.as_deref() {
        Some("node") => MemberType::Node,
        Some("way") => MemberType::Way,
        Some("relation") => MemberType::Relation,
        other => {
            return Err(MapError::BadAttribute {
                at: at.location(),
                element: "relation",
                id: relation.to_string(),
                attribute: "type",
                problem: format!("= {other:?}; allowed: node, way, relation"),
            });
        }
    };
    let reference = parse_id(value(&reference, at)?.as_deref(), "relation", relation, "ref", at)?;
    let role = value(&role, at)?.unwrap_or_default().into_owned();
    Ok(OsmMember { kind, reference, role })
}

fn finish(doc: &mut Objects, order: &mut Vec<Kind>, object: Open, source: &FsPath) -> Result<(), MapError> {
    let duplicate = |element, id, line, first_line| MapError::DuplicateId {
        at: Location { file: source.to_path_buf(), line },
        element,
        id,
        first_line,
    };
    match object {
        Open::Node(n) => {
            let (id, line) = (n.id, n.line);
            doc.nodes.push(n).map_err(|first| duplicate("node", id, line, first))?;
            order.push(Kind::Node);
        }
        Open::Way(w) => {
            let (id, line) = (w.id, w.line);
            doc.ways.push(w).map_err(|first| duplicate("way", id, line, first))?;
            order.push(Kind::Way);
        }
        Open::Relation(r) => {
            let (id, line) = (r.id, r.line);
            doc.relations.push(r).map_err(|first| duplicate("relation", id, line, first))?;
            order.push(Kind::Relation);
        }
        Open::Skipped => {}
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn newlines_are_counted_at_every_length_and_alignment() {
        // Bytes next to '\n' in value (0x0a ^ 1, 0x8a, 0x0b) must not count.
        let pattern = [b'\n', b'a', 0x8a, b'\n', 0x0b, 0x09, b'\n', b'\n', 0x0a ^ 0x80, b'<', b'\n'];
        let bytes: Vec<u8> = pattern.iter().cycle().take(300).copied().collect();
        for start in 0..9 {
            for end in start..bytes.len() {
                let slice = &bytes[start..end];
                assert_eq!(count_newlines(slice), slice.iter().filter(|&&b| b == b'\n').count(), "{start}..{end}");
                assert_eq!(count_byte(slice, b'<'), slice.iter().filter(|&&b| b == b'<').count(), "{start}..{end}");
            }
        }
    }

    fn node(id: i64, line: usize) -> OsmNode {
        OsmNode { id, lat: 0.0, lon: 0.0, tags: Tags::new(), line }
    }

    fn collect(ids: &[i64]) -> Result<Vec<i64>, (i64, usize)> {
        let mut c = Collected::with_capacity(0);
        for (k, &id) in ids.iter().enumerate() {
            c.push(node(id, 10 + k)).map_err(|first| (id, first))?;
        }
        Ok(c.into_sorted().iter().map(|n| n.id).collect())
    }

    #[test]
    fn ids_in_any_order_come_out_rising_and_the_first_repeat_is_found() {
        assert_eq!(collect(&[1, 2, 5]), Ok(vec![1, 2, 5]));
        assert_eq!(collect(&[-1, -2, -7]), Ok(vec![-7, -2, -1]));
        assert_eq!(collect(&[3, -1, 8, 2]), Ok(vec![-1, 2, 3, 8]));
        // A repeat while the order holds, where it breaks, and after it broke: the line of the
        // first object with the id.
        assert_eq!(collect(&[-1, -1]), Err((-1, 10)));
        assert_eq!(collect(&[-1, -2, -3, -2]), Err((-2, 11)));
        assert_eq!(collect(&[1, 2, 3, 1]), Err((1, 10)));
        assert_eq!(collect(&[1, 5, 3, 4, 5]), Err((5, 11)));
        assert_eq!(collect(&[1, 5, 3, 4, 3, 1]), Err((3, 12)));
    }

    #[test]
    fn ids_are_found_close_together_or_far_apart() {
        let dense = IdIndex::new([-9i64, -8, -6, -5].into_iter());
        assert!(matches!(dense, IdIndex::Dense { .. }));
        let sparse = IdIndex::new([-5i64, 3, 1_000_000_007, i64::MAX].into_iter());
        assert!(matches!(sparse, IdIndex::Sparse(_)));
        for index in [&dense, &sparse] {
            assert_eq!(index.get(i64::MIN), None);
            assert_eq!(index.get(-7), None);
            assert_eq!(index.get(4), None);
        }
        assert_eq!([-9, -8, -6, -5].map(|id| dense.get(id)), [Some(0), Some(1), Some(2), Some(3)]);
        assert_eq!([-5, 3, 1_000_000_007, i64::MAX].map(|id| sparse.get(id)), [Some(0), Some(1), Some(2), Some(3)]);
        assert_eq!(IdIndex::new(std::iter::empty()).get(0), None);
    }

    /// A file of nodes (ids -1, -2, ... or given), ways of three nodes each and lanelet
    /// relations, one object per line; `extra` is put in as the line after object `at`.
    fn file(nodes: usize, extra: &str, at: usize) -> String {
        let mut lines = vec!["<?xml version='1.0' encoding='UTF-8'?>".to_string(), "<osm version='0.6'>".to_string()];
        for k in 1..=nodes {
            let tag = if k % 7 == 0 { format!("\n    <tag k='name' v='n{k}' />\n  </node>") } else { String::new() };
            let end = if tag.is_empty() { " />" } else { ">" };
            lines.push(format!("  <node id='-{k}' lat='59.{k:06}' lon='17.{k:06}'{end}{tag}"));
        }
        for w in 1..=nodes / 3 {
            let nds: String = (0..3).map(|i| format!("<nd ref='-{}' />", 3 * (w - 1) + i + 1)).collect();
            lines.push(format!("  <way id='-{}'>{nds}</way>", 1_000_000 + w));
        }
        for r in 1..nodes / 6 {
            lines.push(format!(
                "  <relation id='-{}'><member type='way' ref='-{}' role='left' /><member type='way' ref='-{}' role='right' /><tag k='type' v='lanelet' /></relation>",
                2_000_000 + r,
                1_000_000 + 2 * r - 1,
                1_000_000 + 2 * r
            ));
        }
        lines.insert(at.min(lines.len()), extra.to_string());
        lines.push("</osm>".into());
        lines.join("\n")
    }

    /// Read in halves and alone: the same objects or the same error.
    fn same_either_way(text: &str) -> String {
        let alone = format!("{:?}", parse_objects_split(text, FsPath::new("f.osm"), usize::MAX));
        let halves = format!("{:?}", parse_objects_split(text, FsPath::new("f.osm"), 0));
        assert_eq!(halves, alone);
        alone
    }

    /// Whether the first reader gets to the second reader's start (so the halves are joined).
    fn joins(text: &str) -> bool {
        let split = object_line_after(text, balanced_middle(text)).expect("an object line after the middle");
        let lines = LineCounter { bytes: text.as_bytes(), offset: 0, line: 1 };
        matches!(read_part(text, FsPath::new("f.osm"), lines, Some(split)), Ok(Part { stopped: true, .. }))
    }

    #[test]
    fn a_file_read_in_halves_reads_as_one() {
        let plain = file(3000, "", 0);
        assert!(joins(&plain));
        let parsed = same_either_way(&plain);
        assert!(parsed.starts_with("Ok(") && parsed.contains("id: -2999"), "{}", &parsed[..200]);
        // Rising ids in the first half, falling in the second; an extra node in between.
        let mixed = file(3000, "  <node id='5' lat='1' lon='1' />", 1500).replace("'-1'", "'-40000'");
        assert!(same_either_way(&mixed).starts_with("Ok("));
        // Bare text, comments and an unknown element directly inside <osm> on either side.
        assert!(same_either_way(&file(3000, "  <bounds minlat='1'/><!-- a comment --> text", 2000)).starts_with("Ok("));
    }

    /// `text` with `open` and `close` put around the lines within 70 kB either side of its
    /// balanced middle (at line ends).
    fn around_middle(mut text: String, open: &str, close: &str) -> String {
        let mid = balanced_middle(&text);
        let from = text[..mid - 70_000].rfind('\n').expect("lines before the middle");
        let to = text[mid + 70_000..].find('\n').expect("lines after the middle") + mid + 70_000;
        text.insert_str(to, close);
        text.insert_str(from, open);
        text
    }

    #[test]
    fn a_middle_inside_a_comment_or_an_element_is_read_by_one_reader() {
        // The middle object lines are inside a comment: the second reader's objects are not
        // in the file.
        let commented = around_middle(file(3000, "", 0), "\n<!-- ", " -->");
        assert!(!joins(&commented));
        same_either_way(&commented);
        // Objects inside an unknown element spanning the middle.
        let wrapped = around_middle(file(3000, "", 0), "\n<group>", "\n</group>");
        assert!(!joins(&wrapped));
        assert!(same_either_way(&wrapped).starts_with("Ok("));
        // An object that is not closed before the middle: the nesting error of one reader.
        let unclosed = file(3000, "  <way id='7'>", 1000);
        assert!(same_either_way(&unclosed).contains("inside way 7"));
    }

    #[test]
    fn errors_come_in_file_order_across_the_halves() {
        // A repeat of a first-half id in the second half.
        let repeat = file(3000, "  <node id='-10' lat='1' lon='1' />", 4300);
        assert!(joins(&repeat));
        assert!(same_either_way(&repeat).contains("DuplicateId"));
        // That repeat before a broken attribute later in the second half: the repeat.
        let both = file(3000, "  <node id='-10' lat='1' lon='1' />\n  <node id='x' lat='1' lon='1' />", 4300);
        assert!(same_either_way(&both).contains("DuplicateId"));
        // A broken attribute before the repeat: the attribute.
        let both = file(3000, "  <node id='x' lat='1' lon='1' />\n  <node id='-10' lat='1' lon='1' />", 4300);
        assert!(same_either_way(&both).contains("BadAttribute"));
        // Errors in the first half win over the second half's.
        let early = file(3000, "  <node id='-20' lat='1' lon='1' />", 100).replace("lat='59.002900'", "lat='x'");
        assert!(same_either_way(&early).contains("DuplicateId"));
        // A repeated way and relation across the halves, a way naming a missing node, a file
        // cut short, broken XML in the second half.
        assert!(same_either_way(&file(3000, "  <way id='-1000001'><nd ref='-1' /></way>", 4400)).contains("way"));
        assert!(same_either_way(&file(3000, "  <way id='-5'><nd ref='-99999' /></way>", 4400)).contains("MissingNode"));
        let cut = file(3000, "", 0);
        assert!(same_either_way(&cut[..cut.len() - 7]).contains("cut short"));
        assert!(same_either_way(&file(3000, "  <a></b>", 4400)).contains("Xml"));
    }
}
