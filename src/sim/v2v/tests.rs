use super::batch::*;
use super::*;
use crate::sim::grid::lists::*;
use crate::sim::grid::within_reach;
use crate::sim::{Parallelism, SimBuilder};
use crate::world::Payload;
use crate::world::{Channel, Mailbox, Message, SimTime, VehicleId, VehicleState};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

#[test]
fn the_sensors_lists_are_asked_to_reach_the_wifi_range_also_after_the_config_is_replaced() {
    let config = V2vConfig { wifi_range: 80.0, ..V2vConfig::default() };
    let mut b = SimBuilder::new();
    b.add_plugin(V2vPlugin { config: config.clone() });
    assert_eq!(b.world_mut().resource::<ListFloor>().0, 80.0);
    b.insert_resource(V2vConfig { wifi_range: 30.0, ..config });
    let mut sim = b.build();
    sim.run_for(0.2);
    assert_eq!(sim.world().resource::<ListFloor>().0, 30.0);
}

#[test]
fn the_round_takes_who_is_in_range_from_the_sensor_tick_of_its_instant_and_tests_long_lists_itself() {
    use crate::sim::sensors::SensorsPlugin;
    use crate::sim::{Sensors, Wifi};
    use crate::world::{Radar, SensorSet, VehicleModel, VehicleSpec, Velodyne};
    use glam::DVec2;
    let range = 50.0;
    let mut b = SimBuilder::new();
    b.set_rate(Sensors, 20.0).set_rate(Wifi, 20.0);
    b.add_plugin(SensorsPlugin);
    b.add_plugin(V2vPlugin { config: V2vConfig { wifi_range: range, ..V2vConfig::default() } });
    // A crowd of 80 within 20 m (lists longer than a mask: the round tests them) and a line
    // 12 m apart, some of them exactly 50 m from the crowd's corner (inclusive).
    let mut places: Vec<DVec2> = (0..80).map(|k| DVec2::new(f64::from(k % 9) * 2.5, f64::from(k / 9) * 2.5)).collect();
    places.extend((0..40).map(|k| DVec2::new(f64::from(k) * 12.5 - 30.0, 50.0 + 20.0)));
    places.push(DVec2::new(17.5, 20.0) + DVec2::new(30.0, 40.0)); // 50 m from the crowd's 80th
    let ids: Vec<VehicleId> = (0..places.len()).map(|k| VehicleId(-1 - k as i32)).collect();
    for (&id, &p) in ids.iter().zip(&places) {
        let mut spec = VehicleSpec::new(id, VehicleState::new(p, 0.3, 0.0));
        spec.model = VehicleModel::None;
        spec.sensors =
            SensorSet { radar: Some(Radar::default()), velodyne: Some(Velodyne::default()), omniscient: false };
        b.spawn_vehicle(spec).expect("unique ids");
    }
    let mut sim = b.build();
    let mut noted = 0;
    for round in 0..6 {
        let now = sim.now();
        for &id in &ids {
            let e = sim.entity(id).expect("vehicle");
            sim.world_mut().get_mut::<Mailbox>(e).expect("mailbox").send_copy(Channel::Wifi, now, round);
        }
        sim.run_for(0.05);
        let grid = sim.world().resource::<SensorGrid>();
        // From the third round on the round knows when the next one comes.
        let near = grid.near(range, now);
        assert_eq!(near.is_some(), round >= 2, "round {round}");
        if let Some(near) = near {
            noted += 1;
            // Both kinds of list: some left to the round (more than a mask holds).
            assert!(near.contains(&0) && near.iter().any(|&m| m.count_ones() > 3), "round {round}");
        }
        for (k, &id) in ids.iter().enumerate() {
            let e = sim.entity(id).expect("vehicle");
            let inbox = sim.world().get::<Mailbox>(e).expect("mailbox").inbox(Channel::Wifi);
            let mut heard: Vec<i32> = inbox.iter().filter(|m| m.sent_at == now).map(|m| m.sender.0).collect();
            heard.sort_unstable();
            let mut expected: Vec<i32> = (0..places.len())
                .filter(|&o| o != k && within_reach(places[k], places[o].x, places[o].y, range * range))
                .map(|o| ids[o].0)
                .collect();
            expected.sort_unstable();
            assert_eq!(heard, expected, "receiver {id:?}, round {round}");
        }
    }
    assert_eq!(noted, 4);
}

