//! GCDC 2016 scenario 2, the cooperative intersection: vehicles on the arms of a junction (some
//! in platoons) agree over V2V in which order they cross or turn.
//!
//! A roadside unit (`[[rsu]] message = "intersection_zone"`, [`super::Rsu`]) standing at the
//! junction announces the intersection zone on wifi. A vehicle with
//! `controller.intersection = { .. }` ([`IntersectionParams`]) that hears it finds the junction
//! nearest the unit on its route (its conflict zone: the junction links it drives, from the
//! stop line to the end of its last link) and from then on broadcasts an
//! [`IntersectionMessage`] every control tick: the competition's fields (participant id,
//! intention straight/left/right, distance to the conflict zone, speed) plus the state of the
//! negotiation (its link, arrival estimate, holding the right to go, unable to stop, inside,
//! passed). Every participant keeps the newest message of every other one it heard
//! ([`Known`]) and applies the same rule ([`decide`]):
//! - only vehicles on **conflicting links** (crossing or merging, from the map's junction
//!   conflicts) are ordered against each other, by [`goes_before`] (inside, then holding the
//!   right and unable to stop, then holding the right, then earlier arrival at the stop line,
//!   then lower id: the rule of [`super::crossing::goes_first`], where a vehicle waiting at its
//!   stop line arrived when it stopped, so first come, first served): opposite straight movements and
//!   turns that never meet cross together, and a foe no longer counts once its rear has cleared
//!   the conflict points it shares with the vehicle;
//! - **missing claims mean stop**: a conflicting participant whose newest message is older than
//!   [`STALE`] (lost messages) blocks, as does the vehicle ahead in the same lane, and nobody
//!   takes the right in its first [`LISTEN`] after hearing the unit. A lossy channel costs
//!   time, never a crossing on a guess;
//! - **first in its lane**: a vehicle takes the right only when the one ahead of it on its route
//!   (if a participant before the zone) holds it, so a queue never holds the right from behind
//!   its own stopped leader;
//! - **platoons stay together where safe**: a platoon follower whose member ahead holds the
//!   right (or is inside) and arrives within [`IntersectionParams::platoon_window`] after it
//!   claims the right with it, yielding only to conflicting vehicles that are inside or can no
//!   longer stop.
//!
//! A vehicle without the right brakes to stop [`IntersectionParams::stop_margin`] before its
//! stop line ([`super::crossing::stop_before`]). With `negotiate = false` the vehicle only
//! measures (`metrics.intersection`) and the junction's plain right-of-way
//! ([`super::right_of_way`]) decides, as for any vehicle: the comparison of the README.
//! A vehicle that has not heard the unit is no participant: the plain right-of-way governs it,
//! and the participants do not know of it (the scenario keeps everyone in the unit's range).
//! Per tick the work is O(messages heard) per participant.

use std::cmp::Ordering;
use std::collections::BTreeMap;
use std::sync::Arc;

use bevy_ecs::prelude::{Component, Query, Res};
use bevy_ecs::schedule::IntoScheduleConfigs;
use glam::DVec2;

use crate::map::junctions::Turn;
use crate::sim::params::{MAX_ACCEL, MAX_DISTANCE, MAX_TIME, ParamError, Range, check_all};
use crate::sim::{Control, Plugin, SimBuilder, SimClock};
use crate::world::{Channel, Mailbox, Route, VehicleId, VehicleSize, VehicleState};

use super::crossing::{ETA_TIE, stop_before};
use super::gcdc::{RsuKind, RsuMessage};
use super::longitudinal::{Longitudinal, LongitudinalSystems, install_longitudinal};
use super::path_following::PathFollower;
use super::platoon::PlatoonMember;
use super::right_of_way::{CLEAR, JunctionDriver, JunctionNetwork, passages};

