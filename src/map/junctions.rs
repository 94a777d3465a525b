//! Junctions and their conflicts, computed once from any map's lanelets (JOSM/SML, Lanelet2,
//! CommonRoad, generated): pure functions of the [`LaneletMap`], nothing per tick.
//!
//! - A **conflict** is a pair of routable lanelets whose centre lines cross (`crossing`) or that
//!   enter the same lanelet (`merging`), with the arc length on each where they meet. Lanelets
//!   that leave the same lanelet (diverging) or follow one another (directly, or through
//!   lanelets under 2 m in all, `JOINT_CHAIN`) do not conflict, nor do
//!   lanelets that cross on different levels ([`grade_separated`]: an OpenDRIVE bridge;
//!   [`Junctions::levels_apart`] lists them for the collision check and leader search).
//! - A **junction** is a connected group of conflicting lanelets (its **links**, listed in id
//!   order: a traffic-light state has one character per link in that order).
//! - Its **control** comes from the map where it says so: a Lanelet2 `traffic_light` regulatory
//!   element (or a lanelet tag `traffic_light = yes`, as `map generate --traffic-lights` writes)
//!   on a link or on the lanelets leading into it makes a `traffic_light` junction;
//!   Lanelet2 `right_of_way` elements (roles `right_of_way`/`yield`) or a lanelet tag
//!   `priority = major|minor` make a `priority` junction; a Lanelet2 `all_way_stop` element an
//!   `all_way_stop` one. Otherwise the documented default: the approaches with the most lanes
//!   (then the highest `speed_limit` tag) are major when some other approach has fewer, giving a
//!   `priority` junction; where all approaches are equal, right before left
//!   (`right_before_left`; left before right where a lanelet is tagged `driving_side = left`), or
//!   first come, first served (`first_come`) when a scenario asks for it.
//! - Between two links of the same rank, who yields follows the approach directions (SUMO's
//!   junction model, `docs/web/docs/Networks/SUMO_Road_Networks.md`, and the StVO's
//!   right-before-left): a vehicle yields to one coming from its right; of two opposite
//!   approaches the one turning left yields; of two links from one approach, the one from the
//!   left lane yields.

pub use super::lanelet::{MapSignalProgram, SignalPhase};
use std::collections::BTreeMap;

use glam::DVec2;

use super::lanelet::{LaneletId, LaneletMap};
use super::polyline::project_polyline;

/// Size of a cell of the segment grid used to find crossings [m].
const CELL: f64 = 10.0;
/// Two centre lines closer than this [m] have come together: where a merge's conflict starts.
const MERGE_DISTANCE: f64 = 2.5;
/// Centre lines that pass closer than this [m] without crossing conflict all the same: two
/// vehicles of 2 m width would touch (a left turn sweeping past the opposite right turn).
const NEAR_MISS: f64 = 2.2;
/// A crossing within this distance [m] of an end of both lanelets is a joint, not a conflict.
const JOINT: f64 = 0.5;
/// Lanelets after a lanelet's end through lanelets shorter than this in all [m] meet it at its
/// joint, as its successors do ([`followers_at_joint`]).
const JOINT_CHAIN: f64 = 2.0;
/// Heading changes under this [rad] (30°) count as straight on.
const STRAIGHT: f64 = std::f64::consts::FRAC_PI_6;
/// How far back from a link the lanelets leading into it may carry its rules [m].
const UPSTREAM: f64 = 30.0;
/// Length over which a link's start and end headings are measured [m].
const HEADING_BASE: f64 = 3.0;

/// How two links meet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ConflictKind {
    /// The centre lines cross.
    Crossing,
    /// Both lanelets lead into the same lanelet.
    Merging,
}

/// Who gives way at a conflict when no signal says otherwise.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Yield {
    /// Link `a` yields to link `b`.
    A,
    /// Link `b` yields to link `a`.
    B,
    /// Whoever reached the junction first goes first.
    FirstCome,
}

/// How a junction is controlled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum JunctionControl {
    /// Major and minor links: minor links yield.
    Priority,
    /// Signals ([`super::junctions`] links' states from a program).
    TrafficLight,
    /// Every vehicle stops, then first come, first served.
    AllWayStop,
    /// All approaches equal: yield to the vehicle on the right.
    RightBeforeLeft,
    /// All approaches equal: first come, first served (a scenario's `[junctions] default`).
    FirstCome,
}

impl JunctionControl {
    /// The name used in `map info` and scenario files.
    pub fn name(self) -> &'static str {
        match self {
            JunctionControl::Priority => "priority",
            JunctionControl::TrafficLight => "traffic_light",
            JunctionControl::AllWayStop => "all_way_stop",
            JunctionControl::RightBeforeLeft => "right_before_left",
            JunctionControl::FirstCome => "first_come",
        }
    }
}

/// What a junction does where the map says nothing (a scenario's `[junctions] default`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Fallback {
    /// Yield to the right (to the left on left-hand traffic maps).
    #[default]
    RightBeforeLeft,
    /// First come, first served.
    FirstCome,
}

/// The rules [`find_junctions`] applies where the map is silent.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct JunctionRules {
    /// Rule between equal approaches.
    pub fallback: Fallback,
    /// Left-hand traffic; `None`: from the map (a lanelet tagged `driving_side = left`).
    pub left_hand: Option<bool>,
}

/// Where a link goes, from its heading change.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Turn {
    /// Less than 30° either way.
    Straight,
    /// To the left.
    Left,
    /// To the right.
    Right,
    /// Back the way it came (more than 150°).
    UTurn,
}

/// One link of a junction: a lanelet that conflicts with another of the junction.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Link {
    /// The lanelet.
    pub lanelet: LaneletId,
    /// The routable lanelet leading into it (lowest id), if any.
    pub from: Option<LaneletId>,
    /// Heading at its start \[rad\].
    pub heading_in: f64,
    /// Heading change along it.
    pub turn: Turn,
    /// Whether it has priority (major road) at a `priority` junction.
    pub major: bool,
    /// The Lanelet2 `traffic_light` element controlling it (on it or on `from`).
    pub signal: Option<i64>,
    /// Its length \[m\].
    pub length: f64,
}

