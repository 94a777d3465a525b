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
//! Each message is encoded once ([`super::foxglove_encode`] for the per-tick ones) and handed
//! to the file ([`McapFile`], the `mcap` crate directly) and to the live server's channel (the
//! Foxglove SDK). Nothing is encoded for a channel no sink listens to: without a file, a live
//! server without a client costs a check per channel and tick; without `--mcap` and
//! `--foxglove` there is no recorder at all.

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::{Path as FsPath, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use bevy_ecs::prelude::Resource;
use foxglove::messages::{CompressedImage, LocationFix, Log, SceneUpdate, Timestamp};
use foxglove::{Context, Encode, PartialMetadata, RawChannel, Schema};
use glam::DVec2;

use super::foxglove_encode as encode;
pub use super::foxglove_encode::map_scene;
pub use super::foxglove_tick::{
    BirdseyeImages, FoxgloveRecordPlugin, Record, mcap_path, record_final_state, record_tick,
};
use super::mcap_file::McapFile;
pub use super::mcap_file::partial_path;
use crate::map::{LaneletMap, Projector};
use crate::world::TurnSignal;

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
    /// `/camera/birdseye` goes into the file.
    images_to_file: bool,
    /// The live server's `/camera/birdseye`.
    camera_live: Option<Arc<RawChannel>>,
    live_port: Option<u16>,
    /// Ids of the last tick's vehicles and whether each was changing lanes / braking hard.
    pub(super) previous: Vec<(i32, TurnSignal, &'static str)>,
    /// Sim time of the last tick recorded [µs].
    pub(crate) last_t: Option<u64>,
    pub(super) ticks: u64,
    pub(super) collisions_seen: usize,
    pub(super) lights_seen: Option<u64>,
    pub(super) light_states: Vec<String>,
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
        let images_to_file = core.channels.as_ref().is_some_and(|c| c.camera.file.is_some());
        let camera_live = core.channels.as_ref().and_then(|c| c.camera.live.clone());
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
            images_to_file,
            camera_live,
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
        self.images_to_file || self.camera_live.as_ref().is_some_and(|c| c.has_sinks())
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
    /// The `/map` scene (encoded), logged at the first tick (and again to the live server when
    /// a client subscribes).
    map_scene: Option<Vec<u8>>,
    /// Set by the live server when a client subscribes to `/map`.
    map_wanted: Arc<AtomicBool>,
    projector: Option<Projector>,
    /// Ids of the last tick's vehicles (the deletions of `/vehicles`).
    previous: Vec<(i32, TurnSignal, &'static str)>,
    pub(crate) last_t: Option<u64>,
    v2v_last: [(u64, u64); 2],
    /// The message being encoded (reused).
    buf: Vec<u8>,
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

/// One channel of the Foxglove profile: its id in the file (when recording) and the live
/// server's channel (when serving). A message is encoded once for both.
struct Topic {
    file: Option<u16>,
    live: Option<Arc<RawChannel>>,
}

impl Topic {
    /// The channel `topic` in `file` and on the live server's `context`, with `schema`.
    fn new(
        file: Option<&mut McapFile>,
        live: Option<&Arc<Context>>,
        topic: &str,
        encoding: &str,
        schema: &Schema,
    ) -> Topic {
        let file = file.map(|f| f.channel(topic, encoding, Some((&schema.name, &schema.encoding, &schema.data))));
        let live = live.and_then(|context| {
            context
                .channel_builder(topic)
                .message_encoding(encoding)
                .schema(schema.clone())
                .build_raw()
                .map_err(|e| tracing::warn!("--foxglove: channel {topic}: {e}"))
                .ok()
        });
        Topic { file, live }
    }

    /// A protobuf channel of the Foxglove schema `M`.
    fn protobuf<M: Encode>(file: Option<&mut McapFile>, live: Option<&Arc<Context>>, topic: &str) -> Topic {
        match M::get_schema() {
            Some(schema) => Topic::new(file, live, topic, &M::get_message_encoding(), &schema),
            None => Topic { file: None, live: None },
        }
    }

    /// A JSON channel with a JSON schema.
    fn json(
        file: Option<&mut McapFile>,
        live: Option<&Arc<Context>>,
        topic: &str,
        name: &str,
        schema: &'static str,
    ) -> Topic {
        Topic::new(file, live, topic, "json", &Schema::new(name, "jsonschema", schema.as_bytes()))
    }

    /// Whether a message would go anywhere: the file, or a subscribed live client.
    fn wanted(&self) -> bool {
        self.file.is_some() || self.live.as_ref().is_some_and(|c| c.has_sinks())
    }

    /// `data` at `t_ns` into the file and to the live clients.
    fn log(&self, file: &mut Option<McapFile>, t_ns: u64, data: &[u8]) {
        if let (Some(id), Some(file)) = (self.file, file.as_mut()) {
            file.write(id, t_ns, data);
        }
        if let Some(live) = &self.live
            && live.has_sinks()
        {
            live.log_with_meta(data, PartialMetadata::with_log_time(t_ns));
        }
    }
}

/// The Foxglove-profile channels.
struct FoxgloveChannels {
    map: Topic,
    vehicles: Topic,
    tf: Topic,
    events: Topic,
    v2v: Topic,
    metrics: Topic,
    camera: Topic,
    /// `/vehicle/<id>/state`, made at a vehicle's first tick.
    states: BTreeMap<i32, Topic>,
    /// `/gps/<id>`, made at a vehicle's first tick on a map with a geographic origin.
    gps: BTreeMap<i32, Topic>,
}

impl FoxgloveChannels {
    fn new(mut file: Option<&mut McapFile>, live: Option<&Arc<Context>>) -> FoxgloveChannels {
        FoxgloveChannels {
            map: Topic::protobuf::<SceneUpdate>(file.as_deref_mut(), live, "/map"),
            vehicles: Topic::protobuf::<SceneUpdate>(file.as_deref_mut(), live, "/vehicles"),
            tf: Topic::protobuf::<foxglove::messages::FrameTransforms>(file.as_deref_mut(), live, "/tf"),
            events: Topic::protobuf::<Log>(file.as_deref_mut(), live, "/events"),
            v2v: Topic::json(file.as_deref_mut(), live, "/v2v", "smlworld.V2vRound", V2V_SCHEMA),
            metrics: Topic::json(file.as_deref_mut(), live, "/metrics", "smlworld.Summary", METRICS_SCHEMA),
            camera: Topic::protobuf::<CompressedImage>(file, live, "/camera/birdseye"),
            states: BTreeMap::new(),
            gps: BTreeMap::new(),
        }
    }
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

/// `message` encoded with the SDK into `buf` (cleared).
fn sdk_encode(buf: &mut Vec<u8>, message: &impl Encode) {
    buf.clear();
    if let Err(e) = message.encode(buf) {
        tracing::warn!("--mcap: a message could not be encoded ({e})");
        buf.clear();
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
        let mut mcap = match mcap {
            Some(path) => Some(
                McapFile::create(path, if ros2 { "ros2" } else { "" })
                    .map_err(|message| FoxgloveError::Mcap { path: path.to_path_buf(), message })?,
            ),
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
        let live = server.as_ref().map(|_| &context);
        let (channels, ros2) = match (ros2, mcap.as_mut()) {
            (true, Some(file)) => (None, Some(super::ros2::Ros2Channels::new(file))),
            (true, None) => (None, None),
            (false, file) => (Some(FoxgloveChannels::new(file, live)), None),
        };
        let mut buf = Vec::new();
        let map_scene = map.as_deref().map(|m| {
            sdk_encode(&mut buf, &map_scene(m));
            std::mem::take(&mut buf)
        });
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
            buf,
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
        if let (Some(ros2), Some(file)) = (self.ros2.as_mut(), self.mcap.as_mut()) {
            if first && let Some(map) = self.map.as_deref() {
                ros2.record_map(file, map);
            }
            ros2.record(file, snapshot);
            return;
        }
        let Some(ch) = self.channels.as_mut() else { return };
        let file = &mut self.mcap;
        let buf = &mut self.buf;
        let resend = self.map_wanted.swap(false, Ordering::Relaxed);
        if let Some(scene) = &self.map_scene {
            if first {
                // The map is there from t = 0 (a replay's first row may come later).
                ch.map.log(file, 0, scene);
            } else if resend && let Some(live) = &ch.map.live {
                live.log_with_meta(scene, PartialMetadata::with_log_time(t_ns));
            }
        }
        if ch.vehicles.wanted() {
            encode::vehicles_scene(buf, snapshot, &self.previous);
            ch.vehicles.log(file, t_ns, buf);
        }
        if ch.tf.wanted() {
            encode::frame_transforms(buf, snapshot, first);
            ch.tf.log(file, t_ns, buf);
        }
        let live = self.server.as_ref().map(|_| &self.context);
        for v in &snapshot.vehicles {
            let state = ch.states.entry(v.id).or_insert_with(|| {
                let topic = format!("/vehicle/{}/state", v.id);
                Topic::json(file.as_mut(), live, &topic, STATE_SCHEMA_NAME, STATE_SCHEMA)
            });
            if state.wanted() {
                encode::state_json(buf, snapshot.t_us, v);
                state.log(file, t_ns, buf);
            }
            if let Some(projector) = &self.projector {
                let gps = ch
                    .gps
                    .entry(v.id)
                    .or_insert_with(|| Topic::protobuf::<LocationFix>(file.as_mut(), live, &format!("/gps/{}", v.id)));
                if gps.wanted() {
                    let anchor = match self.gps_anchors.get(&v.id) {
                        Some(a) if a.at.distance(v.position) <= GPS_ANCHOR_RANGE => *a,
                        _ => {
                            let a = GpsAnchor::new(projector, v.position);
                            self.gps_anchors.insert(v.id, a);
                            a
                        }
                    };
                    let (lat, lon) = anchor.lat_lon(v.position);
                    encode::location_fix(buf, snapshot.t_us, v.id, lat, lon, v.yaw);
                    gps.log(file, t_ns, buf);
                }
            }
        }
        if ch.events.wanted() {
            for e in events {
                let log = Log {
                    timestamp: Some(stamp(e.t_us)),
                    level: e.level,
                    message: e.message.clone(),
                    name: e.name.into(),
                    file: String::new(),
                    line: 0,
                };
                sdk_encode(buf, &log);
                ch.events.log(file, e.t_us * 1000, buf);
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
        if !ch.v2v.wanted() {
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
        ch.v2v.log(&mut self.mcap, t_us * 1000, json.as_bytes());
    }

    /// Log a `/camera/birdseye` image (PNG bytes) at `t_us`.
    fn record_image(&mut self, png: Vec<u8>, t_us: u64) {
        if let Some(ch) = self.channels.as_ref()
            && ch.camera.wanted()
        {
            let image = CompressedImage {
                timestamp: Some(stamp(t_us)),
                frame_id: "world".into(),
                data: png.into(),
                format: "png".into(),
            };
            sdk_encode(&mut self.buf, &image);
            ch.camera.log(&mut self.mcap, t_us * 1000, &self.buf);
        }
    }

    /// Log `summary` on `/metrics` at `t_us`, close the MCAP file and rename it into place, stop
    /// the live server.
    fn finish(mut self, summary: Option<&serde_json::Value>, t_us: u64) -> Result<Option<PathBuf>, FoxgloveError> {
        if let (Some(summary), Some(ch)) = (summary, self.channels.as_ref())
            && ch.metrics.wanted()
        {
            let text = summary.to_string();
            ch.metrics.log(&mut self.mcap, t_us * 1000, text.as_bytes());
        }
        if let Some(server) = self.server.take() {
            server.stop().wait_blocking();
        }
        let Some(file) = self.mcap.take() else { return Ok(None) };
        let path = file.path().to_path_buf();
        file.finish().map(Some).map_err(|message| FoxgloveError::Mcap { path, message })
    }
}
