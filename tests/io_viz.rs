//! The 2015 visualisation datagram: checked against an independent parser written the way the
//! 2015 Python receiver read it, hand-built datagrams, the split extension with thousands of
//! vehicles, stale counters, UDP loopback and a flood of garbage.

mod common;

use common::Rng;
use smlworld::world::TurnSignal;
use std::collections::BTreeMap;
use std::net::UdpSocket;
use std::time::Duration;

use smlworld::io::viz::{
    MAX_DATAGRAM_LEN, VizEncoder, VizPart, VizReassembler, VizReceiver, VizSender, VizSenderConfig, VizVehicle,
    decode_datagram, encode_frame,
};

/// One vehicle record as the 2015 receiver saw it: key -> text value.
type OldRecord = BTreeMap<String, String>;

/// The 2015 receiver: read at most 4096 bytes, split on `#`, then `!`, then `;`, then `=`.
/// Returns `None` where the old code would have thrown.
fn old_parse(datagram: &[u8]) -> Option<(i64, Vec<OldRecord>)> {
    let read = &datagram[..datagram.len().min(4096)];
    let text = std::str::from_utf8(read).ok()?;
    let parts: Vec<&str> = text.split('#').collect();
    if parts.len() != 2 {
        return None;
    }
    let counter: i64 = parts[0].parse().ok()?;
    let mut vehicles = Vec::new();
    if !parts[1].is_empty() {
        for v in parts[1].split('!') {
            let mut rec = OldRecord::new();
            for field in v.split(';') {
                let kv: Vec<&str> = field.split('=').collect();
                if kv.len() != 2 {
                    return None;
                }
                rec.insert(kv[0].to_string(), kv[1].to_string());
            }
            vehicles.push(rec);
        }
    }
    Some((counter, vehicles))
}

/// The 2015 receiver's display logic: accept a datagram only if its counter is newer.
struct OldReceiver {
    last: i64,
    shown: Vec<OldRecord>,
}

impl OldReceiver {
    fn receive(&mut self, datagram: &[u8]) {
        if let Some((counter, vehicles)) = old_parse(datagram)
            && counter > self.last
        {
            self.last = counter;
            self.shown = vehicles;
        }
    }
}

fn num(rec: &OldRecord, key: &str) -> f64 {
    rec.get(key).unwrap_or_else(|| panic!("key {key} missing in {rec:?}")).parse().expect("a number")
}

/// Vehicle i of the big test frame; its fields are simple functions of i.
fn vehicle(i: usize) -> VizVehicle {
    VizVehicle {
        id: i as i32 - 1500,
        x: i as f64 * 1.5,
        y: -(i as f64) * 0.25,
        yaw_deg: (i % 360) as f64 - 180.0,
        class_name: if i.is_multiple_of(2) { "Truck".into() } else { "Car".into() },
        indicator: TurnSignal::Off,
    }
}

fn check_old_record(rec: &OldRecord, i: usize) {
    assert_eq!(num(rec, "id") as i64, i as i64 - 1500);
    assert!((num(rec, "x") - i as f64 * 1.5).abs() < 1e-3, "x of vehicle {i}: {rec:?}");
    assert!((num(rec, "y") + i as f64 * 0.25).abs() < 1e-3, "y of vehicle {i}: {rec:?}");
    assert!((num(rec, "yaw") - ((i % 360) as f64 - 180.0)).abs() < 1e-2, "yaw of vehicle {i}: {rec:?}");
    assert_eq!(rec["class_name"], if i.is_multiple_of(2) { "Truck" } else { "Car" });
}

