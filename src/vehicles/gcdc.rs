//! GCDC 2016 cooperative merging over V2V: two platoons, one on a lane that ends, zip into one.
//!
//! A roadside unit ([`Rsu`], `[[rsu]] at = { .. }, range = 300.0, message = "merge_zone"`: a
//! fixed wifi sender, not a vehicle) announces the merge zone at every wifi round; a vehicle with
//! the `gcdc` controller ([`GcdcVehicle`]) takes part from the moment it hears it. With
//! `role = "auto"` the vehicle whose lane ends (a neighbour lane goes on farther) merges, the
//! others make gaps. Every participant broadcasts a [`GcdcMessage`] (the iCLCM fields of
//! GCDC 2016: `id, platoon_id, lane, distance_to_merge_zone, speed, accel, mio, forward_pair,
//! backward_pair, merge_request, stom, merging, head, tail`) at every control tick; the newest
//! leaves at each wifi round, so loss and delay of the channel act on the protocol.
//!
//! Each control tick, before the lane changes ([`GcdcSystems`]), every participant:
//! 1. pairs: from the broadcasts heard in the last [`LOST_AFTER`] (and itself) it computes the
//!    zipper order after the merge and its pairs in it ([`zipper_order`], [`pairs_in`]): a merger's
//!    forward pair is the gap maker that will be ahead of it, its backward pair the one behind;
//!    a pair counts as formed when both name each other (acknowledged both ways). A partner not
//!    heard for [`LOST_AFTER`] drops out of the zipper, and the next vehicle becomes the pair;
//! 2. gap maker: follows its forward pair (the merger, projected into its lane) as a virtual
//!    leader at the rear safe gap, which opens the gap to its real predecessor, and announces STOM
//!    when both gaps are safe (`stom`, [`keep_stom`]);
//! 3. merger: follows its forward pair virtually at the front safe gap, and asks the lane-change
//!    plugin ([`super::lane_changing`]) for the change once its backward pair announces STOM and
//!    its own check of both gaps passes ([`merge_action`]); it asks for an abort when STOM or its
//!    pairs go, or a gap collapses. The lane-change plugin's own safety check and abort rule
//!    stay in force. Mergers hold back the plugin's own mandatory changes
//!    ([`LaneChanger::hold`]) until [`LAST_RESORT`] before the lane's end;
//! 4. after the merge both drive CACC (the gap law of `platoon`, with the predecessor's
//!    broadcast acceleration as feed-forward) behind their new predecessors: one platoon.
//!
//! [`MergeLog`] measures it for `summary.json` `metrics.merge`. The rules are pure functions in
//! [`super::gcdc_protocol`]; sources and departures from the 2015 code are documented there.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use bevy_ecs::prelude::{Component, Local, Query, Res, ResMut, Resource};
use bevy_ecs::schedule::{IntoScheduleConfigs, SystemSet};
use glam::DVec2;

use crate::sim::v2v::channel::{Draw, LinkState};
use crate::sim::{Control, ControlEpoch, Plugin, SimBuilder, SimClock, SimSeed, SimSystems, V2vConfig, V2vStats, Wifi};
use crate::world::{BatchRef, Channel, Mailbox, Message, Payload, Route, VehicleId, VehicleSize, VehicleState};

use super::acc::AdaptiveCruise;
use super::gcdc_protocol::{
    GapPlan, GapRule, MergeAction, MergeView, Pairs, Participant, is_zipper, keep_stom, merge_action, pairs_in,
    ready_point, zipper_order,
};
use super::lane_changing::{LaneChangeSystems, LaneChanger, LaneIndex, Side, neighbour};
use super::lanes::{LaneMap, LanePosition};
use super::longitudinal::{LeaderGap, Longitudinal, LongitudinalSystems, install_longitudinal};
use super::path_following::PathFollower;
use super::platoon::Platooning;

/// A participant not heard for this long is lost \[s\] (ten wifi rounds at 10 Hz: a lossy channel
/// does not end a pair, a vehicle that left does).
pub const LOST_AFTER: f64 = 1.0;
/// A merger gives the decision back to the lane-change plugin's mandatory change this far before
/// the end of its lane \[m\] (the protocol failed; better merge somewhere than stop).
pub const LAST_RESORT: f64 = 60.0;
/// Virtual following keeps this much more than the safe gap \[m\], so STOM does not flicker at
/// the threshold.
pub const GAP_MARGIN: f64 = 3.0;
/// Hardest braking a virtual leader may ask for [m/s²] (comfortable; the real leader may ask
/// for more).
pub const VIRTUAL_DECELERATION: f64 = 1.5;
/// The gaps are planned to be open this far before the end of the ending lane \[m\]: the merges
/// themselves (a lane change of a few seconds, STOM and the checks) and [`LAST_RESORT`] need
/// that road.
pub const READY_ROOM: f64 = 180.0;
/// A gap is opened over at least this much road \[m\] (a pair formed late, or no lane end known).
pub const MIN_PLAN_LENGTH: f64 = 150.0;
/// Wifi draws of the roadside units (see [`Draw::stream`]).
const RSU_STREAM: u64 = 0x5253_5530; // "RSU0"

