//! Qualisys RT 1.11: framing and 6DEuler parsing against hand-built packets (truncated, oversized,
//! wrong-type, NaN), the tracker's scaling/velocity/staleness, the client's handshake against a
//! hand-written server, loopback with the mock server, the `mock-mocap` CLI, and a flood of bad
//! packets over TCP.

mod common;

use common::Rng;
use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use glam::DVec2;
use smlworld::io::mock_mocap::{MocapScript, MockMocapConfig, MockMocapServer};
use smlworld::io::qualisys::{
    BodyMapping, DataFrame, PacketDecoder, PacketType, QtmClient, QtmClientConfig, QtmError, Tracker, TrackerConfig,
    encode_command, parse_data,
};

// ---------- hand-built packets, written from the protocol description ----------

fn packet(kind: i32, payload: &[u8]) -> Vec<u8> {
    let mut p = ((8 + payload.len()) as i32).to_be_bytes().to_vec();
    p.extend_from_slice(&kind.to_be_bytes());
    p.extend_from_slice(payload);
    p
}

fn text_packet(kind: i32, text: &str) -> Vec<u8> {
    let mut t = text.as_bytes().to_vec();
    t.push(0);
    packet(kind, &t)
}

fn euler_component(bodies: &[[f32; 6]]) -> Vec<u8> {
    let mut c = ((16 + 24 * bodies.len()) as i32).to_be_bytes().to_vec();
    c.extend_from_slice(&6i32.to_be_bytes());
    c.extend_from_slice(&(bodies.len() as i32).to_be_bytes());
    c.extend_from_slice(&[0, 3, 0, 1]); // drop rate and out-of-sync counters
    for b in bodies {
        for v in b {
            c.extend_from_slice(&v.to_be_bytes());
        }
    }
    c
}

fn data_payload(timestamp_us: i64, frame: i32, components: &[Vec<u8>]) -> Vec<u8> {
    let mut p = timestamp_us.to_be_bytes().to_vec();
    p.extend_from_slice(&frame.to_be_bytes());
    p.extend_from_slice(&(components.len() as i32).to_be_bytes());
    for c in components {
        p.extend_from_slice(c);
    }
    p
}

const NAN6: [f32; 6] = [f32::NAN; 6];

/// Read one packet the slow, obvious way: size, type, payload.
fn read_raw(stream: &mut TcpStream) -> std::io::Result<(i32, Vec<u8>)> {
    let mut h = [0u8; 8];
    stream.read_exact(&mut h)?;
    let size = i32::from_be_bytes([h[0], h[1], h[2], h[3]]);
    let kind = i32::from_be_bytes([h[4], h[5], h[6], h[7]]);
    let mut payload = vec![0; size as usize - 8];
    stream.read_exact(&mut payload)?;
    Ok((kind, payload))
}

fn loopback0() -> SocketAddr {
    "127.0.0.1:0".parse().expect("addr")
}

// ---------- framing and parsing ----------

#[test]
fn command_framing_matches_the_protocol() {
    let mut want = vec![0, 0, 0, 21, 0, 0, 0, 1];
    want.extend_from_slice(b"Version 1.11\0");
    assert_eq!(encode_command("Version 1.11"), want);
    assert_eq!(encode_command("New").len(), 8 + 3 + 1);
}

#[test]
fn decoder_splits_a_stream_fed_byte_by_byte() {
    let mut stream = text_packet(1, "QTM RT Interface connected");
    stream.extend(packet(3, &data_payload(5, 6, &[euler_component(&[[1.0; 6]])])));
    stream.extend(packet(4, &[]));
    let mut d = PacketDecoder::new(1 << 20);
    let mut got = Vec::new();
    for b in &stream {
        d.push(std::slice::from_ref(b));
        while let Some(p) = d.next_packet() {
            got.push(p.expect("valid packet"));
        }
    }
    assert_eq!(
        got.iter().map(|p| p.kind).collect::<Vec<_>>(),
        [PacketType::Command, PacketType::Data, PacketType::NoMoreData]
    );
    assert_eq!(got[0].text(), "QTM RT Interface connected");
    assert_eq!(got[1].payload.len(), 16 + 16 + 24);
    assert_eq!(d.buffered(), 0);
}

