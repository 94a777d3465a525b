//! A mock Qualisys Track Manager server for tests and demos: answers the handshake commands of
//! the real-time protocol 1.11 and serves `GetCurrentFrame 6DEuler` from scripted trajectories.
//!
//! Scripts are either built in ([`MocapScript::Circles`]: bodies driving around circles on the
//! lab floor) or keyframes read from CSV ([`MocapScript::from_csv`]):
//!
//! ```text
//! # t_s, body, x_mm, y_mm, z_mm, roll_deg, pitch_deg, yaw_deg
//! 0.0, 1, 0, 0, 0, 0, 0, 0
//! 2.0, 1, 1000, 0, 0, 0, 0, 0
//! 1.0, 2, nan, nan, nan, nan, nan, nan
//! ```
//! Bodies are numbered from 1 as QTM numbers them (body 1 is the first 6DOF body in the data
//! packets); a number without keyframes is sent hidden (NaN).
//! Lines starting with `#` and blank lines are ignored; the first other line may name the
//! columns. Between two keyframes of a body the pose is interpolated linearly (yaw along the
//! shorter way); a keyframe with NaN values hides the body until its next keyframe; before its
//! first keyframe a body is hidden, after its last it stays put. The script loops with a period
//! equal to its last keyframe time (over all bodies).

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, TcpListener, TcpStream};
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::qualisys::{
    DEFAULT_QTM_PORT, MAX_PACKET_LEN, PacketDecoder, PacketType, encode_6d_euler_packet, encode_text,
};

/// Default capture rate of the mock \[Hz\]: frame numbers advance at this rate.
pub const DEFAULT_MOCK_RATE_HZ: f64 = 100.0;
/// Greeting the server sends on connect (as QTM does).
pub const GREETING: &str = "QTM RT Interface connected";

/// Errors of the mock server and its scripts.
#[derive(Debug, thiserror::Error)]
pub enum MockMocapError {
    /// The script file cannot be read.
    #[error("{path}: cannot read the motion-capture script: {source}")]
    Read {
        /// The file.
        path: String,
        /// Underlying error.
        source: std::io::Error,
    },
    /// A script line is malformed.
    #[error("{path}:{line}: {problem}; expected `t_s,body,x_mm,y_mm,z_mm,roll_deg,pitch_deg,yaw_deg`")]
    Script {
        /// The file (or `<memory>`).
        path: String,
        /// 1-based line.
        line: usize,
        /// What is wrong.
        problem: String,
    },
    /// A setting is out of range.
    #[error("mock motion capture: {0}")]
    Config(String),
    /// Socket error.
    #[error("mock motion capture server ({what}): {source}")]
    Io {
        /// What was being done.
        what: String,
        /// Underlying error.
        source: std::io::Error,
    },
}

/// One keyframe of a body: time \[s\] and pose `[x, y, z mm, roll, pitch, yaw degrees]`
/// (NaN values: hidden).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keyframe {
    /// Time from the start of the script \[s\].
    pub t_s: f64,
    /// Pose `[x_mm, y_mm, z_mm, roll_deg, pitch_deg, yaw_deg]`.
    pub pose: [f64; 6],
}

/// Scripted trajectories of the mock bodies.
#[derive(Debug, Clone, PartialEq)]
pub enum MocapScript {
    /// Body k drives counter-clockwise around the lab origin on a circle of radius
    /// `radius_mm + k * spacing_mm`, at `speed_mm_s`, starting at angle `k * 2π / bodies`, for
    /// body number k + 1.
    Circles {
        /// Number of bodies.
        bodies: u32,
        /// Radius of body 1's circle \[mm\].
        radius_mm: f64,
        /// Extra radius per body index \[mm\].
        spacing_mm: f64,
        /// Speed along the circle [mm/s].
        speed_mm_s: f64,
    },
    /// Keyframes per body number (1-based), sorted by time.
    Keyframes(BTreeMap<u32, Vec<Keyframe>>),
}

impl MocapScript {
    /// `bodies` bodies on circles of 1 m, 1.3 m, ... at 0.3 m/s (about 35 km/h at scale 1:32).
    pub fn circles(bodies: u32) -> Self {
        Self::Circles { bodies, radius_mm: 1000.0, spacing_mm: 300.0, speed_mm_s: 300.0 }
    }

