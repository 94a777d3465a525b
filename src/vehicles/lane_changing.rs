//! The lane-change plugin: MOBIL's discretionary changes (with keep-right), mandatory changes
//! where the lane cannot reach the destination (lane drops, lane ends), cooperative gap opening,
//! and the manoeuvre itself along a [`LaneChangeProfile`], aborted when the target gap closes
//! before the halfway point.
//!
//! Sources: MOBIL, Kesting, Treiber, Helbing 2007, "General lane-changing model MOBIL for
//! car-following models", Transp. Res. Rec. 1999 (incentive, safety criterion, the asymmetric
//! keep-right bias); the 2015 smart vehicle (`scripts/sml_world_old/smartvehicle.py` of
//! marinarantanen/sml_world) drove one path per lane and switched between them, which is what a
//! change does here: the vehicle's [`Route`] becomes the target lane's path and the path
//! follower follows it plus the profile's offset, which starts at the vehicle's offset from the
//! new lane and ends at zero.
//!
//! Each control tick, before the path follower ([`LaneChangeSystems`]): one index of every
//! vehicle by lanelet and arc length ([`LaneIndex`]) is built (a crossing vehicle is in both
//! lanes), then every vehicle with a [`LaneChanger`] advances its manoeuvre or weighs a change
//! (split over threads), and the accepted changes start one vehicle at a time in query order, so
//! any thread count gives the same run.

use std::collections::BTreeMap;
use std::sync::Arc;

use bevy_ecs::prelude::{Entity, Local, Query, Res, ResMut, Resource};
use bevy_ecs::schedule::{IntoScheduleConfigs, SystemSet};
use glam::DVec2;

use crate::map::{LaneletId, Path, Place, RouteOptions};
use crate::sim::{Control, Parallelism, Plugin, SimBuilder, SimClock, SimSystems};
use crate::world::{Route, VehicleId, VehicleSize, VehicleState};

use super::lane_change::{LaneChangeProfile, Mobil, MobilDecision, Seen, Surroundings, mobil_decision};
use super::lanes::{LaneMap, LanePosition, PREFETCH_AHEAD};
use super::longitudinal::{Longitudinal, LongitudinalSystems, SteeringSystems};
use super::path_following::PathFollower;
use crate::world::prefetch_bytes;

/// Keep-right bias Δa_bias [m/s²] of MOBIL's asymmetric rule: a change to the left needs this
/// much more incentive, a change to the right this much less (Kesting et al. 2007, section 3).
pub const KEEP_RIGHT_BIAS: f64 = 0.3;
/// Discretionary changes are weighed every this many control ticks (0.5 s at 20 Hz).
pub const DISCRETIONARY_EVERY: i64 = 10;
/// Shortest manoeuvre \[m\] across a whole lane ([`LANE_SPACING`]); a shorter lateral move (an
/// abort from part-way) may take less ([`min_change_length`]).
pub const MIN_CHANGE_LENGTH: f64 = 10.0;
/// Distance between lane centres assumed when a change is weighed, before its path is known \[m\].
pub const LANE_SPACING: f64 = 3.5;
/// No discretionary change starts below this speed [m/s]: the shortest manoeuvre (10 m) would
/// take 5 s, so a change ends well within the 8 s the dense-ring test asserts (issue 61 §1).
pub const MIN_CHANGE_SPEED: f64 = 2.0;
/// Road \[m\] a mandatory change given up must leave its vehicle on the old lane after the way
/// back: where its lane ends it stands about this far before the end (behind the lane-end stop of
/// [`limit_for_lane_changes`]) and begins again from there.
pub const ROOM_AFTER_ABORT: f64 = 5.0;
/// Braking [m/s²] assumed of a leader when [`room_to_finish`] weighs the room ahead.
pub const LEADER_BRAKING: f64 = 3.0;
/// Bumper gap \[m\] kept to a standing leader when [`room_to_finish`] weighs the room ahead.
pub const STANDSTILL_GAP: f64 = 2.0;
/// Speed \[m/s\] under which the one ahead of a swap pair (two vehicles at their lanes' ends,
/// each wanting the other's lane) may move in front of its standing partner with less than a
/// standstill gap: it crawls forward and away from it.
pub const SWAP_CRAWL: f64 = 1.0;
/// Least bumper-to-bumper gap \[m\] in front of a standing swap partner that the one ahead moves
/// into ([`SWAP_CRAWL`]).
pub const SWAP_MIN_GAP: f64 = 0.5;

pub use super::lane_state::{
    ChangeKind, FollowLaw, Found, IndexEntry, LaneChangeParams, LaneChanger, LaneCrossings, LaneIndex, Manoeuvre,
    NewLaneChangers, RouteGoal, SEARCH_HORIZON, Side,
};

/// One finished (or aborted) lane change, for `summary.json`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LaneChangeEvent {
    /// Vehicle.
    pub id: VehicleId,
    /// Start \[s\].
    pub t_start: f64,
    /// End \[s\] (back in the old lane for an aborted one).
    pub t_end: f64,
    /// Lanelet left.
    pub from: i64,
    /// Lanelet aimed at.
    pub to: i64,
    /// `left` or `right`.
    pub direction: Side,
    /// `discretionary`, `mandatory` or `requested`.
    pub kind: ChangeKind,
    /// Whether it was aborted back to the old lane.
    pub aborted: bool,
    /// Largest lateral acceleration of the manoeuvre [m/s²].
    pub peak_lateral_accel: f64,
}

/// What the lane changes of a run did.
#[derive(Resource, Debug, Clone)]
pub struct LaneChangeLog {
    /// Every change, in the order they ended (when `keep_events`).
    pub events: Vec<LaneChangeEvent>,
    /// Whether every event is kept for the summary (a run's `metrics.lane_changes`); a
    /// benchmark or soak that writes no summary turns it off, so memory does not grow with the
    /// number of changes made.
    pub keep_events: bool,
    /// Changes ended so far (aborted ones included), by kind: discretionary, mandatory, requested.
    pub counts: [usize; 3],
    /// Of which aborted.
    pub aborted: usize,
    /// Vehicles that reached the end of a lane they had to leave.
    pub missed_exits: std::collections::BTreeSet<VehicleId>,
    /// Longest time a vehicle stood (below 0.5 m/s) waiting for a gap \[s\].
    pub max_wait_s: f64,
}

impl Default for LaneChangeLog {
    fn default() -> Self {
        LaneChangeLog {
            events: Vec::new(),
            keep_events: true,
            counts: [0; 3],
            aborted: 0,
            missed_exits: Default::default(),
            max_wait_s: 0.0,
        }
    }
}

impl LaneChangeLog {
    /// Count `event` (and keep it when `keep_events`).
    pub fn record(&mut self, event: LaneChangeEvent) {
        let k = match event.kind {
            ChangeKind::Discretionary => 0,
            ChangeKind::Mandatory => 1,
            ChangeKind::Requested => 2,
        };
        self.counts[k] += 1;
        self.aborted += usize::from(event.aborted);
        if self.keep_events {
            self.events.push(event);
        }
    }

    /// Changes ended so far, aborted ones included.
    pub fn count(&self) -> usize {
        self.counts.iter().sum()
    }
}

/// Lane paths (a lanelet to the goal) and which lanelets reach a goal, computed once each.
#[derive(Resource, Debug, Clone, Default)]
pub struct LanePaths {
    /// Route resampling density [points per metre].
    pub points_per_meter: f64,
    paths: BTreeMap<(u32, String), Option<Arc<Path>>>,
    reach: BTreeMap<String, Arc<Vec<bool>>>,
    /// Closed loops, one per lane: a loop through a lanelet serves every lanelet it passes.
    loops: Vec<Arc<Path>>,
    /// Where each loop's lanelets start along it [m] (same order as `loops`).
    loop_starts: Vec<BTreeMap<LaneletId, f64>>,
}

impl LanePaths {
    /// Paths resampled at `points_per_meter`.
    pub fn new(points_per_meter: f64) -> LanePaths {
        LanePaths { points_per_meter, ..Default::default() }
    }

