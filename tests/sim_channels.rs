//! Channel realism (issue 21): loss, Gilbert-Elliott bursts and delay on the V2V channels,
//! configured in the scenario (`[v2v.wifi]`, `[v2v.network]`), seeded counter-based draws, and
//! `metrics.v2v` counted per receiver.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use smlworld::app::running::metrics::V2vMetrics;
use smlworld::prelude::*;
use smlworld::sim::channel::{Burst, ChannelModel, Loss};
use smlworld::sim::{ChannelStats, Parallelism, V2vChannelStats};

fn parked(b: &mut SimBuilder, id: i32, p: DVec2) {
    let mut spec = VehicleSpec::new(VehicleId(id), VehicleState::new(p, 0.0, 0.0));
    spec.model = VehicleModel::None;
    b.spawn_vehicle(spec).expect("unique ids");
}

fn platoon_brake_with(v2v: &str, seed: u64) -> Scenario {
    let path: PathBuf = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/platoon_brake.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    let text = text.replacen("seed = ", &format!("seed = {seed} # was "), 1);
    Scenario::parse_str(&with_table(&text, v2v), &path).expect("the scenario with channel settings loads")
}

/// `text` with a TOML `table` put before its first `[[vehicles]]`, after every top-level key.
fn with_table(text: &str, table: &str) -> String {
    let at = text.find("\n[[vehicles]]").expect("the scenario has vehicles");
    format!("{}\n{table}{}", &text[..at], &text[at..])
}

/// Run a scenario for `seconds` with `threads` and return its V2V metrics and every final state.
fn run(scenario: &Scenario, seconds: f64, threads: usize) -> (V2vMetrics, Vec<(VehicleId, VehicleState)>) {
    let mut b = scenario.builder().unwrap();
    b.insert_resource(Parallelism { threads, min_vehicles: 0 });
    let mut sim = b.build();
    sim.run_for(seconds);
    let metrics = V2vMetrics::of(sim.world().resource::<V2vChannelStats>());
    (metrics, sim.states())
}

#[test]
fn bernoulli_loss_over_ten_thousand_receptions() {
    let s = platoon_brake_with("[v2v.wifi]\nloss = 0.3\n", 1);
    let (m, _) = run(&s, 75.0, 1);
    assert!(m.wifi.sent >= 10_000, "{} receptions", m.wifi.sent);
    assert_eq!(m.wifi.lost, m.wifi.sent - m.wifi.delivered);
    let ratio = m.wifi.delivered as f64 / m.wifi.sent as f64;
    assert!((ratio - 0.7).abs() < 0.02, "delivered/sent {ratio}");
}

#[test]
fn burst_loss_matches_the_stationary_share() {
    let s = platoon_brake_with("[v2v.wifi]\nburst = { p_enter = 0.05, p_leave = 0.2, loss_in_burst = 1.0 }\n", 3);
    let (m, _) = run(&s, 60.0, 1);
    let loss = m.wifi.lost as f64 / m.wifi.sent as f64;
    let expected = 0.05 / (0.05 + 0.2);
    assert!((loss - expected).abs() < 0.1 * expected, "loss {loss} vs {expected}");
}

#[test]
fn delay_shows_in_the_age_of_information_within_one_control_tick() {
    let (plain, _) = run(&platoon_brake_with("[v2v.wifi]\nloss = 0.0\n", 1), 20.0, 1);
    let (late, _) = run(&platoon_brake_with("[v2v.wifi]\ndelay_ms = 30.0\n", 1), 20.0, 1);
    assert!((late.wifi.delay_ms_mean - 30.0).abs() < 1e-9, "{}", late.wifi.delay_ms_mean);
    assert!((late.wifi.delay_ms_p95 - 30.0).abs() <= 0.5, "{}", late.wifi.delay_ms_p95);
    let extra = late.wifi.age_of_information_ms_mean - plain.wifi.age_of_information_ms_mean;
    // Delivered at the first control tick (20 Hz: 50 ms) at or after the due time.
    assert!((30.0..=30.0 + 50.0).contains(&extra), "the age grew by {extra} ms");
}

