//! Scenario files (TOML): map, rates, seed, duration and vehicles; parsed strictly, then built
//! into a [`SimBuilder`].
//!
//! ```toml
//! seed = 7
//! duration = 600.0                       # [s]
//! map = "../maps/highway_ring.osm"       # relative to this file
//! [rates]                                # [Hz]; these are the defaults
//! dynamics = 50.0
//! sensors = 20.0
//! control = 20.0
//! wifi = 10.0
//! network = 1.0
//! log = 10.0                             # trajectory log rate
//! [v2v]
//! wifi_range = 50.0                      # [m], inclusive
//! [[vehicles]]
//! id = -1                                # < 0 virtual, >= 0 real
//! class = "car"                          # car, truck, bus, motorcycle, bicycle, emergency
//! model = { type = "kinematic" }         # or "acceleration" (wheelbase, mass, drag, max_steering)
//! route = { loop = "right_lane_node" }   # or { from = NODE, to = NODE }; NODE: id or tag value
//! start = { offset = 30.0 }              # [m] along the route; or { at = NODE, offset = .. }
//!                                        # or { x = .., y = .., yaw = .. } [m, m, rad]
//! speed = 10.0                           # initial speed [m/s]
//! sensors = { radar = { angle_deg = 60.0, range = 100.0 }, velodyne = { range = 50.0 } }
//! controller = { type = "path_following", speed = 12.0 }
//! # or a smart controller: type = "cruise_control", "acc" or "platoon" (see crate::vehicles::setup)
//! [lab]                                  # optional: motion capture, real trucks (crate::io::lab)
//! mocap = { mock = true }
//! trucks = { base_port = 16000 }
//! ```
//! Unknown keys are errors that name the key and list the allowed ones.

use std::collections::BTreeMap;
use std::path::{Path as FsPath, PathBuf};
use std::sync::Arc;

use glam::DVec2;
use serde::Deserialize;

use crate::io::lab::{LabConfig, add_lab_plugins};
use crate::map::routing::Place;
use crate::map::{LaneletMap, MapError, Path, RouteOptions};
use crate::sim::{Rates, V2vConfig, V2vPlugin};
use crate::vehicles::{
    AccSetup, CruiseSetup, PathFollower, PathFollowing, PathFollowingPlugin, PlatoonSetup, SmartController,
    smart_vehicles,
};
use crate::world::{
    AccelerationUnicycle, KinematicUnicycle, Radar, SensorSet, VehicleClass, VehicleId, VehicleModel, VehicleSize,
    VehicleSpec, VehicleState, Velodyne,
};

use super::metrics::MetricsPlugin;
use super::{SimBuilder, SimSeed, default_plugins};

/// What can go wrong with a scenario file.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    /// The file could not be read.
    #[error("{path}: cannot read the scenario: {source}")]
    Io {
        /// The scenario file.
        path: PathBuf,
        /// Underlying error.
        source: std::io::Error,
    },
    /// Not valid TOML, or a key/value the format does not allow (the message names it).
    #[error("{path}: {message}")]
    Syntax {
        /// The scenario file.
        path: PathBuf,
        /// The parser's message, with line, column and key.
        message: String,
    },
    /// A value is out of range or keys contradict each other.
    #[error("{path}: `{key}` {problem}")]
    Invalid {
        /// The scenario file.
        path: PathBuf,
        /// Which key (e.g. `vehicles[2].start`).
        key: String,
        /// What is wrong and what is allowed.
        problem: String,
    },
    /// The map could not be loaded.
    #[error("{path}: map {map}: {source}")]
    Map {
        /// The scenario file.
        path: PathBuf,
        /// The map file, as resolved.
        map: PathBuf,
        /// Why.
        source: Box<MapError>,
    },
    /// A vehicle's route or start could not be found on the map.
    #[error("{path}: `{key}`: {source}")]
    Route {
        /// The scenario file.
        path: PathBuf,
        /// Which key.
        key: String,
        /// Why.
        source: Box<MapError>,
    },
}

/// A node of the map: an id (integer) or a node tag value (string).
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub enum NodeRef {
    /// A node id.
    Id(i64),
    /// A node tag value (`destination=left_lane_node` -> `"left_lane_node"`).
    Tag(String),
}

impl NodeRef {
    fn place(&self) -> Place {
        match self {
            NodeRef::Id(id) => Place::Node(*id),
            NodeRef::Tag(t) => Place::Tag(t.clone()),
        }
    }
}

