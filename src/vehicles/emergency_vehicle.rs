//! Emergency vehicles: a vehicle of class `emergency` broadcasts a beacon on wifi
//! ([`EmergencyBeacon`]: `emergency = true`, its id, lane, position); vehicles that yield to it
//! ([`YieldToEmergency`]) and hear it within `warning_range` behind them in its lane (or the lane
//! it is changing to) ask the lane-change plugin for a change to the right, which it carries out
//! when its safety check allows; a vehicle in the right-most lane, or whose change was refused,
//! moves aside inside its lane ([`LateralShift`]) and slows. Vehicles next to its lane do not
//! change into it while it comes up behind. Once it has passed, all return: the shift goes back
//! to 0, the speed limit is lifted and a vehicle that changed lanes for it asks to change back.
//!
//! Everything travels over the V2V mailboxes, so channel loss and delay act on it: a vehicle
//! reacts only to beacons it received, and keeps acting on the last one for [`BEACON_HOLD`].
//!
//! Source: the 2015 lab code (`scripts/sml_world_old/vehiclesupervisorymodule_old.py` of
//! marinarantanen/sml_world, `EmergencyVehicleSupervisoryModule`): its broadcasts carried an
//! emergency flag, vehicles noted it within 100 m, moved aside within 50 m (a sideways shift
//! inside their lane) and returned when it had passed. We depart where the road has more lanes:
//! one range (`[emergency] warning_range`, default 150 m) for both, because a lane change to the
//! right needs more road than a shift; the shift remains for the right-most lane. SUMO's
//! blue-light device (vehicles ahead within a reaction distance move aside to form a rescue lane)
//! does the same in spirit; like there, the figure that matters is the emergency vehicle's delay
//! against free flow ([`EmergencyLog`]).
//!
//! A vehicle that moved aside inside the emergency vehicle's own lane does not block it: the
//! emergency vehicle shifts to the other side of its lane (over the line by at most
//! [`PASS_SPILL`] where a lane lies there) and passes when the lateral clearance between the two
//! is at least [`PASS_CLEARANCE`] ([`pass_shift`], [`passable`]); a vehicle it cannot pass stays
//! its leader. `metrics.emergency.stuck_s` counts the time it drove below [`STUCK_SHARE`] of its
//! free speed.
//!
//! The decisions are pure functions ([`distance_along_lane`], [`yield_plan`], [`pass_shift`],
//! [`passable`]) beside the systems.

use std::collections::{BTreeMap, BTreeSet};

use bevy_ecs::prelude::{Component, Query, Res, ResMut, Resource, With, Without};
use bevy_ecs::schedule::{IntoScheduleConfigs, SystemSet};
use glam::DVec2;

use crate::map::LaneletId;
use crate::sim::{Control, Plugin, SimBuilder, SimClock, SimSystems};
use crate::world::{Channel, Mailbox, Route, SimTime, VehicleId, VehicleSize, VehicleState, Vehicles};

use super::lane_changing::{ChangeKind, LaneChangeSystems, LaneChanger, LaneIndex, Side};
use super::lanes::{LaneMap, LanePosition};
use super::longitudinal::{LeaderGap, Longitudinal, LongitudinalSystems, find_leaders, install_longitudinal};
use super::path_following::{LateralShift, PathFollower};

/// A received beacon is acted on for this long after it was sent \[s\] (a lost round or two does
/// not end a yield).
pub const BEACON_HOLD: f64 = 1.0;
/// Room kept to the lane's edge when moving aside \[m\].
pub const EDGE_MARGIN: f64 = 0.25;
/// Largest sideways shift inside the lane \[m\].
pub const MAX_SHIFT: f64 = 1.2;
/// A vehicle that moves aside slows to this share of its speed when it began to [-]: enough to
/// drop behind a neighbour alongside in the lane to the right, not so much that the gap it
/// needs there (its new follower closing in on it) grows long.
pub const SLOW_SHARE: f64 = 0.8;
/// Hardest braking used to slow while moving aside [m/s²].
pub const SLOW_DECELERATION: f64 = 1.5;
/// A vehicle that changed lanes for an emergency vehicle asks to change back for this long
/// after it has passed \[s\] (then MOBIL decides as usual).
pub const RETURN_WINDOW: f64 = 10.0;
/// Lateral clearance \[m\] the emergency vehicle needs to pass a vehicle inside its own lane
/// (footprints side by side, taken parallel).
pub const PASS_CLEARANCE: f64 = 0.5;
/// How far the emergency vehicle may reach over its lane's line to pass \[m\], where a lane lies
/// on that side (a rescue lane is made of both lanes' edges); 0 at the road's edge.
pub const PASS_SPILL: f64 = 0.6;
/// The emergency vehicle looks this far ahead in its lane for a vehicle to pass \[m\].
pub const PASS_LOOKAHEAD: f64 = 80.0;
/// Below this share of its free speed the emergency vehicle counts as stuck [-].
pub const STUCK_SHARE: f64 = 0.2;
/// An emergency vehicle this close to the end of its open route [m] has arrived.
const ARRIVED: f64 = 5.0;

