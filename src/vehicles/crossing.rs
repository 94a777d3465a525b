//! Intersection crossing negotiated over V2V: vehicles whose routes pass through a conflict zone
//! (a disc around the junction) agree by wifi on who goes first, and the others stop before it.
//!
//! Every vehicle approaching or inside the zone broadcasts a [`CrossingClaim`] each control tick:
//! its estimated time to reach the zone, whether it has taken the right to go, and whether it is
//! inside. The rule ([`goes_first`]), applied by every vehicle to the claims it hears (their
//! arrival times aged to now), orders vehicles by (inside first, then holding the right and
//! unable to stop, then holding the right to go, then earliest arrival, then lowest id); a
//! vehicle takes the right to go when nobody ahead of it in that order claims the zone, and
//! otherwise brakes to stop `stop_margin` before the zone. The rear of a vehicle leaving the
//! zone ends its claim. A platoon follower takes the right as soon as the member ahead of it
//! holds it, so a platoon crosses (or merges) as one. Two vehicles that take the right in the same round settle it by
//! (arrival, id) at the next round, long before either reaches the zone.

use std::sync::Arc;

use bevy_ecs::prelude::{Component, Query, Res};
use bevy_ecs::schedule::IntoScheduleConfigs;
use glam::DVec2;

use crate::map::Path;
use crate::sim::params::{MAX_ACCEL, MAX_DISTANCE, ParamError, Range, check_all};
use crate::sim::{Control, SimClock};
use crate::sim::{Plugin, SimBuilder};
use crate::world::{Channel, Mailbox, Route, VehicleId, VehicleSize, VehicleState};

use super::PathFollower;
use super::longitudinal::{Longitudinal, LongitudinalSystems, install_longitudinal};
use super::platoon::PlatoonMember;

/// Parameters of intersection negotiation.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct Crossing {
    /// Centre of the conflict zone \[m\] (x, y); vehicles negotiate with claims of the same centre
    /// (within 1 m).
    pub center: [f64; 2],
    /// Radius of the conflict zone \[m\]; it must cover every place where the routes cross.
    pub radius: f64,
    /// Distance kept before the zone when yielding \[m\].
    pub stop_margin: f64,
    /// Braking used to stop before the zone [m/s²] (positive).
    pub deceleration: f64,
    /// Acceleration assumed when estimating the arrival time [m/s²].
    pub acceleration: f64,
}

impl Crossing {
    /// Check the values (keys relative to this table): centre within 1e7 m, radius and margin
    /// [0, 1e7] m (radius > 0), accelerations (0, 1e3] m/s².
    pub fn check(&self) -> Result<(), ParamError> {
        check_all([
            ("center[0]", self.center[0], Range::between(-MAX_DISTANCE, MAX_DISTANCE)),
            ("center[1]", self.center[1], Range::between(-MAX_DISTANCE, MAX_DISTANCE)),
            ("radius", self.radius, Range::positive(MAX_DISTANCE)),
            ("stop_margin", self.stop_margin, Range::non_negative(MAX_DISTANCE)),
            ("deceleration", self.deceleration, Range::positive(MAX_ACCEL)),
            ("acceleration", self.acceleration, Range::positive(MAX_ACCEL)),
        ])
    }
}

impl Default for Crossing {
    fn default() -> Self {
        Crossing { center: [0.0, 0.0], radius: 10.0, stop_margin: 1.0, deceleration: 3.0, acceleration: 2.0 }
    }
}

/// What a vehicle near the zone broadcasts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CrossingClaim {
    /// Centre of the zone \[m\].
    pub center: DVec2,
    /// Whether its front is in the zone.
    pub inside: bool,
    /// Whether it holds the right to go.
    pub going: bool,
    /// Whether it holds the right and can no longer stop before the zone.
    pub committed: bool,
    /// Estimated time until its front reaches the zone \[s\] (0 inside).
    pub eta: f64,
}

/// Arrival times closer than this \[s\] count as a tie, settled by id, so that two vehicles
/// with slightly different estimates of each other never both think they are first.
pub const ETA_TIE: f64 = 0.3;