#[test]
fn small_frame_is_a_plain_2015_datagram_field_by_field() {
    let vehicles = vec![
        VizVehicle { id: 3, x: 12.5, y: -7.25, yaw_deg: 90.0, class_name: "Truck".into(), indicator: TurnSignal::Off },
        VizVehicle { id: -1, x: 0.0, y: 1e3, yaw_deg: -45.5, class_name: "Car".into(), indicator: TurnSignal::Off },
    ];
    let parts = encode_frame(0, &vehicles);
    assert_eq!(parts.len(), 1);
    let text = std::str::from_utf8(&parts[0]).expect("ASCII");
    assert!(!text.contains("part"), "no split fields in a frame that fits: {text}");
    let (counter, recs) = old_parse(&parts[0]).expect("the 2015 parser reads it");
    assert_eq!(counter, 0);
    assert_eq!(recs.len(), 2);
    assert_eq!(recs[0].keys().map(String::as_str).collect::<Vec<_>>(), ["class_name", "id", "x", "y", "yaw"]);
    assert_eq!(recs[0]["id"], "3");
    assert_eq!(num(&recs[0], "x"), 12.5);
    assert_eq!(num(&recs[0], "y"), -7.25);
    assert_eq!(num(&recs[0], "yaw"), 90.0);
    assert_eq!(recs[0]["class_name"], "Truck");
    assert_eq!(recs[1]["id"], "-1");
    assert_eq!(num(&recs[1], "y"), 1000.0);
    assert_eq!(num(&recs[1], "yaw"), -45.5);
    // The record order is `id;x;y;yaw;class_name`, as in 2015.
    assert!(text.starts_with("0#id=3;x="), "{text}");
    assert!(text.contains(";class_name=Truck!id=-1;x="), "{text}");
}

#[test]
fn empty_frame_has_an_empty_body() {
    let parts = encode_frame(41, &[]);
    assert_eq!(parts, vec![b"41#".to_vec()]);
    let d = decode_datagram(b"41#").expect("empty body");
    assert_eq!(d.counter, 41);
    assert!(d.vehicles.is_empty());
}

#[test]
fn class_names_cannot_break_the_format() {
    let v = VizVehicle {
        id: 1,
        x: 0.0,
        y: 0.0,
        yaw_deg: 0.0,
        class_name: "a;b=c!d#e f\u{e9}".into(),
        indicator: TurnSignal::Off,
    };
    let parts = encode_frame(2, &[v]);
    let (_, recs) = old_parse(&parts[0]).expect("still parseable");
    assert_eq!(recs[0]["class_name"], "a_b_c_d_e_f_");
}

#[test]
fn hand_built_datagrams_decode() {
    let d = decode_datagram(b"7#id=3;x=1.5;y=-2.25;yaw=90;class_name=Truck!id=-1;x=0;y=4;yaw=-180;class_name=Car")
        .expect("valid 2015 datagram");
    assert_eq!(d.counter, 7);
    assert_eq!(d.part, None);
    assert_eq!(
        d.vehicles,
        vec![
            VizVehicle {
                id: 3,
                x: 1.5,
                y: -2.25,
                yaw_deg: 90.0,
                class_name: "Truck".into(),
                indicator: TurnSignal::Off
            },
            VizVehicle {
                id: -1,
                x: 0.0,
                y: 4.0,
                yaw_deg: -180.0,
                class_name: "Car".into(),
                indicator: TurnSignal::Off
            },
        ]
    );
    // Fields in another order and an unknown key are fine.
    let d = decode_datagram(b"8#class_name=Bus;yaw=1;y=2;x=3;speed=9;id=4").expect("any order");
    assert_eq!(
        d.vehicles[0],
        VizVehicle { id: 4, x: 3.0, y: 2.0, yaw_deg: 1.0, class_name: "Bus".into(), indicator: TurnSignal::Off }
    );
    let d = decode_datagram(b"9#id=1;x=0;y=0;yaw=0;class_name=A;part=1;parts=2").expect("split part");
    assert_eq!(d.part, Some(VizPart { index: 1, count: 2 }));
}

#[test]
fn malformed_datagrams_are_errors() {
    let bad: [&[u8]; 12] = [
        b"",
        b"no hash here",
        b"-1#",
        b"x#",
        b"1#id=1;x=0;y=0;yaw=0",
        b"1#id=1;x=zero;y=0;yaw=0;class_name=A",
        b"1#id=99999999999;x=0;y=0;yaw=0;class_name=A",
        b"1#id=1;x=0;y=0;yaw=0;class_name=A;x=1",
        b"1#id=1;x;y=0;yaw=0;class_name=A",
        b"1#id=1;x=0;y=0;yaw=0;class_name=A;part=2;parts=2",
        b"1#id=1;x=0;y=0;yaw=0;class_name=A;part=0",
        b"1#\xff\xfe",
    ];
    for b in bad {
        assert!(decode_datagram(b).is_err(), "{:?} should be refused", String::from_utf8_lossy(b));
    }
}