/// `[emergency]` of a scenario file.
#[derive(Resource, Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct EmergencySettings {
    /// How far behind a vehicle an emergency vehicle makes it yield \[m\] (along the lane);
    /// raising it clears the lane earlier (and disturbs more traffic). The beacon must reach
    /// that far: set `[v2v.wifi] range` at least as high.
    pub warning_range: f64,
}

impl Default for EmergencySettings {
    fn default() -> Self {
        EmergencySettings { warning_range: 150.0 }
    }
}

impl EmergencySettings {
    /// Check the values (keys relative to `emergency`): `warning_range` (0, 1e5] m.
    pub fn check(&self) -> Result<(), crate::sim::params::ParamError> {
        use crate::sim::params::{MAX_DISTANCE, Range, check_all};
        check_all([("warning_range", self.warning_range, Range::positive(MAX_DISTANCE))])
    }
}

/// What an emergency vehicle broadcasts on wifi at every control tick (the newest leaves at each
/// wifi round).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EmergencyBeacon {
    /// Always `true`: the emergency flag of the 2015 broadcasts.
    pub emergency: bool,
    /// The sender.
    pub id: VehicleId,
    /// The lanelet it drives on.
    pub lane: LaneletId,
    /// The lanelet it is changing to, if it is changing lanes (the lane it will use).
    pub target_lane: Option<LaneletId>,
    /// Its position \[m\].
    pub position: DVec2,
    /// Its arc length along `lane` \[m\].
    pub s: f64,
    /// Its speed [m/s] (receivers extrapolate `s` by it).
    pub speed: f64,
}

/// Marks an emergency vehicle (class `emergency` of a scenario's `[[vehicles]]`).
#[derive(Component, Debug, Clone, Copy, PartialEq)]
#[require(LateralShift)]
pub struct EmergencyVehicle {
    /// Its desired speed [m/s]: free flow for the delay metric.
    pub desired_speed: f64,
}

/// A vehicle that makes way for emergency vehicles (`yield_to_emergency = true`).
#[derive(Component, Debug, Clone, Copy, PartialEq, Default)]
#[require(LateralShift)]
pub struct YieldToEmergency {
    /// The last beacon heard, and when it was sent \[s\].
    pub heard: Option<(f64, EmergencyBeacon)>,
    /// Whether it asked for a change to the right at the last tick.
    pub requested: bool,
    /// Speed to slow to while moving aside [m/s].
    pub slow_to: Option<f64>,
    /// It changed lanes for an emergency vehicle: ask to change back until this time \[s\].
    pub return_until: Option<f64>,
    /// Whether it has made way at least once (a change to the right, or a shift).
    pub yielded: bool,
}

/// What a vehicle does about an emergency vehicle this tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct YieldPlan {
    /// Ask the lane-change plugin for a change to the right.
    pub change_right: bool,
    /// Shift to the right inside the lane.
    pub move_aside: bool,
    /// Slow down (to drop behind a neighbour alongside in the lane to the right; the vehicles
    /// there are asked to open a gap as well).
    pub slow: bool,
}

