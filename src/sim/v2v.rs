//! V2V: the network round (everyone but the sender) and the wifi round (senders within range).
//!
//! A round takes every out-going message of its channel, sorts them by sender id (so the order
//! never depends on entity layout) into one shared batch, and hands each receiver the batch plus
//! which entries are for it: the payloads are never copied. Wifi finds senders in range with a
//! spatial grid (O(N) per round).
//!
//! Each channel has a [`ChannelModel`] (loss, bursts, delay; perfect by default). A lossy channel
//! decides every reception with a seeded draw ([`super::channel`]); a delaying one queues the
//! reception and [`deliver_delayed`] puts it into the in-box at the first control tick at or
//! after its due time, links never reordered. Wifi stays O(N · neighbours).
//!
//! The network round with a constant, memoryless loss (a [`Loss::Constant`] probability, no
//! bursts, no delay: nothing kept per link, nothing depending on distance) costs O(N) per
//! round, not O(N²): for each receiver it draws how many of the batch's other M messages are
//! lost (one [`binomial`] draw) and stores that count with a key; which ones are lost is a
//! uniformly random subset of that size ([`OrderedSample`]), drawn only when the in-box is
//! read. Given its count, the lost set of independent Bernoulli losses is exactly such a
//! subset, so every receiver still loses each reception independently with probability p.
//! The departure from REFERENCE's keying: these draws are keyed by (seed, network stream,
//! receiver, round, draw number) and not per (sender, receiver, tick, index): one draw no
//! longer belongs to one reception. They remain counter-based, so threads, system order and
//! the order of reading change nothing. Every other network model (bursts, distance loss,
//! delay) decides each reception on its own as before, keyed per reception: O(N²) per round.

use std::collections::HashMap;
use std::sync::Arc;

use bevy_ecs::prelude::{Local, Query, Res, ResMut, Resource};

use super::channel::{ChannelModel, Draw, LinkState, Loss};
use super::random::{OrderedSample, binomial, key, mix, uniform_at};
use super::{Plugin, SimBuilder, SimClock, SimSeed};
use crate::world::{Channel, Mailbox, Message, VehicleId, VehicleState, Vehicles};

use bevy_ecs::schedule::IntoScheduleConfigs;

use super::{Control, ControlEpoch, GridEntry, Network, SimSystems, SpatialGrid, Wifi};

/// Settings of the V2V channels.
#[derive(Resource, Debug, Clone, Copy, PartialEq)]
pub struct V2vConfig {
    /// Wifi range [m], inclusive: a receiver exactly this far from a sender still hears it.
    pub wifi_range: f64,
    /// Loss, bursts and delay of the wifi channel (perfect by default).
    pub wifi: ChannelModel,
    /// Loss, bursts and delay of the network channel (perfect by default; its loss "distance"
    /// model uses the wifi range as its range).
    pub network: ChannelModel,
}

impl Default for V2vConfig {
    fn default() -> Self {
        V2vConfig { wifi_range: 50.0, wifi: ChannelModel::default(), network: ChannelModel::default() }
    }
}

/// Streams of the counter-based draws of each channel (see [`Draw::stream`]).
const WIFI_STREAM: u64 = 0x5769_6669; // "Wifi"
const NETWORK_STREAM: u64 = 0x4e65_7477; // "Netw"
/// Stream of the per-receiver draws of a network round with constant loss (see the module docs).
const NETWORK_LOST_STREAM: u64 = 0x4e65_744c; // "NetL"

/// Delay histogram resolution [µs] and length: 0.5 ms bins up to 5 s (the last bin holds more).
const DELAY_BIN_US: u64 = 500;
const DELAY_BINS: usize = 10_000;

