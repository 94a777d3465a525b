//! Qualisys Track Manager (QTM) real-time protocol 1.11 client, as the 2015 code used it, and a
//! tracker that turns motion-capture bodies into real-vehicle states.
//!
//! # Wire format
//! TCP (default port 22224). Every packet: big-endian i32 size (the 8-byte header included),
//! big-endian i32 type ([`PacketType`]), then the payload. Commands (type 1) are ASCII text ending
//! with one NUL byte. A data packet (type 3) holds an i64 timestamp [µs], an i32 frame number, an
//! i32 component count, then components: i32 size (its 8-byte header included), i32 type (6 =
//! 6DOF Euler), and for 6DOF Euler an i32 body count, 4 bytes of drop-rate/out-of-sync counters
//! and per body six f32: x, y, z [mm], roll, pitch, yaw [degrees]. All integers and floats are
//! big-endian. Sizes are never trusted: a packet larger than the configured bound (default
//! [`MAX_PACKET_LEN`]) is refused before anything is allocated.
//!
//! # Session
//! The client connects, sends `Version 1.11`, then `TakeControl <password>` when a password is
//! configured (i.e. when it is not master), then `New`, then polls `GetCurrentFrame 6DEuler` at a
//! fixed rate (default 24 Hz). Bad packets are logged and dropped; a broken stream (bad size, EOF)
//! makes it reconnect after a delay. It never panics on input.

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use glam::DVec2;

use super::{WarnLimiter, lock};

/// Default QTM real-time port.
pub const DEFAULT_QTM_PORT: u16 = 22224;
/// Default server address: loopback, port 22224.
pub const DEFAULT_QTM_ADDR: SocketAddr = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, DEFAULT_QTM_PORT));
/// Default polling rate of `GetCurrentFrame` [Hz] (the 2015 rate).
pub const DEFAULT_POLL_RATE_HZ: f64 = 24.0;
/// Packet header length [bytes]: size and type.
pub const HEADER_LEN: usize = 8;
/// Default bound on a packet's size field [bytes]; anything larger is refused unread.
pub const MAX_PACKET_LEN: usize = 1 << 20;
/// Component type of 6DOF bodies with Euler angles.
pub const COMPONENT_6D_EULER: i32 = 6;
/// Bytes per 6DOF Euler body: six f32.
pub const BODY_LEN: usize = 24;
/// Bytes before the bodies in a 6DOF Euler component: size, type, body count, counters.
pub const COMPONENT_6D_EULER_HEADER_LEN: usize = 16;
/// Bytes before the components in a data payload: timestamp, frame number, component count.
pub const DATA_HEADER_LEN: usize = 16;
/// The command the client polls with.
pub const POLL_COMMAND: &str = "GetCurrentFrame 6DEuler";
/// The protocol version the client asks for.
pub const VERSION_COMMAND: &str = "Version 1.11";

/// Packet types of the QTM real-time protocol.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum PacketType {
    /// 0: an error message (text).
    Error,
    /// 1: a command or a reply to one (text).
    Command,
    /// 2: XML settings (text).
    Xml,
    /// 3: a data frame.
    Data,
    /// 4: no more data (nothing is being measured).
    NoMoreData,
    /// 5: a C3D file.
    C3d,
    /// 6: an event.
    Event,
}

impl PacketType {
    /// The type for a wire code, `None` for unknown codes.
    pub fn from_code(code: i32) -> Option<Self> {
        Some(match code {
            0 => Self::Error,
            1 => Self::Command,
            2 => Self::Xml,
            3 => Self::Data,
            4 => Self::NoMoreData,
            5 => Self::C3d,
            6 => Self::Event,
            _ => return None,
        })
    }

    /// The wire code.
    pub fn code(self) -> i32 {
        match self {
            Self::Error => 0,
            Self::Command => 1,
            Self::Xml => 2,
            Self::Data => 3,
            Self::NoMoreData => 4,
            Self::C3d => 5,
            Self::Event => 6,
        }
    }
}

/// One framed packet.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Packet {
    /// Its type.
    pub kind: PacketType,
    /// The payload (header removed).
    pub payload: Vec<u8>,
}