/// Role of a `gcdc` vehicle (`controller.role`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// Decided when the merge zone is heard: the vehicle whose lane ends merges.
    #[default]
    Auto,
    /// Stays in its lane and opens a gap for its forward pair.
    GapMaker,
    /// Changes into the other lane behind its forward pair, in front of its backward pair.
    Merger,
}

/// `controller.merge = { safe_gap, gap_rule, speed }`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct MergeParams {
    /// Minimum safe gap \[m\] under the speed-dependent 2015 gaps (front `max(safe_gap,
    /// 0.27 v^1.5)`, rear `max(safe_gap, 0.23 v^1.5)`); raising it opens wider gaps.
    pub safe_gap: f64,
    /// The gaps a merger needs (see [`GapRule`]): `"sml2015"` (default) or `{ time_gap [s],
    /// standstill [m] }`; longer gaps are safer and cost the traffic more.
    pub gap_rule: GapRule,
    /// Cruise speed [m/s] from the moment the merge zone is heard (default: keep `speed`): the
    /// slower platoon catches up with the other's speed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub speed: Option<f64>,
}

impl Default for MergeParams {
    fn default() -> Self {
        MergeParams { safe_gap: 10.0, gap_rule: GapRule::Sml2015, speed: None }
    }
}

impl MergeParams {
    /// Check the values (keys relative to `merge`): `safe_gap` (0, 1e3] m, `gap_rule` (see
    /// [`GapRule::check`]), `speed` [0, 1e3] m/s.
    pub fn check(&self) -> Result<(), crate::sim::params::ParamError> {
        use crate::sim::params::{MAX_SPEED, Range};
        Range::positive(1e3).check("safe_gap", self.safe_gap)?;
        self.gap_rule.check()?;
        match self.speed {
            Some(s) => Range::non_negative(MAX_SPEED).check("speed", s),
            None => Ok(()),
        }
    }
}

/// What a roadside unit says (`message = "merge_zone"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum RsuKind {
    /// The merge zone starts here: the GCDC 2016 scenario 1 start signal.
    MergeZone,
    /// The intersection zone is here: the GCDC 2016 scenario 2 start signal, read by
    /// [`super::gcdc_intersection`] (the unit stands at the junction).
    IntersectionZone,
}

/// A roadside unit: a fixed wifi sender.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rsu {
    /// Sender id of its messages (not a vehicle: ids from `i32::MIN` up).
    pub id: VehicleId,
    /// Where it stands \[m\] (for `merge_zone`: the start of the zone).
    pub position: DVec2,
    /// Its own wifi range \[m\], inclusive.
    pub range: f64,
    /// What it says.
    pub message: RsuKind,
}

/// A roadside unit's broadcast.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RsuMessage {
    /// What it says.
    pub message: RsuKind,
    /// Where the zone starts \[m\].
    pub at: DVec2,
}

/// The roadside units of the scenario.
#[derive(Resource, Debug, Clone, Default)]
pub struct Rsus(pub Vec<Rsu>);

/// The most important object: the vehicle ahead the radar follows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mio {
    /// Its id.
    pub id: VehicleId,
    /// Bumper-to-bumper range \[m\].
    pub range: f64,
    /// Range rate [m/s] (its speed minus ours).
    pub range_rate: f64,
}

/// What every participant broadcasts on wifi (GCDC 2016 iCLCM, as data).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GcdcMessage {
    /// The sender.
    pub id: VehicleId,
    /// The platoon it drives in: the id of the first participant of its lane.
    pub platoon_id: VehicleId,
    /// Its lane, counted from the right (1 = right-most).
    pub lane: u8,
    /// Distance along the road to the merge zone \[m\] (negative inside it; NaN before it heard the
    /// roadside unit).
    pub distance_to_merge_zone: f64,
    /// Speed [m/s].
    pub speed: f64,
    /// Acceleration asked for this tick [m/s²].
    pub accel: f64,
    /// The vehicle ahead its sensors follow.
    pub mio: Option<Mio>,
    /// The vehicle of the other lane that will be ahead of it after the merge.
    pub forward_pair: Option<VehicleId>,
    /// The vehicle of the other lane that will be behind it after the merge.
    pub backward_pair: Option<VehicleId>,
    /// It is a merger that has not merged yet.
    pub merge_request: bool,
    /// Safe to merge: the gap in front of it is open for its forward pair.
    pub stom: bool,
    /// It is changing lanes.
    pub merging: bool,
    /// First of its lane's participants.
    pub head: bool,
    /// Last of its lane's participants.
    pub tail: bool,
}

/// A broadcast heard, and what the receiver keeps about its sender.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Heard {
    /// When it was sent \[s\].
    pub sent: f64,
    /// The message.
    pub message: GcdcMessage,
    /// The sender merges (it asked to merge once; kept after it has merged).
    pub merger: bool,
}

/// A virtual leader: the forward pair projected into our lane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VirtualLeader {
    /// Its id.
    pub id: VehicleId,
    /// Bumper-to-bumper gap along the road \[m\] (negative: it is behind).
    pub gap: f64,
    /// Its speed [m/s].
    pub speed: f64,
    /// Its acceleration [m/s²].
    pub accel: f64,
    /// Gap to keep now \[m\]: on the way to the gap of the rule plus [`GAP_MARGIN`] ([`GapPlan`]).
    pub keep: f64,
    /// How fast the gap to keep grows [m/s] (the plan's relative speed).
    pub rate: f64,
}

