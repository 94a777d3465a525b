//! CommonRoad scenarios in a run: dynamic obstacles as recorded vehicles and static obstacles
//! standing where the file puts them (`obstacles = "replay"`), egos started from a planning
//! problem, and whether they reached its goal.
//!
//! Dynamic obstacle N becomes virtual vehicle -N (class from its `<type>`: car, truck, bus,
//! motorcycle, bicycle; anything else draws as a car), of its rectangle's size, without a
//! dynamics model, mailbox or sensors; its state is played from its trajectory at the file's
//! `timeStepSize` ([`crate::sim::recorded`]). Static obstacle N becomes vehicle -N too, marked
//! [`Stationary`], as the rectangle around its shapes, at rest for the whole run (the map layer
//! draws its outline). Sensors see both and the collision metrics count them like any vehicle. An ego's goal counts as reached at the first sensor tick at which its centre lies in
//! a goal position within the goal's time-step interval (goal orientation and velocity
//! constraints are not checked), and only if it did not collide before (`collision` in
//! `summary.json` then says when it did).

use std::collections::BTreeMap;
use std::sync::Arc;

use bevy_ecs::prelude::{Query, Res, ResMut, Resource};
use bevy_ecs::schedule::IntoScheduleConfigs;

use crate::app::running::metrics::Metrics;
use crate::map::LaneletMap;
use crate::map::commonroad::{CommonRoadScenario, GoalState};
use crate::sim::{
    RecordedSample, RecordedTrajectory, Sensors, SimBuilder, SimClock, SimSystems, recorded_trajectories,
};
use crate::world::{
    Stationary, VehicleClass, VehicleId, VehicleModel, VehicleSize, VehicleSpec, VehicleState, Vehicles,
};

/// The vehicle id of CommonRoad obstacle `id`: its negation (virtual), if it fits an `i32`.
pub fn obstacle_vehicle_id(id: i64) -> Option<VehicleId> {
    i32::try_from(id).ok().filter(|v| *v > 0).map(|v| VehicleId(-v))
}

fn class_of(kind: &str) -> VehicleClass {
    match kind {
        "truck" => VehicleClass::Truck,
        "bus" => VehicleClass::Bus,
        "motorcycle" => VehicleClass::Motorcycle,
        "bicycle" => VehicleClass::Bicycle,
        "parkedVehicle" => VehicleClass::Car,
        _ => VehicleClass::Car,
    }
}

/// Spawn obstacle `what` (for errors) as vehicle `id`: no dynamics model, no mailbox, its class
/// from the CommonRoad `kind`, with `extra` (its recorded trajectory, or [`Stationary`]).
fn spawn_obstacle(
    b: &mut SimBuilder,
    id: VehicleId,
    state: VehicleState,
    kind: &str,
    size: VehicleSize,
    what: &str,
    extra: impl bevy_ecs::bundle::Bundle,
) -> Result<(), String> {
    let mut spec = VehicleSpec::new(id, state);
    spec.class = class_of(kind);
    spec.size = size;
    spec.model = VehicleModel::None;
    spec.mailbox = false;
    let entity =
        b.spawn_vehicle(spec).map_err(|e| format!("{what} as vehicle {id}: {e} (scenario vehicle ids must differ)"))?;
    b.world_mut().entity_mut(entity).insert(extra);
    Ok(())
}

/// Spawn every dynamic obstacle of `sc` as a recorded vehicle and every static one as a
/// [`Stationary`] vehicle; returns how many were spawned; the error names the obstacle.
pub(crate) fn spawn_obstacles(b: &mut SimBuilder, sc: &CommonRoadScenario) -> Result<usize, String> {
    let mut spawned = 0;
    b.add_plugin(recorded_trajectories);
    for o in &sc.obstacles {
        let id = obstacle_vehicle_id(o.id)
            .ok_or_else(|| format!("obstacle {} has no vehicle id (ids 1..=2147483647 become -1, -2, ...)", o.id))?;
        let samples = o
            .states
            .iter()
            .map(|s| RecordedSample {
                t: s.time_step as f64 * sc.time_step_size,
                position: s.position,
                yaw: s.orientation,
                speed: s.velocity,
            })
            .collect();
        let Some(mut rec) = RecordedTrajectory::new(samples) else { continue };
        let state = rec.state_at(0.0);
        let what = format!("obstacle {}", o.id);
        spawn_obstacle(b, id, state, &o.kind, VehicleSize { length: o.length, width: o.width }, &what, rec)?;
        spawned += 1;
    }
    for o in &sc.static_obstacles {
        let id = obstacle_vehicle_id(o.id).ok_or_else(|| {
            format!("static obstacle {} has no vehicle id (ids 1..=2147483647 become -1, -2, ...)", o.id)
        })?;
        let state = VehicleState::with_velocity(o.position, o.orientation, glam::DVec2::ZERO);
        let what = format!("static obstacle {}", o.id);
        spawn_obstacle(b, id, state, &o.kind, VehicleSize { length: o.length, width: o.width }, &what, Stationary)?;
        spawned += 1;
    }
    Ok(spawned)
}