#[test]
fn a_delayed_message_reaches_the_inbox_at_the_first_control_tick_after_it_is_due() {
    let model = ChannelModel { delay_ms: 30.0, ..Default::default() };
    let mut b = SimBuilder::new();
    b.add_plugin(V2vPlugin { config: V2vConfig { wifi_range: 50.0, wifi: model, ..Default::default() } });
    parked(&mut b, -1, DVec2::ZERO);
    parked(&mut b, -2, DVec2::new(10.0, 0.0));
    let mut sim = b.build();
    let e = sim.entity(VehicleId(-1)).unwrap();
    let now = sim.now();
    sim.world_mut().get_mut::<Mailbox>(e).unwrap().send(Channel::Wifi, now, Arc::new(7u32));
    let inbox = |sim: &Sim| {
        let e = sim.entity(VehicleId(-2)).unwrap();
        sim.world().get::<Mailbox>(e).unwrap().wifi_in.len()
    };
    sim.run_for(0.049); // wifi round at 0, control tick at 0: not due yet
    assert_eq!(inbox(&sim), 0, "arrived before its delay");
    sim.run_for(0.002); // control tick at 50 ms
    assert_eq!(inbox(&sim), 1, "not delivered at the first control tick after 30 ms");
}

/// Delayed wifi while vehicles come and go between the round and the delivery: what each of
/// `receivers` holds at 51 ms (sender, payload), and the wifi's (sent, delivered).
/// Each receiver and the (sender, payload) of every message in its in-box.
type Heard = Vec<(i32, Vec<(i32, u32)>)>;

fn delayed_wifi_under_churn(threads: usize) -> (Heard, (u64, u64)) {
    let model = ChannelModel { delay_ms: 30.0, ..Default::default() };
    let mut b = SimBuilder::new();
    b.add_plugin(V2vPlugin { config: V2vConfig { wifi_range: 50.0, wifi: model, ..Default::default() } });
    b.insert_resource(Parallelism { threads, min_vehicles: 0 });
    for k in 1..=6 {
        parked(&mut b, -k, DVec2::new(5.0 * k as f64, 0.0));
    }
    let mut sim = b.build();
    let now = sim.now();
    for k in [1, 4] {
        let e = sim.entity(VehicleId(-k)).unwrap();
        sim.world_mut().get_mut::<Mailbox>(e).unwrap().send(Channel::Wifi, now, Arc::new(100 + k as u32));
    }
    sim.run_for(0.01); // the round at 0 queued every reception for 30 ms
    // -2 leaves, -7 comes, -3 leaves: the query's order is not the round's any more.
    smlworld::world::despawn_vehicle(sim.world_mut(), VehicleId(-2)).unwrap();
    let mut spec = VehicleSpec::new(VehicleId(-7), VehicleState::new(DVec2::new(1.0, 0.0), 0.0, 0.0));
    spec.model = VehicleModel::None;
    smlworld::world::spawn_vehicle(sim.world_mut(), spec).unwrap();
    smlworld::world::despawn_vehicle(sim.world_mut(), VehicleId(-3)).unwrap();
    sim.run_for(0.041); // control tick at 50 ms delivers
    let held = [-1, -4, -5, -6, -7]
        .into_iter()
        .map(|id| {
            let e = sim.entity(VehicleId(id)).unwrap();
            let inbox = &sim.world().get::<Mailbox>(e).unwrap().wifi_in;
            (id, inbox.iter().map(|m| (m.sender.0, *m.payload.downcast_ref::<u32>().unwrap())).collect())
        })
        .collect();
    let wifi = &sim.world().resource::<V2vChannelStats>().wifi;
    (held, (wifi.sent, wifi.delivered))
}

#[test]
fn delayed_messages_reach_the_right_inboxes_when_vehicles_come_and_go_before_they_are_due() {
    for threads in [1, 2] {
        let (held, (sent, delivered)) = delayed_wifi_under_churn(threads);
        let expected: Vec<(i32, Vec<(i32, u32)>)> = vec![
            (-1, vec![(-4, 104)]),
            (-4, vec![(-1, 101)]),
            (-5, vec![(-4, 104), (-1, 101)]),
            (-6, vec![(-4, 104), (-1, 101)]),
            (-7, vec![]), // came after the round
        ];
        assert_eq!(held, expected, "{threads} threads");
        // Each of the 2 senders reached the 5 others; the receptions of -2 and -3 count as
        // delivered though nobody was left to read them.
        assert_eq!((sent, delivered), (10, 10), "{threads} threads");
    }
}