/// Two links that meet.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Conflict {
    /// The link of the lower id.
    pub a: LaneletId,
    /// The other link.
    pub b: LaneletId,
    /// Crossing or merging.
    pub kind: ConflictKind,
    /// Arc length along `a` where they meet \[m\].
    pub s_a: f64,
    /// Arc length along `b` where they meet \[m\].
    pub s_b: f64,
    /// Where they meet \[m\].
    #[serde(skip)]
    pub point: DVec2,
    /// Who gives way when no signal decides.
    pub yields: Yield,
}

impl Conflict {
    /// Whether the vehicle on `mine` gives way to the one on the other link (no signals).
    pub fn yields_from(&self, mine: LaneletId) -> Option<bool> {
        match self.yields {
            Yield::A => Some(mine == self.a),
            Yield::B => Some(mine == self.b),
            Yield::FirstCome => None,
        }
    }

    /// The other link and the arc lengths (on `mine`, on the other) of the meeting point.
    pub fn seen_from(&self, mine: LaneletId) -> (LaneletId, f64, f64) {
        if mine == self.a { (self.b, self.s_a, self.s_b) } else { (self.a, self.s_b, self.s_a) }
    }
}

/// One junction.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Junction {
    /// Id, counted from 1 in the order of each junction's lowest lanelet id.
    pub id: u32,
    /// Its links in lanelet id order (one character of a signal state each).
    pub links: Vec<Link>,
    /// Every conflict between its links, ordered by (a, b).
    pub conflicts: Vec<Conflict>,
    /// How it is controlled.
    pub control: JunctionControl,
    /// Mean of its conflict points \[m\].
    #[serde(skip)]
    pub centre: DVec2,
}

impl Junction {
    /// The lanelets of its links, in link order.
    pub fn lanelets(&self) -> Vec<LaneletId> {
        self.links.iter().map(|l| l.lanelet).collect()
    }

    /// Position of `lanelet` among the links.
    pub fn link_index(&self, lanelet: LaneletId) -> Option<usize> {
        self.links.binary_search_by_key(&lanelet, |l| l.lanelet).ok()
    }
}

/// Every junction of a map and where each link is.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Junctions {
    /// The junctions by id order (`list[k].id == k + 1`).
    pub list: Vec<Junction>,
    by_lanelet: BTreeMap<LaneletId, (u32, u32)>,
    /// Pairs of lanelets (map indices, lower first) whose centre lines cross on different
    /// levels ([`grade_separated`]).
    levels_apart: std::collections::BTreeSet<(u32, u32)>,
}

impl Junctions {
    /// The junction with this id.
    pub fn get(&self, id: u32) -> Option<&Junction> {
        id.checked_sub(1).and_then(|k| self.list.get(k as usize))
    }

    /// Whether lanelets `a` and `b` (map indices) cross on different levels (a bridge over a
    /// road, [`grade_separated`]): vehicles on them pass over each other, neither touch nor
    /// lead each other.
    pub fn levels_apart(&self, a: usize, b: usize) -> bool {
        !self.levels_apart.is_empty() && self.levels_apart.contains(&(a.min(b) as u32, a.max(b) as u32))
    }

    /// Whether any two lanelets cross on different levels.
    pub fn any_levels_apart(&self) -> bool {
        !self.levels_apart.is_empty()
    }

    /// (junction index in `list`, link index) of a lanelet that is a junction link.
    pub fn of_lanelet(&self, lanelet: LaneletId) -> Option<(usize, usize)> {
        self.by_lanelet.get(&lanelet).map(|&(j, k)| (j as usize, k as usize))
    }

    /// Number of junctions.
    pub fn len(&self) -> usize {
        self.list.len()
    }

    /// Whether the map has no junction.
    pub fn is_empty(&self) -> bool {
        self.list.is_empty()
    }
}

/// Where two segments `p0-p1` and `q0-q1` cross: the fractions along each.
fn segment_crossing(p0: DVec2, p1: DVec2, q0: DVec2, q1: DVec2) -> Option<(f64, f64)> {
    let r = p1 - p0;
    let s = q1 - q0;
    let denom = r.perp_dot(s);
    if denom.abs() < 1e-12 {
        return None;
    }
    let qp = q0 - p0;
    let t = qp.perp_dot(s) / denom;
    let u = qp.perp_dot(r) / denom;
    ((0.0..=1.0).contains(&t) && (0.0..=1.0).contains(&u)).then_some((t, u))
}

/// Closest approach of two segments that do not cross: (distance [m], fraction along `p`,
/// fraction along `q`), from the four end-to-segment distances.
fn segment_distance(p0: DVec2, p1: DVec2, q0: DVec2, q1: DVec2) -> (f64, f64, f64) {
    let onto = |a: DVec2, b: DVec2, x: DVec2| {
        let d = b - a;
        let len2 = d.length_squared();
        if len2 < 1e-18 { 0.0 } else { ((x - a).dot(d) / len2).clamp(0.0, 1.0) }
    };
    let mut best = (f64::INFINITY, 0.0, 0.0);
    for (t, x) in [(0.0, p0), (1.0, p1)] {
        let u = onto(q0, q1, x);
        let d = x.distance(q0 + (q1 - q0) * u);
        if d < best.0 {
            best = (d, t, u);
        }
    }
    for (u, x) in [(0.0, q0), (1.0, q1)] {
        let t = onto(p0, p1, x);
        let d = x.distance(p0 + (p1 - p0) * t);
        if d < best.0 {
            best = (d, t, u);
        }
    }
    best
}

/// Cumulative arc length at each point of a polyline [m].
fn arc_lengths(points: &[DVec2]) -> Vec<f64> {
    let mut out = Vec::with_capacity(points.len());
    let mut s = 0.0;
    for (k, p) in points.iter().enumerate() {
        if k > 0 {
            s += p.distance(points[k - 1]);
        }
        out.push(s);
    }
    out
}

/// Heading [rad] of a polyline near its start (`at_end = false`) or its end.
fn heading(points: &[DVec2], at_end: bool) -> f64 {
    if points.len() < 2 {
        return 0.0;
    }
    let n = points.len();
    let (a, b) = if at_end {
        let b = points[n - 1];
        let a = points[..n - 1].iter().rev().find(|p| p.distance(b) >= HEADING_BASE).copied().unwrap_or(points[0]);
        (a, b)
    } else {
        let a = points[0];
        let b = points[1..].iter().find(|p| p.distance(a) >= HEADING_BASE).copied().unwrap_or(points[n - 1]);
        (a, b)
    };
    let d = b - a;
    d.y.atan2(d.x)
}

