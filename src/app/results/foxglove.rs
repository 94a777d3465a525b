//! Runs in the tools robotics labs open (issue 57): an MCAP recording with Foxglove schemas
//! (`--mcap FILE`, `[output] mcap`, `smlworld replay --mcap`) and the Foxglove WebSocket live view
//! (`--foxglove [ADDR]`), both sinks of one [`FoxgloveRecorder`] fed the per-log-tick
//! [`Snapshot`] the CSV writer reads: one snapshot, many sinks (see `docs/mcap.md`).
//!
//! Channels: `/map` (a `foxglove.SceneUpdate` at t = 0), `/vehicles` (a `SceneUpdate` per log
//! tick, departed vehicles deleted), `/tf` (`foxglove.FrameTransforms` `world` -> `vehicle/<id>`),
//! `/vehicle/<id>/state` (JSON), `/v2v` (JSON), `/events` (`foxglove.Log`), `/metrics` (the
//! final `summary.json`), `/camera/birdseye` (`foxglove.CompressedImage`, PNG, with
//! `--mcap-images HZ`) and `/gps/<id>` (`foxglove.LocationFix`, maps with a geographic origin).
//! Log time = sim time \[ns\]. With `--mcap-profile ros2` the file holds ROS 2 messages in CDR
//! instead ([`super::ros2`]).
//!
//! Nothing is built for a channel no sink listens to (`has_sinks`), so a live server without a
//! client costs a check per channel and tick; without `--mcap` and `--foxglove` there is no
//! recorder at all.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::net::SocketAddr;
use std::path::{Path as FsPath, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use bevy_ecs::prelude::{Query, Res, ResMut, Resource, World};
use bevy_ecs::schedule::{IntoScheduleConfigs, ScheduleLabel};
use foxglove::messages::{
    ArrowPrimitive, Color, CompressedImage, CubePrimitive, FrameTransform, FrameTransforms, LinePrimitive, LocationFix,
    Log, Point3, Pose, Quaternion, SceneEntity, SceneEntityDeletion, SceneUpdate, TextPrimitive, Timestamp, Vector3,
};
use foxglove::{Channel, Context, RawChannel, Schema};
use glam::DVec2;

use super::output::{ANGLE_DECIMALS, Fixed, LENGTH_DECIMALS, TIME_DECIMALS};
use crate::map::{LaneletMap, Projector};
use crate::sim::{Phase, Plugin, Sim, SimBuilder, SimClock};
use crate::vehicles::{LaneChanger, LanePosition, Longitudinal, TrafficLights};
use crate::world::{LabDriven, TurnSignal, VehicleClass, VehicleSize, VehicleState, Vehicles};

/// Default address of `--foxglove` (loopback: nothing outside this machine can connect).
pub const DEFAULT_FOXGLOVE_ADDR: &str = "127.0.0.1:8765";

/// What an MCAP recording holds: Foxglove's protobuf schemas, or ROS 2 messages in CDR.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum McapProfile {
    /// Foxglove protobuf schemas and JSON (Foxglove, Lichtblick).
    #[default]
    Foxglove,
    /// ROS 2 messages in CDR (`ros2 bag play`, rosbags).
    Ros2,
}

/// The recording and live-view arguments `smlworld run` and `replay` share.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct FoxgloveOutput {
    /// Write the run as an MCAP file (zstd chunks, indexed; Foxglove schemas, or ROS 2 with
    /// --mcap-profile ros2) to FILE, replacing the scenario's `[output] mcap`.
    #[arg(long, value_name = "FILE")]
    pub mcap: Option<PathBuf>,
    /// Add the bird's-eye view as PNG images on /camera/birdseye at HZ [Hz of sim time].
    #[arg(long, value_name = "HZ", value_parser = crate::range::rate_hz)]
    pub mcap_images: Option<f64>,
    /// Message set of --mcap: `foxglove` (protobuf schemas) or `ros2` (CDR, ROS 2 Humble
    /// messages: /tf, /clock, /vehicles and /map as MarkerArray, `/vehicle/<id>/odom`).
    #[arg(long, value_name = "PROFILE", value_enum, default_value_t = McapProfile::Foxglove)]
    pub mcap_profile: McapProfile,
    /// Serve the run live over the Foxglove WebSocket protocol on ADDR (default 127.0.0.1:8765;
    /// another interface only when given, with a warning). Open it in Foxglove or Lichtblick.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = DEFAULT_FOXGLOVE_ADDR)]
    pub foxglove: Option<SocketAddr>,
}

impl FoxgloveOutput {
    /// Whether anything is recorded or served.
    pub fn any(&self) -> bool {
        self.mcap.is_some() || self.foxglove.is_some()
    }
}

