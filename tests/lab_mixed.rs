//! The lab bridges as plugins: `scenarios/lab_mixed.toml` against its in-process mock motion
//! capture (real time, 5 s), truck status lines, the visualisation stream, stale bodies.
//! Loopback only, ephemeral ports, bounded in time.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::net::{Ipv4Addr, SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use smlworld::app::{RealtimeRunner, RunSummary, Scenario};
use smlworld::io::lab::{MocapTrack, TruckBridge, VizStreamPlugin};
use smlworld::io::mock_mocap::{Keyframe, MocapScript, MockMocapConfig, MockMocapServer};
use smlworld::io::viz::VizReceiver;
use smlworld::world::VehicleId;

fn scenario_path() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/lab_mixed.toml"))
}

/// The shipped scenario with the truck servers on free ports (the file says 16000 + id).
fn lab_mixed_on_free_ports() -> Scenario {
    let text = std::fs::read_to_string(scenario_path()).expect("read scenarios/lab_mixed.toml");
    assert!(text.contains("base_port = 16000"), "the scenario should serve the trucks on 16000 + id");
    let text = text.replace("base_port = 16000", "base_port = 0");
    Scenario::parse_str(&text, &scenario_path()).expect("lab_mixed.toml parses and loads its map")
}

/// `time=<t>XcRtid=<id>,k=v,...` -> (id, fields), parsed from the format of the issue.
fn parse_truck_line(line: &str) -> (i32, BTreeMap<String, String>) {
    let rest = line.strip_prefix("time=").expect("line starts with time=");
    let (_, fields) = rest.split_once("XcRt").expect("XcRt separator");
    let mut map = BTreeMap::new();
    for kv in fields.trim_end().split(',') {
        let (k, v) = kv.split_once('=').expect("k=v");
        map.insert(k.to_string(), v.to_string());
    }
    let id = map["id"].parse().expect("integer id");
    (id, map)
}

