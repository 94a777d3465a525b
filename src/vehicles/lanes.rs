//! Where each vehicle is on the road: the [`LanePosition`] component (lanelet, arc length along
//! its centre line, signed offset), updated once per dynamics step, and the [`LaneMap`] resource
//! it is looked up in (the map with per-lanelet centre paths, neighbours, successors and
//! predecessors, and a coarse grid of lanelets).
//!
//! The lookup is O(1) per vehicle: the lanelet of the last step, then its successors,
//! neighbours and predecessors, each projected in a window around the expected arc length; only a
//! vehicle found in none of them (a start, a jump) falls back to the grid cell under it.

use std::collections::BTreeMap;
use std::sync::Arc;

use bevy_ecs::prelude::{Component, Local, Query, Res, ResMut, Resource, World};
use bevy_ecs::schedule::{IntoScheduleConfigs, SystemSet};
use glam::DVec2;

use crate::map::path::{LANES, groups_of_four, per_lane, walk_four};
use crate::map::{LaneletId, LaneletMap, Neighbours, Path};
use crate::sim::grid::{Pass, vectorised};
use crate::sim::{Control, Parallelism, Plugin, SimBuilder, SimClock, SimSystems};
use crate::world::SimTime;
use crate::world::VehicleState;

/// Size of a cell of the lanelet grid [m].
const CELL: f64 = 25.0;
/// How many vehicles ahead [`update_lane_positions`] asks for the centre line it will read.
pub(crate) const PREFETCH_AHEAD: usize = 8;
/// Half width of the first window a vehicle is looked for in around where it should be [m].
const NARROW_WINDOW: f64 = 2.0;
/// How far beyond a lanelet's end a projection may lie and still count as on it [m].
const END_SLACK: f64 = 0.05;

/// The map as the lane systems use it, built once per run.
#[derive(Resource, Debug, Clone)]
pub struct LaneMap {
    /// The map.
    pub map: Arc<LaneletMap>,
    /// Neighbours of every lanelet (in [`LaneletMap::lanelets`] order).
    pub neighbours: Vec<Neighbours>,
    /// Centre line of every lanelet as a path resampled every metre or finer.
    pub centres: Vec<Path>,
    /// Half the mean width of every lanelet \[m\].
    pub half_widths: Vec<f64>,
    /// Successors of every lanelet (indices, routable only).
    pub successors: Vec<Vec<u32>>,
    /// Predecessors of every lanelet (indices, routable only).
    pub predecessors: Vec<Vec<u32>>,
    /// Id of every lanelet (a dense copy: the lanelets themselves are large and far apart).
    ids: Vec<LaneletId>,
    /// Index of the left and right neighbour of every lanelet (from [`LaneMap::neighbours`]),
    /// so the per-vehicle lane systems look them up in an array, not in the map's id tree.
    beside: Vec<[Option<u32>; 2]>,
    /// 1 / the length of every lanelet's centre line [1/m] (0 for one of no length): where in
    /// its list of vehicles an arc length falls, without a division on the way to that load
    /// ([`super::lane_state::first_at_or_after`]).
    per_length: Vec<f64>,
    /// Cell -> (lanelet, arc length [m] where its centre line enters the cell).
    grid: BTreeMap<(i64, i64), Vec<(u32, f64)>>,
    /// Siblings of every lanelet: `(k, overlap)` for each lanelet `k` that leaves a common
    /// predecessor with it, `overlap` \[m\] the arc length along `k` over which a car on `k` is
    /// still in this lanelet's way ([`SIBLING_CLEARANCE`]). Only those with an overlap.
    siblings: Vec<Vec<(u32, f64)>>,
    /// Offset \[m\] within which [`LaneMap::locate`] keeps a vehicle on its lanelet without
    /// looking at the others: half the half width, less where siblings overlap
    /// ([`SIBLING_STAY`]).
    stay: Vec<f64>,
    /// Per lanelet, the stretches of other lanelets that lie on its lane ([`LaneMap::overlaps`]).
    overlaps: Vec<Vec<Overlap>>,
    /// Per lanelet, the other lanes a car standing at its start stands on
    /// ([`LaneMap::crossing_start`]), found the first time a vehicle enters there (a grid
    /// search per lanelet of a town at set-up was seconds, and few lanelets are entries).
    crossing_start: Vec<std::sync::OnceLock<LanesAt>>,
}

/// Lanelets with an arc length on each \[m\] ([`LaneMap::crossing_start`]).
type LanesAt = Box<[(u32, f64)]>;

/// Half the length \[m\] of the body [`LaneMap::crossing_start`] places at a lane's start: a
/// car's (SUMO's default vehicle is 5 m long).
pub const START_BODY_HALF: f64 = 2.5;