/// What can stop a recording or the live server.
#[derive(Debug, thiserror::Error)]
pub enum FoxgloveError {
    /// The MCAP file could not be created, written or moved into place.
    #[error("--mcap {path}: {message}; check that the folder exists and is writable")]
    Mcap {
        /// The file.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// The WebSocket server could not start.
    #[error("--foxglove {addr}: {message}; is another server on that port? pick one with --foxglove 127.0.0.1:PORT")]
    Server {
        /// The address asked for.
        addr: SocketAddr,
        /// Why.
        message: String,
    },
    /// An option that does not fit the others.
    #[error("{0}")]
    Option(String),
}

pub use super::snapshot::{Event, Snapshot, VehicleSnapshot};

/// The sim time [µs] as a Foxglove timestamp.
fn stamp(t_us: u64) -> Timestamp {
    Timestamp::new((t_us / 1_000_000) as u32, ((t_us % 1_000_000) * 1000) as u32)
}

fn vec3(x: f64, y: f64, z: f64) -> Vector3 {
    Vector3 { x, y, z }
}

/// Rotation about z by `yaw` [rad].
fn yaw_quaternion(yaw: f64) -> Quaternion {
    let (s, c) = (yaw * 0.5).sin_cos();
    Quaternion { x: 0.0, y: 0.0, z: s, w: c }
}

fn color(rgba: [u8; 4], alpha: f64) -> Color {
    Color { r: rgba[0] as f64 / 255.0, g: rgba[1] as f64 / 255.0, b: rgba[2] as f64 / 255.0, a: alpha }
}

/// Name of the JSON schema of `/vehicle/<id>/state`.
const STATE_SCHEMA_NAME: &str = "smlworld.VehicleState";
const STATE_SCHEMA: &str = r#"{"type":"object","properties":{"t":{"type":"number","description":"sim time [s]"},"x":{"type":"number","description":"[m]"},"y":{"type":"number","description":"[m]"},"yaw":{"type":"number","description":"[rad]"},"speed":{"type":"number","description":"[m/s]"},"accel":{"type":["number","null"],"description":"asked for [m/s^2]"},"lanelet":{"type":["integer","null"]},"lane_offset":{"type":["number","null"],"description":"[m], left positive"},"mode":{"type":"string"}}}"#;
const V2V_SCHEMA: &str = r#"{"type":"object","properties":{"t":{"type":"number","description":"sim time [s]"},"wifi":{"type":"object"},"network":{"type":"object"}}}"#;
const METRICS_SCHEMA: &str = r#"{"type":"object","description":"summary.json of the run"}"#;

/// The recorder as the simulation sees it: it gathers each log tick's [`Snapshot`] and events
/// and hands them to a thread of its own that encodes and writes them (the MCAP file, the live
/// server), so the simulation goes on meanwhile. At most [`RECORDER_QUEUE`] ticks wait: a
/// file sink that falls further behind holds the simulation back (the file must be complete);
/// a slow live client never does (the server drops its oldest messages).
#[derive(Resource)]
pub struct FoxgloveRecorder {
    jobs: Option<std::sync::mpsc::SyncSender<Job>>,
    worker: Option<std::thread::JoinHandle<RecorderCore>>,
    /// Snapshots the thread is done with (a `Mutex` only to make the resource `Sync`).
    recycled: std::sync::Mutex<std::sync::mpsc::Receiver<Snapshot>>,
    camera: Option<Arc<RawChannel>>,
    live_port: Option<u16>,
    /// Ids of the last tick's vehicles and whether each was changing lanes / braking hard.
    previous: Vec<(i32, TurnSignal, &'static str)>,
    /// Sim time of the last tick recorded [µs].
    pub(crate) last_t: Option<u64>,
    ticks: u64,
    collisions_seen: usize,
    lights_seen: Option<u64>,
    light_states: Vec<String>,
    v2v_seen: (u64, u64),
}

/// Ticks handed to the recorder thread that may wait there before the simulation waits.
pub const RECORDER_QUEUE: usize = 8;

/// Work for the recorder thread.
enum Job {
    Tick(Snapshot, Vec<Event>),
    V2v { t_us: u64, rounds: (u64, u64), wifi: (u64, u64), network: (u64, u64) },
    Image(Vec<u8>, u64),
}

impl FoxgloveRecorder {
    /// Open the sinks `output` asks for: the MCAP file at `mcap` (already resolved: the CLI's, or
    /// the scenario's `[output] mcap`) and the live server; `map` draws `/map` and gives the
    /// geographic origin of `/gps/<id>`.
    pub fn open(
        output: &FoxgloveOutput,
        mcap: Option<&FsPath>,
        map: Option<Arc<LaneletMap>>,
    ) -> Result<FoxgloveRecorder, FoxgloveError> {
        let mut core = RecorderCore::open(output, mcap, map)?;
        let camera = core.channels.as_ref().map(|c| c.camera_raw.clone());
        let live_port = core.server.as_ref().map(|s| s.port());
        let (jobs, queue) = std::sync::mpsc::sync_channel::<Job>(RECORDER_QUEUE);
        let (recycle, recycled) = std::sync::mpsc::channel::<Snapshot>();
        let worker = std::thread::Builder::new()
            .name("mcap-recorder".into())
            .spawn(move || {
                for job in queue {
                    match job {
                        Job::Tick(snapshot, events) => {
                            core.record(&snapshot, &events);
                            let _ = recycle.send(snapshot);
                        }
                        Job::V2v { t_us, rounds, wifi, network } => core.record_v2v(t_us, rounds, wifi, network),
                        Job::Image(png, t_us) => core.record_image(png, t_us),
                    }
                }
                core
            })
            .map_err(|e| FoxgloveError::Option(format!("cannot start the recorder thread: {e}")))?;
        Ok(FoxgloveRecorder {
            jobs: Some(jobs),
            worker: Some(worker),
            recycled: std::sync::Mutex::new(recycled),
            camera,
            live_port,
            previous: Vec::new(),
            last_t: None,
            ticks: 0,
            collisions_seen: 0,
            lights_seen: None,
            light_states: Vec::new(),
            v2v_seen: (0, 0),
        })
    }

    fn send(&self, job: Job) {
        if let Some(jobs) = &self.jobs {
            // An error means the thread ended (it panicked): `finish` reports it.
            let _ = jobs.send(job);
        }
    }

    /// Log ticks recorded so far.
    pub fn ticks(&self) -> u64 {
        self.ticks
    }

    /// The port the live server listens on (the one asked for, or the one picked for port 0).
    pub fn live_port(&self) -> Option<u16> {
        self.live_port
    }

    /// A snapshot to fill (one the recorder thread is done with, when there is one).
    pub fn take_snapshot(&self) -> Snapshot {
        self.recycled.lock().ok().and_then(|r| r.try_recv().ok()).unwrap_or_default()
    }

    /// Record one log tick: `snapshot` and the `events` since the last one. A tick at the time
    /// of the last one is skipped (the final state is logged once, as in `trajectories.csv`).
    pub fn record(&mut self, snapshot: Snapshot, events: Vec<Event>) {
        if self.last_t == Some(snapshot.t_us) {
            return;
        }
        self.last_t = Some(snapshot.t_us);
        self.ticks += 1;
        self.previous.clear();
        self.previous.extend(snapshot.vehicles.iter().map(|v| (v.id, v.signal, v.mode)));
        self.send(Job::Tick(snapshot, events));
    }

    /// Log a `/camera/birdseye` image (PNG bytes) at `t_us`.
    pub fn record_image(&mut self, png: Vec<u8>, t_us: u64) {
        self.send(Job::Image(png, t_us));
    }

    /// Log a V2V round summary on `/v2v` when a wifi or network round ran since the last call:
    /// round counts (wifi, network) and (sent, delivered) so far of each channel.
    pub fn record_v2v(&mut self, t_us: u64, rounds: (u64, u64), wifi: (u64, u64), network: (u64, u64)) {
        if rounds != self.v2v_seen {
            self.v2v_seen = rounds;
            self.send(Job::V2v { t_us, rounds, wifi, network });
        }
    }

    /// Whether `/camera/birdseye` has a sink (a file, or a subscribed client).
    pub fn wants_images(&self) -> bool {
        self.camera.as_ref().is_some_and(|c| c.has_sinks())
    }