#[test]
fn threads_do_not_change_a_lossy_run_and_seeds_do() {
    let v2v = "[v2v.wifi]\nloss = 0.2\njitter_ms = 20.0\n";
    let (a, states_a) = run(&platoon_brake_with(v2v, 1), 40.0, 1);
    let (b, states_b) = run(&platoon_brake_with(v2v, 1), 40.0, 2);
    assert_eq!(a, b);
    let bits = |s: &[(VehicleId, VehicleState)]| {
        s.iter().map(|(id, s)| (id.0, s.position.x.to_bits(), s.position.y.to_bits())).collect::<Vec<_>>()
    };
    assert_eq!(bits(&states_a), bits(&states_b), "1 vs 2 threads");
    let (c, _) = run(&platoon_brake_with(v2v, 2), 40.0, 1);
    assert_ne!(a.wifi.delivered, c.wifi.delivered, "seeds 1 and 2 lost the same receptions");
}

#[test]
fn bad_channel_settings_name_the_key() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/platoon_brake.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    for (table, needle) in [
        ("[v2v.wifi]\nloss = 1.5\n", "v2v.wifi.loss"),
        ("[v2v.network]\nrange = 10.0\n", "v2v.network.range"),
        ("[v2v.wifi]\nloss = { model = \"cosmic\", p_at_range = 0.5 }\n", "cosmic"),
        ("[v2v.wifi]\nburst = { p_enter = 0.1, p_leave = 0.0 }\n", "v2v.wifi.burst.p_leave"),
        ("[v2v.wifi]\ndelay_ms = nan\n", "v2v.wifi.delay_ms"),
    ] {
        let e = Scenario::parse_str(&with_table(&text, table), &path).expect_err(table).to_string();
        assert!(e.contains(needle), "{table}: {e}");
    }
    let ok = with_table(&text, "[v2v.wifi]\nloss = { model = \"distance\", p_at_0 = 0.01, p_at_range = 0.5 }\n");
    Scenario::parse_str(&ok, &path).expect("the distance model loads");
    let _ = Loss::Constant(0.0);
}

/// The summary's `metrics` as JSON, as `summary.json` writes it.
fn metrics_json(sim: &Sim) -> serde_json::Value {
    serde_json::to_value(sim.world().resource::<smlworld::app::running::metrics::Metrics>().summary()).unwrap()
}

#[test]
fn half_the_beacons_lost_a_platoon_falls_back_to_acc_and_does_not_collide() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/platoon_brake.toml");
    let set = [("v2v.wifi.loss".to_string(), toml::Value::Float(0.5))];
    let scenario =
        smlworld::app::running::scenario::load_with_overrides(&path, None, &set, &ControllerRegistry::default())
            .expect("platoon_brake with --set v2v.wifi.loss=0.5 loads");
    let mut sim = scenario.builder().unwrap().build();
    sim.run_for(70.0);
    let m = metrics_json(&sim);
    assert_eq!(m["collision_count"], 0, "{}", m["collisions"]);
    let followers = m["followers"].as_array().unwrap();
    let degraded: Vec<f64> = followers.iter().map(|f| f["degraded_s"].as_f64().expect("degraded_s")).collect();
    assert!(degraded.iter().any(|&d| d > 0.0), "no follower fell back: {degraded:?}");
    for f in followers {
        let age = f["beacon_age_max_s"].as_f64().expect("beacon_age_max_s");
        // Half the rounds lost: some beacon is older than the 0.3 s timeout (3 rounds at 10 Hz).
        assert!(age > 0.3, "{f}");
    }
}

