//! Routing over lanelets: A* (or Dijkstra) between nodes or tags, closed loops, stitched and
//! resampled paths.

use std::collections::BTreeMap;

use glam::DVec2;

use super::error::MapError;
use super::lanelet::{LaneletId, LaneletMap};
use super::polyline::{polyline_length, project_polyline, sub_polyline};

pub use super::path::{Path, PathProjection};
pub use super::polyline::{resample, resample_count};

/// Options of a route search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RouteOptions {
    /// Resampling density of the returned path [points per metre]; raising it gives a finer path.
    pub points_per_meter: f64,
}

impl Default for RouteOptions {
    fn default() -> Self {
        Self { points_per_meter: 5.0 }
    }
}

/// How a route between two places is searched; both give a shortest route (equal length to
/// the millimetre), and where several routes tie either may be returned.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum RouteSearch {
    /// A* guided by the straight-line distance to the nearest end (admissible: no lanelet
    /// sequence is shorter than the straight line). The default: on a city grid it expands a
    /// narrow band around the straight line instead of a disc.
    #[default]
    AStar,
    /// Plain Dijkstra: the reference the A* search is tested against.
    Dijkstra,
}

/// Where a route starts or ends: a node id, or the value of a node tag
/// (`destination=left_lane_node` is addressed as `left_lane_node`).
#[derive(Debug, Clone, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Place {
    /// A node id.
    Node(i64),
    /// A node tag value.
    Tag(String),
}

impl std::fmt::Display for Place {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Place::Node(id) => write!(f, "node {id}"),
            Place::Tag(t) => write!(f, "tag `{t}`"),
        }
    }
}

/// Millimetres, the integer cost unit of the Dijkstra searches (exact, orderable).
fn mm(metres: f64) -> u64 {
    (metres.max(0.0) * 1000.0).round() as u64
}

/// A search end: a directed lanelet, how far along its centre line the node lies [m], which node
/// it stands for and whether it was found on the lanelet's left bound (the fallback).
#[derive(Debug, Clone, Copy)]
struct End {
    state: u32,
    along: f64,
    node: i64,
    left: bool,
}

/// A route or loop with what the search chose: the nodes actually used (a tag may name several)
/// and a note when a node was matched by the left-bound fallback instead of the 2015 rule.
#[derive(Debug, Clone)]
pub struct Routed {
    /// The path.
    pub path: Path,
    /// Node the path starts at.
    pub from_node: i64,
    /// Node the path ends at (for a loop, the same as `from_node`).
    pub to_node: i64,
    /// Set when a used node lies on no lanelet's right bound and a lanelet whose left bound holds
    /// it was taken instead (Lanelet2 maps); says which node and lanelet.
    pub note: Option<String>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
enum Step {
    Start,
    /// Leaving the end of a directed lanelet.
    Exit(u32),
    /// Arrived at end candidate k.
    Final(u32),
}

impl LaneletMap {
    /// Centre line of a directed lanelet state, in its driving direction.
    fn state_centre(&self, state: u32) -> Vec<DVec2> {
        let l = &self.lanelets[state as usize / 2];
        if state % 2 == 1 { l.centre.iter().rev().copied().collect() } else { l.centre.clone() }
    }

    fn state_length(&self, state: u32) -> f64 {
        self.graph.lengths[state as usize]
    }

    /// Where a directed lanelet state ends: the last point of its centre line in its direction.
    fn state_end(&self, state: u32) -> DVec2 {
        self.graph.ends[state as usize]
    }

    /// Lower bound [mm] on the cost of any route from `p` to the nearest of `targets`, in the
    /// search's rounded millimetres: the straight line shrunk by the worst rounding (half a
    /// millimetre per lanelet, so relative to the shortest lanelet) and 1 m for centre lines
    /// that do not quite meet.
    fn distance_bound(p: DVec2, targets: &[DVec2], shrink: f64) -> u64 {
        let d = targets.iter().map(|t| p.distance_squared(*t)).fold(f64::INFINITY, f64::min).sqrt();
        (d * 1000.0 * shrink - 1000.0).max(0.0) as u64
    }

    /// Ids of the nodes a route may start or end at by the 2015 rule (on the right bound of a
    /// drivable lanelet), in id order: what `smlworld bench --routing` draws its pairs from.
    pub fn routable_nodes(&self) -> Vec<i64> {
        self.graph.node_states.nodes().to_vec()
    }

