//! The scenario's `[lab]` section: motion capture, real trucks and the lab scale, and how it
//! starts the bridges of [`crate::io::lab`] for the real vehicles of a run.
//!
//! # Time with motion capture
//! Motion capture measures the lab in wall-clock time, so a simulation with motion capture has
//! to run in real time (speed 1): `smlworld run` switches to the real-time runner by itself
//! when the scenario has `[lab.mocap]` (see [`LabConfig::needs_wall_clock`]). Such a run is not
//! reproducible bit for bit: the real vehicles' states depend on when frames arrive.
//!
//! # Scenario section
//! ```toml
//! [lab]
//! scale = 32.0                          # lab floor -> world factor (trucks are 1:32)
//! mocap = { mock = true }               # or { addr = "127.0.0.1:22224", password = "..." }
//!                                       # also: poll_rate = 24.0 [Hz], stale_after = 0.5 [s]
//! trucks = { base_port = 16000, desired_distance = 20.0 }   # also: rate = 20.0 [Hz], lane_half_width = 2.0 [m]
//! bodies = { 1 = 0, 2 = 1 }             # QTM body number (1-based) -> vehicle id
//! ```
//! QTM numbers its bodies from 1 (body 1 is the first 6DOF body). Without `bodies`, body k
//! drives real vehicle k (so vehicle 0 needs `bodies`); with it, motion capture drives exactly
//! the vehicles it names (any id). With `mock = true` the run starts a [`MockMocapServer`]
//! in-process on a free loopback port whose bodies (numbered the same way) drive their
//! vehicles' routes at their scenario `speed` from their start: the script of [`ring_script`].

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::time::Duration;

use serde::Deserialize;

use crate::io::lab::{
    LaneIndex, MocapBridge, MocapPlugin, RealVehicleStatsPlugin, TruckBridge, TruckPlugin, ring_script,
};
use crate::io::mock_mocap::{DEFAULT_MOCK_RATE_HZ, MocapScript, MockMocapConfig, MockMocapServer};
use crate::io::qualisys::{
    BodyMapping, DEFAULT_POLL_RATE_HZ, DEFAULT_QTM_ADDR, QtmClient, QtmClientConfig, Tracker, TrackerConfig,
};
use crate::io::trucks::{
    DEFAULT_LAB_SCALE, DEFAULT_TRUCK_BASE_PORT, DEFAULT_TRUCK_RATE_HZ, TruckServer, TruckServerConfig,
};
use crate::map::LaneletMap;
use crate::sim::SimBuilder;
use crate::sim::params::MAX_TIME;
use crate::world::{AccelerationUnicycle, KinematicUnicycle, Route, VehicleId, VehicleState, Vehicles};

use super::{Scenario, ScenarioError};

/// A lab setting that cannot work, naming its key under `[lab]`.
#[derive(Debug, thiserror::Error)]
#[error("`lab.{key}` {problem}")]
pub struct LabError {
    /// The key under `[lab]` (e.g. `mocap.addr`).
    pub key: String,
    /// What is wrong and how to fix it.
    pub problem: String,
}

fn lab_error(key: &str, problem: impl Into<String>) -> LabError {
    LabError { key: key.into(), problem: problem.into() }
}

/// The `[lab]` section of a scenario.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LabConfig {
    /// Lab floor to world factor [-] (default 32): world \[m\] = lab \[m\] * scale.
    #[serde(default = "default_scale")]
    pub scale: f64,
    /// Motion capture input, if any.
    #[serde(default)]
    pub mocap: Option<MocapConfig>,
    /// Real-truck output, if any.
    #[serde(default)]
    pub trucks: Option<TrucksConfig>,
    /// QTM body number (1-based, as TOML keys: `{ 1 = 0, 2 = 1 }`) -> vehicle id; default: body
    /// k drives real vehicle k.
    #[serde(default)]
    pub bodies: Option<std::collections::BTreeMap<String, i32>>,
}

fn default_scale() -> f64 {
    DEFAULT_LAB_SCALE
}

/// `mocap = { ... }`: where the Qualisys server is.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MocapConfig {
    /// Start a mock server in-process (free loopback port) driving the real vehicles' routes.
    #[serde(default)]
    pub mock: bool,
    /// Address of the QTM server (default 127.0.0.1:22224; not with `mock`).
    #[serde(default)]
    pub addr: Option<String>,
    /// `TakeControl` password, when this client is not the master.
    #[serde(default)]
    pub password: Option<String>,
    /// Frame polls per second \[Hz\] (default 24).
    #[serde(default = "default_poll_rate")]
    pub poll_rate: f64,
    /// A body unseen for longer than this marks its vehicle stale \[s\] (default 0.5).
    #[serde(default = "default_stale_after")]
    pub stale_after: f64,
}

