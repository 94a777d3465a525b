//! The network round: every message to everyone but its sender ([`deliver_network`]).

use bevy_ecs::prelude::{Entity, Local, Mut, Query, Res, ResMut};
use std::sync::Arc;

use super::batch::{common_sent_at, into_batch, own_messages};
use super::config::V2vConfig;
use super::delayed::{DelayedMessages, LinkOrder};
use super::stats::{ChannelStats, V2vChannelStats, V2vLinks, V2vStats};
use crate::sim::parallel::{Padded, recycle};
use crate::sim::random::{OrderedSample, binomial, key, mix, uniform_at};
use crate::sim::v2v::channel::{LinkState, Loss, link_key, round_key};
use crate::sim::{ControlEpoch, Parallelism, SimClock, SimSeed};
use crate::world::{BatchRef, Channel, Mailbox, Message, SimTime, VehicleId, VehicleState, Vehicles};

/// Streams of the counter-based draws of each channel (see [`Draw::stream`]).
pub(super) const NETWORK_STREAM: u64 = 0x4e65_7477; // "Netw"
/// Stream of the per-receiver draws of a network round with constant loss (see the module docs).
pub(super) const NETWORK_LOST_STREAM: u64 = 0x4e65_744c; // "NetL"
/// One in-box as the lossy network round's query hands it out.
pub(super) type NetworkItem<'a> = Mut<'a, Mailbox>;

/// Scratch buffers of the network round with constant loss, kept between rounds.
#[derive(Default)]
pub struct LossyScratch {
    pub(super) items: Vec<NetworkItem<'static>>,
    /// Per thread: receptions attempted, delivered, and the delivered ones' age sum [µs].
    pub(super) threads: Vec<Padded<(u64, u64, u64)>>,
}

impl LossyScratch {
    /// Add every thread's counts of this round to `network` (and empty them); returns the
    /// deliveries.
    pub(super) fn absorb(&mut self, network: &mut ChannelStats) -> u64 {
        let mut delivered = 0;
        for t in &mut self.threads {
            let (sent, kept, age_sum_us) = std::mem::take(&mut t.0);
            delivered += kept;
            network.sent += sent;
            network.delivered += kept;
            network.aged += kept;
            network.age_sum_us += age_sum_us;
        }
        delivered
    }
}

/// What every chunk of a network round with constant loss reads (see the module docs).
pub(super) struct LossyRound<'a> {
    pub(super) seed: u64,
    pub(super) round: u64,
    pub(super) p: f64,
    pub(super) now_us: u64,
    pub(super) epoch: u64,
    /// Sum of every message's age [µs].
    pub(super) age_all: u64,
    /// The one time every message was written, if they were all written at once.
    pub(super) uniform_age: Option<SimTime>,
    pub(super) batch: &'a Arc<[Message]>,
}