    /// Ids of the nodes carrying a tag with this value.
    pub fn nodes_with_tag(&self, value: &str) -> Result<&[i64], MapError> {
        self.tag_index.get(value).map(Vec::as_slice).ok_or_else(|| MapError::UnknownTag(value.to_string()))
    }

    /// The directed routable lanelets each node selects, with the position along them: the 2015
    /// rule (seed §3.3.2) takes the lanelets whose right bound (in driving direction) holds the
    /// node; only a node on no right bound falls back to the lanelets whose left bound holds it.
    fn ends_of(&self, nodes: &[i64]) -> Result<Vec<End>, MapError> {
        let mut out = Vec::new();
        for &id in nodes {
            let node = self.nodes.get(&id).ok_or(MapError::UnknownNode(id))?;
            let right = self.graph.node_states.get(id);
            let (states, left) =
                if right.is_empty() { (self.graph.node_left_states.get(id), true) } else { (right, false) };
            for &state in states {
                let (along, _) = project_polyline(&self.state_centre(state), node.position);
                out.push(End { state, along, node: id, left });
            }
        }
        if out.is_empty() {
            return Err(MapError::NodeNotOnLanelet(nodes[0]));
        }
        Ok(out)
    }

    /// [`Self::ends_of`] without the candidates that add nothing: a start at the very end of a
    /// lanelet (its successors start there too) or an end at the very start of one.
    fn useful_ends(&self, nodes: &[i64], is_start: bool) -> Result<Vec<End>, MapError> {
        let all = self.ends_of(nodes)?;
        let useful: Vec<End> = all
            .iter()
            .copied()
            .filter(|e| if is_start { e.along < self.state_length(e.state) - 1e-3 } else { e.along > 1e-3 })
            .collect();
        Ok(if useful.is_empty() { all } else { useful })
    }

    /// Shortest route from `from_node` to `to_node` along the driving direction.
    pub fn route(&self, from_node: i64, to_node: i64, opts: &RouteOptions) -> Result<Path, MapError> {
        self.route_places(&Place::Node(from_node), &Place::Node(to_node), opts)
    }

    /// Shortest route from any node tagged `from_tag` to any node tagged `to_tag` (tag values).
    pub fn route_tags(&self, from_tag: &str, to_tag: &str, opts: &RouteOptions) -> Result<Path, MapError> {
        self.route_places(&Place::Tag(from_tag.into()), &Place::Tag(to_tag.into()), opts)
    }

    /// Shortest route between two places, each a node id or a node tag value.
    pub fn route_places(&self, from: &Place, to: &Place, opts: &RouteOptions) -> Result<Path, MapError> {
        Ok(self.route_places_routed(from, to, opts)?.path)
    }

    /// [`Self::route_places`] with the nodes it used and the fallback note. A tag naming several
    /// nodes is the best of all of them: the shortest route from any start node to any end node.
    pub fn route_places_routed(&self, from: &Place, to: &Place, opts: &RouteOptions) -> Result<Routed, MapError> {
        let (from_nodes, to_nodes) = (self.place_nodes(from)?, self.place_nodes(to)?);
        self.route_between(&from_nodes, &to_nodes, from.to_string(), to.to_string(), opts, RouteSearch::default())
    }

    /// [`Self::route_places`] with a chosen search algorithm.
    pub fn route_places_with(
        &self,
        from: &Place,
        to: &Place,
        opts: &RouteOptions,
        search: RouteSearch,
    ) -> Result<Path, MapError> {
        let (from_nodes, to_nodes) = (self.place_nodes(from)?, self.place_nodes(to)?);
        Ok(self.route_between(&from_nodes, &to_nodes, from.to_string(), to.to_string(), opts, search)?.path)
    }

    /// Shortest closed loop through a place (a node id or a node tag value).
    pub fn closed_loop_at(&self, place: &Place, opts: &RouteOptions) -> Result<Path, MapError> {
        Ok(self.closed_loop_routed(place, opts)?.path)
    }

    /// [`Self::closed_loop_at`] with the node it used and the fallback note. A tag naming several
    /// nodes is the best of all of them: the shortest loop through any of them.
    pub fn closed_loop_routed(&self, place: &Place, opts: &RouteOptions) -> Result<Routed, MapError> {
        self.loop_through(&self.place_nodes(place)?, place.to_string(), opts)
    }