/// Per-vehicle state of a `gcdc` vehicle.
#[derive(Component, Debug, Clone, PartialEq)]
#[require(Longitudinal)]
pub struct GcdcVehicle {
    /// Role (resolved from `auto` when the merge zone is heard).
    pub role: Role,
    /// CACC gap law (`time_gap`, gains, feed-forward).
    pub platoon: Platooning,
    /// Safe gaps and the speed in the merge zone.
    pub merge: MergeParams,
    /// Where the merge zone starts \[m\], once heard.
    pub zone: Option<DVec2>,
    /// Distance along the road to the zone \[m\] (NaN before it is heard).
    pub distance: f64,
    /// The other participants heard in the last [`LOST_AFTER`].
    pub heard: BTreeMap<VehicleId, Heard>,
    /// Its pairs now.
    pub pairs: Pairs,
    /// Both pairs name it back.
    pub acknowledged: bool,
    /// Gap maker: the gap for its forward pair is safe.
    pub stom: bool,
    /// Merger: not merged yet.
    pub merge_request: bool,
    /// Changing lanes now.
    pub merging: bool,
    /// When it merged \[s\] (mergers).
    pub merged: Option<f64>,
    /// Lane from the right (1 = right-most).
    pub lane: u8,
    /// First of its lane's participants.
    pub head: bool,
    /// Last of its lane's participants.
    pub tail: bool,
    /// The first participant of its lane.
    pub platoon_id: Option<VehicleId>,
    /// The forward pair as a virtual leader, while the two are in different lanes.
    pub virtual_leader: Option<VirtualLeader>,
    /// Merger: the side of the lane it merges into.
    pub merge_side: Option<Side>,
    /// Distance to the merge zone of the end of the lane that ends \[m\] (negative), once known.
    pub zone_end: Option<f64>,
    /// The plan of the gap to the forward pair, and that pair.
    pub plan: Option<(VehicleId, GapPlan)>,
    /// Arc length of the zone on the current route: (route identity, s [m]).
    zone_s: Option<(usize, f64)>,
    /// The abort of the change in progress was counted.
    abort_counted: bool,
}

impl GcdcVehicle {
    /// A vehicle that has not heard the merge zone yet.
    pub fn new(role: Role, platoon: Platooning, merge: MergeParams) -> GcdcVehicle {
        GcdcVehicle {
            role,
            platoon,
            merge,
            zone: None,
            distance: f64::NAN,
            heard: BTreeMap::new(),
            pairs: Pairs::default(),
            acknowledged: false,
            stom: false,
            merge_request: false,
            merging: false,
            merged: None,
            lane: 1,
            head: false,
            tail: false,
            platoon_id: None,
            virtual_leader: None,
            merge_side: None,
            zone_end: None,
            plan: None,
            zone_s: None,
            abort_counted: false,
        }
    }

    /// Whether it takes part (it heard the merge zone).
    pub fn active(&self) -> bool {
        self.zone.is_some()
    }

    /// The CACC gap law with the platoon's time gap.
    pub fn law(&self) -> AdaptiveCruise {
        let p = &self.platoon;
        AdaptiveCruise {
            time_gap: p.time_gap,
            standstill: p.standstill,
            gap_gain: p.gap_gain,
            speed_gain: p.speed_gain,
            cruise_gain: p.cruise_gain,
            max_acceleration: p.max_acceleration,
            max_deceleration: p.max_deceleration,
        }
    }
}

/// One merge, for `metrics.merge.merges`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct MergeEvent {
    /// The merger.
    pub id: VehicleId,
    /// When its lane change ended in the other lane \[s\].
    pub t: f64,
    /// Its forward pair then.
    pub forward_pair: Option<VehicleId>,
    /// Its backward pair then.
    pub backward_pair: Option<VehicleId>,
}

/// What the merge protocol measured.
#[derive(Resource, Debug, Clone, Default)]
pub struct MergeLog {
    /// Participants by id: (merger, arc length at the first tick \[m\] for their order in their
    /// lane, distance to the zone at the last tick \[m\]).
    pub participants: BTreeMap<VehicleId, (bool, f64, f64)>,
    /// Pairs acknowledged both ways, each once (lower id first).
    pub pairs: BTreeSet<(VehicleId, VehicleId)>,
    /// When the first pair formed \[s\].
    pub first_pair: Option<f64>,
    /// The merges, in order.
    pub merges: Vec<MergeEvent>,
    /// Smallest bumper-to-bumper gap of a participant to the vehicle ahead in its lane \[m\].
    pub min_gap: f64,
    /// Smallest time gap of the same \[s\] (above 1 m/s).
    pub min_time_gap: f64,
    /// Merges aborted back to the ending lane.
    pub aborted: usize,
    /// Whether any vehicle heard the merge zone.
    pub started: bool,
    /// Speeds of the participants from the announcement on.
    pub motion: BTreeMap<VehicleId, Motion>,
}

