//! The Intelligent Driver Model (Treiber, Hennecke, Helbing 2000, "Congested traffic states in
//! empirical observations and microscopic simulations", Phys. Rev. E 62) as a speed controller
//! of the longitudinal pipeline, with the leader from the sensors like ACC.
//!
//! `a = a_max [1 − (v/v₀)^δ − (s*/s)²]`, `s* = s₀ + v T + v Δv / (2 √(a_max b))`, with gap `s`
//! \[m\] to the leader and approach rate `Δv = v − v_leader` [m/s] (see REFERENCE.md).

use bevy_ecs::prelude::{Component, Local, Query, Res};
use bevy_ecs::schedule::IntoScheduleConfigs;

use crate::sim::Control;
use crate::sim::{Parallelism, Plugin, SimBuilder, SimClock};
use crate::world::{VehicleSize, VehicleState, Vehicles};

use super::lanes::{LanePosition, LanePositionsAt, forward_speed};
use super::longitudinal::{Longitudinal, LongitudinalSystems, install_longitudinal};

pub use super::follow_laws::{IDM_MAX_BRAKING, Idm};

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
) {
    let parallelism = parallelism.as_deref().copied().unwrap_or_else(Parallelism::single);
    let registry = registry.as_deref();
    let sizes = &sizes;
    let fresh = clock.is_some_and(|c| LanePositionsAt::fresh(lanes_at.as_deref(), c.now));
    let demand = |state: &VehicleState,
                  size: &VehicleSize,
                  idm: &IdmController,
                  lon: &mut Longitudinal,
                  pos: Option<&LanePosition>| {
        let leader = lon.leader.map(|l| {
            let length = lon.leader_length.unwrap_or_else(|| {
                registry.and_then(|r| sizes.get(r.get(l.id)?).ok()).map_or(size.length, |s| s.length)
            });
            (l.distance - 0.5 * (size.length + length), l.speed)
        });
        lon.accel = idm.params.acceleration(forward_speed(state, pos, fresh), leader);
    };
    // Straight in the ECS tables' slices (contiguous access), table by table.
    if let Ok(tables) = vehicles.contiguous_iter_mut() {
        for (states, sizes, idms, mut lons, positions) in tables {
            parallelism.for_each_chunk_at(&mut lons, &mut scratch, |start, chunk, _| {
                for (k, lon) in chunk.iter_mut().enumerate() {
                    let i = start + k;
                    demand(&states[i], &sizes[i], &idms[i], lon, positions.map(|p| &p[i]));
                }
            });
        }
    } else {
        // Only if a component were stored sparsely (none is): one at a time.
        for (state, size, idm, mut lon, pos) in &mut vehicles {
            demand(state, size, idm, &mut lon, pos);
        }
    }
}

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
