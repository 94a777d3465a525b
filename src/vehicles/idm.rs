//! The Intelligent Driver Model (Treiber, Hennecke, Helbing 2000, "Congested traffic states in
//! empirical observations and microscopic simulations", Phys. Rev. E 62) as a speed controller
//! of the longitudinal pipeline, with the leader from the sensors like ACC.
//!
//! `a = a_max [1 − (v/v₀)^δ − (s*/s)²]`, `s* = s₀ + v T + v Δv / (2 √(a_max b))`, with gap `s`
//! [m] to the leader and approach rate `Δv = v − v_leader` [m/s] (see REFERENCE.md).

use bevy_ecs::prelude::{Component, Local, Mut, Query, Res};
use bevy_ecs::schedule::IntoScheduleConfigs;

use crate::sim::Control;
use crate::sim::parallel::recycle;
use crate::sim::params::{MAX_ACCEL, MAX_DISTANCE, MAX_SPEED, MAX_TIME, ParamError, Range, check_all};
use crate::sim::{Parallelism, Plugin, SimBuilder, SimClock};
use crate::world::{VehicleSize, VehicleState, Vehicles};

use super::lanes::{LanePosition, LanePositionsAt, forward_speed};
use super::longitudinal::{Longitudinal, LongitudinalSystems, install_longitudinal};

/// Largest braking the IDM asks for [m/s²] (its formula is unbounded when the gap closes).
pub const IDM_MAX_BRAKING: f64 = 9.0;

/// IDM parameters: `controller = { type = "idm", speed, time_gap, min_gap, accel, decel, delta }`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct Idm {
    /// Desired speed v₀ [m/s] (also the path follower's cruise speed).
    pub speed: f64,
    /// Desired time gap T [s]; raising it follows farther.
    pub time_gap: f64,
    /// Standstill gap s₀ [m], bumper to bumper.
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

/// Per-vehicle state of the IDM.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
#[require(Longitudinal)]
pub struct IdmController {
    /// Parameters.
    pub params: Idm,
}

/// The IDM for every vehicle with an [`IdmController`]: the leader is
/// [`Longitudinal::leader`] (from the sensors). The gap is bumper to bumper with the leader's
/// own length (a radar measures to the rear of what it sees), not [`super::LeaderGap::gap`]'s
/// assumption that the leader is as long as we are: a car behind a truck keeps its gap.
///
/// Split over threads (each vehicle's demand depends only on its own components and its
/// leader's length, so any thread count gives the same bits).
#[allow(clippy::type_complexity)]
pub fn control_idm(
    clock: Option<Res<SimClock>>,
    registry: Option<Res<Vehicles>>,
    parallelism: Option<Res<Parallelism>>,
    lanes_at: Option<Res<LanePositionsAt>>,
    sizes: Query<&VehicleSize>,
    mut vehicles: Query<(&VehicleState, &VehicleSize, &IdmController, &mut Longitudinal, Option<&LanePosition>)>,
    mut scratch: Local<Vec<()>>,
    mut buffer: Local<Vec<IdmItem<'static>>>,
) {
    let parallelism = parallelism.as_deref().copied().unwrap_or_else(Parallelism::single);
    let registry = registry.as_deref();
    let sizes = &sizes;
    let fresh = clock.is_some_and(|c| LanePositionsAt::fresh(lanes_at.as_deref(), c.now));
    let mut items: Vec<IdmItem<'_>> = recycle(std::mem::take(&mut *buffer));
    items.extend(vehicles.iter_mut());
    parallelism.for_each_chunk(&mut items, &mut scratch, |chunk, _| {
        for (state, size, idm, lon, pos) in chunk.iter_mut() {
            let leader = lon.leader.map(|l| {
                let length = lon.leader_length.unwrap_or_else(|| {
                    registry.and_then(|r| sizes.get(r.get(l.id)?).ok()).map_or(size.length, |s| s.length)
                });
                (l.distance - 0.5 * (size.length + length), l.speed)
            });
            lon.accel = idm.params.acceleration(forward_speed(state, *pos, fresh), leader);
        }
    });
    *buffer = recycle(items);
}

/// One vehicle's part of [`control_idm`].
type IdmItem<'a> =
    (&'a VehicleState, &'a VehicleSize, &'a IdmController, Mut<'a, Longitudinal>, Option<&'a LanePosition>);

/// The IDM in the [`Control`] schedule.
#[derive(Debug, Clone, Copy, Default)]
pub struct IdmPlugin;

impl Plugin for IdmPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        install_longitudinal(sim);
        sim.add_systems(Control, control_idm.in_set(LongitudinalSystems::Demand));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn free_road_accelerates_below_and_brakes_above_the_desired_speed() {
        let idm = Idm::default();
        assert!((idm.acceleration(0.0, None) - idm.accel).abs() < 1e-12);
        assert!(idm.acceleration(29.0, None) > 0.0);
        assert!(idm.acceleration(31.0, None) < 0.0);
        assert!(idm.acceleration(30.0, None).abs() < 1e-12);
    }

    #[test]
    fn closing_in_on_a_slower_leader_brakes_harder_than_following_an_equal_one() {
        let idm = Idm::default();
        let equal = idm.acceleration(20.0, Some((40.0, 20.0)));
        let closing = idm.acceleration(20.0, Some((40.0, 10.0)));
        assert!(closing < equal && closing < 0.0, "{closing} {equal}");
        // The equilibrium gap at 20 m/s: s0 + v T = 32 m, where a free term of 1 - (20/30)^4 balances.
        assert!(idm.acceleration(20.0, Some((1.0, 0.0))) <= -IDM_MAX_BRAKING + 1e-9);
    }
}
