//! The scenario file's TOML types, parsed strictly (unknown keys are errors naming the key).

use std::path::PathBuf;

use serde::Deserialize;

use super::lab::LabConfig;
use crate::map::routing::Place;
use crate::sim::v2v::channel::plugins::ChannelModelRegistry;
use crate::sim::v2v::channel::{Burst, ChannelModel, Loss};
use crate::sim::{BUILT_IN_CONTROLLERS, Rates, V2vConfig};
use crate::vehicles::{
    AccSetup, CruiseSetup, EmergencySettings, GcdcSetup, Idm, LaneChangeParams, PathFollowing, PlatoonSetup, RsuKind,
    SmartController,
};
use crate::world::{AccelerationUnicycle, KinematicUnicycle, Radar, VehicleClass, Velodyne};

/// A node of the map: an id (integer), a node tag value (string), or on an OpenDRIVE map a
/// lane, `{ road = "5", lane = -1 }` (optionally `section = 1`, else the road's first lane
/// section): the start of its lanelet where a route starts, its end where a route ends.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub enum NodeRef {
    /// A node id.
    Id(i64),
    /// A node tag value (`destination=left_lane_node` -> `"left_lane_node"`).
    Tag(String),
    /// An OpenDRIVE lane.
    Lane {
        /// Road id.
        road: String,
        /// Lane section index in the road (0: the first).
        section: usize,
        /// Lane id.
        lane: i32,
    },
}

impl NodeRef {
    /// Where a route starts or passes: a lane's start.
    pub(crate) fn place(&self) -> Place {
        match self {
            NodeRef::Id(id) => Place::Node(*id),
            NodeRef::Tag(t) => Place::Tag(t.clone()),
            NodeRef::Lane { road, section, lane } => {
                Place::Tag(crate::map::opendrive::lane_tag(road, *section, *lane, false))
            }
        }
    }

    /// Where a route ends: a lane's end (the same as [`NodeRef::place`] for nodes and tags).
    pub(crate) fn end_place(&self) -> Place {
        match self {
            NodeRef::Lane { road, section, lane } => {
                Place::Tag(crate::map::opendrive::lane_tag(road, *section, *lane, true))
            }
            other => other.place(),
        }
    }
}