    /// End the recording: log `summary` on `/metrics` at `t_us`, close the MCAP file and rename
    /// it into place, stop the live server. Returns the file written, if any.
    pub fn finish(mut self, summary: Option<&serde_json::Value>, t_us: u64) -> Result<Option<PathBuf>, FoxgloveError> {
        self.jobs = None;
        let worker = self.worker.take();
        match worker.map(std::thread::JoinHandle::join) {
            Some(Ok(core)) => core.finish(summary, t_us),
            Some(Err(_)) => {
                Err(FoxgloveError::Option("the MCAP recorder thread failed; the file is incomplete".into()))
            }
            None => Ok(None),
        }
    }
}

impl Drop for FoxgloveRecorder {
    /// A run that fails: the thread ends, the temporary file is removed.
    fn drop(&mut self) {
        self.jobs = None;
        if let Some(worker) = self.worker.take() {
            let _ = worker.join();
        }
    }
}

/// The sinks and channels of a run's recording and live view, on the recorder thread.
struct RecorderCore {
    context: Arc<Context>,
    mcap: Option<McapFile>,
    server: Option<foxglove::WebSocketServerHandle>,
    channels: Option<FoxgloveChannels>,
    ros2: Option<super::ros2::Ros2Channels>,
    map: Option<Arc<LaneletMap>>,
    /// The `/map` scene, logged at the first tick (and again when a live client subscribes).
    map_scene: Option<SceneUpdate>,
    /// Set by the live server when a client subscribes to `/map`.
    map_wanted: Arc<AtomicBool>,
    projector: Option<Projector>,
    /// Ids of the last tick's vehicles (the deletions of `/vehicles`).
    previous: Vec<(i32, TurnSignal, &'static str)>,
    pub(crate) last_t: Option<u64>,
    v2v_last: [(u64, u64); 2],
    json: String,
    ticks: u64,
    /// Per vehicle, where `/gps/<id>` last projected exactly (see [`GpsAnchor`]).
    gps_anchors: BTreeMap<i32, GpsAnchor>,
}

/// A point projected exactly to latitude and longitude, with the derivatives there: positions
/// within [`GPS_ANCHOR_RANGE`] of it are projected to first order (well under a millimetre of
/// error), so the exact inverse projection (a Newton iteration) runs once per vehicle every
/// `GPS_ANCHOR_RANGE` metres driven, not at every tick.
#[derive(Debug, Clone, Copy)]
struct GpsAnchor {
    at: DVec2,
    lat: f64,
    lon: f64,
    /// d(lat)/d(x, y) and d(lon)/d(x, y) [deg/m].
    dlat: DVec2,
    dlon: DVec2,
}

/// Largest distance [m] from a [`GpsAnchor`] at which it is used.
const GPS_ANCHOR_RANGE: f64 = 20.0;

impl GpsAnchor {
    fn new(projector: &Projector, at: DVec2) -> GpsAnchor {
        let (lat, lon) = projector.reverse(at);
        let (lat_x, lon_x) = projector.reverse(at + DVec2::X);
        let (lat_y, lon_y) = projector.reverse(at + DVec2::Y);
        GpsAnchor {
            at,
            lat,
            lon,
            dlat: DVec2::new(lat_x - lat, lat_y - lat),
            dlon: DVec2::new(lon_x - lon, lon_y - lon),
        }
    }

    fn lat_lon(&self, p: DVec2) -> (f64, f64) {
        let d = p - self.at;
        (self.lat + self.dlat.dot(d), self.lon + self.dlon.dot(d))
    }
}

/// The Foxglove-profile channels.
struct FoxgloveChannels {
    map: Channel<SceneUpdate>,
    vehicles: Channel<SceneUpdate>,
    tf: Channel<FrameTransforms>,
    events: Channel<Log>,
    v2v: Arc<RawChannel>,
    metrics: Arc<RawChannel>,
    camera: Channel<CompressedImage>,
    /// The same channel, for [`FoxgloveRecorder::wants_images`] on the simulation's side.
    camera_raw: Arc<RawChannel>,
    states: BTreeMap<i32, Arc<RawChannel>>,
    gps: BTreeMap<i32, Channel<LocationFix>>,
}

/// The MCAP file being written: under a temporary name beside the final one until
/// [`FoxgloveRecorder::finish`] renames it into place (removed if the run fails).
struct McapFile {
    handle: Option<foxglove::McapWriterHandle<std::io::BufWriter<std::fs::File>>>,
    tmp: PathBuf,
    path: PathBuf,
}

impl Drop for McapFile {
    fn drop(&mut self) {
        if let Some(handle) = self.handle.take() {
            let _ = handle.close();
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

/// The hidden temporary name of an output beside `path` (`dir/.name.partial`).
pub fn partial_path(path: &FsPath) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "run.mcap".into());
    path.with_file_name(format!(".{name}.partial"))
}

/// Whether `addr` is reachable only from this machine.
fn loopback(addr: &SocketAddr) -> bool {
    addr.ip().is_loopback()
}

/// Re-sends `/map` to a live client that subscribes to it after t = 0.
struct MapSubscriber(Arc<AtomicBool>);

impl foxglove::websocket::ServerListener for MapSubscriber {
    fn on_subscribe(&self, _client: foxglove::websocket::Client, channel: foxglove::websocket::ChannelView) {
        if channel.topic() == "/map" {
            self.0.store(true, Ordering::Relaxed);
        }
    }
}

impl RecorderCore {
    fn open(
        output: &FoxgloveOutput,
        mcap: Option<&FsPath>,
        map: Option<Arc<LaneletMap>>,
    ) -> Result<RecorderCore, FoxgloveError> {
        let context = Context::new();
        let map_wanted = Arc::new(AtomicBool::new(false));
        let ros2 = output.mcap_profile == McapProfile::Ros2;
        if ros2 && output.foxglove.is_some() {
            return Err(FoxgloveError::Option(
                "--mcap-profile ros2 records ROS 2 messages, which the Foxglove live server does not serve; \
                 drop --foxglove or record the foxglove profile"
                    .into(),
            ));
        }
        if ros2 && output.mcap_images.is_some() {
            return Err(FoxgloveError::Option(
                "--mcap-images records foxglove.CompressedImage; use it with --mcap-profile foxglove".into(),
            ));
        }
        let mcap = match mcap {
            Some(path) => {
                let tmp = partial_path(path);
                // zstd level 1: a third of the default level's time for a slightly larger file.
                let options = foxglove::McapWriteOptions::new()
                    .compression(Some(foxglove::McapCompression::Zstd))
                    .compression_level(1)
                    .profile(if ros2 { "ros2" } else { "" });
                let handle = context
                    .mcap_writer_with_options(options.clone())
                    .create_new_buffered_file(&tmp)
                    .or_else(|_| {
                        // A stale partial file from a run that was killed: start over.
                        let _ = std::fs::remove_file(&tmp);
                        context.mcap_writer_with_options(options).create_new_buffered_file(&tmp)
                    })
                    .map_err(|e| FoxgloveError::Mcap { path: path.to_path_buf(), message: e.to_string() })?;
                Some(McapFile { handle: Some(handle), tmp, path: path.to_path_buf() })
            }
            None => None,
        };
        let server = match output.foxglove {
            Some(addr) => {
                if !loopback(&addr) {
                    tracing::warn!(
                        "--foxglove {addr}: serving the run to other machines on that network (no \
                         authentication, no encryption); use 127.0.0.1 to keep it on this machine"
                    );
                }
                let handle = context
                    .websocket_server()
                    .name("smlworld")
                    .bind(addr.ip().to_string(), addr.port())
                    .capabilities([foxglove::websocket::Capability::Time])
                    .listener(Arc::new(MapSubscriber(map_wanted.clone())))
                    .start_blocking()
                    .map_err(|e| FoxgloveError::Server { addr, message: e.to_string() })?;
                tracing::info!(
                    "serving the run on ws://{}:{} (open it in Foxglove or Lichtblick: Open connection, Foxglove WebSocket)",
                    addr.ip(),
                    handle.port()
                );
                Some(handle)
            }
            None => None,
        };
        let projector = map.as_ref().map(|m| m.projector).filter(|p| p.origin_lat != 0.0 || p.origin_lon != 0.0);
        let (channels, ros2) = if ros2 {
            let channels = super::ros2::Ros2Channels::new(&context)
                .ok_or_else(|| FoxgloveError::Option("--mcap-profile ros2: the channels could not be made".into()))?;
            (None, Some(channels))
        } else {
            (Some(FoxgloveChannels::new(&context)?), None)
        };
        let map_scene = map.as_deref().map(map_scene);
        Ok(RecorderCore {
            context,
            mcap,
            server,
            channels,
            ros2,
            map_scene,
            map,
            map_wanted,
            projector,
            previous: Vec::new(),
            last_t: None,
            v2v_last: [(0, 0); 2],
            json: String::new(),
            ticks: 0,
            gps_anchors: BTreeMap::new(),
        })
    }