/// Distance \[m\] along the lane from arc length `from_s` on lanelet `from` forward to `to_s` on
/// lanelet `to`, following `successor`, if `to` is reached within `horizon` \[m\] and the point
/// lies ahead (>= 0). `length(i)` is lanelet `i`'s length \[m\].
pub fn distance_along_lane(
    successor: impl Fn(u32) -> Option<u32>,
    length: impl Fn(u32) -> f64,
    from: u32,
    from_s: f64,
    to: u32,
    to_s: f64,
    horizon: f64,
) -> Option<f64> {
    let mut i = from;
    let mut base = -from_s;
    for _ in 0..64 {
        if i == to {
            let d = base + to_s;
            if (0.0..=horizon).contains(&d) {
                return Some(d);
            }
        }
        base += length(i);
        if base > horizon {
            return None;
        }
        i = successor(i)?;
    }
    None
}

/// The rule: a vehicle `ahead` \[m\] of an emergency vehicle in the lane it uses (`None`: not in
/// its way), within `range` \[m\], changes to the right when there is a lane there
/// (`right_lane`); it moves aside inside its lane and slows while its last request was `refused`, and
/// so does one with no lane to the right (the 2015 behaviour). One already `changing` lanes
/// just finishes.
pub fn yield_plan(ahead: Option<f64>, range: f64, right_lane: bool, changing: bool, refused: bool) -> YieldPlan {
    match ahead {
        Some(d) if d <= range && !changing => {
            YieldPlan { change_right: right_lane, move_aside: !right_lane || refused, slow: !right_lane || refused }
        }
        _ => YieldPlan::default(),
    }
}

/// Sideways shift \[m\] (negative: right) that moves a vehicle of `width` \[m\] to the right edge of
/// a lane of half width `half_width` \[m\], keeping [`EDGE_MARGIN`], at most [`MAX_SHIFT`].
pub fn aside_shift(half_width: f64, width: f64) -> f64 {
    -(half_width - 0.5 * width - EDGE_MARGIN).clamp(0.0, MAX_SHIFT)
}

/// Lateral clearance \[m\] between two vehicles in the same lane at offsets `offset_a`, `offset_b`
/// \[m\] from its centre line (positive left) with widths `width_a`, `width_b` \[m\] (negative:
/// they overlap side by side).
pub fn lateral_clearance(offset_a: f64, width_a: f64, offset_b: f64, width_b: f64) -> f64 {
    (offset_a - offset_b).abs() - 0.5 * (width_a + width_b)
}

/// Whether the emergency vehicle (offset `offset`, width `width`) passes a vehicle ahead in its
/// lane (offset `other_offset`, width `other_width`; all \[m\]) instead of following it: the
/// lateral clearance is at least [`PASS_CLEARANCE`].
pub fn passable(offset: f64, width: f64, other_offset: f64, other_width: f64) -> bool {
    lateral_clearance(offset, width, other_offset, other_width) >= PASS_CLEARANCE
}

/// The emergency vehicle's own shift \[m\] (positive left) to pass a vehicle ahead at
/// `other_offset` \[m\] of width `other_width` \[m\], in a lane of half width `half_width` \[m\],
/// its width `width` \[m\]: to the side the other left free, by what [`PASS_CLEARANCE`] needs
/// plus 0.1 m,
/// within the lane plus [`PASS_SPILL`] where `lane_left` / `lane_right` says a lane lies on that
/// side. `None` when that is not enough (it follows), or the other is not shifted (0.2 m).
pub fn pass_shift(
    other_offset: f64,
    other_width: f64,
    width: f64,
    half_width: f64,
    lane_left: bool,
    lane_right: bool,
) -> Option<f64> {
    if other_offset.abs() < 0.2 {
        return None;
    }
    let left = other_offset < 0.0;
    // 0.1 m more than the clearance: the path follower tracks a shift to a few centimetres.
    let needed = 0.5 * (width + other_width) + PASS_CLEARANCE + 0.1;
    let spill = if (left && lane_left) || (!left && lane_right) { PASS_SPILL } else { 0.0 };
    let room = (half_width - 0.5 * width + spill).max(0.0);
    let shift = (needed - other_offset.abs()).max(0.0);
    (shift <= room + 1e-9).then_some(if left { shift } else { -shift })
}

