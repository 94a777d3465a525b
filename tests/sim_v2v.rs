//! V2V: the network reaches everyone but the sender, wifi range is inclusive, rounds follow the
//! rates, payloads are shared not copied (small `Copy` ones held inline, with no allocation),
//! and no message is lost between rounds.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::collections::BTreeMap;
use std::sync::Arc;

use bevy_ecs::prelude::{Query, Res, ResMut, Resource};
use bevy_ecs::schedule::ScheduleLabel;
use smlworld::prelude::*;

fn parked(b: &mut SimBuilder, id: i32, p: DVec2) {
    let mut spec = VehicleSpec::new(VehicleId(id), VehicleState::new(p, 0.0, 0.0));
    spec.model = VehicleModel::None;
    b.spawn_vehicle(spec).expect("unique ids");
}

fn send(sim: &mut Sim, id: i32, channel: Channel, payload: impl Into<Payload>) {
    let e = sim.entity(VehicleId(id)).unwrap();
    let now = sim.now();
    sim.world_mut().get_mut::<Mailbox>(e).unwrap().send(channel, now, payload);
}

fn inbox_senders(sim: &Sim, id: i32, channel: Channel) -> Vec<i32> {
    let e = sim.entity(VehicleId(id)).unwrap();
    sim.world().get::<Mailbox>(e).unwrap().inbox(channel).iter().map(|m| m.sender.0).collect()
}

#[test]
fn network_reaches_everyone_but_the_sender_without_copying_the_payload() {
    let mut b = SimBuilder::new();
    b.add_plugin(V2vPlugin::default());
    for i in 0..5 {
        parked(&mut b, -1 - i, DVec2::new(i as f64 * 10_000.0, 0.0));
    }
    let mut sim = b.build();
    let payload = Payload::from(Arc::new(String::from("hello")));
    send(&mut sim, -3, Channel::Network, payload.clone());
    sim.run_for(0.5); // the network round at t = 0
    for id in [-1, -2, -4, -5] {
        assert_eq!(inbox_senders(&sim, id, Channel::Network), vec![-3], "receiver {id}");
        let e = sim.entity(VehicleId(id)).unwrap();
        let inbox = &sim.world().get::<Mailbox>(e).unwrap().network_in;
        let m = inbox.iter().next().unwrap();
        assert_eq!(m.payload::<String>().map(String::as_str), Some("hello"));
        assert!(Payload::ptr_eq(&m.payload, &payload), "payload was copied for receiver {id}");
    }
    assert!(inbox_senders(&sim, -3, Channel::Network).is_empty());
    assert!(inbox_senders(&sim, -1, Channel::Wifi).is_empty(), "network messages leaked onto wifi");
    let stats = *sim.world().resource::<V2vStats>();
    assert_eq!((stats.network_sent, stats.network_delivered), (1, 4));
}

/// The system allocator, counting the allocations of each thread (so that tests running beside
/// each other do not count each other's).
struct CountingAllocator;

thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

// SAFETY: every call is passed on to `System` unchanged; the count is a thread-local `Cell`
// with a const initialiser, which does not allocate.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.with(|a| a.set(a.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static ALLOCATOR: CountingAllocator = CountingAllocator;

fn allocations() -> u64 {
    ALLOCATIONS.with(Cell::get)
}

#[test]
fn a_small_copy_payload_is_sent_without_an_allocation_and_read_as_its_type() {
    let mut mailbox = Mailbox::new(VehicleId(1));
    mailbox.wifi_out.reserve(1000);
    mailbox.network_out.reserve(1000);
    let before = allocations();
    for k in 0..1000 {
        mailbox.send_copy(Channel::Wifi, SimTime(k), k as f64 * 0.5);
        mailbox.send_copy(Channel::Network, SimTime(k), (k as u32, -(k as i64)));
    }
    assert_eq!(allocations() - before, 0, "an allocation per message");
    assert!(mailbox.wifi_out.iter().all(|m| m.payload.is_inline()));
    assert_eq!(mailbox.wifi_out[7].payload::<f64>(), Some(&3.5));
    assert_eq!(mailbox.wifi_out[7].payload::<u64>(), None, "another type of the same size");
    assert_eq!(mailbox.network_out[9].payload::<(u32, i64)>(), Some(&(9, -9)));
    // Shared payloads still cost one allocation each (what the inline form saves).
    let before = allocations();
    for k in 0..100 {
        mailbox.send_typed(Channel::Wifi, SimTime(k), k as f64);
    }
    assert!(allocations() - before >= 100);
}

