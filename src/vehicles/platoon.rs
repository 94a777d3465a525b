//! Cooperative ACC / platooning over wifi: members broadcast their speed and acceleration,
//! followers feed the acceleration of the member ahead forward on top of a radar gap law, so a
//! short time gap (default 0.5 s) stays string stable.
//!
//! Membership lives in the messages, not in a global: every platoon vehicle broadcasts a
//! [`PlatoonBeacon`] on wifi each control tick saying which platoon it belongs to (the leader's
//! id), its place in it, its speed and acceleration, and the leader's speed and acceleration
//! (relayed member to member, so they reach the tail beyond wifi range). A vehicle that is not
//! the leader is a member when the vehicle its radar sees ahead on its route broadcasts a fresh
//! beacon of a platoon: it takes the next place. So a vehicle joins at the tail by driving up
//! behind the last member (it keeps the ACC gap `acc_time_gap` until it hears it, then closes to
//! `time_gap`), and a member leaves by broadcasting no platoon any more
//! ([`PlatoonMember::leave`] or `leave_at`): it falls back to ACC and the vehicles behind it see a
//! non-member ahead, so the platoon ends in front of it.
//!
//! The leader only broadcasts: its speed comes from its own speed controller (cruise control or
//! ACC on the same vehicle). A follower's law is the one of [`AdaptiveCruise`] with
//! feed-forward a_ff = `feedforward_gain` · (acceleration of the member ahead). With
//! `feedforward_gain` = 1 and no delay, the gap error obeys the ACC dynamics driven by nothing,
//! so a disturbance never grows down the platoon; the wifi delay (up to one round) is small
//! against the time gap.
//!
//! Degraded cooperation ([`Fallback`], after Ploeg et al. 2015, "Graceful degradation of
//! cooperative adaptive cruise control", IEEE T-ITS 16(1)): a follower whose member ahead last
//! said it is in a platoon, but whose newest beacon is older than `fallback.beacon_timeout`,
//! stays in the platoon (its place and what it broadcasts do not change, so the vehicles behind
//! it keep their feed-forward) but drives ACC on its radar with `fallback.time_gap` and no
//! feed-forward; it returns to the platoon gap as soon as a fresh beacon arrives. A member ahead
//! that says it left, or a new vehicle ahead, ends membership as before (ACC at `acc_time_gap`).

use std::sync::Arc;

use bevy_ecs::prelude::{Component, Query, Res};
use bevy_ecs::schedule::IntoScheduleConfigs;
use serde::{Deserialize, Serialize};

use crate::sim::params::{MAX_GAIN, MAX_TIME, ParamError, Range, check_all};
use crate::sim::{Control, SimClock, WifiRate};
use crate::sim::{Plugin, SimBuilder};
use crate::world::{Channel, Mailbox, SimTime, VehicleId, VehicleState};

use super::acc::AdaptiveCruise;
use super::longitudinal::{Longitudinal, LongitudinalSystems, install_longitudinal};

/// Parameters of a platoon vehicle.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct Platooning {
    /// Time gap inside the platoon \[s\].
    pub time_gap: f64,
    /// Time gap while not a member (joining, after leaving) \[s\].
    pub acc_time_gap: f64,
    /// Standstill distance \[m\], bumper to bumper.
    pub standstill: f64,
    /// Gap error gain k_p [1/s²].
    pub gap_gain: f64,
    /// Relative speed gain k_d [1/s].
    pub speed_gain: f64,
    /// Free-road speed gain [1/s] towards the route speed.
    pub cruise_gain: f64,
    /// Weight of the member ahead's acceleration [-]; 0 turns the feed-forward off.
    pub feedforward_gain: f64,
    /// Largest acceleration asked for [m/s²].
    pub max_acceleration: f64,
    /// Largest braking asked for [m/s²] (positive).
    pub max_deceleration: f64,
    /// The older spelling of [`Fallback::beacon_timeout`] \[s\] (`controller.platoon.beacon_timeout`
    /// in scenario files written before the fallback table): when set, a beacon of the member
    /// ahead older than this puts the follower in fallback. `None`: the fallback table decides.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub beacon_timeout: Option<f64>,
}

/// What a platoon follower does when the beacons of the member ahead stop
/// (`controller.fallback = { beacon_timeout, time_gap }`): ACC on its radar until they return.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct Fallback {
    /// Age \[s\] of the newest beacon of the member ahead above which the follower falls back;
    /// `None` (the default) = 3 wifi intervals (0.3 s at the default 10 Hz). Raising it rides
    /// out longer loss bursts on stale feed-forward.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub beacon_timeout: Option<f64>,
    /// ACC time gap while in fallback \[s\] (default 1.2); raising it is safer and slower to
    /// return to the platoon gap.
    pub time_gap: f64,
}

impl Default for Fallback {
    fn default() -> Self {
        Fallback { beacon_timeout: None, time_gap: 1.2 }
    }
}

/// Wifi intervals in the default [`Fallback::beacon_timeout`].
pub const FALLBACK_WIFI_INTERVALS: f64 = 3.0;