impl<'de> Deserialize<'de> for NodeRef {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<NodeRef, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = NodeRef;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("a node id (integer) or a node tag value (string)")
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<NodeRef, E> {
                Ok(NodeRef::Id(v))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<NodeRef, E> {
                i64::try_from(v).map(NodeRef::Id).map_err(|_| E::custom("node id out of range"))
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<NodeRef, E> {
                Ok(NodeRef::Tag(v.to_string()))
            }
        }
        d.deserialize_any(V)
    }
}

/// The whole scenario file.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioFile {
    /// Seed of the run [-].
    #[serde(default)]
    pub seed: u64,
    /// Default duration [s].
    #[serde(default = "default_duration")]
    pub duration: f64,
    /// Map file, relative to the scenario file.
    #[serde(default)]
    pub map: Option<PathBuf>,
    /// Route resampling density [points per metre].
    #[serde(default = "default_points_per_meter")]
    pub points_per_meter: f64,
    /// Module rates.
    #[serde(default)]
    pub rates: RatesConfig,
    /// V2V settings.
    #[serde(default)]
    pub v2v: V2vSection,
    /// The vehicles.
    #[serde(default)]
    pub vehicles: Vec<VehicleConfig>,
    /// Bridges to the lab (motion capture, real trucks), see [`crate::io::lab`].
    #[serde(default)]
    pub lab: Option<LabConfig>,
}

fn default_duration() -> f64 {
    60.0
}
fn default_points_per_meter() -> f64 {
    5.0
}

/// `[rates]`, all [Hz].
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RatesConfig {
    /// Dynamics [Hz].
    pub dynamics: f64,
    /// Sensors [Hz].
    pub sensors: f64,
    /// Controllers [Hz].
    pub control: f64,
    /// Wifi rounds [Hz].
    pub wifi: f64,
    /// Network rounds [Hz].
    pub network: f64,
    /// Trajectory log [Hz].
    pub log: f64,
}

impl Default for RatesConfig {
    fn default() -> Self {
        let r = Rates::default();
        RatesConfig {
            dynamics: r.dynamics,
            sensors: r.sensors,
            control: r.control,
            wifi: r.wifi,
            network: r.network,
            log: 10.0,
        }
    }
}

/// `[v2v]`.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct V2vSection {
    /// Wifi range [m], inclusive.
    pub wifi_range: f64,
}

impl Default for V2vSection {
    fn default() -> Self {
        V2vSection { wifi_range: V2vConfig::default().wifi_range }
    }
}

/// One `[[vehicles]]` entry.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VehicleConfig {
    /// Unique id (< 0 virtual, >= 0 real).
    pub id: i32,
    /// Class.
    #[serde(default)]
    pub class: VehicleClass,
    /// Length [m] (default 4.12).
    #[serde(default)]
    pub length: Option<f64>,
    /// Width [m] (default 1.7).
    #[serde(default)]
    pub width: Option<f64>,
    /// Dynamics model.
    #[serde(default)]
    pub model: ModelConfig,
    /// Route or loop to drive.
    #[serde(default)]
    pub route: Option<RouteConfig>,
    /// Where it starts.
    #[serde(default)]
    pub start: Option<StartConfig>,
    /// Initial speed [m/s].
    #[serde(default)]
    pub speed: f64,
    /// Sensors.
    #[serde(default)]
    pub sensors: SensorsConfig,
    /// Whether it takes part in V2V.
    #[serde(default = "yes")]
    pub mailbox: bool,
    /// Controller.
    #[serde(default)]
    pub controller: Option<ControllerConfig>,
}

fn yes() -> bool {
    true
}

/// `model = { type = ... }`.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ModelConfig {
    /// Kinematic unicycle (speed command).
    Kinematic {
        /// Wheelbase [m].
        #[serde(default = "default_wheelbase")]
        wheelbase: f64,
        /// Steering limit [rad].
        #[serde(default = "default_max_steering")]
        max_steering: f64,
    },
    /// Acceleration unicycle (throttle command).
    Acceleration {
        /// Wheelbase [m].
        #[serde(default = "default_wheelbase")]
        wheelbase: f64,
        /// Mass [kg].
        #[serde(default = "default_mass")]
        mass: f64,
        /// Drag [N s/m].
        #[serde(default = "default_drag")]
        drag: f64,
        /// Steering limit [rad].
        #[serde(default = "default_max_steering")]
        max_steering: f64,
    },
    /// No dynamics (a real vehicle, or a parked one).
    None,
}