#[test]
fn a_receivers_own_messages_found_beside_the_last_ones_are_those_the_binary_searches_find() {
    let message = |sender: i32| Message {
        sender: VehicleId(sender),
        sent_at: SimTime(0),
        channel: Channel::Network,
        payload: Payload::copied(0u8),
    };
    // One beacon each; some senders with two or three; gaps (receivers that sent nothing).
    let layouts: [Vec<i32>; 4] = [
        (0..40).collect(),
        (0..40).flat_map(|k| std::iter::repeat_n(k, 1 + usize::from(k % 7 == 3) + usize::from(k % 11 == 5))).collect(),
        (0..40).filter(|k| k % 5 != 2).collect(),
        vec![3],
    ];
    for (n, layout) in layouts.iter().enumerate() {
        let batch: Vec<Message> = layout.iter().map(|&k| message(k)).collect();
        // Receivers in rising, falling and shuffled order, with ids beyond the senders'.
        let rising: Vec<i32> = (-2..43).collect();
        let falling: Vec<i32> = rising.iter().rev().copied().collect();
        let shuffled: Vec<i32> = (0..45).map(|k| (k * 17 + 4) % 45 - 2).collect();
        for receivers in [rising, falling, shuffled] {
            let mut hint = 0;
            for &r in &receivers {
                let owner = VehicleId(r);
                let want = batch.partition_point(|m| m.sender < owner)..batch.partition_point(|m| m.sender <= owner);
                assert_eq!(own_messages(&batch, owner, &mut hint), want, "layout {n}, receiver {r}");
                assert_eq!(hint, want.start);
            }
        }
    }
}

#[test]
fn a_joined_batch_is_the_messages_sorted_by_sender_each_senders_in_its_order() {
    let message = |sender: i32, k: u64| Message {
        sender: VehicleId(sender),
        sent_at: SimTime(k),
        channel: Channel::Wifi,
        payload: Payload::copied(k),
    };
    // A chunk as `Outgoing::take` fills it: one sender per run of messages from it.
    let chunk = |messages: Vec<Message>| {
        let mut out = Outgoing { messages, ..Outgoing::default() };
        for (place, m) in out.messages.iter().enumerate() {
            match out.senders.last_mut() {
                Some(last) if last.id == m.sender => last.count += 1,
                _ => out.senders.push(Sender {
                    id: m.sender,
                    position: glam::DVec2::new(place as f64, 0.0),
                    count: 1,
                    place: place as u32,
                }),
            }
        }
        out.note_order();
        out
    };
    let order = |batch: &[Message]| batch.iter().map(|m| (m.sender.0, m.sent_at.0)).collect::<Vec<_>>();
    let ids = |senders: &[Sender]| senders.iter().map(|s| (s.id.0, s.count)).collect::<Vec<_>>();
    for threads in [1, 2, 3] {
        let parallelism = Parallelism::split(threads);
        let join = |chunks: &mut [Outgoing], buffer: &mut Vec<Message>, senders: &mut Vec<Sender>| {
            let mut starts = Vec::new();
            let (batch, found) = join_batch(chunks, buffer, (senders, &mut starts), parallelism);
            // Each sender's messages start where the ones before it end, and are its own.
            let mut at = 0;
            for (sender, &start) in senders.iter().zip(&starts) {
                assert_eq!(start, at, "{threads} threads: sender {:?}", sender.id);
                let own = &batch[start as usize..(start + sender.count) as usize];
                assert!(own.iter().all(|m| m.sender == sender.id), "{threads} threads: {:?}'s", sender.id);
                at += sender.count;
            }
            assert_eq!(at as usize, batch.len());
            (batch, found)
        };
        // Rising across the chunks: moved straight in.
        let mut chunks = [chunk(vec![message(-3, 0), message(-3, 1)]), chunk(vec![]), chunk(vec![message(2, 2)])];
        let mut senders = Vec::new();
        let (batch, found) = join(&mut chunks, &mut Vec::new(), &mut senders);
        assert_eq!(found, Some(true), "rising");
        assert_eq!(order(&batch), [(-3, 0), (-3, 1), (2, 2)]);
        assert_eq!(ids(&senders), [(-3, 2), (2, 1)]);
        assert!(chunks.iter().all(|c| c.messages.is_empty() && c.senders.is_empty()), "the chunks are emptied");
        // Falling, one message each, over chunks of uneven lengths and an empty one: reversed.
        let mut chunks = [
            chunk(vec![message(9, 0), message(7, 1), message(4, 2)]),
            chunk(vec![]),
            chunk(vec![message(3, 3)]),
            chunk(vec![message(-1, 4), message(-2, 5)]),
        ];
        let mut senders = Vec::new();
        let (batch, found) = join(&mut chunks, &mut Vec::new(), &mut senders);
        assert_eq!(found, Some(false), "falling");
        assert_eq!(order(&batch), [(-2, 5), (-1, 4), (3, 3), (4, 2), (7, 1), (9, 0)]);
        assert_eq!(ids(&senders), [(-2, 1), (-1, 1), (3, 1), (4, 1), (7, 1), (9, 1)]);
        assert_eq!(senders.iter().map(|s| s.place).collect::<Vec<_>>(), [1, 0, 0, 2, 1, 0], "each its own place");
        // Falling with two messages from one sender: sorted (stable), its two in their order.
        let mut chunks = [chunk(vec![message(5, 0), message(5, 1)]), chunk(vec![message(1, 2)])];
        let mut senders = Vec::new();
        let (batch, found) = join(&mut chunks, &mut Vec::new(), &mut senders);
        assert_eq!(found, None, "falling with two from one sender");
        assert_eq!(order(&batch), [(1, 2), (5, 0), (5, 1)]);
        assert_eq!(ids(&senders), [(1, 1), (5, 2)]);
        // Each chunk falling, but not across them; each rising, but not across them.
        for (a, b) in [(vec![(5, 0), (1, 1)], vec![(6, 2), (-4, 3)]), (vec![(1, 0), (5, 1)], vec![(2, 2), (8, 3)])] {
            let make = |v: &[(i32, u64)]| chunk(v.iter().map(|&(s, k)| message(s, k)).collect());
            let mut chunks = [make(&a), make(&b)];
            let mut senders = Vec::new();
            let (batch, found) = join(&mut chunks, &mut Vec::new(), &mut senders);
            assert_eq!(found, None, "neither across the chunks");
            let mut want: Vec<(i32, u64)> = a.iter().chain(&b).copied().collect();
            want.sort_by_key(|m| m.0);
            assert_eq!(order(&batch), want);
            assert!(senders.is_sorted_by_key(|s| s.id) && senders.len() == 4);
        }
        // An earlier table's messages in the buffer (and its senders).
        let mut chunks = [chunk(vec![message(1, 1)])];
        let mut earlier = chunk(vec![message(7, 0), message(1, 5)]);
        let (batch, found) = join(&mut chunks, &mut earlier.messages, &mut earlier.senders);
        assert_eq!(found, None, "an earlier table's messages");
        assert_eq!(order(&batch), [(1, 5), (1, 1), (7, 0)]);
        assert_eq!(ids(&earlier.senders), [(1, 1), (1, 1), (7, 1)]);
    }
}