#[test]
fn six_d_euler_bodies_parse_and_nan_bodies_are_skipped() {
    let payload = data_payload(
        1_234_567,
        42,
        &[euler_component(&[
            [100.0, -200.0, 5.0, 1.0, 2.0, 90.0],
            [f32::NAN, 0.0, 0.0, 0.0, 0.0, 0.0],
            [-1.5, 2.5, 0.0, 0.0, 0.0, -179.5],
        ])],
    );
    let f = parse_data(&payload).expect("valid frame");
    assert_eq!(f.timestamp_us, 1_234_567);
    assert_eq!(f.frame, 42);
    assert_eq!(f.body_count, 3);
    assert_eq!(f.bodies.len(), 2, "the NaN body is not tracked this frame");
    assert_eq!(f.bodies[0].index, 0);
    assert_eq!((f.bodies[0].x_mm, f.bodies[0].y_mm, f.bodies[0].z_mm), (100.0, -200.0, 5.0));
    assert_eq!((f.bodies[0].roll_deg, f.bodies[0].pitch_deg, f.bodies[0].yaw_deg), (1.0, 2.0, 90.0));
    assert_eq!(f.bodies[1].index, 2, "indices survive skipped bodies");
    assert_eq!((f.bodies[1].x_mm, f.bodies[1].yaw_deg), (-1.5, -179.5));
}

#[test]
fn other_components_are_skipped_by_their_size() {
    // A 3D component (type 1) with 12 bytes of marker data first.
    let mut three_d = 20i32.to_be_bytes().to_vec();
    three_d.extend_from_slice(&1i32.to_be_bytes());
    three_d.extend_from_slice(&[7; 12]);
    let payload = data_payload(1, 2, &[three_d.clone(), euler_component(&[[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]])]);
    let f = parse_data(&payload).expect("valid");
    assert_eq!(f.bodies[0].yaw_deg, 6.0);
    assert!(matches!(parse_data(&data_payload(1, 2, &[three_d])), Err(QtmError::No6DEuler)));
}

#[test]
fn every_truncation_of_a_data_packet_is_an_error() {
    let payload = data_payload(9, 9, &[euler_component(&[[1.0; 6], [2.0; 6]])]);
    for cut in 0..payload.len() {
        assert!(parse_data(&payload[..cut]).is_err(), "payload cut at {cut} bytes was accepted");
    }
    assert!(parse_data(&payload).is_ok());
}

#[test]
fn inconsistent_counts_and_sizes_are_errors() {
    let body = euler_component(&[[1.0; 6]]);
    // Body count says i32::MAX: must be refused, not allocated.
    let mut huge = body.clone();
    huge[8..12].copy_from_slice(&i32::MAX.to_be_bytes());
    assert!(matches!(parse_data(&data_payload(0, 0, &[huge])), Err(QtmError::BadBodyCount { .. })));
    let mut negative = body.clone();
    negative[8..12].copy_from_slice(&(-1i32).to_be_bytes());
    assert!(matches!(parse_data(&data_payload(0, 0, &[negative])), Err(QtmError::BadBodyCount { .. })));
    // Component size beyond the payload, or below its own header.
    for size in [i32::MAX, 1000, 4, -8] {
        let mut c = body.clone();
        c[0..4].copy_from_slice(&size.to_be_bytes());
        assert!(
            matches!(parse_data(&data_payload(0, 0, &[c])), Err(QtmError::BadComponentSize { .. })),
            "component size {size}"
        );
    }
    let mut p = data_payload(0, 0, &[body]);
    p[12..16].copy_from_slice(&(-3i32).to_be_bytes());
    assert!(matches!(parse_data(&p), Err(QtmError::BadComponentCount(-3))));
}

