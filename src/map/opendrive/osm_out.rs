//! OpenDRIVE -> Lanelet2 OSM (`smlworld map convert x.xodr --out x.osm`).
//!
//! The map built from the `.xodr` keeps its ways (borders with their road-mark tags, shared by
//! neighbouring lanes) and its lanelets (with every `opendrive:*` tag). Its successors come from
//! the file's links, but an OSM lanelet map (ours and Lanelet2's) finds successors from shared
//! nodes: j follows i when j's bounds start at the nodes where i's bounds end. So the end nodes of
//! every linked pair are merged into one node (union-find) before writing; a pair whose ends lie
//! more than [`MERGE_DISTANCE`] apart is not merged (the link is lost, and counted in
//! [`ConvertStats::unmerged_links`]) rather than moving geometry.
//!
//! The origin is one node tagged `origin=true` at the file's `geoReference` `+lat_0 +lon_0`
//! (0, 0 for local metres), which our loader projects with UTM in that node's zone, as Lanelet2's
//! `UtmProjector` does with the same origin; the node also carries `utm_zone` for readers.

use std::collections::BTreeMap;
use std::io::{self, BufWriter, Write};

use quick_xml::escape::escape;

use crate::map::lanelet::LaneletMap;

/// Linked bound ends further apart than this \[m\] are not merged.
pub const MERGE_DISTANCE: f64 = 0.05;

/// What [`write_osm`] wrote.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ConvertStats {
    /// Nodes written (after merging linked ends, plus the origin node).
    pub nodes: usize,
    /// Ways written.
    pub ways: usize,
    /// Lanelet relations written.
    pub lanelets: usize,
    /// Successor links whose bound ends were too far apart to share nodes.
    pub unmerged_links: usize,
}

fn find(parent: &mut BTreeMap<i64, i64>, x: i64) -> i64 {
    let mut root = x;
    while let Some(&p) = parent.get(&root) {
        if p == root {
            break;
        }
        root = p;
    }
    // Path compression.
    let mut cur = x;
    while cur != root {
        let next = parent.get(&cur).copied().unwrap_or(root);
        parent.insert(cur, root);
        cur = next;
    }
    root
}