impl Packet {
    /// The payload as text, without the trailing NUL (invalid UTF-8 replaced).
    pub fn text(&self) -> String {
        let end = self.payload.iter().position(|&b| b == 0).unwrap_or(self.payload.len());
        String::from_utf8_lossy(&self.payload[..end]).into_owned()
    }
}

/// Errors of the QTM protocol layer.
#[derive(Debug, thiserror::Error)]
pub enum QtmError {
    /// A size field outside `8..=bound`: the stream cannot be trusted any more.
    #[error("QTM packet size field {size} is outside 8..={bound} bytes; the stream is out of sync (reconnect)")]
    BadSize {
        /// The size field.
        size: i64,
        /// The bound in force.
        bound: usize,
    },
    /// An unknown packet type (the packet was skipped).
    #[error("QTM packet type {code} is unknown (expected 0..=6); {len} payload bytes skipped")]
    UnknownType {
        /// The type field.
        code: i32,
        /// Payload length skipped.
        len: usize,
    },
    /// A payload shorter than its contents claim.
    #[error("QTM data packet truncated: {what} needs {need} bytes at offset {at}, only {have} left")]
    Truncated {
        /// What was being read.
        what: &'static str,
        /// Bytes needed.
        need: usize,
        /// Offset in the payload.
        at: usize,
        /// Bytes left.
        have: usize,
    },
    /// A component size that is negative, too small or beyond the payload.
    #[error("QTM data packet component {index}: size {size} is outside 8..={room} bytes")]
    BadComponentSize {
        /// 0-based component index.
        index: usize,
        /// The size field.
        size: i32,
        /// Bytes left in the payload.
        room: usize,
    },
    /// A body count that is negative or does not fit its component.
    #[error("QTM 6DOF Euler component: body count {count} does not fit in {room} bytes ({BODY_LEN} per body)")]
    BadBodyCount {
        /// The count field.
        count: i32,
        /// Bytes available for bodies.
        room: usize,
    },
    /// A component count that is negative.
    #[error("QTM data packet: component count {0} is negative")]
    BadComponentCount(i32),
    /// The data packet holds no 6DOF Euler component (wrong `GetCurrentFrame` components?).
    #[error("QTM data packet holds no 6DOF Euler component (type {COMPONENT_6D_EULER}); ask for `{POLL_COMMAND}`")]
    No6DEuler,
    /// A packet of another type where a data packet was expected.
    #[error("expected a QTM data packet (type 3), got {0:?}")]
    NotData(PacketType),
    /// The server refused a command or did not answer in time during the handshake.
    #[error("QTM handshake: {0}")]
    Handshake(String),
    /// A configuration value is out of range.
    #[error("QTM client configuration: {0}")]
    Config(String),
    /// The server closed the connection.
    #[error("QTM server closed the connection")]
    Closed,
    /// Socket error.
    #[error("QTM connection ({what}): {source}")]
    Io {
        /// What was being done.
        what: String,
        /// Underlying error.
        source: std::io::Error,
    },
}

/// Frame a packet: size (header included) and type, big-endian, then the payload.
pub fn encode_packet(kind: PacketType, payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER_LEN + payload.len());
    out.extend_from_slice(&((HEADER_LEN + payload.len()) as i32).to_be_bytes());
    out.extend_from_slice(&kind.code().to_be_bytes());
    out.extend_from_slice(payload);
    out
}

/// A text packet (command, error or XML): the ASCII text and one NUL byte.
pub fn encode_text(kind: PacketType, text: &str) -> Vec<u8> {
    let mut payload = Vec::with_capacity(text.len() + 1);
    payload.extend_from_slice(text.as_bytes());
    payload.push(0);
    encode_packet(kind, &payload)
}

/// A command packet (type 1): size = 8 + text length + 1.
pub fn encode_command(text: &str) -> Vec<u8> {
    encode_text(PacketType::Command, text)
}

/// Splits a byte stream into packets. Feed it bytes with [`Self::push`], take packets with
/// [`Self::next_packet`]. A size outside `8..=bound` is an error after which the stream is out of
/// sync: the decoder stays broken (returns that error again) until [`Self::reset`].
#[derive(Debug)]
pub struct PacketDecoder {
    buf: Vec<u8>,
    start: usize,
    bound: usize,
    broken: Option<i64>,
}