impl<'de> Deserialize<'de> for NodeRef {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<NodeRef, D::Error> {
        struct V;
        impl<'v> serde::de::Visitor<'v> for V {
            type Value = NodeRef;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("a node id (integer), a node tag value (string) or an OpenDRIVE lane { road, lane }")
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
            fn visit_map<A: serde::de::MapAccess<'v>>(self, mut m: A) -> Result<NodeRef, A::Error> {
                use serde::de::Error;
                let (mut road, mut section, mut lane) = (None, 0usize, None);
                while let Some(key) = m.next_key::<String>()? {
                    match key.as_str() {
                        "road" => road = Some(m.next_value::<toml::Value>()?),
                        "section" => section = m.next_value()?,
                        "lane" => lane = Some(m.next_value::<i32>()?),
                        other => {
                            return Err(A::Error::custom(format!(
                                "unknown key `{other}` in a lane (expected `road`, `lane`, `section`)"
                            )));
                        }
                    }
                }
                let road = match road {
                    Some(toml::Value::String(s)) => s,
                    Some(toml::Value::Integer(i)) => i.to_string(),
                    Some(_) => return Err(A::Error::custom("`road` must be a road id (string or integer)")),
                    None => return Err(A::Error::custom("a lane needs `road` (an OpenDRIVE road id)")),
                };
                let lane =
                    lane.ok_or_else(|| A::Error::custom("a lane needs `lane` (an OpenDRIVE lane id, e.g. -1)"))?;
                Ok(NodeRef::Lane { road, section, lane })
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
    /// Default duration \[s\].
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
    /// `[output]`: extra outputs of every run of the scenario (`mcap = "run.mcap"`).
    #[serde(default)]
    pub output: OutputSection,
    /// V2V settings.
    #[serde(default)]
    pub v2v: V2vSection,
    /// The vehicles.
    #[serde(default)]
    pub vehicles: Vec<VehicleConfig>,
    /// Bridges to the lab (motion capture, real trucks), see [`crate::io::lab`].
    #[serde(default)]
    pub lab: Option<LabConfig>,
    /// `obstacles = "replay"`: the dynamic obstacles of a CommonRoad `map` drive as recorded and
    /// its static obstacles stand where the file puts them.
    #[serde(default)]
    pub obstacles: Option<ObstaclesMode>,
    /// Background traffic (`[[traffic]]`).
    #[serde(default)]
    pub traffic: Vec<TrafficConfig>,
    /// `[emergency] warning_range`: how vehicles make way for emergency vehicles.
    #[serde(default)]
    pub emergency: EmergencySettings,
    /// Roadside units (`[[rsu]]`): fixed wifi senders, e.g. the GCDC merge zone.
    #[serde(default)]
    pub rsu: Vec<RsuConfig>,
    /// `[junctions]`: the right-of-way rules' parameters ([`crate::vehicles::JunctionParams`]).
    #[serde(default)]
    pub junctions: crate::vehicles::JunctionParams,
    /// `[[traffic_lights]]`: fixed-time signal programs of junctions.
    #[serde(default)]
    pub traffic_lights: Vec<TrafficLightConfig>,
    /// SUMO demand files (`.rou.xml`, relative to this file) for a SUMO network `map`: their
    /// vehicles, flows and trips enter at their depart times and leave at their route's end
    /// ([`crate::map::sumo::demand`]).
    #[serde(default)]
    pub demand: Vec<PathBuf>,
    /// SUMO time at which this run starts \[s\] (a `.sumocfg`'s `begin`): demand departing
    /// earlier is dropped, later departures come `demand_begin` s earlier.
    #[serde(default)]
    pub demand_begin: f64,
}

/// One `[[traffic_lights]]`: `junction = ID`, `offset = 0.0`, `program = [{ state = "GGrr",
/// duration = 30.0 }, ...]`, one state character per link in the order `map info` lists the
/// junction's links.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrafficLightConfig {
    /// Junction id, as `smlworld map info` lists it.
    pub junction: u32,
    /// Shift of the cycle [s]: the program is at its start at t = offset.
    #[serde(default)]
    pub offset: f64,
    /// The phases, cycled.
    pub program: Vec<crate::map::junctions::SignalPhase>,
}

/// One `[[rsu]]`: `at = { x, y }` or `at = { node = NODE }`, `range = 300.0`,
/// `message = "merge_zone"`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RsuConfig {
    /// Where it stands.
    pub at: RsuAt,
    /// Its wifi range \[m\], inclusive (default 300).
    #[serde(default = "default_rsu_range")]
    pub range: f64,
    /// What it broadcasts: `"merge_zone"` (the merge zone starts here).
    pub message: RsuKind,
}

fn default_rsu_range() -> f64 {
    300.0
}

/// `at = { x = .., y = .. }` \[m\] or `at = { node = NODE }` (a node id or tag value).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RsuAt {
    /// x \[m\].
    #[serde(default)]
    pub x: Option<f64>,
    /// y \[m\].
    #[serde(default)]
    pub y: Option<f64>,
    /// A node of the map.
    #[serde(default)]
    pub node: Option<NodeRef>,
}

/// `lanes = "all"` or a list of node tags (one start lane each).
#[derive(Debug, Clone, PartialEq, Default)]
pub enum TrafficLanes {
    /// Every lane beside the route's start lane.
    #[default]
    All,
    /// The lanes starting at these nodes.
    Tags(Vec<NodeRef>),
}