impl Fallback {
    /// Check the values (keys relative to this table): beacon timeout (0, 86400] s, time gap
    /// [0, 86400] s.
    pub fn check(&self) -> Result<(), ParamError> {
        if let Some(t) = self.beacon_timeout {
            Range::positive(MAX_TIME).check("beacon_timeout", t)?;
        }
        Range::non_negative(MAX_TIME).check("time_gap", self.time_gap)
    }
}

impl Default for Platooning {
    fn default() -> Self {
        let acc = AdaptiveCruise::default();
        Platooning {
            time_gap: 0.5,
            acc_time_gap: acc.time_gap,
            standstill: acc.standstill,
            gap_gain: acc.gap_gain,
            speed_gain: acc.speed_gain,
            cruise_gain: acc.cruise_gain,
            feedforward_gain: 1.0,
            max_acceleration: acc.max_acceleration,
            max_deceleration: acc.max_deceleration,
            beacon_timeout: None,
        }
    }
}

impl Platooning {
    /// Check the values (keys relative to this table): the gap law's ranges, feed-forward gain
    /// [0, 1e6], beacon timeout (0, 86400] s.
    pub fn check(&self) -> Result<(), ParamError> {
        self.law(self.time_gap).check()?;
        if let Some(t) = self.beacon_timeout {
            Range::positive(MAX_TIME).check("beacon_timeout", t)?;
        }
        check_all([
            ("acc_time_gap", self.acc_time_gap, Range::non_negative(MAX_TIME)),
            ("feedforward_gain", self.feedforward_gain, Range::non_negative(MAX_GAIN)),
        ])
    }

    /// The gap law with time gap `time_gap` [s].
    fn law(&self, time_gap: f64) -> AdaptiveCruise {
        AdaptiveCruise {
            time_gap,
            standstill: self.standstill,
            gap_gain: self.gap_gain,
            speed_gain: self.speed_gain,
            cruise_gain: self.cruise_gain,
            max_acceleration: self.max_acceleration,
            max_deceleration: self.max_deceleration,
        }
    }
}

/// What a platoon vehicle broadcasts on wifi every control tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlatoonBeacon {
    /// The platoon it belongs to (its leader's id), or `None` when it is not a member.
    pub platoon: Option<VehicleId>,
    /// Its place: 0 for the leader, 1 for the first follower, ...
    pub index: u32,
    /// Its speed [m/s].
    pub speed: f64,
    /// The acceleration it asked for this tick [m/s²].
    pub acceleration: f64,
    /// The leader's speed [m/s], as last heard.
    pub leader_speed: f64,
    /// The leader's acceleration [m/s²], as last heard.
    pub leader_acceleration: f64,
}

/// Per-vehicle state of a platoon vehicle.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
#[require(Longitudinal)]
pub struct PlatoonMember {
    /// Parameters.
    pub params: Platooning,
    /// Whether this vehicle leads a platoon (its id names the platoon).
    pub lead: bool,
    /// Sim time at which it leaves the platoon, if planned.
    pub leave_at: Option<SimTime>,
    /// Whether it has left (it broadcasts no platoon any more).
    pub left: bool,
    /// The platoon it is in now, if any.
    pub platoon: Option<VehicleId>,
    /// Its place in the platoon (0 = leader).
    pub index: u32,
    /// What it does when the beacons of the member ahead stop.
    pub fallback: Fallback,
    /// Whether it is in fallback now: a follower driving ACC because the beacons of the member
    /// ahead are older than the timeout.
    pub degraded: bool,
    /// Age \[s\] of the newest beacon of the vehicle ahead at the last control tick, while a
    /// follower (`None` otherwise).
    pub beacon_age: Option<f64>,
    /// The latest beacon of the vehicle ahead and when it was sent.
    ahead: Option<(VehicleId, SimTime, PlatoonBeacon)>,
}

impl PlatoonMember {
    /// A platoon leader (its own id names the platoon).
    pub fn leader(params: Platooning) -> PlatoonMember {
        PlatoonMember {
            params,
            lead: true,
            leave_at: None,
            left: false,
            platoon: None,
            index: 0,
            fallback: Fallback::default(),
            degraded: false,
            beacon_age: None,
            ahead: None,
        }
    }

    /// A vehicle that joins the platoon ahead of it when it hears it.
    pub fn follower(params: Platooning) -> PlatoonMember {
        PlatoonMember { lead: false, ..PlatoonMember::leader(params) }
    }

    /// Leave the platoon now.
    pub fn leave(&mut self) {
        self.left = true;
    }

    /// The beacon timeout in force \[s\]: `fallback.beacon_timeout`, else the older
    /// `platoon.beacon_timeout`, else 3 intervals of wifi at `wifi_rate` \[Hz\].
    pub fn beacon_timeout(&self, wifi_rate: f64) -> f64 {
        self.fallback.beacon_timeout.or(self.params.beacon_timeout).unwrap_or(FALLBACK_WIFI_INTERVALS / wifi_rate)
    }

    /// Whether it is in a platoon and not its leader.
    pub fn is_follower(&self) -> bool {
        self.platoon.is_some() && !self.lead
    }
}