/// Writes `map` as Lanelet2 OSM XML (JOSM style: negative ids, unique over all object kinds).
pub fn write_osm<W: Write>(map: &LaneletMap, out: W) -> io::Result<ConvertStats> {
    let mut stats = ConvertStats::default();
    // Merge linked ends: the smaller node id represents its class.
    let mut parent: BTreeMap<i64, i64> = BTreeMap::new();
    let pos = |id: i64| map.nodes.get(&id).map(|n| n.position);
    for l in &map.lanelets {
        let (Some(&lr), Some(&ll)) = (l.right_nodes.last(), l.left_nodes.last()) else { continue };
        for next in &l.successors {
            let Some(n) = map.lanelet(*next) else { continue };
            let (Some(&nr), Some(&nl)) = (n.right_nodes.first(), n.left_nodes.first()) else { continue };
            let close = |a: i64, b: i64| match (pos(a), pos(b)) {
                (Some(p), Some(q)) => p.distance(q) <= MERGE_DISTANCE,
                _ => false,
            };
            if !(close(lr, nr) && close(ll, nl)) {
                let gap = |a: i64, b: i64| pos(a).zip(pos(b)).map_or(f64::NAN, |(p, q)| p.distance(q));
                let place = |l: &crate::map::Lanelet| {
                    let t = |k: &str| l.tags.get(k).map_or("?", String::as_str);
                    format!(
                        "road {} section {} lane {}",
                        t("opendrive:road"),
                        t("opendrive:section"),
                        t("opendrive:lane")
                    )
                };
                tracing::debug!(
                    "not joined: {} -> {}: right bounds {:.3} m, left bounds {:.3} m apart",
                    place(l),
                    place(n),
                    gap(lr, nr),
                    gap(ll, nl)
                );
                stats.unmerged_links += 1;
                continue;
            }
            for (a, b) in [(lr, nr), (ll, nl)] {
                let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
                if ra != rb {
                    let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
                    parent.insert(lo, lo);
                    parent.insert(hi, lo);
                }
            }
        }
    }
    let mut rep = |id: i64| find(&mut parent, id);
    let max_node = map.nodes.keys().map(|k| k.unsigned_abs()).max().unwrap_or(0) as i64;
    let max_way = map.ways.keys().map(|k| k.unsigned_abs()).max().unwrap_or(0) as i64;
    // Node ids -1 (origin), -(1 + |id|); ways and relations after them.
    let node_id = |id: i64| -(1 + id.abs());
    let way_id = |id: i64| -(2 + max_node + id.abs());
    let relation_id = |id: i64| -(3 + max_node + max_way + id.abs());

    let mut w = BufWriter::with_capacity(1 << 20, out);
    w.write_all(b"<?xml version='1.0' encoding='UTF-8'?>\n<osm version='0.6' generator='smlworld map convert'>\n")?;
    let p = &map.projector;
    write!(
        w,
        "  <node id='-1' lat='{:.10}' lon='{:.10}'>\n    <tag k='origin' v='true' />\n    <tag k='utm_zone' v='{}' />\n  </node>\n",
        p.origin_lat,
        p.origin_lon,
        p.zone_name()
    )?;
    stats.nodes += 1;
    // Tags of merged nodes are gathered on the representative; a key already taken there gets a
    // numbered suffix (two lanes starting at one node each keep their `opendrive:start` value).
    let mut merged_tags: BTreeMap<i64, Vec<(String, String)>> = BTreeMap::new();
    for n in map.nodes.values() {
        let r = rep(n.id);
        let list = merged_tags.entry(r).or_default();
        for (k, v) in &n.tags {
            if list.iter().any(|(_, v2)| v2 == v) {
                continue;
            }
            let mut key = k.clone();
            let mut i = 2;
            while list.iter().any(|(k2, _)| *k2 == key) {
                key = format!("{k}:{i}");
                i += 1;
            }
            list.push((key, v.clone()));
        }
    }
    for n in map.nodes.values() {
        if rep(n.id) != n.id {
            continue;
        }
        write!(w, "  <node id='{}' lat='{:.10}' lon='{:.10}'", node_id(n.id), n.lat, n.lon)?;
        match merged_tags.get(&n.id).filter(|t| !t.is_empty()) {
            Some(tags) => {
                w.write_all(b">\n")?;
                write_tags(&mut w, tags.iter().map(|(k, v)| (k.as_str(), v.as_str())))?;
                w.write_all(b"  </node>\n")?;
            }
            None => w.write_all(b" />\n")?,
        }
        stats.nodes += 1;
    }
    for way in map.ways.values() {
        writeln!(w, "  <way id='{}'>", way_id(way.id))?;
        for &n in &way.nodes {
            writeln!(w, "    <nd ref='{}' />", node_id(rep(n)))?;
        }
        write_tags(&mut w, way.tags.iter().map(|(k, v)| (k.as_str(), v.as_str())))?;
        w.write_all(b"  </way>\n")?;
        stats.ways += 1;
    }
    for l in &map.lanelets {
        write!(
            w,
            "  <relation id='{}'>\n    <member type='way' ref='{}' role='left' />\n    <member type='way' ref='{}' role='right' />\n",
            relation_id(l.id.0),
            way_id(l.left_way),
            way_id(l.right_way)
        )?;
        let mut tags: Vec<(&str, &str)> = l.tags.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
        if !l.tags.contains_key("type") {
            tags.push(("type", "lanelet"));
        }
        // Lane types cars may not drive (shoulder, border, median ...) often have no Lanelet2
        // subtype that says so; the Lanelet2 participant tag does, for our loader and Lanelet2's.
        if !l.routable && !l.tags.contains_key("participant:vehicle") {
            tags.push(("participant:vehicle", "no"));
        }
        write_tags(&mut w, tags.into_iter())?;
        w.write_all(b"  </relation>\n")?;
        stats.lanelets += 1;
    }
    w.write_all(b"</osm>\n")?;
    w.flush()?;
    Ok(stats)
}

fn write_tags<'a, W: Write>(w: &mut W, tags: impl Iterator<Item = (&'a str, &'a str)>) -> io::Result<()> {
    for (k, v) in tags {
        writeln!(w, "    <tag k='{}' v='{}' />", escape(k), escape(v))?;
    }
    Ok(())
}