/// A participant's speeds from the merge zone's announcement on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Motion {
    /// Speed when the zone was announced (the first participant heard it) [m/s].
    pub announced: f64,
    /// Lowest speed since [m/s].
    pub lowest: f64,
    /// Hardest deceleration since [m/s²] (positive; speed change between control ticks).
    pub max_decel: f64,
    /// Speed and time at the last control tick ([m/s], \[s\]).
    pub last: (f64, f64),
}

/// `metrics.merge` of `summary.json`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct MergeSummary {
    /// Vehicles that had to merge (role merger).
    pub vehicles_to_merge: usize,
    /// Of which merged into the other lane.
    pub vehicles_merged: usize,
    /// Pairs acknowledged both ways (each once; a re-pairing adds one).
    pub pairs_formed: usize,
    /// From the first pair formed to the last merge \[s\] (0 when none merged).
    pub duration_s: f64,
    /// Smallest bumper-to-bumper gap between a participant and the vehicle ahead in its lane,
    /// from the merge zone's announcement on \[m\] (-1 when never measured).
    pub min_gap_m: f64,
    /// Smallest time gap of the same (gap / own speed, above 1 m/s) \[s\] (-1 when never measured).
    pub min_time_gap_s: f64,
    /// Whether every merger merged and the final order zips the two platoons, each in its order.
    pub zipper_order: bool,
    /// Merges aborted back to the ending lane.
    pub aborted: usize,
    /// Lowest speed of any participant over its speed when the merge zone was announced [-]
    /// (the first participant heard it; -1 when never measured).
    pub min_speed_ratio: f64,
    /// Hardest deceleration of any participant from the announcement on [m/s²] (speed change
    /// between control ticks).
    pub max_decel: f64,
    /// Extra travel time of the participants against the same run without platoon B \[s\]:
    /// the run is repeated without the mergers (`smlworld run` and the Python `run` do so; null
    /// elsewhere), and each gap maker's distance behind where it is at the end of that run is
    /// divided by its speed there, summed over the gap makers (the participants of both runs).
    pub delay_s: Option<f64>,
    /// The merges: `{ id, t, forward_pair, backward_pair }`.
    pub merges: Vec<MergeEvent>,
    /// The participants front to back at the end of the run.
    pub order: Vec<VehicleId>,
}

impl MergeLog {
    /// The summary, if any vehicle heard the merge zone.
    pub fn summary(&self) -> Option<MergeSummary> {
        if !self.started {
            return None;
        }
        let group = |merger: bool| {
            let mut g: Vec<(f64, VehicleId)> =
                self.participants.iter().filter(|p| p.1.0 == merger).map(|(id, p)| (-p.1, *id)).collect();
            g.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            g.into_iter().map(|(_, id)| id).collect::<Vec<_>>()
        };
        let (mergers, others) = (group(true), group(false));
        let mut order: Vec<(f64, VehicleId)> = self.participants.iter().map(|(id, p)| (p.2, *id)).collect();
        order.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let order: Vec<VehicleId> = order.into_iter().map(|(_, id)| id).collect();
        let merged: BTreeSet<VehicleId> = self.merges.iter().map(|m| m.id).collect();
        let last = self.merges.iter().map(|m| m.t).fold(f64::NEG_INFINITY, f64::max);
        let finite_or = |v: f64| if v.is_finite() { v } else { -1.0 };
        Some(MergeSummary {
            vehicles_to_merge: mergers.len(),
            vehicles_merged: merged.len(),
            pairs_formed: self.pairs.len(),
            duration_s: match self.first_pair {
                Some(t0) if last.is_finite() => (last - t0).max(0.0),
                _ => 0.0,
            },
            min_gap_m: finite_or(self.min_gap),
            min_time_gap_s: finite_or(self.min_time_gap),
            zipper_order: merged.len() == mergers.len() && is_zipper(&order, &mergers, &others),
            aborted: self.aborted,
            min_speed_ratio: self
                .motion
                .values()
                .filter(|m| m.announced > 1.0)
                .map(|m| m.lowest / m.announced)
                .reduce(f64::min)
                .unwrap_or(-1.0),
            max_decel: self.motion.values().map(|m| m.max_decel).fold(0.0, f64::max),
            delay_s: None,
            merges: self.merges.clone(),
            order,
        })
    }
}

impl MergeLog {
    /// `delay_s` of [`MergeSummary`]: the extra travel time \[s\] of the gap makers of this run
    /// (`self`) against `without_b`, the same run without the mergers: per gap maker, how far
    /// it is behind its place at the end of that run, divided by its speed there (at least
    /// 1 m/s); `None` when no gap maker is in both.
    pub fn delay_against(&self, without_b: &MergeLog) -> Option<f64> {
        let mut sum = None;
        for (id, &(merger, _, d)) in &self.participants {
            let Some(&(_, _, d_base)) = without_b.participants.get(id).filter(|_| !merger) else { continue };
            let v = without_b.motion.get(id).map_or(1.0, |m| m.last.0.max(1.0));
            if d.is_finite() && d_base.is_finite() {
                *sum.get_or_insert(0.0) += (d - d_base) / v;
            }
        }
        sum
    }
}