impl LossyRound<'_> {
    /// Draw how many of the others' messages each in-box of `chunk` loses and deliver the rest,
    /// counting (attempted, delivered, age sum) into `t`.
    pub(super) fn deliver(&self, chunk: &mut [NetworkItem<'_>], Padded(t): &mut Padded<(u64, u64, u64)>) {
        let (batch, now) = (self.batch, self.now_us);
        let shared = BatchRef::new(batch);
        let mut hint = 0;
        for mailbox in chunk.iter_mut() {
            let owner = mailbox.owner();
            let own = own_messages(batch, owner, &mut hint);
            let others = (batch.len() - own.len()) as u32;
            let counter = key(self.seed, NETWORK_LOST_STREAM ^ mix(u64::from(owner.0 as u32)), self.round);
            let lost = OrderedSample::new(counter, binomial(others, self.p, uniform_at(counter, 0)), others);
            let kept = u64::from(others - lost.remaining());
            t.0 += u64::from(others);
            t.1 += kept;
            t.2 += match self.uniform_age {
                Some(sent) => kept * now.saturating_sub(sent.0),
                None => {
                    let age = |m: &Message| now.saturating_sub(m.sent_at.0);
                    let own_age: u64 = batch[own.clone()].iter().map(age).sum();
                    let at = |position: u32| {
                        let i = position as usize;
                        if i < own.start { i } else { i + own.len() }
                    };
                    let lost_age: u64 = lost.map(|position| age(&batch[at(position)])).sum();
                    self.age_all - own_age - lost_age
                }
            };
            mailbox.network_in.deliver_all_but_lost(self.epoch, self.round, &shared, (owner, others as usize), lost);
        }
    }
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
    mut mailboxes: Query<(Entity, &VehicleState, &mut Mailbox)>,
    parallelism: Option<Res<Parallelism>>,
    mut buffer: Local<Vec<Message>>,
    mut picks: Local<Vec<u32>>,
    mut positions: Local<Vec<(VehicleId, glam::DVec2)>>,
    mut lossy: Local<LossyScratch>,
) {
    stats.network_rounds += 1;
    let round = stats.network_rounds;
    let now = clock.now;
    for (_, _, mut mailbox) in &mut mailboxes {
        if !mailbox.network_out.is_empty() {
            buffer.append(&mut mailbox.network_out);
        }
    }
    let batch = into_batch(&mut buffer);
    stats.network_sent += batch.len() as u64;
    let age_all: u64 = batch.iter().map(|m| now.0.saturating_sub(m.sent_at.0)).sum();
    let model = config.network.clone();
    if let Some(registry) = &registry {
        links.prune(registry);
    }
    let mut delivered = 0;
    if model.is_perfect() {
        // Every in-box gets the batch but its own messages: split over the threads, each
        // counting (attempted, delivered, age sum) for its chunk as a lossy round does
        // (integer sums: the same on any split).
        let (epoch, batch) = (epoch.0, &batch);
        let deliver = |boxes: &mut [Mailbox], Padded(t): &mut Padded<(u64, u64, u64)>| {
            let shared = BatchRef::new(batch);
            let mut hint = 0;
            for mailbox in boxes {
                let owner = mailbox.owner();
                let own = own_messages(batch, owner, &mut hint);
                let n = (batch.len() - own.len()) as u64;
                let own_age: u64 = batch[own].iter().map(|m| now.0.saturating_sub(m.sent_at.0)).sum();
                // Attempted and delivered alike: nothing is lost.
                t.0 += n;
                t.1 += n;
                t.2 += age_all - own_age;
                mailbox.network_in.deliver_all_but(epoch, round, &shared, owner);
            }
        };
        let parallelism = parallelism.map_or(Parallelism::single(), |p| *p);
        let threads = &mut lossy.threads;
        if let Ok(tables) = mailboxes.contiguous_iter_mut() {
            for (_, _, mut boxes) in tables {
                parallelism.for_each_chunk(&mut boxes, threads, deliver);
            }
        } else {
            // Only if a component were stored sparsely (none is): one at a time.
            threads.resize_with(threads.len().max(1), Default::default);
            for (_, _, mut mailbox) in &mut mailboxes {
                deliver(std::slice::from_mut(&mut *mailbox), &mut threads[0]);
            }
        }
        stats.network_delivered += lossy.absorb(&mut channel.network);
        return;
    }
    let seed = seed.map_or(0, |s| s.0);
    if let (&Loss::Constant(p), false) = (&model.loss, model.keeps_link_state()) {
        // One age for the whole batch (beacons written at the same tick): the delivered age
        // is that times the count; otherwise the lost ones' ages are taken off one by one.
        let uniform_age = common_sent_at(&batch);
        let input = LossyRound { seed, round, p, now_us: now.0, epoch: epoch.0, age_all, uniform_age, batch: &batch };
        let parallelism = parallelism.map_or(Parallelism::single(), |p| *p);
        let l = &mut *lossy;
        let mut items: Vec<NetworkItem<'_>> = recycle(std::mem::take(&mut l.items));
        items.extend(mailboxes.iter_mut().map(|(_, _, m)| m));
        parallelism.for_each_chunk(&mut items, &mut l.threads, |chunk, t| input.deliver(chunk, t));
        l.items = recycle(items);
        stats.network_delivered += l.absorb(&mut channel.network);
        return;
    }
    // Senders' positions for the distance model, sorted by id.
    positions.clear();
    if model.uses_distance() {
        positions.extend(mailboxes.iter().map(|(_, state, m)| (m.owner(), state.position)));
        positions.sort_by_key(|p| p.0);
    }
    let ordered = model.delays() && delayed.needs_link_order(Channel::Network, now.0, &model);
    let stateful = model.steps_links() || ordered;
    let mut record =
        model.delays().then(|| delayed.open(Channel::Network, round, &batch, mailboxes.iter().map(|(e, _, _)| e)));
    let network_round = round_key(seed, NETWORK_STREAM, round);
    let shared = BatchRef::new(&batch);
    for (slot, (_, state, mut mailbox)) in mailboxes.iter_mut().enumerate() {
        let owner = mailbox.owner();
        picks.clear();
        let mut index = 0u32;
        let mut previous = None;
        let mut order = LinkOrder::default();
        let mut sender_key = 0;
        for (k, m) in batch.iter().enumerate() {
            if previous == Some(m.sender) {
                index += 1;
            } else {
                index = 0;
                order = LinkOrder::default();
                sender_key = link_key(network_round, m.sender.0, owner.0);
            }
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
            let mut fresh = LinkState::default();
            let link = if stateful { links.network.entry((m.sender, owner)).or_default() } else { &mut fresh };
            let ids = (m.sender, owner);
            let Some(delay) = model.deliver_keyed(sender_key, index, ids, now.0, distance, config.wifi_range, link)
            else {
                continue;
            };
            channel.network.delivered += 1;
            if let Some(record) = &mut record {
                let due = order.due(now.0 + delay);
                channel.network.add_delay(due - now.0);
                record.push(slot as u32, k as u32, due);
            } else {
                channel.network.age_sum_us += now.0.saturating_sub(m.sent_at.0);
                channel.network.aged += 1;
                picks.push(k as u32);
            }
        }
        if !model.delays() {
            delivered += picks.len() as u64;
            mailbox.network_in.deliver_picks(epoch.0, round, &shared, owner, picks.iter().copied());
        }
    }
    if let Some(record) = record {
        delayed.keep(record);
    }
    stats.network_delivered += delivered;
}