/// A participant whose newest message is older than this is missing \[s\]: it blocks every
/// vehicle whose link conflicts with its own (five wifi rounds at 10 Hz: with 20 % loss, five
/// losses in a row happen once in 3,000 rounds).
pub const STALE: f64 = 0.5;
/// Nobody takes the right before it has listened this long after hearing the unit \[s\] (every
/// participant in range has been heard a few times by then).
pub const LISTEN: f64 = 0.5;
/// A vehicle slower than 1 m/s within this distance of where it stops \[m\] is waiting at its
/// stop line (first come, first served from then on).
pub const ARRIVED: f64 = 2.0;
/// The unit announces the junction whose centre is within this distance of it \[m\].
pub const ZONE_MATCH: f64 = 50.0;

/// Where a vehicle goes at the junction (the competition's intention field).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Intention {
    /// Straight on.
    Straight,
    /// Turning left (a U-turn counts as left).
    Left,
    /// Turning right.
    Right,
}

impl Intention {
    /// The intention of a junction link's turn.
    pub fn of(turn: Turn) -> Intention {
        match turn {
            Turn::Straight => Intention::Straight,
            Turn::Left | Turn::UTurn => Intention::Left,
            Turn::Right => Intention::Right,
        }
    }
}

/// `controller.intersection = { negotiate, stop_margin, deceleration, acceleration,
/// platoon_window }`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct IntersectionParams {
    /// Negotiate over V2V (default); `false`: only measure, and the junction's plain
    /// right-of-way decides (`--set 'vehicles.*.controller.intersection.negotiate=false'`).
    pub negotiate: bool,
    /// Distance kept before the stop line (the start of its first junction link, at the edge of
    /// the junction) when yielding \[m\]: left turners into this arm sweep past the front of a
    /// vehicle waiting there (about 2.1 m away at 1 m, 2.5 m at 2 m on the generated T).
    pub stop_margin: f64,
    /// Braking used to stop before the zone [m/s²] (positive); more: decides later.
    pub deceleration: f64,
    /// Acceleration assumed when estimating the arrival time [m/s²].
    pub acceleration: f64,
    /// A platoon follower crosses with the member ahead when it arrives at most this long after
    /// it \[s\]; more: longer platoons stay together, others wait longer.
    pub platoon_window: f64,
}

impl Default for IntersectionParams {
    fn default() -> Self {
        IntersectionParams {
            negotiate: true,
            stop_margin: 2.0,
            deceleration: 3.0,
            acceleration: 2.0,
            platoon_window: 3.0,
        }
    }
}

impl IntersectionParams {
    /// Check the values (keys relative to this table): `stop_margin` [0, 1e7] m, accelerations
    /// (0, 1e3] m/s², `platoon_window` [0, 86 400] s.
    pub fn check(&self) -> Result<(), ParamError> {
        check_all([
            ("stop_margin", self.stop_margin, Range::non_negative(MAX_DISTANCE)),
            ("deceleration", self.deceleration, Range::positive(MAX_ACCEL)),
            ("acceleration", self.acceleration, Range::positive(MAX_ACCEL)),
            ("platoon_window", self.platoon_window, Range::non_negative(MAX_TIME)),
        ])
    }
}

/// What every participant broadcasts on wifi each control tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IntersectionMessage {
    /// Participant id.
    pub id: VehicleId,
    /// Straight, left or right.
    pub intention: Intention,
    /// Distance from its front to its stop line \[m\] (negative inside the zone).
    pub distance_to_zone: f64,
    /// Speed [m/s].
    pub speed: f64,
    /// Its length \[m\] (CAM's vehicle length): with `distance_to_zone`, where its rear is.
    pub length: f64,
    /// The junction link it drives first ([`JunctionNetwork::links`] index: every participant
    /// numbers the links of the same map alike).
    pub link: u32,
    /// Estimated time until its front reaches the stop line \[s\] (0 inside); negative while it
    /// waits there: minus the time it has waited.
    pub eta: f64,
    /// Its front is in the zone.
    pub inside: bool,
    /// It holds the right to go.
    pub going: bool,
    /// It holds the right and can no longer stop before the zone.
    pub committed: bool,
    /// Its rear has left the zone: it no longer takes part.
    pub passed: bool,
}