#[test]
fn receiver_drops_counters_not_newer_than_the_last() {
    let mut r = VizReassembler::new();
    let rec = ";x=0;y=0;yaw=0;class_name=A";
    let mut delivered = Vec::new();
    for counter in [5u64, 3, 5, 6, 6, 2, 9] {
        if let Some(f) = r.push_bytes(format!("{counter}#id={counter}{rec}").as_bytes()) {
            delivered.push(f.counter);
        }
    }
    assert_eq!(delivered, [5, 6, 9]);
    assert_eq!(r.stats().stale, 4);
    assert_eq!(r.stats().frames, 3);
}

#[test]
fn split_parts_share_a_counter_and_are_not_stale_to_a_new_receiver() {
    let rec = |id: i32| format!("id={id};x=0;y=0;yaw=0;class_name=A");
    let part = |c: u64, id: i32, i: u32, n: u32| format!("{c}#{};part={i};parts={n}!{}", rec(id), rec(id + 100));
    let mut r = VizReassembler::new();
    // Parts out of order, then completed.
    assert!(r.push_bytes(part(10, 1, 1, 2).as_bytes()).is_none());
    let f = r.push_bytes(part(10, 0, 0, 2).as_bytes()).expect("frame 10 complete");
    assert_eq!(f.counter, 10);
    assert_eq!(f.vehicles.iter().map(|v| v.id).collect::<Vec<_>>(), [0, 100, 1, 101]);
    // Old counters and repeated parts are stale.
    assert!(r.push_bytes(format!("9#{}", rec(5)).as_bytes()).is_none());
    assert!(r.push_bytes(part(10, 0, 0, 2).as_bytes()).is_none());
    assert_eq!(r.stats().stale, 2);
    // Frame 11 is abandoned when frame 12 starts; its late part is stale.
    assert!(r.push_bytes(part(11, 0, 0, 2).as_bytes()).is_none());
    assert!(r.push_bytes(part(12, 0, 0, 2).as_bytes()).is_none());
    assert!(r.push_bytes(part(11, 1, 1, 2).as_bytes()).is_none());
    let f = r.push_bytes(part(12, 1, 1, 2).as_bytes()).expect("frame 12 complete");
    assert_eq!(f.counter, 12);
    assert_eq!(r.stats().incomplete, 1);
    assert_eq!(r.stats().stale, 3);
    // A plain datagram older than a frame being assembled is stale too.
    assert!(r.push_bytes(part(20, 0, 0, 2).as_bytes()).is_none());
    assert!(r.push_bytes(format!("19#{}", rec(5)).as_bytes()).is_none());
    assert_eq!(r.stats().stale, 4);
    let f = r.push_bytes(format!("21#{}", rec(5)).as_bytes()).expect("a newer plain frame");
    assert_eq!(f.counter, 21);
    assert_eq!(r.stats().incomplete, 2, "frame 20 abandoned");
}