/// The GCDC systems of the [`Control`] schedule, before the lane changes.
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct GcdcSystems;

/// Every roadside unit's message goes to every mailbox within its range at each wifi round,
/// lost as the wifi channel loses messages (its loss model, per link; it is not delayed).
#[allow(clippy::too_many_arguments)]
pub fn broadcast_rsus(
    rsus: Res<Rsus>,
    config: Res<V2vConfig>,
    clock: Res<SimClock>,
    seed: Option<Res<SimSeed>>,
    epoch: Res<ControlEpoch>,
    stats: Res<V2vStats>,
    mut mailboxes: Query<(&VehicleState, &mut Mailbox)>,
    mut links: Local<BTreeMap<(i32, i32), LinkState>>,
) {
    let seed = seed.map_or(0, |s| s.0);
    let round = stats.wifi_rounds;
    let model = &config.wifi;
    for rsu in &rsus.0 {
        let payload = Payload::new(RsuMessage { message: rsu.message, at: rsu.position });
        let batch: Arc<[Message]> =
            Arc::from(vec![Message { sender: rsu.id, sent_at: clock.now, channel: Channel::Wifi, payload }]);
        let shared = BatchRef::new(&batch);
        for (state, mut mailbox) in &mut mailboxes {
            let distance = state.position.distance(rsu.position);
            if distance > rsu.range {
                continue;
            }
            let owner = mailbox.owner();
            let draw = Draw { seed, stream: RSU_STREAM, sender: rsu.id.0, receiver: owner.0, round, index: 0 };
            let link = links.entry((rsu.id.0, owner.0)).or_default();
            if model.deliver(&draw, clock.now.0, distance, rsu.range, link).is_some() {
                mailbox.wifi_in.deliver_picks(epoch.0, round, &shared, owner, std::iter::once(0));
            }
        }
    }
}

/// Road left [m] from arc length `s` of lanelet `i` to the end of its lane (following the first
/// successors; at most `horizon`).
fn lane_remaining(lanes: &LaneMap, i: u32, s: f64, horizon: f64) -> f64 {
    let mut left = lanes.length(i) - s;
    let mut j = i;
    for _ in 0..256 {
        if left > horizon {
            break;
        }
        match lanes.successors[j as usize].first() {
            Some(&k) if k != i => {
                left += lanes.length(k);
                j = k;
            }
            _ => break,
        }
    }
    left
}

/// The side to merge to when the lane of lanelet `i` ends before a neighbour lane one may change
/// into (the lane that ends merges), else `None`.
pub fn ending_lane_side(lanes: &LaneMap, i: u32, s: f64) -> Option<Side> {
    let horizon = 1e5;
    let own = lane_remaining(lanes, i, s, horizon);
    [Side::Right, Side::Left].into_iter().find(|&side| {
        super::lane_changing::allowed(lanes, i, side).is_some_and(|j| {
            let s_j = s * lanes.length(j) / lanes.length(i).max(1e-9);
            lane_remaining(lanes, j, s_j, horizon) > own + 1.0
        })
    })
}

/// Road left \[m\] from arc length `s` of lanelet `i` to the end of the lane that ends in the
/// merge: its own when it ends before a neighbour, else the nearer end of a neighbour lane that
/// ends before its own (a gap maker looking at the mergers' lane); `None` when no lane ends.
fn ending_lane_remaining(lanes: &LaneMap, i: u32, s: f64) -> Option<f64> {
    let horizon = 1e5;
    let own = lane_remaining(lanes, i, s, horizon);
    if ending_lane_side(lanes, i, s).is_some() {
        return Some(own);
    }
    [Side::Right, Side::Left]
        .into_iter()
        .filter_map(|side| {
            let j = neighbour(lanes, i, side)?;
            let s_j = s * lanes.length(j) / lanes.length(i).max(1e-9);
            Some(lane_remaining(lanes, j, s_j, horizon)).filter(|&r| r + 1.0 < own)
        })
        .reduce(f64::min)
}

/// Lane number from the right (1 = right-most) of lanelet `i`.
fn lane_number(lanes: &LaneMap, i: u32) -> u8 {
    let (mut n, mut j) = (1u8, i);
    while let Some(k) = neighbour(lanes, j, Side::Right) {
        n = n.saturating_add(1);
        j = k;
        if n > 16 {
            break;
        }
    }
    n
}

/// One participant's part of [`run_gcdc_protocol`].
type ProtocolItem<'a> = (
    &'a VehicleId,
    &'a VehicleState,
    &'a VehicleSize,
    &'a LanePosition,
    &'a Mailbox,
    &'a Route,
    &'a Longitudinal,
    bevy_ecs::prelude::Mut<'a, PathFollower>,
    bevy_ecs::prelude::Mut<'a, GcdcVehicle>,
    Option<bevy_ecs::prelude::Mut<'a, LaneChanger>>,
);