    /// Read a keyframe script from a CSV file.
    pub fn load(path: &Path) -> Result<Self, MockMocapError> {
        let read = |source| MockMocapError::Read { path: path.display().to_string(), source };
        let size = std::fs::metadata(path).map_err(read)?.len();
        if size > MAX_SCRIPT_BYTES {
            return Err(MockMocapError::Script {
                path: path.display().to_string(),
                line: 0,
                problem: format!("{size} bytes: a script may have at most {MAX_SCRIPT_BYTES} bytes"),
            });
        }
        let text = std::fs::read_to_string(path).map_err(read)?;
        Self::from_csv(&text, &path.display().to_string())
    }

    /// Parse a keyframe script (format in the module docs); `name` names the source in errors.
    pub fn from_csv(text: &str, name: &str) -> Result<Self, MockMocapError> {
        let mut bodies: BTreeMap<u32, Vec<Keyframe>> = BTreeMap::new();
        let mut first = true;
        for (i, raw) in text.lines().enumerate() {
            let line = raw.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let err = |problem: String| MockMocapError::Script { path: name.to_string(), line: i + 1, problem };
            let cols: Vec<&str> = line.split(',').map(str::trim).collect();
            if std::mem::take(&mut first) && cols.first().is_some_and(|c| c.parse::<f64>().is_err()) {
                continue;
            }
            if cols.len() != 8 {
                return Err(err(format!("{} columns", cols.len())));
            }
            let t_s: f64 = cols[0].parse().map_err(|_| err(format!("time {:?} is not a number", cols[0])))?;
            if !(t_s.is_finite() && t_s >= 0.0) {
                return Err(err(format!("time {t_s} must be finite and >= 0")));
            }
            let body: u32 = cols[1].parse().ok().filter(|b| (1..=MAX_MOCK_BODIES).contains(b)).ok_or_else(|| {
                err(format!(
                    "body {:?} is not a body number in 1..={MAX_MOCK_BODIES} (QTM numbers its bodies from 1)",
                    cols[1]
                ))
            })?;
            let mut pose = [0.0; 6];
            for (k, v) in pose.iter_mut().enumerate() {
                *v = cols[2 + k].parse().map_err(|_| err(format!("value {:?} is not a number", cols[2 + k])))?;
            }
            bodies.entry(body).or_default().push(Keyframe { t_s, pose });
        }
        if bodies.is_empty() {
            return Err(MockMocapError::Script { path: name.to_string(), line: 0, problem: "no keyframes".into() });
        }
        for frames in bodies.values_mut() {
            frames.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
        }
        Ok(Self::Keyframes(bodies))
    }

    /// Number of bodies the server reports (the highest body number for keyframes).
    pub fn body_count(&self) -> u32 {
        match self {
            Self::Circles { bodies, .. } => *bodies,
            Self::Keyframes(b) => b.keys().next_back().copied().unwrap_or(0),
        }
    }

    /// Pose of body number `number` (1-based) at `t_s` \[s\], `None` when hidden.
    pub fn pose(&self, number: u32, t_s: f64) -> Option<[f64; 6]> {
        match self {
            Self::Circles { bodies, radius_mm, spacing_mm, speed_mm_s } => {
                if number == 0 || number > *bodies {
                    return None;
                }
                let body = number - 1;
                let r = radius_mm + f64::from(body) * spacing_mm;
                let phase = f64::from(body) * std::f64::consts::TAU / f64::from(*bodies);
                let a = phase + speed_mm_s / r * t_s;
                let yaw = (a + std::f64::consts::FRAC_PI_2).sin().atan2((a + std::f64::consts::FRAC_PI_2).cos());
                Some([r * a.cos(), r * a.sin(), 0.0, 0.0, 0.0, yaw.to_degrees()])
            }
            Self::Keyframes(all) => {
                let frames = all.get(&number)?;
                let period = all.values().filter_map(|f| f.last()).map(|k| k.t_s).fold(0.0, f64::max);
                let t = if period > 0.0 { t_s.rem_euclid(period) } else { t_s };
                let next = frames.partition_point(|k| k.t_s <= t);
                let k0 = frames.get(next.checked_sub(1)?)?;
                if k0.pose.iter().any(|v| !v.is_finite()) {
                    return None;
                }
                let Some(k1) = frames.get(next).filter(|k| k.pose.iter().all(|v| v.is_finite())) else {
                    return Some(k0.pose);
                };
                let u = (t - k0.t_s) / (k1.t_s - k0.t_s);
                let mut p: [f64; 6] = std::array::from_fn(|i| k0.pose[i] + u * (k1.pose[i] - k0.pose[i]));
                let dyaw = (k1.pose[5] - k0.pose[5] + 180.0).rem_euclid(360.0) - 180.0;
                p[5] = k0.pose[5] + u * dyaw;
                Some(p)
            }
        }
    }
}