impl PacketDecoder {
    /// A decoder refusing packets larger than `bound` bytes (header included; at least 8).
    pub fn new(bound: usize) -> Self {
        Self { buf: Vec::new(), start: 0, bound: bound.max(HEADER_LEN), broken: None }
    }

    /// Append received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        if self.start > 0 && self.start == self.buf.len() {
            self.buf.clear();
            self.start = 0;
        } else if self.start > self.bound {
            self.buf.drain(..self.start);
            self.start = 0;
        }
        self.buf.extend_from_slice(bytes);
    }

    /// Forget everything buffered (after a reconnect).
    pub fn reset(&mut self) {
        self.buf.clear();
        self.start = 0;
        self.broken = None;
    }

    /// Bytes buffered but not yet returned as packets.
    pub fn buffered(&self) -> usize {
        self.buf.len() - self.start
    }

    /// The next complete packet: `None` when more bytes are needed.
    pub fn next_packet(&mut self) -> Option<Result<Packet, QtmError>> {
        if let Some(size) = self.broken {
            return Some(Err(QtmError::BadSize { size, bound: self.bound }));
        }
        let rest = &self.buf[self.start..];
        let header: [u8; HEADER_LEN] = rest.get(..HEADER_LEN)?.try_into().ok()?;
        let size = i32::from_be_bytes([header[0], header[1], header[2], header[3]]);
        let code = i32::from_be_bytes([header[4], header[5], header[6], header[7]]);
        let len = match usize::try_from(size) {
            Ok(len) if (HEADER_LEN..=self.bound).contains(&len) => len,
            _ => {
                self.broken = Some(i64::from(size));
                return Some(Err(QtmError::BadSize { size: i64::from(size), bound: self.bound }));
            }
        };
        let payload = rest.get(HEADER_LEN..len)?;
        let result = match PacketType::from_code(code) {
            Some(kind) => Ok(Packet { kind, payload: payload.to_vec() }),
            None => Err(QtmError::UnknownType { code, len: len - HEADER_LEN }),
        };
        self.start += len;
        Some(result)
    }
}

/// One visible 6DOF body of a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Body6DEuler {
    /// 0-based index of the body in QTM's body list.
    pub index: u32,
    /// Position [mm].
    pub x_mm: f32,
    /// Position [mm].
    pub y_mm: f32,
    /// Position [mm].
    pub z_mm: f32,
    /// First Euler angle [degrees].
    pub roll_deg: f32,
    /// Second Euler angle [degrees].
    pub pitch_deg: f32,
    /// Third Euler angle, used as yaw [degrees].
    pub yaw_deg: f32,
}

/// A parsed data packet: its 6DOF Euler bodies.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DataFrame {
    /// Capture timestamp [µs].
    pub timestamp_us: i64,
    /// QTM frame number.
    pub frame: i32,
    /// Bodies QTM reported (visible or not).
    pub body_count: u32,
    /// Visible bodies only: a body with any NaN or infinite value is skipped (not tracked).
    pub bodies: Vec<Body6DEuler>,
}

struct Cursor<'a> {
    data: &'a [u8],
    at: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], QtmError> {
        let have = self.data.len() - self.at;
        if n > have {
            return Err(QtmError::Truncated { what, need: n, at: self.at, have });
        }
        let s = &self.data[self.at..self.at + n];
        self.at += n;
        Ok(s)
    }
    fn i32(&mut self, what: &'static str) -> Result<i32, QtmError> {
        let b = self.take(4, what)?;
        Ok(i32::from_be_bytes([b[0], b[1], b[2], b[3]]))
    }
}

fn be_f32(b: &[u8]) -> f32 {
    f32::from_be_bytes([b[0], b[1], b[2], b[3]])
}

