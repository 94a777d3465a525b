//! `smlworld run --realtime --stream ADDR`: the vehicles arrive at ADDR as 2015 datagrams at
//! 50 Hz, parsed here field by field from the format (not with our decoder).

use std::net::{Ipv4Addr, UdpSocket};
use std::process::Command;
use std::time::{Duration, Instant};

#[test]
fn run_streams_every_vehicle_at_50_hz() {
    let socket = UdpSocket::bind((Ipv4Addr::LOCALHOST, 0)).expect("bind");
    socket.set_read_timeout(Some(Duration::from_millis(200))).expect("timeout");
    let addr = socket.local_addr().expect("address");
    let out_dir = std::env::temp_dir().join(format!("smlworld_lab_stream_{}", std::process::id()));
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/highway.toml");
    let mut child = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["run", scenario, "--realtime", "--duration", "2", "--stream", &addr.to_string(), "--out"])
        .arg(&out_dir)
        .spawn()
        .expect("start smlworld run");

    let mut counters = Vec::new();
    let mut last_body = String::new();
    let mut buf = [0u8; 65536];
    let deadline = Instant::now() + Duration::from_secs(60);
    while Instant::now() < deadline {
        match socket.recv_from(&mut buf) {
            Ok((n, _)) => {
                let text = std::str::from_utf8(&buf[..n]).expect("ASCII datagram");
                let (counter, body) = text.split_once('#').expect("counter#body");
                counters.push(counter.parse::<u64>().expect("integer counter"));
                last_body = body.to_string();
            }
            Err(_) => {
                if child.try_wait().expect("wait").is_some() {
                    break;
                }
            }
        }
    }
    let status = child.wait().expect("run ends");
    assert!(status.success());
    let _ = std::fs::remove_dir_all(&out_dir);

    // 2 s at 50 Hz: ticks at 0, 20, ..., 1980 ms = 100 frames, counters 0..99 in order.
    assert_eq!(counters, (0..100).collect::<Vec<u64>>());
    let records: Vec<&str> = last_body.split('!').collect();
    assert_eq!(records.len(), 12, "highway.toml has 12 vehicles");
    let mut ids = Vec::new();
    for r in records {
        let fields: std::collections::BTreeMap<&str, &str> =
            r.split(';').map(|kv| kv.split_once('=').expect("key=value")).collect();
        ids.push(fields["id"].parse::<i32>().expect("id"));
        let (x, y): (f64, f64) = (fields["x"].parse().expect("x"), fields["y"].parse().expect("y"));
        // Every vehicle drives a lane of the ring: centre-line radius 52, 56 or 60 m.
        let r = x.hypot(y);
        assert!([52.0, 56.0, 60.0].iter().any(|c| (r - c).abs() < 0.5), "vehicle at radius {r}");
        fields["yaw"].parse::<f64>().expect("yaw in degrees");
        assert!(["Car", "Truck", "Bus"].contains(&fields["class_name"]));
    }
    ids.sort_unstable();
    assert_eq!(ids, (-12..=-1).collect::<Vec<i32>>());
}

#[test]
fn motion_capture_scenarios_refuse_another_speed_than_real_time() {
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/lab_mixed.toml");
    let out = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["run", scenario, "--realtime", "--speed", "2", "--duration", "1", "--out"])
        .arg(std::env::temp_dir().join(format!("smlworld_lab_speed_{}", std::process::id())))
        .output()
        .expect("run smlworld run");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--speed must be 1 with motion capture"), "{err}");
}

/// Every datagram a non-realtime `smlworld run ARGS --stream` sends, as text, until it ends.
fn stream_of(args: &[&str]) -> Vec<String> {
    let socket = UdpSocket::bind((Ipv4Addr::LOCALHOST, 0)).expect("bind");
    socket.set_read_timeout(Some(Duration::from_millis(200))).expect("timeout");
    let addr = socket.local_addr().expect("address").to_string();
    let out_dir = std::env::temp_dir().join(format!("smlworld_lab_stream_{}_{}", args.len(), std::process::id()));
    let mut child = Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["run"])
        .args(args)
        .args(["--stream", &addr, "--out"])
        .arg(&out_dir)
        .spawn()
        .expect("start smlworld run");
    let mut texts = Vec::new();
    let mut buf = [0u8; 65536];
    let deadline = Instant::now() + Duration::from_secs(120);
    while Instant::now() < deadline {
        match socket.recv_from(&mut buf) {
            Ok((n, _)) => texts.push(String::from_utf8_lossy(&buf[..n]).into_owned()),
            Err(_) => {
                if child.try_wait().expect("wait").is_some() {
                    break;
                }
            }
        }
    }
    assert!(child.wait().expect("run ends").success());
    let _ = std::fs::remove_dir_all(&out_dir);
    texts
}

#[test]
fn the_stream_carries_the_indicator_of_a_lane_change_in_progress() {
    let scenario = concat!(env!("CARGO_MANIFEST_DIR"), "/scenarios/overtaking.toml");
    // Paced (40 sim s in one wall second): unpaced, the run sends its 2,000 datagrams within
    // a few milliseconds, more than the receiving socket holds, and those of the return to the
    // right lane (the last ones) were lost now and then (1 run in 6 here).
    let texts = stream_of(&[scenario, "--duration", "40", "--realtime", "--speed", "40"]);
    assert!(!texts.is_empty(), "no datagram arrived");
    // The overtaking car signals left to pass, then right to return (keep right); the first
    // signal seen is left, and both appear.
    let sides: Vec<&str> = texts
        .iter()
        .flat_map(|t| t.split('!'))
        .filter_map(|r| r.split(';').find_map(|kv| kv.strip_prefix("indicator=")))
        .collect();
    assert_eq!(sides.first(), Some(&"left"), "{sides:?}");
    assert!(sides.contains(&"right"), "never signals right on the way back: {sides:?}");
    assert!(sides.iter().all(|s| *s == "left" || *s == "right"), "{sides:?}");
    // The 2015 format never carries it (its viewers know no such key).
    let old = stream_of(&[scenario, "--duration", "40", "--stream-format", "2015"]);
    assert!(!old.is_empty() && old.iter().all(|t| !t.contains("indicator")));
}