/// Read the broadcasts, pair, decide STOM and the merge (see the module documentation).
pub fn run_gcdc_protocol(
    clock: Res<SimClock>,
    lanes: Option<Res<LaneMap>>,
    mut log: ResMut<MergeLog>,
    mut vehicles: Query<ProtocolItem<'_>>,
) {
    let Some(lanes) = lanes else { return };
    let lanes = &*lanes;
    let t = clock.now.as_secs();
    for (id, state, size, pos, mailbox, route, lon, mut follower, mut g, mut changer) in &mut vehicles {
        let me = *id;
        let v = state.speed();
        if let std::collections::btree_map::Entry::Vacant(e) = log.participants.entry(me) {
            // Where it starts along its route (once; the path follower may not have run yet).
            e.insert((g.role == Role::Merger, route.0.project(state.position).s, f64::NAN));
        }
        for (sender, sent, m) in mailbox.received::<GcdcMessage>(Channel::Wifi) {
            let sent = sent.as_secs();
            let merger = g.heard.get(&sender).is_some_and(|h| h.merger) || m.merge_request;
            if g.heard.get(&sender).is_none_or(|h| h.sent <= sent) {
                g.heard.insert(sender, Heard { sent, message: *m, merger });
            }
        }
        g.heard.retain(|_, h| t - h.sent <= LOST_AFTER);
        let Some(i) = pos.on() else { continue };
        g.lane = lane_number(lanes, i);
        if g.zone.is_none()
            && let Some((_, _, m)) = mailbox.received::<RsuMessage>(Channel::Wifi).last()
        {
            g.zone = Some(m.at);
            log.started = true;
            let side = ending_lane_side(lanes, i, pos.s);
            if g.role == Role::Auto {
                g.role = if side.is_some() { Role::Merger } else { Role::GapMaker };
            }
            if g.role == Role::Merger {
                g.merge_side = side.or(if g.lane > 1 { Some(Side::Right) } else { Some(Side::Left) });
            }
            if let Some(speed) = g.merge.speed {
                follower.params.speed = speed;
            }
        }
        let Some(zone) = g.zone else { continue };
        // Distance to the zone along the current route (projected once per route).
        let key = Arc::as_ptr(&route.0) as usize;
        // On a new route (a lane change begins) the zone may lie behind the route's start, and
        // the path follower's arc length is still the old route's this tick: carry the distance
        // over from the last tick (it moved a control tick's worth, about 1 m), or it jumps and
        // the zipper, the pairs and the plans with it.
        let (s_zone, s_me) = match g.zone_s {
            Some((k, s)) if k == key => (s, follower.s),
            _ => {
                let s_me = route.0.project(state.position).s;
                let s = if g.distance.is_finite() { s_me + g.distance } else { route.0.project(zone).s };
                g.zone_s = Some((key, s));
                (s, s_me)
            }
        };
        g.distance = s_zone - s_me;
        if g.zone_end.is_none() {
            g.zone_end = Some(ending_lane_remaining(lanes, i, pos.s).map_or(f64::NAN, |rem| g.distance - rem));
        }
        let merger_role = g.role == Role::Merger;
        if let Some(p) = log.participants.get_mut(&me) {
            *p = (merger_role, p.1, g.distance);
        }

        // Merged: a merger whose change ended in the other lane.
        let active_change = changer.as_ref().and_then(|c| c.active.as_ref()).map(|m| m.aborted);
        if merger_role && g.merged.is_none() && active_change.is_none() && ending_lane_side(lanes, i, pos.s).is_none() {
            g.merged = Some(t);
            log.merges.push(MergeEvent { id: me, t, forward_pair: g.pairs.forward, backward_pair: g.pairs.backward });
        }
        match active_change {
            Some(true) if !g.abort_counted => {
                g.abort_counted = true;
                log.aborted += 1;
            }
            None => g.abort_counted = false,
            _ => {}
        }
        g.merging = active_change == Some(false);
        g.merge_request = merger_role && g.merged.is_none();

        // Pairs from the zipper of everyone heard.
        let gv: &GcdcVehicle = &g;
        let mut everyone: Vec<Participant> = gv
            .heard
            .iter()
            .filter(|(_, h)| h.message.distance_to_merge_zone.is_finite())
            .map(|(&id, h)| Participant { id, merger: h.merger, distance: h.message.distance_to_merge_zone })
            .collect();
        everyone.push(Participant { id: me, merger: merger_role, distance: gv.distance });
        let order = zipper_order(&everyone);
        let is_merger = |x: VehicleId| everyone.iter().any(|p| p.id == x && p.merger);
        let pairs = pairs_in(&order, me, is_merger);
        let heard = |x: VehicleId| gv.heard.get(&x).map(|h| h.message);
        let forward_ack = pairs.forward.is_none_or(|f| heard(f).is_some_and(|m| m.backward_pair == Some(me)));
        let backward_ack = pairs.backward.is_none_or(|b| heard(b).is_some_and(|m| m.forward_pair == Some(me)));
        if let Some(f) = pairs.forward
            && heard(f).is_some_and(|m| m.backward_pair == Some(me))
        {
            log.pairs.insert((me.min(f), me.max(f)));
            log.first_pair.get_or_insert(t);
        }

        // Head, tail and platoon id among the participants of our lane.
        let d_me = gv.distance;
        let ahead_in_lane = gv
            .heard
            .iter()
            .filter(|(_, h)| h.message.lane == gv.lane && h.message.distance_to_merge_zone.is_finite())
            .map(|(&id, h)| (h.message.distance_to_merge_zone, id));
        let (mut head, mut tail, mut first) = (true, true, (d_me, me));
        for (d, id) in ahead_in_lane {
            head &= d > d_me;
            tail &= d < d_me;
            if (d, id) < first {
                first = (d, id);
            }
        }

        // The forward pair as a virtual leader while it is in the other lane.
        let gap_to = |d: f64| d_me - d - size.length;
        let safe_gap = gv.merge.safe_gap;
        let rule = gv.merge.gap_rule;
        let d_end = gv.zone_end.filter(|e| e.is_finite());
        let mut plan = gv.plan;
        let virtual_leader = pairs.forward.and_then(|f| {
            let m = heard(f)?;
            let still_apart = if merger_role { gv.merged.is_none() } else { m.merge_request };
            if !still_apart {
                return None;
            }
            let gap = gap_to(m.distance_to_merge_zone);
            // The gap opens along a plan made when the pair formed (a new pair, a new plan).
            let p = match plan {
                Some((id, p)) if id == f => p,
                _ => {
                    let d_ready = ready_point(d_me, d_end, READY_ROOM, MIN_PLAN_LENGTH);
                    let p = GapPlan { d0: d_me, gap0: gap, d_ready };
                    plan = Some((f, p));
                    p
                }
            };
            let full = if merger_role { rule.front(v, safe_gap) } else { rule.rear(v, safe_gap) } + GAP_MARGIN;
            let (keep, rate) = p.keep(d_me, v, full);
            Some(VirtualLeader { id: f, gap, speed: m.speed, accel: m.accel, keep, rate })
        });
        if virtual_leader.is_none() {
            plan = None;
        }
        // Gap maker: STOM for a forward pair that still has to merge.
        let stom = match pairs.forward.and_then(heard).filter(|m| m.merge_request && !merger_role) {
            Some(m) if forward_ack => {
                let gap = gap_to(m.distance_to_merge_zone);
                let room = lon
                    .leader
                    .filter(|l| Some(l.id) != pairs.forward)
                    .map(|l| l.distance - (d_me - m.distance_to_merge_zone) - size.length);
                keep_stom(gv.stom, m.merging, gap, room, v, safe_gap, rule)
            }
            _ => false,
        };
        // Merger: what it sees of its pairs.
        let view = MergeView {
            acknowledged: forward_ack && backward_ack,
            stom: pairs.backward.is_none_or(|b| heard(b).is_some_and(|m| m.stom)),
            front_gap: pairs.forward.and_then(heard).map(|m| gap_to(m.distance_to_merge_zone)),
            rear_gap: pairs.backward.and_then(heard).map(|m| m.distance_to_merge_zone - d_me - size.length),
            speed: v,
            safe_gap,
            rule,
            merging: gv.merging,
            in_zone: d_me <= 0.0,
        };
        g.pairs = pairs;
        g.acknowledged = forward_ack && backward_ack;
        (g.head, g.tail, g.platoon_id) = (head, tail, Some(first.1));
        g.virtual_leader = virtual_leader;
        g.plan = plan;
        g.stom = stom;

        let Some(ch) = changer.as_mut() else { continue };
        if !merger_role || g.merged.is_some() {
            ch.hold = true;
            continue;
        }
        let remaining = if route.0.closed { f64::INFINITY } else { route.0.length - follower.s };
        ch.hold = remaining > LAST_RESORT;
        match merge_action(&view) {
            MergeAction::Merge => ch.request = g.merge_side,
            MergeAction::Abort => ch.abort = true,
            MergeAction::Wait | MergeAction::Continue => {}
        }
    }
}

