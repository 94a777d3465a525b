//! Text codec of the visualisation datagram: encoding frames (split into parts when too big),
//! decoding datagrams, and the errors of the visualisation stream.

use std::fmt::Write as _;
use std::io::Write as _;

use crate::world::TurnSignal;

/// Largest datagram the encoder emits \[bytes\]: the 2015 receiver's buffer size.
pub const MAX_DATAGRAM_LEN: usize = 4096;
/// Key of the split extension: 0-based index of this part within its frame.
pub const PART_KEY: &str = "part";
/// Key of the split extension: number of parts of the frame.
pub const PARTS_KEY: &str = "parts";
/// Most parts a receiver accepts for one frame (bounds the memory a hostile sender can claim);
/// at about 70 vehicles per part, frames of up to roughly 280 000 vehicles.
pub const MAX_PARTS: u32 = 4096;
/// Longest class name sent \[bytes\]; longer names are cut.
pub const MAX_CLASS_NAME_LEN: usize = 64;

/// One vehicle as the visualisation stream carries it.
#[derive(Debug, Clone, PartialEq)]
pub struct VizVehicle {
    /// Vehicle id (non-negative: real vehicle, negative: virtual).
    pub id: i32,
    /// Position east \[m\].
    pub x: f64,
    /// Position north \[m\].
    pub y: f64,
    /// Heading, counter-clockwise from the x axis \[degrees\].
    pub yaw_deg: f64,
    /// Vehicle class shown by the viewer (e.g. `Truck`, `Car`).
    pub class_name: String,
    /// A lane change in progress: the side its indicator shows (key `indicator=left|right`,
    /// sent only when on and only in our stream format; the 2015 viewers never see it).
    pub indicator: TurnSignal,
}

/// What one signalised junction shows, as the lights extension carries it (see the module docs
/// of [`crate::io::viz`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VizLight {
    /// Junction id (from 1, as `smlworld map info` lists them).
    pub junction: u32,
    /// One signal character per link in link order (`G`, `g`, `y`, `r`, ...).
    pub state: String,
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

/// `v` rounded to `scale` (1000: 3 decimals), with -0 made 0: a value that rounds to zero from
/// below would otherwise print as `-0.000`, a sign that is not there (and a replay, reading the
/// run's CSV at 1 mm, would send `0.000` where the run sent `-0.000`).
fn rounded(v: f64, scale: f64) -> f64 {
    (v * scale).round() / scale + 0.0
}

fn write_record(out: &mut String, v: &VizVehicle) {
    let (x, y, yaw) = (rounded(v.x, 1e3), rounded(v.y, 1e3), rounded(v.yaw_deg, 1e2));
    let _ = write!(out, "id={};x={x:.3};y={y:.3};yaw={yaw:.2};class_name=", v.id);
    for c in v.class_name.chars().take(MAX_CLASS_NAME_LEN) {
        let ok = c.is_ascii_graphic() && !matches!(c, '#' | '!' | ';' | '=');
        out.push(if ok { c } else { '_' });
    }
    match v.indicator {
        TurnSignal::Left => out.push_str(";indicator=left"),
        TurnSignal::Right => out.push_str(";indicator=right"),
        TurnSignal::Off => {}
    }
}

/// First byte of a lights datagram (the lights extension): `L<counter>#<id>=<state>;...`.
pub const LIGHTS_PREFIX: u8 = b'L';

/// Whether `bytes` is a lights datagram (starts with [`LIGHTS_PREFIX`]).
pub fn is_lights_datagram(bytes: &[u8]) -> bool {
    bytes.first() == Some(&LIGHTS_PREFIX)
}

/// Encode the states of `lights` for the frame with `counter` into lights datagrams
/// (`L<counter>#<id>=<state>;<id>=<state>...`), each at most [`MAX_DATAGRAM_LEN`] bytes and each
/// complete on its own (a receiver merges them by junction id, so a lost one only delays those
/// junctions to the next frame). States are cut to the characters a state may hold (ASCII
/// letters); an empty list gives no datagram.
pub fn encode_lights(counter: u64, lights: &[VizLight], out: &mut Vec<Vec<u8>>) {
    out.clear();
    let mut buf = Vec::with_capacity(MAX_DATAGRAM_LEN);
    let mut record = String::new();
    for l in lights {
        record.clear();
        let _ = write!(record, "{}=", l.junction);
        record.extend(l.state.chars().filter(char::is_ascii_alphabetic).take(MAX_DATAGRAM_LEN / 2));
        if !buf.is_empty() && buf.len() + 1 + record.len() > MAX_DATAGRAM_LEN {
            out.push(std::mem::replace(&mut buf, Vec::with_capacity(MAX_DATAGRAM_LEN)));
        }
        if buf.is_empty() {
            let _ = write!(buf, "L{counter}#");
        } else {
            buf.push(b';');
        }
        buf.extend_from_slice(record.as_bytes());
    }
    if !buf.is_empty() {
        out.push(buf);
    }
}

/// Decode a lights datagram: its counter and the states it carries. Never panics; anything
/// malformed is an error naming the problem.
pub fn decode_lights(bytes: &[u8]) -> Result<(u64, Vec<VizLight>), VizError> {
    let text = std::str::from_utf8(bytes).map_err(|e| VizError::NotText { at: e.valid_up_to() })?;
    let Some((head, body)) = text.strip_prefix(LIGHTS_PREFIX as char).and_then(|t| t.split_once('#')) else {
        return Err(VizError::MissingHash { head: quote(text) });
    };
    let counter: u64 = head.trim().parse().map_err(|_| VizError::BadCounter { text: quote(head) })?;
    let mut lights = Vec::new();
    for (record, field) in body.split(';').enumerate() {
        if field.trim().is_empty() {
            continue;
        }
        let Some((id, state)) = field.split_once('=') else {
            return Err(VizError::MalformedField { record, field: quote(field) });
        };
        let junction = parse_value(record, "junction", id, "junction id")?;
        let state = state.trim();
        if state.is_empty() || !state.chars().all(|c| c.is_ascii_alphabetic()) {
            return Err(VizError::BadValue {
                record,
                key: "state",
                value: quote(state),
                expected: "signal state (letters such as GGrr)",
            });
        }
        lights.push(VizLight { junction, state: state.to_string() });
    }
    Ok((counter, lights))
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
    let mut indicator = None;
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
            "indicator" => set_once(&mut indicator, parse_value(record, "indicator", value, "left or right")?, dup)?,
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
        indicator: indicator.unwrap_or_default(),
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
