//! The 2015 visualisation datagram over UDP: encoder (with a backward-compatible split of big
//! frames), decoder, reassembler, sender and receiver.
//!
//! # Format (as the 2015 tools spoke it)
//! One UDP datagram per frame, ASCII:
//! `<counter>#id=<id>;x=<x>;y=<y>;yaw=<deg>;class_name=<Class>!id=...`
//! - `counter`: a non-negative integer, 0 for the first frame, +1 per frame;
//! - after `#`, one record per vehicle, records separated by `!`; an empty body means "no vehicles";
//! - a record is `;`-separated `key=value` fields: `id` (integer), `x`, `y` [m], `yaw` [degrees],
//!   `class_name` (text without `#`, `!`, `;`, `=`).
//!
//! A receiver drops a datagram whose counter is not newer than the last one it accepted.
//! The 2015 receiver read one datagram into a 4096-byte buffer ([`MAX_DATAGRAM_LEN`]).
//!
//! # Split extension (big frames)
//! When a frame does not fit in [`MAX_DATAGRAM_LEN`] bytes, the encoder splits its vehicles over
//! several datagrams ("parts"), each at most 4096 bytes and each a complete, valid 2015 datagram:
//! - every part carries the **same** counter, the frame's counter;
//! - the first record of every part gets two extra trailing fields, `part=<i>` (0-based) and
//!   `parts=<n>` (the number of parts of the frame), e.g.
//!   `17#id=0;x=1.000;y=2.000;yaw=90.00;class_name=Truck;part=0;parts=3!id=1;...`.
//!
//! Why it is backward compatible: a 2015 receiver splits on `#`, `!`, `;` and `=` and reads the
//! keys it knows, so it ignores the two extra integer fields; it accepts the first part it sees of
//! a frame (its counter is new) and drops the other parts as stale (same counter), so it shows the
//! first part of every frame, steadily, instead of flickering between parts. A new receiver
//! ([`VizReassembler`]) recognises `part`/`parts`, does not treat parts of the frame it is
//! assembling as stale, and delivers the frame once all its parts have arrived. A frame that fits
//! in one datagram is sent exactly as in 2015, without the extra fields. Unknown keys are ignored
//! by the decoder, so later extensions stay compatible too.

use std::fmt::Write as _;
use std::io::Write as _;
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr, SocketAddrV4, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use super::lock;

/// Default destination of the stream: loopback, port 38008 (the 2015 port).
pub const DEFAULT_VIZ_ADDR: SocketAddr = SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, 38008));
/// Default send rate [Hz] (the 2015 rate).
pub const DEFAULT_VIZ_RATE_HZ: f64 = 50.0;
/// Largest datagram the encoder emits [bytes]: the 2015 receiver's buffer size.
pub const MAX_DATAGRAM_LEN: usize = 4096;
/// Key of the split extension: 0-based index of this part within its frame.
pub const PART_KEY: &str = "part";
/// Key of the split extension: number of parts of the frame.
pub const PARTS_KEY: &str = "parts";
/// Most parts a receiver accepts for one frame (bounds the memory a hostile sender can claim);
/// at about 70 vehicles per part, frames of up to roughly 280 000 vehicles.
pub const MAX_PARTS: u32 = 4096;
/// Longest class name sent [bytes]; longer names are cut.
pub const MAX_CLASS_NAME_LEN: usize = 64;

/// One vehicle as the visualisation stream carries it.
#[derive(Debug, Clone, PartialEq)]
pub struct VizVehicle {
    /// Vehicle id (non-negative: real vehicle, negative: virtual).
    pub id: i32,
    /// Position east [m].
    pub x: f64,
    /// Position north [m].
    pub y: f64,
    /// Heading, counter-clockwise from the x axis [degrees].
    pub yaw_deg: f64,
    /// Vehicle class shown by the viewer (e.g. `Truck`, `Car`).
    pub class_name: String,
}

