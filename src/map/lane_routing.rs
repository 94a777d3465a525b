//! Routes that may change lanes (Lanelet2 style): a Dijkstra over positions on lanelets whose
//! edges are "drive to the end of this lanelet and into a successor" (cost: the length driven) and
//! "change into an allowed neighbour at the same fraction along" (cost: a penalty per change).
//! Kept apart from [`super::routing`] so routes without lane changes stay exactly as they are.
//!
//! The returned path follows the centre lines and blends from the old lane's centre to the new
//! one's over [`LaneChangeOptions::blend_m`] after each change (a smoothstep in the lateral
//! offset); the vehicle-level manoeuvre with its speed-dependent length is not part of the map.

use std::collections::BTreeMap;

use glam::DVec2;

use super::error::MapError;
use super::lanelet::{LaneletId, LaneletMap};
use super::neighbours::Neighbours;
use super::path::Path;
use super::polyline::{polyline_length, project_polyline, resample, sub_polyline};
use super::routing::{Place, RouteOptions};

/// Options of a route search with lane changes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaneChangeOptions {
    /// Resampling density of the returned path [points per metre].
    pub points_per_meter: f64,
    /// Cost of one lane change [m of driving]; raising it trades longer routes for fewer changes.
    pub change_penalty_m: f64,
    /// Length over which the returned path blends into the new lane \[m\] (clipped to what is
    /// left of the lanelet pair); a shorter blend is a sharper change.
    pub blend_m: f64,
}

impl Default for LaneChangeOptions {
    fn default() -> Self {
        LaneChangeOptions { points_per_meter: 5.0, change_penalty_m: 50.0, blend_m: 30.0 }
    }
}

/// One lane change on a route.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaneChange {
    /// Lanelet left.
    pub from: LaneletId,
    /// Lanelet entered (a neighbour of `from`).
    pub to: LaneletId,
    /// Arc length along the returned path where the change begins \[m\].
    pub at_m: f64,
}

/// A route that may change lanes.
#[derive(Debug, Clone)]
pub struct LaneChangeRoute {
    /// The path (its `lanelets` list every lanelet driven on, in order, changes included).
    pub path: Path,
    /// The lane changes, in driving order.
    pub lane_changes: Vec<LaneChange>,
    /// Search cost: length driven plus the penalties \[m\].
    pub cost_m: f64,
}

/// A search node: a lanelet (index) and how far along its centre line [mm]; or the goal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
enum Node {
    At(u32, u64),
    Goal(u32),
}

fn mm(metres: f64) -> u64 {
    (metres.max(0.0) * 1000.0).round() as u64
}

impl LaneletMap {
    /// Candidates for a route end: forward, drivable lanelets with `node` on a bound, and how far
    /// along their centre line the node lies [m].
    fn lane_change_ends(&self, nodes: &[i64]) -> Vec<(usize, f64)> {
        let mut out = Vec::new();
        for node in nodes {
            let Some(p) = self.nodes.get(node).map(|n| n.position) else { continue };
            for (i, l) in self.lanelets.iter().enumerate() {
                if l.routable && (l.left_nodes.contains(node) || l.right_nodes.contains(node)) {
                    out.push((i, project_polyline(&l.centre, p).0));
                }
            }
        }
        out
    }

    /// Shortest route between two places where lane changes into allowed neighbours (see
    /// [`LaneletMap::neighbours`]) are edges of cost [`LaneChangeOptions::change_penalty_m`].
    pub fn route_with_lane_changes(
        &self,
        from: &Place,
        to: &Place,
        opts: &LaneChangeOptions,
    ) -> Result<LaneChangeRoute, MapError> {
        check(opts)?;
        let no_route = || MapError::NoRoute { from: from.to_string(), to: to.to_string() };
        let starts = self.lane_change_ends(&self.place_nodes(from)?);
        let finals = self.lane_change_ends(&self.place_nodes(to)?);
        if starts.is_empty() || finals.is_empty() {
            return Err(no_route());
        }
        let neighbours = self.neighbours();
        let mut finals_on: BTreeMap<usize, Vec<(u32, u64)>> = BTreeMap::new();
        for (k, &(i, along)) in finals.iter().enumerate() {
            finals_on.entry(i).or_default().push((k as u32, mm(along)));
        }
        let len_mm = |i: usize| mm(self.lanelets[i].length);
        let penalty = mm(opts.change_penalty_m);
        let successors = |node: &Node| -> Vec<(Node, u64)> {
            let Node::At(i, a) = *node else { return Vec::new() };
            let i = i as usize;
            let mut out = Vec::new();
            for &(k, f) in finals_on.get(&i).map(Vec::as_slice).unwrap_or(&[]) {
                if f >= a {
                    out.push((Node::Goal(k), f - a));
                }
            }
            let rest = len_mm(i).saturating_sub(a);
            for s in &self.lanelets[i].successors {
                if let Some(j) = self.lanelet_index(*s).filter(|&j| self.lanelets[j].routable) {
                    out.push((Node::At(j as u32, 0), rest));
                }
            }
            let Neighbours { left, right, change_left, change_right } = neighbours[i];
            for (n, ok) in [(left, change_left), (right, change_right)] {
                if let (Some(id), true) = (n, ok) {
                    let j = self.lanelet_index(id).expect("neighbours are lanelets of this map");
                    // Same fraction along; a change needs some road left, so not at the very end.
                    if rest > 0 {
                        let a2 = (a as f64 * len_mm(j) as f64 / len_mm(i).max(1) as f64).round() as u64;
                        out.push((Node::At(j as u32, a2.min(len_mm(j))), penalty));
                    }
                }
            }
            out
        };
        let mut best: Option<(Vec<Node>, u64)> = None;
        for &(i, along) in &starts {
            let start = Node::At(i as u32, mm(along));
            let found = pathfinding::directed::dijkstra::dijkstra(&start, &successors, |n| matches!(n, Node::Goal(_)));
            if let Some((nodes, cost)) = found
                && best.as_ref().is_none_or(|(_, c)| cost < *c)
            {
                best = Some((nodes, cost));
            }
        }
        let (nodes, cost) = best.ok_or_else(no_route)?;
        Ok(self.lane_change_path(&nodes, &finals, cost, opts))
    }

