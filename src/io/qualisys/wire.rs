//! QTM real-time wire format: packet header and types, framing of a byte stream with a bound on
//! size fields, parsing and encoding of 6DOF Euler data frames, and the protocol's errors.

/// Packet header length \[bytes\]: size and type.
pub const HEADER_LEN: usize = 8;
/// Default bound on a packet's size field \[bytes\]; anything larger is refused unread.
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
    /// 0-based index of the body in QTM's body list (see [`Body6DEuler::number`]).
    pub index: u32,
    /// Position \[mm\].
    pub x_mm: f32,
    /// Position \[mm\].
    pub y_mm: f32,
    /// Position \[mm\].
    pub z_mm: f32,
    /// First Euler angle \[degrees\].
    pub roll_deg: f32,
    /// Second Euler angle \[degrees\].
    pub pitch_deg: f32,
    /// Third Euler angle, used as yaw \[degrees\].
    pub yaw_deg: f32,
}

impl Body6DEuler {
    /// QTM's body number, 1-based as QTM numbers its bodies (body 1 is the first 6DOF body):
    /// what `[lab] bodies` and the identity mapping name.
    pub fn number(&self) -> u32 {
        self.index + 1
    }
}

/// A parsed data packet: its 6DOF Euler bodies.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DataFrame {
    /// Capture timestamp \[µs\].
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