impl<'de> Deserialize<'de> for TrafficLanes {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<TrafficLanes, D::Error> {
        use serde::de::Error;
        match toml::Value::deserialize(d)? {
            toml::Value::String(s) if s == "all" => Ok(TrafficLanes::All),
            v @ toml::Value::Array(_) => {
                v.try_into().map(TrafficLanes::Tags).map_err(|e: toml::de::Error| D::Error::custom(e.message()))
            }
            other => Err(D::Error::custom(format!("`lanes` must be \"all\" or a list of node tags, got {other}"))),
        }
    }
}

/// Where a `[[traffic]]` table's vehicles drive: `route = "random"` or a route table.
#[derive(Debug, Clone, PartialEq)]
pub enum TrafficRoute {
    /// `"random"`: every vehicle draws its own origin and destination lanelet (weighted by
    /// length) and drives the shortest route between them (see
    /// [`crate::app::running::random_trips`]).
    Random,
    /// `{ loop = NODE }` or `{ from = NODE, to = NODE, via = [NODE, ...] }`: all on one route.
    Fixed(RouteConfig),
}

impl TrafficRoute {
    /// The route table, `None` for random routes.
    pub fn fixed(&self) -> Option<&RouteConfig> {
        match self {
            TrafficRoute::Fixed(r) => Some(r),
            TrafficRoute::Random => None,
        }
    }
}

impl<'de> Deserialize<'de> for TrafficRoute {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<TrafficRoute, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = TrafficRoute;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("`route = \"random\"` or a table `{ loop = NODE }` / `{ from = NODE, to = NODE }`")
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<TrafficRoute, E> {
                if v == "random" {
                    Ok(TrafficRoute::Random)
                } else {
                    Err(E::custom(format!(
                        "`route` must be \"random\" or a table `{{ loop = NODE }}` / `{{ from = NODE, to = NODE, via = [NODE, ...] }}`, got \"{v}\""
                    )))
                }
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, map: A) -> Result<TrafficRoute, A::Error> {
                RouteConfig::deserialize(serde::de::value::MapAccessDeserializer::new(map)).map(TrafficRoute::Fixed)
            }
        }
        d.deserialize_any(V)
    }
}

/// One `[[traffic]]` table: background vehicles on a route, placed at the start and/or inserted
/// at a rate, everything random drawn from the scenario's `seed`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrafficConfig {
    /// `"random"`, `{ loop = NODE }` or `{ from = NODE, to = NODE, via = [NODE, ...] }`.
    pub route: TrafficRoute,
    /// Vehicles placed at t = 0 (evenly over the lanes, safe spacing for their speed; on random
    /// routes: each on its origin lanelet, spaced apart).
    #[serde(default)]
    pub count: usize,
    /// Vehicles inserted at the route start per hour [veh/h] (Poisson arrivals; a blocked entry
    /// waits). On random routes the total over the map, each at the start of its origin lanelet.
    #[serde(default)]
    pub rate: f64,
    /// No insertion after this sim time [s] (default: the whole run), so that every inserted
    /// vehicle can leave by the end.
    #[serde(default)]
    pub until: Option<f64>,
    /// `"all"` or a list of node tags naming the start lanes.
    #[serde(default)]
    pub lanes: TrafficLanes,
    /// Desired speed range [m/s], drawn uniformly per vehicle.
    #[serde(default = "default_traffic_speed")]
    pub speed: [f64; 2],
    /// Class shares, e.g. `{ car = 0.85, truck = 0.15 }` (normalised).
    #[serde(default = "default_traffic_classes")]
    pub classes: std::collections::BTreeMap<VehicleClass, f64>,
    /// Controller (default IDM); its `speed` is replaced by each vehicle's drawn desired speed.
    #[serde(default)]
    pub controller: Option<ControllerConfig>,
    /// Lane changes (default on, with the defaults).
    #[serde(default = "default_traffic_lane_change")]
    pub lane_change: LaneChangeSetting,
    /// Dynamics model.
    #[serde(default)]
    pub model: ModelConfig,
    /// Sensors (default: a radar of 60° and 100 m).
    #[serde(default = "default_traffic_sensors")]
    pub sensors: SensorsConfig,
    /// Whether these vehicles make way for emergency vehicles (see [`crate::vehicles::emergency_vehicle`]).
    #[serde(default = "yes")]
    pub yield_to_emergency: bool,
    /// First id [-]; ids count up from it. By default traffic is virtual: its ids are negative and
    /// count down from -1000 (or from the next thousand below every vehicle's and the previous
    /// table's ids).
    #[serde(default)]
    pub id_start: Option<i32>,
    /// What a vehicle on a random trip does at its destination: `"leave"` (the default: it is
    /// removed) or `"new_trip"` (it draws a new random trip from there, so a town's traffic
    /// never thins; `smlworld bench --city` drives this way).
    #[serde(default)]
    pub on_arrival: OnArrival,
    /// Random trips only: they start and end on lanelets whose `speed_limit` tag is at least
    /// this [m/s] and drive through none with a lower limit (lanelets without one pass), e.g. 25
    /// keeps them on a motorway (CARLA's Town04 marks its highway 65 mph, 29 m/s, its town 30 to
    /// 55 mph, its junctions' connecting roads not at all); see
    /// [`crate::app::running::random_trips::RandomTrips::on_fast_roads`].
    #[serde(default)]
    pub min_speed_limit: Option<f64>,
}