    /// The note for ends matched on a left bound, `None` when both follow the 2015 rule.
    fn fallback_note(&self, ends: &[End]) -> Option<String> {
        let notes: Vec<String> = ends
            .iter()
            .filter(|e| e.left)
            .map(|e| {
                format!(
                    "node {} lies on no lanelet's right bound; used lanelet {} whose left bound holds it",
                    e.node,
                    self.lanelets[e.state as usize / 2].id
                )
            })
            .collect();
        if notes.is_empty() { None } else { Some(notes.join("; ")) }
    }

    /// The node ids a place stands for.
    pub fn place_nodes(&self, place: &Place) -> Result<Vec<i64>, MapError> {
        match place {
            Place::Node(id) if self.nodes.contains_key(id) => Ok(vec![*id]),
            Place::Node(id) => Err(MapError::UnknownNode(*id)),
            Place::Tag(t) => Ok(self.nodes_with_tag(t)?.to_vec()),
        }
    }

    /// Shortest route from any of `from`'s nodes to any of `to`'s: one Dijkstra over directed
    /// lanelets with exact integer-mm costs, then the crop and stitch of the winner. Kept in one
    /// function (about 85 lines) because the search's predecessor map and end candidates are
    /// what the stitching reads; split, they would travel as a tuple of five.
    fn route_between(
        &self,
        from: &[i64],
        to: &[i64],
        from_name: String,
        to_name: String,
        opts: &RouteOptions,
        search: RouteSearch,
    ) -> Result<Routed, MapError> {
        check_options(opts)?;
        let starts = self.useful_ends(from, true)?;
        let finals = self.useful_ends(to, false)?;
        let reach = |s: &End| finals.iter().any(|f| self.graph.may_reach(s.state, f.state));
        if !starts.iter().any(reach) {
            return Err(MapError::NoRoute { from: from_name, to: to_name });
        }
        // Best start per state: the one furthest along (least left to drive on it).
        let mut best_start: BTreeMap<u32, End> = BTreeMap::new();
        for s in &starts {
            let e = best_start.entry(s.state).or_insert(*s);
            if s.along > e.along {
                *e = *s;
            }
        }
        // End candidates by state, sorted: a few entries, searched for every successor (a tree
        // map's lookup cost more than the search around it).
        let finals_by_state: Vec<(u32, u32)> = {
            let mut v: Vec<(u32, u32)> = finals.iter().enumerate().map(|(k, f)| (f.state, k as u32)).collect();
            v.sort_unstable();
            v
        };
        let finals_on = |state: u32| {
            let from = finals_by_state.partition_point(|&(s, _)| s < state);
            finals_by_state[from..].iter().take_while(move |&&(s, _)| s == state).map(|&(_, k)| k)
        };
        let successors = |step: &Step, out: &mut Vec<(Step, u64)>| {
            match *step {
                Step::Start => {
                    for s in best_start.values() {
                        out.push((Step::Exit(s.state), mm(self.state_length(s.state) - s.along)));
                    }
                    // Start and end on the same lanelet with the end ahead: stay on it.
                    for s in &starts {
                        for k in finals_on(s.state) {
                            let f = finals[k as usize];
                            if f.along >= s.along {
                                out.push((Step::Final(k), mm(f.along - s.along)));
                            }
                        }
                    }
                }
                Step::Exit(state) => {
                    for &next in &self.graph.successors[state as usize] {
                        out.push((Step::Exit(next), mm(self.state_length(next))));
                        for k in finals_on(next) {
                            out.push((Step::Final(k), mm(finals[k as usize].along)));
                        }
                    }
                }
                Step::Final(_) => {}
            }
        };
        let is_final = |s: &Step| matches!(s, Step::Final(_));
        let found = match search {
            RouteSearch::Dijkstra => {
                let listed = |s: &Step| {
                    let mut out = Vec::new();
                    successors(s, &mut out);
                    out
                };
                pathfinding::directed::dijkstra::dijkstra(&Step::Start, listed, is_final)
            }
            RouteSearch::AStar => {
                let targets: Vec<DVec2> = finals
                    .iter()
                    .map(|f| {
                        let centre = self.state_centre(f.state);
                        sub_polyline(&centre, 0.0, f.along).last().copied().unwrap_or(centre[0])
                    })
                    .collect();
                // Every rounded lanelet cost is at least its length minus 0.5 mm.
                let shortest = self.lanelets.iter().map(|l| l.length).fold(f64::INFINITY, f64::min) * 1000.0;
                let shrink = if shortest > 1.0 { 1.0 - 0.5 / shortest } else { 0.0 };
                let heuristic = |s: &Step| match *s {
                    Step::Exit(state) => Self::distance_bound(self.state_end(state), &targets, shrink),
                    Step::Start | Step::Final(_) => 0,
                };
                self.astar(finals.len(), successors, heuristic)
            }
        };
        let (steps, _) = found.ok_or(MapError::NoRoute { from: from_name, to: to_name })?;

        let Some(&Step::Final(k)) = steps.last() else { unreachable!("dijkstra ends on a Final step") };
        let fin = finals[k as usize];
        let mut states: Vec<u32> =
            steps.iter().filter_map(|s| if let Step::Exit(st) = s { Some(*st) } else { None }).collect();
        let start = if states.is_empty() {
            // Same lanelet: the start is the furthest-along start candidate behind the end.
            let start = starts
                .iter()
                .filter(|s| s.state == fin.state && s.along <= fin.along)
                .fold(None::<End>, |b, s| if b.is_some_and(|b| b.along >= s.along) { b } else { Some(*s) })
                .expect("dijkstra only stays on a lanelet with a start behind the end");
            states.push(fin.state);
            start
        } else {
            let start = best_start[&states[0]];
            states.push(fin.state);
            start
        };
        let (first_along, last_along) = (start.along, fin.along);
        let points = self.stitch(&states);
        let total = polyline_length(&points);
        let end_arc = total - self.state_length(fin.state) + last_along;
        let cropped = sub_polyline(&points, first_along, end_arc.max(first_along));
        let lanelets = states.iter().map(|&s| self.lanelets[s as usize / 2].id).collect();
        Ok(Routed {
            path: Path::from_points(lanelets, resample(&cropped, opts.points_per_meter), false),
            from_node: start.node,
            to_node: fin.node,
            note: self.fallback_note(&[start, fin]),
        })
    }

