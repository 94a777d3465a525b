//! V2V: the network round (everyone but the sender) and the wifi round (senders within range).
//!
//! A round takes every out-going message of its channel, sorts them by sender id (so the order
//! never depends on entity layout) into one shared batch, and hands each receiver the batch plus
//! which entries are for it: the payloads are never copied. Wifi finds senders in range with a
//! spatial grid (O(N) per round), or, when the sensors' neighbour lists still hold everyone
//! within the wifi range (every vehicle in one ECS table with sensors reaching at least as far,
//! nobody moved half their skin since their build), from those lists: no grid to build, a
//! short list per receiver ([`crate::sim::sensors`]). Either way the same receptions.
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
use std::mem::ManuallyDrop;
use std::sync::Arc;

use bevy_ecs::prelude::{Entity, Local, Mut, Query, Res, ResMut, Resource};

use super::channel::{ChannelModel, LinkState, Loss, link_key, round_key};
use super::random::{OrderedSample, binomial, key, mix, uniform_at};
use super::{Plugin, SimBuilder, SimClock, SimSeed};
use crate::world::{BatchRef, Channel, Mailbox, Message, SimTime, VehicleId, VehicleState, Vehicles};

use bevy_ecs::schedule::IntoScheduleConfigs;

use super::grid::within_reach;
use super::parallel::{Padded, recycle};
use super::sensors::{DriftScratch, ListFloor, Lists, NEAR_MASK_BITS, NearWanted, SensorGrid};
use super::{Candidates, Control, ControlEpoch, GridEntry, Network, Parallelism, SimSystems, SpatialGrid, Wifi};

/// Settings of the V2V channels.
#[derive(Resource, Debug, Clone, PartialEq)]
pub struct V2vConfig {
    /// Wifi range \[m\], inclusive: a receiver exactly this far from a sender still hears it.
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
    /// Sum of the delivery delays \[µs\].
    pub delay_sum_us: u64,
    /// Sum over deliveries of (delivery time - time the message was written) \[µs\]: the age of
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

    /// Mean delivery delay \[ms\].
    pub fn delay_ms_mean(&self) -> f64 {
        if self.delivered == 0 { 0.0 } else { self.delay_sum_us as f64 / self.delivered as f64 / 1000.0 }
    }

    /// 95th percentile of the delivery delay \[ms\] (to the histogram's 0.5 ms bins).
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

    /// Mean age of information at delivery \[ms\].
    pub fn age_of_information_ms_mean(&self) -> f64 {
        if self.aged == 0 { 0.0 } else { self.age_sum_us as f64 / self.aged as f64 / 1000.0 }
    }

    /// Count one delivery delay [µs]; returns its histogram bin.
    fn add_delay(&mut self, delay_us: u64) -> usize {
        self.delay_sum_us += delay_us;
        if self.delay_bins.is_empty() {
            self.delay_bins = vec![0; DELAY_BINS];
        }
        let bin = ((delay_us / DELAY_BIN_US) as usize).min(DELAY_BINS - 1);
        self.delay_bins[bin] += 1;
        bin
    }