/// Which part of a split frame a datagram holds (the split extension).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VizPart {
    /// 0-based index of this part.
    pub index: u32,
    /// Number of parts of the frame (>= 1).
    pub count: u32,
}

/// One decoded datagram.
#[derive(Debug, Clone, PartialEq)]
pub struct VizDatagram {
    /// Frame counter.
    pub counter: u64,
    /// `Some` when the datagram is one part of a split frame.
    pub part: Option<VizPart>,
    /// Vehicles in this datagram.
    pub vehicles: Vec<VizVehicle>,
}

/// One complete frame, as a receiver delivers it.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct VizFrame {
    /// Frame counter.
    pub counter: u64,
    /// All vehicles of the frame, in the order they were sent.
    pub vehicles: Vec<VizVehicle>,
}

/// Errors of the visualisation stream.
#[derive(Debug, thiserror::Error)]
pub enum VizError {
    /// The datagram is not ASCII/UTF-8 text.
    #[error("visualisation datagram is not UTF-8 text (byte {at}); expected `<counter>#id=..;x=..`")]
    NotText {
        /// Offset of the first bad byte.
        at: usize,
    },
    /// No `#` after the counter.
    #[error("visualisation datagram has no `#` after the counter: {head:?}")]
    MissingHash {
        /// Start of the datagram.
        head: String,
    },
    /// The counter is not a non-negative integer.
    #[error("visualisation datagram counter {text:?} is not a non-negative integer")]
    BadCounter {
        /// The counter text.
        text: String,
    },
    /// A field of a record is not `key=value`.
    #[error("visualisation datagram record {record}: field {field:?} is not `key=value`")]
    MalformedField {
        /// 0-based record index.
        record: usize,
        /// The field text.
        field: String,
    },
    /// A record lacks a required key.
    #[error("visualisation datagram record {record}: key `{key}` is missing (need id, x, y, yaw, class_name)")]
    MissingKey {
        /// 0-based record index.
        record: usize,
        /// The missing key.
        key: &'static str,
    },
    /// A key appears twice in one record.
    #[error("visualisation datagram record {record}: key `{key}` appears twice")]
    DuplicateKey {
        /// 0-based record index.
        record: usize,
        /// The repeated key.
        key: String,
    },
    /// A value cannot be parsed.
    #[error("visualisation datagram record {record}: `{key}={value}` is not a valid {expected}")]
    BadValue {
        /// 0-based record index.
        record: usize,
        /// The key.
        key: &'static str,
        /// The value text.
        value: String,
        /// What was expected.
        expected: &'static str,
    },
    /// The split extension fields are inconsistent.
    #[error("visualisation datagram: bad split fields part={index} parts={count} (need part < parts <= {MAX_PARTS})")]
    BadPart {
        /// `part` value.
        index: u32,
        /// `parts` value.
        count: u32,
    },
    /// A send rate outside `(0, 1e6]` Hz.
    #[error("visualisation send rate {0} Hz must be in (0, 1e6]")]
    BadRate(f64),
    /// Socket error.
    #[error("visualisation stream socket ({what}): {source}")]
    Io {
        /// What was being done.
        what: String,
        /// Underlying error.
        source: std::io::Error,
    },
}

/// At most this many characters of untrusted input are quoted in an error.
const QUOTE_LEN: usize = 40;

fn quote(s: &str) -> String {
    s.chars().take(QUOTE_LEN).collect()
}

/// Encodes frames into datagrams, reusing its buffers from frame to frame.
#[derive(Debug, Default)]
pub struct VizEncoder {
    /// All records of the frame, back to back.
    records: String,
    /// End offset of each record in `records`.
    ends: Vec<usize>,
    /// Record ranges of the parts of a split frame.
    groups: Vec<(usize, usize)>,
    /// Encoded datagrams; only the first `used` are valid.
    parts: Vec<Vec<u8>>,
    used: usize,
}