/// An angle brought into (-π, π].
pub fn wrap_angle(a: f64) -> f64 {
    let t = a.rem_euclid(std::f64::consts::TAU);
    if t > std::f64::consts::PI { t - std::f64::consts::TAU } else { t }
}

/// The turn of a heading change [rad].
fn turn_of(change: f64) -> Turn {
    let c = wrap_angle(change);
    if c.abs() > 5.0 * STRAIGHT {
        Turn::UTurn
    } else if c > STRAIGHT {
        Turn::Left
    } else if c < -STRAIGHT {
        Turn::Right
    } else {
        Turn::Straight
    }
}

/// A conflict found in the geometry, before junctions and rules.
#[derive(Debug, Clone, Copy)]
struct RawConflict {
    a: usize,
    b: usize,
    kind: ConflictKind,
    s_a: f64,
    s_b: f64,
    point: DVec2,
}

/// Every crossing and merging pair of routable lanelets (indices into `map.lanelets`, a < b).
/// O(segments) with a grid of [`CELL`] m, plus the pairs sharing a cell.
/// The conflicts of `map`, and the pairs of lanelets (map indices, lower first) whose centre
/// lines cross on different levels ([`grade_separated`]).
fn raw_conflicts(
    map: &LaneletMap,
    predecessors: &[Vec<usize>],
    successors: &[Vec<usize>],
) -> (Vec<RawConflict>, std::collections::BTreeSet<(u32, u32)>) {
    let mut apart = std::collections::BTreeSet::new();
    let lanelets = &map.lanelets;
    let arcs: Vec<Vec<f64>> = lanelets.iter().map(|l| arc_lengths(&l.centre)).collect();
    let cell = |p: DVec2| ((p.x / CELL).floor() as i64, (p.y / CELL).floor() as i64);
    let mut grid: BTreeMap<(i64, i64), Vec<(u32, u32)>> = BTreeMap::new();
    for (i, l) in lanelets.iter().enumerate() {
        if !l.routable {
            continue;
        }
        for k in 1..l.centre.len() {
            let (a, b) = (l.centre[k - 1], l.centre[k]);
            let (lo, hi) = (cell(a.min(b)), cell(a.max(b)));
            for cx in lo.0..=hi.0 {
                for cy in lo.1..=hi.1 {
                    grid.entry((cx, cy)).or_default().push((i as u32, k as u32 - 1));
                }
            }
        }
    }
    let shares = |x: &[usize], y: &[usize]| x.iter().any(|v| y.contains(v));
    let followers: Vec<Vec<usize>> = (0..lanelets.len()).map(|i| followers_at_joint(lanelets, successors, i)).collect();
    // First crossing (by arc length on the lower index) of every pair.
    let mut crossings: BTreeMap<(usize, usize), (RawConflict, bool, f64)> = BTreeMap::new();
    let mut every_crossing: BTreeMap<(usize, usize), Vec<RawConflict>> = BTreeMap::new();
    // Closest approach of a turnaround and a link it passes near, neither sharing a start nor
    // an end with it: a conflict where it never crosses that link. On issue 54's 20x20 grid, 8
    // of its 12 collisions were U-turners sweeping into the right turn of the arm beside them.
    let mut turn_near: BTreeMap<(usize, usize), (RawConflict, f64)> = BTreeMap::new();
    for segments in grid.values() {
        for (m, &(i, ki)) in segments.iter().enumerate() {
            for &(j, kj) in &segments[m + 1..] {
                if i == j {
                    continue;
                }
                let (i, ki, j, kj) = if i < j { (i, ki, j, kj) } else { (j, kj, i, ki) };
                let (iu, ju) = (i as usize, j as usize);
                // Followers meet at their joint; diverging lanes share their start (one queue),
                // merging ones are merges.
                let (li, lj) = (&lanelets[iu], &lanelets[ju]);
                // A turnaround drawn round the junction leaves its lane with the others from
                // it and crosses some of them further on: those crossings count.
                // So does one that ends in the lane another link ends in, crossing that link on
                // the way (the merge at the end is found below as for any two).
                let diverging = shares(&predecessors[iu], &predecessors[ju]);
                let merging = shares(&successors[iu], &successors[ju]);
                let any_turn = redrawn_turnaround(&li.tags) || redrawn_turnaround(&lj.tags);
                let wide_turn = (diverging || merging) && any_turn;
                if followers[iu].contains(&ju) || followers[ju].contains(&iu) || (diverging || merging) && !wide_turn {
                    continue;
                }
                let (p0, p1) = (li.centre[ki as usize], li.centre[ki as usize + 1]);
                let (q0, q1) = (lj.centre[kj as usize], lj.centre[kj as usize + 1]);
                if grade_separated(li, lj) {
                    // Near misses too: lanes side by side under a bridge's edge.
                    if segment_crossing(p0, p1, q0, q1).is_some() || segment_distance(p0, p1, q0, q1).0 < NEAR_MISS {
                        apart.insert((i, j));
                    }
                    continue;
                }
                let (t, u, crossed, dist) = match segment_crossing(p0, p1, q0, q1) {
                    Some((t, u)) => (t, u, true, 0.0),
                    // Side by side from their common start is one queue, not a conflict.
                    None if wide_turn => continue,
                    None => {
                        let (d, t, u) = segment_distance(p0, p1, q0, q1);
                        if d >= NEAR_MISS {
                            continue;
                        }
                        (t, u, false, d)
                    }
                };
                let s_a = arcs[iu][ki as usize] + t * p0.distance(p1);
                let s_b = arcs[ju][kj as usize] + u * q0.distance(q1);
                let at_end = |s: f64, len: f64| s < JOINT || s > len - JOINT;
                let near_shared_end = |s: f64, len: f64| if diverging { s < JOINT } else { s > len - JOINT };
                if at_end(s_a, li.length) && at_end(s_b, lj.length)
                    || wide_turn && (near_shared_end(s_a, li.length) || near_shared_end(s_b, lj.length))
                {
                    continue;
                }
                let point = p0 + (p1 - p0) * t;
                let c = RawConflict { a: iu, b: ju, kind: ConflictKind::Crossing, s_a, s_b, point };
                // A turnaround drawn round the junction crosses some lanes twice (out and back):
                // each crossing is a conflict of its own. One it only passes close to (its loop
                // sweeping by another arm's right turn) it meets where it comes closest, unless
                // it crosses it too (kept below).
                if any_turn && !crossed {
                    let closest = turn_near.entry((iu, ju)).or_insert((c, dist));
                    if dist < closest.1 {
                        *closest = (c, dist);
                    }
                    continue;
                }
                if any_turn {
                    let pair = every_crossing.entry((iu, ju)).or_default();
                    // One per crossing (a segment in several grid cells is met in each).
                    if crossed && !pair.iter().any(|o| (o.s_a - s_a).abs() < 2.0) {
                        pair.push(c);
                    }
                    continue;
                }
                // A crossing (its first point) wins over a near miss; of near misses, the closest.
                let key = (iu, ju);
                match crossings.get(&key) {
                    None => {
                        crossings.insert(key, (c, crossed, dist));
                    }
                    Some(&(old, old_crossed, old_dist)) => {
                        let better = match (crossed, old_crossed) {
                            (true, false) => true,
                            (false, true) => false,
                            (true, true) => s_a < old.s_a,
                            (false, false) => dist < old_dist,
                        };
                        if better {
                            crossings.insert(key, (c, crossed, dist));
                        }
                    }
                }
            }
        }
    }
    let mut out: Vec<RawConflict> = crossings.into_values().map(|(c, _, _)| c).collect();
    for (pair, (c, _)) in turn_near {
        let met = every_crossing.entry(pair).or_default();
        if met.is_empty() {
            met.push(c);
        }
    }
    out.extend(every_crossing.into_values().flatten());
    // Merges: every pair of routable lanelets leading into the same one, met where their centre
    // lines come within MERGE_DISTANCE (else at their ends).
    let mut merges: BTreeMap<(usize, usize), RawConflict> = BTreeMap::new();
    for preds in predecessors {
        for (m, &a) in preds.iter().enumerate() {
            for &b in &preds[m + 1..] {
                let (a, b) = (a.min(b), a.max(b));
                if merges.contains_key(&(a, b)) {
                    continue;
                }
                let (la, lb) = (&lanelets[a], &lanelets[b]);
                let met = if redrawn_turnaround(&la.tags) || redrawn_turnaround(&lb.tags) {
                    // A turnaround drawn round the junction may cross the other link before it
                    // merges: they meet where it comes near for good.
                    let (t, o, swap) = if redrawn_turnaround(&la.tags) { (a, b, false) } else { (b, a, true) };
                    let (lt, lo) = (&lanelets[t], &lanelets[o]);
                    let last_apart =
                        lt.centre.iter().rposition(|p| project_polyline(&lo.centre, *p).1 >= MERGE_DISTANCE);
                    let k = last_apart.map_or(0, |k| (k + 1).min(lt.centre.len() - 1));
                    lt.centre.get(k).map(|p| {
                        let (s_t, s_o) = (arcs[t][k], project_polyline(&lo.centre, *p).0);
                        if swap { (s_o, s_t, *p) } else { (s_t, s_o, *p) }
                    })
                } else {
                    la.centre.iter().enumerate().find_map(|(k, p)| {
                        let (along, dist) = project_polyline(&lb.centre, *p);
                        (dist < MERGE_DISTANCE).then_some((arcs[a][k], along, *p))
                    })
                };
                let (s_a, s_b, point) =
                    met.unwrap_or((la.length, lb.length, la.centre.last().copied().unwrap_or_default()));
                merges.insert((a, b), RawConflict { a, b, kind: ConflictKind::Merging, s_a, s_b, point });
            }
        }
    }
    out.extend(merges.into_values());
    out.sort_by_key(|c| (c.a, c.b, c.kind));
    (out, apart)
}

