//! The wifi round: each message to the vehicles within the wifi range of its sender
//! ([`deliver_wifi`]), from the sensors' neighbour lists or a grid of its own.

use bevy_ecs::prelude::{Entity, Local, Query, Res, ResMut};
use std::collections::HashMap;
use std::sync::Arc;

use super::batch::{NOT_SENDING, Outgoing, Sender, join_batch, release};
use super::config::V2vConfig;
use super::delayed::{DelayedMessages, LinkOrder, Reception};
use super::stats::{ChannelStats, V2vChannelStats, V2vLinks, V2vStats};
use crate::sim::grid::lists::{DriftScratch, ListFloor, Lists, NEAR_MASK_BITS, NearWanted, SensorGrid};
use crate::sim::grid::within_reach;
use crate::sim::v2v::channel::{ChannelModel, LinkState, Loss, link_key, round_key};
use crate::sim::{Candidates, ControlEpoch, GridEntry, Parallelism, SimClock, SimSeed, SpatialGrid};
use crate::world::{BatchRef, Channel, Mailbox, Message, SimTime, VehicleId, VehicleState, Vehicles};

/// Streams of the counter-based draws of each channel (see [`Draw::stream`]).
pub(super) const WIFI_STREAM: u64 = 0x5769_6669; // "Wifi"

/// Scratch buffers of the wifi round, kept between rounds.
#[derive(Default)]
pub struct WifiScratch {
    pub(super) buffer: Vec<Message>,
    /// The senders, then sorted by id.
    pub(super) senders: Vec<Sender>,
    /// With neighbour lists: each vehicle's place in the senders (by place in the query), or
    /// [`NOT_SENDING`].
    pub(super) sender_of: Vec<u32>,
    /// What each thread gathered of its chunk of out-boxes, joined in chunk order.
    pub(super) gathered: Vec<Outgoing>,
    /// First batch index of each sender's messages.
    pub(super) starts: Vec<u32>,
    pub(super) grid: SpatialGrid,
    /// One per thread.
    pub(super) threads: Vec<WifiThread>,
    /// Scratch of the test that the sensors' neighbour lists still hold.
    pub(super) drift: DriftScratch,
    /// The last round's batch, kept so that its messages are dropped here, split over the
    /// threads ([`release`]), not by whichever in-box happened to hold it last.
    pub(super) previous: Option<Arc<[Message]>>,
    /// The instant of the last round (for [`NearWanted`]).
    pub(super) last_round: Option<SimTime>,
}
/// Where a wifi round finds a vehicle (by its place in the query) among the senders, with
/// neighbour lists.
#[derive(Clone, Copy)]
pub(super) enum SenderOf<'a> {
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
    pub(super) fn get(self, j: u32) -> u32 {
        match self {
            SenderOf::Same => j,
            SenderOf::Reversed(count) => count - 1 - j,
            SenderOf::Table(table) => table[j as usize],
        }
    }
}
/// What one thread of the wifi round keeps and counts for its contiguous chunk of receivers.
/// On cache lines of its own (see [`crate::sim::parallel::Padded`]).
#[repr(align(128))]
pub(super) struct WifiThread {
    /// The senders around the current receiver's cell, the slots of those in range (and
    /// scratch for finding them), and their indices in sender order.
    pub(super) around: Candidates,
    pub(super) marks: Vec<u32>,
    pub(super) slots: Vec<u32>,
    pub(super) heard: Vec<u32>,
    pub(super) picks: Vec<u32>,
    /// This round's counts of the chunk's receivers, added to the channel's after the round.
    pub(super) stats: ChannelStats,
    /// Lowest and highest delay bin this round touched in `stats` (empty: lo > hi).
    pub(super) bins: (usize, usize),
    /// Deliveries made now (a channel without delay).
    pub(super) delivered: u64,
    /// Delayed receptions of the chunk's receivers, in receiver order.
    pub(super) receptions: Vec<Reception>,
    /// Earliest and latest due time of `receptions` [µs] (none: `u64::MAX`, 0).
    pub(super) due: (u64, u64),
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
pub(super) struct WifiRound<'a> {
    pub(super) model: &'a ChannelModel,
    pub(super) range: f64,
    /// [`round_key`] of this round of the wifi stream.
    pub(super) round_key: u64,
    pub(super) round: u64,
    pub(super) now_us: u64,
    pub(super) epoch: u64,
    pub(super) batch: &'a Arc<[Message]>,
    /// When every message of the batch was sent, if at one instant [µs].
    pub(super) sent_at_us: Option<u64>,
    /// Every sender sent one message (a beacon each): sender i's is message i of the batch.
    pub(super) one_each: bool,
    pub(super) senders: &'a [Sender],
    pub(super) starts: &'a [u32],
    pub(super) grid: &'a SpatialGrid,
    /// The sensors' neighbour lists (each vehicle's, by place in the query) and where each
    /// vehicle is among the senders, when they hold everyone within the wifi range: then the
    /// grid is not built. With them, when the sensor tick of this instant noted it
    /// ([`SensorGrid::near`]), which neighbours on each list lie within the range.
    pub(super) nearby: Option<(&'a Lists, SenderOf<'a>, Option<&'a [u64]>)>,
}

impl WifiRound<'_> {
    /// Hand each receiver of `chunk` (the round's receivers from slot `start` on, at `states`)
    /// the messages of the senders within range, less what the channel loses (delayed ones into
    /// `t.receptions`); `links` is the per-link state when the model keeps one (then the whole
    /// round runs as one chunk).
    pub(super) fn receive(
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