/// Most bodies the mock serves: a frame of them (24 bytes each) must fit in one packet
/// ([`MAX_PACKET_LEN`], 1 MiB) that the client accepts.
pub const MAX_MOCK_BODIES: u32 = 40_000;
// A frame of MAX_MOCK_BODIES bodies (24 bytes each, plus headers) fits in one packet.
const _: () = assert!(MAX_MOCK_BODIES as usize * 24 + 64 <= MAX_PACKET_LEN);
/// Highest capture rate the mock accepts \[Hz\] (QTM's cameras reach a few kHz).
pub const MAX_MOCK_RATE_HZ: f64 = 10_000.0;
/// Largest keyframe script read \[bytes\].
pub const MAX_SCRIPT_BYTES: u64 = 64 << 20;
/// Largest command packet a client may send \[bytes\] (QTM commands are a few words).
pub const MAX_COMMAND_LEN: usize = 64 << 10;
/// Most clients served at once; more are refused (logged) until one leaves.
pub const MAX_CLIENTS: usize = 64;

/// Settings of a [`MockMocapServer`].
#[derive(Debug, Clone, PartialEq)]
pub struct MockMocapConfig {
    /// Address to listen on (default 127.0.0.1:22224; port 0 picks a free one).
    pub bind: SocketAddr,
    /// Capture rate \[Hz\]: frame numbers advance at this rate (default 100).
    pub rate_hz: f64,
    /// What the bodies do.
    pub script: MocapScript,
}

impl Default for MockMocapConfig {
    fn default() -> Self {
        Self {
            bind: SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, DEFAULT_QTM_PORT)),
            rate_hz: DEFAULT_MOCK_RATE_HZ,
            script: MocapScript::circles(2),
        }
    }
}

/// A running mock server; each client gets its own thread. Dropping it stops everything.
#[derive(Debug)]
pub struct MockMocapServer {
    local_addr: SocketAddr,
    stop: Arc<AtomicBool>,
    connections: Arc<AtomicU64>,
    thread: Option<JoinHandle<()>>,
}

/// How often server threads check whether they should stop.
const SERVER_TICK: Duration = Duration::from_millis(10);

impl MockMocapServer {
    /// Bind and start serving.
    pub fn start(config: MockMocapConfig) -> Result<Self, MockMocapError> {
        if !(config.rate_hz.is_finite() && config.rate_hz > 0.0 && config.rate_hz <= MAX_MOCK_RATE_HZ) {
            return Err(MockMocapError::Config(format!(
                "rate {} Hz must be positive and at most {MAX_MOCK_RATE_HZ} Hz",
                config.rate_hz
            )));
        }
        if config.script.body_count() > MAX_MOCK_BODIES {
            return Err(MockMocapError::Config(format!(
                "{} bodies: at most {MAX_MOCK_BODIES} fit in one frame packet",
                config.script.body_count()
            )));
        }
        let io = |what: String| move |source| MockMocapError::Io { what, source };
        let listener = TcpListener::bind(config.bind).map_err(io(format!("bind {}", config.bind)))?;
        listener.set_nonblocking(true).map_err(io("set non-blocking".into()))?;
        let local_addr = listener.local_addr().map_err(io("local address".into()))?;
        let stop = Arc::new(AtomicBool::new(false));
        let connections = Arc::new(AtomicU64::new(0));
        let thread = {
            let (stop, connections) = (stop.clone(), connections.clone());
            let world = Arc::new(MockWorld { script: config.script, rate_hz: config.rate_hz, start: Instant::now() });
            std::thread::Builder::new()
                .name("mock-mocap".into())
                .spawn(move || accept_loop(&listener, &world, &stop, &connections))
                .map_err(io("spawn server thread".into()))?
        };
        Ok(Self { local_addr, stop, connections, thread: Some(thread) })
    }

    /// The address actually bound.
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// Clients accepted so far.
    pub fn connections(&self) -> u64 {
        self.connections.load(Ordering::Relaxed)
    }
}