impl VizEncoder {
    /// A new encoder.
    pub fn new() -> Self {
        Self::default()
    }

    /// Encode one frame: one plain 2015 datagram when it fits in [`MAX_DATAGRAM_LEN`] bytes,
    /// else several parts with the split extension (see the module docs). Class names are
    /// sanitised: characters other than printable ASCII and the separators `#!;=` become `_`,
    /// and names are cut to [`MAX_CLASS_NAME_LEN`] bytes.
    pub fn encode(&mut self, counter: u64, vehicles: &[VizVehicle]) -> &[Vec<u8>] {
        self.records.clear();
        self.ends.clear();
        for v in vehicles {
            write_record(&mut self.records, v);
            self.ends.push(self.records.len());
        }
        let header_len = digits(counter) + 1;
        let plain_len = header_len + self.records.len() + vehicles.len().saturating_sub(1);
        self.used = 0;
        if plain_len <= MAX_DATAGRAM_LEN {
            let buf = self.next_buf();
            let _ = write!(buf, "{counter}#");
            self.push_records(0, vehicles.len(), None);
            return &self.parts[..self.used];
        }
        // Group records into parts; every part reserves room for `;part=i;parts=n`.
        let d = digits(vehicles.len() as u64);
        let reserve = 1 + PART_KEY.len() + 1 + d + 1 + PARTS_KEY.len() + 1 + d;
        let budget = MAX_DATAGRAM_LEN - header_len - reserve;
        let mut groups = std::mem::take(&mut self.groups);
        groups.clear();
        let mut start = 0;
        let mut len = 0;
        for i in 0..vehicles.len() {
            let rec_len = self.ends[i] - if i == 0 { 0 } else { self.ends[i - 1] };
            let add = if i == start { rec_len } else { rec_len + 1 };
            if i > start && len + add > budget {
                groups.push((start, i));
                start = i;
                len = rec_len;
            } else {
                len += add;
            }
        }
        groups.push((start, vehicles.len()));
        let count = groups.len() as u64;
        for (index, &(a, b)) in groups.iter().enumerate() {
            let buf = self.next_buf();
            let _ = write!(buf, "{counter}#");
            self.push_records(a, b, Some((index as u64, count)));
        }
        self.groups = groups;
        &self.parts[..self.used]
    }

    fn next_buf(&mut self) -> &mut Vec<u8> {
        if self.used == self.parts.len() {
            self.parts.push(Vec::with_capacity(MAX_DATAGRAM_LEN));
        }
        self.used += 1;
        let buf = &mut self.parts[self.used - 1];
        buf.clear();
        buf
    }

    /// Append records `a..b` to the last buffer, the split fields after the first one.
    fn push_records(&mut self, a: usize, b: usize, split: Option<(u64, u64)>) {
        let buf = &mut self.parts[self.used - 1];
        for i in a..b {
            if i > a {
                buf.push(b'!');
            }
            let start = if i == 0 { 0 } else { self.ends[i - 1] };
            buf.extend_from_slice(&self.records.as_bytes()[start..self.ends[i]]);
            if i == a
                && let Some((index, count)) = split
            {
                let _ = write!(buf, ";{PART_KEY}={index};{PARTS_KEY}={count}");
            }
        }
    }
}

fn digits(mut n: u64) -> usize {
    let mut d = 1;
    while n >= 10 {
        n /= 10;
        d += 1;
    }
    d
}

fn write_record(out: &mut String, v: &VizVehicle) {
    let _ = write!(out, "id={};x={:.3};y={:.3};yaw={:.2};class_name=", v.id, v.x, v.y, v.yaw_deg);
    for c in v.class_name.chars().take(MAX_CLASS_NAME_LEN) {
        let ok = c.is_ascii_graphic() && !matches!(c, '#' | '!' | ';' | '=');
        out.push(if ok { c } else { '_' });
    }
}

