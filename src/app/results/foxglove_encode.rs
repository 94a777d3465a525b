//! The per-tick messages of the Foxglove profile (issue 57), encoded by hand into a reused
//! buffer: `/vehicles` (`foxglove.SceneUpdate`), `/tf` (`foxglove.FrameTransforms`),
//! `/gps/<id>` (`foxglove.LocationFix`) and `/vehicle/<id>/state` (JSON). These are most of a
//! recording's bytes (about 600 per vehicle and log tick); building the SDK's message structs
//! for them (a `String` per id, a `Vec` per primitive) and encoding those took more of the
//! recorder's time than zstd. The bytes are those prost writes for the same structs (fields in
//! field-number order, proto3 defaults left out; the tests compare them byte for byte with the
//! SDK's encoding), so every reader of the Foxglove schemas decodes them.
//!
//! Wire format: <https://protobuf.dev/programming-guides/encoding/>; field numbers from the
//! Foxglove schemas (<https://docs.foxglove.dev/docs/sdk/schemas>, the `foxglove` crate's
//! `messages`). Also `/map` (once, with the SDK's structs).

use glam::DVec2;

use super::output::{ANGLE_DECIMALS, Fixed, LENGTH_DECIMALS, TIME_DECIMALS};
use super::snapshot::{Snapshot, VehicleSnapshot};
use crate::map::LaneletMap;
use crate::world::TurnSignal;
use foxglove::messages::{LinePrimitive, Point3, Pose, SceneEntity, SceneUpdate};

/// Height of the vehicle cubes \[m\] (the map is flat; a box reads better in 3D than a plate).
pub const CUBE_HEIGHT: f64 = 1.5;

/// Protobuf wire types.
const VARINT: u64 = 0;
const FIXED64: u64 = 1;
const LEN: u64 = 2;

fn varint(buf: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        buf.push((v as u8) | 0x80);
        v >>= 7;
    }
    buf.push(v as u8);
}

fn key(buf: &mut Vec<u8>, field: u64, wire: u64) {
    varint(buf, (field << 3) | wire);
}

/// A `double` field (left out when 0, as proto3 does).
fn double(buf: &mut Vec<u8>, field: u64, v: f64) {
    if v != 0.0 {
        double_always(buf, field, v);
    }
}

/// An `optional double` field that is set.
fn double_always(buf: &mut Vec<u8>, field: u64, v: f64) {
    key(buf, field, FIXED64);
    buf.extend_from_slice(&v.to_le_bytes());
}

fn boolean(buf: &mut Vec<u8>, field: u64, v: bool) {
    if v {
        key(buf, field, VARINT);
        buf.push(1);
    }
}

fn uint(buf: &mut Vec<u8>, field: u64, v: u64) {
    if v != 0 {
        key(buf, field, VARINT);
        varint(buf, v);
    }
}

fn bytes(buf: &mut Vec<u8>, field: u64, s: &[u8]) {
    if !s.is_empty() {
        key(buf, field, LEN);
        varint(buf, s.len() as u64);
        buf.extend_from_slice(s);
    }
}

/// A nested message written by `body`, preceded by its length (one byte reserved, the rest
/// made room for when it is longer than 127 bytes).
fn message(buf: &mut Vec<u8>, field: u64, body: impl FnOnce(&mut Vec<u8>)) {
    key(buf, field, LEN);
    let at = buf.len();
    buf.push(0);
    body(buf);
    let len = buf.len() - at - 1;
    if len < 0x80 {
        buf[at] = len as u8;
    } else {
        // A longer length: move the body up by the extra bytes (no allocation).
        let (mut head, mut n, mut v) = ([0u8; 10], 0, len as u64);
        while v >= 0x80 {
            head[n] = (v as u8) | 0x80;
            v >>= 7;
            n += 1;
        }
        head[n] = v as u8;
        n += 1;
        buf.resize(buf.len() + n - 1, 0);
        buf.copy_within(at + 1..at + 1 + len, at + n);
        buf[at..at + n].copy_from_slice(&head[..n]);
    }
}

