//! `smlworld bench --soak SECONDS`: the benchmark world run for a wall-clock time while the
//! process's resident memory is sampled, to show that a long run does not grow: memory after the
//! warm-up stays within [`FLAT_TOLERANCE`] of what it was at the end of the warm-up.

use std::time::{Duration, Instant};

use crate::sim::{Parallelism, Sim};
use crate::vehicles::{FollowLaw, IdmController, LaneChangeParams, LaneChanger, LanePosition, PathFollower, RouteGoal};
use crate::world::{
    Radar, Route, SensorSet, VehicleId, VehicleSpec, VehicleState, Vehicles, Velodyne, despawn_vehicle,
};

use super::bench::{BenchError, BenchWorld};

/// Largest growth of resident memory after the warm-up that still counts as flat [-] (5 %).
pub const FLAT_TOLERANCE: f64 = 0.05;

/// Sim time between two rounds of traffic churn in a soak \[s\].
pub const CHURN_PERIOD: f64 = 10.0;
/// Share of the vehicles that leave and enter in one round of churn [-].
pub const CHURN_SHARE: f64 = 0.05;

/// The warm-up [s of wall time]: the first minute, or a third of a shorter soak.
pub fn warm_up(wall_seconds: f64) -> f64 {
    60f64.min(wall_seconds / 3.0)
}

/// One sample of a soak.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SoakSample {
    /// Wall time since the start of the run \[s\].
    pub wall_s: f64,
    /// Sim time reached \[s\].
    pub sim_s: f64,
    /// Resident memory of the process \[MB\].
    pub rss_mb: f64,
}

/// What a soak measured: printed as JSON by `smlworld bench --soak`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SoakReport {
    /// Number of vehicles.
    pub vehicles: usize,
    /// Wall time asked for \[s\].
    pub wall_seconds: f64,
    /// Sim time run \[s\].
    pub sim_seconds: f64,
    /// Warm-up excluded from the flatness check [s of wall time].
    pub warm_up_s: f64,
    /// Resident memory at the end of the warm-up \[MB\].
    pub rss_after_warm_up_mb: f64,
    /// Largest resident memory after the warm-up \[MB\].
    pub rss_max_after_warm_up_mb: f64,
    /// `rss_max_after_warm_up_mb / rss_after_warm_up_mb - 1` [-].
    pub growth: f64,
    /// `growth <= FLAT_TOLERANCE`.
    pub flat: bool,
    /// Whether Ctrl-C or SIGTERM ended the soak early.
    pub interrupted: bool,
    /// Vehicles that left and were replaced by new ones (traffic churn, with lane changes).
    pub vehicles_replaced: u64,
    /// Every sample, in time order.
    pub samples: Vec<SoakSample>,
}

/// Resident memory of this process now \[MB\] (Linux `VmRSS`), if known.
pub fn rss_mb() -> Option<f64> {
    super::bench::proc_self_mb("status", "VmRSS")
}

/// Run `world` for `wall_seconds` of wall time, sampling memory every `every` \[s\] (`on_sample`
/// sees each sample as it is taken, e.g. to print progress).
pub fn soak(
    world: &BenchWorld,
    wall_seconds: f64,
    every: f64,
    parallelism: Option<Parallelism>,
    mut on_sample: impl FnMut(&SoakSample),
) -> Result<SoakReport, BenchError> {
    let mut builder = world.builder()?;
    builder.insert_resource(parallelism.unwrap_or_default());
    let mut sim = builder.build();
    let start = Instant::now();
    let end = Duration::from_secs_f64(wall_seconds);
    let mut next_sample = Duration::ZERO;
    let mut samples = Vec::new();
    let mut interrupted = false;
    let mut sample = |sim_s: f64, wall: Duration, samples: &mut Vec<SoakSample>| {
        let s = SoakSample { wall_s: wall.as_secs_f64(), sim_s, rss_mb: rss_mb().unwrap_or(0.0) };
        on_sample(&s);
        samples.push(s);
    };
    let mut next_id = -(world.vehicles as i64) - 1;
    let mut next_churn = CHURN_PERIOD;
    let churn_count = ((world.vehicles as f64 * CHURN_SHARE).ceil() as usize).max(1);
    let mut churned = 0u64;
    loop {
        if world.lane_change && sim.now().as_secs() >= next_churn {
            churned += churn(&mut sim, churn_count, &mut next_id) as u64;
            next_churn += CHURN_PERIOD;
        }
        let wall = start.elapsed();
        if wall >= next_sample {
            sample(sim.now().as_secs(), wall, &mut samples);
            next_sample += Duration::from_secs_f64(every);
        }
        if wall >= end {
            break;
        }
        let report = super::runner::run_headless(&mut sim, 0.5, 0.5, |_| {});
        if report.interrupted {
            interrupted = true;
            sample(sim.now().as_secs(), start.elapsed(), &mut samples);
            break;
        }
    }
    let warm = warm_up(wall_seconds);
    let after: Vec<&SoakSample> = samples.iter().filter(|s| s.wall_s >= warm).collect();
    let base = after.first().map_or(0.0, |s| s.rss_mb);
    let max = after.iter().map(|s| s.rss_mb).fold(base, f64::max);
    let growth = if base > 0.0 { max / base - 1.0 } else { 0.0 };
    Ok(SoakReport {
        vehicles: world.vehicles,
        wall_seconds,
        sim_seconds: sim.now().as_secs(),
        warm_up_s: warm,
        rss_after_warm_up_mb: base,
        rss_max_after_warm_up_mb: max,
        growth,
        flat: growth <= FLAT_TOLERANCE,
        interrupted,
        vehicles_replaced: churned,
        samples,
    })
}