    /// The path of a vehicle that makes its own lane changes (the lane-change plugin's mandatory
    /// changes) on a trip that needs them: from `from` along its lane to where that lane ends,
    /// through the lanelets of the route [`LaneletMap::route_with_lane_changes`] finds up to its
    /// first change, then on through first successors (at most 64 lanelets, as the plugin's own
    /// lane paths do). A route without a change is that route's path. Errors: no route even with
    /// lane changes.
    pub fn route_to_lane_end(&self, from: &Place, to: &Place, opts: &RouteOptions) -> Result<Path, MapError> {
        let lc_opts = LaneChangeOptions { points_per_meter: opts.points_per_meter, ..LaneChangeOptions::default() };
        let lc = self.route_with_lane_changes(from, to, &lc_opts)?;
        let Some(first) = lc.lane_changes.first() else { return Ok(lc.path) };
        let mut ids: Vec<LaneletId> = Vec::new();
        for &id in &lc.path.lanelets {
            ids.push(id);
            if id == first.from {
                break;
            }
        }
        let mut points = sub_polyline(&lc.path.points, 0.0, first.at_m);
        let here = points.last().copied().unwrap_or(lc.path.points[0]);
        let mut j = self.lanelet_index(first.from).expect("a route's lanelets are the map's");
        let mut piece = {
            let c = &self.lanelets[j].centre;
            sub_polyline(c, project_polyline(c, here).0, self.lanelets[j].length)
        };
        for _ in 0..64 {
            let skip = usize::from(points.last().zip(piece.first()).is_some_and(|(p, q)| p.distance(*q) < 1e-6));
            points.extend_from_slice(&piece[skip.min(piece.len())..]);
            let next = self.lanelets[j]
                .successors
                .iter()
                .filter_map(|id| self.lanelet_index(*id))
                .find(|&k| self.lanelets[k].routable && !ids.contains(&self.lanelets[k].id));
            let Some(k) = next else { break };
            ids.push(self.lanelets[k].id);
            piece = self.lanelets[k].centre.clone();
            j = k;
        }
        Ok(Path::from_points(ids, resample(&points, opts.points_per_meter), false))
    }

    /// Geometry of a found node sequence: driven centre-line pieces, blended after each change.
    fn lane_change_path(
        &self,
        nodes: &[Node],
        finals: &[(usize, f64)],
        cost: u64,
        opts: &LaneChangeOptions,
    ) -> LaneChangeRoute {
        let mut points: Vec<DVec2> = Vec::new();
        let mut lanelets: Vec<LaneletId> = Vec::new();
        let mut changes = Vec::new();
        // The lane left at the last change, to blend from: (lanelet index, along where left [m]).
        let mut blend_from: Option<(usize, f64)> = None;
        for w in nodes.windows(2) {
            let Node::At(i, a) = w[0] else { break };
            let (i, a) = (i as usize, a as f64 / 1000.0);
            let l = &self.lanelets[i];
            if lanelets.last() != Some(&l.id) {
                lanelets.push(l.id);
            }
            let end = match w[1] {
                Node::Goal(k) => finals[k as usize].1,
                Node::At(j, _) if l.successors.contains(&self.lanelets[j as usize].id) && j as usize != i => l.length,
                Node::At(j, _) => {
                    changes.push(LaneChange {
                        from: l.id,
                        to: self.lanelets[j as usize].id,
                        // `+ 0.0`: an empty sum is -0.0, printed as "-0.00".
                        at_m: polyline_length(&points) + 0.0,
                    });
                    blend_from = Some((i, a));
                    continue;
                }
            };
            let mut piece = sub_polyline(&l.centre, a, end.max(a));
            if let Some((old, old_a)) = blend_from.take() {
                let old = &self.lanelets[old];
                let scale = old.length / l.length.max(1e-9);
                let blend = opts.blend_m.min(end - a).max(1e-9);
                let fine = resample(&piece, 10.0);
                let mut s = 0.0;
                piece = Vec::with_capacity(fine.len());
                for (k, p) in fine.iter().enumerate() {
                    if k > 0 {
                        s += fine[k - 1].distance(*p);
                    }
                    let q = point_at(&old.centre, old_a + s * scale);
                    let t = (s / blend).clamp(0.0, 1.0);
                    let w = t * t * (3.0 - 2.0 * t);
                    piece.push(q.lerp(*p, w));
                }
            }
            let skip = usize::from(points.last().zip(piece.first()).is_some_and(|(p, q)| p.distance(*q) < 1e-6));
            points.extend_from_slice(&piece[skip.min(piece.len())..]);
        }
        let path = Path::from_points(lanelets, resample(&points, opts.points_per_meter), false);
        LaneChangeRoute { path, lane_changes: changes, cost_m: cost as f64 / 1000.0 }
    }
}