#[test]
fn thousands_of_vehicles_split_old_receiver_shows_first_part_new_receiver_all() {
    let n = 3000;
    let vehicles: Vec<VizVehicle> = (0..n).map(vehicle).collect();
    let mut old = OldReceiver { last: -1, shown: Vec::new() };
    let mut new = VizReassembler::new();
    for counter in 0..3u64 {
        let parts = encode_frame(counter, &vehicles);
        assert!(parts.len() >= 40, "3000 records of ~50 bytes need many parts, got {}", parts.len());
        let mut first_index = 0;
        for (k, p) in parts.iter().enumerate() {
            assert!(p.len() <= MAX_DATAGRAM_LEN, "part {k} is {} bytes", p.len());
            // Every part is a complete 2015 datagram with the frame's counter.
            let (c, recs) = old_parse(p).unwrap_or_else(|| panic!("part {k} is not a valid 2015 datagram"));
            assert_eq!(c, counter as i64);
            assert_eq!(recs[0]["part"], k.to_string());
            assert_eq!(recs[0]["parts"], parts.len().to_string());
            for (j, rec) in recs.iter().enumerate() {
                check_old_record(rec, first_index + j);
            }
            first_index += recs.len();
        }
        assert_eq!(first_index, n, "the parts hold every vehicle once");
        // The 2015 receiver shows exactly the first part of the frame.
        let first_len = old_parse(&parts[0]).map(|(_, r)| r.len()).unwrap_or(0);
        let mut last_frame = None;
        for p in &parts {
            old.receive(p);
            if let Some(f) = new.push_bytes(p) {
                last_frame = Some(f);
            }
        }
        assert_eq!(old.last, counter as i64);
        assert_eq!(old.shown.len(), first_len);
        for (j, rec) in old.shown.iter().enumerate() {
            check_old_record(rec, j);
        }
        let frame = last_frame.expect("the new receiver reassembles the frame");
        assert_eq!(frame.counter, counter);
        assert_eq!(frame.vehicles.len(), n);
        for (i, v) in frame.vehicles.iter().enumerate() {
            let want = vehicle(i);
            assert_eq!(v.id, want.id);
            assert!((v.x - want.x).abs() < 1e-3 && (v.y - want.y).abs() < 1e-3);
            assert!((v.yaw_deg - want.yaw_deg).abs() < 1e-2);
            assert_eq!(v.class_name, want.class_name);
        }
    }
    assert_eq!(new.stats().frames, 3);
}

#[test]
fn reversed_parts_reassemble_too() {
    let vehicles: Vec<VizVehicle> = (0..500).map(vehicle).collect();
    let mut parts = encode_frame(4, &vehicles);
    assert!(parts.len() > 1);
    parts.reverse();
    let mut r = VizReassembler::new();
    let frames: Vec<_> = parts.iter().filter_map(|p| r.push_bytes(p)).collect();
    assert_eq!(frames.len(), 1);
    assert_eq!(frames[0].vehicles.iter().map(|v| v.id).collect::<Vec<_>>(), (-1500..-1000).collect::<Vec<_>>());
}

#[test]
fn udp_loopback_sender_to_receiver_with_a_split_frame() {
    let receiver = VizReceiver::bind("127.0.0.1:0".parse().expect("addr")).expect("bind receiver");
    let config = VizSenderConfig { target: receiver.local_addr(), ..VizSenderConfig::default() };
    let mut sender = VizSender::new(&config).expect("sender");
    let vehicles: Vec<VizVehicle> = (0..2000).map(vehicle).collect();
    let mut frame = None;
    // UDP may drop a datagram; a later frame then completes.
    for _ in 0..20 {
        assert!(sender.send(&vehicles).expect("send") > 1);
        frame = receiver.wait_newer(None, Duration::from_millis(200));
        if frame.is_some() {
            break;
        }
    }
    let frame = frame.unwrap_or_else(|| panic!("no complete frame within 20 tries: {:?}", receiver.stats()));
    assert_eq!(frame.vehicles.len(), 2000);
    assert_eq!(frame.vehicles[1999].id, 499);
    assert!(receiver.is_running());
}

#[test]
fn send_if_due_keeps_the_rate() {
    let sink = UdpSocket::bind("127.0.0.1:0").expect("sink");
    let config = VizSenderConfig { target: sink.local_addr().expect("addr"), rate_hz: 50.0, ..Default::default() };
    let mut sender = VizSender::new(&config).expect("sender");
    assert_eq!(sender.period_us(), 20_000);
    let v = [vehicle(0)];
    // One second of calls every millisecond at 50 Hz: exactly 50 frames (t = 0, 20, ..., 980 ms).
    let sent = (0..1000i64).filter(|ms| sender.send_if_due(ms * 1000, &v).expect("send")).count();
    assert_eq!(sent, 50);
    assert_eq!(sender.next_counter(), 50);
    for rate in [0.0, -5.0, f64::NAN, f64::INFINITY, 1e9] {
        assert!(VizSender::new(&VizSenderConfig { rate_hz: rate, ..Default::default() }).is_err(), "rate {rate}");
    }
    // Extreme clocks do not overflow.
    assert!(sender.send_if_due(i64::MAX - 10, &v).expect("send"));
    assert!(!sender.send_if_due(i64::MAX - 5, &v).expect("not due yet"));
}