/// What one channel did, counted per receiver: a broadcast heard by five is five sent.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ChannelStats {
    /// Receptions attempted: (message, receiver in range) pairs.
    pub sent: u64,
    /// Receptions not lost (delivered, or still in flight when the run ended).
    pub delivered: u64,
    /// Sum of the delivery delays [µs].
    pub delay_sum_us: u64,
    /// Sum over deliveries of (delivery time - time the message was written) [µs]: the age of
    /// the information when it arrives (out-box wait + delay).
    pub age_sum_us: u64,
    /// Deliveries whose age was counted.
    pub aged: u64,
    /// Histogram of delays in 0.5 ms bins (empty for a channel without delay).
    delay_bins: Vec<u64>,
}

impl ChannelStats {
    /// Receptions lost: `sent - delivered`.
    pub fn lost(&self) -> u64 {
        self.sent - self.delivered
    }

    /// Mean delivery delay [ms].
    pub fn delay_ms_mean(&self) -> f64 {
        if self.delivered == 0 { 0.0 } else { self.delay_sum_us as f64 / self.delivered as f64 / 1000.0 }
    }

    /// 95th percentile of the delivery delay [ms] (to the histogram's 0.5 ms bins).
    pub fn delay_ms_p95(&self) -> f64 {
        let total: u64 = self.delay_bins.iter().sum();
        if total == 0 {
            return 0.0;
        }
        let target = (total as f64 * 0.95).ceil() as u64;
        let mut seen = 0;
        for (i, n) in self.delay_bins.iter().enumerate() {
            seen += n;
            if seen >= target {
                return (i as u64 * DELAY_BIN_US) as f64 / 1000.0;
            }
        }
        0.0
    }

    /// Mean age of information at delivery [ms].
    pub fn age_of_information_ms_mean(&self) -> f64 {
        if self.aged == 0 { 0.0 } else { self.age_sum_us as f64 / self.aged as f64 / 1000.0 }
    }

    fn add_delay(&mut self, delay_us: u64) {
        self.delay_sum_us += delay_us;
        if self.delay_bins.is_empty() {
            self.delay_bins = vec![0; DELAY_BINS];
        }
        self.delay_bins[((delay_us / DELAY_BIN_US) as usize).min(DELAY_BINS - 1)] += 1;
    }
}

/// Per-receiver counts of both channels ([`ChannelStats`]).
#[derive(Resource, Debug, Clone, PartialEq, Default)]
pub struct V2vChannelStats {
    /// The wifi channel.
    pub wifi: ChannelStats,
    /// The network channel.
    pub network: ChannelStats,
}

/// Per-link channel state (bursts, last due time). A `HashMap` because it is only looked up by
/// link and pruned (each entry kept or dropped on its own), never iterated for a result: its
/// order cannot change one.
#[derive(Resource, Debug, Default)]
pub struct V2vLinks {
    wifi: HashMap<(VehicleId, VehicleId), LinkState>,
    network: HashMap<(VehicleId, VehicleId), LinkState>,
    /// Prune when this many links are held (see [`V2vLinks::prune`]).
    prune_at: usize,
}

impl V2vLinks {
    /// Links held, both channels together.
    pub fn len(&self) -> usize {
        self.wifi.len() + self.network.len()
    }

    /// Whether no link is held.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Drop the links of vehicles that left the registry (despawned background traffic), once
    /// the table has doubled since the last prune (at least [`MIN_PRUNE`] links): amortised O(1)
    /// per link, and a table never larger than twice its live links, so memory stays flat
    /// under churn. Ids are never reused in a run, so a dropped link never comes back.
    fn prune(&mut self, registry: &Vehicles) {
        if self.len() < self.prune_at.max(MIN_PRUNE) {
            return;
        }
        let live = |&(a, b): &(VehicleId, VehicleId)| registry.get(a).is_some() && registry.get(b).is_some();
        self.wifi.retain(|link, _| live(link));
        self.network.retain(|link, _| live(link));
        self.prune_at = 2 * self.len();
    }
}

/// Fewest links worth a prune of [`V2vLinks`].
const MIN_PRUNE: usize = 1024;

