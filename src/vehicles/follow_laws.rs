//! The car-following laws as pure models: the IDM ([`Idm`]), adaptive cruise control
//! ([`AdaptiveCruise`]) and what they follow ([`LeaderGap`]). Their systems are in
//! [`super::idm`], [`super::acc`] and [`super::longitudinal`]; the lane-change plugin evaluates the
//! same laws for MOBIL ([`super::lane_state::FollowLaw`]). Nothing here imports another
//! `vehicles` module, so every one of them may use these.
//!
//! IDM (Treiber, Hennecke, Helbing 2000, "Congested traffic states in empirical observations and
//! microscopic simulations", Phys. Rev. E 62): `a = a_max [1 − (v/v₀)^δ − (s*/s)²]`,
//! `s* = s₀ + v T + v Δv / (2 √(a_max b))`. ACC: the constant-time-gap law described in
//! [`super::acc`].

use crate::sim::params::{MAX_ACCEL, MAX_DISTANCE, MAX_GAIN, MAX_SPEED, MAX_TIME, ParamError, Range, check_all};
use crate::world::VehicleId;

/// The vehicle ahead on the same route, as the sensors see it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LeaderGap {
    /// Its id.
    pub id: VehicleId,
    /// Arc length from our centre to its centre along our route \[m\].
    pub distance: f64,
    /// Bumper-to-bumper gap \[m\]: `distance` minus our own length. Sensors report centres, not
    /// lengths, so this assumes the leader is as long as we are; raise the standstill distance
    /// when following longer vehicles.
    pub gap: f64,
    /// Its speed along our route [m/s].
    pub speed: f64,
    /// Its acceleration along our route [m/s²], from the change of `speed` since the last tick
    /// (0 when the leader just changed).
    pub acceleration: f64,
}

/// Largest braking the IDM asks for [m/s²] (its formula is unbounded when the gap closes).
pub const IDM_MAX_BRAKING: f64 = 9.0;

/// IDM parameters: `controller = { type = "idm", speed, time_gap, min_gap, accel, decel, delta }`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct Idm {
    /// Desired speed v₀ [m/s] (also the path follower's cruise speed).
    pub speed: f64,
    /// Desired time gap T \[s\]; raising it follows farther.
    pub time_gap: f64,
    /// Standstill gap s₀ \[m\], bumper to bumper.
    pub min_gap: f64,
    /// Maximum acceleration a_max [m/s²].
    pub accel: f64,
    /// Comfortable deceleration b [m/s²] (positive).
    pub decel: f64,
    /// Acceleration exponent δ [-].
    pub delta: f64,
}

impl Default for Idm {
    fn default() -> Self {
        Idm { speed: 30.0, time_gap: 1.5, min_gap: 2.0, accel: 1.0, decel: 2.0, delta: 4.0 }
    }
}

impl Idm {
    /// Check the values (keys relative to the `controller` table).
    pub fn check(&self) -> Result<(), ParamError> {
        check_all([
            ("speed", self.speed, Range::positive(MAX_SPEED)),
            ("time_gap", self.time_gap, Range::non_negative(MAX_TIME)),
            ("min_gap", self.min_gap, Range::non_negative(MAX_DISTANCE)),
            ("accel", self.accel, Range::positive(MAX_ACCEL)),
            ("decel", self.decel, Range::positive(MAX_ACCEL)),
            ("delta", self.delta, Range::between(0.1, 100.0)),
        ])
    }

    /// Acceleration [m/s²] at speed `v` [m/s] behind `leader = (gap [m], leader speed [m/s])`,
    /// or on a free road; never below −[`IDM_MAX_BRAKING`].
    pub fn acceleration(&self, v: f64, leader: Option<(f64, f64)>) -> f64 {
        let v = v.max(0.0);
        let r = v / self.speed.max(1e-3);
        // δ = 4 (the default) by multiplication: powf is the IDM's most expensive step.
        let free = 1.0 - if self.delta == 4.0 { (r * r) * (r * r) } else { r.powf(self.delta) };
        let interaction = match leader {
            Some((gap, vl)) => {
                let s_star = self.min_gap
                    + (v * self.time_gap + v * (v - vl) / (2.0 * (self.accel * self.decel).sqrt())).max(0.0);
                let s = gap.max(0.1);
                (s_star / s) * (s_star / s)
            }
            None => 0.0,
        };
        (self.accel * (free - interaction)).max(-IDM_MAX_BRAKING)
    }
}