fn garbage(rng: &mut Rng) -> Vec<u8> {
    const ALPHABET: &[u8] = b"0123456789#!;=.-+eEaxyidwlsn_NnIf ";
    let valid = "id=1;x=2;y=3;yaw=4;class_name=Car";
    match rng.below(7) {
        0 => (0..rng.below(2000)).map(|_| rng.next() as u8).collect(),
        1 => (0..rng.below(300)).map(|_| ALPHABET[rng.below(ALPHABET.len() as u64) as usize]).collect(),
        2 => {
            let full = format!("{}#{valid}!{valid}", rng.below(1000));
            full.as_bytes()[..rng.below(full.len() as u64) as usize].to_vec()
        }
        3 => format!("{}#{valid}", rng.below(1000)).into_bytes(), // valid, mostly stale
        4 => format!("{}#{valid};part={};parts={}", rng.below(1000), rng.below(5000), rng.next() as u32).into_bytes(),
        5 => format!("99999999999999999999999#{valid}").into_bytes(),
        _ => format!("{}#{valid}!!!;;;==", rng.below(1000)).into_bytes(),
    }
}

#[test]
fn thousands_of_bad_datagrams_neither_panic_nor_stop_the_receiver() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    // Straight into the decoder and reassembler.
    let mut r = VizReassembler::new();
    for _ in 0..20_000 {
        let _ = r.push_bytes(&garbage(&mut rng));
    }
    let s = r.stats();
    assert_eq!(s.datagrams, 20_000);
    assert!(s.decode_errors > 5_000 && s.stale > 100, "{s:?}");
    // Over UDP to a running receiver.
    let receiver = VizReceiver::bind("127.0.0.1:0".parse().expect("addr")).expect("bind");
    let socket = UdpSocket::bind("127.0.0.1:0").expect("bind sender");
    for i in 0..3000 {
        socket.send_to(&garbage(&mut rng), receiver.local_addr()).expect("send garbage");
        if i % 100 == 99 {
            std::thread::sleep(Duration::from_millis(2));
        }
    }
    let good = format!("{}#id=77;x=1;y=2;yaw=3;class_name=Truck", u64::MAX);
    let mut frame = None;
    for _ in 0..20 {
        socket.send_to(good.as_bytes(), receiver.local_addr()).expect("send");
        frame = receiver.wait_newer(Some(u64::MAX - 1), Duration::from_millis(100));
        if frame.is_some() {
            break;
        }
    }
    let frame = frame.expect("the receiver still works after the flood");
    assert_eq!(frame.vehicles[0].id, 77);
    assert!(receiver.is_running());
    let s = receiver.stats();
    assert!(s.decode_errors > 100, "{s:?}");
}

#[test]
fn a_reused_encoder_forgets_the_previous_frame() {
    let mut enc = VizEncoder::new();
    let big: Vec<VizVehicle> = (0..1000).map(vehicle).collect();
    assert!(enc.encode(0, &big).len() > 1);
    let small = enc.encode(1, &big[..2]).to_vec();
    assert_eq!(small.len(), 1);
    let (counter, recs) = old_parse(&small[0]).expect("valid");
    assert_eq!(counter, 1);
    assert_eq!(recs.len(), 2);
    check_old_record(&recs[1], 1);
    assert_eq!(enc.encode(2, &big).len(), encode_frame(2, &big).len());
}

#[test]
fn the_indicator_travels_when_on_and_a_bad_one_names_its_key() {
    let mut v =
        VizVehicle { id: 7, x: 1.0, y: 2.0, yaw_deg: 3.0, class_name: "Car".into(), indicator: TurnSignal::Off };
    for side in [TurnSignal::Left, TurnSignal::Right, TurnSignal::Off] {
        v.indicator = side;
        let parts = encode_frame(5, std::slice::from_ref(&v));
        let text = String::from_utf8(parts[0].clone()).expect("text");
        assert_eq!(text.contains("indicator="), side != TurnSignal::Off, "{text}");
        assert_eq!(decode_datagram(&parts[0]).expect("decodes").vehicles, vec![v.clone()]);
    }
    let err = decode_datagram(b"1#id=1;x=0;y=0;yaw=0;class_name=Car;indicator=up").expect_err("bad side");
    assert!(err.to_string().contains("indicator"), "{err}");
}