/// Encode one frame into freshly allocated datagrams (convenience over [`VizEncoder`]).
pub fn encode_frame(counter: u64, vehicles: &[VizVehicle]) -> Vec<Vec<u8>> {
    VizEncoder::new().encode(counter, vehicles).to_vec()
}

/// Decode one datagram. Never panics; any malformed input is an error naming the problem.
/// Empty records (e.g. a trailing `!`) are skipped; unknown keys are ignored.
pub fn decode_datagram(bytes: &[u8]) -> Result<VizDatagram, VizError> {
    let text = std::str::from_utf8(bytes).map_err(|e| VizError::NotText { at: e.valid_up_to() })?;
    let Some((head, body)) = text.split_once('#') else {
        return Err(VizError::MissingHash { head: quote(text) });
    };
    let counter: u64 = head.trim().parse().map_err(|_| VizError::BadCounter { text: quote(head) })?;
    let mut vehicles = Vec::new();
    let mut part = None;
    for (record, rec) in body.split('!').enumerate() {
        if rec.trim().is_empty() {
            continue;
        }
        let (v, p) = decode_record(record, rec)?;
        vehicles.push(v);
        if p.is_some() {
            part = p;
        }
    }
    Ok(VizDatagram { counter, part, vehicles })
}

fn decode_record(record: usize, rec: &str) -> Result<(VizVehicle, Option<VizPart>), VizError> {
    let mut id = None;
    let mut x = None;
    let mut y = None;
    let mut yaw = None;
    let mut class_name = None;
    let mut index = None;
    let mut count = None;
    for field in rec.split(';') {
        if field.is_empty() {
            continue;
        }
        let Some((key, value)) = field.split_once('=') else {
            return Err(VizError::MalformedField { record, field: quote(field) });
        };
        let dup = || VizError::DuplicateKey { record, key: quote(key) };
        match key.trim() {
            "id" => set_once(&mut id, parse_value(record, "id", value, "32-bit integer")?, dup)?,
            "x" => set_once(&mut x, parse_value(record, "x", value, "number")?, dup)?,
            "y" => set_once(&mut y, parse_value(record, "y", value, "number")?, dup)?,
            "yaw" => set_once(&mut yaw, parse_value(record, "yaw", value, "number")?, dup)?,
            "class_name" => set_once(&mut class_name, value.to_string(), dup)?,
            PART_KEY => set_once(&mut index, parse_value(record, PART_KEY, value, "part index")?, dup)?,
            PARTS_KEY => set_once(&mut count, parse_value(record, PARTS_KEY, value, "part count")?, dup)?,
            _ => {}
        }
    }
    let missing = |key| VizError::MissingKey { record, key };
    let part = match (index, count) {
        (None, None) => None,
        (Some(index), Some(count)) if index < count && count <= MAX_PARTS => Some(VizPart { index, count }),
        (i, c) => return Err(VizError::BadPart { index: i.unwrap_or(u32::MAX), count: c.unwrap_or(0) }),
    };
    let vehicle = VizVehicle {
        id: id.ok_or_else(|| missing("id"))?,
        x: x.ok_or_else(|| missing("x"))?,
        y: y.ok_or_else(|| missing("y"))?,
        yaw_deg: yaw.ok_or_else(|| missing("yaw"))?,
        class_name: class_name.ok_or_else(|| missing("class_name"))?,
    };
    Ok((vehicle, part))
}

fn set_once<T>(slot: &mut Option<T>, value: T, dup: impl FnOnce() -> VizError) -> Result<(), VizError> {
    if slot.is_some() {
        return Err(dup());
    }
    *slot = Some(value);
    Ok(())
}

fn parse_value<T: std::str::FromStr>(
    record: usize,
    key: &'static str,
    value: &str,
    expected: &'static str,
) -> Result<T, VizError> {
    value.trim().parse().map_err(|_| VizError::BadValue { record, key, value: quote(value), expected })
}

