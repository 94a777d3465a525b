//! Cruise control: a PID on speed (throttle = kp·e + ki·∫e + kd·ė plus drag feed-forward), with
//! an optional scripted speed dip for demos and tests (a leader braking hard).
//!
//! The reference speed is the route's target speed ([`Longitudinal::route_speed`], i.e. the path
//! follower's cruise speed) except during a [`SpeedDip`]; it moves towards its target at bounded
//! rates and its rate of change is fed forward, so a scripted braking at 6 m/s² really brakes at
//! 6 m/s². The gains act on throttle [N]: the original 500/50/150 suit a 1000 kg car; they are
//! scaled by mass / 1000 kg for heavier models so the closed loop keeps its speed.

use bevy_ecs::prelude::{Component, Query, Res};
use bevy_ecs::schedule::IntoScheduleConfigs;

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
    /// How long to hold the low speed once reached [s]; infinite keeps it for ever.
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
        let step = (target - cc.reference).clamp(-rate * dt, rate * dt);
        let ff = if dt > 0.0 { step / dt } else { 0.0 };
        cc.reference += step;
        let error = cc.reference - v;
        cc.integral = (cc.integral + error * dt).clamp(-20.0, 20.0);
        let derivative = if dt > 0.0 { (error - cc.last_error) / dt } else { 0.0 };
        cc.last_error = error;
        let mass = model.map_or(1000.0, |m| m.mass);
        let pid = (p.kp * error + p.ki * cc.integral + p.kd * derivative) * mass / 1000.0;
        let accel = ff + pid / mass;
        lon.accel = accel.clamp(-p.max_deceleration, p.max_acceleration.max(ff));
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
