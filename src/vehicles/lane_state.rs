//! The state the lane-change plugin shares with the rest of the vehicle pipeline: each vehicle's
//! [`LaneChanger`] (its parameters, law, goal and the [`Manoeuvre`] in progress) and the per-tick
//! [`LaneIndex`] and [`LaneCrossings`]. The path follower and the leader search read these, the
//! plugin ([`super::lane_changing`]) writes them; keeping them here lets both depend on this file
//! instead of on each other.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::AtomicU32;
use std::sync::atomic::Ordering::Relaxed;

use bevy_ecs::lifecycle::HookContext;
use bevy_ecs::prelude::{Component, Entity, Resource};
use bevy_ecs::world::DeferredWorld;

use crate::map::{LaneletId, Path, Place};
use crate::world::{TurnSignal, VehicleId};

use super::follow_laws::{AdaptiveCruise, Idm, LeaderGap};
use super::lane_change::LaneChangeProfile;
use super::lanes::LaneMap;
use crate::sim::Parallelism;
use crate::sim::parallel::{CHUNKS_PER_THREAD, recycle};

/// How far the leader and follower searches look along the lane \[m\].
pub const SEARCH_HORIZON: f64 = 200.0;

/// `lane_change = { politeness, threshold, safe_deceleration, max_lateral_accel, keep_right,
/// cooperative, min_interval, manual }` (all optional, these defaults).
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct LaneChangeParams {
    /// MOBIL politeness p [-]: weight of the followers' acceleration changes.
    pub politeness: f64,
    /// MOBIL threshold Δa_th [m/s²]: the net gain a discretionary change must bring.
    pub threshold: f64,
    /// Safe deceleration b_safe [m/s²]: the new follower may not have to brake harder.
    pub safe_deceleration: f64,
    /// Largest lateral acceleration of the manoeuvre [m/s²] (sets its length).
    pub max_lateral_accel: f64,
    /// Asymmetric keep-right rule (European motorways).
    pub keep_right: bool,
    /// Open a gap (braking up to `safe_deceleration / 2`) for a neighbour that must change.
    pub cooperative: bool,
    /// Least time between two changes of one vehicle \[s\] (no ping-pong).
    pub min_interval: f64,
    /// Change lanes only when asked from outside (Python's `change_lane`, a learning agent such
    /// as `smlworld/HighwayMerge-v0`'s): no discretionary or mandatory change of its own. The
    /// safety check of a requested change still applies.
    pub manual: bool,
}

impl Default for LaneChangeParams {
    fn default() -> Self {
        LaneChangeParams {
            politeness: 0.2,
            threshold: 0.1,
            safe_deceleration: 4.0,
            max_lateral_accel: 1.5,
            keep_right: true,
            cooperative: true,
            min_interval: 4.0,
            manual: false,
        }
    }
}

impl LaneChangeParams {
    /// Check the values (keys relative to `lane_change`).
    pub fn check(&self) -> Result<(), crate::sim::params::ParamError> {
        use crate::sim::params::{MAX_ACCEL, MAX_TIME, Range, check_all};
        check_all([
            ("politeness", self.politeness, Range::between(0.0, 10.0)),
            ("threshold", self.threshold, Range::between(-MAX_ACCEL, MAX_ACCEL)),
            ("safe_deceleration", self.safe_deceleration, Range::positive(MAX_ACCEL)),
            ("max_lateral_accel", self.max_lateral_accel, Range::positive(MAX_ACCEL)),
            ("min_interval", self.min_interval, Range::non_negative(MAX_TIME)),
        ])
    }
}

/// The longitudinal law MOBIL evaluates (the vehicle's own).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FollowLaw {
    /// Treiber's IDM.
    Idm(Idm),
    /// Adaptive cruise control at a cruise speed [m/s].
    Acc(AdaptiveCruise, f64),
}

impl FollowLaw {
    /// Acceleration [m/s²] at speed `v` [m/s] behind `leader = (gap [m], speed [m/s])`.
    pub fn accel(&self, v: f64, leader: Option<(f64, f64)>) -> f64 {
        match self {
            FollowLaw::Idm(p) => p.acceleration(v, leader),
            FollowLaw::Acc(p, cruise) => {
                let gap = leader.map(|(gap, speed)| LeaderGap {
                    id: VehicleId(0),
                    distance: gap,
                    gap,
                    speed,
                    acceleration: 0.0,
                });
                p.acceleration(v, *cruise, gap.as_ref(), 0.0)
            }
        }
    }

    /// Desired speed [m/s].
    pub fn desired_speed(&self) -> f64 {
        match self {
            FollowLaw::Idm(p) => p.speed,
            FollowLaw::Acc(_, cruise) => *cruise,
        }
    }
}

/// Where a vehicle's route goes: round a loop, or to a place.
#[derive(Debug, Clone, PartialEq)]
pub enum RouteGoal {
    /// A closed loop: any lane of the loop will do.
    Loop,
    /// An open route to this place: only lanes that reach it will do.
    To(Place),
    /// An open route given lane by lane (a SUMO route): only the lanes it names as reaching on
    /// will do, and each lane drives the path it gives.
    Lanes(Arc<crate::map::LaneRoute>),
}

impl RouteGoal {
    pub(super) fn key(&self) -> String {
        match self {
            RouteGoal::Loop => String::new(),
            RouteGoal::To(p) => format!("{p:?}"),
            RouteGoal::Lanes(r) => format!("lanes:{}", r.key),
        }
    }
}

/// A side.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Side {
    /// To the left.
    Left,
    /// To the right.
    Right,
}

/// Why a change was made.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ChangeKind {
    /// MOBIL found it worth it.
    Discretionary,
    /// The lane does not lead to the destination.
    Mandatory,
    /// Asked for from outside (Python's `change_lane`).
    Requested,
}