impl Default for ModelConfig {
    fn default() -> Self {
        ModelConfig::Kinematic { wheelbase: default_wheelbase(), max_steering: default_max_steering() }
    }
}

fn default_wheelbase() -> f64 {
    KinematicUnicycle::default().wheelbase
}
fn default_max_steering() -> f64 {
    KinematicUnicycle::default().max_steering
}
fn default_mass() -> f64 {
    AccelerationUnicycle::default().mass
}
fn default_drag() -> f64 {
    AccelerationUnicycle::default().drag
}

/// `route = { loop = NODE }` or `route = { from = NODE, to = NODE }`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RouteConfig {
    /// Closed loop through this node.
    #[serde(rename = "loop", default)]
    pub closed_loop: Option<NodeRef>,
    /// Route start.
    #[serde(default)]
    pub from: Option<NodeRef>,
    /// Route end.
    #[serde(default)]
    pub to: Option<NodeRef>,
}

/// `start = { offset }`, `{ at, offset }` or `{ x, y, yaw }`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StartConfig {
    /// A node to start at (projected onto the route if there is one).
    #[serde(default)]
    pub at: Option<NodeRef>,
    /// Distance along the route from the route start (or from `at`) [m].
    #[serde(default)]
    pub offset: Option<f64>,
    /// Position x [m].
    #[serde(default)]
    pub x: Option<f64>,
    /// Position y [m].
    #[serde(default)]
    pub y: Option<f64>,
    /// Heading [rad] (default: the route's heading there, else 0).
    #[serde(default)]
    pub yaw: Option<f64>,
}

/// `sensors = { radar, velodyne, omniscient }`.
#[derive(Debug, Clone, Copy, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorsConfig {
    /// Radar cone.
    #[serde(default)]
    pub radar: Option<RadarConfig>,
    /// Velodyne circle.
    #[serde(default)]
    pub velodyne: Option<VelodyneConfig>,
    /// Sees everyone.
    #[serde(default)]
    pub omniscient: bool,
}

/// `radar = { angle_deg, range }`.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RadarConfig {
    /// Full opening angle [deg] (converted to radians for the simulation).
    pub angle_deg: f64,
    /// Range [m].
    pub range: f64,
}

impl Default for RadarConfig {
    fn default() -> Self {
        let r = Radar::default();
        RadarConfig { angle_deg: r.angle.to_degrees(), range: r.range }
    }
}

/// `velodyne = { range }`.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VelodyneConfig {
    /// Range [m].
    pub range: f64,
}

impl Default for VelodyneConfig {
    fn default() -> Self {
        VelodyneConfig { range: Velodyne::default().range }
    }
}

/// `controller = { type = ... }`.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ControllerConfig {
    /// Pure pursuit along the route at a cruise speed.
    PathFollowing {
        /// Cruise speed [m/s].
        #[serde(default = "default_cruise")]
        speed: f64,
        /// Shortest look-ahead [m].
        #[serde(default = "default_lookahead_min")]
        lookahead_min: f64,
        /// Look-ahead time [s].
        #[serde(default = "default_lookahead_time")]
        lookahead_time: f64,
        /// Throttle speed gain [1/s].
        #[serde(default = "default_speed_gain")]
        speed_gain: f64,
    },
    /// Cruise control (PID on speed) along the route.
    CruiseControl(CruiseSetup),
    /// Adaptive cruise control on radar along the route.
    Acc(AccSetup),
    /// Platooning (cooperative ACC over wifi) along the route.
    Platoon(PlatoonSetup),
}

impl ControllerConfig {
    /// The smart-vehicle controller this names, if it is one.
    pub fn smart(&self) -> Option<SmartController> {
        match *self {
            ControllerConfig::PathFollowing { .. } => None,
            ControllerConfig::CruiseControl(c) => Some(SmartController::Cruise(c)),
            ControllerConfig::Acc(c) => Some(SmartController::Acc(c)),
            ControllerConfig::Platoon(c) => Some(SmartController::Platoon(c)),
        }
    }
}

fn default_cruise() -> f64 {
    PathFollowing::default().speed
}
fn default_lookahead_min() -> f64 {
    PathFollowing::default().lookahead_min
}
fn default_lookahead_time() -> f64 {
    PathFollowing::default().lookahead_time
}
fn default_speed_gain() -> f64 {
    PathFollowing::default().speed_gain
}

