//! `--mcap-profile ros2` (issue 57 §3): the run as ROS 2 messages in CDR, the way `ros2 bag
//! record` writes MCAP, so `ros2 bag play` replays it into a ROS 2 system: `tf2_msgs/msg/TFMessage`
//! on `/tf`, `nav_msgs/msg/Odometry` on `/vehicle/<id>/odom`, `visualization_msgs/msg/MarkerArray`
//! on `/vehicles` and `/map`, `rosgraph_msgs/msg/Clock` on `/clock`. Message definitions are
//! those of ROS 2 Humble, embedded in each channel's schema (`ros2msg`).

use std::collections::BTreeMap;

use glam::DVec2;

use super::mcap_file::McapFile;

use super::snapshot::{Snapshot, VehicleSnapshot};
use crate::map::LaneletMap;
use crate::world::TurnSignal;

/// A CDR (little-endian, XCDR1) message being written: the 4-byte encapsulation header, then
/// fields aligned to their size from the end of the header.
struct Cdr(Vec<u8>);

impl Cdr {
    fn new() -> Cdr {
        Cdr(vec![0x00, 0x01, 0x00, 0x00])
    }
    fn align(&mut self, n: usize) {
        while !(self.0.len() - 4).is_multiple_of(n) {
            self.0.push(0);
        }
    }
    fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    fn i32(&mut self, v: i32) {
        self.align(4);
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.align(4);
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f32(&mut self, v: f32) {
        self.align(4);
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.align(8);
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.0.extend_from_slice(s.as_bytes());
        self.0.push(0);
    }
    fn time(&mut self, t_us: u64) {
        self.i32((t_us / 1_000_000) as i32);
        self.u32(((t_us % 1_000_000) * 1000) as u32);
    }
    fn header(&mut self, t_us: u64, frame: &str) {
        self.time(t_us);
        self.string(frame);
    }
    fn point(&mut self, x: f64, y: f64, z: f64) {
        self.f64(x);
        self.f64(y);
        self.f64(z);
    }
    fn yaw(&mut self, yaw: f64) {
        let (s, c) = (yaw * 0.5).sin_cos();
        self.f64(0.0);
        self.f64(0.0);
        self.f64(s);
        self.f64(c);
    }
}

const SEPARATOR: &str = "================================================================================\n";

const TIME: &str = "int32 sec\nuint32 nanosec\n";
const DURATION: &str = "int32 sec\nuint32 nanosec\n";
const HEADER: &str = "builtin_interfaces/Time stamp\nstring frame_id\n";
const VECTOR3: &str = "float64 x\nfloat64 y\nfloat64 z\n";
const POINT: &str = "float64 x\nfloat64 y\nfloat64 z\n";
const QUATERNION: &str = "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n";
const POSE: &str = "Point position\nQuaternion orientation\n";
const TRANSFORM: &str = "Vector3 translation\nQuaternion rotation\n";
const TRANSFORM_STAMPED: &str = "std_msgs/Header header\nstring child_frame_id\nTransform transform\n";
const TWIST: &str = "Vector3  linear\nVector3  angular\n";
const POSE_COV: &str = "Pose pose\nfloat64[36] covariance\n";
const TWIST_COV: &str = "Twist twist\nfloat64[36] covariance\n";
const COLOR: &str = "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n";
const COMPRESSED_IMAGE: &str = "std_msgs/Header header\nstring format\nuint8[] data\n";
const UV: &str = "float32 u\nfloat32 v\n";
const MESH_FILE: &str = "string filename\nuint8[] data\n";
const MARKER: &str = "int32 ARROW=0\nint32 CUBE=1\nint32 SPHERE=2\nint32 CYLINDER=3\nint32 LINE_STRIP=4\n\
int32 LINE_LIST=5\nint32 CUBE_LIST=6\nint32 SPHERE_LIST=7\nint32 POINTS=8\nint32 TEXT_VIEW_FACING=9\n\
int32 MESH_RESOURCE=10\nint32 TRIANGLE_LIST=11\nint32 ARROW_STRIP=12\nint32 ADD=0\nint32 MODIFY=0\n\
int32 DELETE=2\nint32 DELETEALL=3\nstd_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\n\
geometry_msgs/Pose pose\ngeometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\n\
builtin_interfaces/Duration lifetime\nbool frame_locked\ngeometry_msgs/Point[] points\n\
std_msgs/ColorRGBA[] colors\nstring texture_resource\nsensor_msgs/CompressedImage texture\n\
UVCoordinate[] uv_coordinates\nstring text\nstring mesh_resource\nMeshFile mesh_file\n\
bool mesh_use_embedded_materials\n";

/// A schema text: the message's own definition, then each dependency after a separator line.
fn definition(main: &str, deps: &[(&str, &str)]) -> String {
    let mut text = main.to_string();
    for (name, body) in deps {
        text.push_str(SEPARATOR);
        text.push_str("MSG: ");
        text.push_str(name);
        text.push('\n');
        text.push_str(body);
    }
    text
}

fn tf_schema() -> String {
    definition(
        "geometry_msgs/TransformStamped[] transforms\n",
        &[
            ("geometry_msgs/TransformStamped", TRANSFORM_STAMPED),
            ("std_msgs/Header", HEADER),
            ("builtin_interfaces/Time", TIME),
            ("geometry_msgs/Transform", TRANSFORM),
            ("geometry_msgs/Vector3", VECTOR3),
            ("geometry_msgs/Quaternion", QUATERNION),
        ],
    )
}

fn odometry_schema() -> String {
    definition(
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n\
         geometry_msgs/TwistWithCovariance twist\n",
        &[
            ("std_msgs/Header", HEADER),
            ("builtin_interfaces/Time", TIME),
            ("geometry_msgs/PoseWithCovariance", POSE_COV),
            ("geometry_msgs/Pose", POSE),
            ("geometry_msgs/Point", POINT),
            ("geometry_msgs/Quaternion", QUATERNION),
            ("geometry_msgs/TwistWithCovariance", TWIST_COV),
            ("geometry_msgs/Twist", TWIST),
            ("geometry_msgs/Vector3", VECTOR3),
        ],
    )
}

fn marker_array_schema() -> String {
    definition(
        "Marker[] markers\n",
        &[
            ("visualization_msgs/Marker", MARKER),
            ("std_msgs/Header", HEADER),
            ("builtin_interfaces/Time", TIME),
            ("geometry_msgs/Pose", POSE),
            ("geometry_msgs/Point", POINT),
            ("geometry_msgs/Quaternion", QUATERNION),
            ("geometry_msgs/Vector3", VECTOR3),
            ("std_msgs/ColorRGBA", COLOR),
            ("builtin_interfaces/Duration", DURATION),
            ("sensor_msgs/CompressedImage", COMPRESSED_IMAGE),
            ("visualization_msgs/UVCoordinate", UV),
            ("visualization_msgs/MeshFile", MESH_FILE),
        ],
    )
}

/// Marker types and actions of `visualization_msgs/msg/Marker`.
const CUBE: i32 = 1;
const LINE_LIST: i32 = 5;
const TEXT_VIEW_FACING: i32 = 9;
const ADD: i32 = 0;
const DELETE: i32 = 2;

/// One `visualization_msgs/Marker` into `c`.
#[allow(clippy::too_many_arguments)]
fn marker(
    c: &mut Cdr,
    t_us: u64,
    ns: &str,
    id: i32,
    kind: i32,
    action: i32,
    at: (DVec2, f64, f64),
    scale: [f64; 3],
    rgba: [f32; 4],
    points: &[DVec2],
    text: &str,
) {
    c.header(t_us, "world");
    c.string(ns);
    c.i32(id);
    c.i32(kind);
    c.i32(action);
    c.point(at.0.x, at.0.y, at.2);
    c.yaw(at.1);
    c.point(scale[0], scale[1], scale[2]);
    for v in rgba {
        c.f32(v);
    }
    c.time(0); // lifetime: forever
    c.u8(0); // frame_locked
    c.u32(points.len() as u32);
    for p in points {
        c.point(p.x, p.y, 0.0);
    }
    c.u32(0); // colors
    c.string(""); // texture_resource
    c.header(0, ""); // texture: header
    c.string(""); // texture: format
    c.u32(0); // texture: data
    c.u32(0); // uv_coordinates
    c.string(text);
    c.string(""); // mesh_resource
    c.string(""); // mesh_file: filename
    c.u32(0); // mesh_file: data
    c.u8(0); // mesh_use_embedded_materials
}

/// The ROS 2-profile channels of a recording (ids in its [`McapFile`]).
pub struct Ros2Channels {
    tf: u16,
    clock: u16,
    vehicles: u16,
    map: u16,
    odom_schema: String,
    odom: BTreeMap<i32, u16>,
    previous: Vec<i32>,
}

fn cdr_channel(file: &mut McapFile, topic: &str, name: &str, schema: &str) -> u16 {
    file.channel(topic, "cdr", Some((name, "ros2msg", schema.as_bytes())))
}

impl Ros2Channels {
    /// The channels in `file`.
    pub fn new(file: &mut McapFile) -> Ros2Channels {
        let markers = marker_array_schema();
        Ros2Channels {
            tf: cdr_channel(file, "/tf", "tf2_msgs/msg/TFMessage", &tf_schema()),
            clock: cdr_channel(
                file,
                "/clock",
                "rosgraph_msgs/msg/Clock",
                &definition("builtin_interfaces/Time clock\n", &[("builtin_interfaces/Time", TIME)]),
            ),
            vehicles: cdr_channel(file, "/vehicles", "visualization_msgs/msg/MarkerArray", &markers),
            map: cdr_channel(file, "/map", "visualization_msgs/msg/MarkerArray", &markers),
            odom_schema: odometry_schema(),
            odom: BTreeMap::new(),
            previous: Vec::new(),
        }
    }