/// A lane change in progress.
///
/// `repr(C)` with the one-byte fields first: `Option<Manoeuvre>`'s "none" lives in the first of
/// them, so the per-tick test for a change under way reads [`LaneChanger`]'s hot lines only.
#[derive(Debug, Clone, PartialEq)]
#[repr(C)]
pub struct Manoeuvre {
    /// Direction as first intended.
    pub direction: Side,
    /// Why.
    pub kind: ChangeKind,
    /// Whether it is being aborted (driving back).
    pub aborted: bool,
    /// Lanelet left (of the change as first intended).
    pub from: LaneletId,
    /// Lanelet aimed at (of the change as first intended).
    pub to: LaneletId,
    /// Lateral profile: the offset from the route goes from `start_offset` to 0.
    pub profile: LaneChangeProfile,
    /// Offset from the (new) route at the start \[m\], positive left.
    pub start_offset: f64,
    /// Arc length along the route where it began \[m\].
    pub s_start: f64,
    /// The route driven before (searched for leaders while crossing, and driven back to on an abort).
    pub old_route: Arc<Path>,
    /// Arc length along `old_route` \[m\].
    pub old_s: f64,
    /// Start time \[s\].
    pub t_start: f64,
    /// Largest lateral acceleration of the profile so far, v² |d''(s)| [m/s²].
    pub peak_lateral_accel: f64,
    /// Speed cap while changing [m/s] (the profile was sized for it).
    pub speed_cap: f64,
}

impl Manoeuvre {
    /// Distance driven since the start along `route` \[m\].
    pub fn driven(&self, route: &Path, s: f64) -> f64 {
        let d = s - self.s_start;
        if route.closed { d.rem_euclid(route.length) } else { d }
    }

    /// Offset from the route \[m\] (positive left) the path follower aims at, `s` along the route.
    pub fn offset_at(&self, route: &Path, s: f64) -> f64 {
        let d = self.driven(route, s);
        if route.closed && d > 0.5 * route.length {
            return self.start_offset;
        }
        self.start_offset + self.profile.offset_at(d)
    }
}

/// Per-vehicle lane-change state (the `lane_change` table of a scenario vehicle).
///
/// Laid out in field order (`repr(C)`): what [`decide_lane_changes`](super::lane_changing::decide_lane_changes)
/// reads or clears for every vehicle every control tick first (the first four cache lines, up to
/// and including whether a change is under way), what only a weighed gap or a manoeuvre reads
/// after (the goal, the law, the manoeuvre's body). In the compiler's order those fields lay
/// spread over all seven lines of the 392 bytes.
#[derive(Component, Debug, Clone, PartialEq)]
#[component(on_add = note_new_changer)]
#[repr(C)]
pub struct LaneChanger {
    /// Parameters.
    pub params: LaneChangeParams,
    /// End time of the last change \[s\].
    pub last_change: f64,
    /// Which lanelets reach the goal (looked up once, shared by every vehicle with this goal).
    pub(super) reach: Option<Arc<Vec<bool>>>,
    /// A slower vehicle in the target lane to fall behind while a mandatory change waits: (gap \[m\], speed [m/s]).
    pub virtual_leader: Option<(f64, f64)>,
    /// A neighbour signalling a mandatory change in our gap: (gap \[m\], speed [m/s]).
    pub yield_to: Option<(f64, f64)>,
    /// Road left \[m\] to the end of a lane the vehicle must leave (a mandatory change waits).
    pub lane_end: Option<f64>,
    /// While crossing: the vehicles ahead in both lanes, (gap \[m\], speed [m/s]) each.
    pub crossing_leaders: [Option<(f64, f64)>; 2],
    pub(super) wait_since: Option<f64>,
    /// A change asked for from outside, carried out when safe (cleared when done or refused).
    pub request: Option<Side>,
    /// A side no discretionary change may go to now, set each tick by a cooperative plugin (a
    /// vehicle does not move into the lane of an emergency vehicle coming up behind it).
    pub keep_out: Option<Side>,
    /// Whether the target lane's vehicles are asked to open a gap for `request` as for a
    /// mandatory change (cooperative plugins set it, e.g. making way for an emergency vehicle;
    /// Python's `change_lane` does not).
    pub signal_request: bool,
    /// Hold the plugin's own changes (mandatory and discretionary): a cooperative plugin that
    /// decides when to change sets it each tick and asks through `request` (GCDC merging).
    pub hold: bool,
    /// Abort the change in progress back to the old lane if it is not halfway yet (set by a
    /// cooperative plugin, taken once by the plugin).
    pub abort: bool,
    pub(super) missed: bool,
    /// `yield_to` is a neighbour we cannot pass (our own lane ends first): fall behind it at
    /// any braking, as before the lane's end.
    pub(super) hold_behind: bool,
    /// The change in progress.
    pub active: Option<Manoeuvre>,
    /// Where the route goes.
    pub goal: RouteGoal,
    /// The longitudinal law MOBIL evaluates.
    pub law: FollowLaw,
}

/// The vehicles a [`LaneChanger`] was added to since
/// [`find_reach`](super::lane_changing::find_reach) last took them (noted by the component's
/// `on_add` hook, where the [`LaneChangePlugin`](super::LaneChangePlugin) installed this list),
/// so that it need not test every vehicle's `Added` tick each control tick.
#[derive(Resource, Debug, Default)]
pub struct NewLaneChangers(pub Vec<Entity>);

/// `on_add` hook of [`LaneChanger`]: note the vehicle in [`NewLaneChangers`], if installed.
fn note_new_changer(mut world: DeferredWorld<'_>, context: HookContext) {
    if let Some(mut new) = world.get_resource_mut::<NewLaneChangers>() {
        new.0.push(context.entity);
    }
}