/// Distance \[m\] between two centre lines from which cars on them pass each other (a car's
/// width, 1.8 m, and a margin): where lanes that leave one lanelet are closer, a car on one is in
/// the way of a car on the other.
pub const SIBLING_CLEARANCE: f64 = 2.2;
/// Offset \[m\] from a lanelet with overlapping siblings past which [`LaneMap::locate`] asks
/// whether a sibling fits better: where lanes diverge, the vehicle was placed on the first, and
/// kept there until half a half width off (0.8 m), while it turned onto the other (issue 54: a
/// right turner placed on the straight lane was not seen behind a vehicle entering its exit).
const SIBLING_STAY: f64 = 0.25;

/// Arc length \[m\] along `k` over which its centre line stays within [`SIBLING_CLEARANCE`] of
/// `j`'s (both leaving one point), sampled every half metre.
fn overlap_along(k: &Path, j: &Path) -> f64 {
    let mut s = 0.0;
    while s <= k.length {
        let p = k.sample_point(s);
        if j.near_within(p, s, 2.0 * SIBLING_CLEARANCE + 1.0, SIBLING_CLEARANCE).is_none() {
            return s;
        }
        s += 0.5;
    }
    k.length
}

/// A stretch of another lanelet that lies on a lanelet's lane, within its half width: where
/// lanes part (lanelets with a common predecessor, a junction's turns from one lane) their
/// first metres, where they join (a common successor) their last. A vehicle indexed there at
/// arc length `s` in `from..=to` stands on the lane at arc length `s + shift`: the leader search
/// along a route ([`crate::vehicles::longitudinal::leader_along_route`]) sees it as the radar
/// saw it, on the route's path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Overlap {
    /// The other lanelet (index).
    pub lanelet: u32,
    /// Its arc lengths that lie on the lane \[m\], from ...
    pub from: f64,
    /// ... to.
    pub to: f64,
    /// Added to its arc length gives the lane's \[m\] (0 where they part).
    pub shift: f64,
}

/// The stretch of lanelet `o` (its centre line `other`) on lanelet `i`'s lane (`lane`, `half`
/// its half width): walked from `o`'s start when they part (`parting`), from its end when they
/// join, while its centre line stays within `half` of the lane's centre line.
fn overlap_of(lane: &Path, half: f64, o: u32, other: &Path, parting: bool) -> Option<Overlap> {
    let n = other.points.len();
    if n < 2 || lane.points.len() < 2 {
        return None;
    }
    let step = other.spacing();
    let shift = if parting { 0.0 } else { lane.length - other.length };
    let mut reach = None;
    for k in 0..n {
        let at = if parting { k } else { n - 1 - k };
        let s = at as f64 * step;
        let p = lane.project_near(other.points[at], s + shift, 4.0);
        if p.lateral.abs() > half || p.s <= 0.0 && !parting || p.s >= lane.length && parting {
            break;
        }
        reach = Some(s);
    }
    let reach = reach?;
    let (from, to) = if parting { (0.0, reach) } else { (reach, other.length) };
    Some(Overlap { lanelet: o, from, to, shift })
}

fn cell_of(p: DVec2) -> (i64, i64) {
    ((p.x / CELL).floor() as i64, (p.y / CELL).floor() as i64)
}

