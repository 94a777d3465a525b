//! Traffic-light states on the visualisation stream (issue 53, item 4): the lights extension of
//! our format round-trips, splits big states over datagrams, leaves older receivers showing the
//! vehicles, and `smlworld run --stream` sends it (never in the 2015 format).

mod scratch_support;
mod view_support;

use smlworld::world::TurnSignal;
use std::net::{Ipv4Addr, UdpSocket};
use std::process::Command;
use std::time::{Duration, Instant};

use scratch_support::Scratch;
use smlworld::io::viz::{
    MAX_DATAGRAM_LEN, VizLight, VizReassembler, VizVehicle, decode_datagram, decode_lights, encode_frame, encode_lights,
};

fn light(junction: u32, state: &str) -> VizLight {
    VizLight { junction, state: state.to_string() }
}

#[test]
fn lights_round_trip_in_one_datagram_or_several() {
    let lights = vec![light(1, "GGgrrr"), light(2, "rrrGGg"), light(3, "yyyrrr")];
    let mut out = Vec::new();
    encode_lights(17, &lights, &mut out);
    assert_eq!(out.len(), 1);
    assert_eq!(String::from_utf8_lossy(&out[0]), "L17#1=GGgrrr;2=rrrGGg;3=yyyrrr");
    assert_eq!(decode_lights(&out[0]).expect("decodes"), (17, lights));

    // A 20 x 20 city: 400 junctions of 16 links do not fit in one datagram.
    let city: Vec<VizLight> = (1..=400).map(|j| light(j, "GGGgrrrrGGGgrrrr")).collect();
    encode_lights(123_456, &city, &mut out);
    assert!(out.len() > 1, "split");
    let mut back = Vec::new();
    for d in &out {
        assert!(d.len() <= MAX_DATAGRAM_LEN, "{} bytes", d.len());
        let (counter, part) = decode_lights(d).expect("each datagram decodes on its own");
        assert_eq!(counter, 123_456);
        back.extend(part);
    }
    assert_eq!(back, city);
    encode_lights(1, &[], &mut out);
    assert!(out.is_empty(), "no lights, no datagram");
}

#[test]
fn older_receivers_drop_the_lights_and_keep_the_vehicles() {
    let vehicles = vec![VizVehicle {
        id: -1,
        x: 1.0,
        y: 2.0,
        yaw_deg: 90.0,
        class_name: "Car".into(),
        indicator: TurnSignal::Off,
    }];
    let frame = encode_frame(5, &vehicles);
    assert_eq!(String::from_utf8_lossy(&frame[0]), "5#id=-1;x=1.000;y=2.000;yaw=90.00;class_name=Car", "unchanged");
    let mut lights = Vec::new();
    encode_lights(5, &[light(1, "Gr"), light(4, "rG")], &mut lights);
    // What an older receiver runs on every datagram: the lights one is not a frame (an error it
    // counts and drops), the vehicle one decodes as before.
    assert!(decode_datagram(&lights[0]).is_err());
    assert_eq!(decode_datagram(&frame[0]).expect("decodes").vehicles, vehicles);

    // A new receiver hands the latest lights out with each frame.
    let mut r = VizReassembler::new();
    assert_eq!(r.push_bytes(&lights[0]), None, "lights alone are no frame");
    let f = r.push_bytes(&frame[0]).expect("the frame");
    assert_eq!(f.vehicles, vehicles);
    assert_eq!(f.lights, vec![light(1, "Gr"), light(4, "rG")]);
    encode_lights(6, &[light(4, "yr")], &mut lights);
    r.push_bytes(&lights[0]);
    let f = r.push_bytes(&encode_frame(6, &vehicles)[0]).expect("the next frame");
    assert_eq!(f.lights, vec![light(1, "Gr"), light(4, "yr")], "junction 1 kept, junction 4 updated");
    assert_eq!(r.stats().decode_errors, 0);
}

#[test]
fn malformed_lights_are_errors_not_panics() {
    for bad in ["L1#x=GG", "L1#1=G1", "Lx#1=G", "L1#1", "L1#1=", "L", "L1#1=G\u{e9}"] {
        assert!(decode_lights(bad.as_bytes()).is_err(), "{bad}");
    }
    assert!(decode_lights(b"L1#1=G\xff").is_err());
    let mut r = VizReassembler::new();
    assert_eq!(r.push_bytes(b"L1#1=G1"), None);
    assert_eq!(r.stats().decode_errors, 1);
}

/// Every datagram `smlworld run SCENARIO --duration 3 --stream ADDR [extra]` sends, as text.
fn stream_of(scenario: &std::path::Path, out: &std::path::Path, extra: &[&str]) -> Vec<String> {
    let socket = UdpSocket::bind((Ipv4Addr::LOCALHOST, 0)).expect("bind");
    socket.set_read_timeout(Some(Duration::from_millis(200))).expect("timeout");
    let addr = socket.local_addr().expect("address").to_string();
    let mut child = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["run", scenario.to_str().unwrap(), "--duration", "3", "--realtime", "--speed", "10", "--stream", &addr])
        .args(extra)
        .arg("--out")
        .arg(out)
        .spawn()
        .expect("start smlworld run");
    let mut texts = Vec::new();
    let mut buf = [0u8; 65536];
    let deadline = Instant::now() + Duration::from_secs(60);
    while Instant::now() < deadline {
        match socket.recv_from(&mut buf) {
            Ok((n, _)) => texts.push(String::from_utf8_lossy(&buf[..n]).into_owned()),
            Err(_) if child.try_wait().expect("wait").is_some() => break,
            Err(_) => {}
        }
    }
    assert!(child.wait().expect("run ends").success());
    texts
}