/// Whether claim `a` (of vehicle `a_id`) goes before claim `b` (of `b_id`): inside first, then
/// holding the right and unable to stop, then holding the right, then earlier arrival (beyond
/// [`ETA_TIE`]), then lower id.
pub fn goes_first(a: &CrossingClaim, a_id: VehicleId, b: &CrossingClaim, b_id: VehicleId) -> bool {
    let class = |c: &CrossingClaim| (u8::from(!c.inside), u8::from(!c.committed), u8::from(!c.going));
    match class(a).cmp(&class(b)) {
        std::cmp::Ordering::Less => true,
        std::cmp::Ordering::Greater => false,
        std::cmp::Ordering::Equal if (a.eta - b.eta).abs() > ETA_TIE => a.eta < b.eta,
        std::cmp::Ordering::Equal => a_id < b_id,
    }
}

/// Acceleration [m/s²] that stops a vehicle at speed `v` [m/s] within `room` \[m\]: the
/// deceleration needed once it exceeds half of `deceleration` [m/s²], else a gentle approach
/// along the profile √(2·deceleration·room); full braking (3 × `deceleration`) with no room left.
pub fn stop_before(v: f64, room: f64, deceleration: f64) -> f64 {
    if room <= 0.1 {
        return if v > 0.0 { -3.0 * deceleration } else { 0.0 };
    }
    let needed = v * v / (2.0 * room);
    if needed >= 0.5 * deceleration { -needed } else { ((2.0 * deceleration * room).sqrt() - v).min(1.0) }
}

/// The highest speed [m/s] a vehicle may drive at over the coming step of `dt` \[s\] and still
/// stop within `room` \[m\], braking by at most `deceleration` [m/s²] in each step after it. Steps
/// hold their speed (the kinematic model's update, and SUMO's default Euler update: its
/// `MSCFModel::maximumSafeStopSpeedEuler` answers the same question): speeds `v, v − b, v − 2b, …`
/// with `b = deceleration · dt` cover `dt` times their sum. `dt <= 0`: the continuous
/// `√(2 · deceleration · room)`. No room: 0.
///
/// A continuous law such as [`stop_before`] asks for an acceleration whose step, at a coarse
/// step (0.25 s and more: a signal env at SUMO's 1 s), carries the vehicle past the point it
/// meant to stop at; bounding the next speed by this one keeps it short of it at any step.
pub fn safe_stop_speed(room: f64, deceleration: f64, dt: f64) -> f64 {
    if room <= 0.0 || deceleration <= 0.0 {
        return 0.0;
    }
    if dt <= 0.0 {
        return (2.0 * deceleration * room).sqrt();
    }
    // Next speed m·b + f (0 <= f < b) covers dt·((m + 1)·f + b·m(m + 1)/2): the largest whole m
    // whose braking alone fits, then the rest as f.
    let b = deceleration * dt;
    let d = room / dt;
    let m = ((-1.0 + (1.0 + 8.0 * d / b).sqrt()) / 2.0).floor().max(0.0);
    let f = (d - b * m * (m + 1.0) / 2.0) / (m + 1.0);
    m * b + f.clamp(0.0, b)
}

/// Whether a vehicle at speed `v` [m/s] can still stop within `room` \[m\] braking by at most
/// `deceleration` [m/s²], its speed held over steps of `dt` \[s\] ([`safe_stop_speed`]): this
/// step brings it down by `deceleration · dt` at most. `dt <= 0`: `v² / (2 room) <= deceleration`.
/// A standing vehicle can always stop.
pub fn can_stop_within(v: f64, room: f64, deceleration: f64, dt: f64) -> bool {
    v <= 0.0 || v - deceleration * dt.max(0.0) <= safe_stop_speed(room, deceleration, dt) + 1e-9
}

