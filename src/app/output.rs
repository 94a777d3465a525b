//! Run outputs: the trajectory log (CSV, its own module at the log rate) and the run summary.

use std::collections::BTreeMap;
use std::io::Write;

use bevy_ecs::prelude::{Query, Res, ResMut, Resource, World};
use bevy_ecs::schedule::{IntoScheduleConfigs, ScheduleLabel};

use crate::io::lab::LabSummary;
use crate::sim::{Phase, SimClock, V2vStats};
use crate::vehicles::{LanePosition, PathFollower};
use crate::world::{VehicleClass, VehicleId, VehicleSize, VehicleState, Vehicles};

use super::{Plugin, RunReport, Sim, SimBuilder, SimSeed};

/// Schedule of the trajectory logger ([`Phase::Sense`]: it sees the state at its tick time).
#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Log;

/// Where trajectory rows go: `t,id,x,y,yaw,vx,vy,lanelet,lane_offset` [s, -, m, m, rad, m/s,
/// m/s, -, m], vehicles in id order, each number with the precision of its unit (`t` to the
/// clock's 1 µs; the rest [`Fixed`]: 1 mm, 1e-5 rad, 1 mm/s); `lanelet` is the id of the lanelet
/// under the reference point and `lane_offset` the signed offset from its centre line (left
/// positive), both empty off-road or without a map.
#[derive(Resource)]
pub struct TrajectoryLog {
    writer: Box<dyn Write + Send + Sync>,
    rows: u64,
    error: Option<std::io::Error>,
    /// Sim time of the last rows written [s], so the final state is logged exactly once.
    last_t: Option<f64>,
}

impl TrajectoryLog {
    /// Log into `writer` (the header is written at once).
    pub fn new(mut writer: Box<dyn Write + Send + Sync>) -> TrajectoryLog {
        let error = writeln!(writer, "t,id,x,y,yaw,vx,vy,lanelet,lane_offset").err();
        TrajectoryLog { writer, rows: 0, error, last_t: None }
    }

    /// Rows written so far.
    pub fn rows(&self) -> u64 {
        self.rows
    }

    /// Flush the writer; returns the first write error of the run, if any.
    pub fn finish(&mut self) -> std::io::Result<()> {
        if let Some(e) = self.error.take() {
            return Err(e);
        }
        self.writer.flush()
    }
}

/// Decimals of lengths [m] and speeds [m/s] in `trajectories.csv`: 1 mm and 1 mm/s.
pub const LENGTH_DECIMALS: usize = 3;
/// Decimals of angles [rad] in `trajectories.csv`: 1e-5 rad (0.6 mdeg, 1 mm at 100 m).
pub const ANGLE_DECIMALS: usize = 5;

/// A number written with at most `.1` decimals, trailing zeros dropped (`12.5`, `0`, `-3.142`),
/// never `-0`: a CSV carries the precision of its unit, not 17 digits of float noise.
pub struct Fixed(pub f64, pub usize);

impl std::fmt::Display for Fixed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let text = format!("{:.*}", self.1, self.0);
        let text = if text.contains('.') { text.trim_end_matches('0').trim_end_matches('.') } else { &text };
        // A value that rounds to zero from below prints as `-0`: a sign that is not there.
        f.write_str(if text == "-0" { "0" } else { text })
    }
}

/// Append every vehicle's state at this tick to the [`TrajectoryLog`].
pub fn log_trajectories(
    clock: Res<SimClock>,
    vehicles: Res<Vehicles>,
    states: Query<(&VehicleState, Option<&LanePosition>)>,
    log: Option<ResMut<TrajectoryLog>>,
) {
    let Some(mut log) = log else { return };
    if log.error.is_some() {
        return;
    }
    let t = clock.now.as_secs();
    if log.last_t == Some(t) {
        return;
    }
    log.last_t = Some(t);
    for (id, e) in vehicles.iter() {
        if let Ok((s, lane)) = states.get(e) {
            let r = write!(
                log.writer,
                "{t:.6},{id},{},{},{},{},{}",
                Fixed(s.position.x, LENGTH_DECIMALS),
                Fixed(s.position.y, LENGTH_DECIMALS),
                Fixed(s.yaw, ANGLE_DECIMALS),
                Fixed(s.velocity.x, LENGTH_DECIMALS),
                Fixed(s.velocity.y, LENGTH_DECIMALS)
            )
            .and_then(|()| match lane.and_then(|l| Some((l.lanelet?, l.offset))) {
                Some((id, offset)) => writeln!(log.writer, ",{},{}", id.0, Fixed(offset, LENGTH_DECIMALS)),
                None => writeln!(log.writer, ",,"),
            });
            if let Err(e) = r {
                log.error = Some(e);
                return;
            }
            log.rows += 1;
        }
    }
}