impl IntersectionMessage {
    /// The message with its arrival estimate made `age` \[s\] older (a vehicle on its way
    /// arrives no earlier than now; one waiting has waited `age` longer).
    pub fn aged(&self, age: f64) -> IntersectionMessage {
        let eta = if self.eta > 0.0 { (self.eta - age).max(0.0) } else { self.eta - age };
        IntersectionMessage { eta, ..*self }
    }
}

/// Whether participant `a` goes before `b` (both messages with their arrival estimates brought
/// to now, [`IntersectionMessage::aged`]): inside first, then holding the right and unable to
/// stop, then holding the right, then earlier arrival at the stop line (beyond [`ETA_TIE`]; a
/// vehicle waiting there arrived when it stopped, so among waiting vehicles the first to come
/// goes first, and a waiting vehicle before one still approaching), then lower id. Every
/// participant applies it to the same messages, so they agree on the order.
pub fn goes_before(a: &IntersectionMessage, b: &IntersectionMessage) -> bool {
    let class = |m: &IntersectionMessage| (u8::from(!m.inside), u8::from(!m.committed), u8::from(!m.going));
    match class(a).cmp(&class(b)) {
        Ordering::Less => true,
        Ordering::Greater => false,
        Ordering::Equal if (a.eta - b.eta).abs() > ETA_TIE => a.eta < b.eta,
        Ordering::Equal => a.id < b.id,
    }
}

/// The newest message heard from one participant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Known {
    /// When it was sent \[s\].
    pub sent: f64,
    /// The message.
    pub message: IntersectionMessage,
}

/// Why a vehicle may not take the right (or `Go`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Decision {
    /// It may go (or must: inside, or unable to stop).
    Go,
    /// Still listening after hearing the unit.
    Listening,
    /// The vehicle ahead in its lane has not taken the right (or is missing).
    Queued(VehicleId),
    /// A conflicting participant's messages are missing.
    Missing(VehicleId),
    /// A conflicting participant goes first.
    Yields(VehicleId),
}

/// What [`decide`] knows of the deciding vehicle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Me {
    /// Its message of this tick (`going`: whether it held the right until now).
    pub message: IntersectionMessage,
    /// Whether it can still stop before the zone.
    pub can_stop: bool,
    /// Whether it has listened for [`LISTEN`] since hearing the unit.
    pub listened: bool,
    /// The vehicle ahead of it on its route, if any.
    pub ahead: Option<VehicleId>,
    /// Whether that vehicle is the member ahead of it in its platoon.
    pub platoon_ahead: bool,
}

/// The rule every participant applies (see the module documentation): whether `me` may hold
/// the right to go, given the newest message of every other participant (`known`, with the
/// time `now` \[s\]) and which links conflict with its own (`conflicts(link)`: the arc length
/// \[m\] along that link of the farthest point where it meets one of ours, `None` if it never
/// does). A foe whose rear is [`CLEAR`] past that point no longer counts.
pub fn decide(
    me: &Me,
    known: &BTreeMap<VehicleId, Known>,
    now: f64,
    conflicts: impl Fn(u32) -> Option<f64>,
    params: &IntersectionParams,
) -> Decision {
    let mine = me.message;
    if mine.inside || (mine.going && !me.can_stop) {
        return Decision::Go;
    }
    if !me.listened {
        return Decision::Listening;
    }
    let mut claim = mine;
    if let Some(ahead) = me.ahead
        && let Some(k) = known.get(&ahead).filter(|k| !k.message.passed)
    {
        let age = now - k.sent;
        let theirs = k.message;
        if age > STALE || !(theirs.going || theirs.inside) {
            return Decision::Queued(ahead);
        }
        // The member ahead goes and this one is close behind: cross together.
        if me.platoon_ahead && mine.eta - theirs.aged(age).eta <= params.platoon_window {
            claim.going = true;
        }
    }
    for (&id, k) in known {
        let theirs = k.message;
        if id == mine.id || theirs.passed {
            continue;
        }
        let Some(point) = conflicts(theirs.link) else { continue };
        if -theirs.distance_to_zone - theirs.length > point + CLEAR {
            continue;
        }
        let age = now - k.sent;
        if age > STALE {
            return Decision::Missing(id);
        }
        if goes_before(&theirs.aged(age), &claim) {
            return Decision::Yields(id);
        }
    }
    Decision::Go
}