/// A reception waiting for its due time.
#[derive(Debug, Clone)]
struct Pending {
    due_us: u64,
    receiver: VehicleId,
    channel: Channel,
    round: u64,
    batch: Arc<[Message]>,
    index: u32,
}

/// Receptions of delaying channels not yet due.
#[derive(Resource, Debug, Default)]
pub struct DelayedMessages {
    pending: Vec<Pending>,
    due: Vec<Pending>,
    picks: Vec<u32>,
}

impl DelayedMessages {
    /// Receptions still in flight.
    pub fn len(&self) -> usize {
        self.pending.len()
    }

    /// Whether none is in flight.
    pub fn is_empty(&self) -> bool {
        self.pending.is_empty()
    }
}

/// Counters of the V2V rounds.
#[derive(Resource, Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct V2vStats {
    /// Network rounds run.
    pub network_rounds: u64,
    /// Wifi rounds run.
    pub wifi_rounds: u64,
    /// Network messages sent (taken from out-boxes).
    pub network_sent: u64,
    /// Wifi messages sent.
    pub wifi_sent: u64,
    /// Network deliveries (one message to one receiver counts one).
    pub network_delivered: u64,
    /// Wifi deliveries.
    pub wifi_delivered: u64,
}

/// Sort by sender id, keeping each sender's own order (stable).
fn into_batch(buffer: &mut Vec<Message>) -> Arc<[Message]> {
    buffer.sort_by_key(|m| m.sender);
    buffer.drain(..).collect()
}