/// `google.protobuf.Timestamp`-like `foxglove` timestamp of sim time `t_us` \[µs\].
fn timestamp(buf: &mut Vec<u8>, field: u64, t_us: u64) {
    message(buf, field, |b| {
        uint(b, 1, t_us / 1_000_000);
        uint(b, 2, (t_us % 1_000_000) * 1000);
    });
}

fn vector3(buf: &mut Vec<u8>, field: u64, x: f64, y: f64, z: f64) {
    message(buf, field, |b| {
        double(b, 1, x);
        double(b, 2, y);
        double(b, 3, z);
    });
}

/// A rotation about z by `yaw` \[rad\].
fn yaw_quaternion(buf: &mut Vec<u8>, field: u64, yaw: f64) {
    let (s, c) = (yaw * 0.5).sin_cos();
    message(buf, field, |b| {
        double(b, 3, s);
        double(b, 4, c);
    });
}

fn pose(buf: &mut Vec<u8>, field: u64, z: f64, yaw: f64) {
    message(buf, field, |b| {
        vector3(b, 1, 0.0, 0.0, z);
        yaw_quaternion(b, 2, yaw);
    });
}

fn color(buf: &mut Vec<u8>, field: u64, rgba: [u8; 4], alpha: f64) {
    message(buf, field, |b| {
        double(b, 1, rgba[0] as f64 / 255.0);
        double(b, 2, rgba[1] as f64 / 255.0);
        double(b, 3, rgba[2] as f64 / 255.0);
        double(b, 4, alpha);
    });
}

/// Decimal digits of `v` into `buf`.
pub fn push_int(buf: &mut Vec<u8>, v: i64) {
    if v < 0 {
        buf.push(b'-');
    }
    buf.extend_from_slice(decimal(v.unsigned_abs(), &mut [0u8; 20]));
}

/// The decimal digits of `n`, written at the end of `digits`.
fn decimal(mut n: u64, digits: &mut [u8; 20]) -> &[u8] {
    let mut i = digits.len();
    loop {
        i -= 1;
        digits[i] = b'0' + (n % 10) as u8;
        n /= 10;
        if n == 0 {
            break;
        }
    }
    &digits[i..]
}

/// A vehicle's entity id and frame, `vehicle/<id>`, written on the stack.
#[derive(Default)]
struct Name {
    bytes: [u8; 24],
}

impl Name {
    /// `vehicle/<id>`.
    fn vehicle(&mut self, id: i32) -> &[u8] {
        const PREFIX: &[u8] = b"vehicle/";
        self.bytes[..PREFIX.len()].copy_from_slice(PREFIX);
        let mut n = PREFIX.len();
        if id < 0 {
            self.bytes[n] = b'-';
            n += 1;
        }
        let mut space = [0u8; 20];
        let digits = decimal(u64::from(id.unsigned_abs()), &mut space);
        let len = digits.len();
        self.bytes[n..n + len].copy_from_slice(digits);
        &self.bytes[..n + len]
    }
}

/// A number as JSON rounded to `decimals` (at most 9), written as an integer and its decimals
/// (`12.500`, `-0.250`): `null` when not finite, [`Fixed`] beyond 1e12.
pub fn push_json_num(buf: &mut Vec<u8>, x: f64, decimals: usize) {
    let decimals = decimals.min(9);
    if !x.is_finite() {
        buf.extend_from_slice(b"null");
        return;
    }
    if x.abs() >= 1e12 {
        use std::io::Write as _;
        let _ = write!(buf, "{}", Fixed(x, decimals));
        return;
    }
    let scale = 10u64.pow(decimals as u32);
    let units = (x.abs() * scale as f64).round() as u64;
    if x < 0.0 && units != 0 {
        buf.push(b'-');
    }
    push_int(buf, (units / scale) as i64);
    if decimals > 0 {
        buf.push(b'.');
        let start = buf.len();
        push_int(buf, (units % scale) as i64);
        let written = buf.len() - start;
        // Zero-pad the decimals on the left.
        let pad = decimals - written;
        buf.splice(start..start, std::iter::repeat_n(b'0', pad));
    }
}