/// `[[traffic]] on_arrival`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OnArrival {
    /// Removed at the route's end.
    #[default]
    Leave,
    /// A random trip draws its next trip from its destination.
    NewTrip,
}

fn default_traffic_speed() -> [f64; 2] {
    [25.0, 33.0]
}
fn default_traffic_classes() -> std::collections::BTreeMap<VehicleClass, f64> {
    [(VehicleClass::Car, 1.0)].into_iter().collect()
}
fn default_traffic_lane_change() -> LaneChangeSetting {
    LaneChangeSetting(Some(LaneChangeParams::default()))
}
pub(crate) fn default_traffic_sensors() -> SensorsConfig {
    SensorsConfig { radar: Some(RadarConfig::default()), ..SensorsConfig::default() }
}

/// What to do with a CommonRoad map's obstacles.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ObstaclesMode {
    /// Each dynamic obstacle N becomes virtual vehicle -N whose state comes from its recorded
    /// trajectory (no dynamics), each static obstacle N a [`crate::world::Stationary`] vehicle
    /// -N at rest; both are seen by sensors and counted in the collision metrics.
    Replay,
}

fn default_duration() -> f64 {
    60.0
}
fn default_points_per_meter() -> f64 {
    5.0
}

/// `[output]`: outputs a run writes beside `trajectories.csv` and `summary.json`.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputSection {
    /// MCAP recording of the run (Foxglove schemas, see `docs/mcap.md`), relative to the run's
    /// output folder (`--out`); `smlworld run --mcap FILE` replaces it.
    #[serde(default)]
    pub mcap: Option<PathBuf>,
}

/// `[rates]`, all \[Hz\].
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RatesConfig {
    /// Dynamics \[Hz\].
    pub dynamics: f64,
    /// Sensors \[Hz\].
    pub sensors: f64,
    /// Controllers \[Hz\].
    pub control: f64,
    /// Wifi rounds \[Hz\].
    pub wifi: f64,
    /// Network rounds \[Hz\].
    pub network: f64,
    /// Trajectory log \[Hz\].
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

/// `[v2v]`: `wifi_range` (kept from before) or `[v2v.wifi] range`, and each channel's model.
#[derive(Debug, Clone, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct V2vSection {
    /// Wifi range \[m\], inclusive (the older spelling of `[v2v.wifi] range`).
    pub wifi_range: Option<f64>,
    /// `[v2v.wifi]`: range, loss, bursts, delay.
    pub wifi: ChannelSection,
    /// `[v2v.network]`: loss, bursts, delay (no range: it reaches everyone).
    pub network: ChannelSection,
}