/// Counts its drops in its own counter.
struct Counted(&'static AtomicUsize);

impl Drop for Counted {
    fn drop(&mut self) {
        self.0.fetch_add(1, Ordering::Relaxed);
    }
}

fn batch(n: usize, drops: &'static AtomicUsize) -> Arc<[Message]> {
    (0..n)
        .map(|i| Message {
            sender: VehicleId(i as i32),
            sent_at: SimTime(0),
            channel: Channel::Wifi,
            payload: Payload::new(Counted(drops)),
        })
        .collect()
}

#[test]
fn a_released_batch_drops_each_message_once_and_only_with_its_last_reference() {
    for threads in [1, 2, 3] {
        // The only reference: every message dropped, once, whatever the thread count.
        static ALONE: AtomicUsize = AtomicUsize::new(0);
        ALONE.store(0, Ordering::Relaxed);
        release(batch(1000, &ALONE), Parallelism::split(threads));
        assert_eq!(ALONE.load(Ordering::Relaxed), 1000, "{threads} threads");
        // Still held elsewhere: nothing dropped until that holder lets go, then all, once.
        static SHARED: AtomicUsize = AtomicUsize::new(0);
        SHARED.store(0, Ordering::Relaxed);
        let held = batch(500, &SHARED);
        release(Arc::clone(&held), Parallelism::split(threads));
        assert_eq!(SHARED.load(Ordering::Relaxed), 0, "{threads} threads");
        assert_eq!(held.len(), 500);
        drop(held);
        assert_eq!(SHARED.load(Ordering::Relaxed), 500, "{threads} threads");
    }
}