    /// Record one log tick.
    fn record(&mut self, snapshot: &Snapshot, events: &[Event]) {
        if self.last_t == Some(snapshot.t_us) {
            return;
        }
        self.last_t = Some(snapshot.t_us);
        self.ticks += 1;
        let t_ns = snapshot.t_us * 1000;
        if let Some(server) = &self.server {
            server.broadcast_time(t_ns);
        }
        let first = self.ticks == 1;
        if let Some(ros2) = self.ros2.as_mut() {
            if first && let Some(map) = self.map.as_deref() {
                ros2.record_map(map);
            }
            ros2.record(snapshot);
            return;
        }
        let Some(ch) = self.channels.as_mut() else { return };
        let resend = self.map_wanted.swap(false, Ordering::Relaxed);
        if (first || resend)
            && let Some(scene) = &self.map_scene
            && ch.map.has_sinks()
        {
            // The map is there from t = 0 (a replay's first row may come later).
            ch.map.log_with_time(scene, if first { 0 } else { t_ns });
        }
        let ts = stamp(snapshot.t_us);
        if ch.vehicles.has_sinks() {
            ch.vehicles.log_with_time(&vehicles_scene(snapshot, &self.previous, ts), t_ns);
        }
        if ch.tf.has_sinks() {
            let mut transforms: Vec<FrameTransform> = Vec::with_capacity(snapshot.vehicles.len() + 1);
            if first {
                transforms.push(FrameTransform {
                    timestamp: Some(ts),
                    parent_frame_id: "world".into(),
                    child_frame_id: "map".into(),
                    translation: Some(vec3(0.0, 0.0, 0.0)),
                    rotation: Some(yaw_quaternion(0.0)),
                });
            }
            transforms.extend(snapshot.vehicles.iter().map(|v| FrameTransform {
                timestamp: Some(ts),
                parent_frame_id: "world".into(),
                child_frame_id: format!("vehicle/{}", v.id),
                translation: Some(vec3(v.position.x, v.position.y, 0.0)),
                rotation: Some(yaw_quaternion(v.yaw)),
            }));
            ch.tf.log_with_time(&FrameTransforms { transforms }, t_ns);
        }
        let t = snapshot.t_us as f64 * 1e-6;
        for v in &snapshot.vehicles {
            let channel = match ch.states.get(&v.id) {
                Some(c) => c,
                None => {
                    let c = ch.json_channel(
                        &self.context,
                        &format!("/vehicle/{}/state", v.id),
                        STATE_SCHEMA_NAME,
                        STATE_SCHEMA,
                    );
                    ch.states.entry(v.id).or_insert(c)
                }
            };
            if channel.has_sinks() {
                self.json.clear();
                // Numbers with the precision of trajectories.csv (1 mm, 1e-5 rad, 1 µs).
                let _ = write!(
                    self.json,
                    r#"{{"t":{},"x":{},"y":{},"yaw":{},"speed":{},"accel":{},"lanelet":{},"lane_offset":{},"mode":"{}"}}"#,
                    JsonNum(t, TIME_DECIMALS),
                    JsonNum(v.position.x, LENGTH_DECIMALS),
                    JsonNum(v.position.y, LENGTH_DECIMALS),
                    JsonNum(v.yaw, ANGLE_DECIMALS),
                    JsonNum(v.velocity.length(), LENGTH_DECIMALS),
                    JsonNum(v.accel, LENGTH_DECIMALS),
                    v.lanelet.map_or("null".to_string(), |l| l.to_string()),
                    JsonNum(v.lane_offset.unwrap_or(f64::NAN), LENGTH_DECIMALS),
                    v.mode
                );
                channel.log_with_meta(self.json.as_bytes(), foxglove::PartialMetadata::with_log_time(t_ns));
            }
            if let Some(projector) = &self.projector {
                let gps = ch
                    .gps
                    .entry(v.id)
                    .or_insert_with(|| self.context.channel_builder(format!("/gps/{}", v.id)).build::<LocationFix>());
                if gps.has_sinks() {
                    let anchor = match self.gps_anchors.get(&v.id) {
                        Some(a) if a.at.distance(v.position) <= GPS_ANCHOR_RANGE => *a,
                        _ => {
                            let a = GpsAnchor::new(projector, v.position);
                            self.gps_anchors.insert(v.id, a);
                            a
                        }
                    };
                    let (lat, lon) = anchor.lat_lon(v.position);
                    gps.log_with_time(
                        &LocationFix {
                            timestamp: Some(ts),
                            frame_id: format!("vehicle/{}", v.id),
                            latitude: lat,
                            longitude: lon,
                            // Heading: clockwise from north [deg], as NMEA gives it.
                            heading: Some((90.0 - v.yaw.to_degrees()).rem_euclid(360.0)),
                            ..Default::default()
                        },
                        t_ns,
                    );
                }
            }
        }
        if ch.events.has_sinks() {
            for e in events {
                ch.events.log_with_time(
                    &Log {
                        timestamp: Some(stamp(e.t_us)),
                        level: e.level,
                        message: e.message.clone(),
                        name: e.name.into(),
                        file: String::new(),
                        line: 0,
                    },
                    e.t_us * 1000,
                );
            }
        }
        self.previous.clear();
        self.previous.extend(snapshot.vehicles.iter().map(|v| (v.id, v.signal, v.mode)));
    }