/// A parsed and checked scenario with its map loaded.
#[derive(Debug, Clone)]
pub struct Scenario {
    /// The scenario file (for messages and relative paths).
    pub path: PathBuf,
    /// Its content.
    pub file: ScenarioFile,
    /// The map, if the scenario names one.
    pub map: Option<Arc<LaneletMap>>,
}

impl Scenario {
    /// Read, parse, check and load the map of a scenario file.
    pub fn load(path: &FsPath) -> Result<Scenario, ScenarioError> {
        let text = std::fs::read_to_string(path).map_err(|source| ScenarioError::Io { path: path.into(), source })?;
        Scenario::parse_str(&text, path)
    }

    /// Parse scenario text; `path` names the file in messages and anchors its relative paths.
    pub fn parse_str(text: &str, path: &FsPath) -> Result<Scenario, ScenarioError> {
        let file: ScenarioFile =
            toml::from_str(text).map_err(|e| ScenarioError::Syntax { path: path.into(), message: e.to_string() })?;
        check(&file, path)?;
        let map = match &file.map {
            Some(m) => {
                let resolved = path.parent().unwrap_or(FsPath::new("")).join(m);
                let map = LaneletMap::load(&resolved).map_err(|e| ScenarioError::Map {
                    path: path.into(),
                    map: resolved.clone(),
                    source: Box::new(e),
                })?;
                Some(Arc::new(map))
            }
            None => None,
        };
        Ok(Scenario { path: path.into(), file, map })
    }

    /// The module rates of the scenario.
    pub fn rates(&self) -> Rates {
        let r = &self.file.rates;
        Rates { dynamics: r.dynamics, sensors: r.sensors, control: r.control, wifi: r.wifi, network: r.network }
    }

    fn invalid(&self, key: String, problem: impl Into<String>) -> ScenarioError {
        ScenarioError::Invalid { path: self.path.clone(), key, problem: problem.into() }
    }

    /// A builder with the scenario's rates, seed, built-in plugins (dynamics, sensors, V2V, path
    /// following, the smart-vehicle controllers, metrics) and vehicles; add your own plugins,
    /// then `build()`.
    pub fn builder(&self) -> Result<SimBuilder, ScenarioError> {
        let mut b = SimBuilder::with_rates(self.rates());
        b.insert_resource(SimSeed(self.file.seed));
        b.add_plugin(default_plugins);
        b.add_plugin(V2vPlugin { config: V2vConfig { wifi_range: self.file.v2v.wifi_range } });
        b.add_plugin(PathFollowingPlugin);
        b.add_plugin(smart_vehicles).add_plugin(MetricsPlugin::default());
        let opts = RouteOptions { points_per_meter: self.file.points_per_meter };
        let mut routes: BTreeMap<String, Arc<Path>> = BTreeMap::new();
        for (i, v) in self.file.vehicles.iter().enumerate() {
            let key = |k: &str| format!("vehicles[{i}] (id {}).{k}", v.id);
            let route = match &v.route {
                Some(r) => {
                    let map =
                        self.map.as_ref().ok_or_else(|| self.invalid(key("route"), "needs a `map` in the scenario"))?;
                    let name = format!("{r:?}");
                    let path = match routes.get(&name) {
                        Some(p) => Arc::clone(p),
                        None => {
                            let route_err = |e| ScenarioError::Route {
                                path: self.path.clone(),
                                key: key("route"),
                                source: Box::new(e),
                            };
                            let p = Arc::new(match (&r.closed_loop, &r.from, &r.to) {
                                (Some(n), _, _) => map.closed_loop_at(&n.place(), &opts).map_err(route_err)?,
                                (None, Some(a), Some(b)) => {
                                    map.route_places(&a.place(), &b.place(), &opts).map_err(route_err)?
                                }
                                _ => return Err(self.invalid(key("route"), "needs `loop` or both `from` and `to`")),
                            });
                            routes.insert(name, Arc::clone(&p));
                            p
                        }
                    };
                    Some(path)
                }
                None => None,
            };
            let (state, along) = self.start_state(v, route.as_deref(), &key)?;
            let mut spec = VehicleSpec::new(VehicleId(v.id), state);
            spec.class = v.class;
            let d = VehicleSize::default();
            spec.size = VehicleSize { length: v.length.unwrap_or(d.length), width: v.width.unwrap_or(d.width) };
            spec.model = match v.model {
                ModelConfig::Kinematic { wheelbase, max_steering } => {
                    VehicleModel::Kinematic(KinematicUnicycle { wheelbase, max_steering })
                }
                ModelConfig::Acceleration { wheelbase, mass, drag, max_steering } => {
                    VehicleModel::Acceleration(AccelerationUnicycle { wheelbase, mass, drag, max_steering })
                }
                ModelConfig::None => VehicleModel::None,
            };
            spec.sensors = SensorSet {
                radar: v.sensors.radar.map(|r| Radar { angle: r.angle_deg.to_radians(), range: r.range }),
                velodyne: v.sensors.velodyne.map(|r| Velodyne { range: r.range }),
                omniscient: v.sensors.omniscient,
            };
            spec.mailbox = v.mailbox;
            spec.route = route;
            let entity = b.spawn_vehicle(spec).map_err(|e| self.invalid(key("id"), e.to_string()))?;
            if let Some(ControllerConfig::PathFollowing { speed, lookahead_min, lookahead_time, speed_gain }) =
                v.controller
            {
                let params = PathFollowing { speed, lookahead_min, lookahead_time, speed_gain, ..Default::default() };
                b.world_mut().entity_mut(entity).insert(PathFollower::starting_at(params, along));
            }
            if let Some(smart) = v.controller.and_then(|c| c.smart()) {
                smart.attach(b.world_mut(), entity);
            }
        }
        if let Some(lab) = &self.file.lab {
            add_lab_plugins(&mut b, lab, self.map.as_deref())
                .map_err(|e| self.invalid(format!("lab.{}", e.key), e.problem))?;
        }
        Ok(b)
    }