/// Clearance \[m\] between two vehicles at `a` and `b` (centres \[m\]) of sizes `size_a`, `size_b`,
/// seen along `a`'s heading `yaw_a` \[rad\], both taken as parallel (a highway): the larger of the
/// longitudinal and the lateral gap between the footprints, 0 when they overlap.
pub fn clearance(a: DVec2, yaw_a: f64, size_a: VehicleSize, b: DVec2, size_b: VehicleSize) -> f64 {
    let d = b - a;
    let h = DVec2::from_angle(yaw_a);
    let lon = d.dot(h).abs() - 0.5 * (size_a.length + size_b.length);
    let lat = h.perp_dot(d).abs() - 0.5 * (size_a.width + size_b.width);
    lon.max(lat).max(0.0)
}

/// One emergency vehicle's run, for `metrics.emergency`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EmergencyRun {
    /// First control tick seen \[s\].
    pub start: f64,
    /// Last control tick seen \[s\].
    pub last: f64,
    /// When it reached the end of its open route \[s\], if it did.
    pub arrived: Option<f64>,
    /// Distance driven \[m\] (its speed integrated over the control ticks, whatever lane).
    pub driven: f64,
    /// Desired speed [m/s].
    pub desired_speed: f64,
    /// Smallest clearance to any other vehicle \[m\].
    pub min_clearance: f64,
    /// Time below [`STUCK_SHARE`] of its desired speed \[s\].
    pub stuck: f64,
}

/// What the emergency-vehicle plugin measured.
#[derive(Resource, Debug, Clone, Default)]
pub struct EmergencyLog {
    /// Per emergency vehicle.
    pub runs: BTreeMap<VehicleId, EmergencyRun>,
    /// Vehicles that made way (changed to the right for it, or moved aside).
    pub yielded: BTreeSet<VehicleId>,
}

/// `metrics.emergency` of `summary.json` (the emergency vehicle with the lowest id).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct EmergencySummary {
    /// The emergency vehicle.
    pub id: VehicleId,
    /// Time it drove \[s\]: from the start to the end of its open route, or to the end of the run.
    pub travel_time_s: f64,
    /// Time the same distance takes alone at its desired speed \[s\].
    pub free_flow_time_s: f64,
    /// `travel_time_s - free_flow_time_s` \[s\]: what the traffic cost it.
    pub delay_s: f64,
    /// Smallest clearance between it and any other vehicle \[m\] (footprints taken parallel);
    /// -1 when no vehicle came within 40 m of it.
    pub min_clearance_m: f64,
    /// Vehicles that made way for it (changed to the right, or moved aside in their lane).
    pub vehicles_yielded: usize,
    /// Time it drove below 20 % ([`STUCK_SHARE`]) of its free speed \[s\].
    pub stuck_s: f64,
}

impl EmergencyLog {
    /// The summary of the emergency vehicle with the lowest id, if there is one.
    pub fn summary(&self) -> Option<EmergencySummary> {
        let (id, r) = self.runs.iter().next()?;
        let travel = r.arrived.unwrap_or(r.last) - r.start;
        let free = if r.desired_speed > 0.0 { r.driven / r.desired_speed } else { travel };
        Some(EmergencySummary {
            id: *id,
            travel_time_s: travel,
            free_flow_time_s: free,
            delay_s: travel - free,
            min_clearance_m: if r.min_clearance.is_finite() { r.min_clearance } else { -1.0 },
            vehicles_yielded: self.yielded.len(),
            stuck_s: r.stuck,
        })
    }
}

/// The emergency-vehicle systems, in [`SimSystems::Control`] before the lane changes.
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct EmergencySystems;