/// Log the state at the end of a run (unless the logger's own tick already did): a 600 s run
/// ends with rows at t = 600, not at the last tick of the log rate.
pub fn log_final_state(sim: &mut Sim) {
    use bevy_ecs::system::RunSystemOnce;
    // The system's parameters are all resources and a query, always valid: the error is
    // unreachable, and a write error is kept in the log for `finish` to report.
    crate::vehicles::refresh_lane_positions(sim.world_mut());
    let _ = sim.world_mut().run_system_once(log_trajectories);
}

/// The trajectory logger as a module of its own at `rate` [Hz]; insert a [`TrajectoryLog`]
/// resource to say where the rows go.
#[derive(Debug, Clone, Copy)]
pub struct TrajectoryLogPlugin {
    /// Log rate [Hz].
    pub rate: f64,
}

impl Plugin for TrajectoryLogPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.add_module("log", Log, Phase::Sense, self.rate);
        // Lane positions are found where they are read (see `update_lane_positions`).
        sim.add_systems(Log, (crate::vehicles::lanes::update_lane_positions, log_trajectories).chain());
    }
}

/// Deliveries per V2V channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct MessagesDelivered {
    /// Network deliveries (one message to one receiver counts one).
    pub network: u64,
    /// Wifi deliveries.
    pub wifi: u64,
}

/// `summary.json` of a run.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RunSummary {
    /// Sim time covered [s] (the time reached when the run was interrupted).
    pub sim_seconds: f64,
    /// Whether Ctrl-C or SIGTERM stopped the run before its end (the outputs hold what ran).
    pub interrupted: bool,
    /// Wall-clock time taken [s].
    pub wall_seconds: f64,
    /// Sim seconds per wall second.
    pub real_time_factor: f64,
    /// Number of vehicles.
    pub vehicles: usize,
    /// V2V deliveries per channel.
    pub messages_delivered: MessagesDelivered,
    /// Rate warnings of the real-time runner.
    pub rate_warnings: u64,
    /// The scenario's seed.
    pub seed: u64,
    /// Per vehicle id (JSON keys are strings), for every vehicle with a route: largest distance
    /// to its route's centre line [m], seen by its path follower at every control tick, or for a
    /// vehicle without one (driven from Python, by a student's controller, by nothing) after
    /// every dynamics step.
    pub max_distance_to_centre_line: BTreeMap<i32, f64>,
    /// Collisions, follower gaps and platoon string stability (when [`super::metrics::MetricsPlugin`] ran).
    pub metrics: Option<super::metrics::MetricsSummary>,
    /// Real vehicles and lab bridges (motion capture, trucks, stream); absent without them.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lab: Option<LabSummary>,
    /// CommonRoad obstacles and planning-problem goals; absent without a CommonRoad map.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub commonroad: Option<super::scenario::commonroad::CommonRoadSummary>,
    /// What `smlworld replay` needs to redraw the run from `trajectories.csv` (map, log rate,
    /// vehicle classes and sizes); set by [`super::run_scenario`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub replay: Option<ReplayInfo>,
}

/// The `replay` part of `summary.json`: what a run's `trajectories.csv` does not say.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReplayInfo {
    /// The map file the run drove on (absolute when it could be resolved); `None` without a map.
    pub map: Option<std::path::PathBuf>,
    /// Trajectory log rate [Hz]: rows of `trajectories.csv` are this far apart in time.
    pub log_rate: f64,
    /// Every vehicle, in the order the run's visualisation stream sent them.
    pub vehicles: Vec<ReplayVehicle>,
}