    /// Which lanelets reach `goal` by driving on (every lanelet for a loop).
    pub fn reach(&mut self, lanes: &LaneMap, goal: &RouteGoal) -> Arc<Vec<bool>> {
        if let RouteGoal::Lanes(route) = goal {
            // Not kept: each route is driven by few vehicles, and the mask is as long as the map.
            return Arc::new(route.reach_mask(&lanes.map));
        }
        let key = goal.key();
        if let Some(r) = self.reach.get(&key) {
            return Arc::clone(r);
        }
        let n = lanes.map.lanelets.len();
        let r = match goal {
            RouteGoal::Loop => vec![true; n],
            RouteGoal::Lanes(route) => route.reach_mask(&lanes.map),
            RouteGoal::To(place) => {
                let nodes = lanes.map.place_nodes(place).unwrap_or_default();
                let mut reach = vec![false; n];
                let mut stack = Vec::new();
                for (i, l) in lanes.map.lanelets.iter().enumerate() {
                    if l.routable && nodes.iter().any(|n| l.right_nodes.contains(n) || l.left_nodes.contains(n)) {
                        reach[i] = true;
                        stack.push(i as u32);
                    }
                }
                while let Some(i) = stack.pop() {
                    for &p in &lanes.predecessors[i as usize] {
                        if !reach[p as usize] {
                            reach[p as usize] = true;
                            stack.push(p);
                        }
                    }
                }
                reach
            }
        };
        let r = Arc::new(r);
        self.reach.insert(key, Arc::clone(&r));
        r
    }

    /// How many paths are kept (lane loops and routes to places).
    pub fn cached(&self) -> usize {
        self.loops.len() + self.paths.values().filter(|p| p.is_some()).count()
    }

    /// A path through lanelet `i` to `goal`: for a loop, any loop of `i`'s lane (one per lane,
    /// shared by all its lanelets, so memory does not grow with the lanelets where vehicles
    /// change lanes: a loop is a whole lane); else [`LanePaths::path`].
    pub fn path_through(&mut self, lanes: &LaneMap, i: u32, goal: &RouteGoal) -> Option<Arc<Path>> {
        if *goal != RouteGoal::Loop {
            return self.path(lanes, i, goal);
        }
        let id = lanes.id(i);
        if let Some(p) = self.loops.iter().find(|p| p.lanelets.contains(&id)) {
            return Some(Arc::clone(p));
        }
        let path = self.path(lanes, i, goal)?;
        if path.closed {
            self.loop_starts.push(lanelet_starts(lanes, &path));
            self.loops.push(Arc::clone(&path));
            self.paths.remove(&(i, goal.key()));
        }
        Some(path)
    }

    /// Where lanelet `i` starts along the loop [`LanePaths::path_through`] gave for it \[m\]
    /// (`None` if no loop passes it).
    pub fn loop_start(&self, lanes: &LaneMap, i: u32) -> Option<f64> {
        let id = lanes.id(i);
        self.loop_starts.iter().find_map(|starts| starts.get(&id).copied())
    }

    /// The path from the start of lanelet `i` along its lane to `goal` (round the loop; to the
    /// place; or to the lane's end when the lane does not reach the place).
    pub fn path(&mut self, lanes: &LaneMap, i: u32, goal: &RouteGoal) -> Option<Arc<Path>> {
        if let RouteGoal::Lanes(route) = goal {
            // The route's own lane paths (not kept, as `reach`).
            return route.path_from(&lanes.map, lanes.id(i), self.points_per_meter).map(Arc::new);
        }
        let key = (i, goal.key());
        if let Some(p) = self.paths.get(&key) {
            return p.clone();
        }
        let reach = self.reach(lanes, goal);
        let map = &lanes.map;
        let l = &map.lanelets[i as usize];
        let opts = RouteOptions { points_per_meter: self.points_per_meter };
        let start = l.right_nodes.first().map(|n| Place::Node(*n));
        let path = match (goal, start) {
            (RouteGoal::Loop, Some(start)) => map.closed_loop_at(&start, &opts).ok(),
            (RouteGoal::To(to), Some(start)) if reach[i as usize] => map.route_places(&start, to, &opts).ok(),
            _ => None,
        };
        let path = path.or_else(|| {
            // The lane's own centre lines to its end (a lane that does not reach the goal).
            let mut points: Vec<DVec2> = Vec::new();
            let mut ids = Vec::new();
            let mut j = i;
            for _ in 0..64 {
                if ids.contains(&lanes.id(j)) {
                    break;
                }
                ids.push(lanes.id(j));
                let c = &map.lanelets[j as usize].centre;
                let skip = usize::from(points.last().zip(c.first()).is_some_and(|(a, b)| a.distance(*b) < 1e-6));
                points.extend_from_slice(&c[skip.min(c.len())..]);
                match lanes.successors[j as usize].first() {
                    Some(&k) => j = k,
                    None => break,
                }
            }
            (points.len() >= 2)
                .then(|| Path::from_points(ids, crate::map::polyline::resample(&points, self.points_per_meter), false))
        });
        let path = path.map(Arc::new);
        self.paths.insert(key, path.clone());
        path
    }
}

/// Where each lanelet of the closed loop `path` starts along it [m]: the first point of its
/// centre line projected on the loop, near where the one before it ended (one projection over
/// the whole loop, for the first).
fn lanelet_starts(lanes: &LaneMap, path: &Path) -> BTreeMap<LaneletId, f64> {
    let mut starts = BTreeMap::new();
    let mut expected: Option<f64> = None;
    for &id in &path.lanelets {
        let Some(k) = lanes.map.lanelet_index(id) else { continue };
        let Some(&first) = lanes.map.lanelets[k].centre.first() else { continue };
        let s = match expected {
            Some(hint) => path.project_near(first, hint, 50.0).s,
            None => path.project(first).s,
        };
        starts.insert(id, s);
        expected = Some(s + lanes.length(k as u32));
    }
    starts
}

/// The projection of `p` on the closed loop `path` near arc length `hint` [m], as over the whole
/// loop (`Path::project`) where the loop does not pass within 15 m of itself: the same nearest
/// point, its arc length in [0, length) (at the loop's start the window may end on the closing
/// segment's end, the same point at arc length `length`).
fn loop_projection_near(path: &Path, p: DVec2, hint: f64) -> crate::map::PathProjection {
    let mut q = path.project_near(p, hint, 15.0);
    if q.s >= path.length {
        q.s -= path.length;
    }
    q
}

/// Mandatory-change signals of the last tick: target lanelet -> (arc length \[m\], speed [m/s],
/// length \[m\], id) of the vehicles waiting to move in.
#[derive(Resource, Debug, Clone, Default)]
pub struct LaneSignals(pub BTreeMap<u32, Vec<(f64, f64, f64, VehicleId)>>);

/// Claims of this tick: target lanelet and arc length of the changes just started, so two
/// vehicles do not take one gap.
#[derive(Resource, Debug, Clone, Default)]
pub struct Claims(pub Vec<(u32, f64)>);

/// The lane-change systems, in [`SimSystems::Control`] before [`SteeringSystems`].
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct LaneChangeSystems;

/// Urgency [0, 1] of a mandatory change with `remaining` \[m\] of lane left at speed `v` [m/s].
pub fn urgency(remaining: f64, v: f64) -> f64 {
    let horizon = 100.0 + 4.0 * v.max(0.0);
    (1.0 - (remaining - 10.0) / horizon).clamp(0.0, 1.0)
}

/// MOBIL's parameters for a change to `side` of `kind` at `urgency`: keep-right bias; for a
/// mandatory change the threshold falls to far below 0 and the accepted deceleration of the new
/// follower grows from half of `safe_deceleration` to all of it as the end nears.
pub fn mobil_for(p: &LaneChangeParams, side: Side, kind: ChangeKind, urgency: f64) -> Mobil {
    let bias = if p.keep_right {
        match side {
            Side::Left => KEEP_RIGHT_BIAS,
            Side::Right => -KEEP_RIGHT_BIAS,
        }
    } else {
        0.0
    };
    match kind {
        ChangeKind::Discretionary => {
            Mobil { politeness: p.politeness, threshold: p.threshold + bias, safe_deceleration: p.safe_deceleration }
        }
        // Leaving a lane that does not lead to the destination is worth b_safe on top of the
        // usual incentive: any gap the safety criterion accepts is taken, and that criterion
        // widens as the end nears.
        ChangeKind::Mandatory | ChangeKind::Requested => Mobil {
            politeness: p.politeness,
            threshold: (p.threshold + bias) * (1.0 - urgency) - p.safe_deceleration,
            safe_deceleration: p.safe_deceleration * (0.5 + 0.5 * urgency),
        },
    }
}