/// Network round: every mailbox's in-box gets every message but its own (less what the channel
/// loses; later when it delays).
#[allow(clippy::too_many_arguments)]
pub fn deliver_network(
    config: Res<V2vConfig>,
    clock: Res<SimClock>,
    seed: Option<Res<SimSeed>>,
    epoch: Res<ControlEpoch>,
    mut stats: ResMut<V2vStats>,
    mut channel: ResMut<V2vChannelStats>,
    mut links: ResMut<V2vLinks>,
    registry: Option<Res<Vehicles>>,
    mut delayed: ResMut<DelayedMessages>,
    mut mailboxes: Query<(&VehicleState, &mut Mailbox)>,
    mut buffer: Local<Vec<Message>>,
    mut picks: Local<Vec<u32>>,
    mut positions: Local<Vec<(VehicleId, glam::DVec2)>>,
) {
    stats.network_rounds += 1;
    let round = stats.network_rounds;
    let now = clock.now;
    for (_, mut mailbox) in &mut mailboxes {
        if !mailbox.network_out.is_empty() {
            buffer.append(&mut mailbox.network_out);
        }
    }
    let batch = into_batch(&mut buffer);
    stats.network_sent += batch.len() as u64;
    let age_all: u64 = batch.iter().map(|m| now.0.saturating_sub(m.sent_at.0)).sum();
    let model = config.network;
    if let Some(registry) = &registry {
        links.prune(registry);
    }
    let mut delivered = 0;
    if model.is_perfect() {
        for (_, mut mailbox) in &mut mailboxes {
            let owner = mailbox.owner();
            let own = batch.partition_point(|m| m.sender < owner)..batch.partition_point(|m| m.sender <= owner);
            let n = (batch.len() - own.len()) as u64;
            delivered += n;
            let own_age: u64 = batch[own].iter().map(|m| now.0.saturating_sub(m.sent_at.0)).sum();
            channel.network.age_sum_us += age_all - own_age;
            channel.network.aged += n;
            mailbox.network_in.deliver_all_but(epoch.0, round, &batch, owner);
        }
        channel.network.sent += delivered;
        channel.network.delivered += delivered;
        stats.network_delivered += delivered;
        return;
    }
    let seed = seed.map_or(0, |s| s.0);
    if let (Loss::Constant(p), false) = (model.loss, model.keeps_link_state()) {
        // One age for the whole batch (beacons written at the same tick): the delivered age
        // is that times the count; otherwise the lost ones' ages are taken off one by one.
        let uniform_age = batch.first().map(|m| m.sent_at).filter(|&t| batch.iter().all(|m| m.sent_at == t));
        for (_, mut mailbox) in &mut mailboxes {
            let owner = mailbox.owner();
            let own = batch.partition_point(|m| m.sender < owner)..batch.partition_point(|m| m.sender <= owner);
            let others = (batch.len() - own.len()) as u32;
            let counter = key(seed, NETWORK_LOST_STREAM ^ mix(u64::from(owner.0 as u32)), round);
            let lost = OrderedSample::new(counter, binomial(others, p, uniform_at(counter, 0)), others);
            let kept = u64::from(others - lost.remaining());
            delivered += kept;
            channel.network.sent += u64::from(others);
            channel.network.delivered += kept;
            channel.network.aged += kept;
            channel.network.age_sum_us += match uniform_age {
                Some(t) => kept * now.0.saturating_sub(t.0),
                None => {
                    let age = |m: &Message| now.0.saturating_sub(m.sent_at.0);
                    let own_age: u64 = batch[own.clone()].iter().map(age).sum();
                    let at = |position: u32| {
                        let i = position as usize;
                        if i < own.start { i } else { i + own.len() }
                    };
                    let lost_age: u64 = lost.map(|position| age(&batch[at(position)])).sum();
                    age_all - own_age - lost_age
                }
            };
            mailbox.network_in.deliver_all_but_lost(epoch.0, round, &batch, owner, lost);
        }
        stats.network_delivered += delivered;
        return;
    }
    // Senders' positions for the distance model, sorted by id.
    positions.clear();
    if model.uses_distance() {
        positions.extend(mailboxes.iter().map(|(state, m)| (m.owner(), state.position)));
        positions.sort_by_key(|p| p.0);
    }
    let stateful = model.keeps_link_state();
    for (state, mut mailbox) in &mut mailboxes {
        let owner = mailbox.owner();
        picks.clear();
        let mut index = 0u32;
        let mut previous = None;
        for (k, m) in batch.iter().enumerate() {
            index = if previous == Some(m.sender) { index + 1 } else { 0 };
            previous = Some(m.sender);
            if m.sender == owner {
                continue;
            }
            channel.network.sent += 1;
            // Every vehicle hears every other: look up the distance and keep link state only
            // when the model needs them (a broadcast round is N² receptions).
            let distance = if model.uses_distance() {
                positions
                    .binary_search_by_key(&m.sender, |p| p.0)
                    .map_or(0.0, |i| positions[i].1.distance(state.position))
            } else {
                0.0
            };
            let draw = Draw { seed, stream: NETWORK_STREAM, sender: m.sender.0, receiver: owner.0, round, index };
            let mut fresh = LinkState::default();
            let link = if stateful { links.network.entry((m.sender, owner)).or_default() } else { &mut fresh };
            let Some(delay) = model.deliver(&draw, now.0, distance, config.wifi_range, link) else { continue };
            channel.network.delivered += 1;
            if model.delays() {
                channel.network.add_delay(delay);
                delayed.pending.push(Pending {
                    due_us: now.0 + delay,
                    receiver: owner,
                    channel: Channel::Network,
                    round,
                    batch: Arc::clone(&batch),
                    index: k as u32,
                });
            } else {
                channel.network.age_sum_us += now.0.saturating_sub(m.sent_at.0);
                channel.network.aged += 1;
                picks.push(k as u32);
            }
        }
        if !model.delays() {
            delivered += picks.len() as u64;
            mailbox.network_in.deliver_picks(epoch.0, round, &batch, owner, picks.iter().copied());
        }
    }
    stats.network_delivered += delivered;
}

/// Scratch buffers of the wifi round, kept between rounds.
#[derive(Default)]
pub struct WifiScratch {
    buffer: Vec<Message>,
    /// (sender, position, message count), then sorted by sender.
    senders: Vec<(VehicleId, glam::DVec2, u32)>,
    /// First batch index of each sender's messages.
    starts: Vec<u32>,
    grid: SpatialGrid,
    heard: Vec<u32>,
    picks: Vec<u32>,
}

