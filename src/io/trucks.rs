//! Real-truck output: one TCP server per real vehicle (port base + id, default base 16000) that
//! sends the truck its 2015 status line at 20 Hz:
//!
//! `time=<t>XcRtid=<id>,lane=<left|center|right>,current_distance=<d>,desired_distance=<dd>,velocity=<v>,x=<x>,y=<y>,yaw=<yaw>,lane_offset=<o>\r\n`
//!
//! Distances, speed, position and lane offset are divided by the lab scale (default 32) before
//! sending, as the trucks expect; `yaw` is sent in degrees and `time` in seconds, as the 2015
//! sender did (`scripts/sml_world_old/vehiclecontrolmodule.py`, `get_tcp_string`: the body's
//! `yaw` in degrees as motion capture gives it, `time` its motion-capture timestamp / 1e6; see
//! [`crate::io::lab`] for which time a virtual vehicle sends). A truck that
//! disconnects can reconnect at any time; a new connection on a port replaces the old one; other
//! trucks are not affected. Nothing is sent before the first [`TruckServer::publish`] for an id.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::Write as _;
use std::net::{IpAddr, Ipv4Addr, SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::lock;

/// Default first port: vehicle id 0 listens on 16000, id 1 on 16001, ...
pub const DEFAULT_TRUCK_BASE_PORT: u16 = 16000;
/// Default rate of the status lines \[Hz\].
pub const DEFAULT_TRUCK_RATE_HZ: f64 = 20.0;
/// Default lab scale: world lengths are divided by this before sending.
pub const DEFAULT_LAB_SCALE: f64 = 32.0;

/// Lane the truck is in (or should be in).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Lane {
    /// Left lane.
    Left,
    /// Centre lane.
    #[default]
    Center,
    /// Right lane.
    Right,
}

impl std::fmt::Display for Lane {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Left => "left",
            Self::Center => "center",
            Self::Right => "right",
        })
    }
}

/// What a truck is told, in world units (the server scales to the lab).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TruckState {
    /// Time stamp \[s\] (sent unscaled): the motion-capture frame time of a real truck.
    pub time: f64,
    /// Lane.
    pub lane: Lane,
    /// Gap to the leader \[m\] (world; sent / scale).
    pub current_distance: f64,
    /// Wanted gap to the leader \[m\] (world; sent / scale).
    pub desired_distance: f64,
    /// Speed [m/s] (world; sent / scale).
    pub velocity: f64,
    /// Position \[m\] (world; sent / scale).
    pub x: f64,
    /// Position \[m\] (world; sent / scale).
    pub y: f64,
    /// Heading \[rad\] (sent in degrees, as the 2015 sender did).
    pub yaw: f64,
    /// Lateral offset from the lane centre \[m\] (world; sent / scale).
    pub lane_offset: f64,
}

/// Format the 2015 status line for vehicle `id`, lengths and speed divided by `scale`.
pub fn format_truck_line(out: &mut String, id: i32, s: &TruckState, scale: f64) {
    let _ = write!(
        out,
        "time={:.6}XcRtid={id},lane={},current_distance={:.4},desired_distance={:.4},velocity={:.4},x={:.4},y={:.4},yaw={:.4},lane_offset={:.4}\r\n",
        s.time,
        s.lane,
        s.current_distance / scale,
        s.desired_distance / scale,
        s.velocity / scale,
        s.x / scale,
        s.y / scale,
        s.yaw.to_degrees(),
        s.lane_offset / scale,
    );
}