fn seen_ahead(f: Found, me: f64) -> Seen {
    // MOBIL assumes every vehicle is as long as we are: shift centres so its gaps are the real ones.
    Seen { s: f.distance - 0.5 * (f.length - me), speed: f.speed }
}

fn seen_behind(f: Found, me: f64) -> Seen {
    Seen { s: -f.distance + 0.5 * (f.length - me), speed: f.speed }
}

/// What one vehicle's evaluation (the parallel part of [`decide_lane_changes`]) leaves for the
/// serial part, which applies it in query order.
#[derive(Debug, Default)]
pub struct Decision {
    /// A change that ended this tick.
    finished: Option<LaneChangeEvent>,
    /// Seconds waited at a standstill for a mandatory change, if waiting.
    waited: Option<f64>,
    /// The vehicle reached the end of a lane it had to leave (first time).
    missed: bool,
    /// Mandatory (or signalled) changes announced to the target lane: (lanelet, s, speed, length).
    signals: [Option<(u32, f64, f64, f64)>; 2],
    /// Changes MOBIL accepts, in the order weighed.
    accepted: [Option<Accepted>; 2],
}

/// A change MOBIL accepts: (gain [m/s²], side, kind, target lanelet, arc length there [m]).
type Accepted = (f64, Side, ChangeKind, u32, f64);

impl Decision {
    /// Nothing to apply (most vehicles, most ticks): the serial part never sees it.
    fn is_empty(&self) -> bool {
        self.finished.is_none()
            && self.waited.is_none()
            && !self.missed
            && self.signals == [None; 2]
            && self.accepted == [None; 2]
    }
}

/// What one thread of [`decide_lane_changes`] hands to its serial part: the non-empty
/// decisions and the vehicles that may need [`limit_for_lane_changes`], each with its item's
/// place, in query order.
/// On cache lines of its own (see [`crate::sim::parallel::Padded`]).
#[derive(Default)]
#[repr(align(128))]
pub struct ChunkOut {
    decisions: Vec<(usize, Decision)>,
    limited: Vec<usize>,
}

/// The vehicles [`limit_for_lane_changes`] visits this control tick, in query order: those
/// [`decide_lane_changes`] left with a limit to apply (most vehicles have none, and scanning
/// every vehicle's [`LaneChanger`] for the few was a serial pass over all of them).
#[derive(Resource, Debug, Default)]
pub struct LaneChangeLimits(pub Vec<Entity>);

/// Whether `ch` asks [`limit_for_lane_changes`] to lower the demand.
fn needs_limit(ch: &LaneChanger) -> bool {
    ch.lane_end.is_some() || ch.virtual_leader.is_some() || ch.yield_to.is_some() || ch.active.is_some()
}

/// One ECS table's lane changers as [`decide_lane_changes`] reads them: slices of the same rows
/// (bevy's contiguous access, no list of the query's items gathered first).
#[derive(Clone, Copy)]
struct ChangerTable<'a> {
    entities: &'a [Entity],
    ids: &'a [VehicleId],
    states: &'a [VehicleState],
    sizes: &'a [VehicleSize],
    positions: &'a [LanePosition],
}

/// What the serial part of [`decide_lane_changes`] writes besides the vehicles' own components.
struct Applying<'a> {
    paths: &'a mut LanePaths,
    log: &'a mut LaneChangeLog,
    signals: &'a mut LaneSignals,
    claims: &'a mut Claims,
    limits: &'a mut LaneChangeLimits,
}

/// A vehicle's [`LaneIndex`] entry on its own lanelet ([`IndexEntry::NOT_ON_A_LANELET`] when
/// on none).
#[inline(always)]
fn index_entry(id: VehicleId, size: &VehicleSize, pos: &LanePosition) -> IndexEntry {
    match pos.on() {
        Some(i) => IndexEntry { lanelet: i, s: pos.s, speed: pos.speed, length: size.length, id },
        None => IndexEntry::NOT_ON_A_LANELET,
    }
}

/// What every vehicle's evaluation reads.
struct Shared<'a> {
    lanes: &'a LaneMap,
    index: &'a LaneIndex,
    signals: &'a BTreeMap<u32, Vec<(f64, f64, f64, VehicleId)>>,
    t: f64,
    dt: f64,
    tick: i64,
}

/// The lanelet beside `i` on the side of `pos`'s offset (the one a crossing vehicle is also in).
fn other_lane(lanes: &LaneMap, pos: &LanePosition, i: u32) -> Option<u32> {
    lanes.beside(i, pos.offset > 0.0)
}

/// Advance or decide every [`LaneChanger`]'s lane change (see the module documentation).
///
/// Three steps: the [`LaneIndex`] is built; every vehicle is evaluated against it on its own
/// (split over threads: its manoeuvre advanced or aborted, MOBIL weighed for each candidate side);
/// then, one vehicle at a time in query order, the changes MOBIL accepted start unless an earlier
/// vehicle claimed the same place this tick, and the log and signals are written. Any thread
/// count gives the same run.
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub fn decide_lane_changes(
    clock: Res<SimClock>,
    lanes: Option<Res<LaneMap>>,
    parallelism: Option<Res<Parallelism>>,
    mut paths: ResMut<LanePaths>,
    mut index: ResMut<LaneIndex>,
    mut log: ResMut<LaneChangeLog>,
    mut crossings: ResMut<LaneCrossings>,
    mut signals: ResMut<LaneSignals>,
    mut claims: ResMut<Claims>,
    mut limits: ResMut<LaneChangeLimits>,
    all: Query<(&VehicleId, &VehicleSize, &LanePosition)>,
    mut changers: Query<(
        Entity,
        &VehicleId,
        &VehicleState,
        &VehicleSize,
        &LanePosition,
        &mut Route,
        &mut PathFollower,
        &mut LaneChanger,
    )>,
    mut entries: Local<Vec<IndexEntry>>,
    mut index_scratch: Local<Vec<()>>,
    mut scratch: Local<Vec<ChunkOut>>,
) {
    // Last tick's list holds every vehicle with a manoeuvre under way (only this system starts
    // or ends one, and it lists each it leaves running): the crossing ones are found among
    // those, not by a serial pass over every LaneChanger.
    let mut previous = std::mem::take(&mut limits.0);
    let Some(lanes) = lanes else { return };
    let lanes = &*lanes;
    let parallelism = parallelism.as_deref().copied().unwrap_or_else(Parallelism::single);
    let t = clock.now.as_secs();
    let dt = clock.dt;
    let tick = if dt > 0.0 { (t / dt).round() as i64 } else { 0 };
    // The index: every vehicle on its lanelet (with the speed found with its position at the
    // start of this control tick: no trigonometry here), a crossing one on the other lane too.
    // Table by table, straight in the ECS tables' slices and split over the threads; a vehicle
    // on no lanelet gets an entry on none (`IndexEntry::NOT_ON_A_LANELET`), which the index leaves out. The
    // entries' order does not matter: the index sorts them.
    let lanelets = lanes.map.lanelets.len();
    match all.contiguous_iter() {
        Ok(tables) => {
            let mut end = 0;
            for (ids, sizes, positions) in tables {
                let start = end;
                end += ids.len();
                // Longer only while the world grows: last tick's entries are overwritten.
                if entries.len() < end {
                    entries.resize(end, IndexEntry::NOT_ON_A_LANELET);
                }
                parallelism.for_each_chunk_at(&mut entries[start..end], &mut index_scratch, |k0, chunk, _| {
                    for (k, e) in chunk.iter_mut().enumerate() {
                        let n = k0 + k;
                        *e = index_entry(ids[n], &sizes[n], &positions[n]);
                    }
                });
            }
            entries.truncate(end);
        }
        // Only if a component were stored sparsely (none is): one at a time.
        Err(_) => {
            entries.clear();
            entries.extend(all.iter().map(|(id, size, pos)| index_entry(*id, size, pos)));
        }
    }
    crossings.0.clear();
    for &e in &previous {
        let Ok((_, id, _, size, pos, _, _, ch)) = changers.get(e) else { continue };
        if let Some(m) = &ch.active {
            crossings.0.insert(*id, (m.from, m.to));
            if let Some(i) = pos.on()
                && let Some(j) = other_lane(lanes, pos, i)
            {
                let s = pos.s * lanes.length(j) / lanes.length(i).max(1e-9);
                entries.push(IndexEntry { lanelet: j, s, speed: pos.speed, length: size.length, id: *id });
            }
        }
    }
    index.rebuild(parallelism, lanelets, &entries);
    previous.clear();
    limits.0 = previous;
    let last_signals = std::mem::take(&mut signals.0);
    claims.0.clear();

    let shared = Shared { lanes, index: &index, signals: &last_signals, t, dt, tick };
    let mut apply =
        Applying { paths: &mut paths, log: &mut log, signals: &mut signals, claims: &mut claims, limits: &mut limits };
    // Table by table, straight in the ECS tables' slices. Evaluations read only the index and
    // the vehicle's own components, so doing one table's serial part before the next table's
    // evaluations keeps the order of the serial part (query order) and the results.
    // Which lanelets reach each goal was looked up by [`find_reach`].
    match changers.contiguous_iter_mut() {
        Ok(tables) => {
            for (entities, ids, states, sizes, positions, mut routes, mut followers, mut chs) in tables {
                let table = ChangerTable { entities, ids, states, sizes, positions };
                // Written through `DerefMut`: every row is marked changed, as `Mut::into_inner`
                // marked every gathered item before.
                decide_table(
                    &shared,
                    parallelism,
                    &mut scratch,
                    table,
                    &mut routes,
                    &mut followers,
                    &mut chs,
                    &mut apply,
                );
            }
        }
        // Only if a component were stored sparsely (none is): one at a time, in query order.
        Err(_) => {
            for (entity, id, state, size, pos, mut route, mut follower, mut ch) in &mut changers {
                let table = ChangerTable {
                    entities: std::slice::from_ref(&entity),
                    ids: std::slice::from_ref(id),
                    states: std::slice::from_ref(state),
                    sizes: std::slice::from_ref(size),
                    positions: std::slice::from_ref(pos),
                };
                let (route, follower, ch) = (
                    std::slice::from_mut(&mut *route),
                    std::slice::from_mut(&mut *follower),
                    std::slice::from_mut(&mut *ch),
                );
                decide_table(&shared, parallelism, &mut scratch, table, route, follower, ch, &mut apply);
            }
        }
    }
}