#[test]
fn oversized_and_undersized_size_fields_are_refused_before_allocating() {
    for size in [i32::MAX, (1 << 20) + 1, 7, 0, -1, i32::MIN] {
        let mut d = PacketDecoder::new(1 << 20);
        let mut bytes = size.to_be_bytes().to_vec();
        bytes.extend_from_slice(&3i32.to_be_bytes());
        bytes.extend_from_slice(&[0; 32]);
        d.push(&bytes);
        match d.next_packet() {
            Some(Err(QtmError::BadSize { size: s, .. })) => assert_eq!(s, i64::from(size)),
            other => panic!("size {size}: expected BadSize, got {other:?}"),
        }
        // The stream is out of sync: it stays refused until reset.
        assert!(matches!(d.next_packet(), Some(Err(QtmError::BadSize { .. }))));
        assert!(d.buffered() <= bytes.len());
        d.reset();
        d.push(&packet(4, &[]));
        assert_eq!(d.next_packet().expect("packet").expect("valid").kind, PacketType::NoMoreData);
    }
}

#[test]
fn wrong_type_packets_are_skipped_and_the_stream_continues() {
    let mut d = PacketDecoder::new(1 << 20);
    d.push(&packet(99, b"whatever"));
    d.push(&packet(-5, &[]));
    d.push(&text_packet(0, "Parse error"));
    assert!(matches!(d.next_packet(), Some(Err(QtmError::UnknownType { code: 99, len: 8 }))));
    assert!(matches!(d.next_packet(), Some(Err(QtmError::UnknownType { code: -5, len: 0 }))));
    let p = d.next_packet().expect("packet").expect("valid");
    assert_eq!((p.kind, p.text()), (PacketType::Error, "Parse error".to_string()));
    assert!(d.next_packet().is_none());
}

// ---------- tracker ----------

fn frame(timestamp_us: i64, n: i32, bodies: &[[f32; 6]]) -> DataFrame {
    parse_data(&data_payload(timestamp_us, n, &[euler_component(bodies)])).expect("valid frame")
}

#[test]
fn tracker_scales_estimates_velocity_and_marks_lost_bodies_stale() {
    let mut t = Tracker::new(TrackerConfig::default());
    let t0 = Instant::now();
    t.update(&frame(0, 1, &[[1000.0, 0.0, 0.0, 0.0, 0.0, 90.0], [0.0, 500.0, 0.0, 0.0, 0.0, 0.0]]), t0);
    let b0 = t.get(1).expect("QTM body 1 (the first in the frame) is vehicle 1");
    // 1000 mm on the lab floor is 1 m, times the scale 32.
    assert!((b0.position - DVec2::new(32.0, 0.0)).length() < 1e-9);
    assert!((b0.yaw - std::f64::consts::FRAC_PI_2).abs() < 1e-6);
    assert_eq!(b0.velocity, DVec2::ZERO);
    // 100 mm in 0.1 s along x: 1 m/s in the lab, 32 m/s in the world.
    let t1 = t0 + Duration::from_millis(100);
    t.update(&frame(100_000, 2, &[[1100.0, 0.0, 0.0, 0.0, 0.0, 90.0], NAN6]), t1);
    let b0 = t.get(1).expect("body 1");
    assert!((b0.velocity - DVec2::new(32.0, 0.0)).length() < 1e-3, "{:?}", b0.velocity);
    assert_eq!(b0.frame, 2);
    // A duplicate of frame 2 (polled twice) changes nothing.
    t.update(&frame(100_000, 2, &[[5000.0, 0.0, 0.0, 0.0, 0.0, 0.0], NAN6]), t1);
    assert!((t.get(1).expect("body 1").position.x - 35.2).abs() < 1e-4);
    // Body 2 was last seen at t0: stale after 0.5 s, kept.
    assert_eq!(t.refresh(t0 + Duration::from_millis(400)), 0);
    assert_eq!(t.refresh(t0 + Duration::from_millis(700)), 2, "both last seen more than 0.5 s before");
    let b1 = t.get(2).expect("a lost body is not deleted");
    assert!(b1.stale);
    assert!((b1.position - DVec2::new(0.0, 16.0)).length() < 1e-9, "keeps its last position");
    assert!(t.get(1).expect("body 1").stale);
    assert_eq!(t.refresh(t0 + Duration::from_millis(800)), 0, "reported once");
    // Seen again: fresh, velocity restarts from zero rather than spanning the gap.
    t.update(&frame(1_000_000, 3, &[NAN6, [0.0, 900.0, 0.0, 0.0, 0.0, 0.0]]), t0 + Duration::from_secs(1));
    let b1 = t.get(2).expect("body 2");
    assert!(!b1.stale);
    assert_eq!(b1.velocity, DVec2::ZERO);
    // QTM restarted its measurement: timestamps start again from zero; the body still moves.
    t.update(&frame(40_000, 1, &[NAN6, [0.0, 1000.0, 0.0, 0.0, 0.0, 0.0]]), t0 + Duration::from_millis(1100));
    let b1 = t.get(2).expect("body 2");
    assert!((b1.position - DVec2::new(0.0, 32.0)).length() < 1e-9);
    assert_eq!(b1.velocity, DVec2::ZERO);
    assert_eq!(b1.frame, 1);
}