fn default_poll_rate() -> f64 {
    DEFAULT_POLL_RATE_HZ
}
fn default_stale_after() -> f64 {
    0.5
}

/// `trucks = { ... }`: the real trucks' TCP servers.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrucksConfig {
    /// Address to listen on (default 127.0.0.1).
    #[serde(default)]
    pub ip: Option<String>,
    /// Vehicle k listens on `base_port + k` (default 16000; 0: free ports, for tests).
    #[serde(default = "default_base_port")]
    pub base_port: u16,
    /// Status lines per second \[Hz\] (default 20).
    #[serde(default = "default_truck_rate")]
    pub rate: f64,
    /// Gap the trucks are asked to keep to their leader \[m\] (world units, default 20).
    #[serde(default = "default_desired_distance")]
    pub desired_distance: f64,
    /// A vehicle counts as on the truck's lane when its centre is at most this far from the
    /// lane's centre line \[m\] (default 2, half of a 4 m lane).
    #[serde(default = "default_lane_half_width")]
    pub lane_half_width: f64,
    /// Longest gap looked for \[m\] (default 100); with no leader closer, this is sent.
    #[serde(default = "default_max_gap")]
    pub max_gap: f64,
}

fn default_base_port() -> u16 {
    DEFAULT_TRUCK_BASE_PORT
}
fn default_truck_rate() -> f64 {
    DEFAULT_TRUCK_RATE_HZ
}
fn default_desired_distance() -> f64 {
    20.0
}
fn default_lane_half_width() -> f64 {
    2.0
}
fn default_max_gap() -> f64 {
    100.0
}

impl LabConfig {
    /// Whether a run must be paced to the wall clock at speed 1 (motion capture is on).
    pub fn needs_wall_clock(&self) -> bool {
        self.mocap.is_some()
    }

    /// Which vehicle each QTM body drives (see the module docs).
    pub fn body_mapping(&self) -> Result<BodyMapping, LabError> {
        let Some(bodies) = &self.bodies else { return Ok(BodyMapping::Identity) };
        let mut table = std::collections::BTreeMap::new();
        for (key, &id) in bodies {
            let number = key.parse::<u32>().ok().filter(|&n| n >= 1).ok_or_else(|| {
                lab_error(
                    &format!("bodies.{key}"),
                    "is not a QTM body number: bodies are numbered from 1 (body 1 is the first 6DOF body)",
                )
            })?;
            if let Some((other, _)) = table.iter().find(|(_, v)| **v == id) {
                return Err(lab_error(
                    &format!("bodies.{key}"),
                    format!("drives vehicle {id}, which body {other} drives already; one body per vehicle"),
                ));
            }
            table.insert(number, id);
        }
        Ok(BodyMapping::Table(table))
    }

    /// Check values the types cannot.
    pub fn check(&self) -> Result<(), LabError> {
        self.body_mapping()?;
        let positive = |key: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(lab_error(key, format!("must be a positive number, got {v}")))
            }
        };
        positive("scale", self.scale)?;
        if let Some(m) = &self.mocap {
            positive("mocap.poll_rate", m.poll_rate)?;
            if m.poll_rate > 1e3 {
                return Err(lab_error("mocap.poll_rate", format!("must be at most 1000 Hz, got {}", m.poll_rate)));
            }
            positive("mocap.stale_after", m.stale_after)?;
            if m.stale_after > MAX_TIME {
                return Err(lab_error(
                    "mocap.stale_after",
                    format!("must be at most {MAX_TIME} s (one day), got {}", m.stale_after),
                ));
            }
            if m.mock && m.addr.is_some() {
                return Err(lab_error("mocap", "takes either `mock = true` or `addr`, not both"));
            }
            if let Some(a) = &m.addr {
                a.parse::<SocketAddr>().map_err(|e| {
                    lab_error("mocap.addr", format!("{a:?} is not an address like \"127.0.0.1:22224\": {e}"))
                })?;
            }
        }
        if let Some(t) = &self.trucks {
            positive("trucks.rate", t.rate)?;
            if t.rate > 1e3 {
                return Err(lab_error("trucks.rate", format!("must be at most 1000 Hz, got {}", t.rate)));
            }
            positive("trucks.lane_half_width", t.lane_half_width)?;
            positive("trucks.max_gap", t.max_gap)?;
            if !(t.desired_distance.is_finite() && t.desired_distance >= 0.0) {
                return Err(lab_error(
                    "trucks.desired_distance",
                    format!("must be zero or more, got {}", t.desired_distance),
                ));
            }
            if let Some(ip) = &t.ip {
                ip.parse::<IpAddr>()
                    .map_err(|e| lab_error("trucks.ip", format!("{ip:?} is not an IP address: {e}")))?;
            }
        }
        Ok(())
    }
}