/// The acceleration [m/s²] bound that keeps a vehicle at speed `v` [m/s] able to stop within
/// `room` \[m\] at `deceleration` [m/s²] with steps of `dt` \[s\] ([`safe_stop_speed`]): a
/// limiter's demand is lowered to it, so the step taken never carries the vehicle past where it
/// stops. Unbounded (infinity) for `dt <= 0`.
pub fn stop_within_step(v: f64, room: f64, deceleration: f64, dt: f64) -> f64 {
    if dt <= 0.0 { f64::INFINITY } else { (safe_stop_speed(room, deceleration, dt) - v) / dt }
}

/// Where `path` enters and leaves the disc (`center`, `radius`) first, as arc lengths \[m\].
pub fn zone_span(path: &Path, center: DVec2, radius: f64) -> Option<(f64, f64)> {
    let spacing = path.spacing();
    let inside = |p: &DVec2| p.distance(center) <= radius;
    let entry = path.points.iter().position(inside)?;
    let exit = path.points[entry..].iter().position(|p| !inside(p)).map_or(path.points.len(), |k| entry + k);
    Some((entry as f64 * spacing, exit as f64 * spacing))
}

/// Per-vehicle state of intersection negotiation.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
#[require(Longitudinal)]
pub struct CrossingNegotiator {
    /// Parameters.
    pub params: Crossing,
    /// Whether it holds the right to go.
    pub going: bool,
    /// Whether it has left the zone (or its route never enters it).
    pub passed: bool,
    span: Option<(f64, f64)>,
    measured: bool,
}

impl CrossingNegotiator {
    /// Not yet at the zone.
    pub fn new(params: Crossing) -> CrossingNegotiator {
        CrossingNegotiator { params, going: false, passed: false, span: None, measured: false }
    }
}

/// Negotiate and, when another vehicle goes first, limit the acceleration to stop before the zone.
#[allow(clippy::type_complexity)]
pub fn yield_at_crossings(
    clock: Res<SimClock>,
    mut vehicles: Query<(
        &VehicleId,
        &VehicleState,
        &VehicleSize,
        &Route,
        &PathFollower,
        &mut Mailbox,
        &mut CrossingNegotiator,
        &mut Longitudinal,
        Option<&PlatoonMember>,
    )>,
) {
    for (&id, state, size, route, follower, mut mailbox, mut neg, mut lon, member) in &mut vehicles {
        let p = neg.params;
        let center = DVec2::from_array(p.center);
        if !neg.measured {
            neg.measured = true;
            neg.span = zone_span(&route.0, center, p.radius);
            neg.passed = neg.span.is_none();
        }
        let Some((entry, exit)) = neg.span else { continue };
        if neg.passed {
            continue;
        }
        let front = follower.s + 0.5 * size.length;
        if follower.s - 0.5 * size.length > exit {
            neg.passed = true;
            neg.going = false;
            continue;
        }
        let v = state.speed().max(0.0);
        let inside = front >= entry;
        let to_zone = (entry - front).max(0.0);
        let a = p.acceleration.max(1e-3);
        let eta = if inside { 0.0 } else { ((v * v + 2.0 * a * to_zone).sqrt() - v) / a };
        let stop_room = to_zone - p.stop_margin;
        let can_stop = v * v <= 2.0 * p.deceleration * stop_room.max(0.0) + 0.5;
        let mine = CrossingClaim { center, inside, going: neg.going, committed: neg.going && !can_stop, eta };
        // A platoon follower crosses right behind the member ahead of it when that one goes.
        let ahead = member.filter(|m| m.is_follower()).and(lon.leader).map(|l| l.id);
        let platoon_goes = ahead.is_some_and(|ahead| {
            mailbox.wifi_in.iter().any(|m| {
                m.sender == ahead
                    && m.payload::<CrossingClaim>()
                        .is_some_and(|c| c.center.distance(center) <= 1.0 && (c.going || c.inside))
            })
        });
        let blocked = !inside
            && !platoon_goes
            && (can_stop || !neg.going)
            && mailbox.wifi_in.iter().any(|m| {
                m.sender != id
                    && m.payload::<CrossingClaim>().is_some_and(|c| {
                        // Their estimate is as old as the message: bring it to now.
                        let age = clock.now.as_secs() - m.sent_at.as_secs();
                        let theirs = CrossingClaim { eta: (c.eta - age).max(0.0), ..*c };
                        c.center.distance(center) <= 1.0 && goes_first(&theirs, m.sender, &mine, id)
                    })
            });
        neg.going = !blocked;
        if blocked {
            lon.limit(stop_before(v, stop_room, p.deceleration));
        }
        let claim = CrossingClaim { center, inside, going: neg.going, committed: neg.going && !can_stop, eta };
        mailbox.wifi_out.retain(|m| m.payload::<CrossingClaim>().is_none());
        mailbox.send(Channel::Wifi, clock.now, Arc::new(claim));
    }
}

