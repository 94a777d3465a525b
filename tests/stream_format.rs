//! Issue 22 items 3 and 4: `--stream-format 2015` sends the class names the 2015 viewers draw
//! and the rear-axle point they centre their sprites on; our viewer draws such a stream where the
//! 2015 viewer would; the default stays our names and the body centre.

use smlworld::world::TurnSignal;
use std::net::{Ipv4Addr, SocketAddr};
use std::path::Path;
use std::time::{Duration, Instant};

use glam::DVec2;
use smlworld::app::Scenario;
use smlworld::io::lab::VizStreamPlugin;
use smlworld::io::viz::{REAR_AXLE_FROM_REAR, StreamFormat, VizFrame, VizReceiver, VizVehicle, viewer_body};
use smlworld::world::{VehicleClass, VehicleId};

/// The lab scenario's vehicles (real trucks 0 and 1 and virtual ones) without the lab bridges,
/// streaming in `format` at 1 Hz: returns the frame of t = 0 and the sim at t = 0.
fn stream(format: StreamFormat) -> (VizFrame, Start) {
    let mut scenario = Scenario::load(Path::new("scenarios/lab_mixed.toml")).unwrap();
    scenario.file.lab = None;
    let mut b = scenario.builder().unwrap();
    let rx = VizReceiver::bind(SocketAddr::from((Ipv4Addr::LOCALHOST, 0))).unwrap();
    b.add_plugin(VizStreamPlugin::new(rx.local_addr(), 1.0).unwrap().with_format(format));
    let mut sim = b.build();
    let start = Start {
        states: sim.states().into_iter().collect(),
        lengths: scenario.file.vehicles.iter().map(|v| (v.id, v.length.unwrap_or(4.12))).collect(),
        classes: scenario.file.vehicles.iter().map(|v| (v.id, v.class)).collect(),
    };
    sim.run_for(0.5);
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        if let Some(f) = rx.latest() {
            assert_eq!(f.counter, 0, "one frame, of t = 0");
            return (f, start);
        }
        assert!(Instant::now() < deadline, "the stream's last frame never arrived");
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// Every vehicle's state and body length at t = 0.
struct Start {
    states: std::collections::BTreeMap<VehicleId, smlworld::world::VehicleState>,
    lengths: std::collections::BTreeMap<i32, f64>,
    classes: std::collections::BTreeMap<i32, VehicleClass>,
}

fn body_of(start: &Start, id: i32) -> (DVec2, f64, f64) {
    let s = start.states[&VehicleId(id)];
    (s.position, s.yaw, start.lengths[&id])
}

#[test]
fn the_2015_format_sends_2015_class_names_and_the_rear_axle_point() {
    let (frame, start) = stream(StreamFormat::Y2015);
    assert!(frame.vehicles.len() >= 4);
    // lab_mixed: real trucks 0 and 1, virtual cars -1, -2, -4, -5, bus -3, truck -6. The name
    // follows the class, not whether the vehicle is real.
    for v in &frame.vehicles {
        let class = start.classes[&v.id];
        let expected = match class {
            VehicleClass::Truck => "SmartVehicle",
            _ => "DummyVehicle",
        };
        assert_eq!(v.class_name, expected, "vehicle {} ({class})", v.id);
        let (centre, yaw, length) = body_of(&start, v.id);
        // The point sits at 0.910 / 4.779 of the body length from its rear bumper.
        let rear = centre - DVec2::from_angle(yaw) * length / 2.0;
        let point = DVec2::new(v.x, v.y);
        let along = (point - rear).dot(DVec2::from_angle(yaw));
        assert!((along - REAR_AXLE_FROM_REAR * length).abs() < 2e-3, "vehicle {}: {along} m from the rear", v.id);
        assert!((point - rear).perp_dot(DVec2::from_angle(yaw)).abs() < 2e-3);
    }
    // Our viewer, told the stream is 2015, draws the body where it is.
    for v in &frame.vehicles {
        let (centre, _, _) = body_of(&start, v.id);
        let (drawn, _, _, _) = viewer_body(StreamFormat::Y2015, v);
        let length = smlworld::io::viz::viewer_footprint(&v.class_name).0;
        // The viewer knows only the class's footprint (the 2015 car, 4.779 m): its centre lies
        // on the body's axis, within the difference of the two lengths' offsets.
        let (_, _, real_length) = body_of(&start, v.id);
        let slack = (length - real_length).abs() * (0.5 - REAR_AXLE_FROM_REAR) + 2e-3;
        assert!(drawn.distance(centre) <= slack, "vehicle {}: drawn at {drawn}, body at {centre}", v.id);
    }
}

#[test]
fn the_default_format_sends_our_names_and_the_body_centre() {
    let (frame, start) = stream(StreamFormat::default());
    for v in &frame.vehicles {
        let ours = ["Car", "Truck", "Bus", "Motorcycle", "Bicycle", "Emergency"];
        assert!(ours.contains(&v.class_name.as_str()), "{}", v.class_name);
        let (centre, _, _) = body_of(&start, v.id);
        assert!(DVec2::new(v.x, v.y).distance(centre) < 2e-3, "vehicle {}", v.id);
        let (drawn, ..) = viewer_body(StreamFormat::Smlworld, v);
        assert!(drawn.distance(centre) < 2e-3);
    }
}

/// A 2015 sender's `SmartVehicle` at P heading θ: the 2015 viewer centres its 7.738 m "Offset"
/// car sprite on P, the car body reaching 0.910 m behind P and 3.869 m ahead
/// (`VisualisationModule.py`). Our viewer draws the same rectangle.
#[test]
fn our_viewer_draws_a_2015_vehicle_where_the_2015_viewer_does() {
    let p = DVec2::new(10.0, -4.0);
    let yaw_deg = 30.0_f64;
    let v =
        VizVehicle { id: -3, x: p.x, y: p.y, yaw_deg, class_name: "SmartVehicle".into(), indicator: TurnSignal::Off };
    let (centre, yaw, length, width) = viewer_body(StreamFormat::Y2015, &v);
    let h = DVec2::from_angle(yaw_deg.to_radians());
    assert!((yaw - yaw_deg.to_radians()).abs() < 1e-12);
    assert!((length, width) == (4.779, 2.096));
    assert!((centre - h * length / 2.0).distance(p - h * 0.910) < 1e-9, "rear bumper");
    assert!((centre + h * length / 2.0).distance(p + h * (4.779 - 0.910)) < 1e-9, "front bumper");
    // Our own stream of the same vehicle: the point is the centre.
    let (centre, ..) = viewer_body(StreamFormat::Smlworld, &v);
    assert_eq!(centre, p);
}

#[test]
fn a_bad_stream_format_names_the_choices() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_smlworld"))
        .args(["run", "scenarios/highway.toml", "--stream", "--stream-format", "2016"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(err.contains("--stream-format") && err.contains("2015") && err.contains("smlworld"), "{err}");
}

/// The table of docs/lab.md ("Stream formats"): each of our classes has one 2015 name, a name the
/// 2015 viewer (`sml_world_old/VisualisationModule.py`, `draw_vehicles`) draws; ids <= -100 are
/// never `DummyVehicle`, which that viewer skips there.
#[test]
fn every_class_maps_to_a_name_the_2015_viewer_draws() {
    let table = [
        (VehicleClass::Car, "DummyVehicle"),
        (VehicleClass::Truck, "SmartVehicle"),
        (VehicleClass::Bus, "DummyVehicle"),
        (VehicleClass::Motorcycle, "DummyVehicle"),
        (VehicleClass::Bicycle, "DummyVehicle"),
        (VehicleClass::Emergency, "SmartVehicle"),
    ];
    assert_eq!(table.len(), VehicleClass::ALL.len(), "every class is in the table");
    for (class, name) in table {
        for id in [0, 3, -1, -99] {
            assert_eq!(StreamFormat::Y2015.class_name(id, class), name, "{class} id {id}");
        }
        for id in [-100, -101, i32::MIN] {
            assert_eq!(StreamFormat::Y2015.class_name(id, class), "SmartVehicle", "{class} id {id}");
        }
        assert_eq!(StreamFormat::Smlworld.class_name(-1, class), class.name(), "our own names by default");
    }
    // What the 2015 viewer draws at the 2015 car's size; our viewer reads every name it sends.
    for name in ["SmartVehicle", "DummyVehicle"] {
        assert_eq!(smlworld::io::viz::viewer_footprint(name), (4.779, 2.096));
    }
}