#[test]
fn tracker_mapping_table_and_scale() {
    let config = TrackerConfig {
        mapping: BodyMapping::Table(BTreeMap::from([(2, 7)])),
        scale: 10.0,
        stale_after: Duration::from_secs(1),
    };
    let mut t = Tracker::new(config);
    t.update(&frame(0, 0, &[[1.0; 6], [2000.0, -1000.0, 0.0, 0.0, 0.0, 0.0]]), Instant::now());
    assert_eq!(t.bodies().map(|b| b.id).collect::<Vec<_>>(), [7], "only mapped bodies are tracked");
    let b = t.get(7).expect("body 2 (the second in the frame) is vehicle 7");
    assert_eq!(b.body, 2);
    assert!((b.position - DVec2::new(20.0, -10.0)).length() < 1e-9);
}

#[test]
fn twenty_thousand_bodies_are_found_by_id_without_a_scan() {
    // Issue 24 item 4: the bridge found each body of a frame by scanning every tracked body
    // (20,000 bodies: 4e8 steps a frame). `seen_in` looks each one up by its mapped id.
    let bodies: Vec<[f32; 6]> = (0..20_000).map(|k| [k as f32, 0.0, 0.0, 0.0, 0.0, 0.0]).collect();
    let mut t = Tracker::new(TrackerConfig::default());
    let started = Instant::now();
    for n in 0..10 {
        let f = frame(i64::from(n) * 10_000, n, &bodies);
        t.update(&f, Instant::now());
        let seen: Vec<i32> = t.seen_in(&f).map(|b| b.id).collect();
        assert_eq!(seen.len(), 20_000);
        assert_eq!((seen[0], seen[19_999]), (1, 20_000), "bodies in frame order, 1-based");
    }
    // Each id once: a duplicate frame is still "seen in" it, an older one is not.
    let old = frame(0, 0, &bodies[..1]);
    assert_eq!(t.seen_in(&old).count(), 0, "body 1 was last seen at frame 9, not frame 0");
    // Generous: the scan took minutes here; the lookup takes well under a second.
    assert!(started.elapsed() < Duration::from_secs(20), "{:?}", started.elapsed());
}

// ---------- client against a hand-written server ----------