/// One vehicle of [`ReplayInfo`].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReplayVehicle {
    /// Vehicle id (non-negative: real, negative: virtual).
    pub id: i32,
    /// Vehicle class (`car`, `truck`, ...).
    pub class: VehicleClass,
    /// Body length [m].
    pub length: f64,
    /// Body width [m].
    pub width: f64,
}

impl ReplayInfo {
    /// The vehicles of `world` (in the stream's query order), with the run's `map` and `log_rate` [Hz].
    pub fn of(world: &mut World, map: Option<std::path::PathBuf>, log_rate: f64) -> ReplayInfo {
        let mut query = world.query::<(&VehicleId, &VehicleState, &VehicleClass, Option<&VehicleSize>)>();
        let vehicles = query
            .iter(world)
            .map(|(id, _, class, size)| {
                let size = size.copied().unwrap_or_default();
                ReplayVehicle { id: id.0, class: *class, length: size.length, width: size.width }
            })
            .collect();
        ReplayInfo { map, log_rate, vehicles }
    }
}

impl RunSummary {
    /// Summarise `sim` after a run described by `report`.
    pub fn new(sim: &Sim, report: &RunReport) -> RunSummary {
        let world = sim.world();
        let stats = world.get_resource::<V2vStats>().copied().unwrap_or_default();
        let vehicles = world.resource::<Vehicles>();
        let deviation = world.get_resource::<super::metrics::Metrics>().map(|m| &m.route_deviation);
        let max_distance_to_centre_line = vehicles
            .iter()
            .filter_map(|(id, e)| match world.get::<PathFollower>(e) {
                Some(f) => Some((id.0, f.max_offset)),
                None => Some((id.0, deviation?.get(&id)?.max_offset)),
            })
            .collect();
        RunSummary {
            sim_seconds: report.sim_seconds,
            interrupted: report.interrupted,
            wall_seconds: report.wall_seconds,
            real_time_factor: if report.wall_seconds > 0.0 {
                report.sim_seconds / report.wall_seconds
            } else {
                f64::INFINITY
            },
            vehicles: vehicles.len(),
            messages_delivered: MessagesDelivered { network: stats.network_delivered, wifi: stats.wifi_delivered },
            rate_warnings: sim.rate_warnings(),
            seed: world.get_resource::<SimSeed>().map_or(0, |s| s.0),
            max_distance_to_centre_line,
            metrics: world.get_resource::<super::metrics::Metrics>().map(|m| {
                let mut summary = m.summary();
                if let Some(log) = world.get_resource::<crate::vehicles::LaneChangeLog>() {
                    summary.lane_changes = Some(log.events.clone());
                    summary.lane_change_summary = Some(super::metrics::LaneChangeSummary::of(log));
                }
                if let Some(t) = world.get_resource::<super::traffic::Traffic>() {
                    use super::traffic::{Throughput, TrafficSummary};
                    summary.traffic =
                        Some(TrafficSummary { inserted: t.inserted, removed: t.removed, waiting_max: t.waiting_max });
                    let hours = report.sim_seconds / 3600.0;
                    let per_hour = if hours > 0.0 { t.removed as f64 / hours } else { 0.0 };
                    summary.throughput = Some(Throughput { vehicles_out: t.removed, per_hour });
                }
                summary.v2v = world.get_resource::<crate::sim::V2vChannelStats>().map(super::metrics::V2vMetrics::of);
                summary.emergency = world
                    .get_resource::<crate::vehicles::EmergencyLog>()
                    .and_then(crate::vehicles::EmergencyLog::summary);
                summary.merge =
                    world.get_resource::<crate::vehicles::MergeLog>().and_then(crate::vehicles::MergeLog::summary);
                summary.sensors = world.get_resource::<crate::sim::SensorStats>().copied();
                summary
            }),
            lab: LabSummary::of(world),
            commonroad: world.get_resource::<super::scenario::commonroad::GoalMonitor>().map(|m| m.summary()),
            replay: None,
        }
    }
}