impl LaneMap {
    /// Index `map` (O(lanelets · points)).
    pub fn new(map: Arc<LaneletMap>) -> LaneMap {
        let neighbours = map.neighbours();
        let n = map.lanelets.len();
        let mut centres = Vec::with_capacity(n);
        let mut half_widths = Vec::with_capacity(n);
        let mut successors = vec![Vec::new(); n];
        let mut predecessors = vec![Vec::new(); n];
        let mut grid: BTreeMap<(i64, i64), Vec<(u32, f64)>> = BTreeMap::new();
        for (i, l) in map.lanelets.iter().enumerate() {
            let segments = (l.length.ceil() as usize).max(1);
            let centre = crate::map::polyline::resample_count(&l.centre, segments + 1);
            centres.push(Path::from_points(vec![l.id], centre, false));
            let widths: f64 = l.left.iter().zip(&l.right).map(|(a, b)| a.distance(*b)).sum();
            let half = 0.5 * widths / l.left.len().max(1) as f64;
            half_widths.push(half);
            if l.routable {
                for s in &l.successors {
                    if let Some(j) = map.lanelet_index(*s).filter(|&j| map.lanelets[j].routable) {
                        successors[i].push(j as u32);
                        predecessors[j].push(i as u32);
                    }
                }
                // The centre path has a point every metre or less: every cell the lane crosses,
                // with the arc length where it enters (again after leaving).
                let path = &centres[i];
                let step = path.spacing().max(1e-9);
                let mut last: BTreeMap<(i64, i64), f64> = BTreeMap::new();
                for (k, p) in path.points.iter().enumerate() {
                    let s = k as f64 * step;
                    for dx in [-1.0, 1.0] {
                        for dy in [-1.0, 1.0] {
                            let c = cell_of(*p + DVec2::new(dx, dy) * half.min(CELL));
                            let seen = last.get(&c).copied();
                            if seen.is_none_or(|t| s - t > 2.0 * CELL) {
                                grid.entry(c).or_default().push((i as u32, s));
                            }
                            last.insert(c, s);
                        }
                    }
                }
            }
        }
        let ids = map.lanelets.iter().map(|l| l.id).collect();
        let index_of = |id: Option<LaneletId>| id.and_then(|id| map.lanelet_index(id)).map(|j| j as u32);
        let beside = neighbours.iter().map(|n| [index_of(n.left), index_of(n.right)]).collect();
        let per_length = centres.iter().map(|c| if c.length > 0.0 { 1.0 / c.length } else { 0.0 }).collect();
        let mut siblings: Vec<Vec<(u32, f64)>> = vec![Vec::new(); n];
        for next in &successors {
            for &j in next {
                for &k in next {
                    if j != k && !siblings[j as usize].iter().any(|&(o, _)| o == k) {
                        let overlap = overlap_along(&centres[k as usize], &centres[j as usize]);
                        if overlap > 0.0 {
                            siblings[j as usize].push((k, overlap));
                        }
                    }
                }
            }
        }
        let stay = (0..n)
            .map(|i| {
                let half = 0.5 * half_widths[i];
                if siblings[i].is_empty() { half } else { half.min(SIBLING_STAY) }
            })
            .collect();
        let mut overlaps = vec![Vec::new(); n];
        for (i, list) in overlaps.iter_mut().enumerate() {
            let (lane, half) = (&centres[i], half_widths[i]);
            let mut add = |o: u32, parting: bool| {
                if o as usize != i && !list.iter().any(|x: &Overlap| x.lanelet == o && (x.shift == 0.0) == parting) {
                    list.extend(overlap_of(lane, half, o, &centres[o as usize], parting));
                }
            };
            for &p in &predecessors[i] {
                for &o in &successors[p as usize] {
                    add(o, true);
                }
            }
            for &q in &successors[i] {
                for &o in &predecessors[q as usize] {
                    add(o, false);
                }
            }
        }
        LaneMap {
            map,
            neighbours,
            centres,
            half_widths,
            successors,
            predecessors,
            ids,
            beside,
            per_length,
            grid,
            siblings,
            stay,
            overlaps,
            crossing_start: (0..n).map(|_| std::sync::OnceLock::new()).collect(),
        }
    }

    /// The lanes that pass over lanelet `i`'s start, where a car entering there stands (its
    /// centre at the start, its body from [`START_BODY_HALF`] behind to as far ahead): `(k, s)`
    /// for each such lanelet `k` other than `i`, those leading into it and those whose stretch
    /// on it the lane index already counts ([`LaneMap::overlaps`]: lanes parting with it), with
    /// the arc length on `k` \[m\] nearest to the body's rear, centre or front. A U-turn drawn
    /// wide round a junction sweeps over the start of an exit on its far side: traffic inserted
    /// there must wait for the U-turner to pass (issue 54's 20x20 grid: 14 of its 23
    /// collisions).
    pub fn crossing_start(&self, i: u32) -> &[(u32, f64)] {
        self.crossing_start.get(i as usize).map_or(&[], |c| c.get_or_init(|| self.find_crossing_start(i).into()))
    }

    fn find_crossing_start(&self, i: u32) -> Vec<(u32, f64)> {
        let mut out: Vec<(u32, f64)> = Vec::new();
        if !self.map.lanelets[i as usize].routable {
            return out;
        }
        let centre = &self.centres[i as usize];
        let (start, heading) = centre.sample(0.0);
        let before = &self.predecessors[i as usize];
        let mut near = Vec::new();
        for ds in [-START_BODY_HALF, 0.0, START_BODY_HALF] {
            // The rear stands out behind the start (into the junction before it).
            let p = if ds < 0.0 {
                start + DVec2::from_angle(heading) * ds
            } else {
                centre.sample_point(ds.min(centre.length))
            };
            self.passing(p, &mut near);
            for &(k, s_k) in &near {
                if k != i && !before.contains(&k) && !self.overlaps(i).iter().any(|o| o.lanelet == k) {
                    out.push((k, s_k));
                }
            }
        }
        out
    }