/// [`decide_lane_changes`]' evaluations (split over threads) and serial part for one table's
/// lane changers: `routes`, `followers` and `chs` are the same rows as `table`'s slices.
#[allow(clippy::too_many_arguments)]
fn decide_table(
    shared: &Shared<'_>,
    parallelism: Parallelism,
    scratch: &mut Vec<ChunkOut>,
    table: ChangerTable<'_>,
    routes: &mut [Route],
    followers: &mut [PathFollower],
    chs: &mut [LaneChanger],
    apply: &mut Applying<'_>,
) {
    let ChangerTable { entities, ids, states, sizes, positions } = table;
    // Each chunk keeps the non-empty decisions with their row (chunks are in query order, and
    // so is each list): the serial part visits only those, not every vehicle. They also note
    // the vehicles [`limit_for_lane_changes`] may have to slow: those with a limit set by the
    // evaluation, or a decision the serial part may turn into a manoeuvre.
    parallelism.for_each_chunk_triple_at(routes, followers, chs, scratch, |start, routes, followers, chs, out| {
        // The changers a few places on: the evaluation reads the first lines of each (see
        // `LaneChanger`'s layout); a miss on them was most of its samples.
        let ahead = chs.as_ptr();
        let len = chs.len();
        for (k, ((route, follower), ch)) in routes.iter_mut().zip(followers.iter_mut()).zip(chs.iter_mut()).enumerate()
        {
            if k + PREFETCH_AHEAD < len {
                prefetch_bytes(ahead.wrapping_add(k + PREFETCH_AHEAD).cast(), LaneChanger::HOT_BYTES);
            }
            let n = start + k;
            let mut decision = Decision::default();
            evaluate(shared, ids[n], &states[n], &sizes[n], &positions[n], route, follower, ch, &mut decision);
            if !decision.is_empty() {
                out.decisions.push((n, decision));
                out.limited.push(n);
            } else if needs_limit(ch) {
                out.limited.push(n);
            }
        }
    });
    let Applying { ref mut paths, ref mut log, ref mut signals, ref mut claims, ref mut limits } = *apply;
    let (lanes, t) = (shared.lanes, shared.t);
    for (k, decision) in scratch.iter_mut().flat_map(|out| out.decisions.drain(..)) {
        let (state, size, pos) = (&states[k], &sizes[k], &positions[k]);
        let (route, follower, ch) = (&mut routes[k], &mut followers[k], &mut chs[k]);
        let me = ids[k];
        if let Some(event) = decision.finished {
            log.record(event);
        }
        if let Some(w) = decision.waited {
            log.max_wait_s = log.max_wait_s.max(w);
        }
        if decision.missed {
            log.missed_exits.insert(me);
        }
        if decision.accepted == [None; 2] && decision.signals == [None; 2] {
            continue;
        }
        let v = pos.speed;
        let mut best: Option<(f64, Side, ChangeKind, u32)> = None;
        for (k, accepted) in decision.accepted.iter().enumerate() {
            if let Some((gain, side, kind, j, s_j)) = *accepted {
                let claimed = claims.0.iter().any(|&(cj, cs)| cj == j && (cs - s_j).abs() < 2.0 * size.length + v);
                if !claimed {
                    if best.is_none_or(|b| gain > b.0) {
                        best = Some((gain, side, kind, j));
                    }
                } else if kind == ChangeKind::Requested {
                    ch.request = None;
                }
            }
            if let Some((j, s_j, speed, length)) = decision.signals[k] {
                signals.0.entry(j).or_default().push((s_j, speed, length, me));
            }
        }
        let Some((_, side, kind, j)) = best else { continue };
        let Some(i) = pos.on() else { continue };
        let Some(path) = paths.path_through(lanes, j, &ch.goal) else { continue };
        let s_j = pos.s * lanes.length(j) / lanes.length(i).max(1e-9);
        let q = if path.closed {
            // A lane's loop may start at any of its lanelets: near where lanelet j starts on it
            // (a lane's loop does not pass within a lane of itself, so the nearest point of the
            // window is the loop's nearest; a ring's loop has tens of thousands of points, and a
            // projection over all of them for every change was the serial part's largest cost).
            match paths.loop_start(lanes, j) {
                Some(start) => loop_projection_near(&path, state.position, start + s_j),
                None => path.project(state.position),
            }
        } else {
            path.project_near(state.position, s_j, 15.0)
        };
        let (law, p) = (ch.law, ch.params);
        let cap = v.max(law.desired_speed().min(v + 3.0));
        let profile = LaneChangeProfile::for_speed(-q.lateral, cap, p.max_lateral_accel, MIN_CHANGE_LENGTH);
        let m = Manoeuvre {
            from: lanes.id(i),
            to: lanes.id(j),
            direction: side,
            kind,
            profile,
            start_offset: q.lateral,
            s_start: q.s,
            old_route: Arc::clone(&route.0),
            old_s: follower.s,
            t_start: t,
            aborted: false,
            peak_lateral_accel: 0.0,
            speed_cap: cap,
        };
        let params = follower.params;
        let max_offset = follower.max_offset;
        route.0 = path;
        *follower = PathFollower::starting_at(params, q.s);
        follower.max_offset = max_offset;
        claims.0.push((j, s_j));
        ch.request = None;
        ch.wait_since = None;
        ch.active = Some(m);
    }
    for k in scratch.iter_mut().flat_map(|out| out.limited.drain(..)) {
        if needs_limit(&chs[k]) {
            limits.0.push(entities[k]);
        }
    }
}