/// The braking bound acts once stopping the closing in time needs at least this [m/s²]; below,
/// the gap law alone handles it (a weaker bound would cap gentle catching up).
pub const BRAKING_BOUND_FROM: f64 = 1.0;

/// Parameters of adaptive cruise control.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct AdaptiveCruise {
    /// Time gap h \[s\] kept to the leader on top of the standstill distance; raising it follows
    /// farther and damps disturbances more.
    pub time_gap: f64,
    /// Standstill distance d₀ \[m\], bumper to bumper, kept when stopped behind the leader.
    pub standstill: f64,
    /// Gap error gain k_p [1/s²]; raising it closes gap errors faster but rings more.
    pub gap_gain: f64,
    /// Relative speed gain k_d [1/s]; raising it damps the following.
    pub speed_gain: f64,
    /// Free-road speed gain k_v [1/s] towards the route speed.
    pub cruise_gain: f64,
    /// Largest acceleration asked for [m/s²].
    pub max_acceleration: f64,
    /// Largest braking asked for [m/s²] (positive).
    pub max_deceleration: f64,
}

impl Default for AdaptiveCruise {
    fn default() -> Self {
        AdaptiveCruise {
            time_gap: 1.5,
            standstill: 2.0,
            gap_gain: 0.2,
            speed_gain: 0.7,
            cruise_gain: 0.5,
            max_acceleration: 2.0,
            max_deceleration: 9.0,
        }
    }
}

impl AdaptiveCruise {
    /// Check the values (keys relative to this table): time gap [0, 86400] s, standstill
    /// [0, 1e7] m, gains [0, 1e6], accelerations (0, 1e3] m/s².
    pub fn check(&self) -> Result<(), ParamError> {
        check_all([
            ("time_gap", self.time_gap, Range::non_negative(MAX_TIME)),
            ("standstill", self.standstill, Range::non_negative(MAX_DISTANCE)),
            ("gap_gain", self.gap_gain, Range::non_negative(MAX_GAIN)),
            ("speed_gain", self.speed_gain, Range::non_negative(MAX_GAIN)),
            ("cruise_gain", self.cruise_gain, Range::non_negative(MAX_GAIN)),
            ("max_acceleration", self.max_acceleration, Range::positive(MAX_ACCEL)),
            ("max_deceleration", self.max_deceleration, Range::positive(MAX_ACCEL)),
        ])
    }

    /// Desired gap \[m\] at speed `v` [m/s]: d₀ + h·v.
    pub fn desired_gap(&self, v: f64) -> f64 {
        self.standstill + self.time_gap * v.max(0.0)
    }

    /// The acceleration [m/s²] this law asks for at speed `v` [m/s] with route speed `cruise`
    /// [m/s], the `leader` ahead if any, and a feed-forward acceleration `ff` [m/s²] (0 for
    /// radar only).
    pub fn acceleration(&self, v: f64, cruise: f64, leader: Option<&LeaderGap>, ff: f64) -> f64 {
        let mut a = self.cruise_gain * (cruise - v);
        if let Some(l) = leader {
            let follow = self.gap_gain * (l.gap - self.desired_gap(v)) + self.speed_gain * (l.speed - v) + ff;
            a = a.min(follow);
            let closing = v - l.speed;
            if closing > 0.0 {
                let room = (l.gap - 0.5 * self.standstill).max(0.05);
                let needed = closing * closing / (2.0 * room);
                if needed >= BRAKING_BOUND_FROM {
                    a = a.min(-needed);
                }
            }
        }
        debug_assert!(self.check().is_ok(), "ACC parameters not checked: {self:?}");
        // max/min, not clamp: total even on parameters that skipped `check` (clamp panics).
        a.max(-self.max_deceleration).min(self.max_acceleration)
    }
}