    /// The lanelets whose lane `p` lies on (within their half width), each with the arc length
    /// nearest to `p` \[m\], into `out` (cleared first), from the grid.
    fn passing(&self, p: DVec2, out: &mut Vec<(u32, f64)>) {
        out.clear();
        for &(j, s) in self.grid.get(&cell_of(p)).map(Vec::as_slice).unwrap_or(&[]) {
            if out.iter().any(|&(k, _)| k == j) {
                continue;
            }
            // The cell spans at most √2 · CELL of centre line from where it entered.
            if let Some((s, _)) = self.on(j, p, s + CELL, 1.5 * CELL) {
                out.push((j, s));
            }
        }
    }

    /// The stretches of other lanelets that lie on lanelet `i`'s lane, where lanes part or
    /// join ([`Overlap`]).
    pub fn overlaps(&self, i: u32) -> &[Overlap] {
        self.overlaps.get(i as usize).map_or(&[], Vec::as_slice)
    }

    /// Index of the lanelet after `i` on the way to lanelet `next` (an id): a successor of `i`,
    /// else looked up in the map.
    pub fn next_on_route(&self, i: u32, next: LaneletId) -> Option<u32> {
        self.successors
            .get(i as usize)
            .and_then(|s| s.iter().copied().find(|&j| self.ids[j as usize] == next))
            .or_else(|| self.map.lanelet_index(next).map(|j| j as u32))
    }

    /// Hint to the processor that lanelet `i`'s centre line around arc length `s` \[m\] will be
    /// read soon (no effect off-road or off x86-64): the six points a walk from there reads
    /// (`crate::map::path::walk_four`: two segments either side of the one at `s`), which
    /// span two or three cache lines.
    pub fn prefetch(&self, i: Option<u32>, s: f64) {
        let Some(path) = i.and_then(|i| self.centres.get(i as usize)) else { return };
        // A multiplication, not a division: this runs beside the lane positions' own divisions.
        let k = path.segment_near(s).saturating_sub(2);
        if let Some(p) = path.points.get(k..(k + 6).min(path.points.len())) {
            crate::world::prefetch_bytes(p.as_ptr().cast(), std::mem::size_of_val(p));
        }
    }

    /// Length of lanelet `i`'s centre line \[m\].
    pub fn length(&self, i: u32) -> f64 {
        self.centres[i as usize].length
    }

    /// 1 / the length of lanelet `i`'s centre line [1/m] (0 when it has no length).
    pub fn per_length(&self, i: u32) -> f64 {
        self.per_length[i as usize]
    }

    /// The successor of lanelet `i` that `route` (lanelet ids in driving order) drives next:
    /// the one after `i` in it, else any successor it holds (a vehicle beside its route's lane),
    /// else the first. A search for the vehicle ahead that took the first successor looked
    /// straight on past a left turner standing in the junction (issue 54: the 5x5 grid's
    /// rear-end collisions on SUMO's internal left-turn lanes).
    pub fn next_on(&self, i: u32, route: &[LaneletId]) -> Option<u32> {
        let successors = self.successors.get(i as usize)?;
        if successors.len() <= 1 || route.is_empty() {
            return successors.first().copied();
        }
        let id = self.id(i);
        let after = route.iter().position(|&r| r == id).and_then(|k| route.get(k + 1));
        let on_route = |want: LaneletId| successors.iter().copied().find(|&j| self.id(j) == want);
        after
            .and_then(|&want| on_route(want))
            .or_else(|| successors.iter().copied().find(|&j| route.contains(&self.id(j))))
            .or_else(|| successors.first().copied())
    }

    /// Lanelets that leave a common predecessor with lanelet `i` and overlap it: `(k, overlap)`,
    /// a car on `k` within `overlap` \[m\] of its start is in the way of one on `i`.
    pub fn siblings(&self, i: u32) -> &[(u32, f64)] {
        &self.siblings[i as usize]
    }

    /// Id of lanelet `i`.
    pub fn id(&self, i: u32) -> LaneletId {
        self.ids[i as usize]
    }

    /// Index of the lanelet beside lanelet `i` on its left (`left`) or right, if any.
    pub fn beside(&self, i: u32, left: bool) -> Option<u32> {
        self.beside[i as usize][usize::from(!left)]
    }