/// platoon_brake with `seed` and the dotted overrides `set` (as `smlworld run --set`).
fn platoon_brake_set(seed: u64, set: &[(&str, &str)]) -> Scenario {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/platoon_brake.toml");
    let set: Vec<(String, toml::Value)> = set
        .iter()
        .map(|(k, v)| (k.to_string(), smlworld::app::running::scenario::parse_override(&format!("{k}={v}")).unwrap().1))
        .collect();
    smlworld::app::running::scenario::load_with_overrides(&path, Some(seed), &set, &ControllerRegistry::default())
        .expect("platoon_brake with overrides loads")
}

#[test]
fn threads_do_not_change_a_run_with_loss_and_sensor_noise_and_seeds_do() {
    let set = [
        ("v2v.wifi.loss", "0.2"),
        ("vehicles.*.sensors.radar.noise", "{ range_sd = 0.2, bearing_sd_deg = 0.5, speed_sd = 0.1 }"),
        ("vehicles.*.sensors.radar.dropout", "0.02"),
        ("vehicles.*.sensors.radar.occlusion", "true"),
    ];
    let sensors = |sim: &Sim| *sim.world().resource::<smlworld::sim::SensorStats>();
    #[allow(clippy::type_complexity)]
    let go = |seed: u64, threads: usize, set: &[(&str, &str)]| {
        let mut b = platoon_brake_set(seed, set).builder().unwrap();
        b.insert_resource(Parallelism { threads, min_vehicles: 0 });
        let mut sim = b.build();
        sim.run_for(40.0);
        let bits: Vec<(i32, u64, u64, u64)> = sim
            .states()
            .iter()
            .map(|(id, s)| (id.0, s.position.x.to_bits(), s.position.y.to_bits(), s.velocity.x.to_bits()))
            .collect();
        (bits, sensors(&sim), metrics_json(&sim))
    };
    let (a, sa, ma) = go(1, 1, &set);
    let (b, sb, mb) = go(1, 2, &set);
    assert_eq!(a, b, "1 vs 2 threads");
    assert_eq!((sa, &ma["v2v"]), (sb, &mb["v2v"]));
    assert!(sa.missed_by_dropout > 0, "{sa:?}");
    // The sensors alone (no wifi loss) make seeds differ.
    let (c, _, _) = go(1, 1, &set[1..]);
    let (d, _, _) = go(2, 1, &set[1..]);
    assert_ne!(c, d, "seeds 1 and 2 drove the same with noisy radars");
    // Nothing random: every seed gives the same bits.
    let plain = |seed: u64| {
        let mut sim = platoon_brake_set(seed, &[]).builder().unwrap().build();
        sim.run_for(40.0);
        sim.states().iter().map(|(id, s)| (id.0, s.position.x.to_bits())).collect::<Vec<_>>()
    };
    assert_eq!(plain(1), plain(2), "a run with nothing random depends on the seed");
}

#[test]
fn bad_sensor_settings_name_the_key() {
    for (key, value, needle) in [
        ("vehicles.0.sensors.radar.dropout", "1.5", "sensors.radar.dropout"),
        ("vehicles.0.sensors.radar.noise.range_sd", "-1.0", "sensors.radar.noise.range_sd"),
        ("vehicles.0.sensors.radar.noise.bearing", "1.0", "bearing"),
    ] {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/platoon_brake.toml");
        let v = smlworld::app::running::scenario::parse_override(&format!("{key}={value}")).unwrap().1;
        let e = smlworld::app::running::scenario::load_with_overrides(
            &path,
            None,
            &[(key.into(), v)],
            &ControllerRegistry::default(),
        )
        .expect_err(key)
        .to_string();
        assert!(e.contains(needle), "{key}: {e}");
    }
}