impl V2vSection {
    /// The wifi range \[m\]: `wifi.range`, else `wifi_range`, else the default 50 m.
    pub fn range(&self) -> f64 {
        self.wifi.range.or(self.wifi_range).unwrap_or(V2vConfig::default().wifi_range)
    }
}

/// `[v2v.wifi]` / `[v2v.network]`: a channel's model ([`crate::sim::v2v::channel`]).
#[derive(Debug, Clone, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct ChannelSection {
    /// Range \[m\] (wifi only).
    pub range: Option<f64>,
    /// `loss = 0.1` (per reception) or `loss = { model = "NAME", ... }`: a built-in model
    /// (`constant`, `distance`, `gilbert_elliott`) or one a plugin registered.
    pub loss: LossConfig,
    /// `burst = { p_enter, p_leave, loss_in_burst }`: Gilbert-Elliott, per link.
    pub burst: Option<BurstConfig>,
    /// Delivery delay \[ms\].
    pub delay_ms: f64,
    /// Extra delay, uniform in [0, jitter_ms) \[ms\].
    pub jitter_ms: f64,
}

/// Why a channel's `loss` could not be turned into a model: the key (relative to the channel's
/// table) and what is wrong.
pub type ChannelProblem = (String, String);

impl ChannelSection {
    /// The model the V2V systems use, its `loss` model looked up in `models`: `Err((key,
    /// problem))` with the key relative to the channel's table (`loss.model`, `loss.p_at_0`, ...).
    pub fn model(&self, models: &ChannelModelRegistry) -> Result<ChannelModel, ChannelProblem> {
        let (loss, model_burst) = match &self.loss {
            LossConfig::Constant(p) => (Loss::Constant(*p), None),
            LossConfig::Model { name, params } => match models.parse(name, params.clone()) {
                Some(Ok(m)) => (m.loss, m.burst),
                Some(Err(e)) if e.key.is_empty() => return Err(("loss".into(), e.problem)),
                Some(Err(e)) => return Err((format!("loss.{}", e.key), e.problem)),
                None => {
                    return Err((
                        "loss.model".into(),
                        format!(
                            "names no known channel model: `{name}` (known: {}); a model of your own must be registered by its plugin (SimBuilder::register_channel_model) before the scenario is loaded",
                            models.known_list()
                        ),
                    ));
                }
            },
        };
        let burst =
            self.burst.map(|b| Burst { p_enter: b.p_enter, p_leave: b.p_leave, loss_in_burst: b.loss_in_burst });
        if burst.is_some() && model_burst.is_some() {
            return Err(("burst".into(), "and a `gilbert_elliott` loss both give bursts; keep one".into()));
        }
        Ok(ChannelModel { loss, burst: burst.or(model_burst), delay_ms: self.delay_ms, jitter_ms: self.jitter_ms })
    }
}

/// `burst = { p_enter, p_leave, loss_in_burst }` (probabilities per message): the same table as
/// `loss = { model = "gilbert_elliott", ... }` takes.
pub type BurstConfig = crate::sim::v2v::channel::GilbertElliott;

/// A channel's loss: a number, or a table naming a model.
#[derive(Debug, Clone, PartialEq)]
pub enum LossConfig {
    /// `loss = p`.
    Constant(f64),
    /// `loss = { model = "NAME", .. }`: the model's name and its other keys, parsed by the
    /// model registered under that name ([`ChannelModelRegistry`]).
    Model {
        /// The model's name.
        name: String,
        /// Its parameters (the table without `model`).
        params: toml::Table,
    },
}

impl Default for LossConfig {
    fn default() -> Self {
        LossConfig::Constant(0.0)
    }
}

