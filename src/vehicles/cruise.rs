//! Cruise control: a PID on speed (throttle = kp·e + ki·∫e + kd·ė plus drag feed-forward), with
//! an optional scripted speed dip for demos and tests (a leader braking hard).
//!
//! The reference speed is the route's target speed ([`Longitudinal::route_speed`], i.e. the path
//! follower's cruise speed) except during a [`SpeedDip`]; it moves towards its target at bounded
//! rates and its rate of change is fed forward, so a scripted braking at 6 m/s² really brakes at
//! 6 m/s². The gains act on throttle \[N\]: the original 500/50/150 suit a 1000 kg car; they are
//! scaled by mass / 1000 kg for heavier models so the closed loop keeps its speed.

use bevy_ecs::prelude::{Component, Query, Res};
use bevy_ecs::schedule::IntoScheduleConfigs;

use crate::sim::params::{MAX_ACCEL, MAX_GAIN, MAX_SPEED, MAX_TIME, ParamError, Range, check_all};
use crate::sim::{Control, SimClock};
use crate::sim::{Plugin, SimBuilder};
use crate::world::{AccelerationUnicycle, VehicleState};

use super::longitudinal::{Longitudinal, LongitudinalSystems, install_longitudinal};

/// A scripted slow-down: at `at` the reference speed ramps down to `speed` at `deceleration`,
/// holds for `hold`, then ramps back to the cruise speed at the controller's `max_acceleration`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct SpeedDip {
    /// Start of the dip [s of sim time].
    pub at: f64,
    /// Speed to slow down to [m/s].
    pub speed: f64,
    /// Deceleration of the ramp down [m/s²] (positive).
    pub deceleration: f64,
    /// How long to hold the low speed once reached \[s\]; infinite keeps it for ever.
    #[serde(default)]
    pub hold: f64,
}

/// Parameters of the cruise controller.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct CruiseControl {
    /// Proportional gain [N/(m/s)] for a 1000 kg vehicle; raising it reacts harder to speed errors.
    pub kp: f64,
    /// Integral gain [N/m] for a 1000 kg vehicle; removes steady errors (e.g. model mismatch).
    pub ki: f64,
    /// Derivative gain [N s/(m/s)] for a 1000 kg vehicle; damps overshoot.
    pub kd: f64,
    /// Largest acceleration of the reference speed [m/s²].
    pub max_acceleration: f64,
    /// Largest braking the controller asks for [m/s²] (positive).
    pub max_deceleration: f64,
    /// Optional scripted slow-down.
    pub dip: Option<SpeedDip>,
}

impl SpeedDip {
    /// Check the values (keys relative to `dip`).
    pub fn check(&self) -> Result<(), ParamError> {
        check_all([
            ("at", self.at, Range::non_negative(MAX_TIME)),
            ("speed", self.speed, Range::non_negative(MAX_SPEED)),
            ("deceleration", self.deceleration, Range::positive(MAX_ACCEL)),
        ])?;
        // `hold` may be infinite (keep the low speed for ever), never NaN or negative.
        if self.hold.is_nan() || self.hold < 0.0 {
            return Err(ParamError {
                key: "hold".into(),
                problem: format!("must be zero or more [s] (inf: for ever), got {}", self.hold),
            });
        }
        Ok(())
    }
}

impl CruiseControl {
    /// Check the values: every gain in [0, 1e6], `max_acceleration` and `max_deceleration` in
    /// (0, 1e3] m/s², and the dip's (keys relative to this table).
    pub fn check(&self) -> Result<(), ParamError> {
        check_all([
            ("kp", self.kp, Range::non_negative(MAX_GAIN)),
            ("ki", self.ki, Range::non_negative(MAX_GAIN)),
            ("kd", self.kd, Range::non_negative(MAX_GAIN)),
            ("max_acceleration", self.max_acceleration, Range::positive(MAX_ACCEL)),
            ("max_deceleration", self.max_deceleration, Range::positive(MAX_ACCEL)),
        ])?;
        match &self.dip {
            Some(d) => d.check().map_err(|e| e.within("dip")),
            None => Ok(()),
        }
    }
}

impl Default for CruiseControl {
    fn default() -> Self {
        CruiseControl { kp: 500.0, ki: 50.0, kd: 150.0, max_acceleration: 2.0, max_deceleration: 9.0, dip: None }
    }
}

/// Per-vehicle state of the cruise controller.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
#[require(Longitudinal)]
pub struct CruiseController {
    /// Parameters.
    pub params: CruiseControl,
    /// Current reference speed [m/s] (NaN before the first tick: starts at the current speed).
    pub reference: f64,
    integral: f64,
    last_error: f64,
}

impl CruiseController {
    /// A controller that has not run yet.
    pub fn new(params: CruiseControl) -> CruiseController {
        CruiseController { params, reference: f64::NAN, integral: 0.0, last_error: 0.0 }
    }
}

/// Target of the reference speed at time `t` [s] and the rate [m/s²] to move towards it at.
fn reference_target(p: &CruiseControl, cruise: f64, t: f64) -> (f64, f64) {
    if let Some(dip) = p.dip
        && t >= dip.at
    {
        let ramp = (cruise - dip.speed).max(0.0) / dip.deceleration.max(1e-9);
        if t < dip.at + ramp + dip.hold.max(0.0) {
            return (dip.speed, dip.deceleration);
        }
    }
    (cruise, p.max_acceleration)
}

/// PID on speed for every vehicle with a [`CruiseController`].
pub fn control_cruise(
    clock: Res<SimClock>,
    mut vehicles: Query<(&VehicleState, Option<&AccelerationUnicycle>, &mut CruiseController, &mut Longitudinal)>,
) {
    let t = clock.now.as_secs();
    let dt = clock.dt;
    for (state, model, mut cc, mut lon) in &mut vehicles {
        let p = cc.params;
        let v = state.speed();
        if cc.reference.is_nan() {
            cc.reference = v;
        }
        let (target, rate) = reference_target(&p, lon.route_speed, t);
        let step = (target - cc.reference).max(-rate * dt).min(rate * dt);
        let ff = if dt > 0.0 { step / dt } else { 0.0 };
        cc.reference += step;
        let error = cc.reference - v;
        cc.integral = (cc.integral + error * dt).clamp(-20.0, 20.0);
        let derivative = if dt > 0.0 { (error - cc.last_error) / dt } else { 0.0 };
        cc.last_error = error;
        let mass = model.map_or(1000.0, |m| m.mass);
        let pid = (p.kp * error + p.ki * cc.integral + p.kd * derivative) * mass / 1000.0;
        let accel = ff + pid / mass;
        debug_assert!(p.check().is_ok(), "cruise parameters not checked: {p:?}");
        // max/min, not clamp: total even on parameters that skipped `check` (clamp panics).
        lon.accel = accel.max(-p.max_deceleration).min(p.max_acceleration.max(ff));
    }
}

/// Cruise control in the [`Control`] schedule.
#[derive(Debug, Clone, Copy, Default)]
pub struct CruisePlugin;

impl Plugin for CruisePlugin {
    fn build(&self, sim: &mut SimBuilder) {
        install_longitudinal(sim);
        sim.add_systems(Control, control_cruise.in_set(LongitudinalSystems::Demand));
    }
}