/// Estimated time \[s\] to cover `d` \[m\] from speed `v` [m/s] at acceleration `a` [m/s²].
pub fn arrival_time(d: f64, v: f64, a: f64) -> f64 {
    if d <= 0.0 {
        return 0.0;
    }
    let v = v.max(0.0);
    let a = a.max(1e-3);
    ((v * v + 2.0 * a * d).sqrt() - v) / a
}

/// A participant's conflict zone on its route.
#[derive(Debug, Clone, PartialEq)]
pub struct Zone {
    /// Junction index (in [`JunctionNetwork::junctions`]).
    pub junction: u32,
    /// Route arc length of the stop line (the first link's start) \[m\].
    pub entry: f64,
    /// Route arc length of the end of its last link \[m\].
    pub exit: f64,
    /// Its links (global link index) with the route arc length of each one's start \[m\].
    pub links: Vec<(u32, f64)>,
    /// Straight, left or right (of its first link).
    pub intention: Intention,
}

/// The zone of `route` announced by a unit at `at`: its passage through the junction whose
/// centre is nearest `at` (within [`ZONE_MATCH`]); `None` if the route does not pass it.
pub fn zone_of(route: &crate::map::Path, network: &JunctionNetwork, at: DVec2) -> Option<Zone> {
    passages(route, &network.map, network)
        .into_iter()
        .filter_map(|p| {
            let d = network.junctions.list.get(p.junction as usize)?.centre.distance(at);
            (d <= ZONE_MATCH).then_some((d, p))
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .and_then(|(_, p)| {
            let &(first, _) = p.links.first()?;
            let intention = Intention::of(network.links.get(first as usize)?.turn);
            Some(Zone { junction: p.junction, entry: p.entry, exit: p.exit, links: p.links, intention })
        })
}

/// Per-vehicle state of the intersection negotiation (and what `metrics.intersection` reads).
#[derive(Component, Debug, Clone, PartialEq)]
#[require(Longitudinal)]
pub struct IntersectionNegotiator {
    /// Parameters.
    pub params: IntersectionParams,
    /// Its zone, once the unit has been heard (and its route passes the junction).
    pub zone: Option<Zone>,
    /// When it first heard the unit \[s\].
    pub heard_at: Option<f64>,
    /// Whether it holds the right to go.
    pub going: bool,
    /// Whether its rear has left the zone (or its route does not pass it).
    pub passed: bool,
    /// The newest message of every other participant heard.
    pub known: BTreeMap<VehicleId, Known>,
    /// The last decision (for logs and tests).
    pub decision: Option<Decision>,
    /// When it came to a stop at its stop line \[s\] (infinite until then).
    pub waiting_since: f64,
}

impl IntersectionNegotiator {
    /// Not yet told of a zone.
    pub fn new(params: IntersectionParams) -> IntersectionNegotiator {
        IntersectionNegotiator {
            params,
            zone: None,
            heard_at: None,
            going: false,
            passed: false,
            known: BTreeMap::new(),
            decision: None,
            waiting_since: f64::INFINITY,
        }
    }

    /// Whether it negotiates now (so the junction's plain right-of-way leaves it alone).
    pub fn negotiating(&self) -> bool {
        self.params.negotiate && self.zone.is_some() && !self.passed
    }
}

/// Every control tick: hear the unit and the other participants, decide, brake before the zone
/// without the right, and broadcast (see the module documentation).
#[allow(clippy::type_complexity)]
pub fn negotiate_intersection(
    clock: Res<SimClock>,
    network: Option<Res<JunctionNetwork>>,
    mut vehicles: Query<(
        &VehicleId,
        &VehicleState,
        &VehicleSize,
        &Route,
        &PathFollower,
        &mut Mailbox,
        &mut IntersectionNegotiator,
        &mut Longitudinal,
        Option<&PlatoonMember>,
        Option<&mut JunctionDriver>,
    )>,
) {
    let Some(network) = network else { return };
    let now = clock.now.as_secs();
    for (&id, state, size, route, follower, mut mailbox, mut neg, mut lon, member, _) in &mut vehicles {
        let neg = &mut *neg;
        if neg.heard_at.is_none()
            && let Some((_, _, m)) =
                mailbox.received::<RsuMessage>(Channel::Wifi).find(|m| m.2.message == RsuKind::IntersectionZone)
        {
            neg.heard_at = Some(now);
            neg.zone = zone_of(&route.0, &network, m.at);
            neg.passed = neg.zone.is_none();
        }
        if !neg.params.negotiate || neg.passed {
            // Passed: keep saying so, so that a participant that lost the first "passed" learns it.
            if neg.params.negotiate
                && let Some(zone) = &neg.zone
            {
                let first = zone.links.first().map_or(u32::MAX, |l| l.0);
                let done = IntersectionMessage {
                    id,
                    intention: zone.intention,
                    distance_to_zone: zone.entry - (follower.s + 0.5 * size.length),
                    speed: state.speed(),
                    length: size.length,
                    link: first,
                    eta: 0.0,
                    inside: false,
                    going: false,
                    committed: false,
                    passed: true,
                };
                broadcast(&mut mailbox, clock.now, done);
            }
            continue;
        }
        let Some(zone) = &neg.zone else { continue };
        for (sender, sent, m) in mailbox.received::<IntersectionMessage>(Channel::Wifi) {
            let sent = sent.as_secs();
            if sender != id && neg.known.get(&sender).is_none_or(|k| k.sent <= sent) {
                neg.known.insert(sender, Known { sent, message: *m });
            }
        }
        let p = neg.params;
        let front = follower.s + 0.5 * size.length;
        let rear = follower.s - 0.5 * size.length;
        let v = state.speed().max(0.0);
        let first = zone.links.first().map_or(u32::MAX, |l| l.0);
        let passed = rear > zone.exit;
        let inside = front >= zone.entry && !passed;
        let to_zone = zone.entry - front;
        let stop_room = to_zone - p.stop_margin;
        let can_stop = v * v <= 2.0 * p.deceleration * stop_room.max(0.0) + 0.5;
        if neg.waiting_since.is_infinite() && !inside && stop_room < ARRIVED && v < 1.0 {
            neg.waiting_since = now;
        }
        let message = IntersectionMessage {
            id,
            intention: zone.intention,
            distance_to_zone: to_zone,
            speed: v,
            length: size.length,
            link: first,
            eta: if inside {
                0.0
            } else if neg.waiting_since.is_finite() {
                neg.waiting_since - now
            } else {
                arrival_time(to_zone, v, p.acceleration)
            },
            inside,
            going: neg.going,
            committed: neg.going && !can_stop,
            passed,
        };
        let decision = if passed {
            Decision::Go
        } else {
            let ahead = lon.leader.map(|l| l.id);
            let me = Me {
                message,
                can_stop,
                listened: neg.heard_at.is_some_and(|t| now - t >= LISTEN),
                ahead,
                platoon_ahead: member.is_some_and(|m| m.is_follower()) && ahead.is_some(),
            };
            let mine = &network.links;
            let conflicts = |other: u32| {
                zone.links
                    .iter()
                    .filter_map(|&(g, _)| mine.get(g as usize))
                    .flat_map(|l| l.conflicts.iter().filter(|c| c.foe == other).map(|c| c.s_foe))
                    .reduce(f64::max)
            };
            decide(&me, &neg.known, now, conflicts, &p)
        };
        let go = decision == Decision::Go;
        if !go {
            lon.limit(stop_before(v, stop_room, p.deceleration));
        }
        let out = IntersectionMessage { going: go && !passed, committed: go && !passed && !can_stop, ..message };
        neg.going = out.going;
        neg.passed = passed;
        if neg.decision != Some(decision) {
            tracing::debug!(target: "gcdc_intersection", "{id} at {now:.2} s, {to_zone:.1} m before the zone: {decision:?}");
        }
        neg.decision = Some(decision);
        if passed {
            neg.known.clear();
        }
        broadcast(&mut mailbox, clock.now, out);
    }
    // The junction rules leave a vehicle to this negotiation while it decides its passage
    // (read as the state stands after this tick's decisions).
    for (.., neg, _, _, driver) in &mut vehicles {
        if let Some(mut driver) = driver {
            driver.own_negotiation = neg.negotiating();
        }
    }
}

/// Replace this vehicle's queued intersection message with `m`.
fn broadcast(mailbox: &mut Mailbox, now: crate::world::SimTime, m: IntersectionMessage) {
    mailbox.wifi_out.retain(|x| x.payload::<IntersectionMessage>().is_none());
    mailbox.send(Channel::Wifi, now, Arc::new(m));
}

/// The cooperative intersection in the [`Control`] schedule, with the other limiters.
#[derive(Debug, Clone, Copy, Default)]
pub struct GcdcIntersectionPlugin;

impl Plugin for GcdcIntersectionPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        install_longitudinal(sim);
        sim.add_systems(Control, negotiate_intersection.in_set(LongitudinalSystems::Limit));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn msg(id: i32, link: u32, eta: f64) -> IntersectionMessage {
        IntersectionMessage {
            id: VehicleId(id),
            intention: Intention::Straight,
            distance_to_zone: 10.0 * eta,
            speed: 10.0,
            length: 4.5,
            link,
            eta,
            inside: false,
            going: false,
            committed: false,
            passed: false,
        }
    }

    fn me(m: IntersectionMessage) -> Me {
        Me { message: m, can_stop: true, listened: true, ahead: None, platoon_ahead: false }
    }

    fn known(list: &[(f64, IntersectionMessage)]) -> BTreeMap<VehicleId, Known> {
        list.iter().map(|&(sent, m)| (m.id, Known { sent, message: m })).collect()
    }

    /// Links 0 and 1 conflict 8 m along each, link 2 conflicts with neither.
    fn conflicts_with(mine: u32) -> impl Fn(u32) -> Option<f64> {
        move |other| matches!((mine, other), (0, 1) | (1, 0)).then_some(8.0)
    }

    const P: IntersectionParams = IntersectionParams {
        negotiate: true,
        stop_margin: 3.0,
        deceleration: 3.0,
        acceleration: 2.0,
        platoon_window: 3.0,
    };

    #[test]
    fn the_earlier_of_two_conflicting_vehicles_goes_and_the_later_yields() {
        let a = msg(-1, 0, 2.0);
        let b = msg(-2, 1, 4.0);
        let now = 10.0;
        let heard = known(&[(now, a), (now, b)]);
        assert_eq!(decide(&me(a), &heard, now, conflicts_with(0), &P), Decision::Go);
        assert_eq!(decide(&me(b), &heard, now, conflicts_with(1), &P), Decision::Yields(VehicleId(-1)));
    }

    #[test]
    fn vehicles_on_links_that_never_meet_go_together() {
        let a = msg(-1, 0, 2.0);
        let c = msg(-3, 2, 4.0);
        let heard = known(&[(0.0, a), (0.0, c)]);
        assert_eq!(decide(&me(c), &heard, 0.0, conflicts_with(2), &P), Decision::Go);
    }

    #[test]
    fn a_missing_conflicting_claim_means_stop_even_when_it_was_behind() {
        let a = msg(-1, 0, 2.0);
        let b = msg(-2, 1, 9.0);
        // b's newest message is 0.6 s old: it may have taken the right since.
        let heard = known(&[(10.0, a), (9.4, b)]);
        assert_eq!(decide(&me(a), &heard, 10.0, conflicts_with(0), &P), Decision::Missing(VehicleId(-2)));
        // Fresh again: a goes.
        let heard = known(&[(10.0, a), (9.9, b)]);
        assert_eq!(decide(&me(a), &heard, 10.0, conflicts_with(0), &P), Decision::Go);
    }

    #[test]
    fn an_old_arrival_estimate_is_aged_before_comparing() {
        // b said 2.5 s, 0.4 s ago: it arrives in 2.1 s, before a's 2.45 s by more than the tie.
        let a = msg(-1, 0, 2.45);
        let b = msg(-2, 1, 2.5);
        let heard = known(&[(10.0, a), (9.6, b)]);
        assert_eq!(decide(&me(a), &heard, 10.0, conflicts_with(0), &P), Decision::Yields(VehicleId(-2)));
    }

    #[test]
    fn inside_or_unable_to_stop_always_goes() {
        let a = IntersectionMessage { inside: true, ..msg(-5, 0, 0.0) };
        let b = IntersectionMessage { inside: true, ..msg(-1, 1, 0.0) };
        let heard = known(&[(0.0, b)]);
        assert_eq!(decide(&me(a), &heard, 0.0, conflicts_with(0), &P), Decision::Go);
        let c = IntersectionMessage { going: true, ..msg(-5, 0, 0.5) };
        let committed = Me { can_stop: false, ..me(c) };
        assert_eq!(decide(&committed, &heard, 0.0, conflicts_with(0), &P), Decision::Go);
        assert_eq!(decide(&me(c), &heard, 0.0, conflicts_with(0), &P), Decision::Yields(VehicleId(-1)));
    }

    #[test]
    fn a_foe_inside_no_longer_blocks_once_its_rear_has_cleared_the_conflict_point() {
        let a = msg(-1, 0, 1.0);
        // Its front 12 m into its link, 4.5 m long: the rear is at 7.5 m, short of 8 + 2.5.
        let b = IntersectionMessage { inside: true, distance_to_zone: -12.0, ..msg(-2, 1, 0.0) };
        let heard = known(&[(0.0, b)]);
        assert_eq!(decide(&me(a), &heard, 0.0, conflicts_with(0), &P), Decision::Yields(VehicleId(-2)));
        // Front at 15.1 m: rear at 10.6 m, past 10.5 m.
        let b = IntersectionMessage { distance_to_zone: -15.1, ..b };
        let heard = known(&[(0.0, b)]);
        assert_eq!(decide(&me(a), &heard, 0.0, conflicts_with(0), &P), Decision::Go);
    }

    #[test]
    fn first_come_first_served_among_waiting_vehicles_and_before_approaching_ones() {
        // Waiting for 4 s and for 2 s (negative estimates), and one 0.5 s away.
        let early = msg(-7, 0, -4.0);
        let late = msg(-1, 1, -2.0);
        let approaching = msg(-2, 1, 0.5);
        assert!(goes_before(&early, &late));
        assert!(!goes_before(&late, &early));
        assert!(goes_before(&late, &approaching));
        // The right to go outranks waiting longer.
        let going = IntersectionMessage { going: true, ..approaching };
        assert!(goes_before(&going, &early));
        // Within the tie of each other: the lower id.
        let close = msg(-9, 1, -3.8);
        assert!(goes_before(&close, &early));
        // Ageing: a waiting vehicle's wait grows, an approaching one's estimate stops at 0.
        assert_eq!(late.aged(0.5).eta, -2.5);
        assert_eq!(approaching.aged(0.8).eta, 0.0);
    }

    #[test]
    fn nobody_goes_while_listening() {
        let a = msg(-1, 0, 2.0);
        let listening = Me { listened: false, ..me(a) };
        assert_eq!(decide(&listening, &BTreeMap::new(), 0.0, conflicts_with(0), &P), Decision::Listening);
    }

    #[test]
    fn a_vehicle_waits_for_the_one_ahead_in_its_lane_to_take_the_right() {
        let ahead = msg(-1, 0, 1.0);
        let behind = msg(-2, 2, 3.0);
        let heard = known(&[(0.0, ahead)]);
        let m = Me { ahead: Some(VehicleId(-1)), ..me(behind) };
        assert_eq!(decide(&m, &heard, 0.0, conflicts_with(2), &P), Decision::Queued(VehicleId(-1)));
        let heard = known(&[(0.0, IntersectionMessage { going: true, ..ahead })]);
        assert_eq!(decide(&m, &heard, 0.0, conflicts_with(2), &P), Decision::Go);
        // Ahead but passed, or not a participant: no queue.
        let heard = known(&[(0.0, IntersectionMessage { passed: true, ..ahead })]);
        assert_eq!(decide(&m, &heard, 0.0, conflicts_with(2), &P), Decision::Go);
    }

    #[test]
    fn a_platoon_follower_crosses_with_its_member_ahead_but_not_past_a_committed_foe() {
        let lead = IntersectionMessage { going: true, ..msg(-1, 0, 1.0) };
        let follower = msg(-2, 0, 2.5);
        let foe = msg(-9, 1, 2.0);
        let heard = known(&[(0.0, lead), (0.0, foe)]);
        let plain = Me { ahead: Some(VehicleId(-1)), ..me(follower) };
        assert_eq!(decide(&plain, &heard, 0.0, conflicts_with(0), &P), Decision::Yields(VehicleId(-9)));
        let platoon = Me { platoon_ahead: true, ..plain };
        assert_eq!(decide(&platoon, &heard, 0.0, conflicts_with(0), &P), Decision::Go);
        // Too far behind the member ahead: no joining.
        let late = Me { message: msg(-2, 0, 4.5), ..platoon };
        assert_eq!(decide(&late, &heard, 0.0, conflicts_with(0), &P), Decision::Yields(VehicleId(-9)));
        // A foe that can no longer stop goes first all the same.
        let committed = IntersectionMessage { going: true, committed: true, ..foe };
        let heard = known(&[(0.0, lead), (0.0, committed)]);
        assert_eq!(decide(&platoon, &heard, 0.0, conflicts_with(0), &P), Decision::Yields(VehicleId(-9)));
    }

    #[test]
    fn arrival_time_is_the_kinematic_one() {
        // From rest, 2 m/s² over 16 m: t = √(2·16/2) = 4 s; at constant 10 m/s (a → 0): 20 m in 2 s.
        assert!((arrival_time(16.0, 0.0, 2.0) - 4.0).abs() < 1e-12);
        assert!((arrival_time(20.0, 10.0, 1e-9) - 2.0).abs() < 1e-3);
        assert_eq!(arrival_time(-1.0, 5.0, 2.0), 0.0);
    }

    #[test]
    fn bad_parameters_name_the_key() {
        let bad = IntersectionParams { deceleration: 0.0, ..IntersectionParams::default() };
        let e = bad.check().err().map(|e| e.key);
        assert_eq!(e.as_deref(), Some("deceleration"));
        assert!(IntersectionParams::default().check().is_ok());
    }
}