    /// Log a V2V round summary on `/v2v` (cumulative counts and those since the last message,
    /// per channel) when a wifi or network round ran since the last call.
    fn record_v2v(&mut self, t_us: u64, rounds: (u64, u64), wifi: (u64, u64), network: (u64, u64)) {
        let Some(ch) = self.channels.as_ref() else { return };
        let last = self.v2v_last;
        self.v2v_last = [wifi, network];
        if !ch.v2v.has_sinks() {
            return;
        }
        let part = |name: &str, rounds: u64, now: (u64, u64), before: (u64, u64)| {
            format!(
                r#""{name}":{{"rounds":{rounds},"sent":{},"delivered":{},"lost":{},"sent_since_last":{},"delivered_since_last":{},"lost_since_last":{}}}"#,
                now.0,
                now.1,
                now.0.saturating_sub(now.1),
                now.0.saturating_sub(before.0),
                now.1.saturating_sub(before.1),
                (now.0.saturating_sub(now.1)).saturating_sub(before.0.saturating_sub(before.1))
            )
        };
        let json = format!(
            r#"{{"t":{},{},{}}}"#,
            t_us as f64 * 1e-6,
            part("wifi", rounds.0, wifi, last[0]),
            part("network", rounds.1, network, last[1])
        );
        ch.v2v.log_with_meta(json.as_bytes(), foxglove::PartialMetadata::with_log_time(t_us * 1000));
    }

    /// Log a `/camera/birdseye` image (PNG bytes) at `t_us`.
    fn record_image(&mut self, png: Vec<u8>, t_us: u64) {
        if let Some(ch) = self.channels.as_ref()
            && ch.camera.has_sinks()
        {
            ch.camera.log_with_time(
                &CompressedImage {
                    timestamp: Some(stamp(t_us)),
                    frame_id: "world".into(),
                    data: png.into(),
                    format: "png".into(),
                },
                t_us * 1000,
            );
        }
    }

    /// Log `summary` on `/metrics` at `t_us`, close the MCAP file and rename it into place, stop
    /// the live server.
    fn finish(mut self, summary: Option<&serde_json::Value>, t_us: u64) -> Result<Option<PathBuf>, FoxgloveError> {
        if let (Some(summary), Some(ch)) = (summary, self.channels.as_ref())
            && ch.metrics.has_sinks()
        {
            let text = summary.to_string();
            ch.metrics.log_with_meta(text.as_bytes(), foxglove::PartialMetadata::with_log_time(t_us * 1000));
        }
        if let Some(server) = self.server.take() {
            server.stop().wait_blocking();
        }
        let Some(mut file) = self.mcap.take() else { return Ok(None) };
        let error = |e: String| FoxgloveError::Mcap { path: file.path.clone(), message: e };
        if let Some(handle) = file.handle.take() {
            let mut writer = handle.close().map_err(|e| error(e.to_string()))?;
            std::io::Write::flush(&mut writer).map_err(|e| error(e.to_string()))?;
        }
        std::fs::rename(&file.tmp, &file.path).map_err(|e| error(format!("cannot move it into place: {e}")))?;
        Ok(Some(file.path.clone()))
    }
}

/// A number as JSON rounded to `.1` decimals (at most 9), written as an integer and its
/// decimals (`12.500`, `-0.250`; formatting a float exactly was a tenth of the recorder's
/// time): `null` when not finite, [`Fixed`] beyond 1e12.
struct JsonNum(f64, usize);

impl std::fmt::Display for JsonNum {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (x, decimals) = (self.0, self.1.min(9));
        if !x.is_finite() {
            return f.write_str("null");
        }
        if x.abs() >= 1e12 {
            return Fixed(x, decimals).fmt(f);
        }
        let scale = 10u64.pow(decimals as u32);
        let units = (x.abs() * scale as f64).round() as u64;
        let sign = if x < 0.0 && units != 0 { "-" } else { "" };
        if decimals == 0 {
            write!(f, "{sign}{units}")
        } else {
            write!(f, "{sign}{}.{:0width$}", units / scale, units % scale, width = decimals)
        }
    }
}

impl FoxgloveChannels {
    fn new(context: &Arc<Context>) -> Result<FoxgloveChannels, FoxgloveError> {
        let json = |topic: &str, name: &str, schema: &'static str| {
            context
                .channel_builder(topic)
                .message_encoding("json")
                .schema(Schema::new(name, "jsonschema", schema.as_bytes()))
                .build_raw()
                .map_err(|e| FoxgloveError::Option(format!("channel {topic}: {e}")))
        };
        let camera = context.channel_builder("/camera/birdseye").build::<CompressedImage>().into_inner();
        Ok(FoxgloveChannels {
            map: context.channel_builder("/map").build(),
            vehicles: context.channel_builder("/vehicles").build(),
            tf: context.channel_builder("/tf").build(),
            events: context.channel_builder("/events").build(),
            v2v: json("/v2v", "smlworld.V2vRound", V2V_SCHEMA)?,
            metrics: json("/metrics", "smlworld.Summary", METRICS_SCHEMA)?,
            camera: Channel::from_raw_channel(camera.clone()),
            camera_raw: camera,
            states: BTreeMap::new(),
            gps: BTreeMap::new(),
        })
    }