/// Every emergency vehicle queues its beacon on wifi and updates its run (distance, clearance).
#[allow(clippy::type_complexity)]
pub fn send_emergency_beacons(
    clock: Res<SimClock>,
    mut log: ResMut<EmergencyLog>,
    mut emergency: Query<(
        &VehicleId,
        &VehicleState,
        &VehicleSize,
        &LanePosition,
        &EmergencyVehicle,
        Option<&mut Mailbox>,
        Option<&LaneChanger>,
        Option<&Route>,
        Option<&PathFollower>,
    )>,
    others: Query<(&VehicleState, &VehicleSize), Without<EmergencyVehicle>>,
) {
    let t = clock.now.as_secs();
    let dt = clock.dt;
    for (id, state, size, pos, ev, mailbox, changer, route, follower) in &mut emergency {
        let run = log.runs.entry(*id).or_insert(EmergencyRun {
            start: t,
            last: t,
            arrived: None,
            driven: 0.0,
            desired_speed: ev.desired_speed,
            min_clearance: f64::INFINITY,
            stuck: 0.0,
        });
        if run.arrived.is_none() {
            run.driven += state.speed() * dt;
            if state.speed() < STUCK_SHARE * ev.desired_speed {
                run.stuck += dt;
            }
            run.last = t;
            if let (Some(r), Some(f)) = (route, follower)
                && !r.0.closed
                && r.0.length - f.s < ARRIVED
            {
                run.arrived = Some(t);
            }
            for (other, other_size) in &others {
                if other.position.distance_squared(state.position) < 40.0 * 40.0 {
                    let c = clearance(state.position, state.yaw, *size, other.position, *other_size);
                    run.min_clearance = run.min_clearance.min(c);
                }
            }
        }
        let (Some(mut mailbox), Some(lane)) = (mailbox, pos.lanelet) else { continue };
        let beacon = EmergencyBeacon {
            emergency: true,
            id: *id,
            lane,
            target_lane: changer.and_then(|c| c.active.as_ref()).map(|m| m.to),
            position: state.position,
            s: pos.s,
            speed: state.speed(),
        };
        mailbox.send_latest(Channel::Wifi, SimTime::from_secs(t), beacon);
    }
}

/// Every yielding vehicle reads its wifi in-box and applies [`yield_plan`]: a lane-change
/// request, a sideways shift and a speed limit, a keep-out side; and the return once passed.
#[allow(clippy::type_complexity)]
pub fn yield_to_emergency_vehicles(
    clock: Res<SimClock>,
    settings: Res<EmergencySettings>,
    lanes: Option<Res<LaneMap>>,
    mut log: ResMut<EmergencyLog>,
    mut vehicles: Query<
        (
            &VehicleId,
            &VehicleState,
            &VehicleSize,
            &LanePosition,
            &Mailbox,
            &mut YieldToEmergency,
            &mut LateralShift,
            Option<&mut LaneChanger>,
        ),
        Without<EmergencyVehicle>,
    >,
) {
    let Some(lanes) = lanes else { return };
    let lanes = &*lanes;
    let t = clock.now.as_secs();
    let range = settings.warning_range;
    let successor = |i: u32| lanes.successors[i as usize].first().copied();
    let length = |i: u32| lanes.length(i);
    let neighbour = |i: u32, side: Side| super::lane_changing::neighbour(lanes, i, side);
    for (id, state, size, pos, mailbox, mut y, mut shift, mut changer) in &mut vehicles {
        // The newest beacon received (one emergency vehicle at a time: the newest message).
        if let Some((_, sent, b)) =
            mailbox.received::<EmergencyBeacon>(Channel::Wifi).filter(|(_, _, b)| b.emergency).last()
        {
            y.heard = Some((sent.as_secs(), *b));
        }
        if y.heard.is_some_and(|(sent, _)| t - sent > BEACON_HOLD) {
            y.heard = None;
        }
        let changing = changer.as_ref().is_some_and(|c| c.active.is_some());
        if y.requested
            && let Some(m) = changer.as_ref().and_then(|c| c.active.as_ref())
            && m.direction == Side::Right
            && m.kind == ChangeKind::Requested
        {
            y.yielded = true;
            log.yielded.insert(*id);
            y.return_until = Some(f64::INFINITY);
        }
        let refused = y.requested && !changing;
        // Where the emergency vehicle is relative to us: ahead of it in the lane it uses, or
        // beside that lane with it behind.
        let mut ahead = None;
        let mut keep_out = None;
        if let (Some((sent, b)), Some(i)) = (y.heard, pos.on()) {
            let ev_s = b.s + b.speed * (t - sent).max(0.0);
            let own_length = lanes.map.lanelet_index(b.lane).map_or(1.0, |e| lanes.length(e as u32));
            for lane in [Some(b.lane), b.target_lane].into_iter().flatten() {
                let Some(e) = lanes.map.lanelet_index(lane).map(|e| e as u32) else { continue };
                // The target lanelet lies beside its own: the same share of its length.
                let ev_s = ev_s * lanes.length(e) / own_length.max(1e-9);
                let d = distance_along_lane(successor, length, e, ev_s, i, pos.s, range);
                if d.is_some() {
                    ahead = ahead.or(d);
                }
                for side in [Side::Left, Side::Right] {
                    if let Some(j) = neighbour(i, side) {
                        let s_j = pos.s * lanes.length(j) / lanes.length(i).max(1e-9);
                        if distance_along_lane(successor, length, e, ev_s, j, s_j, range).is_some() {
                            keep_out = Some(side);
                        }
                    }
                }
            }
        }
        let right_lane = pos.on().and_then(|i| neighbour(i, Side::Right)).is_some() && changer.is_some();
        let plan = yield_plan(ahead, range, right_lane, changing, refused);
        y.requested = false;
        if let Some(ch) = changer.as_mut() {
            ch.keep_out = keep_out;
            ch.signal_request = plan.change_right;
            if plan.change_right {
                ch.request = Some(Side::Right);
                y.requested = true;
            } else if ahead.is_none() && keep_out.is_none() && !changing {
                // It has passed (or is out of hearing): change back once, if asked for.
                match y.return_until {
                    Some(until) if until.is_infinite() => y.return_until = Some(t + RETURN_WINDOW),
                    Some(until) if t <= until => ch.request = Some(Side::Left),
                    _ => {}
                }
                if y.return_until.is_some_and(|until| t > until) {
                    y.return_until = None;
                }
            } else if changing
                && ch.active.as_ref().is_some_and(|m| m.direction == Side::Left && m.kind == ChangeKind::Requested)
            {
                y.return_until = None;
            }
        }
        if plan.move_aside {
            let half = pos.on().map_or(1.75, |i| lanes.half_widths[i as usize]);
            shift.0 = aside_shift(half, size.width);
            y.slow_to = if plan.slow { Some(y.slow_to.unwrap_or(SLOW_SHARE * state.speed())) } else { None };
            if !y.yielded {
                y.yielded = true;
                log.yielded.insert(*id);
            }
        } else {
            shift.0 = 0.0;
            y.slow_to = None;
        }
    }
}