/// Point at arc length `s` [m] of a polyline (clamped to its ends).
fn point_at(points: &[DVec2], s: f64) -> DVec2 {
    let mut s0 = 0.0;
    for w in points.windows(2) {
        let len = w[0].distance(w[1]);
        if s <= s0 + len && len > 0.0 {
            return w[0].lerp(w[1], ((s - s0) / len).clamp(0.0, 1.0));
        }
        s0 += len;
    }
    points.last().copied().unwrap_or(DVec2::ZERO)
}

fn check(opts: &LaneChangeOptions) -> Result<(), MapError> {
    let bad = |what: &str, v: f64, allowed: &str| {
        Err(MapError::InvalidOption(format!("{what} = {v} is not allowed; use a number in {allowed}")))
    };
    if !(opts.points_per_meter.is_finite() && opts.points_per_meter > 0.0 && opts.points_per_meter <= 1000.0) {
        return bad("points_per_meter", opts.points_per_meter, "(0, 1000], e.g. 5");
    }
    if !(opts.change_penalty_m.is_finite() && opts.change_penalty_m > 0.0) {
        return bad("lane change penalty", opts.change_penalty_m, "(0, inf) metres, e.g. 50");
    }
    if !(opts.blend_m.is_finite() && opts.blend_m > 0.0) {
        return bad("blend length", opts.blend_m, "(0, inf) metres, e.g. 30");
    }
    Ok(())
}

/// A route given lane by lane, for vehicles that make its lane changes themselves (a SUMO
/// route: a sequence of edges, each turn reachable from some of an edge's lanes only): which
/// lanelets drive on along the route without a change, and what each lanelet of the route's
/// roads drives. The lane-change plugin changes (mandatorily) out of a lanelet that is not in
/// `reach` into a neighbour that is, as before a lane drop.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LaneRoute {
    /// Names the route among the goals of one simulation.
    pub key: String,
    /// Lanelets from which the rest of the route is driven without a lane change (junction
    /// lanelets between them included).
    pub reach: Vec<LaneletId>,
    /// The lanelets driven from the start of each lanelet of the route's roads: on along the
    /// route for those in `reach`, up to the first lanelet that is not; a lanelet not in `reach`
    /// alone (its end is where the change must be made).
    pub lanes: BTreeMap<LaneletId, Vec<LaneletId>>,
}

impl LaneRoute {
    /// Which lanelets (by index in `map`) reach on along the route.
    pub fn reach_mask(&self, map: &LaneletMap) -> Vec<bool> {
        let mut out = vec![false; map.lanelets.len()];
        for i in self.reach.iter().filter_map(|id| map.lanelet_index(*id)) {
            out[i] = true;
        }
        out
    }

    /// The path driven from the start of lanelet `id` (`None`: not a lanelet of the route's roads).
    pub fn path_from(&self, map: &LaneletMap, id: LaneletId, points_per_meter: f64) -> Option<Path> {
        self.lanes.get(&id).map(|ids| map.path_of_lanelets(ids, points_per_meter))
    }
}

impl LaneletMap {
    /// The path along the centre lines of `ids` (consecutive lanelets, each a successor of the one
    /// before), resampled at `points_per_meter`; unknown ids are skipped.
    pub fn path_of_lanelets(&self, ids: &[LaneletId], points_per_meter: f64) -> Path {
        let mut points: Vec<DVec2> = Vec::new();
        for l in ids.iter().filter_map(|id| self.lanelet(*id)) {
            let skip = usize::from(points.last().zip(l.centre.first()).is_some_and(|(p, q)| p.distance(*q) < 1e-6));
            points.extend_from_slice(&l.centre[skip.min(l.centre.len())..]);
        }
        Path::from_points(ids.to_vec(), resample(&points, points_per_meter), false)
    }
}