    /// Add `other`'s counts to these and zero them; `bins` (lowest, highest) covers every
    /// histogram bin `other` counted in (lowest > highest: none).
    fn absorb(&mut self, other: &mut ChannelStats, bins: (usize, usize)) {
        self.sent += std::mem::take(&mut other.sent);
        self.delivered += std::mem::take(&mut other.delivered);
        self.delay_sum_us += std::mem::take(&mut other.delay_sum_us);
        self.age_sum_us += std::mem::take(&mut other.age_sum_us);
        self.aged += std::mem::take(&mut other.aged);
        if bins.0 <= bins.1 && !other.delay_bins.is_empty() {
            if self.delay_bins.is_empty() {
                self.delay_bins = vec![0; DELAY_BINS];
            }
            for (mine, theirs) in
                self.delay_bins[bins.0..=bins.1].iter_mut().zip(&mut other.delay_bins[bins.0..=bins.1])
            {
                *mine += std::mem::take(theirs);
            }
        }
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

/// A reception waiting for its due time: 16 bytes, no reference count (the round holds the
/// batch once). `slot` is the receiver's place in the round's [`DelayedRound::receivers`]
/// ([`GONE`] once it left the world).
#[derive(Debug, Clone, Copy)]
struct Reception {
    due_us: u64,
    slot: u32,
    index: u32,
}

/// The slot of a reception whose receiver left the world before it was due.
const GONE: u32 = u32::MAX;

/// One round's receptions of a delaying channel not yet delivered, in the order the round made
/// them: grouped by receiver, receivers in query order (their slots never decrease), each
/// receiver's in batch order.
#[derive(Debug)]
struct DelayedRound {
    channel: Channel,
    round: u64,
    batch: Arc<[Message]>,
    /// Every mailbox's entity in the query order of the round: slot k is `receivers[k]`. While
    /// the world keeps that order (no vehicle came or went), the delivery walks the in-boxes in
    /// the same order, in parallel chunks, without looking one up.
    receivers: Vec<Entity>,
    receptions: Vec<Reception>,
    /// Earliest and latest due time of `receptions` [µs].
    first_due_us: u64,
    last_due_us: u64,
    /// When every message of `batch` was written at the same time (beacons of one tick): that
    /// time [µs], so a delivery's age sum is its count times one age, not a read per message.
    sent_at_us: Option<u64>,
}

/// Receptions of delaying channels not yet due: one record per round (its batch shared once,
/// its receptions and receivers in reused buffers), so a delayed reception costs a 16-byte push
/// and its delivery a step through the in-boxes in query order, not a reference count, a sort
/// or a search each.
#[derive(Resource, Debug, Default)]
pub struct DelayedMessages {
    /// Rounds in the order they ran (each channel's in round order).
    rounds: std::collections::VecDeque<DelayedRound>,
    /// Emptied reception and receiver buffers, reused by later rounds.
    spare: Vec<(Vec<Reception>, Vec<Entity>)>,
    /// Time of each channel's previous delaying round [µs], indexed by `Channel as usize`, for
    /// [`DelayedMessages::needs_link_order`].
    previous_round_us: [Option<u64>; 2],
}

impl DelayedMessages {
    /// Receptions still in flight.
    pub fn len(&self) -> usize {
        self.rounds.iter().map(|r| r.receptions.len()).sum()
    }

    /// Whether none is in flight.
    pub fn is_empty(&self) -> bool {
        self.rounds.iter().all(|r| r.receptions.is_empty())
    }

    /// A record for `round`'s receptions on `channel` to the mailboxes `receivers` (in query
    /// order; filled with [`DelayedRound::push`], kept with [`DelayedMessages::keep`]).
    fn open(
        &mut self,
        channel: Channel,
        round: u64,
        batch: &Arc<[Message]>,
        receivers: impl Iterator<Item = Entity>,
    ) -> DelayedRound {
        let (mut receptions, mut entities) = self.spare.pop().unwrap_or_default();
        receptions.clear();
        entities.clear();
        entities.extend(receivers);
        let sent_at_us = common_sent_at(batch).map(|t| t.0);
        DelayedRound {
            channel,
            round,
            batch: Arc::clone(batch),
            receivers: entities,
            receptions,
            first_due_us: u64::MAX,
            last_due_us: 0,
            sent_at_us,
        }
    }

    /// Keep `round` until its receptions are due (or recycle its buffer when it has none).
    fn keep(&mut self, round: DelayedRound) {
        if round.receptions.is_empty() {
            self.spare.push((round.receptions, round.receivers));
        } else {
            self.rounds.push_back(round);
        }
    }

    /// Whether this round of `channel` at `now_us` must order its links by their last due time
    /// ([`LinkState::last_due_us`]), and note the round's time. A link's messages of one round
    /// are ordered within the round (see [`LinkOrder`]); across rounds nothing can overtake
    /// when the rounds lie further apart than the delay's spread, since then every message of
    /// this round is due after every one of the previous round; so with a fixed rate and a
    /// jitter below its period no per-link state is kept for delays after the first round
    /// (which keeps it: the spacing is not known yet, and the second round may need it). A
    /// channel's rounds run at its fixed rate, so the spacing does not change within a run.
    fn needs_link_order(&mut self, channel: Channel, now_us: u64, model: &ChannelModel) -> bool {
        let slot = &mut self.previous_round_us[channel as usize];
        let previous = slot.replace(now_us);
        previous.is_none_or(|p| now_us.saturating_sub(p) < model.delay_spread_us())
    }
}

impl DelayedRound {
    fn push(&mut self, slot: u32, index: u32, due_us: u64) {
        self.first_due_us = self.first_due_us.min(due_us);
        self.last_due_us = self.last_due_us.max(due_us);
        self.receptions.push(Reception { due_us, slot, index });
    }

    /// Move a thread's `receptions` (due from `due.0` to `due.1` [µs]) to the end of this
    /// round's, leaving `receptions` empty: the first non-empty one by swapping buffers (no
    /// copy: one thread's round is never copied), the others by one copy of the slice, rather
    /// than a push per reception on the round's one thread.
    fn append(&mut self, receptions: &mut Vec<Reception>, due: (u64, u64)) {
        if receptions.is_empty() {
            return;
        }
        self.first_due_us = self.first_due_us.min(due.0);
        self.last_due_us = self.last_due_us.max(due.1);
        if self.receptions.is_empty() {
            std::mem::swap(&mut self.receptions, receptions);
        } else {
            self.receptions.extend_from_slice(receptions);
            receptions.clear();
        }
    }
}

/// The due times of one link's messages within one round, never decreasing (a link keeps its
/// order, as [`ChannelModel::deliver`] does with a kept [`LinkState`]).
#[derive(Debug, Default, Clone, Copy)]
struct LinkOrder(u64);

impl LinkOrder {
    fn due(&mut self, due_us: u64) -> u64 {
        self.0 = self.0.max(due_us);
        self.0
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

/// The batch of a round whose messages are `buffer`'s then the `chunks`' (in query order),
/// sorted by sender id as [`into_batch`] sorts them; the round's senders (`senders`' then the
/// chunks') end in `senders`, sorted by id, and the first batch index of each one's messages
/// in `starts`.
///
/// When the round came from one table (`buffer` and `senders` empty) with its senders in id
/// order, or in reverse id order with one message each (vehicles spawned with ids -1, -2, ...,
/// as the benchmark's), each chunk moves its messages and senders straight into its own
/// stretch of the batch and of `senders` (from the end, reversed, for the latter) and writes
/// their starts, the chunks side by side on `parallelism`: no copy through `buffer`, no sort.
/// Those copies (400 kB of messages twice, 320 kB of senders, at 10,000 vehicles) and the sorts
/// were the largest serial stretch of a wifi round. Else everything is appended and sorted
/// (stable). Also returns which of the two orders the senders came in ([`round_order`]), if one.
fn join_batch(
    chunks: &mut [Outgoing],
    buffer: &mut Vec<Message>,
    (senders, starts): (&mut Vec<Sender>, &mut Vec<u32>),
    parallelism: Parallelism,
) -> (Arc<[Message]>, Option<bool>) {
    let order = (buffer.is_empty() && senders.is_empty()).then(|| round_order(chunks)).flatten();
    let Some(rising) = order else {
        for chunk in chunks {
            buffer.append(&mut chunk.messages);
            senders.append(&mut chunk.senders);
        }
        senders.sort_by_key(|sender| sender.id);
        starts.clear();
        let mut at = 0;
        starts.extend(senders.iter().map(|sender| {
            at += sender.count;
            at - sender.count
        }));
        return (into_batch(buffer), None);
    };
    let n = chunks.iter().map(|c| c.messages.len()).sum();
    let m = chunks.iter().map(|c| c.senders.len()).sum();
    let mut batch = Arc::<[Message]>::new_uninit_slice(n);
    let slots = Arc::get_mut(&mut batch).expect("a new batch has no other reference");
    senders.clear();
    starts.clear();
    senders.reserve(m);
    starts.reserve(m);
    // Each chunk's stretch of the batch, the senders and their starts: in chunk order, or from
    // the end; with the batch index of the stretch's first message.
    let mut pieces = Vec::with_capacity(chunks.len());
    let (mut slots_left, mut senders_left) = (slots, &mut senders.spare_capacity_mut()[..m]);
    let mut starts_left = &mut starts.spare_capacity_mut()[..m];
    for chunk in chunks.iter_mut() {
        let (k, j) = (chunk.messages.len(), chunk.senders.len());
        let (slot_piece, sender_piece, start_piece, first);
        if rising {
            first = n - slots_left.len();
            (slot_piece, slots_left) = std::mem::take(&mut slots_left).split_at_mut(k);
            (sender_piece, senders_left) = std::mem::take(&mut senders_left).split_at_mut(j);
            (start_piece, starts_left) = std::mem::take(&mut starts_left).split_at_mut(j);
        } else {
            let (len, count) = (slots_left.len(), senders_left.len());
            first = len - k;
            (slots_left, slot_piece) = std::mem::take(&mut slots_left).split_at_mut(len - k);
            (senders_left, sender_piece) = std::mem::take(&mut senders_left).split_at_mut(count - j);
            (starts_left, start_piece) = std::mem::take(&mut starts_left).split_at_mut(count - j);
        }
        pieces.push((chunk, slot_piece, sender_piece, start_piece, first as u32));
    }
    let threads = parallelism.threads_for(m);
    Parallelism::split(threads).for_each_chunk(&mut pieces, &mut Vec::<()>::new(), |pieces, _| {
        for (chunk, slots, senders, starts, first) in pieces.iter_mut() {
            let written = if rising {
                let mut at = *first;
                for ((to, start), from) in senders.iter_mut().zip(starts.iter_mut()).zip(&chunk.senders) {
                    to.write(*from);
                    start.write(at);
                    at += from.count;
                }
                slots.iter_mut().zip(chunk.messages.drain(..)).map(|(slot, message)| slot.write(message)).count()
            } else {
                // One message each: the sender `k` places from the stretch's end has its message
                // there too.
                let places = senders.iter_mut().zip(starts.iter_mut()).enumerate().rev();
                for ((k, (to, start)), from) in places.zip(&chunk.senders) {
                    to.write(*from);
                    start.write(*first + k as u32);
                }
                slots.iter_mut().rev().zip(chunk.messages.drain(..)).map(|(slot, message)| slot.write(message)).count()
            };
            // (A panic here leaves the batch, senders and starts unwritten and never read.)
            assert!(written == slots.len() && chunk.senders.len() == senders.len(), "every place written");
            chunk.senders.clear();
        }
    });
    drop(pieces);
    // SAFETY: the stretches cut above cover the n places of the batch and the m of `senders`'
    // and `starts`' spare capacity (reserved above), each chunk's as long as its messages and
    // senders, and every stretch was written in full (counted and checked) before this point.
    unsafe {
        senders.set_len(m);
        starts.set_len(m);
        (batch.assume_init(), order)
    }
}

/// Whether a round's chunks (in query order) hold their senders in rising id order (`true`), or
/// in falling id order with one message each (`false`), or neither (`None`); each chunk noted
/// its own order when it was filled ([`Outgoing::take`]).
fn round_order(chunks: &[Outgoing]) -> Option<bool> {
    let filled = || chunks.iter().filter(|c| !c.senders.is_empty());
    let ends = || filled().map(|c| (c.senders[0].id, c.senders[c.senders.len() - 1].id));
    let joins = |rising: bool| {
        ends().zip(ends().skip(1)).all(|((_, last), (first, _))| if rising { last < first } else { last > first })
    };
    if filled().all(|c| c.rising) && joins(true) {
        Some(true)
    } else if filled().all(|c| c.falling) && joins(false) {
        Some(false)
    } else {
        None
    }
}

/// The time every message of `batch` was written, when they were all written at once (beacons
/// of one tick): a delivery's age sum is then its count times one age, not a read per message.
fn common_sent_at(batch: &[Message]) -> Option<SimTime> {
    batch.first().map(|m| m.sent_at).filter(|&t| batch.iter().all(|m| m.sent_at == t))
}

/// One in-box as the lossy network round's query hands it out.
type NetworkItem<'a> = Mut<'a, Mailbox>;

/// Scratch buffers of the network round with constant loss, kept between rounds.
#[derive(Default)]
pub struct LossyScratch {
    items: Vec<NetworkItem<'static>>,
    /// Per thread: receptions attempted, delivered, and the delivered ones' age sum [µs].
    threads: Vec<Padded<(u64, u64, u64)>>,
}

impl LossyScratch {
    /// Add every thread's counts of this round to `network` (and empty them); returns the
    /// deliveries.
    fn absorb(&mut self, network: &mut ChannelStats) -> u64 {
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
struct LossyRound<'a> {
    seed: u64,
    round: u64,
    p: f64,
    now_us: u64,
    epoch: u64,
    /// Sum of every message's age [µs].
    age_all: u64,
    /// The one time every message was written, if they were all written at once.
    uniform_age: Option<SimTime>,
    batch: &'a Arc<[Message]>,
}

impl LossyRound<'_> {
    /// Draw how many of the others' messages each in-box of `chunk` loses and deliver the rest,
    /// counting (attempted, delivered, age sum) into `t`.
    fn deliver(&self, chunk: &mut [NetworkItem<'_>], Padded(t): &mut Padded<(u64, u64, u64)>) {
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

/// The messages of `owner` in `batch` (sorted by sender): looked for first as one message
/// beside `hint`, the start of the previous receiver's (receivers in query order are mostly the
/// senders in id order, rising or falling, one beacon each), else by two binary searches over
/// the batch (a probe per halving, most of them cache misses, per receiver: most of a perfect
/// network round's time at 10,000 vehicles). Sets `hint` to the start found.
fn own_messages(batch: &[Message], owner: VehicleId, hint: &mut usize) -> std::ops::Range<usize> {
    let at = |i: usize| batch.get(i).map(|m| m.sender);
    // One message of `owner` at i with others' (or nothing) either side: all of its messages.
    let single = |i: usize| at(i) == Some(owner) && (i == 0 || at(i - 1) < Some(owner)) && at(i + 1) != Some(owner);
    let own = match [*hint + 1, hint.wrapping_sub(1), *hint].into_iter().find(|&i| single(i)) {
        Some(i) => i..i + 1,
        None => batch.partition_point(|m| m.sender < owner)..batch.partition_point(|m| m.sender <= owner),
    };
    *hint = own.start;
    own
}

/// Scratch buffers of the wifi round, kept between rounds.
#[derive(Default)]
pub struct WifiScratch {
    buffer: Vec<Message>,
    /// The senders, then sorted by id.
    senders: Vec<Sender>,
    /// With neighbour lists: each vehicle's place in the senders (by place in the query), or
    /// [`NOT_SENDING`].
    sender_of: Vec<u32>,
    /// What each thread gathered of its chunk of out-boxes, joined in chunk order.
    gathered: Vec<Outgoing>,
    /// First batch index of each sender's messages.
    starts: Vec<u32>,
    grid: SpatialGrid,
    /// One per thread.
    threads: Vec<WifiThread>,
    /// Scratch of the test that the sensors' neighbour lists still hold.
    drift: DriftScratch,
    /// The last round's batch, kept so that its messages are dropped here, split over the
    /// threads ([`release`]), not by whichever in-box happened to hold it last.
    previous: Option<Arc<[Message]>>,
    /// The instant of the last round (for [`NearWanted`]).
    last_round: Option<SimTime>,
}

/// A vehicle that sends this wifi round.
#[derive(Debug, Clone, Copy)]
struct Sender {
    id: VehicleId,
    /// Where it sends from [m].
    position: glam::DVec2,
    /// How many messages it sends.
    count: u32,
    /// Its place in the query.
    place: u32,
}

/// [`WifiScratch::sender_of`] of a vehicle that sends nothing.
const NOT_SENDING: u32 = u32::MAX;

/// Where a wifi round finds a vehicle (by its place in the query) among the senders, with
/// neighbour lists.
#[derive(Clone, Copy)]
enum SenderOf<'a> {
    /// Every vehicle sent and the senders are in query order: its own place.
    Same,
    /// Every vehicle sent one message and the senders are in reverse query order (the
    /// benchmark's ids fall): the count less one less its place.
    Reversed(u32),
    /// Looked up ([`WifiScratch::sender_of`]; [`NOT_SENDING`] for a vehicle that sent nothing).
    Table(&'a [u32]),
}

impl SenderOf<'_> {
    /// The sender at place `j` of the query, or [`NOT_SENDING`].
    #[inline(always)]
    fn get(self, j: u32) -> u32 {
        match self {
            SenderOf::Same => j,
            SenderOf::Reversed(count) => count - 1 - j,
            SenderOf::Table(table) => table[j as usize],
        }
    }
}

/// The messages of one chunk of out-boxes and who sent them, in query order.
/// On cache lines of its own (see [`crate::sim::parallel::Padded`]).
#[derive(Default)]
#[repr(align(128))]
struct Outgoing {
    senders: Vec<Sender>,
    messages: Vec<Message>,
    /// The senders' ids rise (strictly), as [`Outgoing::take`] left them.
    rising: bool,
    /// The senders' ids fall (strictly) and each sent one message.
    falling: bool,
    /// Earliest and latest send time of `messages` [µs] (none: `u64::MAX`, 0).
    sent: (u64, u64),
}

impl Outgoing {
    /// Empty the wifi out-boxes of `boxes` (at `states`, places `start..` in the query) into this.
    fn take(&mut self, start: usize, states: &[VehicleState], boxes: &mut [Mailbox]) {
        let first = self.messages.len();
        for (k, (state, mailbox)) in states.iter().zip(boxes).enumerate() {
            if !mailbox.wifi_out.is_empty() {
                let (id, position, count) = (mailbox.owner(), state.position, mailbox.wifi_out.len() as u32);
                self.senders.push(Sender { id, position, count, place: (start + k) as u32 });
                // One message (a beacon) moved as one, not by a library copy call per sender.
                if mailbox.wifi_out.len() == 1 {
                    self.messages.extend(mailbox.wifi_out.pop());
                } else {
                    self.messages.append(&mut mailbox.wifi_out);
                }
            }
        }
        // While the messages are in cache: the round's ages need not read the batch again.
        self.sent =
            self.messages[first..].iter().fold((u64::MAX, 0), |(lo, hi), m| (lo.min(m.sent_at.0), hi.max(m.sent_at.0)));
        self.note_order();
    }

    /// Note whether the senders' ids rise or fall ([`Outgoing::rising`], [`Outgoing::falling`]).
    fn note_order(&mut self) {
        let ids = || self.senders.windows(2).map(|w| (w[0].id, w[1].id));
        self.rising = ids().all(|(a, b)| a < b);
        self.falling = self.messages.len() == self.senders.len() && ids().all(|(a, b)| a > b);
    }
}

/// What one thread of the wifi round keeps and counts for its contiguous chunk of receivers.
/// On cache lines of its own (see [`crate::sim::parallel::Padded`]).
#[repr(align(128))]
struct WifiThread {
    /// The senders around the current receiver's cell, the slots of those in range (and
    /// scratch for finding them), and their indices in sender order.
    around: Candidates,
    marks: Vec<u32>,
    slots: Vec<u32>,
    heard: Vec<u32>,
    picks: Vec<u32>,
    /// This round's counts of the chunk's receivers, added to the channel's after the round.
    stats: ChannelStats,
    /// Lowest and highest delay bin this round touched in `stats` (empty: lo > hi).
    bins: (usize, usize),
    /// Deliveries made now (a channel without delay).
    delivered: u64,
    /// Delayed receptions of the chunk's receivers, in receiver order.
    receptions: Vec<Reception>,
    /// Earliest and latest due time of `receptions` [µs] (none: `u64::MAX`, 0).
    due: (u64, u64),
}

impl Default for WifiThread {
    fn default() -> Self {
        WifiThread {
            around: Candidates::default(),
            marks: Vec::new(),
            slots: Vec::new(),
            heard: Vec::new(),
            picks: Vec::new(),
            stats: ChannelStats::default(),
            bins: (usize::MAX, 0),
            delivered: 0,
            receptions: Vec::new(),
            due: (u64::MAX, 0),
        }
    }
}

/// What every chunk of a wifi round reads.
struct WifiRound<'a> {
    model: &'a ChannelModel,
    range: f64,
    /// [`round_key`] of this round of the wifi stream.
    round_key: u64,
    round: u64,
    now_us: u64,
    epoch: u64,
    batch: &'a Arc<[Message]>,
    /// When every message of the batch was sent, if at one instant [µs].
    sent_at_us: Option<u64>,
    /// Every sender sent one message (a beacon each): sender i's is message i of the batch.
    one_each: bool,
    senders: &'a [Sender],
    starts: &'a [u32],
    grid: &'a SpatialGrid,
    /// The sensors' neighbour lists (each vehicle's, by place in the query) and where each
    /// vehicle is among the senders, when they hold everyone within the wifi range: then the
    /// grid is not built. With them, when the sensor tick of this instant noted it
    /// ([`SensorGrid::near`]), which neighbours on each list lie within the range.
    nearby: Option<(&'a Lists, SenderOf<'a>, Option<&'a [u64]>)>,
}

impl WifiRound<'_> {
    /// Hand each receiver of `chunk` (the round's receivers from slot `start` on, at `states`)
    /// the messages of the senders within range, less what the channel loses (delayed ones into
    /// `t.receptions`); `links` is the per-link state when the model keeps one (then the whole
    /// round runs as one chunk).
    fn receive(
        &self,
        start: usize,
        states: &[VehicleState],
        chunk: &mut [Mailbox],
        t: &mut WifiThread,
        mut links: Option<&mut HashMap<(VehicleId, VehicleId), LinkState>>,
    ) {
        let (model, now) = (self.model, self.now_us);
        let (senders, starts, batch) = (self.senders, self.starts, self.batch);
        let shared = BatchRef::new(batch);
        // Without per-link state or distance (a constant loss, no bursts) every reception's fate
        // is `ChannelModel::fate` with one loss probability: no link to look up.
        let memoryless = match (&model.loss, model.burst, links.is_some()) {
            (&Loss::Constant(p), None, false) => Some(p),
            _ => None,
        };
        // The senders around a cell are gathered once for the receivers of that cell in a row
        // (neighbours on the road are mostly neighbours in the query), everyone's once.
        let (grid, mut gathered) = (self.grid, None);
        for (k, (state, mailbox)) in states.iter().zip(chunk.iter_mut()).enumerate() {
            let slot = (start + k) as u32;
            let owner = mailbox.owner();
            t.heard.clear();
            if let Some((lists, sender_of, near)) = self.nearby {
                let list = lists.of(slot as usize);
                match near.filter(|_| list.len() <= NEAR_MASK_BITS) {
                    Some(near) => {
                        // The neighbours the sensor tick found within range (a list never holds
                        // its own vehicle), by their bits.
                        let mut bits = near[slot as usize];
                        while bits != 0 {
                            let j = list[bits.trailing_zeros() as usize];
                            bits &= bits - 1;
                            let i = sender_of.get(j);
                            if i != NOT_SENDING {
                                debug_assert_eq!(senders[i as usize].place, j, "the sender found is the neighbour's");
                                t.heard.push(i);
                            }
                        }
                    }
                    None => {
                        // The senders on its list within range: the test of `Candidates::within`.
                        let (p, r2) = (state.position, self.range * self.range);
                        for &j in list {
                            let i = sender_of.get(j);
                            if i == NOT_SENDING {
                                continue;
                            }
                            let Sender { id, position, place, .. } = senders[i as usize];
                            debug_assert_eq!(place, j, "the sender found is the neighbour's");
                            if within_reach(p, position.x, position.y, r2) & (id != owner) {
                                t.heard.push(i);
                            }
                        }
                    }
                }
            } else {
                let cell = grid.cell_of(state.position);
                // `gathered`: Some(Some(cell)) around that cell, Some(None) everyone.
                let stale = gathered.is_none_or(|g: Option<(i32, i32)>| g.is_some_and(|c| c != cell));
                if stale {
                    let everything = grid.gather_around(cell, self.range, &mut t.around);
                    gathered = Some((!everything).then_some(cell));
                }
                t.around.within(state.position, self.range, owner, &mut t.marks, &mut t.slots);
                t.heard.extend(t.slots.iter().map(|&slot| grid.index_of(slot)));
            }
            t.heard.sort_unstable();
            let attempted = if self.one_each {
                t.heard.len() as u64
            } else {
                t.heard.iter().map(|&i| senders[i as usize].count as u64).sum::<u64>()
            };
            t.stats.sent += attempted;
            if model.is_perfect() {
                match self.sent_at_us {
                    // All sent at one instant (every beacon of a round): the ages at once.
                    Some(sent_at) => t.stats.age_sum_us += attempted * now.saturating_sub(sent_at),
                    None => {
                        for &i in &t.heard {
                            let start = starts[i as usize] as usize;
                            for m in &batch[start..start + senders[i as usize].count as usize] {
                                t.stats.age_sum_us += now.saturating_sub(m.sent_at.0);
                            }
                        }
                    }
                }
                t.stats.aged += attempted;
                t.stats.delivered += attempted;
                t.delivered += attempted;
                let inbox = &mut mailbox.wifi_in;
                if self.one_each {
                    // Each sender's index is its message's: a copy of the list, no lookups.
                    inbox.deliver_picks(self.epoch, self.round, &shared, owner, t.heard.iter().copied());
                } else {
                    let picks = t.heard.iter().flat_map(|&i| {
                        let start = starts[i as usize];
                        start..start + senders[i as usize].count
                    });
                    inbox.deliver_picks(self.epoch, self.round, &shared, owner, picks);
                }
                continue;
            }
            t.picks.clear();
            for &i in &t.heard {
                let Sender { id: sender, position, count, .. } = senders[i as usize];
                let distance = if model.uses_distance() { position.distance(state.position) } else { 0.0 };
                let mut fresh = LinkState::default();
                let link = match links.as_deref_mut() {
                    Some(links) => links.entry((sender, owner)).or_default(),
                    None => &mut fresh,
                };
                let key = link_key(self.round_key, sender.0, owner.0);
                let mut order = LinkOrder::default();
                for index in 0..count {
                    let k = starts[i as usize] + index;
                    let fate = match memoryless {
                        Some(p) => model.fate(key, index, p),
                        None => model.deliver_keyed(key, index, (sender, owner), now, distance, self.range, link),
                    };
                    let Some(delay) = fate else {
                        continue;
                    };
                    t.stats.delivered += 1;
                    if model.delays() {
                        let due = order.due(now + delay);
                        let bin = t.stats.add_delay(due - now);
                        t.bins = (t.bins.0.min(bin), t.bins.1.max(bin));
                        t.due = (t.due.0.min(due), t.due.1.max(due));
                        t.receptions.push(Reception { due_us: due, slot, index: k });
                    } else {
                        // One instant for the whole batch (beacons): no read of the message.
                        let sent_at = self.sent_at_us.unwrap_or_else(|| batch[k as usize].sent_at.0);
                        t.stats.age_sum_us += now.saturating_sub(sent_at);
                        t.stats.aged += 1;
                        t.picks.push(k);
                    }
                }
            }
            if !model.delays() {
                t.delivered += t.picks.len() as u64;
                mailbox.wifi_in.deliver_picks(self.epoch, self.round, &shared, owner, t.picks.iter().copied());
            }
        }
    }
}

/// Wifi round: each mailbox's in-box gets the messages of the senders within range (inclusive),
/// less what the channel loses; later when it delays. The receivers are cut into contiguous
/// chunks over [`Parallelism::threads`] threads (each reads the shared batch and grid and
/// writes only its own in-box and its thread's counts and delayed receptions, which are joined
/// in chunk order: the same bits for any thread count), unless the model keeps per-link state
/// (bursts, or a jitter wider than the rounds' spacing), which runs on one thread.
#[allow(clippy::too_many_arguments)]
pub fn deliver_wifi(
    config: Res<V2vConfig>,
    clock: Res<SimClock>,
    seed: Option<Res<SimSeed>>,
    epoch: Res<ControlEpoch>,
    parallelism: Option<Res<Parallelism>>,
    mut stats: ResMut<V2vStats>,
    mut channel: ResMut<V2vChannelStats>,
    mut links: ResMut<V2vLinks>,
    registry: Option<Res<Vehicles>>,
    mut delayed: ResMut<DelayedMessages>,
    sensor_grid: Option<Res<SensorGrid>>,
    (floor, near_wanted): (Option<ResMut<ListFloor>>, Option<ResMut<NearWanted>>),
    mut mailboxes: Query<(Entity, Option<&VehicleId>, &VehicleState, &mut Mailbox)>,
    mut scratch: Local<WifiScratch>,
) {
    stats.wifi_rounds += 1;
    let round = stats.wifi_rounds;
    // A config inserted after the plugin was built: the lists reach its range from the next
    // sensor tick on (until then a round whose range they do not cover uses a grid).
    if let Some(mut floor) = floor
        && floor.0 != config.wifi_range
    {
        floor.0 = config.wifi_range;
    }
    let now = clock.now;
    let seed = seed.map_or(0, |s| s.0);
    let model = config.wifi.clone();
    if let Some(registry) = &registry {
        links.prune(registry);
    }
    let ordered = model.delays() && delayed.needs_link_order(Channel::Wifi, now.0, &model);
    let stateful = model.steps_links() || ordered;
    let s = &mut *scratch;
    let parallelism = parallelism.map_or(Parallelism::single(), |p| *p);
    // The senders and their messages in query order: each thread empties a contiguous chunk of
    // out-boxes (the reads of ten thousand out-boxes are most of a round's serial time), the
    // chunks joined in order, so any thread count gathers the same batch.
    s.senders.clear();
    let mut base = 0;
    // Earliest and latest send time of the round's messages [µs], as each chunk found them.
    let mut sent = (u64::MAX, 0);
    let mut note_sent = |chunks: &[Outgoing]| {
        for out in chunks.iter().filter(|out| !out.messages.is_empty()) {
            sent = (sent.0.min(out.sent.0), sent.1.max(out.sent.1));
        }
    };
    if let Ok(tables) = mailboxes.contiguous_iter_mut() {
        for (_, _, states, mut boxes) in tables {
            // The last table's messages and senders stay in the chunks (see `join_batch`).
            for out in &mut s.gathered {
                s.buffer.append(&mut out.messages);
                s.senders.append(&mut out.senders);
            }
            parallelism.for_each_chunk_at(&mut boxes, &mut s.gathered, |start, chunk, out| {
                out.take(base + start, &states[start..], chunk)
            });
            note_sent(&s.gathered);
            base += states.len();
        }
    } else {
        // Only if a component were stored sparsely (none is): one at a time.
        let out = &mut Outgoing::default();
        for (_, _, state, mut mailbox) in &mut mailboxes {
            out.take(0, std::slice::from_ref(state), std::slice::from_mut(&mut *mailbox));
            note_sent(std::slice::from_ref(out));
        }
        s.senders.append(&mut out.senders);
        s.buffer.append(&mut out.messages);
    }
    // (`order`: whether the senders came in rising or falling ids, if one of the two.)
    let (batch, order) = join_batch(&mut s.gathered, &mut s.buffer, (&mut s.senders, &mut s.starts), parallelism);
    stats.wifi_sent += batch.len() as u64;
    // The sensors' neighbour lists, when every vehicle lies in one table and they still hold
    // everyone within the wifi range; else a grid of the senders.
    let nearby = sensor_grid.as_deref().and_then(|sensor_grid| {
        let readonly = mailboxes.as_readonly();
        let mut full = readonly.contiguous_iter().ok()?.filter(|t| !t.0.is_empty());
        let (_, ids, states, _) = full.next()?;
        if full.next().is_some() {
            return None;
        }
        sensor_grid.lists_within(ids?, states, config.wifi_range, (parallelism, now), &mut s.drift)
    });
    let senders = &s.senders;
    // With every vehicle of the one table sending, in id order (rising, or falling with one
    // message each), a vehicle's sender is its own place or the mirror of it: no table to fill
    // on this thread each round.
    let everyone = nearby.is_some_and(|lists| senders.len() == lists.len());
    let by_place = order.filter(|_| everyone);
    if let (Some(lists), None) = (nearby, by_place) {
        s.sender_of.clear();
        s.sender_of.resize(lists.len(), NOT_SENDING);
        for (i, sender) in senders.iter().enumerate() {
            s.sender_of[sender.place as usize] = i as u32;
        }
    } else if nearby.is_none() {
        s.grid.rebuild_on(parallelism, config.wifi_range, senders.len(), |i| {
            let Sender { id, position, .. } = senders[i];
            GridEntry { position, velocity: glam::DVec2::ZERO, id, index: i as u32 }
        });
    }
    let input = WifiRound {
        model: &model,
        range: config.wifi_range,
        round_key: round_key(seed, WIFI_STREAM, round),
        round,
        now_us: now.0,
        epoch: epoch.0,
        batch: &batch,
        sent_at_us: (!batch.is_empty() && sent.0 == sent.1).then_some(sent.0),
        one_each: batch.len() == s.senders.len(),
        senders: &s.senders,
        starts: &s.starts,
        grid: &s.grid,
        nearby: nearby.map(|lists| {
            let sender_of = match by_place {
                Some(true) => SenderOf::Same,
                Some(false) => SenderOf::Reversed(s.senders.len() as u32),
                None => SenderOf::Table(&s.sender_of),
            };
            (lists, sender_of, sensor_grid.as_deref().and_then(|g| g.near(config.wifi_range, now)))
        }),
    };
    // Receivers table by table, straight in the ECS tables' slices (contiguous access); a
    // receiver's slot is its place in query order, counted across the tables.
    let mut record = model.delays().then(|| delayed.open(Channel::Wifi, round, &batch, std::iter::empty()));
    let mut delivered = 0;
    let mut base = 0;
    if s.threads.is_empty() {
        s.threads.push(WifiThread::default());
    }
    let mut receive = |entities: &[Entity], states: &[VehicleState], boxes: &mut [Mailbox]| {
        if let Some(record) = &mut record {
            record.receivers.extend_from_slice(entities);
        }
        if stateful {
            input.receive(base, states, boxes, &mut s.threads[0], Some(&mut links.wifi));
        } else {
            parallelism.for_each_chunk_at(boxes, &mut s.threads, |start, chunk, t| {
                input.receive(base + start, &states[start..], chunk, t, None)
            });
        }
        base += entities.len();
        // Each thread's counts and delayed receptions (in receiver order), in chunk order.
        for t in &mut s.threads {
            delivered += std::mem::take(&mut t.delivered);
            channel.wifi.absorb(&mut t.stats, t.bins);
            t.bins = (usize::MAX, 0);
            if let Some(record) = &mut record {
                record.append(&mut t.receptions, std::mem::replace(&mut t.due, (u64::MAX, 0)));
            }
        }
    };
    if let Ok(tables) = mailboxes.contiguous_iter_mut() {
        for (entities, _, states, mut boxes) in tables {
            receive(entities, states, &mut boxes);
        }
    } else {
        // Only if a component were stored sparsely (none is): one at a time.
        for (entity, _, state, mut mailbox) in &mut mailboxes {
            receive(std::slice::from_ref(&entity), std::slice::from_ref(state), std::slice::from_mut(&mut *mailbox));
        }
    }
    if let Some(record) = record {
        delayed.keep(record);
    }
    stats.wifi_delivered += delivered;
    if let Some(previous) = s.previous.replace(batch) {
        release(previous, parallelism);
    }
    // The next round, if the rounds keep their spacing: the sensor tick then notes who is
    // within range on each list (from the coordinates it gathers anyway).
    if let Some(mut wanted) = near_wanted {
        let next = s.last_round.filter(|&last| last < now).map(|last| SimTime(now.0 + (now.0 - last.0)));
        if wanted.0 != next {
            wanted.0 = next;
        }
    }
    s.last_round = Some(now);
}

/// Let go of `batch`; if this was its last reference, drop its messages split over the
/// threads of `parallelism`, each thread a contiguous chunk.
///
/// A round's batch was freed by the in-box that dropped it last, inside the next round's
/// parallel section: ten thousand payloads (each an allocation) freed on one thread, about
/// 0.2 ms while the other threads waited. Chunks of a batch (sorted by sender) are mostly the
/// payloads the same thread allocated when its chunk of vehicles sent them.
fn release(batch: Arc<[Message]>, parallelism: Parallelism) {
    // SAFETY: `ManuallyDrop<Message>` is `repr(transparent)` over `Message` (same size and
    // alignment), so the allocation is the same `ArcInner` either way. Dropping this form never
    // drops a message: should a payload's drop panic below, the rest leak, none is dropped
    // twice.
    let mut batch: Arc<[ManuallyDrop<Message>]> =
        unsafe { Arc::from_raw(Arc::into_raw(batch) as *const [ManuallyDrop<Message>]) };
    let Some(messages) = Arc::get_mut(&mut batch) else {
        // Others still hold it (in-boxes that kept several rounds, delayed receptions): back to
        // the form that drops its messages when the last of them lets go.
        // SAFETY: as above, the other way; no message was dropped.
        drop(unsafe { Arc::from_raw(Arc::into_raw(batch) as *const [Message]) });
        return;
    };
    parallelism.for_each_chunk(messages, &mut Vec::<()>::new(), |chunk, _| {
        for message in chunk {
            // SAFETY: this is the batch's only reference, each message is in one chunk and
            // dropped once here, and the `ManuallyDrop` form frees the allocation after
            // without dropping any again.
            unsafe { ManuallyDrop::drop(message) };
        }
    });
}

/// One mailbox as [`deliver_delayed`]'s query hands it out.
type DelayItem<'a> = (Entity, Mut<'a, Mailbox>);

/// Scratch buffers of [`deliver_delayed`], kept between ticks.
#[derive(Default)]
pub struct DelayScratch {
    /// The mailboxes in query order (the query's items, gathered to be cut into chunks).
    items: Vec<DelayItem<'static>>,
    /// One per thread.
    threads: Vec<DueThread>,
    /// Position in `items` of each entity (by entity index), filled when a round's receivers no
    /// longer match the query's order.
    position_of: Vec<u32>,
    /// The receptions a delivery keeps, gathered (then swapped with the round's).
    merged: Vec<Reception>,
}

/// What one thread of a delivery keeps and counts for its chunk of in-boxes.
/// On cache lines of its own (see [`crate::sim::parallel::Padded`]).
#[repr(align(128))]
struct DueThread {
    picks: Vec<u32>,
    /// Receptions of the chunk not due yet, in order.
    kept: Vec<Reception>,
    /// Earliest and latest due time of `kept` [µs] (none: `u64::MAX`, 0).
    due: (u64, u64),
    delivered: u64,
    age_sum_us: u64,
}

impl Default for DueThread {
    fn default() -> Self {
        DueThread { picks: Vec::new(), kept: Vec::new(), due: (u64::MAX, 0), delivered: 0, age_sum_us: 0 }
    }
}

/// One due round as every chunk of its delivery reads it.
struct DueRound<'a> {
    now: u64,
    epoch: u64,
    round: &'a DelayedRound,
}

impl DueRound<'_> {
    /// Put the due receptions of the in-boxes `chunk` (slots `start..start + chunk.len()`) into
    /// them, one delivery per in-box, and keep the others in `t.kept`.
    fn deliver(&self, start: usize, chunk: &mut [DelayItem<'_>], t: &mut DueThread) {
        let (r, now) = (self.round, self.now);
        let shared = BatchRef::new(&r.batch);
        let receptions = &r.receptions;
        let end = start + chunk.len();
        let mut i = receptions.partition_point(|x| (x.slot as usize) < start);
        while i < receptions.len() && (receptions[i].slot as usize) < end {
            let slot = receptions[i].slot;
            t.picks.clear();
            while i < receptions.len() && receptions[i].slot == slot {
                let reception = receptions[i];
                if reception.due_us <= now {
                    t.picks.push(reception.index);
                    if r.sent_at_us.is_none() {
                        t.age_sum_us += now.saturating_sub(r.batch[reception.index as usize].sent_at.0);
                    }
                } else {
                    t.due = (t.due.0.min(reception.due_us), t.due.1.max(reception.due_us));
                    t.kept.push(reception);
                }
                i += 1;
            }
            if t.picks.is_empty() {
                continue;
            }
            if let Some(sent) = r.sent_at_us {
                t.age_sum_us += t.picks.len() as u64 * now.saturating_sub(sent);
            }
            t.delivered += t.picks.len() as u64;
            // The in-box two places on: its buffers arrive while this one is written.
            if let Some((_, next)) = chunk.get(slot as usize + 2 - start) {
                next.inbox(r.channel).prefetch(self.epoch);
            }
            let (_, mailbox) = &mut chunk[slot as usize - start];
            let owner = mailbox.owner();
            let inbox = mailbox.inbox_mut(r.channel);
            inbox.deliver_picks(self.epoch, r.round, &shared, owner, t.picks.iter().copied());
        }
    }
}

impl DelayedRound {
    /// Whether the slots of this round are the places of `items` (no vehicle came or went).
    fn matches(&self, items: &[DelayItem<'_>]) -> bool {
        self.receivers.len() == items.len() && self.receivers.iter().zip(items).all(|(a, (b, _))| a == b)
    }

    /// Renumber the receptions by the receivers' places in `items` (the query's order now),
    /// those of receivers that left the world [`GONE`], keeping each receiver's order.
    fn realign(&mut self, items: &[DelayItem<'_>], position_of: &mut Vec<u32>) {
        position_of.clear();
        for (k, (entity, _)) in items.iter().enumerate() {
            let at = entity.index().index() as usize;
            if position_of.len() <= at {
                position_of.resize(at + 1, GONE);
            }
            position_of[at] = k as u32;
        }
        for reception in &mut self.receptions {
            let Some(&entity) = self.receivers.get(reception.slot as usize) else {
                reception.slot = GONE;
                continue;
            };
            let at = position_of.get(entity.index().index() as usize).copied().unwrap_or(GONE);
            let here = items.get(at as usize).is_some_and(|(e, _)| *e == entity);
            reception.slot = if here { at } else { GONE };
        }
        // Each receiver's receptions stay in order: within a receiver they are in batch order
        // (the rounds push them so), so sorting by (slot, batch index) keeps it, in place (a
        // stable sort would allocate a buffer each time vehicles came or went).
        self.receptions.sort_unstable_by_key(|x| (x.slot, x.index));
        self.receivers.clear();
        self.receivers.extend(items.iter().map(|(e, _)| *e));
    }
}

/// Put the delayed receptions that are due into their in-boxes (control phase, before the
/// controllers): per receiver and round in one delivery, rounds in the order they ran, so a
/// receiver's in-box holds its rounds in order and a link keeps its order. A round's in-boxes
/// are cut into contiguous chunks over [`Parallelism::threads`] threads (each writes only its
/// in-boxes and its thread's counts and kept receptions, joined in chunk order: the same bits
/// for any thread count). A reception whose receiver left the world counts as delivered when
/// due, as it did reach the air.
#[allow(clippy::too_many_arguments)]
pub fn deliver_delayed(
    clock: Res<SimClock>,
    epoch: Res<ControlEpoch>,
    parallelism: Option<Res<Parallelism>>,
    mut stats: ResMut<V2vStats>,
    mut channel: ResMut<V2vChannelStats>,
    mut delayed: ResMut<DelayedMessages>,
    mut mailboxes: Query<(Entity, &mut Mailbox)>,
    mut scratch: Local<DelayScratch>,
) {
    let now = clock.now.0;
    if delayed.rounds.iter().all(|r| r.first_due_us > now) {
        return;
    }
    let parallelism = parallelism.map_or(Parallelism::single(), |p| *p);
    let d = &mut *delayed;
    let s = &mut *scratch;
    let mut items: Vec<DelayItem<'_>> = recycle(std::mem::take(&mut s.items));
    items.extend(mailboxes.iter_mut());
    let mut k = 0;
    while k < d.rounds.len() {
        let r = &mut d.rounds[k];
        if r.first_due_us > now {
            k += 1;
            continue;
        }
        if !r.matches(&items) {
            r.realign(&items, &mut s.position_of);
        }
        let due = DueRound { now, epoch: epoch.0, round: r };
        parallelism.for_each_chunk_at(&mut items, &mut s.threads, |start, chunk, t| due.deliver(start, chunk, t));
        let stats_of = match r.channel {
            Channel::Wifi => &mut channel.wifi,
            Channel::Network => &mut channel.network,
        };
        let (mut delivered, mut first_due, mut last_due) = (0, u64::MAX, 0);
        // Receivers that left (at the end: their slot is the largest): the due ones count as
        // delivered, the others wait there.
        let gone = r.receptions.partition_point(|x| x.slot != GONE);
        let mut waiting = gone;
        for i in gone..r.receptions.len() {
            let x = r.receptions[i];
            if x.due_us <= now {
                delivered += 1;
                stats_of.age_sum_us += now.saturating_sub(r.batch[x.index as usize].sent_at.0);
            } else {
                (first_due, last_due) = (first_due.min(x.due_us), last_due.max(x.due_us));
                r.receptions[waiting] = x;
                waiting += 1;
            }
        }
        // The kept receptions of the chunks, in chunk order, then the waiting ones of receivers
        // that left: the slots still never decrease.
        s.merged.clear();
        for t in &s.threads {
            s.merged.extend_from_slice(&t.kept);
        }
        s.merged.extend_from_slice(&r.receptions[gone..waiting]);
        std::mem::swap(&mut r.receptions, &mut s.merged);
        for t in &mut s.threads {
            delivered += std::mem::take(&mut t.delivered);
            stats_of.age_sum_us += std::mem::take(&mut t.age_sum_us);
            let (a, b) = std::mem::replace(&mut t.due, (u64::MAX, 0));
            (first_due, last_due) = (first_due.min(a), last_due.max(b));
            t.kept.clear();
        }
        stats_of.aged += delivered;
        match r.channel {
            Channel::Wifi => stats.wifi_delivered += delivered,
            Channel::Network => stats.network_delivered += delivered,
        }
        (r.first_due_us, r.last_due_us) = (first_due, last_due);
        if r.receptions.is_empty() {
            if let Some(done) = d.rounds.remove(k) {
                d.spare.push((done.receptions, done.receivers));
            }
        } else {
            k += 1;
        }
    }
    s.items = recycle(items);
}

/// Network and wifi V2V in the [`Network`] and [`Wifi`] schedules.
#[derive(Debug, Clone, Default)]
pub struct V2vPlugin {
    /// Settings (wifi range).
    pub config: V2vConfig,
}

/// Marks that [`V2vPlugin`]'s systems are in the schedules.
#[derive(Resource, Debug, Clone, Copy)]
struct V2vInstalled;

impl Plugin for V2vPlugin {
    /// Adds the V2V systems once: a second `V2vPlugin` (a scenario's channels after
    /// `default_plugins`' perfect ones) only replaces the [`V2vConfig`]. Added twice, every round
    /// ran twice (the second over empty out-boxes, counting a round of its own).
    fn build(&self, sim: &mut SimBuilder) {
        sim.insert_resource(self.config.clone());
        // The sensors' neighbour lists reach the wifi range all around, so a round reads them.
        sim.insert_resource(ListFloor(self.config.wifi_range));
        if !sim.world_mut().contains_resource::<NearWanted>() {
            sim.insert_resource(NearWanted::default());
        }
        if sim.world_mut().contains_resource::<V2vInstalled>() {
            return;
        }
        sim.insert_resource(V2vInstalled);
        sim.insert_resource(V2vStats::default());
        sim.insert_resource(V2vChannelStats::default());
        sim.insert_resource(V2vLinks::default());
        sim.insert_resource(DelayedMessages::default());
        sim.add_systems(Network, deliver_network.in_set(SimSystems::Communicate));
        sim.add_systems(Wifi, deliver_wifi.in_set(SimSystems::Communicate));
        // Always, not only when `self.config` delays: the config may be replaced after the
        // plugin is built (the degraded bench inserts a delaying one after `default_plugins`),
        // and then the delayed receptions were queued and never delivered. With nothing queued
        // it looks at an empty queue and returns.
        sim.add_systems(Control, deliver_delayed.in_set(SimSystems::Communicate));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::Payload;
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
        let mut places: Vec<DVec2> =
            (0..80).map(|k| DVec2::new(f64::from(k % 9) * 2.5, f64::from(k / 9) * 2.5)).collect();
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
            (0..40)
                .flat_map(|k| std::iter::repeat_n(k, 1 + usize::from(k % 7 == 3) + usize::from(k % 11 == 5)))
                .collect(),
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
                    let want =
                        batch.partition_point(|m| m.sender < owner)..batch.partition_point(|m| m.sender <= owner);
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
            for (a, b) in [(vec![(5, 0), (1, 1)], vec![(6, 2), (-4, 3)]), (vec![(1, 0), (5, 1)], vec![(2, 2), (8, 3)])]
            {
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
}
