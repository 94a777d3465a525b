//! Emergency braking: full braking when the time to collision with the vehicle ahead on the
//! route drops below a threshold, whatever the speed controllers asked for.
//!
//! Time to collision = gap / closing speed (only while closing). Once triggered, braking holds
//! (also at standstill) until the vehicle ahead pulls away or is gone, so it neither chatters
//! on and off nor creeps up to a stopped vehicle.

use bevy_ecs::prelude::{Component, Query};
use bevy_ecs::schedule::IntoScheduleConfigs;

use crate::sim::Control;
use crate::sim::params::{MAX_ACCEL, MAX_TIME, ParamError, Range, check_all};
use crate::sim::{Plugin, SimBuilder};
use crate::world::VehicleState;

use super::longitudinal::{Longitudinal, LongitudinalSystems, install_longitudinal};

/// Parameters of emergency braking.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct EmergencyBraking {
    /// Time-to-collision threshold \[s\]; raising it brakes earlier (and more often).
    pub ttc: f64,
    /// Braking applied [m/s²] (positive).
    pub deceleration: f64,
}

impl EmergencyBraking {
    /// Check the values (keys relative to this table): `ttc` [0, 86400] s (0: off),
    /// `deceleration` (0, 1e3] m/s².
    pub fn check(&self) -> Result<(), ParamError> {
        check_all([
            ("ttc", self.ttc, Range::non_negative(MAX_TIME)),
            ("deceleration", self.deceleration, Range::positive(MAX_ACCEL)),
        ])
    }
}

impl Default for EmergencyBraking {
    fn default() -> Self {
        EmergencyBraking { ttc: 1.5, deceleration: 9.0 }
    }
}

/// Time to collision \[s\] for a bumper gap `gap` \[m\] closing at `closing` [m/s]; infinite when not
/// closing, zero when already touching.
pub fn time_to_collision(gap: f64, closing: f64) -> f64 {
    if gap <= 0.0 {
        0.0
    } else if closing <= 0.0 {
        f64::INFINITY
    } else {
        gap / closing
    }
}

/// Per-vehicle state of emergency braking.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
#[require(Longitudinal)]
pub struct EmergencyBrake {
    /// Parameters.
    pub params: EmergencyBraking,
    /// Whether it is braking now.
    pub active: bool,
    /// How many times it triggered.
    pub triggered: u32,
}

impl EmergencyBrake {
    /// Armed, not braking.
    pub fn new(params: EmergencyBraking) -> EmergencyBrake {
        EmergencyBrake { params, active: false, triggered: 0 }
    }
}

/// Override the demand with full braking where the time to collision is below the threshold.
pub fn brake_for_emergencies(mut vehicles: Query<(&VehicleState, &mut EmergencyBrake, &mut Longitudinal)>) {
    for (state, mut brake, mut lon) in &mut vehicles {
        let v = state.speed();
        let (ttc, closing) = match lon.leader {
            Some(l) => (time_to_collision(l.gap, v - l.speed), v - l.speed),
            None => (f64::INFINITY, 0.0),
        };
        if !brake.active && ttc < brake.params.ttc {
            brake.active = true;
            brake.triggered += 1;
        } else if brake.active && (lon.leader.is_none() || closing < 0.0) {
            brake.active = false;
        }
        lon.emergency = brake.active;
        if brake.active {
            lon.limit(-brake.params.deceleration);
        }
    }
}

/// Emergency braking in the [`Control`] schedule, after every speed controller and limiter.
#[derive(Debug, Clone, Copy, Default)]
pub struct EmergencyBrakingPlugin;

impl Plugin for EmergencyBrakingPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        install_longitudinal(sim);
        sim.add_systems(Control, brake_for_emergencies.in_set(LongitudinalSystems::Limit));
    }
}
