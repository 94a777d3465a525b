//! Writes a generated map as JOSM-compatible OSM XML: the in-memory map in metres ([`Builder`]),
//! projected back to lat/lon around the generators' origin and streamed to any [`Write`].

use std::io::{self, BufWriter, Write};

use glam::DVec2;

use super::{GenerateError, MapStats, ORIGIN_LAT, ORIGIN_LON};
use crate::map::projection::Projector;

/// The one tag of a generated way, key and value.
pub(super) type WayTag = (&'static str, &'static str);
/// Road edge.
pub(super) const EXTERIOR: WayTag = ("line_type", "exterior");
/// Line between two lanes.
pub(super) const INTERIOR: WayTag = ("line_type", "interior");
/// Unpainted bound of a turn inside a junction (Lanelet2's line-string type).
pub(super) const VIRTUAL: WayTag = ("type", "virtual");

/// Extra tags of a generated lanelet relation, key and value.
pub(super) type LaneletTags = Vec<(&'static str, &'static str)>;

/// A map under construction, in metres; node 0 is the origin.
pub(super) struct Builder {
    /// Node positions [m], by index.
    pub(super) nodes: Vec<DVec2>,
    /// One `(key, value)` tag per node at most; generated maps never need two.
    node_tags: Vec<Option<(&'static str, String)>>,
    /// Node indices and the one tag of each way.
    ways: Vec<(Vec<usize>, WayTag)>,
    /// (left way, right way, extra tags).
    lanelets: Vec<(usize, usize, LaneletTags)>,
}

impl Builder {
    /// An empty map holding only the origin node (index 0, tagged `origin=true`).
    pub(super) fn new() -> Builder {
        let mut b = Builder { nodes: Vec::new(), node_tags: Vec::new(), ways: Vec::new(), lanelets: Vec::new() };
        let origin = b.node(DVec2::ZERO);
        b.tag(origin, "origin", "true".to_string());
        b
    }

    /// Adds a node at `p` [m]; returns its index.
    pub(super) fn node(&mut self, p: DVec2) -> usize {
        self.nodes.push(p);
        self.node_tags.push(None);
        self.nodes.len() - 1
    }

    /// Sets the one tag of `node`, replacing any earlier one.
    pub(super) fn tag(&mut self, node: usize, key: &'static str, value: String) {
        self.node_tags[node] = Some((key, value));
    }

    /// Adds a way through the node indices `nodes`; returns its index.
    pub(super) fn way(&mut self, nodes: Vec<usize>, tag: WayTag) -> usize {
        self.ways.push((nodes, tag));
        self.ways.len() - 1
    }

    /// Adds a lanelet relation between the ways `left` and `right` (indices).
    pub(super) fn lanelet(&mut self, left: usize, right: usize) {
        self.lanelets.push((left, right, Vec::new()));
    }

    /// Adds a lanelet relation with extra tags (`priority`, `traffic_light`).
    pub(super) fn lanelet_tagged(&mut self, left: usize, right: usize, tags: LaneletTags) {
        self.lanelets.push((left, right, tags));
    }

    /// Writes JOSM-style XML. Ids: nodes -1, -2, ..., then ways, then relations, so every id is
    /// unique over all object kinds. Tag values are generated identifiers: nothing to escape.
    pub(super) fn write<W: Write>(&self, out: W) -> io::Result<MapStats> {
        let projector = Projector::new(ORIGIN_LAT, ORIGIN_LON);
        let node_id = |i: usize| -(i as i64) - 1;
        let way_id = |i: usize| -((self.nodes.len() + i) as i64) - 1;
        let relation_id = |i: usize| -((self.nodes.len() + self.ways.len() + i) as i64) - 1;
        let mut w = CountingWriter { inner: BufWriter::with_capacity(1 << 20, out), bytes: 0 };
        w.write_all(b"<?xml version='1.0' encoding='UTF-8'?>\n<osm version='0.6' generator='smlworld'>\n")?;
        for (i, (&p, tag)) in self.nodes.iter().zip(&self.node_tags).enumerate() {
            let (lat, lon) = if i == 0 { (ORIGIN_LAT, ORIGIN_LON) } else { projector.reverse(p) };
            write!(w, "  <node id='{}' lat='{lat:.10}' lon='{lon:.10}'", node_id(i))?;
            match tag {
                Some((k, v)) => write!(w, ">\n    <tag k='{k}' v='{v}' />\n  </node>\n")?,
                None => w.write_all(b" />\n")?,
            }
        }
        for (i, (nodes, (key, value))) in self.ways.iter().enumerate() {
            writeln!(w, "  <way id='{}'>", way_id(i))?;
            for &n in nodes {
                writeln!(w, "    <nd ref='{}' />", node_id(n))?;
            }
            write!(w, "    <tag k='{key}' v='{value}' />\n  </way>\n")?;
        }
        for (i, (left, right, tags)) in self.lanelets.iter().enumerate() {
            write!(
                w,
                "  <relation id='{}'>\n    <member type='way' ref='{}' role='left' />\n    \
                 <member type='way' ref='{}' role='right' />\n",
                relation_id(i),
                way_id(*left),
                way_id(*right)
            )?;
            for (k, v) in tags {
                writeln!(w, "    <tag k='{k}' v='{v}' />")?;
            }
            w.write_all(b"    <tag k='type' v='lanelet' />\n  </relation>\n")?;
        }
        w.write_all(b"</osm>\n")?;
        w.flush()?;
        Ok(MapStats { nodes: self.nodes.len(), ways: self.ways.len(), lanelets: self.lanelets.len(), bytes: w.bytes })
    }
}

/// Counts the bytes written through it.
struct CountingWriter<W: Write> {
    inner: W,
    bytes: u64,
}

impl<W: Write> Write for CountingWriter<W> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.bytes += n as u64;
        Ok(n)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}

/// Runs a generator into memory and returns the XML as text.
pub(super) fn to_string(
    write: impl FnOnce(&mut Vec<u8>) -> Result<MapStats, GenerateError>,
) -> Result<String, GenerateError> {
    let mut buf = Vec::new();
    write(&mut buf)?;
    // Only ASCII is ever written.
    String::from_utf8(buf).map_err(|e| GenerateError::Io(io::Error::new(io::ErrorKind::InvalidData, e)))
}