/// Parse a data payload (type 3, header removed); takes the first 6DOF Euler component and
/// skips others by their (bounded) size. Never panics; inconsistent sizes are errors.
pub fn parse_data(payload: &[u8]) -> Result<DataFrame, QtmError> {
    let mut c = Cursor { data: payload, at: 0 };
    let ts = c.take(8, "timestamp")?;
    let timestamp_us = i64::from_be_bytes([ts[0], ts[1], ts[2], ts[3], ts[4], ts[5], ts[6], ts[7]]);
    let frame = c.i32("frame number")?;
    let count = c.i32("component count")?;
    if count < 0 {
        return Err(QtmError::BadComponentCount(count));
    }
    for index in 0..count as usize {
        let room = payload.len() - c.at;
        let size = c.i32("component size")?;
        let kind = c.i32("component type")?;
        let len = match usize::try_from(size) {
            Ok(len) if (8..=room).contains(&len) => len,
            _ => return Err(QtmError::BadComponentSize { index, size, room }),
        };
        let body = c.take(len - 8, "component")?;
        if kind == COMPONENT_6D_EULER {
            return parse_6d_euler(body, timestamp_us, frame);
        }
    }
    Err(QtmError::No6DEuler)
}

/// Parse a 6DOF Euler component after its size and type fields.
fn parse_6d_euler(data: &[u8], timestamp_us: i64, frame: i32) -> Result<DataFrame, QtmError> {
    let mut c = Cursor { data, at: 0 };
    let count = c.i32("body count")?;
    c.take(4, "drop-rate and out-of-sync counters")?;
    let room = data.len() - c.at;
    let n = match usize::try_from(count) {
        Ok(n) if n <= room / BODY_LEN => n,
        _ => return Err(QtmError::BadBodyCount { count, room }),
    };
    let mut bodies = Vec::with_capacity(n);
    for index in 0..n {
        let b = c.take(BODY_LEN, "body")?;
        let v: [f32; 6] = std::array::from_fn(|i| be_f32(&b[4 * i..4 * i + 4]));
        if v.iter().all(|x| x.is_finite()) {
            bodies.push(Body6DEuler {
                index: index as u32,
                x_mm: v[0],
                y_mm: v[1],
                z_mm: v[2],
                roll_deg: v[3],
                pitch_deg: v[4],
                yaw_deg: v[5],
            });
        }
    }
    Ok(DataFrame { timestamp_us, frame, body_count: n as u32, bodies })
}

/// Parse a whole packet as a data frame.
pub fn parse_data_packet(packet: &Packet) -> Result<DataFrame, QtmError> {
    if packet.kind != PacketType::Data {
        return Err(QtmError::NotData(packet.kind));
    }
    parse_data(&packet.payload)
}

/// Build a data packet with one 6DOF Euler component; each body is `[x, y, z mm, roll, pitch,
/// yaw degrees]`, NaN for an invisible body. Used by the mock server.
pub fn encode_6d_euler_packet(timestamp_us: i64, frame: i32, bodies: &[[f32; 6]]) -> Vec<u8> {
    let comp_len = COMPONENT_6D_EULER_HEADER_LEN + BODY_LEN * bodies.len();
    let mut p = Vec::with_capacity(DATA_HEADER_LEN + comp_len);
    p.extend_from_slice(&timestamp_us.to_be_bytes());
    p.extend_from_slice(&frame.to_be_bytes());
    p.extend_from_slice(&1i32.to_be_bytes());
    p.extend_from_slice(&(comp_len as i32).to_be_bytes());
    p.extend_from_slice(&COMPONENT_6D_EULER.to_be_bytes());
    p.extend_from_slice(&(bodies.len() as i32).to_be_bytes());
    p.extend_from_slice(&[0; 4]);
    for b in bodies {
        for v in b {
            p.extend_from_slice(&v.to_be_bytes());
        }
    }
    encode_packet(PacketType::Data, &p)
}

/// Settings of a [`QtmClient`].
#[derive(Debug, Clone, PartialEq)]
pub struct QtmClientConfig {
    /// QTM server (default 127.0.0.1:22224).
    pub addr: SocketAddr,
    /// `GetCurrentFrame` polls per second [Hz] (default 24; raising it lowers latency).
    pub poll_rate_hz: f64,
    /// When set, `TakeControl <password>` is sent before `New` (needed when not master).
    pub password: Option<String>,
    /// Wait before reconnecting after a failure (default 1 s).
    pub reconnect_delay: Duration,
    /// Longest wait for a handshake reply or a connection (default 2 s).
    pub handshake_timeout: Duration,
    /// Bound on a packet's size field [bytes] (default 1 MiB).
    pub max_packet_len: usize,
}