/// Wifi round: each mailbox's in-box gets the messages of the senders within range (inclusive),
/// less what the channel loses; later when it delays.
#[allow(clippy::too_many_arguments)]
pub fn deliver_wifi(
    config: Res<V2vConfig>,
    clock: Res<SimClock>,
    seed: Option<Res<SimSeed>>,
    epoch: Res<ControlEpoch>,
    mut stats: ResMut<V2vStats>,
    mut channel: ResMut<V2vChannelStats>,
    mut links: ResMut<V2vLinks>,
    registry: Option<Res<Vehicles>>,
    mut delayed: ResMut<DelayedMessages>,
    mut mailboxes: Query<(&VehicleState, &mut Mailbox)>,
    mut scratch: Local<WifiScratch>,
) {
    stats.wifi_rounds += 1;
    let round = stats.wifi_rounds;
    let now = clock.now;
    let seed = seed.map_or(0, |s| s.0);
    let model = config.wifi;
    if let Some(registry) = &registry {
        links.prune(registry);
    }
    let stateful = model.keeps_link_state();
    let s = &mut *scratch;
    s.senders.clear();
    for (state, mut mailbox) in &mut mailboxes {
        if !mailbox.wifi_out.is_empty() {
            s.senders.push((mailbox.owner(), state.position, mailbox.wifi_out.len() as u32));
            s.buffer.append(&mut mailbox.wifi_out);
        }
    }
    let batch = into_batch(&mut s.buffer);
    stats.wifi_sent += batch.len() as u64;
    s.senders.sort_by_key(|&(id, _, _)| id);
    s.starts.clear();
    let mut at = 0;
    for &(_, _, count) in &s.senders {
        s.starts.push(at);
        at += count;
    }
    s.grid.rebuild(
        config.wifi_range,
        s.senders.iter().enumerate().map(|(i, &(id, position, _))| GridEntry {
            position,
            velocity: glam::DVec2::ZERO,
            id,
            index: i as u32,
        }),
    );
    let mut delivered = 0;
    for (state, mut mailbox) in &mut mailboxes {
        let owner = mailbox.owner();
        s.heard.clear();
        let heard = &mut s.heard;
        s.grid.for_each_within(state.position, config.wifi_range, |_, e, _| {
            if e.id != owner {
                heard.push(e.index);
            }
        });
        s.heard.sort_unstable();
        let (senders, starts) = (&s.senders, &s.starts);
        let attempted = s.heard.iter().map(|&i| senders[i as usize].2 as u64).sum::<u64>();
        channel.wifi.sent += attempted;
        if model.is_perfect() {
            let picks = s.heard.iter().flat_map(|&i| {
                let start = starts[i as usize];
                start..start + senders[i as usize].2
            });
            for &i in &s.heard {
                let start = starts[i as usize] as usize;
                for m in &batch[start..start + senders[i as usize].2 as usize] {
                    channel.wifi.age_sum_us += now.0.saturating_sub(m.sent_at.0);
                }
            }
            channel.wifi.aged += attempted;
            channel.wifi.delivered += attempted;
            delivered += attempted;
            mailbox.wifi_in.deliver_picks(epoch.0, round, &batch, owner, picks);
            continue;
        }
        s.picks.clear();
        for &i in &s.heard {
            let (sender, position, count) = senders[i as usize];
            let distance = position.distance(state.position);
            let mut fresh = LinkState::default();
            let link = if stateful { links.wifi.entry((sender, owner)).or_default() } else { &mut fresh };
            for index in 0..count {
                let k = starts[i as usize] + index;
                let draw = Draw { seed, stream: WIFI_STREAM, sender: sender.0, receiver: owner.0, round, index };
                let Some(delay) = model.deliver(&draw, now.0, distance, config.wifi_range, link) else { continue };
                channel.wifi.delivered += 1;
                if model.delays() {
                    channel.wifi.add_delay(delay);
                    delayed.pending.push(Pending {
                        due_us: now.0 + delay,
                        receiver: owner,
                        channel: Channel::Wifi,
                        round,
                        batch: Arc::clone(&batch),
                        index: k,
                    });
                } else {
                    channel.wifi.age_sum_us += now.0.saturating_sub(batch[k as usize].sent_at.0);
                    channel.wifi.aged += 1;
                    s.picks.push(k);
                }
            }
        }
        if !model.delays() {
            delivered += s.picks.len() as u64;
            mailbox.wifi_in.deliver_picks(epoch.0, round, &batch, owner, s.picks.iter().copied());
        }
    }
    stats.wifi_delivered += delivered;
}