/// Counters of what a receiver saw.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct VizStats {
    /// Datagrams received (good or bad).
    pub datagrams: u64,
    /// Complete frames delivered.
    pub frames: u64,
    /// Datagrams that could not be decoded.
    pub decode_errors: u64,
    /// Datagrams dropped because their counter was not newer than the last frame.
    pub stale: u64,
    /// Split frames abandoned before all their parts arrived.
    pub incomplete: u64,
}

#[derive(Debug)]
struct Pending {
    counter: u64,
    parts: Vec<Option<Vec<VizVehicle>>>,
    missing: u32,
}

/// Turns decoded datagrams into frames: drops stale counters, reassembles split frames.
///
/// Rules: a datagram whose counter is not newer than the last delivered frame is stale. A plain
/// datagram is a whole frame. A part starts assembling its frame (abandoning an older unfinished
/// one); parts of the frame being assembled are not stale; the frame is delivered when all
/// its parts are in. Any datagram older than the frame being assembled is stale.
#[derive(Debug, Default)]
pub struct VizReassembler {
    last: Option<u64>,
    pending: Option<Pending>,
    stats: VizStats,
}

impl VizReassembler {
    /// A receiver state that has seen nothing yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Decode raw bytes and feed them in; decode errors are counted and logged at debug level.
    pub fn push_bytes(&mut self, bytes: &[u8]) -> Option<VizFrame> {
        self.stats.datagrams += 1;
        match decode_datagram(bytes) {
            Ok(d) => self.push_decoded(d),
            Err(e) => {
                self.stats.decode_errors += 1;
                tracing::debug!("dropping visualisation datagram: {e}");
                None
            }
        }
    }

    /// Feed one decoded datagram; returns a frame when one is complete.
    pub fn push(&mut self, datagram: VizDatagram) -> Option<VizFrame> {
        self.stats.datagrams += 1;
        self.push_decoded(datagram)
    }

    fn push_decoded(&mut self, d: VizDatagram) -> Option<VizFrame> {
        let older_than_pending = self.pending.as_ref().is_some_and(|p| d.counter < p.counter);
        if older_than_pending || self.last.is_some_and(|l| d.counter <= l) {
            self.stats.stale += 1;
            return None;
        }
        let Some(part) = d.part else {
            if self.pending.take().is_some() {
                self.stats.incomplete += 1;
            }
            return Some(self.deliver(d.counter, d.vehicles));
        };
        match &self.pending {
            Some(p) if p.counter == d.counter && p.parts.len() == part.count as usize => {}
            other => {
                if other.is_some() {
                    self.stats.incomplete += 1;
                }
                self.pending =
                    Some(Pending { counter: d.counter, parts: vec![None; part.count as usize], missing: part.count });
            }
        }
        let pending = self.pending.as_mut()?;
        let slot = &mut pending.parts[part.index as usize];
        if slot.is_some() {
            self.stats.stale += 1;
            return None;
        }
        *slot = Some(d.vehicles);
        pending.missing -= 1;
        if pending.missing > 0 {
            return None;
        }
        let done = self.pending.take()?;
        let vehicles = done.parts.into_iter().flatten().flatten().collect();
        Some(self.deliver(done.counter, vehicles))
    }

    fn deliver(&mut self, counter: u64, vehicles: Vec<VizVehicle>) -> VizFrame {
        self.last = Some(counter);
        self.stats.frames += 1;
        VizFrame { counter, vehicles }
    }

    /// What was seen so far.
    pub fn stats(&self) -> VizStats {
        self.stats
    }
}

/// Settings of a [`VizSender`].
#[derive(Debug, Clone, PartialEq)]
pub struct VizSenderConfig {
    /// Where datagrams go (default 127.0.0.1:38008).
    pub target: SocketAddr,
    /// Local address to send from; `None` (default): loopback, any port, for a loopback target,
    /// else the unspecified address of the target's family.
    pub bind: Option<SocketAddr>,
    /// Frames per second [Hz] for [`VizSender::send_if_due`] (default 50; raising it sends more often).
    pub rate_hz: f64,
}