/// A real vehicle of the run as the lab bridges see it: id, start state, route.
type RealVehicle = (VehicleId, VehicleState, Option<Route>);

/// Start the bridges of `config` for the real vehicles (id >= 0) already spawned in `sim`, and
/// add their plugins plus [`RealVehicleStatsPlugin`]. `map` gives the trucks their lanes.
pub fn add_lab_plugins(sim: &mut SimBuilder, config: &LabConfig, map: Option<&LaneletMap>) -> Result<(), LabError> {
    config.check()?;
    let real = real_vehicles(sim, config)?;
    sim.add_plugin(RealVehicleStatsPlugin);
    if let Some(m) = &config.mocap {
        let mapping = config.body_mapping()?;
        let tracked = tracked_vehicles(sim, config, &mapping)?;
        let ids: Vec<VehicleId> = tracked.iter().map(|(_, (id, _, _))| *id).collect();
        sim.add_plugin(MocapPlugin::new(start_mocap(m, config.scale, mapping, &tracked)?, ids));
    }
    if let Some(t) = &config.trucks {
        let ip = match &t.ip {
            Some(ip) => ip.parse().map_err(|e| lab_error("trucks.ip", format!("{e}")))?,
            None => IpAddr::V4(Ipv4Addr::LOCALHOST),
        };
        let ids: Vec<i32> = real.iter().map(|(id, _, _)| id.0).collect();
        let server = TruckServer::start(
            &TruckServerConfig { ip, base_port: t.base_port, rate_hz: t.rate, scale: config.scale },
            &ids,
        )
        .map_err(|e| lab_error("trucks", format!("cannot start the truck servers: {e}")))?;
        for id in &ids {
            if let Some(a) = server.local_addr(*id) {
                tracing::info!("truck {id}: status lines on tcp://{a}");
            }
        }
        let bridge = TruckBridge {
            server,
            desired_distance: t.desired_distance,
            lane_half_width: t.lane_half_width,
            max_gap: t.max_gap,
        };
        sim.add_plugin(TruckPlugin::new(bridge, t.rate, map.map(LaneIndex::new)));
    }
    Ok(())
}

/// The real vehicles (id >= 0) spawned in `sim`; with motion capture none may have a dynamics
/// model (the bridge owns their state).
fn real_vehicles(sim: &mut SimBuilder, config: &LabConfig) -> Result<Vec<RealVehicle>, LabError> {
    let world = sim.world_mut();
    let entities: Vec<_> = world.resource::<Vehicles>().iter().filter(|(id, _)| id.is_real()).collect();
    let mut out = Vec::with_capacity(entities.len());
    for (id, e) in entities {
        let driven = world.get::<KinematicUnicycle>(e).is_some() || world.get::<AccelerationUnicycle>(e).is_some();
        if config.mocap.is_some() && driven {
            return Err(lab_error(
                "mocap",
                format!(
                    "drives real vehicle {id}, which also has a dynamics model: give it `model = {{ type = \"none\" }}`"
                ),
            ));
        }
        let state = world.get::<VehicleState>(e).copied().unwrap_or_default();
        out.push((id, state, world.get::<Route>(e).cloned()));
    }
    Ok(out)
}