    /// A* from [`Step::Start`] to the first [`Step::Final`] over arrays indexed by step (start,
    /// every directed lanelet state, every end candidate) instead of a hash map: (steps, cost).
    /// Among equally promising steps the one furthest from the start goes first, so ties on a
    /// regular grid run straight for the goal. The heuristic must never overestimate; it need
    /// not be consistent (a step reached more cheaply is searched again).
    fn astar(
        &self,
        finals: usize,
        mut successors: impl FnMut(&Step, &mut Vec<(Step, u64)>),
        heuristic: impl Fn(&Step) -> u64,
    ) -> Option<(Vec<Step>, u64)> {
        // The arrays of the last search on this thread, reset where it wrote: a fresh pair per
        // search (16 bytes a state) was zeroed by the kernel on every random trip of a town.
        thread_local! {
            static SCRATCH: std::cell::RefCell<AstarScratch> = std::cell::RefCell::default();
        }
        let mut scratch = SCRATCH.with(|s| s.take());
        let found = self.astar_in(&mut scratch, finals, &mut successors, heuristic);
        let AstarScratch { best, parent, touched, open, next } = &mut scratch;
        for &i in touched.iter() {
            best[i] = u64::MAX;
            parent[i] = usize::MAX;
        }
        touched.clear();
        open.clear();
        next.clear();
        SCRATCH.with(|s| s.replace(scratch));
        found
    }

    /// [`LaneletMap::astar`] over `scratch`, whose `best` and `parent` hold no step on entry
    /// (`u64::MAX`, `usize::MAX`); the steps written are listed in `touched`.
    fn astar_in(
        &self,
        scratch: &mut AstarScratch,
        finals: usize,
        successors: &mut impl FnMut(&Step, &mut Vec<(Step, u64)>),
        heuristic: impl Fn(&Step) -> u64,
    ) -> Option<(Vec<Step>, u64)> {
        use std::cmp::Reverse;
        let states = 2 * self.lanelets.len();
        let index = |s: &Step| match *s {
            Step::Start => 0,
            Step::Exit(x) => 1 + x as usize,
            Step::Final(k) => 1 + states + k as usize,
        };
        let step_of = |i: usize| match i {
            0 => Step::Start,
            i if i <= states => Step::Exit((i - 1) as u32),
            i => Step::Final((i - 1 - states) as u32),
        };
        let AstarScratch { best, parent, touched, open, next } = scratch;
        let len = 1 + states + finals;
        if best.len() < len {
            best.resize(len, u64::MAX);
            parent.resize(len, usize::MAX);
        }
        best[0] = 0;
        touched.push(0);
        open.push((Reverse(heuristic(&Step::Start)), 0u64, Reverse(0usize)));
        while let Some((_, cost, Reverse(i))) = open.pop() {
            if cost > best[i] {
                continue;
            }
            let step = step_of(i);
            if let Step::Final(_) = step {
                let mut steps = vec![step];
                let mut at = i;
                while parent[at] != usize::MAX {
                    at = parent[at];
                    steps.push(step_of(at));
                }
                steps.reverse();
                return Some((steps, cost));
            }
            next.clear();
            successors(&step, next);
            for &(to, step_cost) in next.iter() {
                let j = index(&to);
                let reached = cost + step_cost;
                if reached < best[j] {
                    if best[j] == u64::MAX {
                        touched.push(j);
                    }
                    best[j] = reached;
                    parent[j] = i;
                    open.push((Reverse(reached + heuristic(&to)), reached, Reverse(j)));
                }
            }
        }
        None
    }