#[test]
fn client_handshake_and_polling_against_a_hand_written_server() {
    let listener = TcpListener::bind(loopback0()).expect("bind");
    let addr = listener.local_addr().expect("addr");
    let server = std::thread::spawn(move || -> Vec<String> {
        let (mut s, _) = listener.accept().expect("accept");
        s.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
        s.write_all(&text_packet(1, "QTM RT Interface connected")).expect("greet");
        let mut seen = Vec::new();
        let replies = ["Version set to 1.11", "You are now master", "Creating new connection"];
        for reply in replies {
            let (kind, payload) = read_raw(&mut s).expect("command");
            assert_eq!(kind, 1, "commands are type 1");
            assert_eq!(payload.last(), Some(&0), "commands end with NUL");
            seen.push(String::from_utf8_lossy(&payload[..payload.len() - 1]).into_owned());
            s.write_all(&text_packet(1, reply)).expect("reply");
        }
        let started = Instant::now();
        while started.elapsed() < Duration::from_millis(500) {
            let (kind, payload) = read_raw(&mut s).expect("poll");
            assert_eq!(kind, 1);
            seen.push(String::from_utf8_lossy(&payload[..payload.len() - 1]).into_owned());
            let n = seen.len() as i32;
            let bodies = [[f32::NAN; 6], [320.0, 0.0, 0.0, 0.0, 0.0, 45.0]];
            s.write_all(&packet(3, &data_payload(i64::from(n) * 10_000, n, &[euler_component(&bodies)])))
                .expect("data");
        }
        seen
    });
    let config =
        QtmClientConfig { addr, poll_rate_hz: 20.0, password: Some("secret".into()), ..QtmClientConfig::default() };
    let client = QtmClient::spawn(config).expect("client");
    let f = client.next_timeout(Duration::from_secs(5)).expect("a frame");
    assert_eq!(f.frame.bodies.len(), 1);
    assert_eq!(f.frame.bodies[0].index, 1);
    assert_eq!(f.frame.bodies[0].x_mm, 320.0);
    let seen = server.join().expect("server thread");
    assert_eq!(seen[..3], ["Version 1.11", "TakeControl secret", "New"]);
    let polls = &seen[3..];
    assert!(polls.iter().all(|c| c == "GetCurrentFrame 6DEuler"), "{polls:?}");
    // 0.5 s at 20 Hz: never more than 11 polls (plus one in flight); at least a few.
    assert!((3..=12).contains(&polls.len()), "{} polls in 0.5 s at 20 Hz", polls.len());
    let stats = client.stats();
    assert_eq!(stats.sessions, 1);
    assert_eq!(stats.bad_packets, 0);
}

#[test]
fn handshake_refused_version_makes_the_client_retry() {
    let listener = TcpListener::bind(loopback0()).expect("bind");
    let addr = listener.local_addr().expect("addr");
    let server = std::thread::spawn(move || {
        for _ in 0..2 {
            let (mut s, _) = listener.accept().expect("accept");
            s.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
            let (_, version) = read_raw(&mut s).expect("Version command");
            assert_eq!(version, b"Version 1.11\0");
            s.write_all(&text_packet(0, "Version not supported")).expect("refuse");
            assert!(read_raw(&mut s).is_err(), "the client must hang up after a refused Version");
        }
    });
    let config = QtmClientConfig { addr, reconnect_delay: Duration::from_millis(20), ..QtmClientConfig::default() };
    let client = QtmClient::spawn(config).expect("client");
    server.join().expect("server saw two attempts");
    let stats = client.stats();
    assert_eq!(stats.sessions, 0);
    assert!(client.is_running());
}

// ---------- loopback with the mock server ----------

#[test]
fn client_tracks_mock_bodies_driving_circles() {
    let server =
        MockMocapServer::start(MockMocapConfig { bind: loopback0(), rate_hz: 100.0, script: MocapScript::circles(2) })
            .expect("mock server");
    let client = QtmClient::spawn(QtmClientConfig {
        addr: server.local_addr(),
        poll_rate_hz: 50.0,
        ..QtmClientConfig::default()
    })
    .expect("client");
    let mut tracker = Tracker::new(TrackerConfig::default());
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut frames = 0;
    while frames < 15 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
        frames += client.poll(&mut tracker, Instant::now());
    }
    assert!(frames >= 15, "only {frames} frames from the mock");
    // Radii 1.0 m and 1.3 m on the floor, times 32; speed 0.3 m/s times 32.
    for (id, radius) in [(1, 32.0), (2, 41.6)] {
        let b = tracker.get(id).expect("body tracked");
        assert!(!b.stale);
        assert!((b.position.length() - radius).abs() < 1e-3 * radius, "vehicle {id} at {:?}", b.position);
        let tangent = b.position.perp().normalize();
        let heading = DVec2::from_angle(b.yaw);
        assert!(heading.dot(tangent) > 0.9999, "vehicle {id} heading {} along the circle", b.yaw);
        assert!((b.velocity.length() - 9.6).abs() < 0.2, "vehicle {id} speed {}", b.velocity.length());
        assert!(b.velocity.normalize().dot(tangent) > 0.99);
    }
    assert_eq!(client.stats().bad_packets, 0);
    assert_eq!(server.connections(), 1);
}

