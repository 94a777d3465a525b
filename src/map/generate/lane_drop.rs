//! A straight two-lane road whose left lane ends (GCDC 2016 scenario 1, the cooperative merge).

use std::io::Write;

use glam::DVec2;

use super::osm_writer::{Builder, EXTERIOR, INTERIOR, to_string};
use super::{GenerateError, MapStats, check_count, check_positive, invalid};

/// Tag value of the node where the right lane starts (`destination=lane_drop_right_start`).
pub const LANE_DROP_RIGHT_START: &str = "lane_drop_right_start";
/// Tag value of the node where the left lane starts.
pub const LANE_DROP_LEFT_START: &str = "lane_drop_left_start";
/// Tag value of the node on the left edge where the left lane ends.
pub const LANE_DROP_LEFT_END: &str = "lane_drop_left_end";
/// Tag value of the node at the end of the road (right edge).
pub const LANE_DROP_END: &str = "lane_drop_end";

/// Parameters of [`lane_drop`]: a road along +x from the origin, right lane at `0 < y < w`, left
/// lane at `w < y < 2w` up to `drop_at`, then the right lane alone up to `length`.
#[derive(Debug, Clone, PartialEq)]
pub struct LaneDropParams {
    /// Length of the road \[m\] (> `drop_at`).
    pub length: f64,
    /// Where the left lane ends [m from the start] (> 0).
    pub drop_at: f64,
    /// Width of both lanes \[m\] (> 0).
    pub lane_width: f64,
    /// Largest lanelet length \[m\] (> 0): both lanes are cut into lanelets this long or shorter,
    /// side by side, so a change can happen on any of them.
    pub segment: f64,
    /// Largest distance between consecutive nodes \[m\] (> 0).
    pub node_spacing: f64,
}

impl Default for LaneDropParams {
    /// 500 m of road, the left lane ending at 300 m, lanes of 3.5 m, lanelets of at most 50 m.
    fn default() -> Self {
        LaneDropParams { length: 500.0, drop_at: 300.0, lane_width: 3.5, segment: 50.0, node_spacing: 2.0 }
    }
}

/// The lane-drop map as JOSM-compatible XML text.
pub fn lane_drop(params: &LaneDropParams) -> Result<String, GenerateError> {
    to_string(|buf| write_lane_drop(params, buf))
}

/// Writes the lane-drop map. The line between the lanes is `interior` (changes allowed both
/// ways); the road edges, and the left edge of the single lane after the drop, are `exterior`.
pub fn write_lane_drop<W: Write>(params: &LaneDropParams, out: W) -> Result<MapStats, GenerateError> {
    let p = params;
    for (name, v) in [
        ("length", p.length),
        ("drop_at", p.drop_at),
        ("lane_width", p.lane_width),
        ("segment", p.segment),
        ("node_spacing", p.node_spacing),
    ] {
        check_positive(name, v)?;
    }
    // As the ring's limit: a line of more nodes than this is a mistake in the numbers, not a
    // map (it would take minutes and gigabytes to write).
    let nodes = p.length / p.node_spacing;
    if nodes > 1e7 {
        return Err(invalid(
            "node_spacing",
            p.node_spacing,
            &format!(
                "a spacing that gives at most 10000000 nodes along length = {} [m] (it gives {nodes:.0})",
                p.length
            ),
        ));
    }
    if p.drop_at >= p.length {
        return Err(invalid("drop_at", p.drop_at, &format!("a distance below length = {} [m]", p.length)));
    }
    let cuts = |a: f64, b: f64| -> Vec<f64> {
        let n = ((b - a) / p.segment).ceil().max(1.0) as usize;
        (0..=n).map(|k| a + (b - a) * k as f64 / n as f64).collect()
    };
    let mut xs = cuts(0.0, p.drop_at);
    let after = cuts(p.drop_at, p.length);
    let drop_index = xs.len() - 1;
    xs.extend_from_slice(&after[1..]);
    let per_segment = xs.windows(2).map(|w| ((w[1] - w[0]) / p.node_spacing).ceil().max(1.0) as usize).max();
    let per_segment = per_segment.unwrap_or(1);
    check_count("segment / node_spacing (nodes per lanelet)", per_segment, 1, 1_000_000)?;
    let w = p.lane_width;
    let mut b = Builder::new();
    // lines[y][k]: node indices of the line at height y over segment k (shared end nodes).
    let mut line = |y: f64, segments: usize| -> Vec<Vec<usize>> {
        let mut prev: Option<usize> = None;
        (0..segments)
            .map(|k| {
                let first = prev.unwrap_or_else(|| b.node(DVec2::new(xs[k], y)));
                let mut nodes = vec![first];
                for j in 1..=per_segment {
                    let x = xs[k] + (xs[k + 1] - xs[k]) * j as f64 / per_segment as f64;
                    nodes.push(b.node(DVec2::new(x, y)));
                }
                prev = nodes.last().copied();
                nodes
            })
            .collect()
    };
    let segments = xs.len() - 1;
    let right_edge = line(0.0, segments);
    let middle = line(w, segments);
    let left_edge = line(2.0 * w, drop_index);
    let right_ways: Vec<usize> = right_edge.iter().map(|n| b.way(n.clone(), EXTERIOR)).collect();
    let middle_ways: Vec<usize> = middle
        .iter()
        .enumerate()
        .map(|(k, n)| b.way(n.clone(), if k < drop_index { INTERIOR } else { EXTERIOR }))
        .collect();
    let left_ways: Vec<usize> = left_edge.iter().map(|n| b.way(n.clone(), EXTERIOR)).collect();
    for k in 0..segments {
        b.lanelet(middle_ways[k], right_ways[k]);
        if k < drop_index {
            b.lanelet(left_ways[k], middle_ways[k]);
        }
    }
    // The parameter checks above leave at least one segment before the drop, each with two nodes
    // or more; should a line still be empty, the error says so instead of a panic.
    let first = |line: &[Vec<usize>]| line.first().and_then(|n| n.first()).copied();
    let last = |line: &[Vec<usize>]| line.last().and_then(|n| n.last()).copied();
    let (Some(right_start), Some(left_start), Some(left_end), Some(road_end)) =
        (first(&right_edge), first(&left_edge), last(&left_edge), last(&right_edge))
    else {
        return Err(invalid("segment", p.segment, "a length that leaves a segment before and after the drop"));
    };
    b.tag(right_start, "destination", LANE_DROP_RIGHT_START.to_string());
    b.tag(left_start, "destination", LANE_DROP_LEFT_START.to_string());
    b.tag(left_end, "destination", LANE_DROP_LEFT_END.to_string());
    b.tag(road_end, "destination", LANE_DROP_END.to_string());
    Ok(b.write(out)?)
}