/// Every emergency vehicle with a vehicle ahead in its lane that moved aside shifts to the free
/// side ([`pass_shift`]), and no longer follows a vehicle it clears by [`PASS_CLEARANCE`]
/// ([`passable`]): its leader becomes the next one it does not clear. O(1) lookups per
/// emergency vehicle.
#[allow(clippy::type_complexity)]
pub fn pass_shifted_vehicles(
    lanes: Option<Res<LaneMap>>,
    index: Option<Res<LaneIndex>>,
    registry: Res<Vehicles>,
    mut emergency: Query<
        (&VehicleId, &VehicleSize, &LanePosition, &mut LateralShift, &mut Longitudinal),
        With<EmergencyVehicle>,
    >,
    others: Query<(&VehicleSize, &LanePosition), Without<EmergencyVehicle>>,
) {
    let (Some(lanes), Some(index)) = (lanes, index) else { return };
    let lanes = &*lanes;
    for (id, size, pos, mut shift, mut lon) in &mut emergency {
        let Some(i) = pos.on() else { continue };
        let half = lanes.half_widths[i as usize];
        let other = |o: VehicleId| registry.get(o).and_then(|e| others.get(e).ok());
        // The lane index finds the others in its lane (this lanelet or the next ones): their
        // offsets are from the same lane's centre line.
        let clears =
            |o: VehicleId| other(o).is_some_and(|(sz, p)| passable(pos.offset, size.width, p.offset, sz.width));
        let ahead = index.ahead(lanes, i, pos.s, *id).filter(|f| f.distance <= PASS_LOOKAHEAD);
        let target = ahead.and_then(|f| other(f.id)).and_then(|(sz, p)| {
            let lane_left = super::lane_changing::neighbour(lanes, i, Side::Left).is_some();
            let lane_right = super::lane_changing::neighbour(lanes, i, Side::Right).is_some();
            pass_shift(p.offset, sz.width, size.width, half, lane_left, lane_right)
        });
        // Hold the shift while the vehicle just passed is still alongside.
        let alongside = index
            .behind(lanes, i, pos.s, *id)
            .filter(|f| f.distance <= 0.5 * (f.length + size.length) + 2.0)
            .and_then(|f| other(f.id))
            .is_some_and(|(_, p)| p.offset.abs() >= 0.2);
        shift.0 = match target {
            Some(t) => t,
            None if alongside => shift.0,
            None => 0.0,
        };
        if lon.leader.is_some_and(|l| clears(l.id)) {
            let next = index.ahead_where(lanes, i, pos.s, *id, |o| !clears(o));
            lon.leader = next.map(|f| LeaderGap {
                id: f.id,
                distance: f.distance,
                gap: f.distance - size.length,
                speed: f.speed,
                acceleration: 0.0,
            });
        }
    }
}