/// The vehicles motion capture drives, with their body numbers: those `[lab] bodies` names (each
/// must exist), else the real vehicles (id >= 0), body k for vehicle k (vehicle 0 has none: an
/// error naming the fix). None may have a dynamics model (the bridge owns their state).
fn tracked_vehicles(
    sim: &mut SimBuilder,
    config: &LabConfig,
    mapping: &BodyMapping,
) -> Result<Vec<(u32, RealVehicle)>, LabError> {
    let world = sim.world_mut();
    let wanted: Vec<(u32, VehicleId)> = match mapping {
        BodyMapping::Table(t) => t.iter().map(|(b, id)| (*b, VehicleId(*id))).collect(),
        BodyMapping::Identity => {
            let mut out = Vec::new();
            for (id, _) in world.resource::<Vehicles>().iter().filter(|(id, _)| id.is_real()) {
                let Some(body) = mapping.body_of(id.0) else {
                    return Err(lab_error(
                        "mocap",
                        format!(
                            "drives real vehicle {id} by QTM body {id}, but QTM numbers its bodies from 1: map a body to it with `[lab] bodies = {{ 1 = {id} }}`"
                        ),
                    ));
                };
                out.push((body, id));
            }
            out
        }
    };
    let mut out = Vec::with_capacity(wanted.len());
    for (body, id) in wanted {
        let Some(e) = world.resource::<Vehicles>().get(id) else {
            return Err(lab_error(
                &format!("bodies.{body}"),
                format!("names vehicle {id}, which the scenario does not have"),
            ));
        };
        let driven = world.get::<KinematicUnicycle>(e).is_some() || world.get::<AccelerationUnicycle>(e).is_some();
        if config.mocap.is_some() && driven {
            return Err(lab_error(
                "mocap",
                format!(
                    "drives vehicle {id} (QTM body {body}), which also has a dynamics model: give it `model = {{ type = \"none\" }}`"
                ),
            ));
        }
        let state = world.get::<VehicleState>(e).copied().unwrap_or_default();
        out.push((body, (id, state, world.get::<Route>(e).cloned())));
    }
    Ok(out)
}

/// Connect the motion-capture client (to the mock server it starts for `mock = true`, else to
/// `addr`) and its tracker; `tracked` are the vehicles it drives with their body numbers.
fn start_mocap(
    m: &MocapConfig,
    scale: f64,
    mapping: BodyMapping,
    tracked: &[(u32, RealVehicle)],
) -> Result<MocapBridge, LabError> {
    let mut mock = None;
    let addr = if m.mock {
        let script = ring_script(
            tracked.iter().filter_map(|(body, (_, s, r))| Some((*body, *s, r.as_ref()?.0.as_ref()))),
            scale,
            1.0,
        );
        let server = MockMocapServer::start(MockMocapConfig {
            bind: SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 0),
            rate_hz: DEFAULT_MOCK_RATE_HZ,
            script,
        })
        .map_err(|e| lab_error("mocap.mock", format!("cannot start the mock server: {e}")))?;
        let addr = server.local_addr();
        tracing::info!("mock motion capture serving the real vehicles' routes on {addr}");
        mock = Some(server);
        addr
    } else {
        match &m.addr {
            Some(a) => a.parse().map_err(|e| lab_error("mocap.addr", format!("{e}")))?,
            None => DEFAULT_QTM_ADDR,
        }
    };
    let client = QtmClient::spawn(QtmClientConfig {
        addr,
        poll_rate_hz: m.poll_rate,
        password: m.password.clone(),
        ..Default::default()
    })
    .map_err(|e| lab_error("mocap", format!("cannot start the client: {e}")))?;
    let tracker = Tracker::new(TrackerConfig { mapping, scale, stale_after: Duration::from_secs_f64(m.stale_after) });
    Ok(MocapBridge::new(client, tracker, mock))
}

/// The mock motion-capture script of `scenario`'s real vehicles (what `mocap = { mock = true }`
/// serves), without starting any bridge: for `smlworld mock-mocap --scenario`.
pub fn scenario_script(scenario: &Scenario) -> Result<MocapScript, ScenarioError> {
    let mut plain = scenario.clone();
    let lab = plain.file.lab.take();
    let scale = lab.as_ref().map_or(DEFAULT_LAB_SCALE, |l| l.scale);
    let mapping = lab.as_ref().map_or(Ok(BodyMapping::Identity), LabConfig::body_mapping).map_err(|e| {
        ScenarioError::Invalid { path: scenario.path.clone(), key: format!("lab.{}", e.key), problem: e.problem }
    })?;
    let mut builder = plain.builder()?;
    let world = builder.world_mut();
    let vehicles: Vec<(u32, VehicleState, Route)> = world
        .resource::<Vehicles>()
        .iter()
        .filter_map(|(id, e)| {
            let body = match &mapping {
                BodyMapping::Identity if !id.is_real() => return None,
                m => m.body_of(id.0)?,
            };
            Some((body, *world.get::<VehicleState>(e)?, world.get::<Route>(e)?.clone()))
        })
        .collect();
    Ok(ring_script(vehicles.iter().map(|(b, s, r)| (*b, *s, r.0.as_ref())), scale, 1.0))
}