/// The lanelets that follow lanelet `i` at its end: its successors, and theirs while the
/// lanelets between add up to less than [`JOINT_CHAIN`]. Their centre lines meet `i`'s at its
/// joint, which is no conflict. A chain of tiny lanelets counts as the joint: CARLA Town04's
/// road 841 (junction 804) starts with lane sections of 0.1, 0.5 and 0.2 m, and the 0.6 m
/// after road 40's end made it "cross" road 40 lane -2 0.6 m before that end, a junction of a
/// lane with its own continuation; a platoon leader braked there for the car ahead of it and
/// its follower ran into it (`scenarios/town04_platoon.toml` with seed 2, t = 435 s).
fn followers_at_joint(lanelets: &[super::lanelet::Lanelet], successors: &[Vec<usize>], i: usize) -> Vec<usize> {
    let mut out: Vec<usize> = Vec::new();
    let mut todo = vec![(i, 0.0)];
    while let Some((k, before)) = todo.pop() {
        for &j in &successors[k] {
            if j == i || out.contains(&j) {
                continue;
            }
            out.push(j);
            let through = before + lanelets[j].length;
            if through < JOINT_CHAIN {
                todo.push((j, through));
            }
        }
    }
    out
}

/// Whether lanelets `a` and `b`, where they cross, lie at different levels (a bridge over a
/// road), so that they never conflict ([`Junctions::levels_apart`] lists such crossing pairs).
/// Known only for
/// OpenDRIVE maps: roads that meet at grade are joined in a junction (ASAM OpenDRIVE 1.8,
/// §12 "Junctions": "Junctions ... connect roads ... where they cross"), so two lanelets
/// outside any junction (tag `opendrive:junction` = `-1`), or in two different junctions,
/// cross on different levels, as CARLA Town04's highway does over itself (roads 39 and 47).
/// A junction's connecting road and a road outside it are left at one level (they meet at the
/// junction's border).
pub fn grade_separated(a: &super::lanelet::Lanelet, b: &super::lanelet::Lanelet) -> bool {
    match (a.tags.get("opendrive:junction"), b.tags.get("opendrive:junction")) {
        (Some(ja), Some(jb)) => (ja == "-1" && jb == "-1") || (ja != "-1" && jb != "-1" && ja != jb),
        _ => false,
    }
}