impl Default for QtmClientConfig {
    fn default() -> Self {
        Self {
            addr: DEFAULT_QTM_ADDR,
            poll_rate_hz: DEFAULT_POLL_RATE_HZ,
            password: None,
            reconnect_delay: Duration::from_secs(1),
            handshake_timeout: Duration::from_secs(2),
            max_packet_len: MAX_PACKET_LEN,
        }
    }
}

/// A frame with the instant it arrived.
#[derive(Debug, Clone, PartialEq)]
pub struct TimedFrame {
    /// When the client received it.
    pub received_at: Instant,
    /// The parsed frame.
    pub frame: DataFrame,
}

/// Counters of a client's life.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct QtmStats {
    /// Whether a session is established now.
    pub connected: bool,
    /// Sessions established (handshake done).
    pub sessions: u64,
    /// Data frames parsed and handed over.
    pub frames: u64,
    /// Packets dropped as malformed (bad data, unknown type, bad size).
    pub bad_packets: u64,
    /// Error packets (type 0) received from the server.
    pub error_replies: u64,
    /// The last problem seen, if any.
    pub last_error: Option<String>,
}

/// Frames waiting in the client's queue at most; older ones are dropped when it is full.
const FRAME_QUEUE: usize = 256;
/// Read timeout of the client socket: bounds how late a poll or a stop request can be.
const CLIENT_TICK: Duration = Duration::from_millis(5);

