//! Scenario files (TOML): map, rates, seed, duration and vehicles; parsed strictly, then built
//! into a [`crate::sim::SimBuilder`].
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
//! # or one a plugin registered: type = "my_cautious", gap = 20.0 (see crate::sim::ScenarioController)
//! [lab]                                  # optional: motion capture, real trucks (see `lab`)
//! mocap = { mock = true }
//! trucks = { base_port = 16000 }
//! ```
//! Unknown keys are errors that name the key and list the allowed ones.
//!
//! # CommonRoad scenarios
//! `map` may name a CommonRoad scenario file (`.xml` with a `<commonRoad>` root). Then
//! `obstacles = "replay"` turns each dynamic obstacle N into virtual vehicle -N driven by its
//! recorded trajectory, and `planning_problem = ID` in a `[[vehicles]]` entry starts that vehicle
//! at the planning problem's initial state (no `start` then); `summary.json` says in
//! `commonroad.goals` whether it reached the goal (see [`commonroad`]). Routes name lanelet ends
//! by tag: `route = { from = "start_1", to = "end_5" }`.

mod assemble;
mod check;
pub mod commonroad;
mod file;
pub mod lab;
pub mod overrides;
pub mod sumocfg;

use std::collections::BTreeMap;
use std::path::{Path as FsPath, PathBuf};
use std::sync::Arc;

use crate::map::commonroad::{CommonRoadScenario, is_commonroad};
use crate::map::{LaneletMap, MapError};
use crate::sim::{ControllerRegistry, Rates};