/// Errors of the truck servers.
#[derive(Debug, thiserror::Error)]
pub enum TruckError {
    /// An id that cannot have a port (negative: virtual, or base + id > 65535).
    #[error(
        "vehicle {id}: no truck port (base {base} + id must be in 1..=65535 and id >= 0; real vehicles have ids >= 0)"
    )]
    BadId {
        /// The id.
        id: i32,
        /// The base port.
        base: u16,
    },
    /// The same id given twice.
    #[error("vehicle {0}: truck server requested twice")]
    DuplicateId(i32),
    /// `publish` for an id without a server.
    #[error("vehicle {0} has no truck server (started ids only)")]
    UnknownId(i32),
    /// A rate or scale that is not positive.
    #[error("truck server configuration: {0}")]
    Config(String),
    /// Socket error.
    #[error("truck server for vehicle {id} ({what}): {source}")]
    Io {
        /// The vehicle id.
        id: i32,
        /// What was being done.
        what: String,
        /// Underlying error.
        source: std::io::Error,
    },
}

/// Settings of a [`TruckServer`].
#[derive(Debug, Clone, PartialEq)]
pub struct TruckServerConfig {
    /// Address to listen on (default 127.0.0.1).
    pub ip: IpAddr,
    /// Vehicle id k listens on `base_port + k` (default 16000). 0 means "any free port" for
    /// every truck (tests); ask [`TruckServer::local_addr`] for the ports actually bound.
    pub base_port: u16,
    /// Lines per second \[Hz\] (default 20).
    pub rate_hz: f64,
    /// Lab scale (default 32): lengths and speeds are divided by it.
    pub scale: f64,
}

impl Default for TruckServerConfig {
    fn default() -> Self {
        Self {
            ip: IpAddr::V4(Ipv4Addr::LOCALHOST),
            base_port: DEFAULT_TRUCK_BASE_PORT,
            rate_hz: DEFAULT_TRUCK_RATE_HZ,
            scale: DEFAULT_LAB_SCALE,
        }
    }
}

#[derive(Debug)]
struct Truck {
    addr: SocketAddr,
    state: Arc<Mutex<Option<TruckState>>>,
    connected: Arc<AtomicBool>,
    connections: Arc<AtomicU64>,
    thread: Option<JoinHandle<()>>,
}

/// One TCP server per real vehicle; a background thread per truck. Dropping it stops them.
#[derive(Debug)]
pub struct TruckServer {
    trucks: BTreeMap<i32, Truck>,
    stop: Arc<AtomicBool>,
}

/// How often a truck thread checks for connections and stop requests.
const TRUCK_TICK: Duration = Duration::from_millis(5);

impl TruckServer {
    /// Start one listener per id.
    pub fn start(config: &TruckServerConfig, ids: &[i32]) -> Result<Self, TruckError> {
        let period = match Duration::try_from_secs_f64(1.0 / config.rate_hz) {
            Ok(p) if config.rate_hz > 0.0 && config.rate_hz <= 1e6 => p,
            _ => return Err(TruckError::Config(format!("rate {} Hz must be in (0, 1e6]", config.rate_hz))),
        };
        if !(config.scale.is_finite() && config.scale > 0.0) {
            return Err(TruckError::Config(format!("scale {} must be positive", config.scale)));
        }
        let stop = Arc::new(AtomicBool::new(false));
        let mut server = Self { trucks: BTreeMap::new(), stop: stop.clone() };
        for &id in ids {
            if server.trucks.contains_key(&id) {
                return Err(TruckError::DuplicateId(id));
            }
            let port = match (config.base_port, u16::try_from(id)) {
                (0, Ok(_)) => 0,
                (base, Ok(k)) => base.checked_add(k).ok_or(TruckError::BadId { id, base })?,
                (base, Err(_)) => return Err(TruckError::BadId { id, base }),
            };
            let io = |what: String| move |source| TruckError::Io { id, what, source };
            let listener = TcpListener::bind((config.ip, port)).map_err(io(format!("bind {}:{port}", config.ip)))?;
            listener.set_nonblocking(true).map_err(io("set non-blocking".into()))?;
            let addr = listener.local_addr().map_err(io("local address".into()))?;
            let truck = Truck {
                addr,
                state: Arc::new(Mutex::new(None)),
                connected: Arc::new(AtomicBool::new(false)),
                connections: Arc::new(AtomicU64::new(0)),
                thread: None,
            };
            let ctx = TruckThread {
                id,
                scale: config.scale,
                period,
                state: truck.state.clone(),
                connected: truck.connected.clone(),
                connections: truck.connections.clone(),
                stop: stop.clone(),
            };
            let thread = std::thread::Builder::new()
                .name(format!("truck-{id}"))
                .spawn(move || ctx.run(&listener))
                .map_err(io("spawn thread".into()))?;
            server.trucks.insert(id, Truck { thread: Some(thread), ..truck });
        }
        Ok(server)
    }