#[test]
fn link_state_of_despawned_vehicles_is_dropped_so_memory_stays_flat_under_churn() {
    use smlworld::sim::V2vLinks;
    // Bursts keep state per link (a model without bursts or delay keeps none).
    let burst = Burst { p_enter: 0.1, p_leave: 0.5, loss_in_burst: 1.0 };
    let model = ChannelModel { burst: Some(burst), ..Default::default() };
    let mut b = SimBuilder::new();
    b.add_plugin(V2vPlugin { config: V2vConfig { wifi_range: 50.0, wifi: model.clone(), network: model } });
    parked(&mut b, -1, DVec2::ZERO);
    let mut sim = b.build();
    let mut most = 0;
    // 3,000 short-lived vehicles, one at a time beside -1, each talking on both channels.
    for k in 0..3000 {
        let id = VehicleId(-2 - k);
        let mut spec = VehicleSpec::new(id, VehicleState::new(DVec2::new(10.0, 0.0), 0.0, 0.0));
        spec.model = VehicleModel::None;
        smlworld::world::spawn_vehicle(sim.world_mut(), spec).unwrap();
        let now = sim.now();
        for v in [VehicleId(-1), id] {
            let e = sim.entity(v).unwrap();
            let mut mailbox = sim.world_mut().get_mut::<Mailbox>(e).unwrap();
            mailbox.send(Channel::Wifi, now, Arc::new(1u32));
            mailbox.send(Channel::Network, now, Arc::new(2u32));
        }
        sim.run_for(1.0);
        smlworld::world::despawn_vehicle(sim.world_mut(), id).unwrap();
        most = most.max(sim.world().resource::<V2vLinks>().len());
    }
    assert!(most >= 4, "the links were kept at all: {most}");
    // Two live vehicles hold 4 links (2 per channel); a bounded table may hold some stale ones.
    assert!(most <= 2048, "the link table grew to {most} entries under churn");
}

/// Received network messages (sender, sent_at [µs]) of each of `n` parked vehicles after each
/// of three network rounds with constant `loss`, and the network's channel stats. Round 1
/// carries one message per vehicle written at t = 0 (one age); round 2 messages written at
/// 0.25 s (even ids) and 0.5 s (odd ids, two each), so the ages differ.
/// Per round, each vehicle's in-box as (sender, send time [µs]) pairs.
type Rounds = Vec<Vec<Vec<(i32, u64)>>>;

fn lossy_network_rounds(n: i32, loss: f64, seed: u64, threads: usize) -> (Rounds, ChannelStats) {
    let mut b = SimBuilder::new();
    let network = ChannelModel { loss: Loss::Constant(loss), ..Default::default() };
    b.add_plugin(V2vPlugin { config: V2vConfig { network, ..Default::default() } });
    b.insert_resource(SimSeed(seed));
    b.insert_resource(Parallelism::split(threads));
    for i in 0..n {
        // Far apart: wifi is out of play, the network reaches everyone.
        parked(&mut b, -1 - i, DVec2::new(f64::from(i) * 1000.0, 0.0));
    }
    let mut sim = b.build();
    let send_from = |sim: &mut Sim, ids: &mut dyn Iterator<Item = i32>| {
        let now = sim.now();
        for id in ids {
            let e = sim.entity(VehicleId(id)).unwrap();
            sim.world_mut().get_mut::<Mailbox>(e).unwrap().send(Channel::Network, now, Arc::new(id));
        }
    };
    let inboxes = |sim: &Sim| {
        (0..n)
            .map(|i| {
                let e = sim.entity(VehicleId(-1 - i)).unwrap();
                let inbox = &sim.world().get::<Mailbox>(e).unwrap().network_in;
                inbox.iter().map(|m| (m.sender.0, m.sent_at.0)).collect::<Vec<_>>()
            })
            .collect::<Vec<_>>()
    };
    let mut rounds = Vec::new();
    send_from(&mut sim, &mut (0..n).map(|i| -1 - i));
    sim.run_for(0.25); // round 1 at t = 0
    rounds.push(inboxes(&sim));
    send_from(&mut sim, &mut (0..n).map(|i| -1 - i).filter(|id| id % 2 == 0));
    sim.run_for(0.25);
    send_from(&mut sim, &mut (0..n).map(|i| -1 - i).filter(|id| id % 2 != 0));
    send_from(&mut sim, &mut (0..n).map(|i| -1 - i).filter(|id| id % 2 != 0));
    sim.run_for(0.75); // round 2 at t = 1 s
    rounds.push(inboxes(&sim));
    send_from(&mut sim, &mut (0..n).map(|i| -1 - i));
    sim.run_for(1.0); // round 3 at t = 2 s
    rounds.push(inboxes(&sim));
    (rounds, sim.world().resource::<V2vChannelStats>().network.clone())
}