/// Union-find root with path halving.
fn root(parent: &mut [usize], mut i: usize) -> usize {
    while parent[i] != i {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    i
}

/// Number of same-direction lanes beside lanelet `i` and itself.
fn lane_count(i: usize, map: &LaneletMap, neighbours: &[super::Neighbours]) -> usize {
    let mut n = 1;
    for side in [0, 1] {
        let mut at = i;
        for _ in 0..16 {
            let next = if side == 0 { neighbours[at].left } else { neighbours[at].right };
            match next.and_then(|id| map.lanelet_index(id)) {
                Some(j) => {
                    n += 1;
                    at = j;
                }
                None => break,
            }
        }
    }
    n
}

/// A lanelet's `speed_limit` tag [km/h, as Lanelet2], 0 when it has none.
fn speed_limit(map: &LaneletMap, i: usize) -> f64 {
    map.lanelets[i]
        .tags
        .get("speed_limit")
        .and_then(|v| v.trim().trim_end_matches("km/h").trim().parse().ok())
        .unwrap_or(0.0)
}

/// Who yields between links `a` and `b` of equal rank, from their approach headings, turns and
/// start points: the vehicle coming from the right goes first (the left on left-hand maps); of
/// opposite approaches the one turning left (right, on left-hand maps) yields; of links from
/// one direction, the one starting further left yields; ties to the lower lanelet id.
fn equal_rank_yield(a: &Link, a_start: DVec2, b: &Link, b_start: DVec2, left_hand: bool) -> Yield {
    let d = wrap_angle(b.heading_in - a.heading_in);
    let far_turn = if left_hand { Turn::Right } else { Turn::Left };
    let by_id = || if a.lanelet < b.lanelet { Yield::B } else { Yield::A };
    if d.abs() <= STRAIGHT {
        // Same approach: the one on the right (left, on left-hand maps) goes first.
        let dir = DVec2::from_angle(a.heading_in);
        let side = dir.perp_dot(b_start - a_start);
        if side.abs() < 0.1 {
            return by_id();
        }
        let b_right = side < 0.0;
        return if b_right != left_hand { Yield::A } else { Yield::B };
    }
    if d.abs() >= std::f64::consts::PI - STRAIGHT {
        return match (a.turn == far_turn, b.turn == far_turn) {
            (true, false) => Yield::A,
            (false, true) => Yield::B,
            _ => by_id(),
        };
    }
    // b's heading turned counter-clockwise from a's: b comes from a's right.
    let b_from_right = d > 0.0;
    if b_from_right != left_hand { Yield::A } else { Yield::B }
}

/// The right of way a lanelet's traffic signs give its arm of the next junction: `minor`
/// behind a stop or yield sign, `major` on a priority road. Signs by German number, which
/// CommonRoad's `trafficSignID` uses for every country it converts and Lanelet2 tags as
/// `subtype=de206`: 205 yield, 206 stop, 301 right of way at the next junction, 306 priority
/// road; or by name. A stop or yield sign wins over a priority sign on the same lanelet.
pub fn sign_priority<S: AsRef<str>>(signs: &[S]) -> Option<&'static str> {
    let is = |names: &[&str]| {
        signs.iter().any(|s| {
            let s = s.as_ref().trim();
            let s = match s.get(..2) {
                Some(country) if s.len() > 2 && country.eq_ignore_ascii_case("de") => &s[2..],
                _ => s,
            };
            names.iter().any(|n| s.eq_ignore_ascii_case(n))
        })
    };
    if is(&["205", "206", "yield", "stop", "give_way"]) {
        Some("minor")
    } else if is(&["301", "306", "priority", "priority_road", "right_of_way"]) {
        Some("major")
    } else {
        None
    }
}

