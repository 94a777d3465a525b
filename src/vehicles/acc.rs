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
use crate::sim::{Plugin, SimBuilder};
use crate::world::VehicleState;

use super::longitudinal::{Longitudinal, LongitudinalSystems, install_longitudinal};

pub use super::follow_laws::{AdaptiveCruise, BRAKING_BOUND_FROM};

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