    /// Set what vehicle `id` is told from now on (sent at the next tick, and every tick after).
    pub fn publish(&self, id: i32, state: TruckState) -> Result<(), TruckError> {
        let truck = self.trucks.get(&id).ok_or(TruckError::UnknownId(id))?;
        *lock(&truck.state) = Some(state);
        Ok(())
    }

    /// The address vehicle `id` listens on.
    pub fn local_addr(&self, id: i32) -> Option<SocketAddr> {
        self.trucks.get(&id).map(|t| t.addr)
    }

    /// Whether a truck is connected to vehicle `id`'s server now.
    pub fn is_connected(&self, id: i32) -> bool {
        self.trucks.get(&id).is_some_and(|t| t.connected.load(Ordering::Relaxed))
    }

    /// Connections accepted so far on vehicle `id`'s server.
    pub fn connections(&self, id: i32) -> u64 {
        self.trucks.get(&id).map_or(0, |t| t.connections.load(Ordering::Relaxed))
    }

    /// The ids served, ascending.
    pub fn ids(&self) -> impl Iterator<Item = i32> + '_ {
        self.trucks.keys().copied()
    }
}

impl Drop for TruckServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.trucks.values_mut() {
            if let Some(h) = t.thread.take() {
                let _ = h.join();
            }
        }
    }
}

struct TruckThread {
    id: i32,
    scale: f64,
    period: Duration,
    state: Arc<Mutex<Option<TruckState>>>,
    connected: Arc<AtomicBool>,
    connections: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
}

impl TruckThread {
    fn run(self, listener: &TcpListener) {
        let mut client: Option<TcpStream> = None;
        let mut line = String::with_capacity(256);
        let mut next_send = Instant::now();
        while !self.stop.load(Ordering::Relaxed) {
            match listener.accept() {
                Ok((stream, peer)) => {
                    let ready = stream.set_nonblocking(false).and_then(|()| stream.set_nodelay(true));
                    match ready.and_then(|()| stream.set_write_timeout(Some(self.period))) {
                        Ok(()) => {
                            if client.is_some() {
                                tracing::info!("truck {}: {peer} replaces the previous connection", self.id);
                            } else {
                                tracing::info!("truck {}: {peer} connected", self.id);
                            }
                            client = Some(stream);
                            self.connections.fetch_add(1, Ordering::Relaxed);
                            self.connected.store(true, Ordering::Relaxed);
                            next_send = Instant::now();
                        }
                        Err(e) => tracing::warn!("truck {}: cannot set up {peer}: {e}", self.id),
                    }
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
                Err(e) => tracing::warn!("truck {}: accept: {e}", self.id),
            }
            let now = Instant::now();
            if now >= next_send {
                next_send += self.period;
                if next_send < now {
                    next_send = now + self.period;
                }
                if let Some(stream) = client.as_mut() {
                    line.clear();
                    if let Some(s) = lock(&self.state).as_ref() {
                        format_truck_line(&mut line, self.id, s, self.scale);
                    }
                    if !line.is_empty()
                        && let Err(e) = stream.write_all(line.as_bytes())
                    {
                        tracing::info!("truck {}: disconnected ({e}); waiting for it to reconnect", self.id);
                        client = None;
                        self.connected.store(false, Ordering::Relaxed);
                    }
                }
            }
            std::thread::sleep(TRUCK_TICK);
        }
    }
}