/// Update membership from the beacons heard and, for followers, set the acceleration.
pub fn control_platoon(
    clock: Res<SimClock>,
    wifi: Option<Res<WifiRate>>,
    mut vehicles: Query<(&VehicleId, &VehicleState, &Mailbox, &mut PlatoonMember, &mut Longitudinal)>,
) {
    let now = clock.now;
    let wifi_rate = wifi.map_or(crate::sim::Rates::default().wifi, |r| r.0);
    for (&id, state, mailbox, mut member, mut lon) in &mut vehicles {
        if member.leave_at.is_some_and(|t| now >= t) {
            member.left = true;
        }
        let ahead_id = lon.leader.map(|l| l.id);
        for m in mailbox.wifi_in.iter() {
            if Some(m.sender) == ahead_id
                && let Some(b) = m.payload::<PlatoonBeacon>()
            {
                member.ahead = Some((m.sender, m.sent_at, *b));
            }
        }
        let p = member.params;
        let timeout = member.beacon_timeout(wifi_rate);
        // The newest beacon of the vehicle ahead now, and its age [s].
        let heard = member.ahead.filter(|&(sender, _, _)| Some(sender) == ahead_id);
        let age = heard.map(|(_, sent_at, _)| now.0.saturating_sub(sent_at.0) as f64 * 1e-6);
        let fresh = heard.filter(|&(_, _, b)| b.platoon.is_some() && age.is_some_and(|a| a <= timeout));
        // Stale beacons of a member ahead that last said it is in our platoon: fall back.
        let degraded = !member.lead
            && !member.left
            && fresh.is_none()
            && member.platoon.is_some()
            && heard.is_some_and(|(_, _, b)| b.platoon == member.platoon);
        if member.left {
            member.platoon = None;
        } else if member.lead {
            member.platoon = Some(id);
            member.index = 0;
        } else if !degraded {
            member.platoon = fresh.and_then(|(_, _, b)| b.platoon);
            member.index = fresh.map_or(0, |(_, _, b)| b.index + 1);
        }
        member.degraded = degraded;
        member.beacon_age = age.filter(|_| member.is_follower());
        if member.lead && !member.left {
            continue;
        }
        let v = state.speed();
        lon.accel = match fresh.filter(|_| member.platoon.is_some()) {
            Some((_, _, b)) => p.law(p.time_gap).acceleration(
                v,
                lon.route_speed,
                lon.leader.as_ref(),
                p.feedforward_gain * b.acceleration,
            ),
            None if degraded => {
                p.law(member.fallback.time_gap).acceleration(v, lon.route_speed, lon.leader.as_ref(), 0.0)
            }
            None => p.law(p.acc_time_gap).acceleration(v, lon.route_speed, lon.leader.as_ref(), 0.0),
        };
    }
}

/// Broadcast every platoon vehicle's beacon with the acceleration finally asked for.
pub fn send_platoon_beacons(
    clock: Res<SimClock>,
    mut vehicles: Query<(&VehicleId, &VehicleState, &PlatoonMember, &Longitudinal, &mut Mailbox)>,
) {
    for (&id, state, member, lon, mut mailbox) in &mut vehicles {
        let speed = state.speed();
        let acceleration = if lon.accel.is_nan() { 0.0 } else { lon.accel };
        let (leader_speed, leader_acceleration) = match (member.platoon, member.ahead) {
            (Some(p), _) if p == id => (speed, acceleration),
            (Some(_), Some((_, _, b))) => (b.leader_speed, b.leader_acceleration),
            _ => (speed, acceleration),
        };
        let beacon = PlatoonBeacon {
            platoon: member.platoon,
            index: member.index,
            speed,
            acceleration,
            leader_speed,
            leader_acceleration,
        };
        // Only the newest beacon matters: replace one still waiting for the wifi round.
        mailbox.wifi_out.retain(|m| m.payload::<PlatoonBeacon>().is_none());
        mailbox.send(Channel::Wifi, clock.now, Arc::new(beacon));
    }
}

/// Platooning in the [`Control`] schedule: membership and follower control after the other
/// speed controllers (a leader's speed comes from them), beacons after the final decision.
#[derive(Debug, Clone, Copy, Default)]
pub struct PlatoonPlugin;

impl Plugin for PlatoonPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        install_longitudinal(sim);
        sim.add_systems(
            Control,
            (
                control_platoon.in_set(LongitudinalSystems::Cooperate),
                send_platoon_beacons.in_set(LongitudinalSystems::Report),
            ),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_beacon_timeout_is_the_fallback_table_then_the_older_key_then_three_wifi_intervals() {
        let mut member = PlatoonMember::follower(Platooning::default());
        assert!((member.beacon_timeout(10.0) - 0.3).abs() < 1e-12);
        assert!((member.beacon_timeout(5.0) - 0.6).abs() < 1e-12);
        member.params.beacon_timeout = Some(0.5);
        assert_eq!(member.beacon_timeout(10.0), 0.5);
        member.fallback.beacon_timeout = Some(0.2);
        assert_eq!(member.beacon_timeout(10.0), 0.2);
    }
}