#[test]
fn lab_mixed_tracks_the_real_trucks_and_virtual_vehicles_see_them() {
    let scenario = lab_mixed_on_free_ports();
    let mut builder = scenario.builder().expect("builder starts the mock server and truck servers");
    let viewer = VizReceiver::bind(SocketAddr::from((Ipv4Addr::LOCALHOST, 0))).expect("bind viz receiver");
    builder.add_plugin(VizStreamPlugin::new(viewer.local_addr(), 50.0).expect("stream"));
    let mut sim = builder.build();

    // A truck connects to vehicle 1's server and reads its lines while the run goes on.
    let addr = sim.world().resource::<TruckBridge>().server.local_addr(1).expect("truck 1 is served");
    let stop = Arc::new(AtomicBool::new(false));
    let reader = {
        let stop = stop.clone();
        std::thread::spawn(move || {
            let stream = TcpStream::connect(addr).expect("connect to truck 1's server");
            stream.set_read_timeout(Some(Duration::from_millis(200))).expect("timeout");
            let mut r = BufReader::new(stream);
            let mut lines = Vec::new();
            while !stop.load(Ordering::Relaxed) && lines.len() < 10_000 {
                let mut line = String::new();
                if matches!(r.read_line(&mut line), Ok(n) if n > 0) {
                    lines.push(line);
                }
            }
            lines
        })
    };

    let report = RealtimeRunner::new(1.0).run(&mut sim, 5.0, 1.0, |_| {});
    stop.store(true, Ordering::Relaxed);
    let lines = reader.join().expect("reader thread");

    // Motion capture moved the real trucks along the right lane (centre radius 60 m) at 8 m/s:
    // truck 0 started 60 m along the lane from the positive x axis, so after about 5 s it is
    // about 100 m along: at angle 100/60 rad (counter-clockwise).
    let s0 = sim.state(VehicleId(0)).expect("truck 0 exists");
    assert!((s0.position.length() - 60.0).abs() < 0.3, "truck 0 off the right lane: {:?}", s0.position);
    let angle = s0.position.y.atan2(s0.position.x).rem_euclid(std::f64::consts::TAU);
    let travelled = (angle - 1.0) * 60.0;
    assert!((travelled - 40.0).abs() < 3.0, "truck 0 drove {travelled:.2} m in 5 s, expected 40 m (8 m/s)");
    let s1 = sim.state(VehicleId(1)).expect("truck 1 exists");
    assert!((s1.speed() - 8.0).abs() < 1.0, "truck 1 speed from motion capture {} m/s, expected 8", s1.speed());

    let json = serde_json::to_value(RunSummary::new(&sim, &report)).expect("summary serialises");
    let real = &json["lab"]["real_vehicles"];
    for id in ["0", "1"] {
        let v = &real[id];
        // 24 polls per second for 5 s: 120 frames; half of that on a busy machine.
        assert!(v["frames_received"].as_u64().expect("frames") >= 60, "vehicle {id}: {v}");
        assert_eq!(v["stale"], false, "vehicle {id}: {v}");
        assert!(v["stale_seconds"].as_f64().expect("stale_seconds") < 1.0, "vehicle {id}: {v}");
        assert!(v["detections_by_virtual"].as_u64().expect("detections") > 0, "vehicle {id} never detected: {v}");
        assert!(v["v2v_received_by_virtual"].as_u64().expect("v2v") > 0, "vehicle {id} never heard: {v}");
    }
    // Truck 1 follows truck 0 30 m behind on the same lane (offsets 30 and 60 m).
    assert_eq!(real["1"]["truck_leader"], 0, "{}", real["1"]);
    let gap = real["1"]["truck_current_distance"].as_f64().expect("gap");
    assert!((gap - 30.0).abs() < 0.5, "gap of truck 1 {gap} m, expected 30 m");

    // What truck 1 was told: gap and desired gap / 32, lane right (the outer lane).
    assert!(lines.len() >= 40, "about 20 lines per second expected, got {}", lines.len());
    let (id, fields) = parse_truck_line(lines.last().expect("a line"));
    assert_eq!(id, 1);
    assert_eq!(fields["lane"], "right");
    let d: f64 = fields["current_distance"].parse().expect("number");
    assert!((d - 30.0 / 32.0).abs() < 0.02, "current_distance {d}, expected 30/32");
    let dd: f64 = fields["desired_distance"].parse().expect("number");
    assert!((dd - 20.0 / 32.0).abs() < 1e-6, "desired_distance {dd}, expected 20/32");
    let v: f64 = fields["velocity"].parse().expect("number");
    assert!((v - 8.0 / 32.0).abs() < 0.04, "velocity {v}, expected 8/32");

    // Issue 22 item 1: yaw in degrees (truck 1 drives counter-clockwise round the origin, so
    // its heading is its polar angle + 90 deg), and time the motion-capture frame time: the
    // mock's frames are 1/DEFAULT_MOCK_RATE_HZ apart, the truck ticks 1/20 s.
    for line in &lines[lines.len() - 10..] {
        let (_, f) = parse_truck_line(line);
        let num = |k: &str| f[k].parse::<f64>().expect("number");
        let heading = (num("y").atan2(num("x")).to_degrees() + 90.0).rem_euclid(360.0);
        let yaw = num("yaw").rem_euclid(360.0);
        let diff = (yaw - heading).abs();
        assert!(!(3.0..=357.0).contains(&diff), "yaw {yaw} deg, heading {heading} deg: {line}");
    }
    let times: Vec<f64> =
        lines.iter().map(|l| l["time=".len()..].split("XcRt").next().unwrap().parse().unwrap()).collect();
    let rate = smlworld::io::mock_mocap::DEFAULT_MOCK_RATE_HZ;
    assert!(
        times.iter().all(|t| ((t * rate) - (t * rate).round()).abs() < 1e-3),
        "times are not motion-capture frame times (1/{rate} s apart): {times:?}"
    );
    assert!(
        times.iter().any(|t| ((t * 20.0) - (t * 20.0).round()).abs() > 1e-3),
        "every time is a truck tick (sim time), none a motion-capture frame time: {times:?}"
    );

    // The stream carried every vehicle, real ones where the simulation has them.
    let frame = viewer.latest().expect("stream frames arrived");
    assert_eq!(frame.vehicles.len(), 8);
    let t0 = frame.vehicles.iter().find(|v| v.id == 0).expect("truck 0 streamed");
    assert_eq!(t0.class_name, "Truck");
    assert!((t0.x.hypot(t0.y) - 60.0).abs() < 0.3);
}