impl LaneChanger {
    /// Whether the lanelets that reach its goal have been looked up (at the first control tick
    /// that finds the vehicle on a lanelet, [`find_reach`](super::lane_changing::find_reach)):
    /// until then it makes no change.
    pub fn knows_its_goal_lanes(&self) -> bool {
        self.reach.is_some()
    }

    /// The leading bytes of a changer that the evaluation reads every control tick (every field
    /// up to and including the first byte of `active`).
    pub const HOT_BYTES: usize = std::mem::offset_of!(LaneChanger, active) + 1;

    /// The turn signal others see: on the side of the change in progress (an aborted change
    /// drives back, so the side it goes now), off without one.
    pub fn signal(&self) -> TurnSignal {
        match &self.active {
            None => TurnSignal::Off,
            Some(m) if (m.direction == Side::Left) != m.aborted => TurnSignal::Left,
            Some(_) => TurnSignal::Right,
        }
    }

    /// A vehicle that has not changed lanes yet.
    pub fn new(params: LaneChangeParams, law: FollowLaw, goal: RouteGoal) -> LaneChanger {
        LaneChanger {
            params,
            law,
            goal,
            request: None,
            active: None,
            last_change: f64::NEG_INFINITY,
            virtual_leader: None,
            yield_to: None,
            lane_end: None,
            crossing_leaders: [None; 2],
            keep_out: None,
            signal_request: false,
            hold: false,
            abort: false,
            wait_since: None,
            missed: false,
            hold_behind: false,
            reach: None,
        }
    }
}

/// Vehicles crossing between two lanes this tick: id -> (from, to). Leader searches count them
/// in both lanes.
#[derive(Resource, Debug, Clone, Default)]
pub struct LaneCrossings(pub BTreeMap<VehicleId, (LaneletId, LaneletId)>);

/// One vehicle in the [`LaneIndex`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IndexEntry {
    /// Lanelet index.
    pub lanelet: u32,
    /// Arc length along it \[m\].
    pub s: f64,
    /// Speed [m/s].
    pub speed: f64,
    /// Length \[m\].
    pub length: f64,
    /// Its id.
    pub id: VehicleId,
}

impl IndexEntry {
    /// An entry on no lanelet, which [`LaneIndex::rebuild`] leaves out.
    pub const NOT_ON_A_LANELET: IndexEntry =
        IndexEntry { lanelet: u32::MAX, s: 0.0, speed: 0.0, length: 0.0, id: VehicleId(0) };
}

/// `list.partition_point(|e| e.s < s)` for a lanelet's entries (sorted by arc length, the
/// lanelet 1 / `per_length` \[m\] long): the first entry at or after `s`. Traffic spreads along a
/// lanelet, so the place in proportion to `s / length` is a few entries off: walk from there (in
/// cache) instead of a binary search's dependent loads over the whole list; search the rest of
/// the list when the walk goes far (a queue, an empty stretch). The guess is a multiplication by
/// the length's inverse, not a division: it only picks where the exact search starts, and a
/// division (about 15 cycles) lay between the caller's lookup and the list's first load.
pub fn first_at_or_after(list: &[IndexEntry], s: f64, per_length: f64) -> usize {
    const WALK: usize = 8;
    let n = list.len();
    if n == 0 {
        return 0;
    }
    let guess = if per_length > 0.0 && per_length.is_finite() && s.is_finite() {
        ((s * per_length).clamp(0.0, 1.0) * n as f64) as usize
    } else {
        0
    };
    let mut k = guess.min(n);
    if k < n && list[k].s < s {
        // Forward: the answer lies after k.
        for _ in 0..WALK {
            k += 1;
            if k == n || list[k].s >= s {
                return k;
            }
        }
        k + 1 + list[k + 1..].partition_point(|e| e.s < s)
    } else {
        // Backward: the answer is at or before k.
        for _ in 0..WALK {
            if k == 0 || list[k - 1].s < s {
                return k;
            }
            k -= 1;
        }
        list[..k].partition_point(|e| e.s < s)
    }
}

/// The order of the [`LaneIndex`]: arc length, then id.
fn entry_order(x: &IndexEntry, y: &IndexEntry) -> std::cmp::Ordering {
    x.s.total_cmp(&y.s).then(x.id.cmp(&y.id))
}

/// Sort a lanelet's entries by [`entry_order`]. Vehicles come in spawn order, which along a lane
/// is mostly the order they drive in (a few overtake per tick): an insertion sort then costs a
/// comparison or two per entry instead of a full sort's log n. Past a budget of moves (input far
/// from sorted: traffic inserted at a route's start comes in reverse; past about 10 sim s of the
/// `--lane-change` bench several lanelets a tick) the rest is sorted fully, by the standard
/// library's stable sort, which merges the runs it finds already in order (a list of a few long
/// runs costs about a pass; an unstable sort cost a full sort each time: control 5 % slower in a
/// 30 s run), so the worst case stays O(n log n). The order is total (arc length, then id):
/// either sort gives the same list.
fn sort_nearly_sorted(list: &mut [IndexEntry]) {
    let budget = 4 * list.len() + 16;
    let mut moves = 0;
    for k in 1..list.len() {
        let mut j = k;
        while j > 0 && entry_order(&list[j - 1], &list[j]).is_gt() {
            list.swap(j - 1, j);
            j -= 1;
        }
        moves += k - j;
        if moves > budget {
            list.sort_by(entry_order);
            return;
        }
    }
}