impl<'de> Deserialize<'de> for LossConfig {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<LossConfig, D::Error> {
        use serde::de::Error;
        let forms = "`loss = 0.1` (probability per reception) or `loss = { model = \"NAME\", ... }` (e.g. `{ model = \"distance\", p_at_0 = 0.01, p_at_range = 0.5 }`)";
        match toml::Value::deserialize(d)? {
            toml::Value::Float(p) => Ok(LossConfig::Constant(p)),
            toml::Value::Integer(p) => Ok(LossConfig::Constant(p as f64)),
            toml::Value::Table(mut params) => match params.remove("model") {
                Some(toml::Value::String(name)) => Ok(LossConfig::Model { name, params }),
                Some(other) => Err(D::Error::custom(format!("`model` is {other}, not a name; expected {forms}"))),
                None => Err(D::Error::custom(format!("a loss table needs `model`; expected {forms}"))),
            },
            other => Err(D::Error::custom(format!("got {other}; expected {forms}"))),
        }
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
    /// Length \[m\] (default 4.12).
    #[serde(default)]
    pub length: Option<f64>,
    /// Width \[m\] (default 1.7).
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
    /// Id of a planning problem of the CommonRoad `map`: the vehicle starts at its initial state
    /// (position, heading, speed) and the summary says whether it reached the goal.
    #[serde(default)]
    pub planning_problem: Option<i64>,
    /// Lane changes: `lane_change = { politeness, ... }`, `true` (the defaults) or `false`
    /// (none, as without the key).
    #[serde(default)]
    pub lane_change: LaneChangeSetting,
    /// Whether it makes way for emergency vehicles (see [`crate::vehicles::emergency_vehicle`]).
    #[serde(default = "yes")]
    pub yield_to_emergency: bool,
}

/// `lane_change = false`, `true` or a table of [`LaneChangeParams`].
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LaneChangeSetting(pub Option<LaneChangeParams>);

impl<'de> Deserialize<'de> for LaneChangeSetting {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<LaneChangeSetting, D::Error> {
        use serde::de::Error;
        match toml::Value::deserialize(d)? {
            toml::Value::Boolean(false) => Ok(LaneChangeSetting(None)),
            toml::Value::Boolean(true) => Ok(LaneChangeSetting(Some(LaneChangeParams::default()))),
            v @ toml::Value::Table(_) => v
                .try_into()
                .map(|p| LaneChangeSetting(Some(p)))
                .map_err(|e: toml::de::Error| D::Error::custom(e.message())),
            other => Err(D::Error::custom(format!(
                "`lane_change` must be `false`, `true` or a table such as {{ politeness = 0.2 }}, got {other}"
            ))),
        }
    }
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
        /// Wheelbase \[m\].
        #[serde(default = "default_wheelbase")]
        wheelbase: f64,
        /// Steering limit \[rad\].
        #[serde(default = "default_max_steering")]
        max_steering: f64,
    },
    /// Acceleration unicycle (throttle command).
    Acceleration {
        /// Wheelbase \[m\].
        #[serde(default = "default_wheelbase")]
        wheelbase: f64,
        /// Mass \[kg\].
        #[serde(default = "default_mass")]
        mass: f64,
        /// Drag [N s/m].
        #[serde(default = "default_drag")]
        drag: f64,
        /// Steering limit \[rad\].
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

/// `route = { loop = NODE }` or `route = { from = NODE, to = NODE, via = [NODE, ...] }`.
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
    /// Places an open route passes, in order, between `from` and `to` (each leg the shortest).
    #[serde(default)]
    pub via: Vec<NodeRef>,
}

/// `start = { offset }`, `{ at, offset }` or `{ x, y, yaw }`.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StartConfig {
    /// A node to start at (projected onto the route if there is one).
    #[serde(default)]
    pub at: Option<NodeRef>,
    /// Distance along the route from the route start (or from `at`) \[m\].
    #[serde(default)]
    pub offset: Option<f64>,
    /// Position x \[m\].
    #[serde(default)]
    pub x: Option<f64>,
    /// Position y \[m\].
    #[serde(default)]
    pub y: Option<f64>,
    /// Heading \[rad\] (default: the route's heading there, else 0).
    #[serde(default)]
    pub yaw: Option<f64>,
}