    fn start_state(
        &self,
        v: &VehicleConfig,
        route: Option<&Path>,
        key: &dyn Fn(&str) -> String,
    ) -> Result<(VehicleState, f64), ScenarioError> {
        let start = v.start.clone().unwrap_or(StartConfig { at: None, offset: None, x: None, y: None, yaw: None });
        let node_position = |n: &NodeRef| -> Result<DVec2, ScenarioError> {
            let map =
                self.map.as_ref().ok_or_else(|| self.invalid(key("start.at"), "needs a `map` in the scenario"))?;
            let ids = map.place_nodes(&n.place()).map_err(|e| ScenarioError::Route {
                path: self.path.clone(),
                key: key("start.at"),
                source: Box::new(e),
            })?;
            ids.first()
                .and_then(|id| map.nodes.get(id))
                .map(|n| n.position)
                .ok_or_else(|| self.invalid(key("start.at"), "names no node of the map"))
        };
        let (position, yaw, along) = match (route, &start.at, start.x.zip(start.y)) {
            (_, None, Some(p)) => {
                let p = DVec2::new(p.0, p.1);
                let (heading, along) = route.map_or((0.0, 0.0), |r| {
                    let projection = r.project(p);
                    (projection.heading, projection.s)
                });
                (p, start.yaw.unwrap_or(heading), along)
            }
            (Some(r), at, None) => {
                let base = match at {
                    Some(n) => r.project(node_position(n)?).s,
                    None => 0.0,
                };
                let along = base + start.offset.unwrap_or(0.0);
                let (p, heading) = r.sample(along);
                let along = if r.closed { along.rem_euclid(r.length) } else { along.clamp(0.0, r.length) };
                (p, start.yaw.unwrap_or(heading), along)
            }
            (None, Some(n), None) => (node_position(n)?, start.yaw.unwrap_or(0.0), 0.0),
            (None, None, None) => (DVec2::ZERO, start.yaw.unwrap_or(0.0), 0.0),
            (_, Some(_), Some(_)) => return Err(self.invalid(key("start"), "takes either `at` or `x`/`y`, not both")),
        };
        Ok((VehicleState::new(position, yaw, v.speed), along))
    }
}