/// Every vehicle by lanelet and arc length, built once per control tick: leader and follower
/// in any lane in O(log k) for k vehicles on a lanelet.
#[derive(Resource, Debug, Clone, Default)]
pub struct LaneIndex {
    entries: Vec<IndexEntry>,
    starts: Vec<u32>,
    /// Each lanelet's count, then where its next entry goes, while [`LaneIndex::rebuild`] fills
    /// `entries` on one thread.
    fill: Vec<u32>,
    /// The same per chunk of the items, while [`LaneIndex::rebuild`] fills `entries` over the
    /// threads ([`LaneIndex::scatters_split`]).
    chunk_fills: Vec<Vec<u32>>,
    /// The allocations of the chunks of the items and of the stretches of `entries` each chunk
    /// fills (slices: a pointer and a length), kept between ticks ([`recycle`]).
    spare: [Vec<(usize, usize)>; 2],
    /// Where each vehicle's entry went ([`Slots`]), for ids whose key is below a bound in
    /// proportion to the entries (the others are searched for as before); a vehicle gone reads
    /// a place that is not its own.
    slots: Slots,
}

/// Where vehicle `id`'s place is kept in [`Slots`]: ids of either sign (traffic's are
/// negative) interleaved, 0, -1, 1, -2, 2, ... as 0, 1, 2, 3, 4, ...
#[inline]
fn slot_key(id: VehicleId) -> usize {
    ((id.0 << 1) ^ (id.0 >> 31)) as u32 as usize
}

/// Most chunks [`LaneIndex::rebuild`] counts and places the items in side by side: those of
/// four threads (the most [`Parallelism::default`] uses).
const SCATTER_CHUNKS: usize = 4 * CHUNKS_PER_THREAD;

/// Most groups of lanelets [`LaneIndex::rebuild`] sorts side by side (as many).
const SORT_GROUPS: usize = 4 * CHUNKS_PER_THREAD;

/// Consecutive lanelets of the [`LaneIndex`] that one thread sorts: their entries and where each
/// lanelet's starts among them (plus the end), offset by the group's first entry.
#[derive(Default)]
struct SortGroup<'a> {
    entries: &'a mut [IndexEntry],
    starts: &'a [u32],
}

impl SortGroup<'_> {
    /// Sort each lanelet's entries, then note where each vehicle's entry went in `slots` (the
    /// group's entries start at `starts[0]` in the index).
    fn sort(&mut self, slots: &Slots) {
        let Some(&base) = self.starts.first() else { return };
        for w in self.starts.windows(2) {
            sort_nearly_sorted(&mut self.entries[(w[0] - base) as usize..(w[1] - base) as usize]);
        }
        for (k, e) in self.entries.iter().enumerate() {
            slots.note(e.id, base + k as u32);
        }
    }
}

/// By vehicle id ([`slot_key`]): where in the [`LaneIndex`]'s entries the last rebuild put an
/// entry of that vehicle. Written by the sorting threads side by side: a crossing vehicle's two
/// entries may lie in two groups, and either may be noted (relaxed atomic stores: plain stores
/// on x86-64). Only a hint, checked where it is read ([`LaneIndex::own_place`]).
#[derive(Debug, Default)]
struct Slots(Vec<AtomicU32>);

impl Clone for Slots {
    fn clone(&self) -> Slots {
        Slots(self.0.iter().map(|a| AtomicU32::new(a.load(Relaxed))).collect())
    }
}

impl Slots {
    /// Grow to hold the keys below `bound` (new places hold nothing).
    fn reach(&mut self, bound: usize) {
        if self.0.len() < bound {
            self.0.resize_with(bound, || AtomicU32::new(u32::MAX));
        }
    }

    #[inline]
    fn note(&self, id: VehicleId, place: u32) {
        if let Some(a) = self.0.get(slot_key(id)) {
            a.store(place, Relaxed);
        }
    }

    #[inline]
    fn get(&self, id: VehicleId) -> Option<usize> {
        self.0.get(slot_key(id)).map(|a| a.load(Relaxed) as usize)
    }
}

/// A vehicle found by the index: distance along the lane [m, centre to centre], speed, length.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Found {
    /// Distance along the lane from the asking position \[m\], positive.
    pub distance: f64,
    /// Speed [m/s].
    pub speed: f64,
    /// Length \[m\].
    pub length: f64,
    /// Id.
    pub id: VehicleId,
}

impl LaneIndex {
    /// Rebuild from `items` (in any order; an entry whose lanelet is not below `lanelets` is
    /// left out): a counting sort by lanelet, then each lanelet's entries by arc length and id,
    /// the lanelets' sorts split over `parallelism`'s threads in groups of consecutive lanelets
    /// (each lanelet's order depends on its entries only, so any split gives the same index).
    /// Allocation free once the buffers have grown.
    pub fn rebuild(&mut self, parallelism: Parallelism, lanelets: usize, items: &[IndexEntry]) {
        if LaneIndex::scatters_split(parallelism, lanelets, items.len()) {
            self.place_split(parallelism, lanelets, items);
        } else {
            self.place(lanelets, items);
        }
        // Noted by the sorting threads (a serial pass over every entry was as long as the sort).
        self.slots.reach((8 * self.entries.len()).max(1 << 12));
        self.sort(parallelism, lanelets);
    }