/// The CACC of every participant: the gap law behind the real leader (feed-forward of its
/// broadcast acceleration) and behind the virtual one, the lower acceleration wins.
pub fn control_gcdc(mut vehicles: Query<(&VehicleState, &GcdcVehicle, &mut Longitudinal)>) {
    for (state, g, mut lon) in &mut vehicles {
        let v = state.speed();
        let law = g.law();
        let ff = |id: VehicleId| g.heard.get(&id).map_or(0.0, |h| g.platoon.feedforward_gain * h.message.accel);
        let cruise = lon.route_speed;
        let mut a = law.acceleration(v, cruise, lon.leader.as_ref(), lon.leader.map_or(0.0, |l| ff(l.id)));
        if let Some(vl) = g.virtual_leader {
            // Follow the planned gap, not the law's own (which may be wider than the plan now:
            // a pair side by side opens its gap along the plan, not by braking at once), with
            // the plan's growth as a relative speed.
            let extra = vl.keep - law.desired_gap(v);
            let leader = LeaderGap {
                id: vl.id,
                distance: vl.gap + extra,
                gap: vl.gap - extra,
                speed: vl.speed - vl.rate,
                acceleration: vl.accel,
            };
            let follow = law.acceleration(v, cruise, Some(&leader), g.platoon.feedforward_gain * vl.accel);
            a = a.min(follow.max(-VIRTUAL_DECELERATION));
        }
        lon.accel = a;
    }
}