    /// `p` on lanelet `i` near arc length `hint` [m] (whole lanelet when `hint` is NaN): its arc
    /// length and signed offset, if it lies on the lanelet.
    fn on(&self, i: u32, p: DVec2, hint: f64, window: f64) -> Option<(f64, f64)> {
        let path = &self.centres[i as usize];
        let (s, point, lateral, direction) = path.near_within(p, hint, window, self.half_widths[i as usize] + 1e-9)?;
        // At either end the nearest point may be the end itself with `p` beyond it.
        let along = (p - point).dot(direction);
        if (s <= 0.0 && along < -END_SLACK) || (s >= path.length && along > END_SLACK) {
            return None;
        }
        // Perpendicular offset (the full distance when `p` lies just past an end).
        Some((s, lateral))
    }

    /// Where `p` is: `(lanelet index, s [m], offset [m])`, looking first around `last` (the
    /// lanelet and arc length of the previous step, advanced by `ds` \[m\]), else in the grid.
    pub fn locate(&self, p: DVec2, last: Option<(u32, f64)>, ds: f64) -> Option<(u32, f64, f64)> {
        let better = |best: Option<(u32, f64, f64)>, c: Option<(u32, f64, f64)>| match (best, c) {
            (Some(b), Some(c)) if c.2.abs() < b.2.abs() => Some(c),
            (None, c) => c,
            (b, _) => b,
        };
        if let Some((i, s)) = last {
            let hint = s + ds;
            // The step is known to a few centimetres (`ds`): look in a narrow window first, and
            // again in a wide one when the vehicle is not where expected (a jump, a bridge).
            let narrow = self
                .on(i, p, hint, NARROW_WINDOW)
                .filter(|&(s, _)| (s - hint).abs() < NARROW_WINDOW - 1.0 || s <= 0.0 || s >= self.length(i));
            let mut best = narrow.or_else(|| self.on(i, p, hint, 6.0)).map(|(s, o)| (i, s, o));
            if best.is_some_and(|b| b.2.abs() < self.stay[i as usize]) {
                return best;
            }
            // Lanes leaving where this one leaves: the vehicle may have turned onto one.
            for &(k, _) in &self.siblings[i as usize] {
                best = better(best, self.on(k, p, hint, 6.0).map(|(s, o)| (k, s, o)));
            }
            let len = self.length(i);
            for &j in &self.successors[i as usize] {
                best = better(best, self.on(j, p, hint - len, 6.0).map(|(s, o)| (j, s, o)));
            }
            for j in self.beside[i as usize].into_iter().flatten() {
                let h = hint * self.length(j) / len.max(1e-9);
                best = better(best, self.on(j, p, h, 6.0).map(|(s, o)| (j, s, o)));
            }
            for &j in &self.predecessors[i as usize] {
                best = better(best, self.on(j, p, hint + self.length(j), 6.0).map(|(s, o)| (j, s, o)));
            }
            if best.is_some() {
                return best;
            }
        }
        let mut best = None;
        for &(j, s) in self.grid.get(&cell_of(p)).map(Vec::as_slice).unwrap_or(&[]) {
            // The cell spans at most √2 · CELL of centre line from where it entered.
            best = better(best, self.on(j, p, s + CELL, 1.5 * CELL).map(|(s, o)| (j, s, o)));
        }
        best
    }
}

/// Where a vehicle is on the road, brought up to date before anything reads it: at the start of
/// every control tick ([`LaneSystems`]), before each trajectory log row and on demand
/// ([`refresh_lane_positions`]); never more than once per instant.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
pub struct LanePosition {
    /// The lanelet under the reference point (`None` off-road).
    pub lanelet: Option<LaneletId>,
    /// Its index in [`LaneletMap::lanelets`] (`u32::MAX` off-road).
    pub index: u32,
    /// Arc length along the lanelet's centre line \[m\].
    pub s: f64,
    /// Signed offset from the centre line \[m\], positive to the left.
    pub offset: f64,
    /// Signed forward speed [m/s] ([`VehicleState::speed`]) when the position was found: the
    /// control tick's readers take it from here instead of each computing it (trigonometry).
    pub speed: f64,
}

impl Default for LanePosition {
    fn default() -> Self {
        LanePosition { lanelet: None, index: u32::MAX, s: 0.0, offset: 0.0, speed: 0.0 }
    }
}

impl LanePosition {
    /// Where `state` is on `lanes`, found afresh (at spawn; [`update_lane_positions`] keeps it).
    pub fn of(lanes: &LaneMap, state: &VehicleState) -> LanePosition {
        LanePosition::found(lanes, lanes.locate(state.position, None, 0.0), state.speed())
    }

