//! Adaptive cruise control on radar: keep a time gap plus a standstill distance to the nearest
//! vehicle ahead on the same route, cruise at the route speed when nobody is ahead.
//!
//! Constant-time-gap law: with gap d, own speed v, leader speed v_l and desired gap
//! d* = d₀ + h·v, the acceleration is a = k_p (d − d*) + k_d (v_l − v) + a_ff, capped by the
//! free-road cruise law k_v (v_route − v) and by a braking bound −(v − v_l)² / (2 (d − d₀/2))
//! that stops the closing before the gap shrinks below half the standstill distance (once that
//! needs more than [`BRAKING_BOUND_FROM`]). In steady
//! state behind a constant-speed leader, d = d₀ + h·v exactly. Radar-only ACC is string stable
//! when 2·k_d·h + k_p·h² ≥ 2 (the default gains at 1.5 s: 2.55); at h = 0.5 s it is not
//! (0.76), which is why platoons use V2V feed-forward ([`crate::vehicles::platoon`]).

use bevy_ecs::prelude::{Component, Query};
use bevy_ecs::schedule::IntoScheduleConfigs;

use crate::sim::Control;
use crate::sim::params::{MAX_ACCEL, MAX_DISTANCE, MAX_GAIN, MAX_TIME, ParamError, Range, check_all};
use crate::sim::{Plugin, SimBuilder};
use crate::world::VehicleState;

use super::longitudinal::{LeaderGap, Longitudinal, LongitudinalSystems, install_longitudinal};

/// The braking bound acts once stopping the closing in time needs at least this [m/s²]; below,
/// the gap law alone handles it (a weaker bound would cap gentle catching up).
pub const BRAKING_BOUND_FROM: f64 = 1.0;

/// Parameters of adaptive cruise control.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct AdaptiveCruise {
    /// Time gap h [s] kept to the leader on top of the standstill distance; raising it follows
    /// farther and damps disturbances more.
    pub time_gap: f64,
    /// Standstill distance d₀ [m], bumper to bumper, kept when stopped behind the leader.
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

    /// Desired gap [m] at speed `v` [m/s]: d₀ + h·v.
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

/// Per-vehicle state of the ACC.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
#[require(Longitudinal)]
pub struct AccController {
    /// Parameters.
    pub params: AdaptiveCruise,
}

/// Adaptive cruise control for every vehicle with an [`AccController`].
pub fn control_acc(mut vehicles: Query<(&VehicleState, &AccController, &mut Longitudinal)>) {
    for (state, acc, mut lon) in &mut vehicles {
        lon.accel = acc.params.acceleration(state.speed(), lon.route_speed, lon.leader.as_ref(), 0.0);
    }
}

/// ACC in the [`Control`] schedule.
#[derive(Debug, Clone, Copy, Default)]
pub struct AccPlugin;

impl Plugin for AccPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        install_longitudinal(sim);
        sim.add_systems(Control, control_acc.in_set(LongitudinalSystems::Demand));
    }
}