/// Broadcast every participant's [`GcdcMessage`] with the acceleration finally asked for.
pub fn send_gcdc_messages(
    clock: Res<SimClock>,
    mut vehicles: Query<(&VehicleId, &VehicleState, &GcdcVehicle, &Longitudinal, &mut Mailbox)>,
) {
    for (&id, state, g, lon, mut mailbox) in &mut vehicles {
        let v = state.speed();
        let message = GcdcMessage {
            id,
            platoon_id: g.platoon_id.unwrap_or(id),
            lane: g.lane,
            distance_to_merge_zone: g.distance,
            speed: v,
            accel: if lon.accel.is_nan() { 0.0 } else { lon.accel },
            mio: lon.leader.map(|l| Mio { id: l.id, range: l.gap, range_rate: l.speed - v }),
            forward_pair: g.pairs.forward,
            backward_pair: g.pairs.backward,
            merge_request: g.merge_request,
            stom: g.stom,
            merging: g.merging,
            head: g.head,
            tail: g.tail,
        };
        mailbox.send_latest(Channel::Wifi, clock.now, message);
    }
}

/// Smallest gap and time gap of every active participant to the vehicle ahead in its lane (the
/// lane index counts a vehicle changing lanes in both).
pub fn measure_merge(
    clock: Res<SimClock>,
    lanes: Option<Res<LaneMap>>,
    index: Option<Res<LaneIndex>>,
    mut log: ResMut<MergeLog>,
    vehicles: Query<(&VehicleId, &VehicleState, &VehicleSize, &LanePosition, &GcdcVehicle)>,
) {
    let (Some(lanes), Some(index)) = (lanes, index) else { return };
    let t = clock.now.as_secs();
    for (id, state, size, pos, g) in &vehicles {
        // Speeds of every participant from the announcement on (the first one to hear it).
        if log.started {
            let v = state.speed();
            let m = log.motion.entry(*id).or_insert(Motion { announced: v, lowest: v, max_decel: 0.0, last: (v, t) });
            if t > m.last.1 {
                m.max_decel = m.max_decel.max((m.last.0 - v) / (t - m.last.1));
            }
            m.lowest = m.lowest.min(v);
            m.last = (v, t);
        }
        let Some(i) = pos.on().filter(|_| g.active()) else { continue };
        if let Some(f) = index.ahead(&lanes, i, pos.s, *id) {
            let gap = f.distance - 0.5 * (f.length + size.length);
            log.min_gap = log.min_gap.min(gap);
            let v = state.speed();
            if v > 1.0 {
                log.min_time_gap = log.min_time_gap.min(gap / v);
            }
        }
    }
}

/// GCDC merging: the roadside units and the `gcdc` vehicles (needs the lanes and the lane-change
/// plugin).
#[derive(Debug, Clone, Default)]
pub struct GcdcPlugin {
    /// The roadside units.
    pub rsus: Vec<Rsu>,
}

impl Plugin for GcdcPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        install_longitudinal(sim);
        sim.insert_resource(Rsus(self.rsus.clone()));
        sim.world_mut().insert_resource(MergeLog {
            min_gap: f64::INFINITY,
            min_time_gap: f64::INFINITY,
            ..MergeLog::default()
        });
        // After the wifi round (Communicate) of the same schedule: the sets are chained.
        sim.add_systems(Wifi, broadcast_rsus.in_set(SimSystems::Control));
        sim.configure_sets(Control, GcdcSystems.in_set(SimSystems::Control).before(LaneChangeSystems));
        sim.add_systems(Control, run_gcdc_protocol.in_set(GcdcSystems));
        sim.add_systems(Control, control_gcdc.in_set(LongitudinalSystems::Cooperate));
        sim.add_systems(Control, (send_gcdc_messages, measure_merge).in_set(LongitudinalSystems::Report));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_summary_counts_merges_and_checks_the_zipper() {
        let mut log = MergeLog { min_gap: 8.0, min_time_gap: 0.5, started: true, ..MergeLog::default() };
        // Mergers -1, -2 (start s 120, 100), others 1, 2 (start s 110, 90); final distances zip.
        for (id, merger, s, d) in [(-1, true, 120.0, 10.0), (-2, true, 100.0, 50.0), (1, false, 110.0, 30.0)] {
            log.participants.insert(VehicleId(id), (merger, s, d));
        }
        log.participants.insert(VehicleId(2), (false, 90.0, 70.0));
        log.pairs.extend([(VehicleId(-1), VehicleId(1)), (VehicleId(-2), VehicleId(1)), (VehicleId(-2), VehicleId(2))]);
        log.first_pair = Some(5.0);
        for (id, t) in [(-1, 12.0), (-2, 20.0)] {
            log.merges.push(MergeEvent { id: VehicleId(id), t, forward_pair: None, backward_pair: None });
        }
        let s = log.summary().expect("the log has a summary");
        assert_eq!((s.vehicles_to_merge, s.vehicles_merged, s.pairs_formed), (2, 2, 3));
        assert_eq!(s.duration_s, 15.0);
        assert!(s.zipper_order, "{:?}", s.order);
        // One merger did not merge: no zipper.
        log.merges.pop();
        assert!(!log.summary().expect("the log has a summary").zipper_order);
        assert!(MergeLog::default().summary().is_none(), "nobody heard the zone");
    }
}