/// Look up which lanelets reach the goal ([`LanePaths::reach`], cached per goal) for every
/// [`LaneChanger`] added since the last control tick, or added before and off the road until
/// now (kept in `waiting`), before [`decide_lane_changes`] reads it. A [`LaneChanger`] is
/// inserted once, when its vehicle spawns. Doing this in the serial gathering of
/// `decide_lane_changes` read every vehicle's `LaneChanger` every tick for the few new ones: a
/// cache miss per vehicle, a third of the lane-change decisions' serial time (issue 19 item 8).
/// The new ones come from [`NewLaneChangers`], which the component's `on_add` hook fills: an
/// `Added<LaneChanger>` query tested every vehicle's tick every control tick, on one thread
/// (2 ms of a 10 s `--lane-change` bench run). The first run also takes every changer without
/// its lanelets looked up, in case some were added before the plugin installed the list (and
/// so does the first run after a tick without a [`LaneMap`]).
#[allow(clippy::type_complexity)]
pub fn find_reach(
    lanes: Option<Res<LaneMap>>,
    mut paths: ResMut<LanePaths>,
    mut new: ResMut<NewLaneChangers>,
    mut changers: Query<(Entity, &LanePosition, &mut LaneChanger)>,
    mut waiting: Local<Vec<Entity>>,
    mut started: Local<bool>,
) {
    waiting.append(&mut new.0);
    let Some(lanes) = lanes else {
        // Nothing to look up on: the first run with a map takes them all.
        waiting.clear();
        *started = false;
        return;
    };
    if !std::mem::replace(&mut *started, true) {
        waiting.extend(changers.iter().filter(|(_, _, ch)| ch.reach.is_none()).map(|(e, _, _)| e));
        waiting.sort_unstable();
        waiting.dedup();
    }
    waiting.retain(|&e| {
        let Ok((_, pos, mut ch)) = changers.get_mut(e) else { return false };
        if ch.reach.is_some() {
            return false;
        }
        if pos.on().is_none() {
            return true;
        }
        ch.reach = Some(paths.reach(&lanes, &ch.goal));
        false
    });
}