fn start_mock(bodies: BTreeMap<u32, Vec<Keyframe>>) -> MockMocapServer {
    MockMocapServer::start(MockMocapConfig {
        bind: SocketAddr::from((Ipv4Addr::LOCALHOST, 0)),
        rate_hz: 100.0,
        script: MocapScript::Keyframes(bodies),
    })
    .expect("mock server")
}

fn scenario_text(addr: SocketAddr) -> String {
    format!(
        r#"
duration = 3.0
[lab]
mocap = {{ addr = "{addr}", stale_after = 0.3 }}
bodies = {{ 1 = 0, 2 = 1 }}
[[vehicles]]
id = 0
class = "truck"
model = {{ type = "none" }}
start = {{ x = 0.0, y = 0.0 }}
[[vehicles]]
id = 1
class = "truck"
model = {{ type = "none" }}
start = {{ x = 0.0, y = 0.0 }}
[[vehicles]]
id = -1
start = {{ x = 0.0, y = 5.0 }}
sensors = {{ omniscient = true }}
"#
    )
}

#[test]
fn a_lost_body_marks_its_vehicle_stale_and_keeps_it() {
    let nan = [f64::NAN; 6];
    let mut bodies = BTreeMap::new();
    // Body 1 (vehicle 0) stands at (1000, 0) mm for 10 s; body 2 (vehicle 1) stands at
    // (0, 500) mm and vanishes at 1 s.
    bodies.insert(
        1,
        vec![
            Keyframe { t_s: 0.0, pose: [1000.0, 0.0, 0.0, 0.0, 0.0, 90.0] },
            Keyframe { t_s: 10.0, pose: [1000.0, 0.0, 0.0, 0.0, 0.0, 90.0] },
        ],
    );
    bodies.insert(
        2,
        vec![Keyframe { t_s: 0.0, pose: [0.0, 500.0, 0.0, 0.0, 0.0, 0.0] }, Keyframe { t_s: 1.0, pose: nan }],
    );
    let server = start_mock(bodies);
    let scenario = Scenario::parse_str(&scenario_text(server.local_addr()), Path::new("stale.toml")).expect("scenario");
    let mut sim = scenario.builder().expect("builder").build();
    let report = RealtimeRunner::new(1.0).run(&mut sim, 2.5, 1.0, |_| {});

    // Lab millimetres times 32 / 1000: (1000, 0) mm -> (32, 0) m; (0, 500) mm -> (0, 16) m.
    let s0 = sim.state(VehicleId(0)).expect("vehicle 0");
    assert!((s0.position.x - 32.0).abs() < 1e-3 && s0.position.y.abs() < 1e-3, "{:?}", s0.position);
    assert!((s0.yaw - std::f64::consts::FRAC_PI_2).abs() < 1e-5);
    let s1 = sim.state(VehicleId(1)).expect("a stale vehicle is kept");
    assert!(s1.position.x.abs() < 1e-3 && (s1.position.y - 16.0).abs() < 1e-3, "{:?}", s1.position);
    assert_eq!(s1.velocity, glam::DVec2::ZERO, "a stale vehicle stands still");

    let e1 = sim.entity(VehicleId(1)).expect("entity");
    let track = *sim.world().get::<MocapTrack>(e1).expect("track");
    assert!(track.stale);
    // Lost at 1 s, stale after 0.3 s more, run ends at 2.5 s: about 1.2 s stale.
    assert!((track.stale_seconds - 1.2).abs() < 0.4, "stale for {} s, expected about 1.2", track.stale_seconds);

    let json = serde_json::to_value(RunSummary::new(&sim, &report)).expect("summary");
    assert_eq!(json["vehicles"], 3);
    assert_eq!(json["lab"]["real_vehicles"]["1"]["stale"], true);
    assert_eq!(json["lab"]["real_vehicles"]["0"]["stale"], false);
    assert!(json["lab"]["real_vehicles"]["0"]["stale_seconds"].as_f64().expect("number") < 0.5);
    assert!(json["lab"]["real_vehicles"]["0"]["detections_by_virtual"].as_u64().expect("number") > 0);
}

#[test]
fn motion_capture_refuses_real_vehicles_with_a_dynamics_model() {
    let server = start_mock(BTreeMap::from([(1, vec![Keyframe { t_s: 0.0, pose: [0.0; 6] }])]));
    let text = scenario_text(server.local_addr()).replacen("model = { type = \"none\" }\n", "", 1);
    let scenario = Scenario::parse_str(&text, Path::new("bad.toml")).expect("parses");
    let err =
        scenario.builder().err().expect("a real vehicle with a model under motion capture is an error").to_string();
    assert!(err.contains("lab.mocap") && err.contains("real vehicle 0") && err.contains("type = \"none\""), "{err}");
}