/// A QTM client running on a background thread: connects, handshakes, polls frames, reconnects
/// after failures. Dropping it stops the thread.
#[derive(Debug)]
pub struct QtmClient {
    frames: Receiver<TimedFrame>,
    stats: Arc<Mutex<QtmStats>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl QtmClient {
    /// Start the client thread (it connects in the background and keeps retrying).
    pub fn spawn(config: QtmClientConfig) -> Result<Self, QtmError> {
        if poll_period(config.poll_rate_hz).is_none() {
            return Err(QtmError::Config(format!(
                "poll rate {} Hz must be a positive number of at most 1e6",
                config.poll_rate_hz
            )));
        }
        let (tx, frames) = std::sync::mpsc::sync_channel(FRAME_QUEUE);
        let stats = Arc::new(Mutex::new(QtmStats::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (stats, stop) = (stats.clone(), stop.clone());
            std::thread::Builder::new()
                .name("qtm-client".into())
                .spawn(move || client_loop(&config, &tx, &stats, &stop))
                .map_err(|source| QtmError::Io { what: "spawn client thread".into(), source })?
        };
        Ok(Self { frames, stats, stop, thread: Some(thread) })
    }

    /// The next received frame, if any (non-blocking).
    pub fn try_next(&self) -> Option<TimedFrame> {
        self.frames.try_recv().ok()
    }

    /// Wait up to `timeout` for the next frame.
    pub fn next_timeout(&self, timeout: Duration) -> Option<TimedFrame> {
        self.frames.recv_timeout(timeout).ok()
    }

    /// Feed every frame received so far into `tracker`, then mark bodies unseen for too long as
    /// stale at `now`. Returns the number of frames fed. This is what a plugin's system calls.
    pub fn poll(&self, tracker: &mut Tracker, now: Instant) -> usize {
        let mut n = 0;
        while let Ok(f) = self.frames.try_recv() {
            tracker.update(&f.frame, f.received_at);
            n += 1;
        }
        tracker.refresh(now);
        n
    }

    /// Counters so far.
    pub fn stats(&self) -> QtmStats {
        lock(&self.stats).clone()
    }

    /// Whether the client thread is still running (it only ends when dropped).
    pub fn is_running(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }
}

impl Drop for QtmClient {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The period of a rate [Hz], `None` unless the rate is in `(0, 1e6]` with a representable period.
fn poll_period(rate_hz: f64) -> Option<Duration> {
    if rate_hz > 0.0 && rate_hz <= 1e6 { Duration::try_from_secs_f64(1.0 / rate_hz).ok() } else { None }
}

/// Everything a client session needs besides its socket.
struct Session<'a> {
    config: &'a QtmClientConfig,
    tx: &'a SyncSender<TimedFrame>,
    stats: &'a Mutex<QtmStats>,
    stop: &'a AtomicBool,
    decoder: PacketDecoder,
    warn: WarnLimiter,
    buf: Vec<u8>,
}

fn client_loop(config: &QtmClientConfig, tx: &SyncSender<TimedFrame>, stats: &Mutex<QtmStats>, stop: &AtomicBool) {
    let mut session = Session {
        config,
        tx,
        stats,
        stop,
        decoder: PacketDecoder::new(config.max_packet_len),
        warn: WarnLimiter::new(Duration::from_secs(1)),
        buf: vec![0; 64 * 1024],
    };
    let mut connect_warn = WarnLimiter::new(Duration::from_secs(10));
    while !stop.load(Ordering::Relaxed) {
        let result = TcpStream::connect_timeout(&config.addr, config.handshake_timeout)
            .map_err(|source| QtmError::Io { what: format!("connect to {}", config.addr), source })
            .and_then(|stream| {
                session.decoder.reset();
                session.run(stream)
            });
        lock(stats).connected = false;
        match result {
            Ok(()) => return,
            Err(e) => {
                connect_warn.warn(&format!("QTM client: {e}; retrying in {:?}", config.reconnect_delay));
                lock(stats).last_error = Some(e.to_string());
            }
        }
        let until = Instant::now() + config.reconnect_delay;
        while !stop.load(Ordering::Relaxed) && Instant::now() < until {
            std::thread::sleep(CLIENT_TICK.min(config.reconnect_delay));
        }
    }
}

impl Session<'_> {
    /// One connection: handshake then poll until stopped (Ok) or the stream breaks (Err).
    fn run(&mut self, mut stream: TcpStream) -> Result<(), QtmError> {
        let io = |what: &str| {
            let what = what.to_string();
            move |source| QtmError::Io { what, source }
        };
        stream.set_nodelay(true).map_err(io("set nodelay"))?;
        stream.set_read_timeout(Some(CLIENT_TICK)).map_err(io("set read timeout"))?;
        self.command(&mut stream, VERSION_COMMAND, true)?;
        if let Some(pw) = &self.config.password {
            let take = format!("TakeControl {pw}");
            self.command(&mut stream, &take, false)?;
        }
        self.command(&mut stream, "New", false)?;
        {
            let mut s = lock(self.stats);
            s.connected = true;
            s.sessions += 1;
        }
        tracing::info!("QTM client: connected to {}", self.config.addr);
        let period = poll_period(self.config.poll_rate_hz).unwrap_or(Duration::from_secs(1));
        let poll = encode_command(POLL_COMMAND);
        let mut next_poll = Instant::now();
        while !self.stop.load(Ordering::Relaxed) {
            let now = Instant::now();
            if now >= next_poll {
                stream.write_all(&poll).map_err(io("send GetCurrentFrame"))?;
                next_poll += period;
                if next_poll < now {
                    next_poll = now + period;
                }
            }
            // Packets already buffered first: an EOF must not hide them.
            while let Some(p) = self.decoder.next_packet() {
                self.handle(p)?;
            }
            self.read_some(&mut stream)?;
        }
        Ok(())
    }

    /// Read what is available (up to one read timeout) into the decoder.
    fn read_some(&mut self, stream: &mut TcpStream) -> Result<(), QtmError> {
        match stream.read(&mut self.buf) {
            Ok(0) => Err(QtmError::Closed),
            Ok(n) => {
                self.decoder.push(&self.buf[..n]);
                Ok(())
            }
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => Ok(()),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => Ok(()),
            Err(source) => Err(QtmError::Io { what: "read".into(), source }),
        }
    }

    /// Send a handshake command and wait for its reply (skipping the server's greeting and
    /// other packets). An error reply is fatal when `required`, else a warning.
    fn command(&mut self, stream: &mut TcpStream, text: &str, required: bool) -> Result<(), QtmError> {
        stream
            .write_all(&encode_command(text))
            .map_err(|source| QtmError::Io { what: format!("send `{text}`"), source })?;
        let deadline = Instant::now() + self.config.handshake_timeout;
        while Instant::now() < deadline && !self.stop.load(Ordering::Relaxed) {
            while let Some(p) = self.decoder.next_packet() {
                let p = match p {
                    Ok(p) => p,
                    Err(e @ QtmError::BadSize { .. }) => return Err(e),
                    Err(e) => {
                        self.bad_packet(&e);
                        continue;
                    }
                };
                let reply = p.text();
                match p.kind {
                    PacketType::Command if reply.starts_with("QTM RT Interface connected") => {}
                    PacketType::Command => {
                        tracing::debug!("QTM `{text}` -> `{reply}`");
                        return Ok(());
                    }
                    PacketType::Error if required => {
                        return Err(QtmError::Handshake(format!("`{text}` refused: {reply}")));
                    }
                    PacketType::Error => {
                        lock(self.stats).error_replies += 1;
                        tracing::warn!("QTM `{text}` refused: {reply}; continuing");
                        return Ok(());
                    }
                    _ => {}
                }
            }
            self.read_some(stream)?;
        }
        Err(QtmError::Handshake(format!("no reply to `{text}` within {:?}", self.config.handshake_timeout)))
    }

    fn handle(&mut self, p: Result<Packet, QtmError>) -> Result<(), QtmError> {
        let p = match p {
            Ok(p) => p,
            Err(e @ QtmError::BadSize { .. }) => {
                lock(self.stats).bad_packets += 1;
                return Err(e);
            }
            Err(e) => {
                self.bad_packet(&e);
                return Ok(());
            }
        };
        match p.kind {
            PacketType::Data => match parse_data(&p.payload) {
                Ok(frame) => {
                    lock(self.stats).frames += 1;
                    let timed = TimedFrame { received_at: Instant::now(), frame };
                    if let Err(TrySendError::Full(_)) = self.tx.try_send(timed) {
                        tracing::debug!("QTM client: frame queue full, frame dropped");
                    }
                }
                Err(e) => self.bad_packet(&e),
            },
            PacketType::Error => {
                let text = p.text();
                let mut s = lock(self.stats);
                s.error_replies += 1;
                s.last_error = Some(format!("QTM error reply: {text}"));
                drop(s);
                self.warn.warn(&format!("QTM error reply: {text}"));
            }
            PacketType::NoMoreData => tracing::debug!("QTM: no more data"),
            other => tracing::debug!("QTM: ignoring {other:?} packet"),
        }
        Ok(())
    }

    fn bad_packet(&mut self, e: &QtmError) {
        let mut s = lock(self.stats);
        s.bad_packets += 1;
        s.last_error = Some(e.to_string());
        drop(s);
        self.warn.warn(&format!("QTM client: dropped packet: {e}"));
    }
}

/// Which vehicle id each QTM body drives.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub enum BodyMapping {
    /// Body k is real vehicle k.
    #[default]
    Identity,
    /// Body index -> vehicle id; bodies not listed are ignored.
    Table(BTreeMap<u32, i32>),
}