    /// `/map` at t = 0: every lanelet bound as one LINE_LIST marker.
    pub fn record_map(&self, file: &mut McapFile, map: &LaneletMap) {
        let mut points = Vec::new();
        let mut seen = std::collections::BTreeSet::new();
        for l in &map.lanelets {
            for (way, bound) in [(l.left_way, &l.left), (l.right_way, &l.right)] {
                if seen.insert(way) {
                    for w in bound.windows(2) {
                        points.extend_from_slice(w);
                    }
                }
            }
        }
        let mut c = Cdr::new();
        c.u32(1);
        marker(
            &mut c,
            0,
            "map",
            0,
            LINE_LIST,
            ADD,
            (DVec2::ZERO, 0.0, 0.0),
            [0.2, 0.0, 0.0],
            [0.93, 0.75, 0.16, 1.0],
            &points,
            "",
        );
        file.write(self.map, 0, &c.0);
    }

    /// One log tick: `/clock`, `/tf`, `/vehicles` and each vehicle's `/vehicle/<id>/odom`.
    pub fn record(&mut self, file: &mut McapFile, snapshot: &Snapshot) {
        let t_us = snapshot.t_us;
        let t_ns = t_us * 1000;
        let mut c = Cdr::new();
        c.time(t_us);
        file.write(self.clock, t_ns, &c.0);

        let mut c = Cdr::new();
        c.u32(snapshot.vehicles.len() as u32);
        for v in &snapshot.vehicles {
            c.header(t_us, "world");
            c.string(&format!("vehicle/{}", v.id));
            c.point(v.position.x, v.position.y, 0.0);
            c.yaw(v.yaw);
        }
        file.write(self.tf, t_ns, &c.0);

        let gone: Vec<i32> = self
            .previous
            .iter()
            .copied()
            .filter(|id| snapshot.vehicles.binary_search_by_key(id, |v| v.id).is_err())
            .collect();
        let mut c = Cdr::new();
        c.u32((snapshot.vehicles.len() * 2 + gone.len() * 2) as u32);
        for v in &snapshot.vehicles {
            vehicle_markers(&mut c, t_us, v);
        }
        for &id in &gone {
            for ns in ["vehicles", "ids"] {
                marker(&mut c, t_us, ns, id, CUBE, DELETE, (DVec2::ZERO, 0.0, 0.0), [1.0; 3], [0.0; 4], &[], "");
            }
        }
        file.write(self.vehicles, t_ns, &c.0);
        self.previous.clear();
        self.previous.extend(snapshot.vehicles.iter().map(|v| v.id));

        for v in &snapshot.vehicles {
            let schema = &self.odom_schema;
            let channel = *self.odom.entry(v.id).or_insert_with(|| {
                cdr_channel(file, &format!("/vehicle/{}/odom", v.id), "nav_msgs/msg/Odometry", schema)
            });
            let mut c = Cdr::new();
            c.header(t_us, "world");
            c.string(&format!("vehicle/{}", v.id));
            c.point(v.position.x, v.position.y, 0.0);
            c.yaw(v.yaw);
            for _ in 0..36 {
                c.f64(0.0);
            }
            // Twist in the vehicle's frame: forward and leftward speed [m/s].
            let (s, co) = v.yaw.sin_cos();
            c.point(v.velocity.x * co + v.velocity.y * s, -v.velocity.x * s + v.velocity.y * co, 0.0);
            c.point(0.0, 0.0, 0.0);
            for _ in 0..36 {
                c.f64(0.0);
            }
            file.write(channel, t_ns, &c.0);
        }
    }
}

/// A vehicle's cube (class colour, opaque when real) and its id as text.
fn vehicle_markers(c: &mut Cdr, t_us: u64, v: &VehicleSnapshot) {
    let rgba = crate::render::class_color(v.class.name());
    let mut color =
        [rgba[0] as f32 / 255.0, rgba[1] as f32 / 255.0, rgba[2] as f32 / 255.0, if v.real { 1.0 } else { 0.6 }];
    if v.signal != TurnSignal::Off {
        // Changing lanes: amber.
        color = [1.0, 0.63, 0.0, color[3]];
    }
    marker(c, t_us, "vehicles", v.id, CUBE, ADD, (v.position, v.yaw, 0.75), [v.length, v.width, 1.5], color, &[], "");
    marker(
        c,
        t_us,
        "ids",
        v.id,
        TEXT_VIEW_FACING,
        ADD,
        (v.position, 0.0, 2.5),
        [0.0, 0.0, 1.5],
        [1.0, 1.0, 1.0, 1.0],
        &[],
        &v.id.to_string(),
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cdr_aligns_from_the_end_of_the_encapsulation_header() {
        let mut c = Cdr::new();
        c.u8(1);
        c.f64(2.0); // 7 bytes of padding after the u8: offsets count from after the header
        c.string("ab"); // length 3 (with the NUL), then the bytes
        assert_eq!(&c.0[..4], &[0, 1, 0, 0]);
        assert_eq!(c.0.len(), 4 + 1 + 7 + 8 + 4 + 3);
        assert_eq!(&c.0[12..20], &2.0f64.to_le_bytes());
        assert_eq!(&c.0[20..27], &[3, 0, 0, 0, b'a', b'b', 0]);
    }

    #[test]
    fn schemas_name_every_dependency_once() {
        let text = marker_array_schema();
        for name in [
            "visualization_msgs/Marker",
            "std_msgs/Header",
            "sensor_msgs/CompressedImage",
            "visualization_msgs/MeshFile",
        ] {
            assert_eq!(text.matches(&format!("MSG: {name}\n")).count(), 1, "{name}");
        }
    }
}