/// The `/vehicles` scene of one tick into `buf` (cleared): deletions of the vehicles of
/// `previous` (ascending ids) that left, then per vehicle a cube of its size and class colour,
/// its velocity as an arrow, its id as text, the indicator while changing lanes.
pub fn vehicles_scene(buf: &mut Vec<u8>, snapshot: &Snapshot, previous: &[(i32, TurnSignal, &'static str)]) {
    buf.clear();
    let t_us = snapshot.t_us;
    let mut name = Name::default();
    let mut i = 0;
    for &(id, _, _) in previous {
        while i < snapshot.vehicles.len() && snapshot.vehicles[i].id < id {
            i += 1;
        }
        if snapshot.vehicles.get(i).is_none_or(|v| v.id != id) {
            // SceneEntityDeletion: timestamp 1, type 2 (MATCHING_ID = 0, left out), id 3.
            message(buf, 1, |b| {
                timestamp(b, 1, t_us);
                bytes(b, 3, name.vehicle(id));
            });
        }
    }
    for v in &snapshot.vehicles {
        message(buf, 2, |b| vehicle_entity(b, t_us, v, &mut name));
    }
}

/// One vehicle's `foxglove.SceneEntity` (fields in number order).
fn vehicle_entity(b: &mut Vec<u8>, t_us: u64, v: &VehicleSnapshot, name: &mut Name) {
    timestamp(b, 1, t_us);
    let name = name.vehicle(v.id);
    bytes(b, 2, name); // frame_id
    bytes(b, 3, name); // id
    boolean(b, 5, true); // frame_locked
    let speed = v.velocity.length();
    if speed > 0.01 {
        // ArrowPrimitive (7), in the vehicle's frame: along its velocity relative to its heading.
        let heading = v.velocity.y.atan2(v.velocity.x) - v.yaw;
        message(b, 7, |a| {
            pose(a, 1, CUBE_HEIGHT + 0.2, heading);
            double(a, 2, speed * 0.5); // shaft_length: 0.5 s of travel
            double(a, 3, 0.15);
            double(a, 4, 0.6);
            double(a, 5, 0.5);
            color(a, 6, [30, 30, 30, 255], 1.0);
        });
    }
    let rgba = crate::render::class_color(v.class.name());
    // CubePrimitive (8): pose 1, size 2, color 3.
    message(b, 8, |c| {
        pose(c, 1, CUBE_HEIGHT * 0.5, 0.0);
        vector3(c, 2, v.length, v.width, CUBE_HEIGHT);
        color(c, 3, rgba, if v.real { 1.0 } else { 0.6 });
    });
    let side = match v.signal {
        TurnSignal::Left => Some(1.0),
        TurnSignal::Right => Some(-1.0),
        TurnSignal::Off => None,
    };
    if let Some(side) = side {
        // Amber lamps at the front and rear corners of the indicating side.
        for x in [v.length * 0.5, -v.length * 0.5] {
            message(b, 8, |c| {
                message(c, 1, |p| {
                    vector3(p, 1, x, side * v.width * 0.5, CUBE_HEIGHT * 0.5);
                    yaw_quaternion(p, 2, 0.0);
                });
                vector3(c, 2, 0.4, 0.3, 0.4);
                color(c, 3, [255, 160, 0, 255], 1.0);
            });
        }
    }
    // TextPrimitive (13): pose 1, billboard 2, font_size 3, scale_invariant 4, color 5, text 6.
    message(b, 13, |t| {
        pose(t, 1, CUBE_HEIGHT + 1.0, 0.0);
        boolean(t, 2, true);
        double(t, 3, 14.0);
        boolean(t, 4, true);
        color(t, 5, [255, 255, 255, 255], 1.0);
        let digits = &name[b"vehicle/".len()..];
        bytes(t, 6, digits);
    });
}

/// The `/tf` message of one tick into `buf` (cleared): `world` -> `vehicle/<id>` per vehicle,
/// with `world` -> `map` first when `with_map`.
pub fn frame_transforms(buf: &mut Vec<u8>, snapshot: &Snapshot, with_map: bool) {
    buf.clear();
    let t_us = snapshot.t_us;
    // FrameTransform: timestamp 1, parent 2, child 3, translation 4, rotation 5.
    let transform = |buf: &mut Vec<u8>, child: &[u8], p: DVec2, yaw: f64| {
        message(buf, 1, |b| {
            timestamp(b, 1, t_us);
            bytes(b, 2, b"world");
            bytes(b, 3, child);
            vector3(b, 4, p.x, p.y, 0.0);
            yaw_quaternion(b, 5, yaw);
        });
    };
    if with_map {
        transform(buf, b"map", DVec2::ZERO, 0.0);
    }
    let mut name = Name::default();
    for v in &snapshot.vehicles {
        transform(buf, name.vehicle(v.id), v.position, v.yaw);
    }
}

/// A vehicle's `/gps/<id>` `foxglove.LocationFix` at `t_us` into `buf` (cleared): latitude,
/// longitude \[deg\] and heading (clockwise from north \[deg\], as NMEA gives it).
pub fn location_fix(buf: &mut Vec<u8>, t_us: u64, id: i32, lat: f64, lon: f64, yaw: f64) {
    buf.clear();
    let mut name = Name::default();
    // Fields in number order, as prost writes them: latitude 1, longitude 2, (altitude 3,
    // covariance 4 and 5: zero), timestamp 6, frame_id 7, heading 10.
    double(buf, 1, lat);
    double(buf, 2, lon);
    timestamp(buf, 6, t_us);
    bytes(buf, 7, name.vehicle(id));
    double_always(buf, 10, (90.0 - yaw.to_degrees()).rem_euclid(360.0));
}

/// A vehicle's `/vehicle/<id>/state` JSON at `t_us` into `buf` (cleared), with the precision of
/// trajectories.csv (1 mm, 1e-5 rad, 1 µs).
pub fn state_json(buf: &mut Vec<u8>, t_us: u64, v: &VehicleSnapshot) {
    buf.clear();
    buf.extend_from_slice(b"{\"t\":");
    push_json_num(buf, t_us as f64 * 1e-6, TIME_DECIMALS);
    buf.extend_from_slice(b",\"x\":");
    push_json_num(buf, v.position.x, LENGTH_DECIMALS);
    buf.extend_from_slice(b",\"y\":");
    push_json_num(buf, v.position.y, LENGTH_DECIMALS);
    buf.extend_from_slice(b",\"yaw\":");
    push_json_num(buf, v.yaw, ANGLE_DECIMALS);
    buf.extend_from_slice(b",\"speed\":");
    push_json_num(buf, v.velocity.length(), LENGTH_DECIMALS);
    buf.extend_from_slice(b",\"accel\":");
    push_json_num(buf, v.accel, LENGTH_DECIMALS);
    buf.extend_from_slice(b",\"lanelet\":");
    match v.lanelet {
        Some(l) => push_int(buf, l),
        None => buf.extend_from_slice(b"null"),
    }
    buf.extend_from_slice(b",\"lane_offset\":");
    push_json_num(buf, v.lane_offset.unwrap_or(f64::NAN), LENGTH_DECIMALS);
    buf.extend_from_slice(b",\"mode\":\"");
    buf.extend_from_slice(v.mode.as_bytes());
    buf.extend_from_slice(b"\"}");
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

fn sdk_color(rgba: [u8; 4], alpha: f64) -> foxglove::messages::Color {
    foxglove::messages::Color {
        r: rgba[0] as f64 / 255.0,
        g: rgba[1] as f64 / 255.0,
        b: rgba[2] as f64 / 255.0,
        a: alpha,
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
    let identity = foxglove::messages::Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.0 };
    let origin = foxglove::messages::Vector3 { x: 0.0, y: 0.0, z: 0.0 };
    let line = |points: Vec<Point3>, thickness: f64, rgba: [u8; 4]| LinePrimitive {
        r#type: foxglove::messages::line_primitive::Type::LineList as i32,
        pose: Some(Pose { position: Some(origin), orientation: Some(identity) }),
        thickness,
        scale_invariant: false,
        points,
        color: Some(sdk_color(rgba, 1.0)),
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
            timestamp: Some(foxglove::messages::Timestamp::new(0, 0)),
            frame_id: "map".into(),
            id: "map".into(),
            frame_locked: true,
            lines,
            ..Default::default()
        }],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::VehicleClass;
    use foxglove::Encode;
    use foxglove::messages::{
        ArrowPrimitive, Color, CubePrimitive, FrameTransform, FrameTransforms, LocationFix, Quaternion,
        SceneEntityDeletion, TextPrimitive, Timestamp, Vector3,
    };

    fn stamp(t_us: u64) -> Timestamp {
        Timestamp::new((t_us / 1_000_000) as u32, ((t_us % 1_000_000) * 1000) as u32)
    }

    fn vec3(x: f64, y: f64, z: f64) -> Option<Vector3> {
        Some(Vector3 { x, y, z })
    }

    fn quat(yaw: f64) -> Option<Quaternion> {
        let (s, c) = (yaw * 0.5).sin_cos();
        Some(Quaternion { x: 0.0, y: 0.0, z: s, w: c })
    }

    fn col(rgba: [u8; 4], a: f64) -> Option<Color> {
        Some(sdk_color(rgba, a))
    }

    fn sdk_bytes(m: &impl Encode) -> Vec<u8> {
        let mut out = Vec::new();
        m.encode(&mut out).expect("encodes");
        out
    }

    /// The `/vehicles` scene built with the SDK's structs, as the recorder wrote it before the
    /// hand encoding (the reference the bytes are compared with).
    fn sdk_scene(snapshot: &Snapshot, previous: &[i32]) -> SceneUpdate {
        let ts = stamp(snapshot.t_us);
        let deletions = previous
            .iter()
            .filter(|id| !snapshot.vehicles.iter().any(|v| v.id == **id))
            .map(|id| SceneEntityDeletion { timestamp: Some(ts), r#type: 0, id: format!("vehicle/{id}") })
            .collect();
        let entities = snapshot
            .vehicles
            .iter()
            .map(|v| {
                let speed = v.velocity.length();
                let heading = v.velocity.y.atan2(v.velocity.x) - v.yaw;
                let arrows = if speed > 0.01 {
                    vec![ArrowPrimitive {
                        pose: Some(Pose { position: vec3(0.0, 0.0, CUBE_HEIGHT + 0.2), orientation: quat(heading) }),
                        shaft_length: speed * 0.5,
                        shaft_diameter: 0.15,
                        head_length: 0.6,
                        head_diameter: 0.5,
                        color: col([30, 30, 30, 255], 1.0),
                    }]
                } else {
                    Vec::new()
                };
                let mut cubes = vec![CubePrimitive {
                    pose: Some(Pose { position: vec3(0.0, 0.0, CUBE_HEIGHT * 0.5), orientation: quat(0.0) }),
                    size: vec3(v.length, v.width, CUBE_HEIGHT),
                    color: col(crate::render::class_color(v.class.name()), if v.real { 1.0 } else { 0.6 }),
                }];
                if v.signal != TurnSignal::Off {
                    let side = if v.signal == TurnSignal::Left { 1.0 } else { -1.0 };
                    for x in [v.length * 0.5, -v.length * 0.5] {
                        cubes.push(CubePrimitive {
                            pose: Some(Pose {
                                position: vec3(x, side * v.width * 0.5, CUBE_HEIGHT * 0.5),
                                orientation: quat(0.0),
                            }),
                            size: vec3(0.4, 0.3, 0.4),
                            color: col([255, 160, 0, 255], 1.0),
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
                        pose: Some(Pose { position: vec3(0.0, 0.0, CUBE_HEIGHT + 1.0), orientation: quat(0.0) }),
                        billboard: true,
                        font_size: 14.0,
                        scale_invariant: true,
                        color: col([255, 255, 255, 255], 1.0),
                        text: v.id.to_string(),
                    }],
                    ..Default::default()
                }
            })
            .collect();
        SceneUpdate { deletions, entities }
    }

    fn vehicle(id: i32, x: f64, signal: TurnSignal) -> VehicleSnapshot {
        VehicleSnapshot {
            id,
            position: DVec2::new(x, -3.25),
            yaw: 0.3 * id as f64,
            velocity: DVec2::new(12.0, 0.5 * id as f64),
            accel: -0.5,
            lanelet: Some(7),
            lane_offset: Some(0.12),
            length: 4.5,
            width: 1.8,
            class: if id % 2 == 0 { VehicleClass::Car } else { VehicleClass::Truck },
            real: id < 0,
            signal,
            mode: "following",
        }
    }

    fn snapshot() -> Snapshot {
        let mut parked = vehicle(4, 1000.0, TurnSignal::Off);
        parked.velocity = DVec2::ZERO;
        Snapshot {
            // 12.3456 s: a timestamp with both seconds and nanoseconds.
            t_us: 12_345_600,
            vehicles: vec![
                vehicle(-1, 0.0, TurnSignal::Off),
                vehicle(1, 55.5, TurnSignal::Left),
                vehicle(3, -20.0, TurnSignal::Right),
                parked,
                vehicle(123_456, 1.0e5, TurnSignal::Off),
            ],
        }
    }

    #[test]
    fn vehicles_scene_is_the_sdks_encoding_byte_for_byte() {
        let s = snapshot();
        let previous: Vec<(i32, TurnSignal, &'static str)> =
            [-2, -1, 1, 2, 3, 4, 9, 123_456, 200_000].iter().map(|&id| (id, TurnSignal::Off, "none")).collect();
        let mut buf = Vec::new();
        vehicles_scene(&mut buf, &s, &previous);
        let ids: Vec<i32> = previous.iter().map(|p| p.0).collect();
        let reference = sdk_scene(&s, &ids);
        assert_eq!(reference.deletions.len(), 4);
        assert_eq!(buf, sdk_bytes(&reference));
        // And it reads back as the same message.
        let decoded = <SceneUpdate as foxglove::Decode>::decode(&buf[..]).expect("decodes");
        assert_eq!(decoded, reference);
    }

    #[test]
    fn departed_vehicles_are_deleted() {
        let s =
            Snapshot { t_us: 100, vehicles: vec![vehicle(1, 0.0, TurnSignal::Off), vehicle(3, 0.0, TurnSignal::Off)] };
        let previous = [(0, TurnSignal::Off, "none"), (1, TurnSignal::Off, "none"), (2, TurnSignal::Off, "none")];
        let mut buf = Vec::new();
        vehicles_scene(&mut buf, &s, &previous);
        let scene = <SceneUpdate as foxglove::Decode>::decode(&buf[..]).expect("decodes");
        let gone: Vec<&str> = scene.deletions.iter().map(|d| d.id.as_str()).collect();
        assert_eq!(gone, vec!["vehicle/0", "vehicle/2"]);
        assert_eq!(scene.entities.len(), 2);
    }

    #[test]
    fn transforms_and_location_fixes_are_the_sdks_encoding() {
        let s = snapshot();
        let mut buf = Vec::new();
        for with_map in [false, true] {
            frame_transforms(&mut buf, &s, with_map);
            let mut transforms = Vec::new();
            let t = |child: String, p: DVec2, yaw: f64| FrameTransform {
                timestamp: Some(stamp(s.t_us)),
                parent_frame_id: "world".into(),
                child_frame_id: child,
                translation: vec3(p.x, p.y, 0.0),
                rotation: quat(yaw),
            };
            if with_map {
                transforms.push(t("map".into(), DVec2::ZERO, 0.0));
            }
            transforms.extend(s.vehicles.iter().map(|v| t(format!("vehicle/{}", v.id), v.position, v.yaw)));
            assert_eq!(buf, sdk_bytes(&FrameTransforms { transforms }), "with_map {with_map}");
        }
        let v = &s.vehicles[1];
        location_fix(&mut buf, s.t_us, v.id, 57.7, 11.97, v.yaw);
        let fix = LocationFix {
            timestamp: Some(stamp(s.t_us)),
            frame_id: "vehicle/1".into(),
            latitude: 57.7,
            longitude: 11.97,
            heading: Some((90.0 - v.yaw.to_degrees()).rem_euclid(360.0)),
            ..Default::default()
        };
        assert_eq!(buf, sdk_bytes(&fix));
        // Heading due north (yaw pi/2) is 0, not left out.
        location_fix(&mut buf, 0, 5, 1.0, 2.0, std::f64::consts::FRAC_PI_2);
        let decoded = <LocationFix as foxglove::Decode>::decode(&buf[..]).expect("decodes");
        assert_eq!(decoded.heading.map(|h| h.abs() < 1e-9 || (h - 360.0).abs() < 1e-9), Some(true));
    }

    #[test]
    fn json_numbers_are_rounded_to_their_unit() {
        let text = |x: f64, d: usize| {
            let mut buf = Vec::new();
            push_json_num(&mut buf, x, d);
            String::from_utf8(buf).unwrap()
        };
        assert_eq!(text(12.5, 3), "12.500");
        assert_eq!(text(-0.25, 3), "-0.250");
        assert_eq!(text(-0.0001, 3), "0.000");
        assert_eq!(text(1.0 / 3.0, 5), "0.33333");
        assert_eq!(text(3.000_04, 5), "3.00004");
        assert_eq!(text(f64::NAN, 3), "null");
        assert_eq!(text(7.0, 0), "7");
        assert_eq!(text(-1234.5678, 3), "-1234.568");
    }

    #[test]
    fn the_state_is_json_with_every_field() {
        let mut v = vehicle(-1, 1.0, TurnSignal::Off);
        v.lanelet = None;
        v.accel = f64::NAN;
        let mut buf = Vec::new();
        state_json(&mut buf, 1_500_000, &v);
        let parsed: serde_json::Value = serde_json::from_slice(&buf).expect("valid JSON");
        assert_eq!(parsed["t"], serde_json::json!(1.5));
        assert_eq!(parsed["x"], serde_json::json!(1.0));
        assert_eq!(parsed["y"], serde_json::json!(-3.25));
        assert_eq!(parsed["speed"], serde_json::json!(12.01));
        assert!(parsed["accel"].is_null() && parsed["lanelet"].is_null());
        assert_eq!(parsed["lane_offset"], serde_json::json!(0.12));
        assert_eq!(parsed["mode"], "following");
    }

    #[test]
    fn dashes_are_half_paint_half_gap_across_points() {
        let mut out = Vec::new();
        dash(&[DVec2::ZERO, DVec2::new(4.0, 0.0), DVec2::new(12.0, 0.0)], 6.0, &mut out);
        let xs: Vec<f64> = out.iter().map(|p| p.x).collect();
        // Paint 0-3, gap 3-6, paint 6-9, gap 9-12 (the first paint split at no point).
        assert_eq!(xs, vec![0.0, 3.0, 6.0, 9.0]);
    }
}
