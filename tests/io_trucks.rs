//! Real-truck output: the 2015 status line read by a raw TCP client, scaling by the lab factor,
//! reconnects that leave other trucks alone, bad ids, and clients that misbehave.

use std::io::{BufRead, BufReader, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use smlworld::io::trucks::{Lane, TruckError, TruckServer, TruckServerConfig, TruckState};

fn config() -> TruckServerConfig {
    TruckServerConfig { base_port: 0, ..TruckServerConfig::default() }
}

fn connect(server: &TruckServer, id: i32) -> BufReader<TcpStream> {
    let addr = server.local_addr(id).expect("a server for this id");
    assert!(addr.ip().is_loopback(), "binds to loopback by default");
    let s = TcpStream::connect(addr).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
    BufReader::new(s)
}

/// Read one line the way a truck would: up to `\n`, which must be preceded by `\r`.
fn read_line(r: &mut BufReader<TcpStream>) -> String {
    let mut line = String::new();
    r.read_line(&mut line).expect("a line within 5 s");
    assert!(line.ends_with("\r\n"), "line must end with CRLF: {line:?}");
    line.truncate(line.len() - 2);
    line
}

/// Split `time=<t>XcRtid=<id>,lane=...` into (time, [(key, value)...]).
fn parse_line(line: &str) -> (f64, Vec<(String, String)>) {
    let rest = line.strip_prefix("time=").unwrap_or_else(|| panic!("no `time=` prefix: {line}"));
    let (time, fields) = rest.split_once("XcRt").unwrap_or_else(|| panic!("no `XcRt` separator: {line}"));
    let fields = fields
        .split(',')
        .map(|f| {
            let (k, v) = f.split_once('=').unwrap_or_else(|| panic!("field {f:?} is not key=value"));
            (k.to_string(), v.to_string())
        })
        .collect();
    (time.parse().expect("time is a number"), fields)
}

fn value(fields: &[(String, String)], key: &str) -> f64 {
    let v = &fields.iter().find(|(k, _)| k == key).unwrap_or_else(|| panic!("no {key}")).1;
    v.parse().unwrap_or_else(|_| panic!("{key}={v} is not a number"))
}

fn state(time: f64) -> TruckState {
    TruckState {
        time,
        lane: Lane::Left,
        current_distance: 64.0,
        desired_distance: 32.0,
        velocity: 16.0,
        x: 320.0,
        y: -96.0,
        yaw: 1.5,
        lane_offset: 1.6,
    }
}

#[test]
fn the_2015_line_scaled_by_32() {
    let server = TruckServer::start(&config(), &[0, 3]).expect("start");
    server.publish(3, state(12.5)).expect("publish");
    let mut truck = connect(&server, 3);
    let (time, fields) = parse_line(&read_line(&mut truck));
    assert_eq!(time, 12.5);
    let keys: Vec<&str> = fields.iter().map(|(k, _)| k.as_str()).collect();
    assert_eq!(
        keys,
        ["id", "lane", "current_distance", "desired_distance", "velocity", "x", "y", "yaw", "lane_offset"]
    );
    assert_eq!(fields[0].1, "3");
    assert_eq!(fields[1].1, "left");
    // World values divided by the lab scale 32; time as given.
    assert_eq!(value(&fields, "current_distance"), 2.0);
    assert_eq!(value(&fields, "desired_distance"), 1.0);
    assert_eq!(value(&fields, "velocity"), 0.5);
    assert_eq!(value(&fields, "x"), 10.0);
    assert_eq!(value(&fields, "y"), -3.0);
    // Issue 22 item 1: yaw in degrees, as the 2015 sender sent it (1.5 rad = 85.9437 deg).
    assert!((value(&fields, "yaw") - 1.5f64.to_degrees()).abs() < 1e-4, "{fields:?}");
    assert_eq!(value(&fields, "lane_offset"), 0.05);
    // Later states show up in later lines; lanes are spelled as in 2015.
    for (lane, name) in [(Lane::Center, "center"), (Lane::Right, "right")] {
        server.publish(3, TruckState { lane, ..state(13.0) }).expect("publish");
        let deadline = Instant::now() + Duration::from_secs(5);
        loop {
            let (_, f) = parse_line(&read_line(&mut truck));
            if f[1].1 == name {
                break;
            }
            assert!(Instant::now() < deadline, "lane {name} never sent");
        }
    }
}

#[test]
fn lines_come_at_about_20_hz_and_only_after_a_publish() {
    let server = TruckServer::start(&config(), &[1]).expect("start");
    let mut truck = connect(&server, 1);
    truck.get_ref().set_read_timeout(Some(Duration::from_millis(200))).expect("timeout");
    let mut line = String::new();
    assert!(truck.read_line(&mut line).is_err(), "nothing is sent before the first publish: {line:?}");
    server.publish(1, state(0.0)).expect("publish");
    truck.get_ref().set_read_timeout(Some(Duration::from_secs(5))).expect("timeout");
    read_line(&mut truck);
    let start = Instant::now();
    let mut n = 0;
    while start.elapsed() < Duration::from_millis(500) {
        read_line(&mut truck);
        n += 1;
    }
    // 0.5 s at 20 Hz is 10 lines; the server never sends faster, a loaded machine may send fewer.
    assert!((3..=12).contains(&n), "{n} lines in 0.5 s");
}

#[test]
fn a_truck_reconnects_and_the_others_are_not_affected() {
    let server = TruckServer::start(&config(), &[0, 1]).expect("start");
    server.publish(0, state(1.0)).expect("publish");
    server.publish(1, state(2.0)).expect("publish");
    let mut other = connect(&server, 1);
    read_line(&mut other);
    for round in 0..3 {
        let mut truck = connect(&server, 0);
        let (time, _) = parse_line(&read_line(&mut truck));
        assert_eq!(time, 1.0 + f64::from(round));
        drop(truck);
        server.publish(0, state(2.0 + f64::from(round))).expect("publish");
        // The other truck keeps getting its lines meanwhile.
        let (time, fields) = parse_line(&read_line(&mut other));
        assert_eq!((time, fields[0].1.as_str()), (2.0, "1"));
    }
    assert_eq!(server.connections(0), 3);
    assert_eq!(server.connections(1), 1);
    assert!(server.is_connected(1));
}

#[test]
fn misbehaving_clients_do_not_stop_the_server() {
    let server = TruckServer::start(&config(), &[5]).expect("start");
    server.publish(5, state(3.0)).expect("publish");
    let addr = server.local_addr(5).expect("addr");
    for i in 0..300 {
        let mut s = TcpStream::connect(addr).expect("connect");
        let _ = s.write_all(&vec![i as u8; 1 + i % 700]);
    }
    let mut truck = connect(&server, 5);
    let deadline = Instant::now() + Duration::from_secs(5);
    let (time, _) = parse_line(&read_line(&mut truck));
    assert_eq!(time, 3.0);
    assert!(Instant::now() < deadline);
}

#[test]
fn bad_ids_and_settings_are_errors() {
    assert!(matches!(TruckServer::start(&config(), &[-1]), Err(TruckError::BadId { id: -1, .. })));
    assert!(matches!(TruckServer::start(&config(), &[2, 2]), Err(TruckError::DuplicateId(2))));
    let high = TruckServerConfig { base_port: 65535, ..config() };
    assert!(matches!(TruckServer::start(&high, &[1]), Err(TruckError::BadId { id: 1, base: 65535 })));
    assert!(matches!(
        TruckServer::start(&TruckServerConfig { rate_hz: 0.0, ..config() }, &[1]),
        Err(TruckError::Config(_))
    ));
    assert!(matches!(
        TruckServer::start(&TruckServerConfig { scale: -1.0, ..config() }, &[1]),
        Err(TruckError::Config(_))
    ));
    for rate in [0.0, -1.0, f64::NAN, 1e-310, 1e9] {
        let bad = TruckServerConfig { rate_hz: rate, ..config() };
        assert!(matches!(TruckServer::start(&bad, &[1]), Err(TruckError::Config(_))), "rate {rate}");
    }
    let server = TruckServer::start(&config(), &[4]).expect("start");
    assert!(matches!(server.publish(9, TruckState::default()), Err(TruckError::UnknownId(9))));
    assert_eq!(server.ids().collect::<Vec<_>>(), [4]);
}

#[test]
fn default_ports_are_16000_plus_id() {
    let defaults = TruckServerConfig::default();
    assert_eq!(defaults.base_port, 16000);
    assert_eq!(defaults.rate_hz, 20.0);
    assert_eq!(defaults.scale, 32.0);
    // Bind a high base to avoid clashing with a real lab setup on this machine.
    let base = 47000 + (std::process::id() % 1000) as u16 * 2;
    let server = match TruckServer::start(&TruckServerConfig { base_port: base, ..defaults }, &[0, 1]) {
        Ok(s) => s,
        Err(TruckError::Io { source, .. }) if source.kind() == std::io::ErrorKind::AddrInUse => return,
        Err(e) => panic!("{e}"),
    };
    assert_eq!(server.local_addr(0).map(|a| a.port()), Some(base));
    assert_eq!(server.local_addr(1).map(|a| a.port()), Some(base + 1));
}