#[test]
fn a_run_streams_its_light_states_in_our_format_only() {
    let dir = Scratch::new("smlworld-stream-lights", "run");
    let map = dir.join("x.osm");
    let status = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["map", "generate", "intersection4", "--traffic-lights", "--out", map.to_str().unwrap()])
        .output()
        .expect("runs smlworld");
    assert!(status.status.success());
    let scenario = dir.join("lights.toml");
    std::fs::write(
        &scenario,
        "seed = 7\nduration = 60.0\nmap = \"x.osm\"\n\n[[traffic]]\nroute = \"random\"\nrate = 600.0\n\
         speed = [10.0, 12.0]\nclasses = { car = 1.0 }\nlane_change = false\n",
    )
    .unwrap();
    let texts = stream_of(&scenario, &dir.join("out"), &[]);
    let lights: Vec<&String> = texts.iter().filter(|t| t.starts_with('L')).collect();
    assert!(lights.len() > 10, "{} lights datagrams of {}", lights.len(), texts.len());
    let (_, first) = decode_lights(lights[0].as_bytes()).expect("decodes");
    assert_eq!(first.len(), 1);
    assert_eq!(first[0].junction, 1);
    assert_eq!(first[0].state.len(), 12, "one character per link");
    // Each lights datagram comes just before the frame with its counter.
    let i = texts.iter().position(|t| t.starts_with('L')).expect("a lights datagram");
    let counter = &texts[i][1..texts[i].find('#').expect("a #")];
    assert!(texts[i + 1].starts_with(&format!("{counter}#")), "{} then {}", texts[i], texts[i + 1]);

    let old = stream_of(&scenario, &dir.join("out2015"), &["--stream-format", "2015"]);
    assert!(!old.is_empty() && old.iter().all(|t| !t.starts_with('L')), "the 2015 format carries no lights");
}

#[test]
fn the_viewer_draws_stop_lines_in_the_streamed_colours() {
    use smlworld::map::LaneletMap;
    use smlworld::render::{BirdseyeView, SIGNAL_GREEN, SIGNAL_RED};
    use view_support::{ChildGuard, free_udp_port, send_scene};

    let dir = Scratch::new("smlworld-stream-lights", "view");
    let map_path = dir.join("x.osm");
    let status = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["map", "generate", "intersection4", "--traffic-lights", "--out", map_path.to_str().unwrap()])
        .output()
        .expect("runs smlworld");
    assert!(status.status.success());
    let addr = free_udp_port();
    let frames = dir.join("frames");
    let viewer = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["view", "--listen", &addr.to_string(), "--map", map_path.to_str().unwrap()])
        .args(["--width", "640", "--height", "640", "--pixels-per-meter", "4", "--center", "0,0"])
        .args(["--duration", "120", "--frames", frames.to_str().unwrap()])
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("start smlworld view");
    let _viewer = ChildGuard(viewer);

    // Links 0..6 green, 6..12 red.
    let state = "GGGGGGrrrrrr";
    let sender = UdpSocket::bind((Ipv4Addr::LOCALHOST, 0)).expect("bind sender");
    let mut lights = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(90);
    let mut counter = 0;
    let img = loop {
        encode_lights(counter, &[light(1, state)], &mut lights);
        sender.send_to(&lights[0], addr).expect("send lights");
        send_scene(&sender, addr, counter, &[(-1, 60.0, 60.0, 0.0, "Car")]);
        counter += 1;
        if let Some(img) = std::fs::read_dir(&frames)
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| e.path())
            .find(|p| p.extension().is_some_and(|x| x == "png"))
            .and_then(|p| image::open(p).ok())
        {
            break img.to_rgba8();
        }
        assert!(Instant::now() < deadline, "no frame written in 90 s");
        std::thread::sleep(Duration::from_millis(50));
    };
    let map = LaneletMap::load(&map_path).unwrap();
    let view = BirdseyeView::new(640, 640, 4.0, glam::DVec2::ZERO).expect("a valid view");
    for (k, link) in map.junctions().list[0].links.iter().enumerate() {
        let lanelet = map.lanelet(link.lanelet).expect("a link's lanelet");
        // Links starting on one stop line share it side by side: look at this link's part.
        let same: Vec<usize> = map.junctions().list[0]
            .links
            .iter()
            .enumerate()
            .filter(|(_, o)| map.lanelet(o.lanelet).is_some_and(|x| x.left[0].distance(lanelet.left[0]) < 0.01))
            .map(|(i, _)| i)
            .collect();
        let part = same.iter().position(|&i| i == k).expect("itself") as f64;
        let f = (part + 0.5) / same.len() as f64;
        let p = view.world_to_pixel(lanelet.left[0] + (lanelet.right[0] - lanelet.left[0]) * f);
        let want = if state.as_bytes()[k] == b'G' { SIGNAL_GREEN } else { SIGNAL_RED };
        assert_eq!(img.get_pixel(p.x as u32, p.y as u32).0, want, "link {k}");
    }
}