    /// A JSON channel; a topic that cannot be built (never: the names are ours) falls back to
    /// one without a schema.
    fn json_channel(&self, context: &Arc<Context>, topic: &str, name: &str, schema: &'static str) -> Arc<RawChannel> {
        context
            .channel_builder(topic)
            .message_encoding("json")
            .schema(Schema::new(name, "jsonschema", schema.as_bytes()))
            .build_raw()
            .unwrap_or_else(|_| self.metrics.clone())
    }
}

/// Dash period of dashed lane lines on `/map` [m] (half paint, half gap, as the frames draw).
const DASH_PERIOD: f64 = 6.0;

/// Whether a lanelet bound way is painted dashed: SML `line_type=interior`, Lanelet2
/// `subtype=dashed`, OpenDRIVE/SUMO broken marks.
fn dashed_way(map: &LaneletMap, way: i64) -> bool {
    map.ways.get(&way).is_some_and(|w| {
        let tag = |k: &str| w.tags.get(k).map(String::as_str);
        tag("line_type") == Some("interior")
            || tag("subtype").is_some_and(|s| s.starts_with("dashed"))
            || tag("subtype") == Some("broken")
    })
}

/// Segments of `points` dashed with `period` (half paint), appended to `out` as pairs.
fn dash(points: &[DVec2], period: f64, out: &mut Vec<Point3>) {
    let paint = period * 0.5;
    let mut phase = 0.0; // distance into the current period
    for w in points.windows(2) {
        let (a, b) = (w[0], w[1]);
        let len = a.distance(b);
        if len <= 0.0 {
            continue;
        }
        let dir = (b - a) / len;
        let mut s = 0.0;
        while s < len {
            let in_paint = phase < paint;
            let left = if in_paint { paint - phase } else { period - phase };
            let step = left.min(len - s);
            if in_paint {
                let p = a + dir * s;
                let q = a + dir * (s + step);
                out.push(Point3 { x: p.x, y: p.y, z: 0.0 });
                out.push(Point3 { x: q.x, y: q.y, z: 0.0 });
            }
            s += step;
            phase = (phase + step) % period;
        }
    }
}

/// The `/map` scene: every lanelet bound once (solid or dashed as the map says), stop lines.
pub fn map_scene(map: &LaneletMap) -> SceneUpdate {
    let mut solid = Vec::new();
    let mut dashed = Vec::new();
    let mut seen = std::collections::BTreeSet::new();
    for l in &map.lanelets {
        for (way, points) in [(l.left_way, &l.left), (l.right_way, &l.right)] {
            if !seen.insert(way) || points.len() < 2 {
                continue;
            }
            if dashed_way(map, way) {
                dash(points, DASH_PERIOD, &mut dashed);
            } else {
                for w in points.windows(2) {
                    solid.push(Point3 { x: w[0].x, y: w[0].y, z: 0.0 });
                    solid.push(Point3 { x: w[1].x, y: w[1].y, z: 0.0 });
                }
            }
        }
    }
    let mut stops = Vec::new();
    for junction in crate::render::stop_lines(map, &map.junctions()) {
        for (a, b) in junction {
            if a != b {
                stops.push(Point3 { x: a.x, y: a.y, z: 0.0 });
                stops.push(Point3 { x: b.x, y: b.y, z: 0.0 });
            }
        }
    }
    let line = |points: Vec<Point3>, thickness: f64, rgba: [u8; 4]| LinePrimitive {
        r#type: foxglove::messages::line_primitive::Type::LineList as i32,
        pose: Some(Pose { position: Some(vec3(0.0, 0.0, 0.0)), orientation: Some(yaw_quaternion(0.0)) }),
        thickness,
        scale_invariant: false,
        points,
        color: Some(color(rgba, 1.0)),
        colors: Vec::new(),
        indices: Vec::new(),
    };
    let mut lines = vec![line(solid, 0.2, [236, 190, 40, 255]), line(dashed, 0.15, [242, 242, 236, 255])];
    if !stops.is_empty() {
        lines.push(line(stops, 0.4, [242, 242, 236, 255]));
    }
    lines.retain(|l| !l.points.is_empty());
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![SceneEntity {
            timestamp: Some(stamp(0)),
            frame_id: "map".into(),
            id: "map".into(),
            frame_locked: true,
            lines,
            ..Default::default()
        }],
    }
}

/// Height of the vehicle cubes [m] (the map is flat; a box reads better in 3D than a plate).
const CUBE_HEIGHT: f64 = 1.5;

/// The `/vehicles` scene of one tick: a cube, id text and velocity arrow per vehicle, the
/// indicator while changing lanes, and deletions of the vehicles of `previous` (sorted ids)
/// that left.
pub fn vehicles_scene(snapshot: &Snapshot, previous: &[(i32, TurnSignal, &'static str)], ts: Timestamp) -> SceneUpdate {
    let mut deletions = Vec::new();
    let mut i = 0;
    for &(id, _, _) in previous {
        while i < snapshot.vehicles.len() && snapshot.vehicles[i].id < id {
            i += 1;
        }
        if snapshot.vehicles.get(i).is_none_or(|v| v.id != id) {
            deletions.push(SceneEntityDeletion {
                timestamp: Some(ts),
                r#type: foxglove::messages::scene_entity_deletion::Type::MatchingId as i32,
                id: format!("vehicle/{id}"),
            });
        }
    }
    let entities = snapshot
        .vehicles
        .iter()
        .map(|v| {
            let rgba = crate::render::class_color(v.class.name());
            let speed = v.velocity.length();
            let mut arrows = Vec::new();
            if speed > 0.01 {
                // In the vehicle's frame: along its velocity relative to its heading.
                let heading = v.velocity.y.atan2(v.velocity.x) - v.yaw;
                arrows.push(ArrowPrimitive {
                    pose: Some(Pose {
                        position: Some(vec3(0.0, 0.0, CUBE_HEIGHT + 0.2)),
                        orientation: Some(yaw_quaternion(heading)),
                    }),
                    shaft_length: speed * 0.5,
                    shaft_diameter: 0.15,
                    head_length: 0.6,
                    head_diameter: 0.5,
                    color: Some(color([30, 30, 30, 255], 1.0)),
                });
            }
            let mut cubes = vec![CubePrimitive {
                pose: Some(Pose {
                    position: Some(vec3(0.0, 0.0, CUBE_HEIGHT * 0.5)),
                    orientation: Some(yaw_quaternion(0.0)),
                }),
                size: Some(vec3(v.length, v.width, CUBE_HEIGHT)),
                color: Some(color(rgba, if v.real { 1.0 } else { 0.6 })),
            }];
            let side = match v.signal {
                TurnSignal::Left => Some(1.0),
                TurnSignal::Right => Some(-1.0),
                TurnSignal::Off => None,
            };
            if let Some(side) = side {
                // Amber lamps at the front and rear corners of the indicating side.
                for x in [v.length * 0.5, -v.length * 0.5] {
                    cubes.push(CubePrimitive {
                        pose: Some(Pose {
                            position: Some(vec3(x, side * v.width * 0.5, CUBE_HEIGHT * 0.5)),
                            orientation: Some(yaw_quaternion(0.0)),
                        }),
                        size: Some(vec3(0.4, 0.3, 0.4)),
                        color: Some(color([255, 160, 0, 255], 1.0)),
                    });
                }
            }
            SceneEntity {
                timestamp: Some(ts),
                frame_id: format!("vehicle/{}", v.id),
                id: format!("vehicle/{}", v.id),
                frame_locked: true,
                cubes,
                arrows,
                texts: vec![TextPrimitive {
                    pose: Some(Pose {
                        position: Some(vec3(0.0, 0.0, CUBE_HEIGHT + 1.0)),
                        orientation: Some(yaw_quaternion(0.0)),
                    }),
                    billboard: true,
                    font_size: 14.0,
                    scale_invariant: true,
                    color: Some(color([255, 255, 255, 255], 1.0)),
                    text: v.id.to_string(),
                }],
                lines: Vec::new(),
                ..Default::default()
            }
        })
        .collect();
    SceneUpdate { deletions, entities }
}

/// Schedule of the recorder when it runs apart from the trajectory log (a replay, a test).
#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Record;

/// Schedule of `/camera/birdseye` (`--mcap-images HZ`).
#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct BirdseyeImages;

/// The recorder on the trajectory log's ticks ([`super::output::Log`], after the CSV rows):
/// insert a [`FoxgloveRecorder`] resource first. With `images` \[Hz\], a module of its own draws
/// the bird's-eye view into `/camera/birdseye`.
pub struct FoxgloveRecordPlugin {
    /// `--mcap-images` \[Hz\].
    pub images: Option<f64>,
    /// The map the images draw.
    pub map: Option<Arc<LaneletMap>>,
}

impl Plugin for FoxgloveRecordPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.add_systems(super::output::Log, record_tick.after(super::output::log_trajectories));
        if let (Some(hz), Some(map)) = (self.images, self.map.as_ref()) {
            let options = crate::render::FrameOutput::default();
            match crate::render::FrameRecorder::new(map, &options) {
                Ok(rec) => {
                    sim.insert_resource(BirdseyeCamera(rec));
                    sim.add_module("mcap_images", BirdseyeImages, Phase::Sense, hz);
                    sim.add_systems(BirdseyeImages, record_birdseye);
                }
                Err(e) => tracing::warn!("--mcap-images: no bird's-eye view ({e}); recording without /camera/birdseye"),
            }
        }
    }
}

/// The off-screen renderer of `/camera/birdseye`.
#[derive(Resource)]
struct BirdseyeCamera(crate::render::FrameRecorder);

/// Draw the bird's-eye view into `/camera/birdseye` (PNG).
fn record_birdseye(world: &mut World) {
    let wants = world.get_resource::<FoxgloveRecorder>().is_some_and(|r| r.wants_images());
    if !wants {
        return;
    }
    let t_us = world.get_resource::<SimClock>().map_or(0, |c| c.now.0);
    let image =
        world.resource_scope(|world, mut camera: bevy_ecs::prelude::Mut<BirdseyeCamera>| camera.0.render(world));
    match image.map_err(|e| e.to_string()).and_then(|img| png_bytes(&img)) {
        Ok(png) => {
            if let Some(mut rec) = world.get_resource_mut::<FoxgloveRecorder>() {
                rec.record_image(png, t_us);
            }
        }
        Err(e) => tracing::warn!("--mcap-images at t = {} s: {e}", t_us as f64 * 1e-6),
    }
}

/// `image` as PNG bytes (fast compression: a frame per tick).
fn png_bytes(image: &image::RgbaImage) -> Result<Vec<u8>, String> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new_with_quality(
        &mut out,
        image::codecs::png::CompressionType::Fast,
        image::codecs::png::FilterType::Adaptive,
    )
    .write_image(image.as_raw(), image.width(), image.height(), image::ExtendedColorType::Rgba8)
    .map_err(|e| e.to_string())?;
    Ok(out)
}

