//! Delayed receptions: queued per round with their due times ([`DelayedMessages`]) and put
//! into the in-boxes at the first control tick at or after them ([`deliver_delayed`]).

use bevy_ecs::prelude::{Entity, Local, Mut, Query, Res, ResMut, Resource};
use std::sync::Arc;

use super::batch::common_sent_at;
use super::stats::{V2vChannelStats, V2vStats};
use crate::sim::parallel::recycle;
use crate::sim::v2v::channel::ChannelModel;
use crate::sim::{ControlEpoch, Parallelism, SimClock};
use crate::world::{BatchRef, Channel, Mailbox, Message};

/// A reception waiting for its due time: 16 bytes, no reference count (the round holds the
/// batch once). `slot` is the receiver's place in the round's [`DelayedRound::receivers`]
/// ([`GONE`] once it left the world).
#[derive(Debug, Clone, Copy)]
pub(super) struct Reception {
    pub(super) due_us: u64,
    pub(super) slot: u32,
    pub(super) index: u32,
}

/// The slot of a reception whose receiver left the world before it was due.
pub(super) const GONE: u32 = u32::MAX;

/// One round's receptions of a delaying channel not yet delivered, in the order the round made
/// them: grouped by receiver, receivers in query order (their slots never decrease), each
/// receiver's in batch order.
#[derive(Debug)]
pub(super) struct DelayedRound {
    pub(super) channel: Channel,
    pub(super) round: u64,
    pub(super) batch: Arc<[Message]>,
    /// Every mailbox's entity in the query order of the round: slot k is `receivers[k]`. While
    /// the world keeps that order (no vehicle came or went), the delivery walks the in-boxes in
    /// the same order, in parallel chunks, without looking one up.
    pub(super) receivers: Vec<Entity>,
    pub(super) receptions: Vec<Reception>,
    /// Earliest and latest due time of `receptions` [µs].
    pub(super) first_due_us: u64,
    pub(super) last_due_us: u64,
    /// When every message of `batch` was written at the same time (beacons of one tick): that
    /// time [µs], so a delivery's age sum is its count times one age, not a read per message.
    pub(super) sent_at_us: Option<u64>,
}

/// Receptions of delaying channels not yet due: one record per round (its batch shared once,
/// its receptions and receivers in reused buffers), so a delayed reception costs a 16-byte push
/// and its delivery a step through the in-boxes in query order, not a reference count, a sort
/// or a search each.
#[derive(Resource, Debug, Default)]
pub struct DelayedMessages {
    /// Rounds in the order they ran (each channel's in round order).
    pub(super) rounds: std::collections::VecDeque<DelayedRound>,
    /// Emptied reception and receiver buffers, reused by later rounds.
    pub(super) spare: Vec<(Vec<Reception>, Vec<Entity>)>,
    /// Time of each channel's previous delaying round [µs], indexed by `Channel as usize`, for
    /// [`DelayedMessages::needs_link_order`].
    pub(super) previous_round_us: [Option<u64>; 2],
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
    pub(super) fn open(
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
    pub(super) fn keep(&mut self, round: DelayedRound) {
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
    pub(super) fn needs_link_order(&mut self, channel: Channel, now_us: u64, model: &ChannelModel) -> bool {
        let slot = &mut self.previous_round_us[channel as usize];
        let previous = slot.replace(now_us);
        previous.is_none_or(|p| now_us.saturating_sub(p) < model.delay_spread_us())
    }
}

impl DelayedRound {
    pub(super) fn push(&mut self, slot: u32, index: u32, due_us: u64) {
        self.first_due_us = self.first_due_us.min(due_us);
        self.last_due_us = self.last_due_us.max(due_us);
        self.receptions.push(Reception { due_us, slot, index });
    }

    /// Move a thread's `receptions` (due from `due.0` to `due.1` [µs]) to the end of this
    /// round's, leaving `receptions` empty: the first non-empty one by swapping buffers (no
    /// copy: one thread's round is never copied), the others by one copy of the slice, rather
    /// than a push per reception on the round's one thread.
    pub(super) fn append(&mut self, receptions: &mut Vec<Reception>, due: (u64, u64)) {
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
pub(super) struct LinkOrder(pub(super) u64);

impl LinkOrder {
    pub(super) fn due(&mut self, due_us: u64) -> u64 {
        self.0 = self.0.max(due_us);
        self.0
    }
}
/// One mailbox as [`deliver_delayed`]'s query hands it out.
pub(super) type DelayItem<'a> = (Entity, Mut<'a, Mailbox>);

/// Scratch buffers of [`deliver_delayed`], kept between ticks.
#[derive(Default)]
pub struct DelayScratch {
    /// The mailboxes in query order (the query's items, gathered to be cut into chunks).
    pub(super) items: Vec<DelayItem<'static>>,
    /// One per thread.
    pub(super) threads: Vec<DueThread>,
    /// Position in `items` of each entity (by entity index), filled when a round's receivers no
    /// longer match the query's order.
    pub(super) position_of: Vec<u32>,
    /// The receptions a delivery keeps, gathered (then swapped with the round's).
    pub(super) merged: Vec<Reception>,
}

/// What one thread of a delivery keeps and counts for its chunk of in-boxes.
/// On cache lines of its own (see [`crate::sim::parallel::Padded`]).
#[repr(align(128))]
pub(super) struct DueThread {
    pub(super) picks: Vec<u32>,
    /// Receptions of the chunk not due yet, in order.
    pub(super) kept: Vec<Reception>,
    /// Earliest and latest due time of `kept` [µs] (none: `u64::MAX`, 0).
    pub(super) due: (u64, u64),
    pub(super) delivered: u64,
    pub(super) age_sum_us: u64,
}

impl Default for DueThread {
    fn default() -> Self {
        DueThread { picks: Vec::new(), kept: Vec::new(), due: (u64::MAX, 0), delivered: 0, age_sum_us: 0 }
    }
}

/// One due round as every chunk of its delivery reads it.
pub(super) struct DueRound<'a> {
    pub(super) now: u64,
    pub(super) epoch: u64,
    pub(super) round: &'a DelayedRound,
}

impl DueRound<'_> {
    /// Put the due receptions of the in-boxes `chunk` (slots `start..start + chunk.len()`) into
    /// them, one delivery per in-box, and keep the others in `t.kept`.
    pub(super) fn deliver(&self, start: usize, chunk: &mut [DelayItem<'_>], t: &mut DueThread) {
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
    pub(super) fn matches(&self, items: &[DelayItem<'_>]) -> bool {
        self.receivers.len() == items.len() && self.receivers.iter().zip(items).all(|(a, (b, _))| a == b)
    }

    /// Renumber the receptions by the receivers' places in `items` (the query's order now),
    /// those of receivers that left the world [`GONE`], keeping each receiver's order.
    pub(super) fn realign(&mut self, items: &[DelayItem<'_>], position_of: &mut Vec<u32>) {
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