#[test]
fn small_copy_payloads_arrive_inline_through_both_channels() {
    let mut b = SimBuilder::new();
    b.add_plugin(V2vPlugin::default());
    parked(&mut b, -1, DVec2::new(0.0, 0.0));
    parked(&mut b, -2, DVec2::new(20.0, 0.0));
    parked(&mut b, -3, DVec2::new(5000.0, 0.0));
    let mut sim = b.build();
    for (id, speed) in [(-1, 11.5_f64), (-2, 22.5), (-3, 33.5)] {
        let e = sim.entity(VehicleId(id)).unwrap();
        let now = sim.now();
        let mut mailbox = sim.world_mut().get_mut::<Mailbox>(e).unwrap();
        mailbox.send_copy(Channel::Wifi, now, speed);
        mailbox.send_copy(Channel::Network, now, [id as f32, speed as f32]);
    }
    let e = sim.entity(VehicleId(-1)).unwrap();
    sim.run_for(0.05); // the wifi round at t = 0
    let mailbox = sim.world().get::<Mailbox>(e).unwrap();
    let wifi: Vec<_> = mailbox.received::<f64>(Channel::Wifi).map(|(s, _, v)| (s.0, *v)).collect();
    assert_eq!(wifi, [(-2, 22.5)], "wifi: the one sender in range");
    assert!(mailbox.inbox(Channel::Wifi).iter().all(|m| m.payload.is_inline()));
    sim.run_for(0.45); // the network round at t = 0
    let mailbox = sim.world().get::<Mailbox>(e).unwrap();
    let network: Vec<_> = mailbox.received::<[f32; 2]>(Channel::Network).map(|(s, _, v)| (s.0, *v)).collect();
    assert_eq!(network, [(-3, [-3.0, 33.5]), (-2, [-2.0, 22.5])]);
    assert!(mailbox.inbox(Channel::Network).iter().all(|m| m.payload.is_inline()));
}

#[test]
fn wifi_range_is_inclusive() {
    let mut b = SimBuilder::new();
    b.add_plugin(V2vPlugin { config: V2vConfig { wifi_range: 50.0, ..Default::default() } });
    parked(&mut b, -1, DVec2::new(0.0, 0.0));
    parked(&mut b, -2, DVec2::new(50.0, 0.0)); // exactly at range
    parked(&mut b, -3, DVec2::new(0.0, -50.0 - 1e-6)); // just outside
    parked(&mut b, -4, DVec2::new(30.0, 40.0 - 1e-9)); // just inside
    parked(&mut b, -5, DVec2::new(-1000.0, 0.0));
    parked(&mut b, -6, DVec2::new(-1000.0, 49.0));
    let mut sim = b.build();
    send(&mut sim, -1, Channel::Wifi, Arc::new(1u32));
    send(&mut sim, -5, Channel::Wifi, Arc::new(5u32));
    sim.run_for(0.05); // the wifi round at t = 0
    assert_eq!(inbox_senders(&sim, -2, Channel::Wifi), vec![-1]);
    assert_eq!(inbox_senders(&sim, -3, Channel::Wifi), Vec::<i32>::new());
    assert_eq!(inbox_senders(&sim, -4, Channel::Wifi), vec![-1]);
    assert_eq!(inbox_senders(&sim, -6, Channel::Wifi), vec![-5]);
    assert_eq!(inbox_senders(&sim, -1, Channel::Wifi), Vec::<i32>::new());
    assert_eq!(inbox_senders(&sim, -5, Channel::Wifi), Vec::<i32>::new());
    assert_eq!(sim.world().resource::<V2vStats>().wifi_delivered, 3);
}

#[test]
fn rounds_follow_the_rates_over_ten_seconds() {
    for (wifi, network) in [(10.0, 1.0), (25.0, 2.0), (7.0, 0.5)] {
        let mut b = SimBuilder::with_rates(Rates { wifi, network, ..Default::default() });
        b.add_plugin(V2vPlugin::default());
        parked(&mut b, -1, DVec2::ZERO);
        let mut sim = b.build();
        sim.run_for(10.0);
        let stats = *sim.world().resource::<V2vStats>();
        assert_eq!(stats.wifi_rounds, (wifi * 10.0) as u64, "wifi at {wifi} Hz");
        assert_eq!(stats.network_rounds, (network * 10.0) as u64, "network at {network} Hz");
    }
}

#[test]
fn a_second_v2v_plugin_replaces_the_channels_without_running_each_round_twice() {
    // A scenario adds its channels after `default_plugins` added perfect ones.
    let mut b = SimBuilder::with_rates(Rates { wifi: 10.0, network: 1.0, ..Default::default() });
    b.add_plugin(V2vPlugin::default());
    let config = V2vConfig { wifi_range: 80.0, ..V2vConfig::default() };
    b.add_plugin(V2vPlugin { config });
    parked(&mut b, -1, DVec2::ZERO);
    let mut sim = b.build();
    sim.run_for(10.0);
    let stats = *sim.world().resource::<V2vStats>();
    assert_eq!((stats.wifi_rounds, stats.network_rounds), (100, 10), "each round once");
    assert_eq!(sim.world().resource::<V2vConfig>().wifi_range, 80.0, "the second plugin's channels");
}