#[test]
fn bad_lab_settings_are_errors_naming_the_key() {
    for (lab, key) in [
        ("scale = -1.0", "lab.scale"),
        ("mocap = { addr = \"not an address\" }", "lab.mocap.addr"),
        ("mocap = { mock = true, addr = \"127.0.0.1:1\" }", "lab.mocap"),
        ("trucks = { rate = 0.0 }", "lab.trucks.rate"),
        ("trucks = { ip = \"nowhere\" }", "lab.trucks.ip"),
        ("mocap = { mock = true, colour = 1 }", "colour"),
    ] {
        let text = format!("[lab]\n{lab}\n");
        let err = Scenario::parse_str(&text, Path::new("lab.toml"))
            .err()
            .unwrap_or_else(|| panic!("{lab} accepted"))
            .to_string();
        assert!(err.contains(key), "{lab}: {err}");
    }
}

#[test]
fn the_mock_script_drives_the_trucks_along_the_right_lane_in_lab_millimetres() {
    let scenario = Scenario::load(&scenario_path()).expect("scenario");
    let script = smlworld::app::running::scenario::scenario_script(&scenario).expect("script");
    assert_eq!(script.body_count(), 2);
    // Truck 0 starts 60 m along the right lane (radius 60 m, from the positive x axis,
    // counter-clockwise) at 8 m/s; lab mm = world m / 32 * 1000.
    for t in [0.0, 5.0, 20.0] {
        let pose = script.pose(1, t).expect("body 1 (truck 0) visible");
        let angle = (60.0 + 8.0 * t) / 60.0;
        let (x, y) = (60.0 * f64::cos(angle) / 32.0 * 1000.0, 60.0 * f64::sin(angle) / 32.0 * 1000.0);
        // Keyframes every metre on a 60 m circle: chords sag at most 1/(8*60) m = 65 µm x 31.25.
        assert!((pose[0] - x).abs() < 5.0 && (pose[1] - y).abs() < 5.0, "t={t}: {pose:?} vs ({x}, {y})");
        let heading = (angle.to_degrees() + 90.0).rem_euclid(360.0);
        let yaw = pose[5].rem_euclid(360.0);
        assert!((yaw - heading).abs() < 1.5 || (yaw - heading).abs() > 358.5, "t={t}: yaw {yaw} vs {heading}");
    }
    // One lap of 2 pi 60 m at 8 m/s, then it starts over.
    let lap = std::f64::consts::TAU * 60.0 / 8.0;
    let (a, b) = (script.pose(2, 1.0).expect("visible"), script.pose(2, 1.0 + lap).expect("visible"));
    assert!((a[0] - b[0]).abs() < 5.0 && (a[1] - b[1]).abs() < 5.0, "{a:?} vs {b:?}");
}

#[test]
fn lanes_of_the_ring_and_gaps_along_a_lane() {
    use smlworld::io::lab::{LaneIndex, leader_gap};
    use smlworld::io::trucks::Lane;
    use smlworld::map::{LaneletMap, RouteOptions};
    use smlworld::world::Detection;

    let map = LaneletMap::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/maps/highway_ring.osm"))).expect("map");
    let lanes = LaneIndex::new(&map);
    // Counter-clockwise lanes with centre radii 52 (left), 56 (centre), 60 (right): the
    // driving direction's left is the inside of the ring.
    let at = |r: f64, a: f64| glam::DVec2::new(r * a.cos(), r * a.sin());
    for (r, lane) in [(52.0, Lane::Left), (56.0, Lane::Center), (60.0, Lane::Right)] {
        for a in [0.3, 2.0, 4.0] {
            let (found, offset) = lanes.locate(at(r + 0.5, a)).expect("a lane");
            assert_eq!(found, lane, "radius {r}");
            assert!((offset + 0.5).abs() < 0.05, "0.5 m outside the centre line is 0.5 m right: {offset}");
        }
    }

    let route = map.closed_loop_tag("right_lane_node", &RouteOptions::default()).expect("right lane loop");
    let det = |id: i32, p: glam::DVec2| Detection {
        id: VehicleId(id),
        position: p,
        velocity: glam::DVec2::ZERO,
        sensor: "radar",
    };
    // Truck at arc 0 (angle 0); others: 30 m ahead on the lane, 20 m ahead one lane in,
    // 10 m behind, and 90 m ahead.
    let others = [
        det(5, at(60.0, 30.0 / 60.0)),
        det(6, at(56.0, 20.0 / 60.0)),
        det(7, at(60.0, -10.0 / 60.0)),
        det(8, at(60.0, 90.0 / 60.0)),
    ];
    let s = route.project(at(60.0, 0.0)).s;
    let (leader, gap) = leader_gap(&route, s, &others, 2.0, 100.0).expect("a leader");
    assert_eq!(leader, VehicleId(5));
    assert!((gap - 30.0).abs() < 0.05, "gap {gap}, expected 30 m along the lane");
    assert!(leader_gap(&route, s, &others[1..], 2.0, 100.0).is_some_and(|(id, _)| id == VehicleId(8)));
    assert!(leader_gap(&route, s, &others[1..], 2.0, 80.0).is_none(), "nothing within 80 m ahead on the lane");
}