/// One vehicle's part of [`decide_lane_changes`]: everything that depends only on itself and the
/// index (so it may run on any thread); what must be applied in order is left in `out`.
#[allow(clippy::too_many_arguments)]
fn evaluate(
    shared: &Shared<'_>,
    me: VehicleId,
    state: &VehicleState,
    size: &VehicleSize,
    pos: &LanePosition,
    route: &mut Route,
    follower: &mut PathFollower,
    ch: &mut LaneChanger,
    out: &mut Decision,
) {
    let Shared { lanes, index, signals: last_signals, t, dt, tick } = *shared;
    let v = pos.speed;
    // Written only when they change, so change detection sees real changes.
    if ch.virtual_leader.is_some() {
        ch.virtual_leader = None;
    }
    if ch.yield_to.is_some() {
        ch.yield_to = None;
    }
    if ch.hold_behind {
        ch.hold_behind = false;
    }
    if ch.lane_end.is_some() {
        ch.lane_end = None;
    }
    if ch.crossing_leaders != [None; 2] {
        ch.crossing_leaders = [None; 2];
    }
    let Some(i) = pos.on() else { return };
    let len_i = lanes.length(i);
    // The law (72 bytes of the changer) is read where a gap is weighed, not every tick: most
    // ticks weigh none, and its cache lines stay unread.
    let p = ch.params;

    // Road left [m] to the end of a lane that does not reach the goal (infinite on one that does).
    let must_leave =
        !p.manual && ch.active.is_none() && !route.0.closed && ch.reach.as_deref().is_some_and(|r| !r[i as usize]);
    let lane_left = if must_leave { (route.0.length - follower.s).max(0.0) } else { f64::INFINITY };

    // Cooperation: a neighbour signalling a mandatory change into our gap.
    if p.cooperative
        && let Some(list) = last_signals.get(&i)
    {
        let leader = index.ahead(lanes, i, pos.s, me).map_or(f64::INFINITY, |f| f.distance);
        let nearest = list
            .iter()
            .filter(|(s, _, _, sid)| *sid != me && *s > pos.s && *s - pos.s < leader.min(150.0))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        if let Some(&(s, speed, length, sid)) = nearest {
            let gap = s - pos.s - 0.5 * (length + size.length);
            let closing = (v - speed).max(0.0);
            // It wants our lane as we want its: it waits at its lane's end until it gets in.
            let swap = lane_left.is_finite()
                && index.lanelet_of(sid).is_some_and(|j| {
                    ch.reach.as_deref().is_some_and(|r| r[j as usize])
                        && [Side::Left, Side::Right].into_iter().any(|side| allowed(lanes, i, side) == Some(j))
                });
            if swap || lane_left < s - pos.s + 0.5 * (length + size.length) + STANDSTILL_GAP {
                // We cannot pass it: our own lane ends first, or it waits to swap lanes with us. Two
                // such vehicles at their lane ends, each wanting the other's lane, waited for
                // ever side by side (a 5x5 SUMO grid gridlocked from such pairs, issue 54). Held
                // a standstill gap behind it, we leave it the room beside it to change into, then
                // take its place. As the stop at the lane's end, this braking is not capped.
                if gap > 0.0 {
                    ch.yield_to = Some((gap, speed));
                    ch.hold_behind = true;
                }
            } else if gap > 2.0 && closing * closing / (2.0 * (gap - 2.0)) <= 0.5 * p.safe_deceleration {
                // Only when we can fall behind it braking at most b_safe / 2; a neighbour already
                // alongside is passed instead (it merges behind us), or both would wait for ever.
                ch.yield_to = Some((gap, speed));
            }
        }
    }

    let abort_asked = ch.abort;
    if abort_asked {
        ch.abort = false;
    }
    if ch.active.is_some() {
        let Some(mut m) = ch.active.take() else { return };
        // In both lanes: follow the vehicle ahead in each (from the index, real lengths).
        let gap_of = |f: Found| (f.distance - 0.5 * (f.length + size.length), f.speed);
        ch.crossing_leaders[0] = index.ahead(lanes, i, pos.s, me).map(gap_of);
        // Three quarters of the way across, the vehicle is in the lane it aims at and clear of
        // the other lane's vehicles (2.6 m apart for 3.5 m lanes): it follows only its new lane,
        // or a stopped leader in the lane it leaves would hold it across both.
        let across = m.offset_at(&route.0, follower.s).abs() < 0.25 * m.profile.offset.abs();
        if !across && let Some(j) = other_lane(lanes, pos, i) {
            let s_j = pos.s * lanes.length(j) / len_i.max(1e-9);
            ch.crossing_leaders[1] = index.ahead(lanes, j, s_j, me).map(gap_of);
        }
        let mut driven = m.driven(&route.0, follower.s);
        // As the speed falls the rest of the profile is shortened to the length sized for the
        // speed (down to the shortest manoeuvre), the fraction done kept: below the speed it was
        // sized for, a change advances by time, not distance, and one caught by a stop wave ends
        // while braking instead of standing across two lanes (issue 61 §1).
        if driven < m.profile.length {
            let sized = LaneChangeProfile::for_speed(
                m.profile.offset,
                v,
                p.max_lateral_accel,
                min_change_length(m.profile.offset),
            );
            if sized.length < 0.9 * m.profile.length {
                let u = driven / m.profile.length;
                let s_start = follower.s - u * sized.length;
                m.s_start = if route.0.closed { s_start.rem_euclid(route.0.length) } else { s_start };
                m.profile = sized;
                m.speed_cap = m.speed_cap.min(sized.speed_for(p.max_lateral_accel));
                driven = u * sized.length;
            }
        }
        let d2 = profile_curvature(&m.profile, driven);
        m.peak_lateral_accel = m.peak_lateral_accel.max(v * v * d2);
        m.old_s = m.old_route.project_near(state.position, m.old_s + v * dt, v.abs() * dt + 5.0).s;
        if driven >= m.profile.length {
            out.finished = Some(LaneChangeEvent {
                id: me,
                t_start: m.t_start,
                t_end: t,
                from: m.from.0,
                to: m.to.0,
                direction: m.direction,
                kind: m.kind,
                aborted: m.aborted,
                peak_lateral_accel: m.peak_lateral_accel,
            });
            ch.last_change = t;
            return;
        }
        if !m.aborted && driven < 0.5 * m.profile.length {
            // Still mostly in the old lane: is the target gap still there?
            let moving_left = m.direction == Side::Left;
            let target = if (pos.offset > 0.0) == moving_left { neighbour(lanes, i, m.direction) } else { Some(i) };
            let closed = abort_asked
                || target.is_some_and(|j| {
                    let s_j = pos.s * lanes.length(j) / len_i.max(1e-9);
                    let (ahead, behind) = (index.ahead(lanes, j, s_j, me), index.behind(lanes, j, s_j, me));
                    target_gap_closed(&ch.law, p.safe_deceleration, v, size.length, ahead, behind)
                });
            if closed {
                let back = m.old_route.project_near(state.position, m.old_s, 10.0);
                let offset = back.lateral;
                let profile =
                    LaneChangeProfile::for_speed(-offset, m.speed_cap, p.max_lateral_accel, min_change_length(offset));
                // No way back where the old lane's route ends before the way back would: a
                // mandatory change at the end of its lane, aborted there, stood on a route
                // ending under it, its abort never done (it ends by distance), and never changed
                // again (issue 54's 20x20 grid: a vehicle stood in the junction for good). It
                // goes on with its change; the vehicles of the lane it enters see it in both.
                // Nor where the way back leaves no room to stand and begin again: put back on a
                // route ending a few metres on, with no lane end known while its abort lasted,
                // it arrived there and left the world in the middle of the road (a lane drop's
                // queue, a change asked to abort 4-5 m before the end).
                let again = if m.kind == ChangeKind::Mandatory { ROOM_AFTER_ABORT } else { 0.0 };
                if m.old_route.closed || back.s + profile.length + again <= m.old_route.length {
                    let old = std::mem::replace(&mut route.0, Arc::clone(&m.old_route));
                    let aborted = Manoeuvre {
                        profile,
                        start_offset: offset,
                        s_start: back.s,
                        old_route: old,
                        old_s: follower.s,
                        aborted: true,
                        ..m
                    };
                    let (params, max_offset) = (follower.params, follower.max_offset);
                    *follower = PathFollower::starting_at(params, back.s);
                    follower.max_offset = max_offset;
                    ch.active = Some(aborted);
                    return;
                }
            }
        }
        ch.active = Some(m);
        return;
    }

    // Mandatory need: this lane does not reach the destination. (`reach` is read here once, not
    // cloned: an Arc's count is an atomic shared by every vehicle with the goal.)
    let Some(reach) = ch.reach.as_deref() else { return };
    let reaches = |side: Side| allowed(lanes, i, side).is_some_and(|j| reach[j as usize]);
    let (reach_here, reach_right, reach_left) = (reach[i as usize], reaches(Side::Right), reaches(Side::Left));
    let reaches = |side: Side| if side == Side::Right { reach_right } else { reach_left };
    let remaining = if route.0.closed { f64::INFINITY } else { (route.0.length - follower.s).max(0.0) };
    let mut mandatory: Option<Side> = None;
    if !reach_here && !p.manual {
        mandatory = [Side::Right, Side::Left].into_iter().find(|&side| reaches(side));
    }
    let u = if mandatory.is_some() { urgency(remaining, v) } else { 0.0 };
    if mandatory.is_some() {
        ch.lane_end = Some(remaining);
        if v < 0.5 {
            let since = *ch.wait_since.get_or_insert(t);
            out.waited = Some(t - since);
            tracing::trace!(target: "lane_changes", "{me} waits {:.1} s to leave lanelet {i}, {remaining:.1} m left", t - since);
        } else {
            ch.wait_since = None;
        }
        if remaining < 1.0 && !ch.missed {
            ch.missed = true;
            out.missed = true;
        }
    }
    let since_last = t - ch.last_change;
    let mut candidates: [(Side, ChangeKind); 2] = [(Side::Left, ChangeKind::Discretionary); 2];
    let mut n = 0;
    if let Some(side) = ch.request {
        candidates[0] = (side, ChangeKind::Requested);
        n = 1;
    } else if ch.hold {
        // A cooperative plugin decides this vehicle's changes (it asks through `request`).
        n = 0;
    } else if let Some(side) = mandatory {
        if since_last >= p.min_interval || u > 0.5 {
            candidates[0] = (side, ChangeKind::Mandatory);
            n = 1;
        }
    } else if !p.manual && since_last >= p.min_interval && (tick + i64::from(me.0)).rem_euclid(DISCRETIONARY_EVERY) == 0
    {
        // Discretionary changes are weighed every DISCRETIONARY_EVERY control ticks, the
        // vehicles staggered by id: a driver does not reconsider at 20 Hz.
        candidates = [(Side::Right, ChangeKind::Discretionary), (Side::Left, ChangeKind::Discretionary)];
        n = 2;
    }
    if n == 0 {
        return;
    }
    let leader = index.ahead(lanes, i, pos.s, me);
    let follower_now = index.behind(lanes, i, pos.s, me);
    for (k, &(side, kind)) in candidates[..n].iter().enumerate() {
        let Some(j) = allowed(lanes, i, side) else {
            if kind == ChangeKind::Requested {
                ch.request = None;
            }
            continue;
        };
        if kind == ChangeKind::Discretionary && (!reaches(side) || ch.keep_out == Some(side)) {
            continue;
        }
        let scale = len_i / lanes.length(j).max(1e-9);
        let s_j = pos.s / scale;
        let unscale = |f: Found| Found { distance: f.distance * scale, ..f };
        let tl = index.ahead(lanes, j, s_j, me).map(unscale);
        let tf = index.behind(lanes, j, s_j, me).map(unscale);
        let around = Surroundings {
            me: Seen { s: 0.0, speed: v },
            length: size.length,
            leader: leader.map(|f| seen_ahead(f, size.length)),
            follower: follower_now.map(|f| seen_behind(f, size.length)),
            target_leader: tl.map(|f| seen_ahead(f, size.length)),
            target_follower: tf.map(|f| seen_behind(f, size.length)),
        };
        let mobil = mobil_for(&p, side, kind, u);
        let law = &ch.law;
        let decision = mobil_decision(&mobil, &around, |v, l| law.accel(v, l));
        match decision {
            // Whether an earlier vehicle claimed the place this tick is known only in query
            // order: the serial part decides (and drops a claimed request).
            MobilDecision::Change(_)
                if kind == ChangeKind::Discretionary && !room_to_finish(v, size.length, leader, tl) => {}
            MobilDecision::Change(gain) => out.accepted[k] = Some((gain, side, kind, j, s_j)),
            _ if kind == ChangeKind::Requested => ch.request = None,
            MobilDecision::Unsafe(_)
                if kind == ChangeKind::Mandatory
                    && u > 0.5
                    && v < SWAP_CRAWL
                    && tf.is_some_and(|f| {
                        f.speed.abs() < 0.1
                            && f.distance - 0.5 * (f.length + size.length) >= SWAP_MIN_GAP
                            && last_signals.get(&i).is_some_and(|list| list.iter().any(|x| x.3 == f.id))
                    }) =>
            {
                // The one ahead of a swap pair, both at their lanes' ends: its partner stands
                // behind the place it moves into, holding for it (below), so the place is safe
                // however short: it drives forward and away from that nose. MOBIL's test asks a
                // whole standstill gap of the new follower; a partner that stopped less than a
                // slot behind then left both waiting for ever, and the queues behind them (99
                // vehicles for 1,690 s on the 20x20 SUMO grid, issue 54).
                out.accepted[k] = Some((0.0, side, kind, j, s_j));
            }
            MobilDecision::Occupied | MobilDecision::Unsafe(_) if kind == ChangeKind::Mandatory && u > 0.5 => {
                // Fall behind the vehicle beside us in the target lane, then signal.
                if let Some(l) = tl.filter(|f| f.distance < size.length + f.length) {
                    let gap = (l.distance - 0.5 * (l.length + size.length), l.speed);
                    // A vehicle beside us that must change into our lane as we into its: the two
                    // swap lanes only once one is a length behind the other. Both falling back
                    // (the rule for others) kept pairs abreast to their lane ends, where they
                    // waited for ever (pairs of turners on a SUMO grid, issue 54). So the one
                    // behind (the greater id when level) drops back at any braking, as before
                    // its lane's end, and the one ahead drives on and changes first.
                    let swapping = last_signals.get(&i).is_some_and(|list| list.iter().any(|x| x.3 == l.id));
                    if !swapping {
                        ch.virtual_leader = Some(gap);
                    } else if l.distance > 1e-6 || l.id < me {
                        ch.yield_to = Some(gap);
                        ch.hold_behind = true;
                    }
                }
            }
            _ => {}
        }
        if kind == ChangeKind::Mandatory || (kind == ChangeKind::Requested && ch.signal_request) {
            out.signals[k] = Some((j, s_j, v, size.length));
        }
    }
}