/// Slow the vehicles that move aside to their `slow_to` speed, braking at most
/// [`SLOW_DECELERATION`].
pub fn slow_for_emergency_vehicles(mut vehicles: Query<(&VehicleState, &YieldToEmergency, &mut Longitudinal)>) {
    for (state, y, mut lon) in &mut vehicles {
        if let Some(target) = y.slow_to {
            lon.limit((target - state.speed()).max(-SLOW_DECELERATION));
        }
    }
}

/// Emergency vehicles and yielding to them (needs the lanes and the lane-change plugin).
#[derive(Debug, Clone, Copy, Default)]
pub struct EmergencyVehiclePlugin {
    /// `[emergency]` of the scenario.
    pub settings: EmergencySettings,
}

impl Plugin for EmergencyVehiclePlugin {
    fn build(&self, sim: &mut SimBuilder) {
        install_longitudinal(sim);
        sim.insert_resource(self.settings);
        sim.world_mut().init_resource::<EmergencyLog>();
        sim.configure_sets(Control, EmergencySystems.in_set(SimSystems::Control).before(LaneChangeSystems));
        sim.add_systems(
            Control,
            (send_emergency_beacons, yield_to_emergency_vehicles).chain().in_set(EmergencySystems),
        );
        sim.add_systems(Control, slow_for_emergency_vehicles.in_set(LongitudinalSystems::Limit));
        sim.add_systems(Control, pass_shifted_vehicles.in_set(LongitudinalSystems::FindLeader).after(find_leaders));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Three lanelets of 100 m in a row: 0 -> 1 -> 2 (then nothing).
    fn along(from: u32, from_s: f64, to: u32, to_s: f64, horizon: f64) -> Option<f64> {
        distance_along_lane(|i| (i < 2).then_some(i + 1), |_| 100.0, from, from_s, to, to_s, horizon)
    }

    #[test]
    fn distance_along_the_lane_counts_forward_over_successors_only() {
        assert_eq!(along(0, 20.0, 0, 50.0, 150.0), Some(30.0));
        assert_eq!(along(0, 20.0, 1, 50.0, 150.0), Some(130.0));
        assert_eq!(along(0, 20.0, 2, 50.0, 150.0), None, "230 m: beyond the horizon");
        assert_eq!(along(1, 50.0, 0, 90.0, 150.0), None, "behind");
        assert_eq!(along(0, 50.0, 0, 20.0, 150.0), None, "behind on the same lanelet");
        // A ring of two lanelets: what is behind on the lanelet is ahead after a lap.
        let ring =
            |from, from_s, to, to_s| distance_along_lane(|i| Some(1 - i), |_| 100.0, from, from_s, to, to_s, 190.0);
        assert_eq!(ring(0, 50.0, 0, 20.0), Some(170.0));
    }

    #[test]
    fn vehicles_in_its_way_change_right_or_move_aside_and_others_do_nothing() {
        let change = YieldPlan { change_right: true, move_aside: false, slow: false };
        assert_eq!(yield_plan(Some(80.0), 150.0, true, false, false), change);
        // Refused last tick: keep asking, and move aside and slow meanwhile.
        let aside = YieldPlan { change_right: true, move_aside: true, slow: true };
        assert_eq!(yield_plan(Some(80.0), 150.0, true, false, true), aside);
        // Right-most lane: the 2015 behaviour, a shift inside the lane, and slow.
        let right_most = YieldPlan { change_right: false, move_aside: true, slow: true };
        assert_eq!(yield_plan(Some(80.0), 150.0, false, false, false), right_most);
        // Too far, not in its way, or already changing: nothing.
        assert_eq!(yield_plan(Some(151.0), 150.0, true, false, false), YieldPlan::default());
        assert_eq!(yield_plan(None, 150.0, true, false, true), YieldPlan::default());
        assert_eq!(yield_plan(Some(10.0), 150.0, true, true, false), YieldPlan::default());
    }

    #[test]
    fn moving_aside_keeps_a_margin_to_the_edge() {
        // A 4 m lane, a 1.7 m car: 2 - 0.85 - 0.25 = 0.9 m to the right.
        assert!((aside_shift(2.0, 1.7) + 0.9).abs() < 1e-12);
        assert_eq!(aside_shift(1.0, 2.5), 0.0, "no room: stay");
        assert_eq!(aside_shift(4.0, 1.7), -MAX_SHIFT);
    }

    #[test]
    fn clearance_is_the_gap_between_parallel_footprints() {
        let car = VehicleSize { length: 4.0, width: 2.0 };
        // 10 m ahead in the same lane: 10 - 4 = 6 m.
        assert!((clearance(DVec2::ZERO, 0.0, car, DVec2::new(10.0, 0.0), car) - 6.0).abs() < 1e-12);
        // Beside, 4 m apart: 4 - 2 = 2 m.
        assert!((clearance(DVec2::ZERO, 0.0, car, DVec2::new(1.0, 4.0), car) - 2.0).abs() < 1e-12);
        assert_eq!(clearance(DVec2::ZERO, 0.0, car, DVec2::new(1.0, 0.5), car), 0.0);
    }

    #[test]
    fn the_summary_reports_delay_against_free_flow() {
        let mut log = EmergencyLog::default();
        log.runs.insert(
            VehicleId(-1),
            EmergencyRun {
                start: 0.0,
                last: 60.0,
                arrived: None,
                driven: 1500.0,
                desired_speed: 30.0,
                min_clearance: 3.0,
                stuck: 1.5,
            },
        );
        log.yielded.extend([VehicleId(1), VehicleId(2)]);
        let s = log.summary().expect("the log has a summary");
        assert_eq!((s.travel_time_s, s.free_flow_time_s, s.delay_s), (60.0, 50.0, 10.0));
        assert_eq!((s.min_clearance_m, s.vehicles_yielded, s.stuck_s), (3.0, 2, 1.5));
    }

    #[test]
    fn it_passes_a_vehicle_moved_aside_when_the_lateral_clearance_is_half_a_metre() {
        // A 2 m wide emergency vehicle behind a 1.7 m car moved 0.9 m right in a 4 m lane.
        assert!((lateral_clearance(0.0, 2.0, -0.9, 1.7) + 0.95).abs() < 1e-12);
        assert!(!passable(0.0, 2.0, -0.9, 1.7), "centred: no room");
        // It shifts left by 1.55 m: 0.6 m clear; that reaches 0.55 m over the line, allowed
        // with a lane on the left, not at the road's edge (a lane keeps it within 1 m).
        let s = pass_shift(-0.9, 1.7, 2.0, 2.0, true, false).expect("a lane on the left");
        assert!((s - 1.55).abs() < 1e-12, "{s}");
        assert!(passable(s, 2.0, -0.9, 1.7));
        assert!(passable(1.45, 2.0, -0.9, 1.7), "0.5 m is enough");
        assert!(!passable(1.44, 2.0, -0.9, 1.7), "0.49 m is not");
        assert_eq!(pass_shift(-0.9, 1.7, 2.0, 2.0, false, true), None, "the road's edge on the left");
        // Mirrored: a car moved left is passed on the right.
        assert_eq!(pass_shift(0.9, 1.7, 2.0, 2.0, false, true).map(|s| (s * 100.0).round()), Some(-155.0));
        // A car in the middle of the lane is followed, not passed.
        assert_eq!(pass_shift(0.1, 1.7, 2.0, 2.0, true, true), None);
        // A wide lane needs no spill.
        assert!(pass_shift(-1.2, 1.7, 2.0, 2.5, false, false).is_some());
    }
}
