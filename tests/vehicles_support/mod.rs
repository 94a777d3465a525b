//! Helpers shared by the smart-vehicle tests: straight roads, spawning controlled vehicles,
//! building a sim with every controller and the metrics.
#![allow(dead_code)]

use std::sync::Arc;

use bevy_ecs::prelude::Bundle;
use smlworld::app::running::metrics::{Metrics, MetricsPlugin, MetricsSummary};
use smlworld::map::routing::resample;
use smlworld::prelude::*;
use smlworld::vehicles::smart_vehicles;

/// A straight open road from `a` to `b` [m], points every 0.5 m.
pub fn straight(a: DVec2, b: DVec2) -> Arc<Path> {
    Arc::new(Path::from_points(Vec::new(), resample(&[a, b], 2.0), false))
}

/// A builder with dynamics, sensors, V2V, path following, every smart controller and metrics.
pub fn builder(warmup: f64) -> SimBuilder {
    let mut b = SimBuilder::new();
    b.add_plugin(default_plugins)
        .add_plugin(PathFollowingPlugin)
        .add_plugin(smart_vehicles)
        .add_plugin(MetricsPlugin { warmup });
    b
}

/// Spawn vehicle `id` of `length` [m] at arc length `s` [m] on `path`, driving at `speed` [m/s]
/// (acceleration model, default radar), following the path at cruise speed `cruise` [m/s], with
/// the controller components `controller`.
#[allow(clippy::too_many_arguments)]
pub fn spawn(
    b: &mut SimBuilder,
    id: i32,
    path: &Arc<Path>,
    s: f64,
    speed: f64,
    length: f64,
    cruise: f64,
    controller: impl Bundle,
) {
    let (p, yaw) = path.sample(s);
    let mut spec = VehicleSpec::new(VehicleId(id), VehicleState::new(p, yaw, speed));
    spec.model = VehicleModel::Acceleration(AccelerationUnicycle::default());
    spec.size = VehicleSize { length, width: 2.0 };
    spec.sensors = SensorSet { radar: Some(Radar::default()), ..Default::default() };
    spec.route = Some(Arc::clone(path));
    let e = b.spawn_vehicle(spec).expect("fresh id");
    b.world_mut()
        .entity_mut(e)
        .insert((PathFollower::new(PathFollowing { speed: cruise, ..Default::default() }), controller));
}

/// The metrics summary of a run.
pub fn summary(sim: &Sim) -> MetricsSummary {
    sim.world().resource::<Metrics>().summary()
}

/// Bumper-to-bumper gap [m] between vehicles `ahead` and `behind` on a straight road along x.
pub fn gap_x(sim: &Sim, ahead: i32, behind: i32, length: f64) -> f64 {
    let a = sim.state(VehicleId(ahead)).expect("vehicle ahead");
    let b = sim.state(VehicleId(behind)).expect("vehicle behind");
    a.position.x - b.position.x - length
}