/// Planning-problem egos and when each reached its goal.
#[derive(Resource, Debug, Clone)]
pub struct GoalMonitor {
    map: Arc<LaneletMap>,
    time_step_size: f64,
    egos: Vec<(VehicleId, i64, Vec<GoalState>)>,
    reached: BTreeMap<i32, Option<f64>>,
    /// First collision of each ego that collided before reaching its goal [s].
    collided: BTreeMap<i32, f64>,
    obstacles: usize,
}

/// Whether and when a planning problem's ego reached its goal (`summary.json`: `commonroad.goals`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct GoalResult {
    /// The planning problem's id.
    pub planning_problem: i64,
    /// Whether the ego reached a goal state without colliding before (a goal reached after a
    /// collision does not count).
    pub reached: bool,
    /// Sim time it first did \[s\].
    pub time: Option<f64>,
    /// Sim time of the ego's first collision \[s\], if it collided before reaching the goal
    /// (`reached` is then false).
    pub collision: Option<f64>,
}

/// The `commonroad` part of `summary.json`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct CommonRoadSummary {
    /// Obstacles spawned: dynamic ones driven from their recordings plus static ones.
    pub obstacles: usize,
    /// Per ego vehicle id (JSON keys are strings): its planning problem's goal.
    pub goals: BTreeMap<i32, GoalResult>,
}

impl GoalMonitor {
    /// Watch `egos` (vehicle id, planning problem id) of `sc`; `obstacles` were spawned.
    pub(crate) fn new(
        sc: &CommonRoadScenario,
        map: Arc<LaneletMap>,
        egos: &[(VehicleId, i64)],
        obstacles: usize,
    ) -> GoalMonitor {
        let egos: Vec<_> = egos
            .iter()
            .filter_map(|(v, pp)| Some((*v, *pp, sc.planning_problems.iter().find(|p| p.id == *pp)?.goals.clone())))
            .collect();
        let reached = egos.iter().map(|(v, _, _)| (v.0, None)).collect();
        GoalMonitor { map, time_step_size: sc.time_step_size, egos, reached, collided: BTreeMap::new(), obstacles }
    }

    /// What the summary reports.
    pub fn summary(&self) -> CommonRoadSummary {
        let goals = self
            .egos
            .iter()
            .map(|(v, pp, _)| {
                let time = self.reached.get(&v.0).copied().flatten();
                let collision = self.collided.get(&v.0).copied();
                (v.0, GoalResult { planning_problem: *pp, reached: time.is_some(), time, collision })
            })
            .collect();
        CommonRoadSummary { obstacles: self.obstacles, goals }
    }
}

/// Each sensor tick: mark egos whose centre lies in a goal within its time interval; an ego
/// that collided first (see [`Metrics::collided`]) can no longer reach its goal.
pub fn check_goals(
    clock: Res<SimClock>,
    vehicles: Res<Vehicles>,
    states: Query<&VehicleState>,
    metrics: Option<Res<Metrics>>,
    mut monitor: ResMut<GoalMonitor>,
) {
    let t = clock.now.as_secs();
    let step = (t / monitor.time_step_size).round() as i64;
    let monitor = &mut *monitor;
    for (id, _, goals) in &monitor.egos {
        if monitor.reached.get(&id.0).copied().flatten().is_some() || monitor.collided.contains_key(&id.0) {
            continue;
        }
        if let Some(&crash) = metrics.as_ref().and_then(|m| m.collided.get(id)).filter(|&&crash| crash <= t) {
            monitor.collided.insert(id.0, crash);
            continue;
        }
        let Some(state) = vehicles.get(*id).and_then(|e| states.get(e).ok()) else { continue };
        let hit = goals.iter().any(|g| {
            (g.time_start..=g.time_end).contains(&step)
                && (g.shapes.is_empty() || g.shapes.iter().any(|s| s.contains(state.position, &monitor.map)))
        });
        if hit {
            monitor.reached.insert(id.0, Some(t));
        }
    }
}

/// Insert the monitor and its system (in the sensor module's Sense set).
pub(crate) fn add_goal_monitor(b: &mut SimBuilder, monitor: GoalMonitor) {
    b.insert_resource(monitor);
    b.add_systems(Sensors, check_goals.in_set(SimSystems::Sense));
}