impl Drop for MockMocapServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[derive(Debug)]
struct MockWorld {
    script: MocapScript,
    rate_hz: f64,
    start: Instant,
}

impl MockWorld {
    /// The current frame as a data packet; positions at the frame's own time.
    fn frame_packet(&self) -> Vec<u8> {
        let frame = (self.start.elapsed().as_secs_f64() * self.rate_hz).floor();
        let t = frame / self.rate_hz;
        let bodies: Vec<[f32; 6]> = (1..=self.script.body_count())
            .map(|b| self.script.pose(b, t).map_or([f32::NAN; 6], |p| p.map(|v| v as f32)))
            .collect();
        encode_6d_euler_packet((t * 1e6) as i64, frame as i32, &bodies)
    }
}

fn accept_loop(listener: &TcpListener, world: &Arc<MockWorld>, stop: &Arc<AtomicBool>, connections: &AtomicU64) {
    let mut clients: Vec<JoinHandle<()>> = Vec::new();
    while !stop.load(Ordering::Relaxed) {
        match listener.accept() {
            Ok((stream, peer)) => {
                clients.retain(|h| !h.is_finished());
                if clients.len() >= MAX_CLIENTS {
                    tracing::warn!("mock motion capture: {MAX_CLIENTS} clients already; refusing {peer}");
                    drop(stream);
                    continue;
                }
                connections.fetch_add(1, Ordering::Relaxed);
                tracing::info!("mock motion capture: client {peer} connected");
                let (world, stop) = (world.clone(), stop.clone());
                let spawned = std::thread::Builder::new().name("mock-mocap-client".into()).spawn(move || {
                    if let Err(e) = serve_client(stream, &world, &stop) {
                        tracing::info!("mock motion capture: client {peer}: {e}");
                    }
                });
                match spawned {
                    Ok(h) => clients.push(h),
                    Err(e) => tracing::warn!("mock motion capture: cannot spawn a client thread: {e}"),
                }
                clients.retain(|h| !h.is_finished());
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => std::thread::sleep(SERVER_TICK),
            Err(e) => {
                tracing::warn!("mock motion capture: accept: {e}");
                std::thread::sleep(SERVER_TICK);
            }
        }
    }
    for h in clients {
        let _ = h.join();
    }
}

fn serve_client(mut stream: TcpStream, world: &MockWorld, stop: &AtomicBool) -> std::io::Result<()> {
    stream.set_nonblocking(false)?;
    stream.set_nodelay(true)?;
    stream.set_read_timeout(Some(SERVER_TICK))?;
    stream.write_all(&encode_text(PacketType::Command, GREETING))?;
    let mut decoder = PacketDecoder::new(MAX_COMMAND_LEN);
    let mut buf = vec![0u8; 4096];
    while !stop.load(Ordering::Relaxed) {
        match stream.read(&mut buf) {
            Ok(0) => return Ok(()),
            Ok(n) => decoder.push(&buf[..n]),
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => continue,
            Err(e) => return Err(e),
        }
        while let Some(p) = decoder.next_packet() {
            let reply = match p {
                Ok(p) if p.kind == PacketType::Command => answer(&p.text(), world),
                Ok(p) => encode_text(PacketType::Error, &format!("Unexpected packet type {:?}", p.kind)),
                Err(e) => {
                    stream.write_all(&encode_text(PacketType::Error, &e.to_string()))?;
                    return Ok(());
                }
            };
            stream.write_all(&reply)?;
        }
    }
    Ok(())
}

/// The reply to one command, as QTM words it.
fn answer(command: &str, world: &MockWorld) -> Vec<u8> {
    let mut words = command.split_whitespace();
    let verb = words.next().unwrap_or("").to_ascii_lowercase();
    let text = |t: &str| encode_text(PacketType::Command, t);
    match verb.as_str() {
        "version" => match words.next() {
            Some(v) => text(&format!("Version set to {v}")),
            None => text("Version is 1.11"),
        },
        "takecontrol" => text("You are now master"),
        "releasecontrol" => text("You are now a regular client"),
        "new" => text("Creating new connection"),
        "getcurrentframe" if command.to_ascii_lowercase().contains("6deuler") => world.frame_packet(),
        "getcurrentframe" => encode_text(PacketType::Error, "The mock serves only 6DEuler frames"),
        _ => encode_text(PacketType::Error, "Parse error"),
    }
}