#[test]
fn a_body_hidden_by_the_script_becomes_stale_but_stays() {
    let csv = "t_s,body,x_mm,y_mm,z_mm,roll_deg,pitch_deg,yaw_deg\n\
               0,1,0,0,0,0,0,0\n60,1,0,0,0,0,0,0\n\
               # body 2 visible for 1 s, then hidden\n\
               0,2,500,0,0,0,0,0\n1.0,2,nan,nan,nan,nan,nan,nan\n";
    let script = MocapScript::from_csv(csv, "<test>").expect("script");
    assert_eq!(script.body_count(), 2);
    let server = MockMocapServer::start(MockMocapConfig { bind: loopback0(), rate_hz: 100.0, script }).expect("mock");
    let client =
        QtmClient::spawn(QtmClientConfig { addr: server.local_addr(), poll_rate_hz: 50.0, ..Default::default() })
            .expect("client");
    let mut tracker = Tracker::new(TrackerConfig { stale_after: Duration::from_millis(300), ..Default::default() });
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut seen_fresh = false;
    while Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(20));
        client.poll(&mut tracker, Instant::now());
        match tracker.get(2) {
            Some(b) if !b.stale => seen_fresh = true,
            Some(b) if b.stale && seen_fresh => break,
            _ => {}
        }
    }
    let b1 = tracker.get(2).expect("body 2 kept");
    assert!(seen_fresh && b1.stale, "body 2 should be seen, then stale");
    assert!((b1.position - DVec2::new(16.0, 0.0)).length() < 1e-6, "last position kept");
    assert!(!tracker.get(1).expect("body 1").stale, "body 1 is still visible");
}

#[test]
fn bad_scripts_name_the_line() {
    let e = MocapScript::from_csv("0,1,1,2,3,4,5,6\n0.5,1,1,2,x,4,5,6\n", "s.csv").expect_err("bad value");
    assert!(e.to_string().contains("s.csv:2"), "{e}");
    assert!(MocapScript::from_csv("1,2,3\n", "s.csv").is_err());
    assert!(MocapScript::from_csv("-1,0,0,0,0,0,0,0\n", "s.csv").is_err());
    assert!(MocapScript::from_csv("# nothing\n", "s.csv").is_err());
    // Issue 22 item 2: bodies are numbered from 1, as in QTM.
    let e = MocapScript::from_csv("0,0,0,0,0,0,0,0\n", "s.csv").expect_err("body 0");
    assert!(e.to_string().contains("from 1"), "{e}");
    let with_header = "# a comment first\nt_s,body,x,y,z,r,p,yaw\n0,1,0,0,0,0,0,0\n";
    assert_eq!(MocapScript::from_csv(with_header, "s.csv").expect("header after a comment").body_count(), 1);
    // Interpolation: halfway between two keyframes; yaw the short way round.
    let s = MocapScript::from_csv("0,1,0,0,0,0,0,170\n2,1,1000,0,0,0,0,-170\n", "s.csv").expect("valid");
    let p = s.pose(1, 1.0).expect("visible");
    assert!((p[0] - 500.0).abs() < 1e-9);
    assert!((p[5] - 180.0).abs() < 1e-9, "yaw {}", p[5]);
}

#[test]
fn the_mock_caps_its_inputs() {
    use smlworld::io::mock_mocap::{MAX_COMMAND_LEN, MAX_MOCK_BODIES};
    let start = |rate_hz: f64, script: MocapScript| {
        MockMocapServer::start(MockMocapConfig { bind: loopback0(), rate_hz, script })
    };
    let e = start(100.0, MocapScript::circles(MAX_MOCK_BODIES + 1)).expect_err("too many bodies");
    assert!(e.to_string().contains("bodies"), "{e}");
    for rate in [f64::NAN, -1.0, 1e9] {
        let e = start(rate, MocapScript::circles(1)).expect_err("bad rate");
        assert!(e.to_string().contains("rate"), "{rate}: {e}");
    }
    let e = MocapScript::from_csv(
        "0,1,0,0,0,0,0,0
0,4000000000,0,0,0,0,0,0
",
        "s.csv",
    )
    .expect_err("huge body");
    assert!(e.to_string().contains("s.csv:2"), "{e}");
    // A command packet over the cap gets an error and the connection closed, not a 1 MiB buffer.
    let server = start(100.0, MocapScript::circles(1)).expect("mock");
    let mut s = TcpStream::connect(server.local_addr()).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let (_, greeting) = read_raw(&mut s).expect("greeting");
    assert!(String::from_utf8_lossy(&greeting).contains("QTM"));
    // Only the header (size, type): the mock must refuse it from the size alone.
    let mut header = ((MAX_COMMAND_LEN + 100) as i32).to_be_bytes().to_vec();
    header.extend_from_slice(&1i32.to_be_bytes());
    s.write_all(&header).expect("send");
    let (kind, _) = read_raw(&mut s).expect("an error packet");
    assert_eq!(kind, 0, "packet type Error");
}