    /// The position [`LaneMap::locate`] `found` (off-road when `None`), moving at `speed` [m/s].
    fn found(lanes: &LaneMap, found: Option<(u32, f64, f64)>, speed: f64) -> LanePosition {
        match found {
            Some((i, s, offset)) => LanePosition { lanelet: Some(lanes.id(i)), index: i, s, offset, speed },
            None => LanePosition { speed, ..LanePosition::default() },
        }
    }

    /// Index of the lanelet, if on one.
    pub fn on(&self) -> Option<u32> {
        (self.index != u32::MAX).then_some(self.index)
    }
}

/// The set of the lane-position update in the [`Control`] schedule, in [`SimSystems::Sense`]
/// (before every controller).
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct LaneSystems;

/// When the lane positions were last brought up to date (`None`: never). The dynamics moves the
/// vehicles at the end of an instant (after sensing and control of that instant), so positions
/// found at instant `t` hold for everything else that runs at `t`.
#[derive(Resource, Debug, Clone, Copy, Default, PartialEq)]
pub struct LanePositionsAt(pub Option<SimTime>);

impl LanePositionsAt {
    /// Whether the lane positions were found at `now` (so [`LanePosition::speed`] is current).
    pub fn fresh(at: Option<&LanePositionsAt>, now: SimTime) -> bool {
        at.is_some_and(|a| a.0 == Some(now))
    }
}

/// The signed forward speed of `state` [m/s]: [`LanePosition::speed`] when `fresh` (found this
/// instant, see [`LanePositionsAt::fresh`]), else computed.
pub fn forward_speed(state: &VehicleState, pos: Option<&LanePosition>, fresh: bool) -> f64 {
    match pos {
        Some(p) if fresh => p.speed,
        _ => state.speed(),
    }
}

/// Bring every [`LanePosition`] up to date now (for readers outside the schedules: Python's
/// state arrays, `change_lane`, the final trajectory row). Does nothing without a [`LaneMap`].
pub fn refresh_lane_positions(world: &mut World) {
    if !world.contains_resource::<LaneMap>() {
        return;
    }
    // The system is registered once and kept (a fresh one per call costs more than the update
    // on a small world: Python steps call this every step).
    let id = match world.get_resource::<RefreshSystem>() {
        Some(r) => r.0,
        None => {
            let id = world.register_system(update_lane_positions);
            world.insert_resource(RefreshSystem(id));
            id
        }
    };
    // Every parameter is optional or a query: running it cannot fail.
    let _ = world.run_system(id);
}

/// The registered [`update_lane_positions`] of [`refresh_lane_positions`].
#[derive(Resource)]
struct RefreshSystem(bevy_ecs::system::SystemId);

/// Update every [`LanePosition`] from the vehicle's state (split over threads; each vehicle's
/// result depends only on itself, so any thread count gives the same bits).
///
/// Runs where positions are read (the control tick, the trajectory log, [`refresh_lane_positions`])
/// rather than after every dynamics step: 20 Hz instead of 50 Hz at the default rates, the
/// same positions at every instant they are read. A second call at the same instant does nothing.
pub fn update_lane_positions(
    clock: Option<Res<SimClock>>,
    lanes: Option<Res<LaneMap>>,
    mut at: Option<ResMut<LanePositionsAt>>,
    parallelism: Option<Res<Parallelism>>,
    mut vehicles: Query<(&VehicleState, &mut LanePosition)>,
    mut scratch: Local<Vec<()>>,
) {
    let Some(lanes) = lanes else { return };
    let lanes = &*lanes;
    let now = clock.map_or(SimTime::ZERO, |c| c.now);
    let last = at.as_deref().and_then(|a| a.0);
    if last == Some(now) {
        return;
    }
    if let Some(a) = at.as_deref_mut() {
        a.0 = Some(now);
    }
    // Time since the last update: each vehicle moved about its speed times this along its lane.
    let dt = last.map_or(0.0, |l| now.0.saturating_sub(l.0) as f64 * 1e-6);
    let parallelism = parallelism.as_deref().copied().unwrap_or_else(Parallelism::single);
    // Straight in the ECS tables' slices (contiguous access), table by table; four at a time
    // where they can, in vector code where the processor has it.
    let update = |states: &[VehicleState], positions: &mut [LanePosition]| {
        vectorised(LanePositionsPass { lanes, states, positions, dt });
    };
    if let Ok(tables) = vehicles.contiguous_iter_mut() {
        for (states, mut positions) in tables {
            parallelism
                .for_each_chunk_at(&mut positions, &mut scratch, |start, chunk, _| update(&states[start..], chunk));
        }
    } else {
        // Only if a component were stored sparsely (none is): one at a time.
        for (state, mut pos) in &mut vehicles {
            update(std::slice::from_ref(state), std::slice::from_mut(&mut *pos));
        }
    }
}