/// `sensors = { radar, velodyne, omniscient, NAME = { .. } }`: the built-in sensors, and those
/// of plugins by their registered names.
#[derive(Debug, Clone, Default)]
pub struct SensorsConfig {
    /// Radar cone.
    pub radar: Option<RadarConfig>,
    /// Velodyne circle.
    pub velodyne: Option<VelodyneConfig>,
    /// Sees everyone.
    pub omniscient: bool,
    /// Plugin sensors: name -> their table, parsed by the sensor registered under that name
    /// ([`crate::sim::sensor_plugins::SensorRegistry`]) when the scenario is checked.
    pub plugins: std::collections::BTreeMap<String, toml::Table>,
}

impl<'de> Deserialize<'de> for SensorsConfig {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<SensorsConfig, D::Error> {
        use serde::de::Error;
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct BuiltIn {
            #[serde(default)]
            radar: Option<RadarConfig>,
            #[serde(default)]
            velodyne: Option<VelodyneConfig>,
            #[serde(default)]
            omniscient: bool,
        }
        let mut table = toml::Table::deserialize(d)?;
        let names: Vec<String> =
            table.keys().filter(|k| !["radar", "velodyne", "omniscient"].contains(&k.as_str())).cloned().collect();
        let mut plugins = std::collections::BTreeMap::new();
        for name in names {
            match table.remove(&name) {
                Some(toml::Value::Table(t)) => {
                    plugins.insert(name, t);
                }
                other => {
                    return Err(D::Error::custom(format!(
                        "`{name}` is {}: a plugin sensor's settings are a table (`{name} = {{ range = 50.0 }}`); the built-in sensors are radar, velodyne and omniscient",
                        other.map_or("missing".to_string(), |v| v.to_string())
                    )));
                }
            }
        }
        let b: BuiltIn =
            toml::Value::Table(table).try_into().map_err(|e: toml::de::Error| D::Error::custom(e.message()))?;
        Ok(SensorsConfig { radar: b.radar, velodyne: b.velodyne, omniscient: b.omniscient, plugins })
    }
}

/// `radar = { angle_deg, range, noise, dropout, occlusion }`.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RadarConfig {
    /// Full opening angle \[deg\] (converted to radians for the simulation).
    pub angle_deg: f64,
    /// Range \[m\].
    pub range: f64,
    /// Gaussian measurement noise (none by default).
    pub noise: NoiseConfig,
    /// Probability a detection is missed [-] (0 by default).
    pub dropout: f64,
    /// Whether a vehicle hidden behind a nearer one is not seen (false by default).
    pub occlusion: bool,
}

impl Default for RadarConfig {
    fn default() -> Self {
        let r = Radar::default();
        RadarConfig {
            angle_deg: r.angle.to_degrees(),
            range: r.range,
            noise: NoiseConfig::default(),
            dropout: 0.0,
            occlusion: false,
        }
    }
}

/// `velodyne = { range, noise, dropout, occlusion }`.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VelodyneConfig {
    /// Range \[m\].
    pub range: f64,
    /// Gaussian measurement noise (none by default).
    pub noise: NoiseConfig,
    /// Probability a detection is missed [-] (0 by default).
    pub dropout: f64,
    /// Whether a vehicle hidden behind a nearer one is not seen (false by default).
    pub occlusion: bool,
}

impl Default for VelodyneConfig {
    fn default() -> Self {
        VelodyneConfig {
            range: Velodyne::default().range,
            noise: NoiseConfig::default(),
            dropout: 0.0,
            occlusion: false,
        }
    }
}