/// The shortest manoeuvre \[m\] for a lateral move of `offset` \[m\]: [`MIN_CHANGE_LENGTH`] across a
/// whole lane, shorter for a part (a kinematic vehicle's shortest S-bend grows with the square
/// root of its lateral move), never under 3 m.
pub fn min_change_length(offset: f64) -> f64 {
    (MIN_CHANGE_LENGTH * (offset.abs() / LANE_SPACING).sqrt()).clamp(3.0, MIN_CHANGE_LENGTH)
}

/// Whether a discretionary change at speed `v` [m/s] has room to finish: should the target
/// lane's `target_leader` and our lane's `leader` (distances centre to centre, our `length` \[m\])
/// brake to a stop at [`LEADER_BRAKING`] now, we could still drive the shortest whole manoeuvre
/// ([`MIN_CHANGE_LENGTH`]: a change in progress is shortened as the speed falls) behind the first
/// and three quarters of it (clear of the lane we leave) behind the second, keeping
/// [`STANDSTILL_GAP`]. Without it a change begun in stop-and-go traffic stood across two lanes
/// behind a stopped leader for up to 37 s (issue 61 §1; 80 vehicles on the three-lane ring).
/// Nothing starts below [`MIN_CHANGE_SPEED`].
pub fn room_to_finish(v: f64, length: f64, leader: Option<Found>, target_leader: Option<Found>) -> bool {
    if v < MIN_CHANGE_SPEED {
        return false;
    }
    [(target_leader, MIN_CHANGE_LENGTH), (leader, 0.75 * MIN_CHANGE_LENGTH)].into_iter().all(|(f, need)| {
        f.is_none_or(|f| {
            let gap = f.distance - 0.5 * (f.length + length);
            gap + f.speed * f.speed / (2.0 * LEADER_BRAKING) >= need + STANDSTILL_GAP
        })
    })
}

/// Whether the gap a change aims at has closed (the abort rule before the halfway point): the
/// vehicle ahead in the target lane overlaps us, or the one behind overlaps us or would have to
/// brake harder than `safe_deceleration` [m/s²] behind us at our speed `v` [m/s] (`length`: ours).
pub fn target_gap_closed(
    law: &FollowLaw,
    safe_deceleration: f64,
    v: f64,
    length: f64,
    ahead: Option<Found>,
    behind: Option<Found>,
) -> bool {
    let front = ahead.is_some_and(|f| f.distance - 0.5 * (f.length + length) <= 0.0);
    let back = behind.is_some_and(|f| {
        let gap = f.distance - 0.5 * (f.length + length);
        gap <= 0.0 || law.accel(f.speed, Some((gap, v))) < -safe_deceleration
    });
    front || back
}

/// The neighbour on `side` of lanelet `i`, if any (whatever the line between them).
pub fn neighbour(lanes: &LaneMap, i: u32, side: Side) -> Option<u32> {
    lanes.beside(i, side == Side::Left)
}

/// The neighbour on `side` of lanelet `i` when the line between them may be crossed that way.
pub fn allowed(lanes: &LaneMap, i: u32, side: Side) -> Option<u32> {
    let n = lanes.neighbours[i as usize];
    let ok = match side {
        Side::Left => n.change_left,
        Side::Right => n.change_right,
    };
    if ok { neighbour(lanes, i, side) } else { None }
}

/// `|d''(s)|` of a profile [1/m] at `s` [m] driven: the quintic's second derivative.
fn profile_curvature(p: &LaneChangeProfile, s: f64) -> f64 {
    let u = (s / p.length).clamp(0.0, 1.0);
    (p.offset * (60.0 * u - 180.0 * u * u + 120.0 * u * u * u) / (p.length * p.length)).abs()
}

/// Lower the demand for lane changes: fall behind a vehicle in the target lane while a mandatory
/// change waits, open a gap for a neighbour that must change in (braking at most
/// `safe_deceleration / 2`), and keep under the speed the manoeuvre was sized for.
pub fn limit_for_lane_changes(
    limits: Res<LaneChangeLimits>,
    mut vehicles: Query<(&VehicleState, &VehicleSize, &LaneChanger, &mut Longitudinal)>,
) {
    // Most vehicles are doing none of this: only those the decisions listed are visited.
    for &e in &limits.0 {
        let Ok((state, size, ch, mut lon)) = vehicles.get_mut(e) else { continue };
        if !needs_limit(ch) {
            continue;
        }
        let v = state.speed();
        let floor = -0.5 * ch.params.safe_deceleration;
        if let Some(remaining) = ch.lane_end {
            // Stop before the end as behind a standing vehicle there (the last resort).
            let gap = remaining - 0.5 * size.length - 1.0;
            lon.limit(ch.law.accel(v, Some((gap, 0.0))));
        }
        if let Some(leader) = ch.virtual_leader {
            lon.limit(ch.law.accel(v, Some(leader)).max(floor));
        }
        if let Some(leader) = ch.yield_to {
            let a = ch.law.accel(v, Some(leader));
            lon.limit(if ch.hold_behind { a } else { a.max(floor) });
        }
        if let Some(m) = &ch.active {
            lon.limit(2.0 * (m.speed_cap - v));
            for leader in ch.crossing_leaders.into_iter().flatten() {
                lon.limit(ch.law.accel(v, Some(leader)));
            }
        }
    }
}

/// Lane changes for every vehicle with a [`LaneChanger`] (needs the [`super::lanes::LanesPlugin`]).
#[derive(Debug, Clone, Copy)]
pub struct LaneChangePlugin {
    /// Route resampling density of the lane paths [points per metre].
    pub points_per_meter: f64,
}