/// Every message a receiver has seen: (sender, sequence number).
#[derive(Resource, Default)]
struct Received {
    last_round: BTreeMap<(i32, Channel), u64>,
    seen: Vec<(i32, Channel, u64)>,
}

/// A sender: numbered message on both channels every tick of its schedule.
fn chatter(
    clock: Res<SimClock>,
    mut boxes: Query<(&VehicleId, &mut Mailbox)>,
    mut counter: bevy_ecs::prelude::Local<u64>,
) {
    for (id, mut mailbox) in &mut boxes {
        if id.0 == -1 {
            mailbox.send(Channel::Network, clock.now, Arc::new(*counter));
            mailbox.send(Channel::Wifi, clock.now, Arc::new(*counter));
            *counter += 1;
        }
    }
}

/// A receiver in the control phase: reads only rounds it has not seen yet.
fn listen(boxes: Query<(&VehicleId, &Mailbox)>, mut received: ResMut<Received>) {
    for (id, mailbox) in &boxes {
        if id.0 == -1 {
            continue;
        }
        for channel in [Channel::Network, Channel::Wifi] {
            let inbox = mailbox.inbox(channel);
            let last = received.last_round.get(&(id.0, channel)).copied().unwrap_or(0);
            let new: Vec<u64> = inbox.iter_after(last).map(|m| *m.payload::<u64>().unwrap()).collect();
            received.seen.extend(new.into_iter().map(|n| (id.0, channel, n)));
            if let Some(r) = inbox.latest_round() {
                received.last_round.insert((id.0, channel), r);
            }
        }
    }
}

#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct Chatter;

/// Run 10 s with the sender at `send_rate`, control at `control_rate`; return what the
/// receiver -2 saw per channel and how many messages were sent.
fn exchange(send_rate: f64, control_rate: f64) -> (Vec<u64>, Vec<u64>, u64) {
    let mut b = SimBuilder::with_rates(Rates { control: control_rate, ..Default::default() });
    b.add_plugin(V2vPlugin::default());
    b.add_module("chatter", Chatter, Phase::Control, send_rate);
    b.add_systems(Chatter, chatter);
    b.add_systems(Control, listen);
    b.insert_resource(Received::default());
    parked(&mut b, -1, DVec2::ZERO);
    parked(&mut b, -2, DVec2::new(10.0, 0.0));
    let mut sim = b.build();
    sim.run_for(10.0);
    let sent = sim.scheduler().ticks(Chatter).unwrap();
    let r = sim.world().resource::<Received>();
    let pick = |c: Channel| r.seen.iter().filter(|s| s.0 == -2 && s.1 == c).map(|s| s.2).collect::<Vec<_>>();
    (pick(Channel::Network), pick(Channel::Wifi), sent)
}

#[test]
fn no_message_lost_between_rounds_when_control_is_faster_or_slower() {
    // Sender at 20 Hz, network 1 Hz, wifi 10 Hz, control 20 Hz (faster than V2V): the last round
    // is at t = 9 s (network) / 9.9 s (wifi); a message sent at t is in the first round after t
    // (a round at t itself runs before the control phase at t).
    let (network, wifi, sent) = exchange(20.0, 20.0);
    assert_eq!(sent, 200);
    assert_eq!(network, (0..180).collect::<Vec<u64>>(), "network");
    assert_eq!(wifi, (0..198).collect::<Vec<u64>>(), "wifi");
    // Control at 2 Hz (slower than wifi): every round since the last control tick is kept.
    // The last control tick is at 9.5 s, so it has seen the rounds up to 9.5 s.
    let (network, wifi, _) = exchange(20.0, 2.0);
    assert_eq!(network, (0..180).collect::<Vec<u64>>(), "network, slow control");
    assert_eq!(wifi, (0..190).collect::<Vec<u64>>(), "wifi, slow control");
}

/// A deterministic pseudo-random sequence in [0, 1).
fn lcg(state: &mut u64) -> f64 {
    *state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    (*state >> 11) as f64 / (1u64 << 53) as f64
}

/// How the vehicles of [`moving_wifi_rounds`] are numbered and which send each round.
#[derive(Clone, Copy, PartialEq)]
enum Senders {
    /// Ids -1, -2, ... (falling in spawn order, as the benchmark's); a changing two thirds send.
    Some,
    /// Ids -1, -2, ...; every vehicle sends one message.
    AllFalling,
    /// Ids 1, 2, ... (rising in spawn order); every vehicle sends one message, one of them two.
    AllRising,
}

