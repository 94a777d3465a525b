//! Network input bounds (issue 24): the viewer's reassembler follows a sender that restarts
//! (counter back to 0) or whose counter hit u64::MAX, and caps vehicles per datagram and frame.

use smlworld::io::viz::{
    MAX_VEHICLES_PER_DATAGRAM, MAX_VEHICLES_PER_FRAME, RESTART_AFTER, VizDatagram, VizPart, VizReassembler, VizVehicle,
};
use smlworld::world::TurnSignal;

fn vehicles(n: usize) -> Vec<VizVehicle> {
    (0..n)
        .map(|i| VizVehicle {
            id: -(i as i32) - 1,
            x: i as f64,
            y: 0.0,
            yaw_deg: 0.0,
            class_name: "Car".into(),
            indicator: TurnSignal::Off,
        })
        .collect()
}

fn whole(counter: u64, n: usize) -> VizDatagram {
    VizDatagram { counter, part: None, vehicles: vehicles(n) }
}

/// Counters of the frames delivered when `counters` arrive in this order.
fn delivered(r: &mut VizReassembler, counters: impl IntoIterator<Item = u64>) -> Vec<u64> {
    counters.into_iter().filter_map(|c| r.push(whole(c, 1))).map(|f| f.counter).collect()
}

#[test]
fn a_sender_that_restarts_from_zero_is_followed() {
    let mut r = VizReassembler::new();
    assert_eq!(delivered(&mut r, 500..520).len(), 20);
    // A second `run --stream` starts at 0: after RESTART_AFTER datagrams in order it is followed.
    let after = delivered(&mut r, 0..40);
    assert_eq!(after.first(), Some(&(u64::from(RESTART_AFTER) - 1)), "{after:?}");
    assert_eq!(after.len(), 40 - RESTART_AFTER as usize + 1);
    assert_eq!(r.stats().restarts, 1);
}

#[test]
fn a_counter_at_u64_max_does_not_freeze_the_viewer() {
    let mut r = VizReassembler::new();
    assert_eq!(delivered(&mut r, [u64::MAX]), [u64::MAX]);
    let later = delivered(&mut r, 1..100);
    assert!(later.len() >= 99 - RESTART_AFTER as usize, "frames after the huge counter: {later:?}");
}

#[test]
fn a_few_reordered_datagrams_are_still_stale() {
    let mut r = VizReassembler::new();
    delivered(&mut r, 100..110);
    // Two late datagrams from before: dropped, no restart.
    assert!(delivered(&mut r, [105, 106]).is_empty());
    assert_eq!(r.stats().restarts, 0);
    assert_eq!(delivered(&mut r, [110]), [110]);
}

#[test]
fn vehicles_are_capped_per_datagram_and_per_frame() {
    let mut r = VizReassembler::new();
    let f = r.push(whole(1, MAX_VEHICLES_PER_DATAGRAM + 500)).expect("a frame");
    assert_eq!(f.vehicles.len(), MAX_VEHICLES_PER_DATAGRAM);
    assert_eq!(r.stats().vehicles_dropped, 500);

    // A split frame whose parts add up to more than the frame cap.
    let parts = (MAX_VEHICLES_PER_FRAME / MAX_VEHICLES_PER_DATAGRAM + 3) as u32;
    let mut frame = None;
    for index in 0..parts {
        let d = VizDatagram {
            counter: 2,
            part: Some(VizPart { index, count: parts }),
            vehicles: vehicles(MAX_VEHICLES_PER_DATAGRAM),
        };
        frame = r.push(d).or(frame);
    }
    let frame = frame.expect("the split frame is delivered");
    assert_eq!(frame.vehicles.len(), MAX_VEHICLES_PER_FRAME);
    assert_eq!(r.stats().vehicles_dropped, 500 + 3 * MAX_VEHICLES_PER_DATAGRAM as u64);
}