/// Every junction of `map` with its links, conflicts, control and who yields.
pub fn find_junctions(map: &LaneletMap, rules: &JunctionRules) -> Junctions {
    let n = map.lanelets.len();
    let mut successors = vec![Vec::new(); n];
    let mut predecessors = vec![Vec::new(); n];
    for (i, l) in map.lanelets.iter().enumerate() {
        if !l.routable {
            continue;
        }
        for s in &l.successors {
            if let Some(j) = map.lanelet_index(*s).filter(|&j| map.lanelets[j].routable)
                && !successors[i].contains(&j)
            {
                successors[i].push(j);
                predecessors[j].push(i);
            }
        }
    }
    let (mut raw, levels_apart) = raw_conflicts(map, &predecessors, &successors);
    // Links the file says are no foes (SUMO `<request foes>`) pass each other.
    raw.retain(|c| !stated_no_foes(&map.lanelets[c.a].tags, &map.lanelets[c.b].tags));
    if raw.is_empty() {
        return Junctions { levels_apart, ..Junctions::default() };
    }
    let mut parent: Vec<usize> = (0..n).collect();
    for c in &raw {
        let (ra, rb) = (root(&mut parent, c.a), root(&mut parent, c.b));
        if ra != rb {
            parent[ra.max(rb)] = ra.min(rb);
        }
    }
    // Groups by their lowest lanelet index (lanelets are sorted by id, so: by lowest id).
    let mut groups: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    let mut in_conflict = vec![false; n];
    for c in &raw {
        in_conflict[c.a] = true;
        in_conflict[c.b] = true;
    }
    for i in (0..n).filter(|&i| in_conflict[i]) {
        let r = root(&mut parent, i);
        groups.entry(r).or_default().push(i);
    }
    let left_hand = rules
        .left_hand
        .unwrap_or_else(|| map.lanelets.iter().any(|l| l.tags.get("driving_side").is_some_and(|v| v == "left")));
    let neighbours = map.neighbours();
    // Lanelet2 elements by the lanelets that carry them or that they name.
    let mut signal_of: BTreeMap<LaneletId, i64> = BTreeMap::new();
    let mut role_of: BTreeMap<LaneletId, bool> = BTreeMap::new();
    let mut all_way: BTreeMap<LaneletId, i64> = BTreeMap::new();
    for re in map.regulatory.values() {
        match re.subtype.as_str() {
            "traffic_light" => {
                for l in &re.lanelets {
                    signal_of.entry(*l).or_insert(re.id);
                }
            }
            "right_of_way" => {
                for (l, role) in &re.lanelet_roles {
                    match role.as_str() {
                        "right_of_way" => {
                            role_of.insert(*l, true);
                        }
                        "yield" => {
                            role_of.entry(*l).or_insert(false);
                        }
                        _ => {}
                    }
                }
            }
            // A Lanelet2 sign element: the signs it refers to (ways tagged `subtype=de206`, ...)
            // rank the lanelets that carry it, as `right_of_way` roles do.
            "traffic_sign" => {
                let kinds: Vec<&str> = re
                    .way_roles
                    .iter()
                    .filter(|(_, role)| role == "refers")
                    .filter_map(|(w, _)| map.ways.get(w)?.tags.get("subtype").map(String::as_str))
                    .collect();
                match sign_priority(&kinds) {
                    Some("major") => re.lanelets.iter().for_each(|l| {
                        role_of.insert(*l, true);
                    }),
                    Some(_) => re.lanelets.iter().for_each(|l| {
                        role_of.entry(*l).or_insert(false);
                    }),
                    None => {}
                }
            }
            "all_way_stop" => {
                for l in re.lanelets.iter().chain(re.lanelet_roles.iter().map(|(l, _)| l)) {
                    all_way.insert(*l, re.id);
                }
            }
            _ => {}
        }
    }
    let tag_priority = |i: usize| match map.lanelets[i].tags.get("priority").map(String::as_str) {
        Some("major") => Some(true),
        Some("minor") => Some(false),
        _ => None,
    };
    let index_of: BTreeMap<usize, (usize, usize)> =
        groups.values().enumerate().flat_map(|(j, g)| g.iter().enumerate().map(move |(k, &i)| (i, (j, k)))).collect();
    let mut list = Vec::with_capacity(groups.len());
    let mut by_lanelet = BTreeMap::new();
    for (j, members) in groups.values().enumerate() {
        let from = |i: usize| predecessors[i].iter().copied().filter(|p| !members.contains(p)).min();
        // The lanelets leading into a link, nearest first, up to UPSTREAM m back along single
        // predecessors (Lanelet2 maps put the light and the stop line a few short lanelets before
        // the junction, behind crosswalks).
        let upstream = |i: usize| {
            let mut out = vec![i];
            let mut back = 0.0;
            let mut at = from(i);
            while let Some(p) = at {
                if out.contains(&p) || out.len() > 8 || back > UPSTREAM {
                    break;
                }
                out.push(p);
                back += map.lanelets[p].length;
                at = predecessors[p].iter().copied().filter(|q| !members.contains(q)).min();
            }
            out
        };
        let on_link_or_from = |i: usize, f: &dyn Fn(usize) -> Option<bool>| upstream(i).into_iter().find_map(f);
        // A Lanelet2 light's id, or 0 for a lanelet tagged `traffic_light = yes` (generated maps).
        let signal = |i: usize| {
            upstream(i).into_iter().find_map(|k| {
                let l = &map.lanelets[k];
                signal_of
                    .get(&l.id)
                    .copied()
                    .or_else(|| (l.tags.get("traffic_light").is_some_and(|v| v == "yes")).then_some(0))
            })
        };
        let mut links: Vec<Link> = members
            .iter()
            .map(|&i| {
                let l = &map.lanelets[i];
                let h_in = heading(&l.centre, false);
                let h_out = heading(&l.centre, true);
                Link {
                    lanelet: l.id,
                    from: from(i).map(|p| map.lanelets[p].id),
                    heading_in: h_in,
                    turn: turn_of(h_out - h_in),
                    major: false,
                    signal: signal(i),
                    length: l.length,
                }
            })
            .collect();
        let map_role = |i: usize| {
            on_link_or_from(i, &|k| role_of.get(&map.lanelets[k].id).copied())
                .or_else(|| on_link_or_from(i, &tag_priority))
        };
        let roles: Vec<Option<bool>> = members.iter().map(|&i| map_role(i)).collect();
        let control = if links.iter().any(|l| l.signal.is_some()) {
            JunctionControl::TrafficLight
        } else if roles.iter().any(Option::is_some) {
            JunctionControl::Priority
        } else if members.iter().any(|&i| upstream(i).iter().any(|&k| all_way.contains_key(&map.lanelets[k].id))) {
            JunctionControl::AllWayStop
        } else {
            JunctionControl::RightBeforeLeft
        };
        // A file that states each junction's type (SUMO `<junction type>`, as the tag
        // `junction_control` on its links) is taken at its word.
        let stated = members.iter().find_map(|&i| stated_control(&map.lanelets[i].tags));
        let mut control = stated.unwrap_or(control);
        match control {
            JunctionControl::Priority => {
                // An arm the map says nothing of is major where the others are only marked
                // minor (stop or yield signs on the side roads, as CommonRoad and OSM maps
                // mark them), else minor.
                let unmarked = !roles.contains(&Some(true));
                for (l, r) in links.iter_mut().zip(&roles) {
                    l.major = r.unwrap_or(unmarked);
                }
            }
            JunctionControl::RightBeforeLeft | JunctionControl::TrafficLight if stated.is_some() => {}
            JunctionControl::RightBeforeLeft | JunctionControl::TrafficLight => {
                // The documented default: approaches with more lanes, then a higher speed limit,
                // are major when some approach has less.
                let strength = |i: usize| {
                    let a = from(i).unwrap_or(i);
                    (lane_count(a, map, &neighbours), (speed_limit(map, a) * 10.0) as i64)
                };
                let strengths: Vec<(usize, i64)> = members.iter().map(|&i| strength(i)).collect();
                let (best, worst) = (strengths.iter().max().copied(), strengths.iter().min().copied());
                if best != worst {
                    for (l, s) in links.iter_mut().zip(&strengths) {
                        l.major = Some(*s) == best;
                    }
                    if control == JunctionControl::RightBeforeLeft {
                        control = JunctionControl::Priority;
                    }
                }
            }
            JunctionControl::AllWayStop | JunctionControl::FirstCome => {}
        }
        if control == JunctionControl::RightBeforeLeft && rules.fallback == Fallback::FirstCome {
            control = JunctionControl::FirstCome;
        }
        let starts: Vec<DVec2> =
            members.iter().map(|&i| map.lanelets[i].centre.first().copied().unwrap_or_default()).collect();
        let mut conflicts = Vec::new();
        let mut centre = DVec2::ZERO;
        for c in raw.iter().filter(|c| index_of.get(&c.a).is_some_and(|&(g, _)| g == j)) {
            let (ka, kb) = (index_of[&c.a].1, index_of[&c.b].1);
            let (la, lb) = (&links[ka], &links[kb]);
            let (ta, tb) = (&map.lanelets[c.a].tags, &map.lanelets[c.b].tags);
            let yields = if let Some(y) = stated_yield(ta, tb) {
                y
            } else if redrawn_turnaround(ta) != redrawn_turnaround(tb) {
                // A turnaround we drew wider than the file's meets links the file never
                // ranked it against: it yields, as a U-turn yields to every other movement.
                if redrawn_turnaround(ta) { Yield::A } else { Yield::B }
            } else if matches!(control, JunctionControl::FirstCome | JunctionControl::AllWayStop) {
                Yield::FirstCome
            } else if la.major != lb.major {
                if la.major { Yield::B } else { Yield::A }
            } else {
                equal_rank_yield(la, starts[ka], lb, starts[kb], left_hand)
            };
            centre += c.point;
            conflicts.push(Conflict {
                a: la.lanelet,
                b: lb.lanelet,
                kind: c.kind,
                s_a: c.s_a,
                s_b: c.s_b,
                point: c.point,
                yields,
            });
        }
        centre /= conflicts.len().max(1) as f64;
        for (k, l) in links.iter().enumerate() {
            by_lanelet.insert(l.lanelet, (j as u32, k as u32));
        }
        links.sort_by_key(|l| l.lanelet);
        list.push(Junction { id: j as u32 + 1, links, conflicts, control, centre });
    }
    Junctions { list, by_lanelet, levels_apart }
}