/// `noise = { range_sd, bearing_sd_deg, speed_sd }` of a radar or velodyne: standard deviations
/// of Gaussian errors, 0 by default.
#[derive(Debug, Clone, Copy, Default, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NoiseConfig {
    /// Of the range to the target's centre [m].
    pub range_sd: f64,
    /// Of the bearing to the target's centre [deg] (converted to radians for the simulation).
    pub bearing_sd_deg: f64,
    /// Of each velocity component [m/s].
    pub speed_sd: f64,
}

impl NoiseConfig {
    /// The simulation's errors with this noise, `dropout` and `occlusion`.
    pub fn with(&self, dropout: f64, occlusion: bool) -> crate::world::SensorError {
        crate::world::SensorError {
            range_sd: self.range_sd,
            bearing_sd: self.bearing_sd_deg.to_radians(),
            speed_sd: self.speed_sd,
            dropout,
            occlusion,
        }
    }
}

/// `controller = { type = ... }`: a built-in controller, or one a plugin registered by name
/// (see [`crate::sim::ScenarioController`]).
// The built-in variant is the common one and is matched on by users' code: left unboxed.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
pub enum ControllerConfig {
    /// A built-in controller.
    BuiltIn(BuiltInController),
    /// A controller registered by a plugin: its name and the table's other keys, checked against
    /// the registry when the scenario is loaded with one ([`super::Scenario::load_with`]).
    Registered {
        /// The `type` value.
        name: String,
        /// The other keys of the table.
        params: toml::Table,
    },
}

/// The built-in `controller = { type = ... }` tables.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum BuiltInController {
    /// Pure pursuit along the route at a cruise speed.
    PathFollowing {
        /// Cruise speed [m/s].
        #[serde(default = "default_cruise")]
        speed: f64,
        /// Shortest look-ahead \[m\].
        #[serde(default = "default_lookahead_min")]
        lookahead_min: f64,
        /// Look-ahead time \[s\].
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
    /// Treiber's IDM on radar along the route.
    Idm(Idm),
    /// GCDC 2016 merging over V2V with CACC along the route.
    Gcdc(GcdcSetup),
}

impl<'de> Deserialize<'de> for ControllerConfig {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<ControllerConfig, D::Error> {
        use serde::de::Error;
        let mut table = toml::Table::deserialize(d)?;
        let name = match table.get("type") {
            Some(toml::Value::String(s)) => s.clone(),
            Some(other) => return Err(D::Error::custom(format!("`type` must be a string, got {other}"))),
            None => return Err(D::Error::custom("missing field `type` (the controller's name)")),
        };
        if BUILT_IN_CONTROLLERS.contains(&name.as_str()) {
            let built_in: BuiltInController =
                toml::Value::Table(table).try_into().map_err(|e: toml::de::Error| D::Error::custom(e.message()))?;
            return Ok(ControllerConfig::BuiltIn(built_in));
        }
        table.remove("type");
        Ok(ControllerConfig::Registered { name, params: table })
    }
}

impl ControllerConfig {
    /// The smart-vehicle controller this names, if it is one.
    pub fn smart(&self) -> Option<SmartController> {
        match self {
            ControllerConfig::BuiltIn(BuiltInController::CruiseControl(c)) => Some(SmartController::Cruise(*c)),
            ControllerConfig::BuiltIn(BuiltInController::Acc(c)) => Some(SmartController::Acc(*c)),
            ControllerConfig::BuiltIn(BuiltInController::Platoon(c)) => Some(SmartController::Platoon(*c)),
            ControllerConfig::BuiltIn(BuiltInController::Idm(c)) => Some(SmartController::Idm(*c)),
            ControllerConfig::BuiltIn(BuiltInController::Gcdc(c)) => Some(SmartController::Gcdc(*c)),
            _ => None,
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