pub use file::{
    BuiltInController, BurstConfig, ChannelSection, ControllerConfig, LossConfig, ModelConfig, NodeRef, ObstaclesMode,
    RadarConfig, RatesConfig, RouteConfig, RsuAt, RsuConfig, ScenarioFile, SensorsConfig, StartConfig, TrafficRoute,
    V2vSection, VehicleConfig, VelodyneConfig,
};
pub use lab::{LabConfig, LabError, MocapConfig, TrucksConfig, add_lab_plugins, scenario_script};
pub use overrides::{apply_override, load_with_overrides, parse_override};

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
    /// A SUMO demand file could not be read or routed.
    #[error("{path}: demand: {source}")]
    Demand {
        /// The scenario file.
        path: PathBuf,
        /// Why (names the demand file, line and element).
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

/// A parsed and checked scenario with its map loaded.
#[derive(Debug, Clone)]
pub struct Scenario {
    /// The scenario file (for messages and relative paths).
    pub path: PathBuf,
    /// Its content.
    pub file: ScenarioFile,
    /// The map, if the scenario names one.
    pub map: Option<Arc<LaneletMap>>,
    /// The whole CommonRoad scenario when the map is a CommonRoad file (obstacles, planning
    /// problems).
    pub commonroad: Option<Arc<CommonRoadScenario>>,
    /// The SUMO demand of `demand = [...]`, routed on the map.
    pub demand: Option<Arc<crate::map::sumo::demand::Demand>>,
}

impl Scenario {
    /// Read, parse, check and load the map of a scenario file that names only built-in
    /// controllers.
    pub fn load(path: &FsPath) -> Result<Scenario, ScenarioError> {
        Scenario::load_with(path, &ControllerRegistry::default())
    }

    /// [`Scenario::load`] for a scenario that may name the controllers of `controllers` (the
    /// registry a [`crate::sim::SimBuilder`] collected from its plugins).
    pub fn load_with(path: &FsPath, controllers: &ControllerRegistry) -> Result<Scenario, ScenarioError> {
        let text = std::fs::read_to_string(path).map_err(|source| ScenarioError::Io { path: path.into(), source })?;
        Scenario::parse_str_with(&text, path, controllers)
    }

    /// Parse scenario text that names only built-in controllers; `path` names the file in
    /// messages and anchors its relative paths.
    pub fn parse_str(text: &str, path: &FsPath) -> Result<Scenario, ScenarioError> {
        Scenario::parse_str_with(text, path, &ControllerRegistry::default())
    }

    /// [`Scenario::parse_str`] for a scenario that may name the controllers of `controllers`.
    pub fn parse_str_with(
        text: &str,
        path: &FsPath,
        controllers: &ControllerRegistry,
    ) -> Result<Scenario, ScenarioError> {
        let file: ScenarioFile =
            toml::from_str(text).map_err(|e| ScenarioError::Syntax { path: path.into(), message: e.to_string() })?;
        check::check(&file, path, controllers)?;
        let (map, commonroad) = match &file.map {
            Some(m) => {
                let resolved = path.parent().unwrap_or(FsPath::new("")).join(m);
                let map_err = |e| ScenarioError::Map { path: path.into(), map: resolved.clone(), source: Box::new(e) };
                let text = std::fs::read_to_string(&resolved)
                    .map_err(|source| map_err(MapError::Io { path: resolved.clone(), source }))?;
                if is_commonroad(&text) {
                    let sc = CommonRoadScenario::parse_str(&text, &resolved).map_err(map_err)?;
                    (Some(Arc::new(sc.map.clone())), Some(Arc::new(sc)))
                } else {
                    (Some(Arc::new(LaneletMap::parse_str(&text, &resolved).map_err(map_err)?)), None)
                }
            }
            None => (None, None),
        };
        let demand = match (&map, file.demand.is_empty()) {
            (_, true) => None,
            (None, false) => {
                return Err(ScenarioError::Invalid {
                    path: path.into(),
                    key: "demand".into(),
                    problem: "needs a SUMO network (`.net.xml`) as `map`".into(),
                });
            }
            (Some(m), false) => {
                let files: Vec<PathBuf> =
                    file.demand.iter().map(|d| path.parent().unwrap_or(FsPath::new("")).join(d)).collect();
                let demand = crate::map::sumo::demand::Demand::load(&files, m, file.demand_begin, file.duration)
                    .map_err(|e| ScenarioError::Demand { path: path.into(), source: Box::new(e) })?;
                for w in &demand.warnings {
                    tracing::warn!("{w}");
                }
                Some(Arc::new(demand))
            }
        };
        let scenario = Scenario { path: path.into(), file, map, commonroad, demand };
        scenario.check_commonroad()?;
        scenario.check_traffic_lights()?;
        Ok(scenario)
    }

    /// The module rates of the scenario.
    pub fn rates(&self) -> Rates {
        let r = &self.file.rates;
        Rates { dynamics: r.dynamics, sensors: r.sensors, control: r.control, wifi: r.wifi, network: r.network }
    }

    /// `obstacles` and `planning_problem` need a CommonRoad map that has them.
    fn check_commonroad(&self) -> Result<(), ScenarioError> {
        let ids = |sc: &CommonRoadScenario| {
            sc.planning_problems.iter().map(|p| p.id.to_string()).collect::<Vec<_>>().join(", ")
        };
        if self.file.obstacles.is_some() && self.commonroad.is_none() {
            return Err(self.invalid("obstacles".into(), "needs a CommonRoad scenario file as `map`"));
        }
        for (i, v) in self.file.vehicles.iter().enumerate() {
            let Some(pp) = v.planning_problem else { continue };
            let key = format!("vehicles[{i}] (id {}).planning_problem", v.id);
            let Some(sc) = &self.commonroad else {
                return Err(self.invalid(key, "needs a CommonRoad scenario file as `map`"));
            };
            if !sc.planning_problems.iter().any(|p| p.id == pp) {
                return Err(
                    self.invalid(key, format!("{pp} is not a planning problem of the map (it has: {})", ids(sc)))
                );
            }
            if v.start.is_some() {
                return Err(self.invalid(key, "sets the start: remove `start` (or `planning_problem`)"));
            }
        }
        Ok(())
    }

    /// Every `[[traffic_lights]]` names a junction of the map and gives each phase one valid
    /// character per link.
    fn check_traffic_lights(&self) -> Result<(), ScenarioError> {
        if self.file.traffic_lights.is_empty() {
            return Ok(());
        }
        let Some(map) = &self.map else {
            return Err(self.invalid("traffic_lights".into(), "needs a `map` with junctions"));
        };
        let junctions = self.junctions_plugin(map).junctions();
        let ids = || {
            let list: Vec<String> = junctions.list.iter().map(|j| j.id.to_string()).collect();
            if list.is_empty() { "none: the map has no junction".to_string() } else { list.join(", ") }
        };
        let mut seen = BTreeMap::new();
        for (k, light) in self.file.traffic_lights.iter().enumerate() {
            let key = format!("traffic_lights[{k}].junction");
            let Some(j) = junctions.get(light.junction) else {
                return Err(self.invalid(
                    key,
                    format!(
                        "{} is not a junction of the map (`smlworld map info` lists them; ids: {})",
                        light.junction,
                        ids()
                    ),
                ));
            };
            if let Some(first) = seen.insert(light.junction, k) {
                return Err(self.invalid(
                    key,
                    format!("junction {} already has a program in traffic_lights[{first}]", light.junction),
                ));
            }
            for (i, phase) in light.program.iter().enumerate() {
                crate::vehicles::right_of_way::check_state(&phase.state, j.links.len())
                    .map_err(|p| self.invalid(format!("traffic_lights[{k}].program[{i}].state"), p))?;
            }
        }
        Ok(())
    }

    /// The junction rules of this scenario on `map`.
    pub fn junctions_plugin(&self, map: &Arc<LaneletMap>) -> crate::vehicles::JunctionsPlugin {
        crate::vehicles::JunctionsPlugin {
            map: Arc::clone(map),
            params: self.file.junctions,
            programs: self.file.traffic_lights.iter().map(|l| (l.junction, l.program.clone(), l.offset)).collect(),
        }
    }

    fn invalid(&self, key: String, problem: impl Into<String>) -> ScenarioError {
        ScenarioError::Invalid { path: self.path.clone(), key, problem: problem.into() }
    }
}