    /// Centre lines of consecutive directed lanelets joined into one polyline.
    fn stitch(&self, states: &[u32]) -> Vec<DVec2> {
        let mut points: Vec<DVec2> = Vec::new();
        for &s in states {
            let c = self.state_centre(s);
            let skip = usize::from(points.last().is_some_and(|p| p.distance(c[0]) < 1e-6));
            points.extend_from_slice(&c[skip..]);
        }
        points
    }

    /// Shortest closed loop through `node`: around and back to the lanelet it started on.
    pub fn closed_loop(&self, node: i64, opts: &RouteOptions) -> Result<Path, MapError> {
        self.closed_loop_at(&Place::Node(node), opts)
    }

    /// Shortest closed loop through any node carrying the tag value `tag`.
    pub fn closed_loop_tag(&self, tag: &str, opts: &RouteOptions) -> Result<Path, MapError> {
        self.closed_loop_at(&Place::Tag(tag.into()), opts)
    }

    fn loop_through(&self, nodes: &[i64], name: String, opts: &RouteOptions) -> Result<Routed, MapError> {
        check_options(opts)?;
        let mut best: Option<(u64, Vec<u32>, End)> = None;
        for start in self.ends_of(nodes)? {
            let s = start.state;
            let found = pathfinding::directed::dijkstra::dijkstra(
                &Step::Exit(s),
                |step: &Step| -> Vec<(Step, u64)> {
                    let Step::Exit(state) = *step else { return Vec::new() };
                    self.graph.successors[state as usize]
                        .iter()
                        .map(|&next| {
                            if next == s {
                                (Step::Final(s), 0)
                            } else {
                                (Step::Exit(next), mm(self.state_length(next)))
                            }
                        })
                        .collect()
                },
                |step| matches!(step, Step::Final(_)),
            );
            if let Some((steps, cost)) = found {
                let cost = cost + mm(self.state_length(s));
                if best.as_ref().is_none_or(|b| cost < b.0) {
                    let states =
                        steps.iter().filter_map(|st| if let Step::Exit(x) = st { Some(*x) } else { None }).collect();
                    best = Some((cost, states, start));
                }
            }
        }
        let (_, states, start) = best.ok_or(MapError::NoRoute { from: name.clone(), to: name })?;
        let mut ring = self.stitch(&states);
        if ring.len() > 1 && ring[ring.len() - 1].distance(ring[0]) < 1e-6 {
            ring.pop();
        }
        ring.push(ring[0]);
        // Rotate the loop so that it starts at the node.
        let total = polyline_length(&ring);
        let mut rotated = sub_polyline(&ring, start.along, total);
        rotated.extend_from_slice(&sub_polyline(&ring, 0.0, start.along)[1..]);
        let mut points = resample(&rotated, opts.points_per_meter);
        points.pop();
        let lanelets = states.iter().map(|&s| self.lanelets[s as usize / 2].id).collect();
        Ok(Routed {
            path: Path::from_points(lanelets, points, true),
            from_node: start.node,
            to_node: start.node,
            note: self.fallback_note(&[start]),
        })
    }