/// The lane positions of a slice of vehicles, `dt` [s] after the last update, as a [`Pass`]:
/// four at a time where [`update_four`] can, else one at a time ([`update_one`]).
struct LanePositionsPass<'a, 'b> {
    lanes: &'a LaneMap,
    states: &'b [VehicleState],
    positions: &'b mut [LanePosition],
    dt: f64,
}

impl Pass for LanePositionsPass<'_, '_> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        let LanePositionsPass { lanes, states, positions, dt } = self;
        let n = positions.len().min(states.len());
        for r in groups_of_four(n) {
            // The centre-line points a vehicle a few places on will read are far apart in memory
            // on a big map: ask for them now so their loads overlap these vehicles' work.
            for ahead in positions.iter().skip(r.start + PREFETCH_AHEAD).take(r.len()) {
                // Where its walk will start: about its speed times the step on.
                lanes.prefetch(ahead.on(), ahead.s + ahead.speed * dt);
            }
            let (states, positions) = (&states[r.clone()], &mut positions[r]);
            if !update_four(lanes, states, positions, dt) {
                for (state, pos) in states.iter().zip(positions) {
                    update_one(lanes, state, pos, dt);
                }
            }
        }
    }
}

/// Update one vehicle's lane position from its state, `dt` [s] after the last update.
#[inline(always)]
fn update_one(lanes: &LaneMap, state: &VehicleState, pos: &mut LanePosition, dt: f64) {
    let last = pos.on().map(|i| (i, pos.s));
    // Moved about its speed times the step along the lane since the last update (the length
    // of the velocity: no trigonometry per vehicle and step).
    let found = lanes.locate(state.position, last, state.velocity.length() * dt);
    set_found(lanes, pos, found, state);
}

/// Write what [`LaneMap::locate`] `found` for the vehicle at `state` into `pos` (only if it
/// changed).
#[inline(always)]
fn set_found(lanes: &LaneMap, pos: &mut LanePosition, found: Option<(u32, f64, f64)>, state: &VehicleState) {
    let new = LanePosition::found(lanes, found, state.speed());
    if *pos != new {
        *pos = new;
    }
}

/// [`update_one`] for four vehicles at once, when all four take [`LaneMap::locate`]'s common
/// path: on a lanelet at the last update, the walk along its centre line from there short
/// ([`walk_four`]: the same bits as [`Path::walk`]), and the vehicle found on the same lanelet
/// within the narrow window, within its stay offset. Then it writes what four
/// [`update_one`]s write (the same operations in the same order, lane by lane) and returns true;
/// else it writes nothing and returns false. The walks' divisions are shared four wide, as in
/// the path following.
#[inline(always)]
fn update_four(lanes: &LaneMap, states: &[VehicleState], positions: &mut [LanePosition], dt: f64) -> bool {
    let (states, positions): (&[VehicleState; LANES], &mut [LanePosition; LANES]) =
        match (states.try_into(), positions.try_into()) {
            (Ok(s), Ok(p)) => (s, p),
            _ => return false,
        };
    let mut on = [0u32; LANES];
    for l in 0..LANES {
        match positions[l].on() {
            Some(i) if (i as usize) < lanes.centres.len() => on[l] = i,
            _ => return false,
        }
    }
    let paths: [&Path; LANES] = per_lane(|l| &lanes.centres[on[l] as usize]);
    let p: [DVec2; LANES] = per_lane(|l| states[l].position);
    // `update_one`'s hint for `LaneMap::locate`.
    let hint: [f64; LANES] = per_lane(|l| positions[l].s + states[l].velocity.length() * dt);
    let Some(walked) = walk_four(paths, p, hint, [NARROW_WINDOW; LANES]) else { return false };
    let stay: [f64; LANES] = per_lane(|l| lanes.stay[on[l] as usize]);
    let mut found = [true; LANES];
    for l in 0..LANES {
        // `LaneMap::locate`'s stay (the middle of the lane or less, which also puts it within `Path::near_within`'s
        // distance, the half width). The walk's segments lie inside the centre line (neither
        // its first nor its last), so the arc length is inside it too: `LaneMap::on`'s tests at
        // the ends do not apply. Nor does the narrow window: where a vehicle is found outside
        // it, `locate` walks again with a wider window from the same hint, and that walk ends
        // where this one did.
        found[l] = walked.lateral[l].abs() < stay[l];
    }
    if found != [true; LANES] {
        return false;
    }
    for l in 0..LANES {
        set_found(lanes, &mut positions[l], Some((on[l], walked.s[l], walked.lateral[l])), &states[l]);
    }
    true
}