impl BodyMapping {
    /// The vehicle id of body `index`, if it is tracked.
    pub fn id_of(&self, index: u32) -> Option<i32> {
        match self {
            Self::Identity => i32::try_from(index).ok(),
            Self::Table(t) => t.get(&index).copied(),
        }
    }
}

/// Settings of a [`Tracker`].
#[derive(Debug, Clone, PartialEq)]
pub struct TrackerConfig {
    /// Body -> vehicle id (default: body k is vehicle k).
    pub mapping: BodyMapping,
    /// Lab floor to world factor (default 32, the trucks' scale): world [m] = lab [m] * scale.
    pub scale: f64,
    /// A body unseen for longer than this is reported stale (default 0.5 s; raising it hides
    /// short occlusions, lowering it reports losses sooner).
    pub stale_after: Duration,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self { mapping: BodyMapping::Identity, scale: 32.0, stale_after: Duration::from_millis(500) }
    }
}

/// A real vehicle as motion capture sees it, in world units.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackedBody {
    /// Vehicle id (from the body mapping).
    pub id: i32,
    /// QTM body index.
    pub body: u32,
    /// World position [m] (lab position scaled by the factor).
    pub position: DVec2,
    /// Heading, the third Euler angle [rad].
    pub yaw: f64,
    /// World velocity from successive frames [m/s]; zero on the first sighting or after a loss.
    pub velocity: DVec2,
    /// True when the body has not been seen for longer than the timeout; the vehicle keeps its
    /// last state.
    pub stale: bool,
    /// QTM frame number of the last sighting.
    pub frame: i32,
    /// QTM timestamp of the last sighting [µs].
    pub timestamp_us: i64,
    /// When the last sighting arrived.
    pub last_seen: Instant,
}