impl Plugin for LaneChangePlugin {
    fn build(&self, sim: &mut SimBuilder) {
        super::longitudinal::install_longitudinal(sim);
        sim.insert_resource(LanePaths::new(self.points_per_meter));
        sim.world_mut().init_resource::<LaneIndex>();
        sim.world_mut().init_resource::<LaneChangeLog>();
        sim.world_mut().init_resource::<LaneCrossings>();
        sim.world_mut().init_resource::<LaneSignals>();
        sim.world_mut().init_resource::<Claims>();
        sim.world_mut().init_resource::<LaneChangeLimits>();
        sim.world_mut().init_resource::<NewLaneChangers>();
        sim.configure_sets(Control, LaneChangeSystems.in_set(SimSystems::Control).before(SteeringSystems));
        sim.add_systems(Control, (find_reach, decide_lane_changes).chain().in_set(LaneChangeSystems));
        sim.add_systems(Control, limit_for_lane_changes.in_set(LongitudinalSystems::Limit));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vehicles::follow_laws::Idm;

    fn idm() -> FollowLaw {
        FollowLaw::Idm(Idm { speed: 30.0, ..Idm::default() })
    }

    fn around(leader: Option<Seen>, target_leader: Option<Seen>, target_follower: Option<Seen>) -> Surroundings {
        Surroundings {
            me: Seen { s: 0.0, speed: 20.0 },
            length: 4.0,
            leader,
            follower: None,
            target_leader,
            target_follower,
        }
    }

    fn decide(p: &LaneChangeParams, side: Side, a: &Surroundings) -> MobilDecision {
        let law = idm();
        mobil_decision(&mobil_for(p, side, ChangeKind::Discretionary, 0.0), a, |v, l| law.accel(v, l))
    }

    #[test]
    fn mobil_changes_towards_the_faster_lane_only() {
        let p = LaneChangeParams { keep_right: false, ..LaneChangeParams::default() };
        let slow = Some(Seen { s: 30.0, speed: 10.0 });
        // Behind a slow leader with a free target lane: a positive incentive, change.
        let go = decide(&p, Side::Left, &around(slow, None, None));
        assert!(matches!(go, MobilDecision::Change(g) if g > p.threshold), "{go:?}");
        // The other way round (free now, slow leader there): the incentive is negative, stay.
        let stay = decide(&p, Side::Left, &around(None, slow, None));
        assert!(matches!(stay, MobilDecision::NoGain(g) if g < 0.0), "{stay:?}");
    }

    #[test]
    fn mobil_refuses_a_gap_whose_new_follower_would_brake_harder_than_safe() {
        let p = LaneChangeParams::default();
        let slow = Some(Seen { s: 30.0, speed: 10.0 });
        // A fast follower 8 m behind in the target lane: it would have to brake hard.
        let fast_close = Some(Seen { s: -12.0, speed: 30.0 });
        let d = decide(&p, Side::Left, &around(slow, None, fast_close));
        assert!(matches!(d, MobilDecision::Unsafe(a) if a < -p.safe_deceleration), "{d:?}");
        // The same follower 150 m back: safe, change.
        let far = Some(Seen { s: -150.0, speed: 30.0 });
        assert!(matches!(decide(&p, Side::Left, &around(slow, None, far)), MobilDecision::Change(_)));
    }

    #[test]
    fn keep_right_makes_left_harder_and_right_easier() {
        let p = LaneChangeParams::default();
        let left = mobil_for(&p, Side::Left, ChangeKind::Discretionary, 0.0);
        let right = mobil_for(&p, Side::Right, ChangeKind::Discretionary, 0.0);
        assert!(left.threshold > p.threshold && right.threshold < p.threshold);
        assert!((left.threshold - right.threshold - 2.0 * KEEP_RIGHT_BIAS).abs() < 1e-12);
        // On a free road both lanes give the same acceleration: only keep-right moves the car.
        let free = around(None, None, None);
        assert!(matches!(decide(&p, Side::Right, &free), MobilDecision::Change(_)));
        assert!(matches!(decide(&p, Side::Left, &free), MobilDecision::NoGain(_)));
        let symmetric = LaneChangeParams { keep_right: false, ..p };
        assert!(matches!(decide(&symmetric, Side::Right, &free), MobilDecision::NoGain(_)));
    }

    #[test]
    fn mandatory_urgency_grows_towards_the_end_and_widens_the_accepted_gap() {
        assert_eq!(urgency(1000.0, 20.0), 0.0);
        assert_eq!(urgency(5.0, 20.0), 1.0);
        let mut last = -1.0;
        for r in (0..=200).rev().map(|r| r as f64) {
            let u = urgency(r, 20.0);
            assert!(u >= last, "urgency falls nearer the end at {r} m");
            last = u;
        }
        let p = LaneChangeParams::default();
        // The threshold (keep-right bias included) falls to 0 at the end, under a constant
        // bonus of b_safe for leaving a lane that does not lead to the destination.
        let far = mobil_for(&p, Side::Left, ChangeKind::Mandatory, 0.0);
        let near = mobil_for(&p, Side::Left, ChangeKind::Mandatory, 1.0);
        assert!(near.threshold < far.threshold, "{far:?} {near:?}");
        assert_eq!(near.threshold, -p.safe_deceleration);
        assert_eq!(far.threshold, p.threshold + KEEP_RIGHT_BIAS - p.safe_deceleration);
        assert!(near.safe_deceleration > far.safe_deceleration);
        assert_eq!(near.safe_deceleration, p.safe_deceleration);
        // A gap whose new follower brakes at 3 m/s²: refused far from the end, taken near it.
        let law = idm();
        let mut gap = 1.0;
        while law.accel(20.0, Some((gap, 20.0))) < -3.0 {
            gap += 0.05;
        }
        let a = around(None, None, Some(Seen { s: -(gap + 4.0), speed: 20.0 }));
        let decide_at =
            |u| mobil_decision(&mobil_for(&p, Side::Right, ChangeKind::Mandatory, u), &a, |v, l| law.accel(v, l));
        assert!(matches!(decide_at(0.0), MobilDecision::Unsafe(_)), "{:?}", decide_at(0.0));
        assert!(matches!(decide_at(1.0), MobilDecision::Change(_)), "{:?}", decide_at(1.0));
    }

    fn found(distance: f64, speed: f64) -> Found {
        Found { distance, speed, length: 4.0, id: VehicleId(9) }
    }

    #[test]
    fn the_target_gap_closes_when_a_follower_closes_in_or_a_leader_overlaps() {
        let law = idm();
        assert!(!target_gap_closed(&law, 4.0, 20.0, 4.0, Some(found(40.0, 20.0)), Some(found(40.0, 20.0))));
        assert!(target_gap_closed(&law, 4.0, 20.0, 4.0, None, Some(found(10.0, 30.0))), "fast follower 6 m behind");
        assert!(target_gap_closed(&law, 4.0, 20.0, 4.0, Some(found(3.0, 20.0)), None), "leader overlapping");
        assert!(!target_gap_closed(&law, 4.0, 20.0, 4.0, None, Some(found(10.0, 10.0))), "slow follower falls back");
    }
}

#[cfg(test)]
mod loop_tests {
    use super::*;
    use crate::map::LaneletMap;
    use crate::map::generate::{RingParams, ring_highway};

    #[test]
    fn a_change_onto_a_loop_projects_near_its_lanelet_as_over_the_whole_loop() {
        // Three lanes round a ring: every lanelet of every lane's loop, points along it and
        // beside it (within and across the lane), start and end of the lanelet included.
        let ring = RingParams { lanes: 3, radius: 400.0, lane_width: 3.5, clockwise: false, node_spacing: 20.0 };
        let map = LaneletMap::parse_str(&ring_highway(&ring).unwrap(), std::path::Path::new("ring")).unwrap();
        let lanes = LaneMap::new(Arc::new(map));
        let mut paths = LanePaths::new(0.5);
        let mut checked = 0;
        for j in 0..lanes.map.lanelets.len() as u32 {
            let path = paths.path_through(&lanes, j, &RouteGoal::Loop).expect("a ring lane is a loop");
            assert!(path.closed);
            let start = paths.loop_start(&lanes, j).expect("the loop through j knows where j starts");
            for f in [0.0, 0.25, 0.6, 0.999] {
                let s_j = f * lanes.length(j);
                let (point, heading) = lanes.centres[j as usize].sample(s_j);
                for offset in [-3.5, -1.2, 0.0, 1.6, 3.5] {
                    let p = point + offset * DVec2::new(-heading.sin(), heading.cos());
                    let near = loop_projection_near(&path, p, start + s_j);
                    let all = path.project(p);
                    assert_eq!(
                        (near.s.to_bits(), near.lateral.to_bits(), near.point),
                        (all.s.to_bits(), all.lateral.to_bits(), all.point),
                        "lanelet {j} at {s_j} m, {offset} m beside: near {near:?}, whole loop {all:?}"
                    );
                    checked += 1;
                }
            }
        }
        assert_eq!(paths.loops.len(), 3, "one loop a lane");
        assert!(checked >= 3 * 20, "{checked} points");
    }
}