/// One round of churn: the `count` oldest vehicles (ids nearest -1) leave the world (despawned:
/// entity, mailbox, sensor readings and lane-change state freed) and as many enter where they
/// were, with new ids (counting down from `next_id`) and fresh IDM and lane-change state, as
/// `[[traffic]]` removal and insertion do. Returns how many were replaced.
fn churn(sim: &mut Sim, count: usize, next_id: &mut i64) -> usize {
    let leaving: Vec<VehicleId> = {
        let vehicles = sim.world().resource::<Vehicles>();
        let mut ids: Vec<VehicleId> = vehicles.iter().map(|(id, _)| id).collect();
        ids.sort_unstable_by_key(|id| std::cmp::Reverse(id.0));
        ids.truncate(count);
        ids
    };
    let mut replaced = 0;
    for id in leaving {
        let Some(e) = sim.entity(id) else { continue };
        let world = sim.world();
        let (Some(state), Some(route), Some(follower), Some(idm)) = (
            world.get::<VehicleState>(e).copied(),
            world.get::<Route>(e).cloned(),
            world.get::<PathFollower>(e).copied(),
            world.get::<IdmController>(e).copied(),
        ) else {
            continue;
        };
        let Ok(new_id) = i32::try_from(*next_id) else { return replaced };
        if despawn_vehicle(sim.world_mut(), id).is_err() {
            continue;
        }
        *next_id -= 1;
        let mut spec = VehicleSpec::new(VehicleId(new_id), state);
        spec.sensors =
            SensorSet { radar: Some(Radar::default()), velodyne: Some(Velodyne::default()), omniscient: false };
        spec.route = Some(route.0);
        if let Ok(e) = sim.spawn_vehicle(spec) {
            let law = FollowLaw::Idm(idm.params);
            sim.world_mut().entity_mut(e).insert((
                follower,
                idm,
                LanePosition::default(),
                LaneChanger::new(LaneChangeParams::default(), law, RouteGoal::Loop),
            ));
            replaced += 1;
        }
    }
    replaced
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::VehicleState;

    /// The soak's churn must not leave anything behind: bevy's records of removed components
    /// are cleared every step (they grew by ~360 B per departed vehicle, the soak's memory with them).
    #[test]
    fn churn_leaves_no_record_of_the_departed_vehicles_behind() {
        let world = BenchWorld { vehicles: 200, lane_change: true, ..Default::default() };
        let mut b = world.builder().expect("the bench world builds");
        b.insert_resource(Parallelism::single());
        let mut sim = b.build();
        let mut next_id = -201;
        sim.run_for(1.0);
        assert_eq!(churn(&mut sim, 10, &mut next_id), 10, "ten vehicles replaced");
        assert_eq!(sim.world().resource::<Vehicles>().iter().count(), 200);
        sim.run_for(0.1);
        assert_eq!(sim.world().removed::<VehicleState>().count(), 0, "removal records kept after a step");
    }
}