/// The control a link's tag `junction_control` states (SUMO nets, [`super::sumo`]).
fn stated_control(tags: &super::lanelet::Tags) -> Option<JunctionControl> {
    match tags.get("junction_control")?.as_str() {
        "priority" => Some(JunctionControl::Priority),
        "traffic_light" => Some(JunctionControl::TrafficLight),
        "all_way_stop" => Some(JunctionControl::AllWayStop),
        "right_before_left" => Some(JunctionControl::RightBeforeLeft),
        "first_come" => Some(JunctionControl::FirstCome),
        _ => None,
    }
}

/// Who yields between two links of one SUMO junction, from its `<request>` rows (tags
/// `sumo:junction`, `sumo:link_index`, `sumo:response`): link i yields to link j where bit j of
/// i's `response` is set, bits read from the right (SUMO_Road_Networks.md, "Requests"). `None`
/// where the links are not of one such junction or neither yields to the other.
fn stated_yield(a: &super::lanelet::Tags, b: &super::lanelet::Tags) -> Option<Yield> {
    let junction = a.get("sumo:junction")?;
    if b.get("sumo:junction") != Some(junction) {
        return None;
    }
    let index = |t: &super::lanelet::Tags| t.get("sumo:link_index")?.parse::<usize>().ok();
    let responds = |t: &super::lanelet::Tags, to: usize| {
        t.get("sumo:response").is_some_and(|r| {
            let r = r.as_bytes();
            to < r.len() && r[r.len() - 1 - to] == b'1'
        })
    };
    let (ia, ib) = (index(a)?, index(b)?);
    match (responds(a, ib), responds(b, ia)) {
        (true, false) => Some(Yield::A),
        (false, true) => Some(Yield::B),
        _ => None,
    }
}

/// Whether a link is a SUMO turnaround drawn wider than the file's shape
/// ([`super::sumo`], tag `sumo:shape=turnaround`).
pub(crate) fn redrawn_turnaround(tags: &super::lanelet::Tags) -> bool {
    tags.get("sumo:shape").is_some_and(|v| v == "turnaround")
}

/// Whether two links of one SUMO junction are no foes by its `<request>` rows (tag
/// `sumo:foes` of each: bit j set where link j is a foe, read from the right).
fn stated_no_foes(a: &super::lanelet::Tags, b: &super::lanelet::Tags) -> bool {
    // The file's foes describe its own shape of a turnaround, not the wider one we drew.
    if redrawn_turnaround(a) || redrawn_turnaround(b) {
        return false;
    }
    let Some(junction) = a.get("sumo:junction") else { return false };
    if b.get("sumo:junction") != Some(junction) {
        return false;
    }
    let index = |t: &super::lanelet::Tags| t.get("sumo:link_index")?.parse::<usize>().ok();
    let foe = |t: &super::lanelet::Tags, to: usize| {
        t.get("sumo:foes").map(|r| {
            let r = r.as_bytes();
            to < r.len() && r[r.len() - 1 - to] == b'1'
        })
    };
    match (index(a), index(b)) {
        (Some(ia), Some(ib)) => foe(a, ib) == Some(false) && foe(b, ia) == Some(false),
        _ => false,
    }
}

/// The program of `junction` from the map's own signal programs: every link names the same
/// program (tag `signal_program`) and its character (tag `signal_index`); each phase's state is
/// then re-ordered into the junction's link order. `None` where a link has no such tags (the
/// default program applies). SUMO's `u` (red-yellow) shows red, `s` and `o` (green with a stop,
/// blinking yield) the yielding green `g`, `O` (off) `G`.
pub fn map_program(map: &LaneletMap, junction: &Junction) -> Option<(Vec<SignalPhase>, f64)> {
    let mut program: Option<&str> = None;
    let mut indices = Vec::with_capacity(junction.links.len());
    for link in &junction.links {
        let tags = &map.lanelet(link.lanelet)?.tags;
        let id = tags.get("signal_program")?;
        if program.is_some_and(|p| p != id) {
            return None;
        }
        program = Some(id);
        indices.push(tags.get("signal_index")?.parse::<usize>().ok()?);
    }
    let p = map.signal_programs.get(program?)?;
    let phases = p
        .phases
        .iter()
        .map(|ph| {
            let chars = ph.state.as_bytes();
            let state = indices
                .iter()
                .map(|&k| match chars.get(k).copied().unwrap_or(b'r') {
                    b'G' | b'O' => 'G',
                    b'g' | b's' | b'o' => 'g',
                    b'y' | b'Y' => 'y',
                    _ => 'r',
                })
                .collect();
            SignalPhase { state, duration: ph.duration }
        })
        .collect();
    Some((phases, p.offset))
}