impl Default for VizSenderConfig {
    fn default() -> Self {
        Self { target: DEFAULT_VIZ_ADDR, bind: None, rate_hz: DEFAULT_VIZ_RATE_HZ }
    }
}

/// Sends frames of the visualisation stream over UDP; the counter starts at 0.
#[derive(Debug)]
pub struct VizSender {
    socket: UdpSocket,
    target: SocketAddr,
    encoder: VizEncoder,
    counter: u64,
    period_us: i64,
    next_due_us: Option<i64>,
}

impl VizSender {
    /// Bind the sending socket.
    pub fn new(config: &VizSenderConfig) -> Result<Self, VizError> {
        if !(config.rate_hz > 0.0 && config.rate_hz <= 1e6) {
            return Err(VizError::BadRate(config.rate_hz));
        }
        let bind = config.bind.unwrap_or_else(|| match config.target.ip() {
            ip if ip.is_loopback() => SocketAddr::new(ip, 0),
            IpAddr::V4(_) => SocketAddr::new(IpAddr::V4(Ipv4Addr::UNSPECIFIED), 0),
            IpAddr::V6(_) => SocketAddr::new(IpAddr::V6(Ipv6Addr::UNSPECIFIED), 0),
        });
        let socket = UdpSocket::bind(bind).map_err(|source| VizError::Io { what: format!("bind {bind}"), source })?;
        Ok(Self {
            socket,
            target: config.target,
            encoder: VizEncoder::new(),
            counter: 0,
            period_us: ((1e6 / config.rate_hz).round() as i64).max(1),
            next_due_us: None,
        })
    }

    /// Send one frame now (one or more datagrams); returns the number of datagrams sent.
    /// The counter advances even when sending fails, so a receiver never sees a reused counter.
    pub fn send(&mut self, vehicles: &[VizVehicle]) -> Result<usize, VizError> {
        let counter = self.counter;
        self.counter += 1;
        let parts = self.encoder.encode(counter, vehicles);
        for part in parts {
            self.socket
                .send_to(part, self.target)
                .map_err(|source| VizError::Io { what: format!("send to {}", self.target), source })?;
        }
        Ok(parts.len())
    }

    /// Send a frame if one period (1 / rate) has passed since the last one sent by this method,
    /// `now_us` being the caller's clock [µs] (sim or wall time). Returns whether it sent.
    pub fn send_if_due(&mut self, now_us: i64, vehicles: &[VizVehicle]) -> Result<bool, VizError> {
        if self.next_due_us.is_some_and(|due| now_us < due) {
            return Ok(false);
        }
        let base = self.next_due_us.unwrap_or(now_us);
        // Keep a fixed cadence; after a long pause, restart from now instead of bursting.
        let start = if now_us.saturating_sub(base) >= self.period_us { now_us } else { base };
        self.next_due_us = Some(start.saturating_add(self.period_us));
        self.send(vehicles)?;
        Ok(true)
    }

    /// Counter the next frame will carry.
    pub fn next_counter(&self) -> u64 {
        self.counter
    }

    /// Period between frames for [`Self::send_if_due`] [µs].
    pub fn period_us(&self) -> i64 {
        self.period_us
    }
}

#[derive(Debug, Default)]
struct Shared {
    latest: Option<VizFrame>,
    stats: VizStats,
}

/// Receives the visualisation stream on a background thread; keeps the newest complete frame.
/// Bad datagrams are counted and logged, never fatal. Dropping the receiver stops the thread.
#[derive(Debug)]
pub struct VizReceiver {
    shared: Arc<(Mutex<Shared>, Condvar)>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    local_addr: SocketAddr,
}

/// How often the receiving thread checks whether it should stop.
const RECV_POLL: Duration = Duration::from_millis(50);

