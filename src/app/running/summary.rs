//! What a run reports: `summary.json` ([`RunSummary`]: times, deliveries, metrics, lab and
//! CommonRoad summaries) and the part of it that `smlworld replay` reads ([`ReplayInfo`]).

use std::collections::BTreeMap;

use bevy_ecs::prelude::{Has, World};

use crate::io::lab::LabSummary;
use crate::sim::{Sim, SimSeed, V2vStats};
use crate::vehicles::PathFollower;
use crate::world::{LabDriven, Stationary, VehicleClass, VehicleId, VehicleSize, VehicleState, Vehicles};

use super::runner::RunReport;

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
    /// Sim time covered \[s\] (the time reached when the run was interrupted).
    pub sim_seconds: f64,
    /// Whether Ctrl-C or SIGTERM stopped the run before its end (the outputs hold what ran).
    pub interrupted: bool,
    /// Wall-clock time taken \[s\].
    pub wall_seconds: f64,
    /// Sim seconds per wall second.
    pub real_time_factor: f64,
    /// Number of vehicles in the world at the end (background traffic that left is counted in
    /// `metrics.traffic.removed`).
    pub vehicles: usize,
    /// V2V deliveries per channel.
    pub messages_delivered: MessagesDelivered,
    /// Rate warnings of the real-time runner.
    pub rate_warnings: u64,
    /// The scenario's seed.
    pub seed: u64,
    /// Per vehicle id (JSON keys are strings), for every vehicle with a route, those removed
    /// during the run (background traffic at its route's end) included: largest distance
    /// to its route's centre line \[m\], seen by its path follower at every control tick, or for a
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
    /// vehicle classes and sizes); set by [`crate::app::run_scenario`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub replay: Option<ReplayInfo>,
}

/// The `replay` part of `summary.json`: what a run's `trajectories.csv` does not say.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReplayInfo {
    /// The map file the run drove on (absolute when it could be resolved); `None` without a map.
    pub map: Option<std::path::PathBuf>,
    /// Trajectory log rate \[Hz\]: rows of `trajectories.csv` are this far apart in time.
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
    /// Body length \[m\].
    pub length: f64,
    /// Body width \[m\].
    pub width: f64,
    /// A stationary obstacle (CommonRoad static obstacle): the map draws it, replays draw no
    /// sprite for it. Absent (false) for every other vehicle.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub stationary: bool,
    /// Its state came from the lab (motion capture, a real truck): replays draw it "real".
    /// Absent (false) for every virtual vehicle.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub lab: bool,
}

impl ReplayInfo {
    /// The vehicles of `world` (in the stream's query order), with the run's `map` and `log_rate` \[Hz\].
    pub fn of(world: &mut World, map: Option<std::path::PathBuf>, log_rate: f64) -> ReplayInfo {
        let mut query = world.query::<(
            &VehicleId,
            &VehicleState,
            &VehicleClass,
            Option<&VehicleSize>,
            Has<Stationary>,
            Has<LabDriven>,
        )>();
        let vehicles = query
            .iter(world)
            .map(|(id, _, class, size, stationary, lab)| {
                let size = size.copied().unwrap_or_default();
                ReplayVehicle { id: id.0, class: *class, length: size.length, width: size.width, stationary, lab }
            })
            .collect();
        ReplayInfo { map, log_rate, vehicles }
    }
}

/// Decimals a figure of `summary.json` keeps, from its key (the unit its name gives), as the CSV
/// keeps the precision of its unit: times \[s\] the clock's 1 µs (`t`, `t_*`, `*_s`, `*seconds*`,
/// `*time*`, ...), milliseconds 1 µs too, angles 1e-5 rad, dimensionless ratios and rates
/// 1e-6; everything else (lengths \[m\], speeds [m/s], accelerations [m/s²], per-hour counts)
/// 1 mm, 1 mm/s, 1 mm/s².
pub fn figure_decimals(key: &str) -> usize {
    let k = key.to_ascii_lowercase();
    let words: Vec<&str> = k.split('_').collect();
    let has = |w: &str| words.contains(&w);
    if has("ms") {
        3
    } else if has("t")
        || has("s")
        || has("time")
        || has("seconds")
        || has("wait")
        || has("waited")
        || has("depart")
        || has("until")
        || has("warmup")
        || has("duration")
        || has("age")
    {
        crate::app::results::output::TIME_DECIMALS
    } else if has("yaw") || has("angle") || has("rad") || has("heading") {
        crate::app::results::output::ANGLE_DECIMALS
    } else if has("factor")
        || has("rate")
        || has("ratio")
        || has("fraction")
        || has("share")
        || has("loss")
        || has("probability")
        || has("amplification")
        || has("stops")
        || has("impatience")
    {
        6
    } else {
        crate::app::results::output::LENGTH_DECIMALS
    }
}