/// Keeps [`LanePosition`] up to date on a map ([`LaneMap`] resource).
#[derive(Debug, Clone)]
pub struct LanesPlugin {
    /// The map.
    pub map: Arc<LaneletMap>,
}

impl Plugin for LanesPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.world_mut().init_resource::<Parallelism>();
        sim.insert_resource(LaneMap::new(Arc::clone(&self.map)));
        sim.world_mut().init_resource::<LanePositionsAt>();
        sim.configure_sets(Control, LaneSystems.in_set(SimSystems::Sense));
        sim.add_systems(Control, update_lane_positions.in_set(LaneSystems));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::RouteOptions;
    use crate::map::generate::{RingParams, ring_highway, ring_lane_tag};
    use crate::sim::grid::with_avx2;

    fn bits(positions: &[LanePosition]) -> Vec<(Option<LaneletId>, u32, [u64; 3])> {
        positions.iter().map(|p| (p.lanelet, p.index, [p.s, p.offset, p.speed].map(f64::to_bits))).collect()
    }

    #[test]
    fn four_lane_positions_at_once_are_the_bits_of_four_one_at_a_time() {
        // A three-lane ring like the benchmark's: vehicles along its lanes, mostly near the centre
        // line, now and then off it, beside the road or far from the last update.
        let ring = RingParams { lanes: 3, radius: 800.0, lane_width: 3.5, clockwise: false, node_spacing: 20.0 };
        let map = LaneletMap::parse_str(&ring_highway(&ring).unwrap(), std::path::Path::new("ring")).unwrap();
        let options = RouteOptions { points_per_meter: 0.5 };
        let loops: Vec<Path> = (0..3).map(|k| map.closed_loop_tag(&ring_lane_tag(3, k), &options).unwrap()).collect();
        let lanes = LaneMap::new(Arc::new(map));
        let mut next = crate::world::random::draws(0x9e37_79b9_7f4a_7c15);
        let n = 4001;
        let (mut states, mut positions) = (Vec::new(), Vec::new());
        let dt = 0.05;
        for k in 0..n {
            let path = &loops[k % loops.len()];
            let s = next() * path.length;
            let (point, heading) = path.sample(s);
            let offset = (next() - 0.5)
                * match (k % 29, k % 31) {
                    (0, _) => 30.0,
                    (_, 0) => 2.0,
                    _ => 0.2,
                };
            let speed = 30.0 * next();
            let side = DVec2::from_angle(heading).perp();
            let then = VehicleState::new(point + side * offset, heading, speed);
            let mut position = if k % 37 == 0 { LanePosition::default() } else { LanePosition::of(&lanes, &then) };
            match k % 41 {
                0 => position.s += 10.0,    // far from where it is: the narrow window misses
                1..=4 => position.s -= 1.5, // a step behind: found by the walk outside the narrow window
                _ => {}
            }
            // A dynamics step or three later (the control tick does not divide the steps evenly).
            let moved = speed * dt * (0.8 + 0.4 * next());
            // Now and then across a lane's edge since (into the next lane, or off the road).
            let across = if k % 7 == 0 { (next() - 0.5) * 6.0 } else { 0.0 };
            let to = then.position + DVec2::from_angle(heading) * moved + side * across;
            let now = VehicleState::new(to, heading + 1e-3 * (next() - 0.5), speed);
            states.push(now);
            positions.push(position);
        }
        let mut want = positions.clone();
        for (state, pos) in states.iter().zip(&mut want) {
            update_one(&lanes, state, pos, dt);
        }
        let want = bits(&want);
        let mut plain = positions.clone();
        LanePositionsPass { lanes: &lanes, states: &states, positions: &mut plain, dt }.run();
        assert_eq!(bits(&plain), want, "scalar code");
        if std::arch::is_x86_feature_detected!("avx2") {
            let mut four = positions.clone();
            // SAFETY: the processor has AVX2, checked just above.
            unsafe { with_avx2(LanePositionsPass { lanes: &lanes, states: &states, positions: &mut four, dt }) };
            assert_eq!(bits(&four), want, "AVX2 code");
        }
        // Both ways were taken; a group left to one at a time is left as it was.
        let mut taken = 0;
        for g in 0..n / LANES {
            let r = g * LANES..(g + 1) * LANES;
            let mut four = positions[r.clone()].to_vec();
            if update_four(&lanes, &states[r.clone()], &mut four, dt) {
                taken += 1;
            } else {
                assert_eq!(bits(&four), bits(&positions[r]), "group {g} changed");
            }
        }
        assert!(taken > n / LANES / 4 && taken < n / LANES, "{taken} of {} groups four at once", n / LANES);
    }
}