/// Vehicles with radars and velodynes moving on a square, some or all of them sending on wifi
/// each round (`senders`); every round, each vehicle's in-box holds this round's messages of
/// exactly the senders within `wifi_range` (a scan over everyone). Returns the receptions
/// counted.
fn moving_wifi_rounds(wifi_range: f64, sensor_rate: f64, threads: usize, senders: Senders) -> usize {
    let mut rng = 5u64;
    let mut b = SimBuilder::new();
    b.insert_resource(smlworld::sim::Parallelism { threads, min_vehicles: 0 });
    b.set_rate(Sensors, sensor_rate);
    b.add_plugin(SensorsPlugin);
    b.add_plugin(V2vPlugin { config: V2vConfig { wifi_range, ..Default::default() } });
    let mut vehicles = Vec::new();
    for i in 0..250 {
        let p = DVec2::new(lcg(&mut rng) * 600.0 - 300.0, lcg(&mut rng) * 600.0 - 300.0);
        let yaw = lcg(&mut rng) * std::f64::consts::TAU;
        let id = if senders == Senders::AllRising { 1 + i } else { -1 - i };
        let mut spec = VehicleSpec::new(VehicleId(id), VehicleState::new(p, yaw, 0.0));
        spec.model = VehicleModel::None;
        spec.sensors =
            SensorSet { radar: Some(Radar::default()), velodyne: Some(Velodyne::default()), omniscient: false };
        b.spawn_vehicle(spec).expect("unique ids");
        // Speed [m/s] (up to 40), heading [rad].
        vehicles.push((id, p, lcg(&mut rng) * 40.0, yaw));
    }
    let mut sim = b.build();
    let dt = 0.1; // one wifi round at 10 Hz
    let mut receptions = 0;
    for round in 0..40u32 {
        for (k, (id, p, speed, yaw)) in vehicles.iter_mut().enumerate() {
            if round > 0 {
                *p += DVec2::from_angle(*yaw) * *speed * dt;
                if round % 15 == 7 && k % 60 == 0 {
                    *p += DVec2::new(-120.0, 90.0); // a jump
                }
            }
            let e = sim.entity(VehicleId(*id)).expect("vehicle exists");
            *sim.world_mut().get_mut::<VehicleState>(e).expect("state") = VehicleState::new(*p, *yaw, 0.0);
        }
        let sending = |k: usize| senders != Senders::Some || !(k as u32 + round).is_multiple_of(3);
        for (k, &(id, ..)) in vehicles.iter().enumerate() {
            if sending(k) {
                send(&mut sim, id, Channel::Wifi, Arc::new(round));
            }
        }
        if senders == Senders::AllRising && round % 4 == 1 {
            send(&mut sim, vehicles[7].0, Channel::Wifi, Arc::new(round));
        }
        let now = sim.now();
        sim.run_for(dt);
        for &(id, p, ..) in &vehicles {
            let e = sim.entity(VehicleId(id)).expect("vehicle exists");
            let inbox = sim.world().get::<Mailbox>(e).expect("mailbox").inbox(Channel::Wifi);
            let mut heard: Vec<i32> = inbox.iter().filter(|m| m.sent_at == now).map(|m| m.sender.0).collect();
            heard.sort_unstable();
            let mut expected: Vec<i32> = (vehicles.iter().enumerate())
                .filter(|&(k, o)| sending(k) && o.0 != id && (o.1 - p).length_squared() <= wifi_range * wifi_range)
                .flat_map(|(k, o)| {
                    let twice = senders == Senders::AllRising && round % 4 == 1 && k == 7;
                    std::iter::repeat_n(o.0, 1 + usize::from(twice))
                })
                .collect();
            expected.sort_unstable();
            assert_eq!(heard, expected, "receiver {id}, round {round}, wifi range {wifi_range} m");
            receptions += heard.len();
        }
    }
    receptions
}

#[test]
fn moving_receivers_hear_exactly_the_senders_in_range_round_after_round() {
    // Within the sensors' 100 m (the wifi round reads the sensors' neighbour lists, built at
    // the same instant or kept from an earlier sensor tick, at 20 Hz or at 2 Hz) and beyond it
    // (it cannot: a grid of the senders).
    for threads in [1, 3] {
        assert!(moving_wifi_rounds(50.0, 20.0, threads, Senders::Some) > 10_000);
        assert!(moving_wifi_rounds(50.0, 2.0, threads, Senders::Some) > 10_000);
        assert!(moving_wifi_rounds(170.0, 20.0, threads, Senders::Some) > 10_000);
        // Everyone sending in id order, falling or rising: the round finds each neighbour's
        // messages by its place among the senders without a table (issue 25).
        assert!(moving_wifi_rounds(50.0, 20.0, threads, Senders::AllFalling) > 10_000);
        assert!(moving_wifi_rounds(50.0, 20.0, threads, Senders::AllRising) > 10_000);
    }
}