#[test]
fn constant_network_loss_loses_its_share_of_every_round_and_counts_what_the_inboxes_hold() {
    let n = 120;
    for loss in [0.1, 0.4] {
        let (rounds, stats) = lossy_network_rounds(n, loss, 1, 1);
        // Every message reaches the n - 1 others: n, then n / 2 + 2 (n / 2), then n messages.
        let messages = n + (n / 2 + n) + n;
        assert_eq!(stats.sent, (messages * (n - 1)) as u64);
        assert!(stats.sent >= 10_000);
        let held: u64 = rounds.iter().flatten().map(|inbox| inbox.len() as u64).sum();
        assert_eq!(stats.delivered, held, "the stats count what the in-boxes hold");
        let ratio = stats.delivered as f64 / stats.sent as f64;
        assert!((ratio - (1.0 - loss)).abs() < 0.02, "loss {loss}: delivered/sent {ratio}");
        for (r, round) in rounds.iter().enumerate() {
            for (i, inbox) in round.iter().enumerate() {
                let me = -1 - i as i32;
                assert!(inbox.iter().all(|&(s, _)| s != me), "round {r}: {me} heard itself");
                assert!(inbox.windows(2).all(|w| w[0].0 <= w[1].0), "round {r}: {me}'s in-box is not in sender order");
            }
            // No position is favoured: the first and the last sender of the batch lose their share.
            for sender in [-n, -1] {
                let messages = if r == 1 && sender % 2 != 0 { 2 } else { 1 };
                let heard = round.iter().flatten().filter(|&&(s, _)| s == sender).count();
                let share = heard as f64 / f64::from(messages * (n - 1));
                assert!((share - (1.0 - loss)).abs() < 0.12, "round {r}: sender {sender}'s messages heard {share}");
            }
        }
        // Ages: round 1 all 0 (written at the round), round 2 written 0.75 s and 0.5 s before,
        // round 3 again 0; the stats must add exactly the delivered ones.
        let round_time = [0u64, 1_000_000, 2_000_000];
        let ages: u64 = rounds
            .iter()
            .zip(round_time)
            .map(|(round, t)| round.iter().flatten().map(|&(_, sent_at)| t - sent_at).sum::<u64>())
            .sum();
        assert_eq!(stats.age_sum_us, ages, "age of the delivered messages");
        assert_eq!(stats.aged, held);
        assert!(ages > 0);
    }
}

#[test]
fn constant_network_loss_is_the_same_on_any_thread_count_and_differs_by_seed() {
    let (a, sa) = lossy_network_rounds(60, 0.2, 1, 1);
    let (b, sb) = lossy_network_rounds(60, 0.2, 1, 2);
    assert_eq!(a, b, "1 vs 2 threads");
    assert_eq!(sa, sb);
    let (c, _) = lossy_network_rounds(60, 0.2, 2, 1);
    assert_ne!(a, c, "seeds 1 and 2 lost the same receptions");
    // Receivers and rounds draw apart: two receivers (or two rounds) do not lose the same senders.
    let lost_of = |inbox: &Vec<(i32, u64)>, me: i32| {
        (1..=60).map(|k| -k).filter(|&s| s != me && !inbox.iter().any(|&(x, _)| x == s)).collect::<Vec<_>>()
    };
    assert_ne!(lost_of(&a[0][0], -1), lost_of(&a[0][1], -2));
    assert_ne!(lost_of(&a[0][0], -1), lost_of(&a[2][0], -1));
}

#[test]
fn a_perfect_network_round_split_over_threads_delivers_and_counts_what_one_thread_does() {
    // Loss 0: the perfect round (every in-box the batch but its own), which splits its in-boxes
    // over the threads and adds each chunk's counts.
    let n = 90;
    let (one, stats) = lossy_network_rounds(n, 0.0, 1, 1);
    let messages = n + (n / 2 + n) + n;
    assert_eq!((stats.sent, stats.delivered), ((messages * (n - 1)) as u64, (messages * (n - 1)) as u64));
    let held: u64 = one.iter().flatten().map(|inbox| inbox.len() as u64).sum();
    assert_eq!(stats.aged, held);
    let round_time = [0u64, 1_000_000, 2_000_000];
    let ages: u64 =
        one.iter().zip(round_time).map(|(round, t)| round.iter().flatten().map(|&(_, s)| t - s).sum::<u64>()).sum();
    assert_eq!(stats.age_sum_us, ages);
    assert!(ages > 0);
    for threads in [2, 3] {
        let (split, split_stats) = lossy_network_rounds(n, 0.0, 1, threads);
        assert_eq!(split, one, "{threads} threads");
        assert_eq!(split_stats, stats, "{threads} threads");
    }
}