/// Green time of each phase of [`default_program`] \[s\].
pub const DEFAULT_GREEN: f64 = 27.0;
/// Yellow time of [`default_program`] \[s\] (SUMO's default for 50 km/h roads is 3 s).
pub const DEFAULT_YELLOW: f64 = 3.0;
/// All-red time between phases of [`default_program`] \[s\].
pub const DEFAULT_ALL_RED: f64 = 2.0;

/// A fixed-time program for a junction that has lights but no program (a Lanelet2 map, a
/// generated `--traffic-lights` map): links are grouped into axes by their approach heading
/// (opposite approaches share an axis); each axis in turn gets [`DEFAULT_GREEN`] s (`G` for
/// straight and the near turn, `g` for the far turn, which yields to the opposite `G`), then
/// [`DEFAULT_YELLOW`] s yellow and [`DEFAULT_ALL_RED`] s all red. Like SUMO's
/// `netconvert --tls.guess` static programs.
pub fn default_program(junction: &Junction, left_hand: bool) -> Vec<SignalPhase> {
    let far_turn = if left_hand { Turn::Right } else { Turn::Left };
    let mut axes: Vec<f64> = Vec::new();
    let axis_of: Vec<usize> = junction
        .links
        .iter()
        .map(|l| {
            let a = l.heading_in.rem_euclid(std::f64::consts::PI);
            let near = |x: f64| {
                let d = (x - a).abs();
                d.min(std::f64::consts::PI - d) <= STRAIGHT
            };
            match axes.iter().position(|&x| near(x)) {
                Some(k) => k,
                None => {
                    axes.push(a);
                    axes.len() - 1
                }
            }
        })
        .collect();
    let mut phases = Vec::new();
    for k in 0..axes.len() {
        let green: String = junction
            .links
            .iter()
            .zip(&axis_of)
            .map(|(l, &a)| {
                if a != k {
                    'r'
                } else if l.turn == far_turn || l.turn == Turn::UTurn {
                    'g'
                } else {
                    'G'
                }
            })
            .collect();
        let yellow: String = green.chars().map(|c| if c == 'r' { 'r' } else { 'y' }).collect();
        let red: String = green.chars().map(|_| 'r').collect();
        phases.push(SignalPhase { state: green, duration: DEFAULT_GREEN });
        phases.push(SignalPhase { state: yellow, duration: DEFAULT_YELLOW });
        phases.push(SignalPhase { state: red, duration: DEFAULT_ALL_RED });
    }
    phases
}

impl LaneletMap {
    /// The map's junctions under the default rules ([`find_junctions`]), found once and shared
    /// by everything that asks (the right-of-way plugin, random trips, the light log, `map info`).
    pub fn junctions(&self) -> std::sync::Arc<Junctions> {
        let found = || find_junctions(self, &JunctionRules::default());
        let cached = self.junctions.get_or_init(|| std::sync::Arc::new(found()));
        // The cache holds nothing else; should it ever, the junctions are found afresh.
        std::sync::Arc::clone(cached).downcast::<Junctions>().unwrap_or_else(|_| std::sync::Arc::new(found()))
    }

    /// Whether any lanelet is tagged `driving_side = left`.
    pub fn left_hand_traffic(&self) -> bool {
        self.lanelets.iter().any(|l| l.tags.get("driving_side").is_some_and(|v| v == "left"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segments_cross_at_their_fractions() {
        let c =
            segment_crossing(DVec2::new(0.0, 0.0), DVec2::new(4.0, 0.0), DVec2::new(1.0, -1.0), DVec2::new(1.0, 3.0));
        assert_eq!(c, Some((0.25, 0.25)));
        assert_eq!(segment_crossing(DVec2::ZERO, DVec2::X, DVec2::Y, DVec2::new(1.0, 1.0)), None);
    }

    #[test]
    fn turns_are_classified_by_heading_change() {
        assert_eq!(turn_of(0.1), Turn::Straight);
        assert_eq!(turn_of(std::f64::consts::FRAC_PI_2), Turn::Left);
        assert_eq!(turn_of(-std::f64::consts::FRAC_PI_2), Turn::Right);
        assert_eq!(turn_of(3.0), Turn::UTurn);
        assert_eq!(turn_of(std::f64::consts::TAU - 0.2), Turn::Straight);
    }

    fn link(id: i64, heading: f64, turn: Turn) -> Link {
        Link { lanelet: LaneletId(id), from: None, heading_in: heading, turn, major: false, signal: None, length: 10.0 }
    }

    #[test]
    fn the_vehicle_from_the_right_goes_first() {
        use std::f64::consts::{FRAC_PI_2, PI};
        // a drives north, b drives west: b comes from a's right (the east), so a yields.
        let a = link(1, FRAC_PI_2, Turn::Straight);
        let b = link(2, PI, Turn::Straight);
        assert_eq!(equal_rank_yield(&a, DVec2::new(0.0, -10.0), &b, DVec2::new(10.0, 0.0), false), Yield::A);
        assert_eq!(equal_rank_yield(&b, DVec2::new(10.0, 0.0), &a, DVec2::new(0.0, -10.0), false), Yield::B);
        // On a left-hand traffic map, the other way round.
        assert_eq!(equal_rank_yield(&a, DVec2::new(0.0, -10.0), &b, DVec2::new(10.0, 0.0), true), Yield::B);
        // Opposite approaches: the left turn yields to the straight one.
        let c = link(3, -FRAC_PI_2, Turn::Left);
        assert_eq!(equal_rank_yield(&a, DVec2::ZERO, &c, DVec2::ZERO, false), Yield::B);
        assert_eq!(equal_rank_yield(&c, DVec2::ZERO, &a, DVec2::ZERO, false), Yield::A);
    }
}