/// Turns frames into tracked vehicles: mapping, scaling, velocity, staleness.
#[derive(Debug, Clone)]
pub struct Tracker {
    config: TrackerConfig,
    bodies: BTreeMap<i32, TrackedBody>,
}

impl Tracker {
    /// An empty tracker.
    pub fn new(config: TrackerConfig) -> Self {
        Self { config, bodies: BTreeMap::new() }
    }

    /// Take one frame received at `received_at`. A sample with the same timestamp as a body's
    /// last one (the same frame polled twice) is ignored; an older timestamp means QTM restarted
    /// its measurement: the sample is taken with zero velocity.
    pub fn update(&mut self, frame: &DataFrame, received_at: Instant) {
        let s = self.config.scale / 1000.0;
        for b in &frame.bodies {
            let Some(id) = self.config.mapping.id_of(b.index) else { continue };
            let position = DVec2::new(f64::from(b.x_mm) * s, f64::from(b.y_mm) * s);
            let yaw = f64::from(b.yaw_deg).to_radians();
            match self.bodies.get_mut(&id) {
                Some(t) if frame.timestamp_us == t.timestamp_us => {}
                Some(t) => {
                    let dt = (frame.timestamp_us - t.timestamp_us) as f64 * 1e-6;
                    // dt < 0: QTM started a new measurement (timestamps restart): no velocity yet.
                    t.velocity = if t.stale || dt < 0.0 { DVec2::ZERO } else { (position - t.position) / dt };
                    if t.stale {
                        tracing::info!("motion capture: vehicle {id} (body {}) tracked again", b.index);
                    }
                    t.position = position;
                    t.yaw = yaw;
                    t.stale = false;
                    t.frame = frame.frame;
                    t.timestamp_us = frame.timestamp_us;
                    t.last_seen = received_at;
                }
                None => {
                    self.bodies.insert(
                        id,
                        TrackedBody {
                            id,
                            body: b.index,
                            position,
                            yaw,
                            velocity: DVec2::ZERO,
                            stale: false,
                            frame: frame.frame,
                            timestamp_us: frame.timestamp_us,
                            last_seen: received_at,
                        },
                    );
                }
            }
        }
    }

    /// Mark bodies unseen for longer than the timeout at `now` as stale (logged once per loss).
    /// Returns how many became stale in this call.
    pub fn refresh(&mut self, now: Instant) -> usize {
        let mut n = 0;
        for t in self.bodies.values_mut() {
            if !t.stale && now.saturating_duration_since(t.last_seen) > self.config.stale_after {
                t.stale = true;
                t.velocity = DVec2::ZERO;
                n += 1;
                tracing::warn!(
                    "motion capture: vehicle {} (body {}) lost for more than {:?}; marked stale",
                    t.id,
                    t.body,
                    self.config.stale_after
                );
            }
        }
        n
    }

    /// All vehicles ever tracked, by id (stale ones included).
    pub fn bodies(&self) -> impl Iterator<Item = &TrackedBody> {
        self.bodies.values()
    }

    /// One vehicle by id.
    pub fn get(&self, id: i32) -> Option<&TrackedBody> {
        self.bodies.get(&id)
    }
}