/// The wifi messages (send time [µs], payload) vehicle -2 received from -1, in the order its
/// in-box held them, over 400 wifi rounds with -1 sending two messages each round; `threads` split the
/// wifi round.
fn wifi_arrivals(model: ChannelModel, threads: usize) -> Vec<(u64, u32)> {
    let mut b = SimBuilder::new();
    b.add_plugin(V2vPlugin { config: V2vConfig { wifi_range: 50.0, wifi: model, ..Default::default() } });
    b.insert_resource(Parallelism::split(threads));
    parked(&mut b, -1, DVec2::ZERO);
    parked(&mut b, -2, DVec2::new(10.0, 0.0));
    parked(&mut b, -3, DVec2::new(20.0, 0.0));
    let mut sim = b.build();
    let (mut arrivals, mut seen) = (Vec::new(), std::collections::HashSet::new());
    for step in 0..800 {
        // Control ticks every 50 ms, wifi rounds every 100 ms: send before every other tick.
        if step % 2 == 0 {
            let (e, now) = (sim.entity(VehicleId(-1)).unwrap(), sim.now());
            let mut mailbox = sim.world_mut().get_mut::<Mailbox>(e).unwrap();
            mailbox.send(Channel::Wifi, now, Arc::new(1u32));
            mailbox.send(Channel::Wifi, now, Arc::new(2u32));
        }
        sim.run_for(0.05);
        let e = sim.entity(VehicleId(-2)).unwrap();
        // An in-box holds its rounds until the next delivery: take each message once.
        let inbox = &sim.world().get::<Mailbox>(e).unwrap().wifi_in;
        for m in inbox.iter().filter(|m| m.sender == VehicleId(-1)) {
            let message = (m.sent_at.0, *m.payload::<u32>().unwrap());
            if seen.insert(message) {
                arrivals.push(message);
            }
        }
    }
    arrivals
}

#[test]
fn a_link_keeps_its_order_whether_the_jitter_is_narrower_or_wider_than_the_rounds() {
    // 10 Hz wifi: 40 ms of jitter fits between two rounds (no state kept per link), 350 ms
    // spans four rounds (the link's last due time is kept).
    for jitter_ms in [40.0, 350.0] {
        let model = ChannelModel { delay_ms: 5.0, jitter_ms, ..Default::default() };
        let arrivals = wifi_arrivals(model.clone(), 1);
        assert!(arrivals.len() >= 790, "jitter {jitter_ms}: {} of 800 arrived", arrivals.len());
        let bad = arrivals.windows(2).position(|w| w[0] > w[1]);
        assert!(
            arrivals.is_sorted(),
            "jitter {jitter_ms}: at {bad:?} {:?}: a message overtook an earlier one on its link",
            bad.map(|i| &arrivals[i.saturating_sub(4)..(i + 4).min(arrivals.len())])
        );
        assert_eq!(arrivals, wifi_arrivals(model, 2), "jitter {jitter_ms}: threads changed the arrivals");
    }
}