    /// Shortest route from the start of lanelet `from` to the end of lanelet `to`, both driven
    /// in their own direction, through successors only (no lane change): what random trips
    /// drive. `from == to` is that one lanelet. Unlike [`Self::route_places`] it starts on
    /// exactly `from`, not on whichever lanelet at its start node is best.
    pub fn route_lanelets(&self, from: LaneletId, to: LaneletId, opts: &RouteOptions) -> Result<Path, MapError> {
        check_options(opts)?;
        let state = |id: LaneletId| {
            self.lanelet_index(id)
                .filter(|&i| self.lanelets[i].routable)
                .map(|i| (2 * i) as u32)
                .ok_or(MapError::UnknownLanelet(id.0))
        };
        let (first, last) = (state(from)?, state(to)?);
        let mut states = vec![first];
        if first != last {
            let no_route = || MapError::NoRoute { from: format!("lanelet {from}"), to: format!("lanelet {to}") };
            if !self.graph.may_reach(first, last) {
                return Err(no_route());
            }
            let successors = |step: &Step, out: &mut Vec<(Step, u64)>| match *step {
                Step::Start => out.push((Step::Exit(first), mm(self.state_length(first)))),
                Step::Exit(s) => out.extend(self.graph.successors[s as usize].iter().map(|&next| {
                    if next == last { (Step::Final(0), 0) } else { (Step::Exit(next), mm(self.state_length(next))) }
                })),
                Step::Final(_) => {}
            };
            // The search ends on entering `to`, so the straight line runs to where `to` starts.
            let target = [self.lanelets[last as usize / 2].centre[0]];
            let shortest = self.lanelets.iter().map(|l| l.length).fold(f64::INFINITY, f64::min) * 1000.0;
            let shrink = if shortest > 1.0 { 1.0 - 0.5 / shortest } else { 0.0 };
            let heuristic = |s: &Step| match *s {
                Step::Exit(state) => Self::distance_bound(self.state_end(state), &target, shrink),
                Step::Start | Step::Final(_) => 0,
            };
            let (steps, _) = self.astar(1, successors, heuristic).ok_or_else(no_route)?;
            states = steps.iter().filter_map(|s| if let Step::Exit(x) = s { Some(*x) } else { None }).collect();
            states.push(last);
        }
        let points = self.stitch(&states);
        let lanelets = states.iter().map(|&s| self.lanelets[s as usize / 2].id).collect();
        Ok(Path::from_points(lanelets, resample(&points, opts.points_per_meter), false))
    }

    /// Number of (i, j) lanelet pairs where j follows i.
    pub fn successor_pairs(&self) -> usize {
        self.lanelets.iter().map(|l| l.successors.len()).sum()
    }

    /// The seed's adjacency matrix: n x n in [`LaneletMap::lanelets`] order, entry (i, j) = length
    /// of lanelet i \[m\] when j follows i, else 1e10.
    pub fn adjacency_matrix(&self) -> Vec<Vec<f64>> {
        let n = self.lanelets.len();
        let mut m = vec![vec![1e10; n]; n];
        for (i, l) in self.lanelets.iter().enumerate() {
            for s in &l.successors {
                if let Some(j) = self.lanelet_index(*s) {
                    m[i][j] = l.length;
                }
            }
        }
        m
    }

    /// Bounding box of all nodes \[m\]: (min, max). Zero when the map has no nodes.
    pub fn bounding_box(&self) -> (DVec2, DVec2) {
        let mut it = self.nodes.values().map(|n| n.position);
        let Some(first) = it.next() else { return (DVec2::ZERO, DVec2::ZERO) };
        it.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p)))
    }
}

fn check_options(opts: &RouteOptions) -> Result<(), MapError> {
    if opts.points_per_meter.is_finite() && opts.points_per_meter > 0.0 && opts.points_per_meter <= 1000.0 {
        Ok(())
    } else {
        Err(MapError::InvalidOption(format!(
            "points_per_meter = {} is not allowed; use a number in (0, 1000], e.g. 5",
            opts.points_per_meter
        )))
    }
}

/// What [`LaneletMap::astar`] keeps between searches on a thread.
#[derive(Default)]
struct AstarScratch {
    /// Best cost so far by step index (`u64::MAX`: not reached).
    best: Vec<u64>,
    /// The step each was reached from (`usize::MAX`: none).
    parent: Vec<usize>,
    /// Steps whose `best` was written (to reset after the search).
    touched: Vec<usize>,
    /// Open steps: (Reverse(cost + bound), cost, Reverse(step index)).
    open: std::collections::BinaryHeap<(std::cmp::Reverse<u64>, u64, std::cmp::Reverse<usize>)>,
    /// The successors of the step being expanded.
    next: Vec<(Step, u64)>,
}