#[test]
fn mock_mocap_cli_serves_frames() {
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["mock-mocap", "--port", "0", "--bodies", "3", "--rate", "50"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("start smlworld mock-mocap");
    let mut line = String::new();
    let read = child.stdout.take().map(|out| BufReader::new(out).read_line(&mut line));
    let result = (|| {
        read.ok_or("no stdout")?.map_err(|_| "read stdout")?;
        let addr: SocketAddr = line
            .split("listening on ")
            .nth(1)
            .and_then(|rest| rest.split_whitespace().next())
            .and_then(|a| a.parse().ok())
            .ok_or("no address in the first line")?;
        let client = QtmClient::spawn(QtmClientConfig { addr, ..Default::default() }).map_err(|_| "client")?;
        client.next_timeout(Duration::from_secs(10)).ok_or("no frame")
    })();
    let _ = child.kill();
    let _ = child.wait();
    let f = result.unwrap_or_else(|e| panic!("{e}; first line: {line:?}"));
    assert_eq!(f.frame.body_count, 3);
    assert_eq!(f.frame.bodies.len(), 3);
}

#[test]
fn mock_mocap_cli_reports_a_missing_script() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["mock-mocap", "--port", "0", "--script", "/nonexistent/path/script.csv"])
        .output()
        .expect("run");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("/nonexistent/path/script.csv"), "{err}");
}

// ---------- flood of bad packets over TCP ----------

/// A packet that is framed correctly but wrong inside (the stream stays in sync).
fn bad_in_sync_packet(rng: &mut Rng) -> Vec<u8> {
    let good = data_payload(1, 1, &[euler_component(&[[1.0; 6], [2.0; 6]])]);
    match rng.below(6) {
        0 => packet(7 + rng.below(1000) as i32, &vec![0xab; rng.below(64) as usize]),
        1 => packet(3, &good[..rng.below(good.len() as u64) as usize]),
        2 => packet(3, &(0..rng.below(200)).map(|_| rng.next() as u8).collect::<Vec<_>>()),
        3 => {
            let mut p = good.clone();
            let at = 16 + rng.below(12) as usize;
            p[at..at + 4].copy_from_slice(&(rng.next() as i32).to_be_bytes());
            packet(3, &p)
        }
        4 => packet(3, &data_payload(2, 2, &[euler_component(&[NAN6, NAN6])])),
        _ => text_packet(0, "garbage error"),
    }
}