/// Check values the types cannot: ranges, unique ids, keys that exclude each other.
fn check(file: &ScenarioFile, path: &FsPath) -> Result<(), ScenarioError> {
    let invalid =
        |key: String, problem: &str| ScenarioError::Invalid { path: path.into(), key, problem: problem.into() };
    let positive = |key: String, v: f64| {
        if v.is_finite() && v > 0.0 {
            Ok(())
        } else {
            Err(invalid(key, &format!("must be a positive number, got {v}")))
        }
    };
    let non_negative = |key: String, v: f64| {
        if v.is_finite() && v >= 0.0 { Ok(()) } else { Err(invalid(key, &format!("must be zero or more, got {v}"))) }
    };
    positive("duration".into(), file.duration)?;
    positive("points_per_meter".into(), file.points_per_meter)?;
    let r = &file.rates;
    for (k, v) in [
        ("dynamics", r.dynamics),
        ("sensors", r.sensors),
        ("control", r.control),
        ("wifi", r.wifi),
        ("network", r.network),
        ("log", r.log),
    ] {
        positive(format!("rates.{k}"), v)?;
        if v > 1e6 {
            return Err(invalid(
                format!("rates.{k}"),
                &format!("must be at most 1e6 Hz (one tick per microsecond), got {v}"),
            ));
        }
    }
    non_negative("v2v.wifi_range".into(), file.v2v.wifi_range)?;
    if let Some(lab) = &file.lab {
        lab.check().map_err(|e| invalid(format!("lab.{}", e.key), &e.problem))?;
    }
    let mut seen = BTreeMap::new();
    for (i, v) in file.vehicles.iter().enumerate() {
        let key = |k: &str| format!("vehicles[{i}] (id {}).{k}", v.id);
        if let Some(first) = seen.insert(v.id, i) {
            return Err(invalid(key("id"), &format!("is already used by vehicles[{first}]; ids must be unique")));
        }
        if let Some(l) = v.length {
            positive(key("length"), l)?;
        }
        if let Some(w) = v.width {
            positive(key("width"), w)?;
        }
        non_negative(key("speed"), v.speed)?;
        match v.model {
            ModelConfig::Kinematic { wheelbase, max_steering } => {
                positive(key("model.wheelbase"), wheelbase)?;
                non_negative(key("model.max_steering"), max_steering)?;
            }
            ModelConfig::Acceleration { wheelbase, mass, drag, max_steering } => {
                positive(key("model.wheelbase"), wheelbase)?;
                positive(key("model.mass"), mass)?;
                non_negative(key("model.drag"), drag)?;
                non_negative(key("model.max_steering"), max_steering)?;
            }
            ModelConfig::None => {}
        }
        if let Some(route) = &v.route {
            match (&route.closed_loop, &route.from, &route.to) {
                (Some(_), None, None) | (None, Some(_), Some(_)) => {}
                _ => {
                    return Err(invalid(
                        key("route"),
                        "needs either `loop = NODE` or both `from = NODE` and `to = NODE` (NODE: a node id or a tag value)",
                    ));
                }
            }
        }
        if let Some(s) = &v.start {
            if s.x.is_some() != s.y.is_some() {
                return Err(invalid(key("start"), "needs both `x` and `y` [m], or neither"));
            }
            if s.at.is_some() && s.x.is_some() {
                return Err(invalid(key("start"), "takes either `at = NODE` or `x`/`y`, not both"));
            }
            if s.offset.is_some() && v.route.is_none() {
                return Err(invalid(key("start.offset"), "is a distance along the route: add a `route`"));
            }
            if s.offset.is_some() && s.x.is_some() {
                return Err(invalid(key("start.offset"), "cannot be combined with `x`/`y`"));
            }
        }
        if let Some(r) = v.sensors.radar {
            if !(r.angle_deg > 0.0 && r.angle_deg <= 360.0) {
                return Err(invalid(
                    key("sensors.radar.angle_deg"),
                    &format!("must be in (0, 360] degrees, got {}", r.angle_deg),
                ));
            }
            non_negative(key("sensors.radar.range"), r.range)?;
        }
        if let Some(r) = v.sensors.velodyne {
            non_negative(key("sensors.velodyne.range"), r.range)?;
        }
        if let Some(ControllerConfig::PathFollowing { speed, lookahead_min, lookahead_time, speed_gain }) = v.controller
        {
            if v.route.is_none() {
                return Err(invalid(key("controller"), "path_following needs a `route` to follow"));
            }
            non_negative(key("controller.speed"), speed)?;
            positive(key("controller.lookahead_min"), lookahead_min)?;
            non_negative(key("controller.lookahead_time"), lookahead_time)?;
            non_negative(key("controller.speed_gain"), speed_gain)?;
        }
        if let Some(smart) = v.controller.and_then(|c| c.smart()) {
            if v.route.is_none() {
                return Err(invalid(key("controller"), "needs a `route` to follow"));
            }
            smart.check().map_err(|(k, problem)| invalid(key(&format!("controller.{k}")), &problem))?;
        }
    }
    Ok(())
}