#[test]
fn a_perfect_wifi_round_ages_its_messages_whether_sent_at_one_instant_or_several() {
    // Five parked vehicles within wifi range. Round 1 (t = 0): all sent at 0 (one instant: the
    // ages are added at once). Round 2 (t = 0.1 s): even ids send at 0.04 s, odd at 0.08 s.
    let n = 5;
    let mut b = SimBuilder::new();
    b.add_plugin(V2vPlugin::default());
    for i in 0..n {
        parked(&mut b, -1 - i, DVec2::new(f64::from(i) * 10.0, 0.0));
    }
    let mut sim = b.build();
    let send = |sim: &mut Sim, odd: Option<bool>| {
        let now = sim.now();
        for id in (0..n).map(|i| -1 - i).filter(|id| odd.is_none_or(|o| (id % 2 != 0) == o)) {
            let e = sim.entity(VehicleId(id)).unwrap();
            sim.world_mut().get_mut::<Mailbox>(e).unwrap().send(Channel::Wifi, now, Arc::new(id));
        }
    };
    let ages = |sim: &Sim, round_us: u64| -> (u64, u64) {
        let (mut sum, mut count) = (0, 0);
        for i in 0..n {
            let e = sim.entity(VehicleId(-1 - i)).unwrap();
            for m in sim.world().get::<Mailbox>(e).unwrap().wifi_in.iter() {
                sum += round_us - m.sent_at.0;
                count += 1;
            }
        }
        (sum, count)
    };
    send(&mut sim, None);
    sim.run_for(0.04);
    let first = ages(&sim, 0);
    send(&mut sim, Some(false));
    sim.run_for(0.04);
    send(&mut sim, Some(true));
    sim.run_for(0.04);
    let second = ages(&sim, 100_000);
    // Round 3 (t = 0.2 s): all sent at 0.12 s, one instant again, 80 ms old.
    send(&mut sim, None);
    sim.run_for(0.1);
    let third = ages(&sim, 200_000);
    let stats = sim.world().resource::<V2vChannelStats>().wifi.clone();
    let all = (n * (n - 1)) as u64;
    assert_eq!(first, (0, all), "round 1: everyone hears the 4 others, sent at the round");
    // Round 2: the 2 even senders' messages are 60 ms old, the 3 odd ones' 20 ms, 4 hearers each.
    assert_eq!(second, (2 * 4 * 60_000 + 3 * 4 * 20_000, all));
    assert_eq!(third, (80_000 * all, all));
    assert_eq!((stats.age_sum_us, stats.aged), (first.0 + second.0 + third.0, 3 * all));
}

#[test]
fn a_network_round_over_several_tables_and_threads_delivers_by_sender_id_then_send_order() {
    // Ids neither rising nor falling in query order, one to three messages a sender, and every
    // fifth vehicle moved to a second ECS table: the round's out-boxes are emptied over the
    // threads table by table, and every in-box gets the others' messages by sender id, each
    // sender's in the order it sent them.
    let n = 40;
    let id = |i: i32| if i % 3 == 0 { 100 + i } else { -1 - i };
    for threads in [1, 2, 3] {
        let mut b = SimBuilder::new();
        b.add_plugin(V2vPlugin::default());
        b.insert_resource(Parallelism::split(threads));
        for i in 0..n {
            // Far apart: wifi is out of play, the network reaches everyone.
            parked(&mut b, id(i), DVec2::new(f64::from(i) * 1000.0, 0.0));
        }
        let mut sim = b.build();
        for i in (0..n).step_by(5) {
            let e = sim.entity(VehicleId(id(i))).unwrap();
            sim.world_mut().entity_mut(e).insert(smlworld::vehicles::LateralShift(0.0));
        }
        let now = sim.now();
        let mut sent: Vec<(i32, u32)> = Vec::new();
        for i in 0..n {
            let e = sim.entity(VehicleId(id(i))).unwrap();
            let mut mailbox = sim.world_mut().get_mut::<Mailbox>(e).unwrap();
            for k in 0..(i % 3 + 1) as u32 {
                mailbox.send(Channel::Network, now, Arc::new(k));
                sent.push((id(i), k));
            }
        }
        sim.run_for(0.25); // the round at t = 0
        // By sender id (a stable sort keeps each sender's in send order).
        sent.sort_by_key(|&(sender, _)| sender);
        for i in 0..n {
            let e = sim.entity(VehicleId(id(i))).unwrap();
            let inbox = &sim.world().get::<Mailbox>(e).unwrap().network_in;
            let got: Vec<(i32, u32)> = inbox.iter().map(|m| (m.sender.0, *m.payload::<u32>().unwrap())).collect();
            let expected: Vec<(i32, u32)> = sent.iter().copied().filter(|&(sender, _)| sender != id(i)).collect();
            assert_eq!(got, expected, "{threads} threads, receiver {}", id(i));
        }
    }
}