#[test]
fn thousands_of_bad_tcp_packets_neither_panic_nor_stop_the_client() {
    let listener = TcpListener::bind(loopback0()).expect("bind");
    let addr = listener.local_addr().expect("addr");
    let done = Arc::new(AtomicBool::new(false));
    let server_done = done.clone();
    let server = std::thread::spawn(move || -> usize {
        let mut rng = Rng(0x1234_5678_9abc_def1);
        let mut sent = 0;
        for round in 0..12 {
            let (mut s, _) = listener.accept().expect("accept");
            s.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
            s.write_all(&text_packet(1, "QTM RT Interface connected")).expect("greet");
            for _ in 0..2 {
                let _ = read_raw(&mut s).expect("handshake command");
                s.write_all(&text_packet(1, "ok")).expect("reply");
            }
            let mut blob = Vec::new();
            for _ in 0..250 {
                blob.extend(bad_in_sync_packet(&mut rng));
                sent += 1;
            }
            s.write_all(&blob).expect("bad packets");
            // End the round with something that breaks the stream, or, last, a good frame.
            match round % 4 {
                _ if round == 11 => {
                    let good = [[1.0, 2.0, 3.0, 0.0, 0.0, 0.0]];
                    s.write_all(&packet(3, &data_payload(9, 424_242, &[euler_component(&good)]))).expect("good");
                    while !server_done.load(Ordering::Relaxed) {
                        std::thread::sleep(Duration::from_millis(5));
                    }
                }
                0 => s.write_all(&i32::MAX.to_be_bytes()).expect("huge size"),
                1 => s.write_all(&[0, 0, 0, 3, 0, 0, 0, 3]).expect("size below the header"),
                2 => s.write_all(&[0, 0, 3, 232, 0, 0, 0, 3, 1, 2, 3]).expect("truncated by close"),
                _ => s.write_all(&(0..500).map(|_| rng.next() as u8).collect::<Vec<_>>()).expect("noise"),
            }
            sent += 1;
            // Close gracefully: unread polls at close would make the kernel reset the
            // connection and drop the bad packets still queued for the client.
            let _ = s.shutdown(std::net::Shutdown::Write);
            let mut sink = [0u8; 4096];
            while matches!(s.read(&mut sink), Ok(n) if n > 0) {}
        }
        sent
    });
    let config = QtmClientConfig {
        addr,
        poll_rate_hz: 100.0,
        reconnect_delay: Duration::from_millis(10),
        handshake_timeout: Duration::from_millis(500),
        ..QtmClientConfig::default()
    };
    let client = QtmClient::spawn(config).expect("client");
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut good = None;
    while good.is_none() && Instant::now() < deadline {
        if let Some(f) = client.next_timeout(Duration::from_millis(100))
            && f.frame.frame == 424_242
        {
            good = Some(f);
        }
    }
    done.store(true, Ordering::Relaxed);
    let sent = server.join().expect("server");
    assert!(sent >= 3000, "{sent}");
    let f = good.expect("the client survives the flood and reads the last good frame");
    assert_eq!(f.frame.bodies[0].x_mm, 1.0);
    assert!(client.is_running());
    let stats = client.stats();
    assert!(stats.sessions >= 12, "{stats:?}");
    // About 2/3 of the in-sync packets are malformed (the rest are NaN frames and error replies).
    assert!(stats.bad_packets > 1800, "{stats:?}");
}

#[test]
fn random_bytes_never_panic_the_decoder_or_the_parser() {
    let mut rng = Rng(0xdead_beef_cafe_f00d);
    let valid = packet(3, &data_payload(1, 1, &[euler_component(&[[1.0; 6]; 3])]));
    let (mut packets, mut errors) = (0u32, 0u32);
    for _ in 0..20_000 {
        let bytes: Vec<u8> = match rng.below(3) {
            0 => (0..rng.below(300)).map(|_| rng.next() as u8).collect(),
            1 => {
                let mut v = valid.clone();
                for _ in 0..1 + rng.below(4) {
                    let at = rng.below(v.len() as u64) as usize;
                    v[at] = rng.next() as u8;
                }
                v
            }
            _ => valid[..rng.below(valid.len() as u64) as usize].to_vec(),
        };
        // Straight into the payload parser, and framed through the decoder.
        if parse_data(&bytes).is_err() {
            errors += 1;
        }
        let mut d = PacketDecoder::new(1 << 20);
        d.push(&bytes);
        for _ in 0..64 {
            match d.next_packet() {
                Some(Ok(p)) => {
                    packets += 1;
                    let _ = parse_data(&p.payload);
                }
                Some(Err(QtmError::BadSize { .. })) | None => break,
                Some(Err(_)) => errors += 1,
            }
        }
    }
    assert!(packets > 1000 && errors > 10_000, "{packets} packets, {errors} errors");
}

#[test]
fn absurd_poll_rates_are_refused() {
    for rate in [0.0, -1.0, f64::NAN, f64::INFINITY, 1e-310, 1e9] {
        let config = QtmClientConfig { poll_rate_hz: rate, addr: loopback0(), ..Default::default() };
        assert!(matches!(QtmClient::spawn(config), Err(QtmError::Config(_))), "rate {rate}");
    }
}