/// Round every float of `value` to [`figure_decimals`] of the key it stands under (numbers in
/// arrays and maps keyed by ids take the key of the array or map), so `summary.json` holds `0.1`
/// and `4.4`, not `0.09999999999999999` and `4.3999999999999995`. Integers stay as they are.
pub fn round_figures(value: &mut serde_json::Value) {
    fn walk(value: &mut serde_json::Value, key: &str) {
        match value {
            serde_json::Value::Object(map) => {
                for (k, v) in map.iter_mut() {
                    // Maps keyed by vehicle ids (`max_distance_to_centre_line`) keep their name.
                    let by_id = k.parse::<i64>().is_ok();
                    walk(v, if by_id { key } else { k });
                }
            }
            serde_json::Value::Array(items) => items.iter_mut().for_each(|v| walk(v, key)),
            serde_json::Value::Number(n) if n.is_f64() => {
                if let Some(x) = n.as_f64()
                    && let Some(r) =
                        serde_json::Number::from_f64(crate::app::results::output::rounded(x, figure_decimals(key)))
                {
                    *n = r;
                }
            }
            _ => {}
        }
    }
    walk(value, "");
}

impl RunSummary {
    /// The summary as `summary.json` holds it: every figure rounded to its unit's precision
    /// ([`round_figures`]).
    pub fn to_json(&self) -> serde_json::Value {
        let mut value = serde_json::to_value(self).unwrap_or(serde_json::Value::Null);
        round_figures(&mut value);
        value
    }

    /// Summarise `sim` after a run described by `report`.
    pub fn new(sim: &Sim, report: &RunReport) -> RunSummary {
        let world = sim.world();
        let stats = world.get_resource::<V2vStats>().copied().unwrap_or_default();
        let vehicles = world.resource::<Vehicles>();
        let deviation = world.get_resource::<super::metrics::Metrics>().map(|m| &m.route_deviation);
        let mut max_distance_to_centre_line: BTreeMap<i32, f64> = vehicles
            .iter()
            .filter_map(|(id, e)| match world.get::<PathFollower>(e) {
                Some(f) => Some((id.0, f.max_offset)),
                None => Some((id.0, deviation?.get(&id)?.max_offset)),
            })
            .collect();
        // Background traffic that left the world drove too (issue 61: a lane-drop run reported
        // `{}` after 73 vehicles drove).
        if let Some(t) = world.get_resource::<super::traffic::Traffic>() {
            max_distance_to_centre_line.extend(t.departed_max_offset.iter().map(|(&id, &d)| (id, d)));
        }
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
                if world.contains_resource::<super::trips::TripLog>() {
                    summary.trips = Some(super::trips::TripsSummary::of(&super::trips::trip_records(world)));
                }
                summary.v2v = world.get_resource::<crate::sim::V2vChannelStats>().map(super::metrics::V2vMetrics::of);
                summary.emergency = world
                    .get_resource::<crate::vehicles::EmergencyLog>()
                    .and_then(crate::vehicles::EmergencyLog::summary);
                summary.merge =
                    world.get_resource::<crate::vehicles::MergeLog>().and_then(crate::vehicles::MergeLog::summary);
                summary.intersection = world
                    .get_resource::<super::metrics::IntersectionLog>()
                    .and_then(super::metrics::IntersectionLog::summary);
                summary.sensors = world.get_resource::<crate::sim::SensorStats>().map(|&built_in| {
                    let plugins = world.get_resource::<crate::sim::PluginSensorStats>();
                    let by_sensor = plugins.map(|p| p.0.iter().map(|(k, v)| (k.to_string(), *v)).collect());
                    super::metrics::SensorMetrics { built_in, by_sensor: by_sensor.unwrap_or_default() }
                });
                if let Some(j) = world.get_resource::<crate::vehicles::JunctionStats>() {
                    summary.junctions = Some(j.summary());
                    if world.get_resource::<crate::vehicles::TrafficLights>().is_some_and(|l| !l.controllers.is_empty())
                    {
                        summary.red_light_crossings = Some(j.red_crossings);
                    }
                }
                summary
            }),
            lab: LabSummary::of(world),
            commonroad: world.get_resource::<super::scenario::commonroad::GoalMonitor>().map(|m| m.summary()),
            replay: None,
        }
    }
}