/// Issue 22 item 2: QTM numbers its bodies from 1; `[lab] bodies` maps body numbers to any
/// vehicle ids (here virtual ones), the mock server numbering its bodies the same way; bad
/// tables name the key.
#[test]
fn qtm_bodies_are_numbered_from_1_and_mapped_by_lab_bodies() {
    // Body 1 stands at (1000, 0) mm, body 2 at (0, 500) mm.
    let mut bodies = BTreeMap::new();
    bodies.insert(1, vec![Keyframe { t_s: 0.0, pose: [1000.0, 0.0, 0.0, 0.0, 0.0, 0.0] }]);
    bodies.insert(2, vec![Keyframe { t_s: 0.0, pose: [0.0, 500.0, 0.0, 0.0, 0.0, 90.0] }]);
    let server = start_mock(bodies);
    let text = format!(
        r#"
duration = 1.0
[lab]
mocap = {{ addr = "{}", stale_after = 0.3 }}
bodies = {{ 1 = -1, 2 = -2 }}
[[vehicles]]
id = -1
model = {{ type = "none" }}
[[vehicles]]
id = -2
model = {{ type = "none" }}
"#,
        server.local_addr()
    );
    let scenario = Scenario::parse_str(&text, Path::new("bodies.toml")).expect("scenario");
    let mut sim = scenario.builder().expect("builder").build();
    RealtimeRunner::new(1.0).run(&mut sim, 1.0, 1.0, |_| {});
    let s1 = sim.state(VehicleId(-1)).unwrap();
    let s2 = sim.state(VehicleId(-2)).unwrap();
    assert!((s1.position - glam::DVec2::new(32.0, 0.0)).length() < 1e-3, "body 1 drives -1: {:?}", s1.position);
    assert!((s2.position - glam::DVec2::new(0.0, 16.0)).length() < 1e-3, "body 2 drives -2: {:?}", s2.position);

    // Vehicle 0 has no body without a table; bad tables name their key.
    let no_zero = "[lab]\nmocap = { addr = \"127.0.0.1:1\" }\n[[vehicles]]\nid = 0\nmodel = { type = \"none\" }\n";
    let err = Scenario::parse_str(no_zero, Path::new("zero.toml")).unwrap().builder().err().unwrap().to_string();
    assert!(err.contains("bodies = { 1 = 0 }") && err.contains("from 1"), "{err}");
    for (bodies, key) in
        [("{ 0 = -1 }", "lab.bodies.0"), ("{ 1 = -1, 2 = -1 }", "lab.bodies.2"), ("{ x = -1 }", "lab.bodies.x")]
    {
        let err =
            Scenario::parse_str(&format!("[lab]\nbodies = {bodies}\n"), Path::new("b.toml")).err().unwrap().to_string();
        assert!(err.contains(key), "{bodies}: {err}");
    }
    let missing = "[lab]\nmocap = { addr = \"127.0.0.1:1\" }\nbodies = { 3 = -7 }\n";
    let err = Scenario::parse_str(missing, Path::new("m.toml")).unwrap().builder().err().unwrap().to_string();
    assert!(err.contains("lab.bodies.3") && err.contains("-7"), "{err}");
}