/// Intersection negotiation in the [`Control`] schedule, after the speed controllers.
#[derive(Debug, Clone, Copy, Default)]
pub struct CrossingPlugin;

impl Plugin for CrossingPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        install_longitudinal(sim);
        sim.add_systems(Control, yield_at_crossings.in_set(LongitudinalSystems::Limit));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Room covered by a vehicle holding speed `v` for a step of `dt`, then braking by
    /// `deceleration · dt` a step until it stands (the kinematic model's update).
    fn covered(mut v: f64, deceleration: f64, dt: f64) -> f64 {
        let mut d = 0.0;
        while v > 0.0 {
            d += v * dt;
            v -= deceleration * dt;
        }
        d
    }

    #[test]
    fn the_safe_stop_speed_covers_exactly_the_room_at_any_step() {
        for &dt in &[0.02, 0.1, 0.25, 0.5, 1.0] {
            for &room in &[0.05, 0.3, 1.0, 2.8, 10.0, 37.5, 120.0] {
                let v = safe_stop_speed(room, 4.5, dt);
                let d = covered(v, 4.5, dt);
                assert!(d <= room + 1e-9 && d > room - 1e-6, "dt {dt} room {room}: v {v} covers {d}");
            }
        }
        // Continuous limit: √(2 b room); at 50 Hz within b·dt of it.
        assert!((safe_stop_speed(50.0, 4.5, 0.0) - 450f64.sqrt()).abs() < 1e-12);
        assert!((safe_stop_speed(50.0, 4.5, 0.02) - 450f64.sqrt()).abs() < 4.5 * 0.02);
        assert_eq!(safe_stop_speed(0.0, 4.5, 1.0), 0.0);
        assert_eq!(safe_stop_speed(-1.0, 4.5, 1.0), 0.0);
    }

    #[test]
    fn at_a_one_second_step_the_gentle_stop_law_alone_passes_the_line_and_the_bound_keeps_it_short() {
        // The creeping branch of stop_before asks for up to +1 m/s²: 0.3 m before the line at
        // 0.5 m/s, a 1 s step at 1.5 m/s covers 1.5 m.
        let (v, room, dt) = (0.5, 0.3, 1.0);
        let gentle = stop_before(v, room, 3.0);
        assert!((v + gentle * dt) * dt > room, "the continuous law alone overshoots");
        let bounded = gentle.min(stop_within_step(v, room, 7.5, dt));
        assert!((v + bounded * dt).max(0.0) * dt <= room + 1e-9);
        // At 50 Hz the bound does not act on that approach.
        assert!(stop_within_step(v, room, 7.5, 0.02) > gentle);
    }

    #[test]
    fn stopping_is_possible_when_this_step_can_reach_the_safe_speed() {
        // 14 m/s, 20 m before the line: at 7.5 m/s² (needs 4.9 continuously) yes, at 3 no.
        assert!(can_stop_within(14.0, 20.0, 7.5, 1.0) && can_stop_within(14.0, 20.0, 7.5, 0.0));
        assert!(!can_stop_within(14.0, 20.0, 3.0, 0.05) && !can_stop_within(14.0, 20.0, 3.0, 0.0));
        // At the line, standing or crawling: it stops (the step takes its speed away).
        assert!(can_stop_within(0.0, -0.2, 7.5, 1.0));
        assert!(can_stop_within(0.6, 0.0, 7.5, 1.0));
        assert!(!can_stop_within(0.6, 0.0, 7.5, 0.0));
    }
}