impl VizReceiver {
    /// Bind `addr` (e.g. 127.0.0.1:38008, or port 0 for any) and start receiving.
    pub fn bind(addr: SocketAddr) -> Result<Self, VizError> {
        let io = |what: String| move |source| VizError::Io { what, source };
        let socket = bind_with_big_buffer(addr).map_err(io(format!("bind {addr}")))?;
        socket.set_read_timeout(Some(RECV_POLL)).map_err(io("set read timeout".into()))?;
        let local_addr = socket.local_addr().map_err(io("local address".into()))?;
        let shared = Arc::new((Mutex::new(Shared::default()), Condvar::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (shared, stop) = (shared.clone(), stop.clone());
            std::thread::Builder::new()
                .name("viz-receiver".into())
                .spawn(move || receive_loop(&socket, &shared, &stop))
                .map_err(io("spawn receiver thread".into()))?
        };
        Ok(Self { shared, stop, thread: Some(thread), local_addr })
    }

    /// The address actually bound (useful with port 0).
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// The newest complete frame, if any.
    pub fn latest(&self) -> Option<VizFrame> {
        lock(&self.shared.0).latest.clone()
    }

    /// Wait up to `timeout` for a frame with a counter newer than `after` (`None`: any frame).
    pub fn wait_newer(&self, after: Option<u64>, timeout: Duration) -> Option<VizFrame> {
        let deadline = Instant::now() + timeout;
        let mut guard = lock(&self.shared.0);
        loop {
            if let Some(f) = &guard.latest
                && after.is_none_or(|a| f.counter > a)
            {
                return Some(f.clone());
            }
            let left = deadline.checked_duration_since(Instant::now())?;
            guard = match self.shared.1.wait_timeout(guard, left) {
                Ok((g, _)) => g,
                Err(poisoned) => poisoned.into_inner().0,
            };
        }
    }

    /// Counters of what was received.
    pub fn stats(&self) -> VizStats {
        lock(&self.shared.0).stats
    }

    /// Whether the receiving thread is still running.
    pub fn is_running(&self) -> bool {
        self.thread.as_ref().is_some_and(|t| !t.is_finished())
    }
}

impl Drop for VizReceiver {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Receive buffer asked for [bytes]: a split frame arrives as a burst of up to hundreds of
/// datagrams, more than the usual 208 KiB default holds. The kernel may grant less.
pub const RECV_BUFFER_LEN: usize = 4 << 20;

/// Bind a UDP socket with a receive buffer of [`RECV_BUFFER_LEN`] (or what the system allows).
fn bind_with_big_buffer(addr: SocketAddr) -> std::io::Result<UdpSocket> {
    use socket2::{Domain, Protocol, Socket, Type};
    let socket = Socket::new(Domain::for_address(addr), Type::DGRAM, Some(Protocol::UDP))?;
    if let Err(e) = socket.set_recv_buffer_size(RECV_BUFFER_LEN) {
        tracing::warn!("visualisation receiver: cannot enlarge the receive buffer ({e}); big frames may be lost");
    }
    socket.bind(&addr.into())?;
    Ok(socket.into())
}

fn receive_loop(socket: &UdpSocket, shared: &(Mutex<Shared>, Condvar), stop: &AtomicBool) {
    // Bigger than MAX_DATAGRAM_LEN so datagrams from newer senders are read whole.
    let mut buf = vec![0u8; 65536];
    let mut reassembler = VizReassembler::new();
    while !stop.load(Ordering::Relaxed) {
        match socket.recv_from(&mut buf) {
            Ok((n, _)) => {
                let frame = reassembler.push_bytes(&buf[..n]);
                let mut s = lock(&shared.0);
                s.stats = reassembler.stats();
                if let Some(f) = frame {
                    s.latest = Some(f);
                    shared.1.notify_all();
                }
            }
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
            Err(e) => {
                tracing::warn!("visualisation receiver: {e}");
                std::thread::sleep(RECV_POLL);
            }
        }
    }
}