    /// Each lanelet's entries by [`entry_order`], over the threads in groups of lanelets.
    fn sort(&mut self, parallelism: Parallelism, lanelets: usize) {
        let LaneIndex { entries, starts, slots, .. } = self;
        let slots = &*slots;
        let acc = *starts.last().unwrap_or(&0);
        let threads = parallelism.threads_for(entries.len());
        let groups = (threads * CHUNKS_PER_THREAD).min(SORT_GROUPS).min(lanelets);
        if threads <= 1 || groups <= 1 {
            SortGroup { entries, starts }.sort(slots);
            return;
        }
        // Groups of consecutive lanelets of about equal entry counts, one a chunk.
        let mut parts: [SortGroup<'_>; SORT_GROUPS] = Default::default();
        let mut rest: &mut [IndexEntry] = entries;
        let mut first = 0;
        for (g, part) in parts.iter_mut().enumerate().take(groups) {
            let end = if g + 1 == groups {
                lanelets
            } else {
                let target = (acc as usize * (g + 1) / groups) as u32;
                starts.partition_point(|&s| s < target).clamp(first, lanelets)
            };
            let len = (starts[end] - starts[first]) as usize;
            let (mine, others) = std::mem::take(&mut rest).split_at_mut(len);
            rest = others;
            *part = SortGroup { entries: mine, starts: &starts[first..=end] };
            first = end;
        }
        Parallelism::split(threads).for_each_chunk(&mut parts[..groups], &mut Vec::<()>::new(), |chunk, _| {
            for part in chunk {
                part.sort(slots);
            }
        });
    }

    /// Whether [`LaneIndex::rebuild`] counts and places `items` entries over the threads: with
    /// more than one, and many entries per lanelet and chunk (each chunk keeps a count per
    /// lanelet, and the counts are summed up on one thread).
    pub(crate) fn scatters_split(parallelism: Parallelism, lanelets: usize, items: usize) -> bool {
        let chunks = parallelism.chunks_for(items);
        parallelism.threads_for(items) > 1 && chunks <= SCATTER_CHUNKS && lanelets * chunks * 4 <= items
    }

    /// `items` by lanelet into `entries` (in the items' order within each lanelet), each
    /// lanelet's start in `starts` (then the end): a counting sort on this thread.
    fn place(&mut self, lanelets: usize, items: &[IndexEntry]) {
        let LaneIndex { entries, starts, fill, .. } = self;
        // Each lanelet's count in `fill`, then where its entries start.
        fill.clear();
        fill.resize(lanelets, 0);
        for e in items {
            if let Some(c) = fill.get_mut(e.lanelet as usize) {
                *c += 1;
            }
        }
        starts.clear();
        let mut acc = 0;
        for c in fill.iter_mut() {
            starts.push(acc);
            acc += std::mem::replace(c, acc);
        }
        starts.push(acc);
        // Every place is written below: no need to clear what the last tick left.
        entries.resize(acc as usize, IndexEntry::NOT_ON_A_LANELET);
        for e in items {
            if let Some(k) = fill.get_mut(e.lanelet as usize) {
                entries[*k as usize] = *e;
                *k += 1;
            }
        }
    }

    /// [`LaneIndex::place`] over the threads, with the same result: the items cut into chunks,
    /// each chunk's entries counted per lanelet on its own, then (on this thread) each chunk
    /// given a stretch of each lanelet's place, after the earlier chunks' (so within a lanelet
    /// the entries keep the items' order), and each chunk's entries written into its stretches.
    /// On the `--lane-change` bench the one-thread counting and placing took 6 ms a run.
    fn place_split(&mut self, parallelism: Parallelism, lanelets: usize, items: &[IndexEntry]) {
        let LaneIndex { entries, starts, chunk_fills, spare, .. } = self;
        let threads = Parallelism::split(parallelism.threads_for(items.len()));
        let size = items.len().div_ceil(parallelism.chunks_for(items.len()).max(1));
        let mut parts: Vec<&[IndexEntry]> = recycle(std::mem::take(&mut spare[0]));
        parts.extend(items.chunks(size.max(1)));
        let chunks = parts.len();
        if chunk_fills.len() < chunks {
            chunk_fills.resize_with(chunks, Vec::new);
        }
        let fills = &mut chunk_fills[..chunks];
        // Each chunk's count per lanelet.
        let mut counting: [(&[IndexEntry], Option<&mut Vec<u32>>); SCATTER_CHUNKS] = Default::default();
        for ((job, part), counts) in counting.iter_mut().zip(&parts).zip(fills.iter_mut()) {
            *job = (part, Some(counts));
        }
        threads.for_each_chunk(&mut counting[..chunks], &mut Vec::<()>::new(), |jobs, _| {
            for (part, counts) in jobs.iter_mut() {
                let Some(counts) = counts.as_deref_mut() else { continue };
                counts.clear();
                counts.resize(lanelets, 0);
                for e in part.iter() {
                    if let Some(c) = counts.get_mut(e.lanelet as usize) {
                        *c += 1;
                    }
                }
            }
        });
        // Lanelet after lanelet, chunk after chunk: where each stretch starts.
        starts.clear();
        let mut acc = 0u32;
        for l in 0..lanelets {
            starts.push(acc);
            for counts in fills.iter_mut() {
                acc += std::mem::replace(&mut counts[l], acc);
            }
        }
        starts.push(acc);
        // Every place is written below: no need to clear what the last tick left.
        entries.resize(acc as usize, IndexEntry::NOT_ON_A_LANELET);
        // The stretches, chunk k's of lanelet l at k * lanelets + l.
        let mut cut: Vec<&mut [IndexEntry]> = recycle(std::mem::take(&mut spare[1]));
        cut.resize_with(chunks * lanelets, Default::default);
        let mut rest: &mut [IndexEntry] = entries;
        for l in 0..lanelets {
            for k in 0..chunks {
                let end = if k + 1 < chunks { fills[k + 1][l] } else { starts[l + 1] };
                let (piece, others) = std::mem::take(&mut rest).split_at_mut((end - fills[k][l]) as usize);
                cut[k * lanelets + l] = piece;
                rest = others;
            }
        }
        let mut placing: [(&[IndexEntry], &mut [&mut [IndexEntry]]); SCATTER_CHUNKS] = Default::default();
        let mut left: &mut [&mut [IndexEntry]] = &mut cut;
        for (job, part) in placing.iter_mut().zip(&parts) {
            let (mine, others) = std::mem::take(&mut left).split_at_mut(lanelets);
            *job = (part, mine);
            left = others;
        }
        threads.for_each_chunk(&mut placing[..chunks], &mut Vec::<()>::new(), |jobs, _| {
            for (part, places) in jobs.iter_mut() {
                for e in part.iter() {
                    if let Some(place) = places.get_mut(e.lanelet as usize) {
                        let (first, rest) = std::mem::take(place).split_first_mut().expect("counted");
                        *first = *e;
                        *place = rest;
                    }
                }
            }
        });
        spare[1] = recycle(cut);
        spare[0] = recycle(parts);
    }

    /// `first_at_or_after(self.on(i), s, ..)` read from `me`'s own entry instead of searched
    /// for, when `me` has an entry at arc length `s` on lanelet `i` (a vehicle asking about its
    /// own lane: the leader search of every vehicle, every control tick). Entries before it at
    /// the same arc length (smaller ids) are walked back over. `None`: search.
    #[inline]
    fn own_place(&self, i: u32, s: f64, me: VehicleId) -> Option<usize> {
        let k = self.slots.get(me)?;
        let e = self.entries.get(k)?;
        // `!=` also turns a NaN `s` away.
        if e.id != me || e.lanelet != i || e.s != s {
            return None;
        }
        let start = *self.starts.get(i as usize)? as usize;
        let list = &self.entries[start..=k];
        let mut k = k - start;
        while k > 0 && list[k - 1].s.partial_cmp(&s) != Some(std::cmp::Ordering::Less) {
            k -= 1;
        }
        Some(k)
    }

    /// The first of lanelet `i`'s entries (`list`) at or after arc length `s`: at `me`'s own
    /// entry when it is there ([`LaneIndex::own_place`]), else searched for.
    #[inline]
    fn start_of(&self, lanes: &LaneMap, list: &[IndexEntry], i: u32, s: f64, me: VehicleId) -> usize {
        self.own_place(i, s, me).unwrap_or_else(|| first_at_or_after(list, s, lanes.per_length(i)))
    }

    /// Fetch `me`'s own entry into the cache ahead of its [`LaneIndex::ahead_where`] (a hint).
    #[inline]
    pub fn prefetch_own(&self, me: VehicleId) {
        if let Some(k) = self.slots.get(me)
            && k < self.entries.len()
        {
            crate::world::prefetch_bytes(self.entries.as_ptr().wrapping_add(k).cast(), size_of::<IndexEntry>());
        }
    }

    /// The lanelet (map index) vehicle `id` was indexed on, `None` when it is not in the index.
    /// O(1) where its slot is kept, else a scan of the entries.
    pub fn lanelet_of(&self, id: VehicleId) -> Option<u32> {
        if let Some(e) = self.slots.get(id).and_then(|k| self.entries.get(k)).filter(|e| e.id == id) {
            return Some(e.lanelet);
        }
        self.entries.iter().find(|e| e.id == id).map(|e| e.lanelet)
    }

    pub(crate) fn on(&self, i: u32) -> &[IndexEntry] {
        let i = i as usize;
        if i + 1 >= self.starts.len() {
            return &[];
        }
        &self.entries[self.starts[i] as usize..self.starts[i + 1] as usize]
    }

    /// Nearest vehicle at or ahead of arc length `s` on lanelet `i` (then its first successors),
    /// other than `me`, within [`SEARCH_HORIZON`].
    pub fn ahead(&self, lanes: &LaneMap, i: u32, s: f64, me: VehicleId) -> Option<Found> {
        self.ahead_where(lanes, i, s, me, |_| true)
    }

    /// [`LaneIndex::ahead`] among the vehicles for which `seen(id)` holds (e.g. those the
    /// sensors detect).
    pub fn ahead_where(
        &self,
        lanes: &LaneMap,
        i: u32,
        s: f64,
        me: VehicleId,
        seen: impl Fn(VehicleId) -> bool,
    ) -> Option<Found> {
        self.ahead_along(lanes, i, s, me, &[], seen)
    }

    /// [`LaneIndex::ahead_where`] past the end of lanelet `i` along `route` (lanelet ids in
    /// driving order, [`LaneMap::next_on`]); an empty route takes the first successors.
    pub fn ahead_along(
        &self,
        lanes: &LaneMap,
        mut i: u32,
        s: f64,
        me: VehicleId,
        route: &[LaneletId],
        seen: impl Fn(VehicleId) -> bool,
    ) -> Option<Found> {
        // Distance from the asking point to the start of lanelet `i` (after the first one).
        let mut base = 0.0;
        let mut first = true;
        for _ in 0..8 {
            let list = self.on(i);
            let from = if first { self.start_of(lanes, list, i, s, me) } else { 0 };
            // Distance to an entry at arc length `at` of this lanelet (or of a sibling).
            let distance = |at: f64| if first { at - s } else { base + at };
            let on_i = list[from..].iter().find(|e| e.id != me && seen(e.id));
            let mut nearest = on_i.map(|e| (distance(e.s), e));
            // Where lanes diverge, a car on a sibling near its start is still in the way.
            for &(k, overlap) in lanes.siblings(i) {
                let list = self.on(k);
                let at = if first { first_at_or_after(list, s, lanes.per_length(k)) } else { 0 };
                let far = nearest.map_or(f64::INFINITY, |(d, _)| d);
                let e = list[at..].iter().take_while(|e| e.s < overlap).find(|e| e.id != me && seen(e.id));
                if let Some(e) = e.filter(|e| distance(e.s) < far) {
                    nearest = Some((distance(e.s), e));
                }
            }
            if let Some((distance, e)) = nearest {
                return Some(Found { distance, speed: e.speed, length: e.length, id: e.id });
            }
            base = if first { lanes.length(i) - s } else { base + lanes.length(i) };
            first = false;
            if base > SEARCH_HORIZON {
                return None;
            }
            i = lanes.next_on(i, route)?;
        }
        None
    }

    /// Nearest vehicle behind arc length `s` on lanelet `i` (then its first predecessors),
    /// other than `me`, within [`SEARCH_HORIZON`].
    pub fn behind(&self, lanes: &LaneMap, mut i: u32, s: f64, me: VehicleId) -> Option<Found> {
        // Distance from the asking point back to the end of lanelet `i` (after the first one).
        let mut base = 0.0;
        let mut first = true;
        for _ in 0..8 {
            let list = self.on(i);
            let end = if first { self.start_of(lanes, list, i, s, me) } else { list.len() };
            if let Some(e) = list[..end].iter().rev().find(|e| e.id != me) {
                let distance = if first { s - e.s } else { base + lanes.length(i) - e.s };
                return Some(Found { distance, speed: e.speed, length: e.length, id: e.id });
            }
            base = if first { s } else { base + lanes.length(i) };
            first = false;
            if base > SEARCH_HORIZON {
                return None;
            }
            i = *lanes.predecessors[i as usize].first()?;
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_index_is_the_same_on_any_thread_count_and_leaves_out_entries_on_no_lanelet() {
        // 40 lanelets, 3,300 entries in scrambled order, some on no lanelet; then fewer entries
        // (the buffers shrink) on fewer lanelets.
        let scrambled = |n: usize, lanelets: usize| -> Vec<IndexEntry> {
            (0..n)
                .map(|k| IndexEntry {
                    lanelet: if k % 97 == 0 { u32::MAX } else { (k * 7919 % lanelets) as u32 },
                    s: ((k * 104_729) % 1000) as f64 * 0.5,
                    speed: k as f64,
                    length: 4.0,
                    id: VehicleId(k as i32),
                })
                .collect()
        };
        let mut many: Vec<LaneIndex> = vec![LaneIndex::default(); 4];
        for (n, lanelets) in [(3300, 40), (500, 5), (3001, 1), (3000, 700)] {
            let items = scrambled(n, lanelets);
            let mut one = LaneIndex::default();
            one.rebuild(Parallelism::single(), lanelets, &items);
            let mut seen = 0;
            for i in 0..lanelets as u32 {
                let list = one.on(i);
                assert!(list.iter().all(|e| e.lanelet == i), "lanelet {i}");
                assert!(list.is_sorted_by(|a, b| entry_order(a, b).is_le()), "lanelet {i} sorted");
                seen += list.len();
            }
            assert_eq!(seen, items.iter().filter(|e| e.lanelet != u32::MAX).count(), "all on a lanelet, once");
            // Counted and placed over the threads where each chunk has many entries per lanelet.
            let split = |threads| LaneIndex::scatters_split(Parallelism::split(threads), lanelets, n);
            assert_eq!([2, 3, 4].map(split), [lanelets < 500; 3], "{n} entries on {lanelets} lanelets");
            for (index, threads) in many.iter_mut().zip([2, 3, 4, 8]) {
                index.rebuild(Parallelism::split(threads), lanelets, &items);
                for i in 0..lanelets as u32 {
                    assert_eq!(index.on(i), one.on(i), "{threads} threads, lanelet {i} of {lanelets}");
                }
                assert!(index.on(lanelets as u32).is_empty());
            }
        }
    }

    #[test]
    fn what_every_tick_reads_of_a_lane_changer_lies_in_its_first_four_cache_lines() {
        use std::mem::offset_of;
        // (offset, size) of every field the evaluation reads or clears for every vehicle.
        let hot = [
            (offset_of!(LaneChanger, params), size_of::<LaneChangeParams>()),
            (offset_of!(LaneChanger, last_change), 8),
            (offset_of!(LaneChanger, reach), 8),
            (offset_of!(LaneChanger, virtual_leader), 24),
            (offset_of!(LaneChanger, yield_to), 24),
            (offset_of!(LaneChanger, lane_end), 16),
            (offset_of!(LaneChanger, crossing_leaders), 48),
            (offset_of!(LaneChanger, wait_since), 16),
            (offset_of!(LaneChanger, request), 1),
            (offset_of!(LaneChanger, keep_out), 1),
            (offset_of!(LaneChanger, hold), 1),
            (offset_of!(LaneChanger, abort), 1),
            (offset_of!(LaneChanger, missed), 1),
            (offset_of!(LaneChanger, hold_behind), 1),
            // Whether a change is under way: `Option<Manoeuvre>`'s "none" is in its first byte.
            (offset_of!(LaneChanger, active), 1),
        ];
        // All within what the decisions prefetch (`HOT_BYTES`), and that within four lines.
        for (k, (offset, size)) in hot.into_iter().enumerate() {
            assert!(offset + size <= LaneChanger::HOT_BYTES, "field {k} at {offset}..{}", offset + size);
        }
        const { assert!(LaneChanger::HOT_BYTES <= 256, "the hot bytes within four cache lines") };
        let none: Option<Manoeuvre> = None;
        let first = |m: &Option<Manoeuvre>| unsafe { *(m as *const Option<Manoeuvre>).cast::<u8>() };
        let some = Some(Manoeuvre {
            direction: Side::Left,
            kind: ChangeKind::Discretionary,
            aborted: false,
            from: LaneletId(1),
            to: LaneletId(2),
            profile: super::super::lane_change::LaneChangeProfile { offset: 3.5, length: 40.0 },
            start_offset: 3.5,
            s_start: 0.0,
            old_route: Arc::new(Path::from_points(vec![LaneletId(1)], vec![glam::DVec2::ZERO, glam::DVec2::X], false)),
            old_s: 0.0,
            t_start: 0.0,
            peak_lateral_accel: 0.0,
            speed_cap: 20.0,
        });
        let other = Some(Manoeuvre { direction: Side::Right, aborted: true, ..some.clone().unwrap() });
        assert!(first(&none) != first(&some) && first(&none) != first(&other), "none is told in the first byte");
    }

    fn entry(s: f64) -> IndexEntry {
        IndexEntry { lanelet: 0, s, speed: 0.0, length: 4.0, id: VehicleId(0) }
    }

    #[test]
    fn nearly_sorted_lists_sort_like_a_full_sort() {
        // Sorted, a few swapped neighbours, reversed, shuffled, equal arc lengths (ids decide).
        let make = |s: &[f64]| -> Vec<IndexEntry> {
            s.iter()
                .enumerate()
                .map(|(k, &s)| IndexEntry { lanelet: 0, s, speed: 0.0, length: 4.0, id: VehicleId(-(k as i32) % 7) })
                .collect()
        };
        let sorted: Vec<f64> = (0..500).map(|k| k as f64 * 0.5).collect();
        let mut swapped = sorted.clone();
        for k in (3..490).step_by(17) {
            swapped.swap(k, k + 2);
        }
        let reversed: Vec<f64> = sorted.iter().rev().copied().collect();
        let shuffled: Vec<f64> = (0..500).map(|k| ((k * 7919) % 500) as f64 * 0.25).collect();
        let ties = vec![3.0; 40];
        // Two sorted runs, the second before the first: the vehicles that came round a loop.
        let rotated: Vec<f64> = sorted[350..].iter().chain(&sorted[..350]).copied().collect();
        for case in [sorted, swapped, reversed, shuffled, ties, rotated, Vec::new(), vec![1.0]] {
            let mut got = make(&case);
            let mut want = got.clone();
            want.sort_unstable_by(entry_order);
            sort_nearly_sorted(&mut got);
            assert_eq!(got, want, "{case:?}");
        }
    }

    #[test]
    fn a_vehicles_own_entry_gives_the_place_a_search_finds() {
        // 6 lanelets; ids of both signs, several vehicles at the same arc length (the ones with
        // smaller ids sort first and count as ahead), a crossing vehicle with an entry on two
        // lanelets, an id past the slots' bound. Built on one thread and on two.
        let mut items: Vec<IndexEntry> = (0..600)
            .map(|k: i32| IndexEntry {
                lanelet: (k * 7 % 6) as u32,
                s: ((k * 37) % 50) as f64 * 2.0,
                speed: 1.0,
                length: 4.0,
                id: VehicleId(if k % 2 == 0 { -1 - k } else { k }),
            })
            .collect();
        items.push(IndexEntry { lanelet: 3, s: 10.0, ..items[5] });
        items.push(IndexEntry { lanelet: 2, s: 10.0, id: VehicleId(i32::MIN), ..items[0] });
        items.push(IndexEntry { lanelet: 2, s: 10.0, id: VehicleId(i32::MAX), ..items[0] });
        for threads in [1, 2] {
            let mut index = LaneIndex::default();
            index.rebuild(Parallelism::split(threads), 6, &items);
            let mut found = 0;
            for e in &items {
                let list = index.on(e.lanelet);
                let want = list.partition_point(|x| x.s < e.s);
                match index.own_place(e.lanelet, e.s, e.id) {
                    Some(k) => {
                        assert_eq!(k, want, "{e:?} on {threads} threads");
                        found += 1;
                    }
                    // Only the crossing vehicle's other entry and the ids past the bound.
                    None => assert!(e.id == items[5].id || e.id.0.unsigned_abs() > 1 << 20, "{e:?}"),
                }
                // Elsewhere, or at another arc length: no place (the caller searches).
                assert_eq!(index.own_place((e.lanelet + 1) % 6, e.s, e.id), None);
                assert_eq!(index.own_place(e.lanelet, e.s + 0.5, e.id), None);
                assert_eq!(index.own_place(e.lanelet, f64::NAN, e.id), None);
            }
            assert_eq!(found, 600, "every vehicle with one entry and a small id, once");
            assert!(list_has_ties(&index), "the case of equal arc lengths is covered");
            // A vehicle with no entry: none.
            assert_eq!(index.own_place(0, 0.0, VehicleId(5000)), None);
        }
    }

    fn list_has_ties(index: &LaneIndex) -> bool {
        (0..6).any(|i| index.on(i).windows(2).any(|w| w[0].s == w[1].s))
    }

    #[test]
    fn first_at_or_after_is_the_partition_point_for_spread_queued_and_empty_lanes() {
        let mut state = 12345u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let length = 500.0;
        for case in 0..200 {
            // Spread over the lanelet, queued in one stretch, with repeated positions, or empty.
            let n = case % 60;
            let mut list: Vec<IndexEntry> = (0..n)
                .map(|k| match case % 3 {
                    0 => entry(next() * length),
                    1 => entry(400.0 + next() * 20.0),
                    _ => entry((k / 3) as f64 * 10.0),
                })
                .collect();
            list.sort_by(|a, b| a.s.total_cmp(&b.s));
            for q in 0..50 {
                let s = match q % 4 {
                    0 => next() * length,
                    1 => list.get(q % list.len().max(1)).map_or(0.0, |e| e.s),
                    2 => -5.0 + next() * 10.0,
                    _ => length - 5.0 + next() * 10.0,
                };
                let want = list.partition_point(|e| e.s < s);
                assert_eq!(first_at_or_after(&list, s, 1.0 / length), want, "case {case}, s {s}, n {n}");
            }
        }
        // A NaN position (never from the index, but a caller's bug must not panic): like the
        // binary search, the first entry.
        let nan = f64::NAN;
        assert_eq!(first_at_or_after(&[entry(1.0)], nan, 1.0 / length), [entry(1.0)].partition_point(|e| e.s < nan));
    }
}