/// Put the delayed receptions that are due into their in-boxes (control phase, before the
/// controllers): per receiver and round in one delivery, in round order, so a link keeps its order.
pub fn deliver_delayed(
    clock: Res<SimClock>,
    epoch: Res<ControlEpoch>,
    registry: Res<Vehicles>,
    mut stats: ResMut<V2vStats>,
    mut channel: ResMut<V2vChannelStats>,
    mut delayed: ResMut<DelayedMessages>,
    mut mailboxes: Query<&mut Mailbox>,
) {
    let now = clock.now.0;
    let d = &mut *delayed;
    if d.pending.is_empty() {
        return;
    }
    d.due.clear();
    let mut k = 0;
    while k < d.pending.len() {
        if d.pending[k].due_us <= now {
            d.due.push(d.pending.swap_remove(k));
        } else {
            k += 1;
        }
    }
    // swap_remove scrambles the order: sort what is due by (receiver, channel, round, index).
    d.due.sort_by_key(|p| (p.receiver, p.channel, p.round, p.index));
    let mut start = 0;
    while start < d.due.len() {
        let first = &d.due[start];
        let end = start
            + d.due[start..]
                .iter()
                .take_while(|p| (p.receiver, p.channel, p.round) == (first.receiver, first.channel, first.round))
                .count();
        let group = &d.due[start..end];
        d.picks.clear();
        d.picks.extend(group.iter().map(|p| p.index));
        let stats_of = match first.channel {
            Channel::Wifi => &mut channel.wifi,
            Channel::Network => &mut channel.network,
        };
        for p in group {
            stats_of.age_sum_us += now.saturating_sub(p.batch[p.index as usize].sent_at.0);
            stats_of.aged += 1;
        }
        match first.channel {
            Channel::Wifi => stats.wifi_delivered += group.len() as u64,
            Channel::Network => stats.network_delivered += group.len() as u64,
        }
        if let Some(mut mailbox) = registry.get(first.receiver).and_then(|e| mailboxes.get_mut(e).ok()) {
            let inbox = match first.channel {
                Channel::Wifi => &mut mailbox.wifi_in,
                Channel::Network => &mut mailbox.network_in,
            };
            inbox.deliver_picks(epoch.0, first.round, &first.batch, first.receiver, d.picks.iter().copied());
        }
        start = end;
    }
}

/// Network and wifi V2V in the [`Network`] and [`Wifi`] schedules.
#[derive(Debug, Clone, Copy, Default)]
pub struct V2vPlugin {
    /// Settings (wifi range).
    pub config: V2vConfig,
}

impl Plugin for V2vPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.insert_resource(self.config);
        sim.insert_resource(V2vStats::default());
        sim.insert_resource(V2vChannelStats::default());
        sim.insert_resource(V2vLinks::default());
        sim.insert_resource(DelayedMessages::default());
        sim.add_systems(Network, deliver_network.in_set(SimSystems::Communicate));
        sim.add_systems(Wifi, deliver_wifi.in_set(SimSystems::Communicate));
        if self.config.wifi.delays() || self.config.network.delays() {
            sim.add_systems(Control, deliver_delayed.in_set(SimSystems::Communicate));
        }
    }
}