/// What drives a vehicle now, for `/vehicle/<id>/state`.
fn mode(lab: bool, lon: Option<&Longitudinal>, yielding: bool, changing: bool) -> &'static str {
    match lon {
        _ if lab => "lab",
        Some(l) if l.emergency => "emergency_braking",
        _ if yielding => "yielding",
        _ if changing => "lane_change",
        Some(l) if l.leader.is_some() => "following",
        Some(_) => "cruise",
        None => "none",
    }
}

/// Log-tick system: fill the snapshot from the world, gather the events since the last tick
/// (collisions, lane changes and merges, emergency braking, making way for an emergency
/// vehicle, light changes, vehicles that appear or leave) and record them. O(N) in the vehicles.
#[allow(clippy::type_complexity)]
pub fn record_tick(
    clock: Res<SimClock>,
    vehicles: Res<Vehicles>,
    q: Query<(
        &VehicleState,
        Option<&VehicleSize>,
        Option<&VehicleClass>,
        Option<&LabDriven>,
        Option<&LanePosition>,
        Option<&Longitudinal>,
        Option<&LaneChanger>,
        Option<&crate::vehicles::YieldToEmergency>,
    )>,
    metrics: Option<Res<crate::app::running::metrics::Metrics>>,
    lights: Option<Res<TrafficLights>>,
    (v2v, v2v_channels): (Option<Res<crate::sim::v2v::V2vStats>>, Option<Res<crate::sim::v2v::V2vChannelStats>>),
    recorder: Option<ResMut<FoxgloveRecorder>>,
) {
    let Some(mut rec) = recorder else { return };
    let t_us = clock.now.0;
    if rec.last_t == Some(t_us) {
        return;
    }
    let rec = &mut *rec;
    let mut snapshot = rec.take_snapshot();
    let mut events = Vec::new();
    snapshot.t_us = t_us;
    snapshot.vehicles.clear();
    events.clear();
    let mut merges: Vec<(i32, String, &'static str)> = Vec::new();
    for (id, e) in vehicles.iter() {
        let Ok((s, size, class, lab, lane, lon, changer, yields)) = q.get(e) else { continue };
        let yielding = yields.is_some_and(|y| y.requested || y.slow_to.is_some());
        let size = size.copied().unwrap_or_default();
        let manoeuvre = changer.and_then(|c| c.active.as_ref());
        let signal = changer.map_or(TurnSignal::Off, |c| c.signal());
        if let Some(m) = manoeuvre
            && signal != TurnSignal::Off
        {
            let kind = match m.kind {
                crate::vehicles::lane_state::ChangeKind::Mandatory => "merge",
                _ => "lane_change",
            };
            merges.push((
                id.0,
                format!(
                    "lanelet {} -> {} ({:?}{})",
                    m.from.0,
                    m.to.0,
                    m.kind,
                    if m.aborted { ", aborted" } else { "" }
                ),
                kind,
            ));
        }
        snapshot.vehicles.push(VehicleSnapshot {
            id: id.0,
            position: s.position,
            yaw: s.yaw,
            velocity: s.velocity,
            accel: lon.map_or(f64::NAN, |l| l.accel),
            lanelet: lane.and_then(|l| l.lanelet).map(|l| l.0),
            lane_offset: lane.filter(|l| l.lanelet.is_some()).map(|l| l.offset),
            length: size.length,
            width: size.width,
            class: class.copied().unwrap_or_default(),
            real: lab.is_some(),
            signal,
            mode: mode(lab.is_some(), lon, yielding, manoeuvre.is_some()),
        });
    }
    // Changes against the last tick (both lists in id order).
    let mut j = 0;
    for v in &snapshot.vehicles {
        while j < rec.previous.len() && rec.previous[j].0 < v.id {
            let id = rec.previous[j].0;
            events.push(Event::info(t_us, "vehicle", format!("vehicle {id} left")));
            j += 1;
        }
        let before = rec.previous.get(j).filter(|p| p.0 == v.id).copied();
        if before.is_some() {
            j += 1;
        } else if rec.ticks > 0 {
            events.push(Event::info(t_us, "vehicle", format!("vehicle {} appeared", v.id)));
        }
        let (was_signal, was_mode) = before.map_or((TurnSignal::Off, ""), |b| (b.1, b.2));
        if was_signal == TurnSignal::Off
            && v.signal != TurnSignal::Off
            && let Some((_, text, kind)) = merges.iter().find(|m| m.0 == v.id)
        {
            let side = if v.signal == TurnSignal::Left { "left" } else { "right" };
            events.push(Event::info(t_us, kind, format!("vehicle {} changes lanes {side}: {text}", v.id)));
        }
        if v.mode == "yielding" && was_mode != "yielding" {
            events.push(Event::info(t_us, "emergency", format!("vehicle {} makes way for an emergency vehicle", v.id)));
        }
        if v.mode == "emergency_braking" && was_mode != "emergency_braking" {
            events.push(Event::warning(t_us, "emergency", format!("vehicle {} brakes hard (emergency braking)", v.id)));
        }
    }
    for p in &rec.previous[j..] {
        events.push(Event::info(t_us, "vehicle", format!("vehicle {} left", p.0)));
    }
    if let Some(m) = &metrics {
        for c in m.collisions.iter().skip(rec.collisions_seen) {
            events.push(Event::warning(
                crate::world::SimTime::from_secs(c.t).0.min(t_us),
                "collision",
                format!("collision: vehicles {} and {}", c.a.0, c.b.0),
            ));
        }
        rec.collisions_seen = m.collisions.len();
    }
    if let Some(lights) = &lights
        && rec.lights_seen != Some(lights.changes)
    {
        rec.lights_seen = Some(lights.changes);
        rec.light_states.resize(lights.controllers.len(), String::new());
        for (i, c) in lights.controllers.iter().enumerate() {
            let now = lights.state_of(c.junction).unwrap_or_default();
            if rec.light_states[i] != now {
                events.push(Event::info(t_us, "light", format!("junction {}: {now}", c.junction + 1)));
                rec.light_states[i] = now;
            }
        }
    }
    if let (Some(stats), Some(ch)) = (&v2v, &v2v_channels) {
        rec.record_v2v(
            t_us,
            (stats.wifi_rounds, stats.network_rounds),
            (ch.wifi.sent, ch.wifi.delivered),
            (ch.network.sent, ch.network.delivered),
        );
    }
    rec.record(snapshot, events);
}

/// Record the state at the end of a run (unless the log's own tick already did), as
/// [`super::output::log_final_state`] does for the CSV.
pub fn record_final_state(sim: &mut Sim) {
    use bevy_ecs::system::RunSystemOnce;
    if sim.world().get_resource::<FoxgloveRecorder>().is_some() {
        let _ = sim.world_mut().run_system_once(record_tick);
    }
}

/// Where `[output] mcap` or `--mcap` puts the file: the CLI's path as given, the scenario's
/// relative to the output folder.
pub fn mcap_path(cli: Option<&FsPath>, scenario: Option<&FsPath>, out: &FsPath) -> Option<PathBuf> {
    match (cli, scenario) {
        (Some(p), _) => Some(p.to_path_buf()),
        (None, Some(p)) if p.is_absolute() => Some(p.to_path_buf()),
        (None, Some(p)) => Some(out.join(p)),
        (None, None) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_numbers_are_rounded_to_their_unit() {
        let text = |x: f64, d: usize| JsonNum(x, d).to_string();
        assert_eq!(text(12.5, 3), "12.500");
        assert_eq!(text(-0.25, 3), "-0.250");
        assert_eq!(text(-0.0001, 3), "0.000");
        assert_eq!(text(1.0 / 3.0, 5), "0.33333");
        assert_eq!(text(f64::NAN, 3), "null");
        assert_eq!(text(7.0, 0), "7");
    }

    #[test]
    fn dashes_are_half_paint_half_gap_across_points() {
        let mut out = Vec::new();
        dash(&[DVec2::ZERO, DVec2::new(4.0, 0.0), DVec2::new(12.0, 0.0)], 6.0, &mut out);
        let xs: Vec<f64> = out.iter().map(|p| p.x).collect();
        // Paint 0-3, gap 3-6, paint 6-9, gap 9-12 (the first paint split at no point).
        assert_eq!(xs, vec![0.0, 3.0, 6.0, 9.0]);
    }

    #[test]
    fn departed_vehicles_are_deleted() {
        let v = |id| VehicleSnapshot {
            id,
            position: DVec2::ZERO,
            yaw: 0.0,
            velocity: DVec2::ZERO,
            accel: f64::NAN,
            lanelet: None,
            lane_offset: None,
            length: 4.0,
            width: 2.0,
            class: VehicleClass::Car,
            real: false,
            signal: TurnSignal::Off,
            mode: "none",
        };
        let snapshot = Snapshot { t_us: 100, vehicles: vec![v(1), v(3)] };
        let previous = [(0, TurnSignal::Off, "none"), (1, TurnSignal::Off, "none"), (2, TurnSignal::Off, "none")];
        let scene = vehicles_scene(&snapshot, &previous, stamp(100));
        let gone: Vec<&str> = scene.deletions.iter().map(|d| d.id.as_str()).collect();
        assert_eq!(gone, vec!["vehicle/0", "vehicle/2"]);
        assert_eq!(scene.entities.len(), 2);
    }

    #[test]
    fn the_cli_path_wins_and_the_scenario_path_is_under_the_output_folder() {
        let out = FsPath::new("out/x");
        assert_eq!(mcap_path(None, Some(FsPath::new("a.mcap")), out), Some(PathBuf::from("out/x/a.mcap")));
        assert_eq!(mcap_path(Some(FsPath::new("b.mcap")), Some(FsPath::new("a.mcap")), out), Some("b.mcap".into()));
        assert_eq!(partial_path(FsPath::new("d/r.mcap")), PathBuf::from("d/.r.mcap.partial"));
    }
}
