//! V2V mailboxes: out-boxes a controller fills, in-boxes the V2V rounds fill with shared batches.
//!
//! A round collects every out-going message of a channel into one batch (`Arc<[Message]>`) and
//! hands each receiver the batch plus which entries are for it, so a broadcast to N vehicles
//! copies neither the messages nor their payloads. An in-box keeps every round delivered since
//! the control phase last ran: a controller faster than V2V sees the same round again (check
//! [`Inbox::latest_round`]), a slower one sees all rounds it missed. Out-boxes keep what is
//! written between rounds until the next round of their channel takes it.
//!
//! A delivery names its entries in one of three ways: the whole batch but the receiver's own
//! messages (a perfect network round), a list of batch indices (wifi, delayed receptions,
//! per-link channel models), or the whole batch but the receiver's own and a random subset of
//! lost ones (a network round with constant, memoryless loss): that subset is held as an
//! [`OrderedSample`] (a key and a count, two words) and its positions are drawn while the
//! in-box is iterated, so a round with N receivers stores O(N), not N² picks.

use std::any::Any;
use std::cell::Cell;
use std::ops::Range;
use std::ptr::NonNull;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use bevy_ecs::prelude::Component;

use super::random::OrderedSample;
use super::{SimTime, VehicleId};

pub use super::payload::Payload;

/// The two V2V channels of the 2015 simulator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Channel {
    /// Long range: every vehicle with a mailbox receives every message (but its own).
    Network,
    /// Short range: only receivers within the wifi range of the sender (inclusive).
    Wifi,
}

/// One V2V message.
#[derive(Clone)]
pub struct Message {
    /// Who sent it.
    pub sender: VehicleId,
    /// When it was written [sim time].
    pub sent_at: SimTime,
    /// The channel it travels on.
    pub channel: Channel,
    /// The content; use [`Message::payload`] to read it as a concrete type.
    pub payload: Payload,
}

impl Message {
    /// The payload as a `T`, or `None` if it holds something else.
    pub fn payload<T: Any>(&self) -> Option<&T> {
        self.payload.downcast_ref::<T>()
    }
}

impl std::fmt::Debug for Message {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Message")
            .field("sender", &self.sender)
            .field("sent_at", &self.sent_at)
            .field("channel", &self.channel)
            .finish_non_exhaustive()
    }
}

/// Which entries of a delivery's batch are for the receiver.
#[derive(Debug, Clone)]
enum Selection {
    /// Every message of the batch but `exclude`'s.
    AllBut,
    /// The batch indices in `Inbox::picks[range]`.
    Picks(Range<usize>),
    /// Every message but `exclude`'s (the batch sorted by sender, so they are contiguous) less
    /// the positions `lost` yields, counted among the messages that are not `exclude`'s.
    AllButLost {
        lost: OrderedSample,
        /// Messages delivered (not `exclude`'s, not lost).
        kept: usize,
    },
}

/// A round's batch as the in-boxes of one thread's chunk take it: a count of that chunk's own
/// on the shared batch, which it hands out and takes back in bulk.
///
/// Every in-box of a round took a reference to the one batch (and let go of the last round's):
/// two locked operations per receiver on one count, from every thread at once, so the cache
/// line of the count went back and forth between the cores. perf put 92 % of the wifi
/// delivery's two-thread samples on those two instructions, and the round took several times
/// the processor time on two threads that it took on one. A round made one counted reference
/// per chunk, each thread counting on its own line; still two locked operations per receiver
/// (a quarter of the wifi reception's samples on one thread). Now a `BatchRef` counts the
/// references it hands out ([`BatchRef::lend`]) `LEND_BLOCK` at a time, and takes the in-boxes'
/// references to an earlier round back ([`BatchRef::take_back`]) run by run: a locked
/// operation every few hundred receivers. It is used on the thread that made it (not `Sync`).
pub(crate) struct BatchRef {
    /// The chunk's own reference (which keeps the batch while the chunk delivers).
    own: Held,
    /// References counted into `own`'s count but not handed out yet.
    spare: Cell<usize>,
    /// References to another round's batch handed back by in-boxes and not yet taken off its
    /// count: consecutive in-boxes mostly held the same one.
    returned: Cell<Option<(NonNull<Counted>, usize)>>,
}

/// References [`BatchRef::lend`] counts in at a time.
const LEND_BLOCK: usize = 256;

/// A shared batch and its count of references ([`Held`]), aligned so that the count shares
/// its cache lines with nothing else.
#[repr(align(128))]
struct Counted {
    count: AtomicUsize,
    batch: Arc<[Message]>,
}

/// One counted reference to a [`Counted`] batch: `Arc`'s protocol (an increment to clone, a
/// decrement to drop, the last one frees), on a count [`BatchRef`] can move in bulk.
pub(crate) struct Held(NonNull<Counted>);

// SAFETY: a `Held` gives shared access to a `Counted` (an atomic count and an `Arc<[Message]>`,
// both `Send + Sync`) and frees it only as the last reference, like `Arc<Counted>`.
unsafe impl Send for Held {}
// SAFETY: as above.
unsafe impl Sync for Held {}
const _: () = {
    const fn send_sync<T: Send + Sync>() {}
    send_sync::<Arc<[Message]>>()
};

impl Held {
    fn counted(&self) -> &Counted {
        // SAFETY: this reference is counted, so the `Counted` is alive.
        unsafe { self.0.as_ref() }
    }
}

impl Clone for Held {
    fn clone(&self) -> Held {
        // Relaxed, as `Arc::clone`: a new reference is made from an existing one.
        self.counted().count.fetch_add(1, Ordering::Relaxed);
        Held(self.0)
    }
}

impl Drop for Held {
    fn drop(&mut self) {
        release(self.0, 1);
    }
}

/// Take `n` references off `counted`'s count, freeing it when they were the last ones.
fn release(counted: NonNull<Counted>, n: usize) {
    // SAFETY: the caller gives up `n` counted references, so the `Counted` is alive until the
    // decrement; Release then Acquire before freeing, as `Arc`'s drop.
    unsafe {
        if counted.as_ref().count.fetch_sub(n, Ordering::Release) == n {
            std::sync::atomic::fence(Ordering::Acquire);
            drop(Box::from_raw(counted.as_ptr()));
        }
    }
}

impl std::fmt::Debug for Held {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Held").field("messages", &self.len()).finish()
    }
}

impl std::ops::Deref for Held {
    type Target = [Message];
    fn deref(&self) -> &[Message] {
        &self.counted().batch
    }
}

impl BatchRef {
    /// A chunk's own reference to `batch` (one count taken on the shared batch).
    pub(crate) fn new(batch: &Arc<[Message]>) -> BatchRef {
        let counted = Box::new(Counted { count: AtomicUsize::new(1), batch: Arc::clone(batch) });
        let own = Held(NonNull::from(Box::leak(counted)));
        BatchRef { own, spare: Cell::new(0), returned: Cell::new(None) }
    }

    /// A counted reference for an in-box: from the references counted in ahead, a block of
    /// them counted in at once when none is left.
    fn lend(&self) -> Held {
        let spare = match self.spare.get() {
            0 => {
                self.own.counted().count.fetch_add(LEND_BLOCK, Ordering::Relaxed);
                LEND_BLOCK
            }
            n => n,
        };
        self.spare.set(spare - 1);
        Held(self.own.0)
    }

    /// Take back an in-box's reference `held` (to any round's batch): counted off with the run
    /// of references to the same batch it belongs to.
    fn take_back(&self, held: Held) {
        let counted = held.0;
        std::mem::forget(held);
        match self.returned.get() {
            Some((c, n)) if c == counted => self.returned.set(Some((c, n + 1))),
            other => {
                self.returned.set(Some((counted, 1)));
                if let Some((c, n)) = other {
                    release(c, n);
                }
            }
        }
    }
}

impl Drop for BatchRef {
    fn drop(&mut self) {
        if let Some((c, n)) = self.returned.take() {
            release(c, n);
        }
        // The spare references are counted on the batch `own` holds, which keeps it: this
        // cannot free it.
        let spare = self.spare.take();
        if spare > 0 {
            release(self.own.0, spare);
        }
    }
}

impl std::ops::Deref for BatchRef {
    type Target = [Message];
    fn deref(&self) -> &[Message] {
        &self.own
    }
}

/// One round's delivery into an in-box: a shared batch and which of its entries are for us.
#[derive(Debug, Clone)]
struct Delivery {
    round: u64,
    batch: Held,
    /// Messages from this sender are skipped (the receiver's own).
    exclude: VehicleId,
    selection: Selection,
}

/// Received messages of one channel: every round delivered since the control phase last ran.
#[derive(Debug, Clone, Default)]
pub struct Inbox {
    deliveries: Vec<Delivery>,
    picks: Vec<u32>,
    epoch: u64,
}

impl Inbox {
    /// All received messages, oldest round first, in sender-id order within a round.
    pub fn iter(&self) -> InboxIter<'_> {
        InboxIter::at(self, 0)
    }

    /// The messages of rounds numbered above `round` only (what a controller that remembers the
    /// last round it read has not seen yet).
    pub fn iter_after(&self, round: u64) -> InboxIter<'_> {
        let delivery = self.deliveries.partition_point(|d| d.round <= round);
        InboxIter::at(self, delivery)
    }

    /// Number of received messages.
    pub fn len(&self) -> usize {
        self.deliveries
            .iter()
            .map(|d| match &d.selection {
                Selection::Picks(r) => r.len(),
                Selection::AllBut => d.batch.iter().filter(|m| m.sender != d.exclude).count(),
                Selection::AllButLost { kept, .. } => *kept,
            })
            .sum()
    }

    /// Whether nothing was received.
    pub fn is_empty(&self) -> bool {
        self.iter().next().is_none()
    }

    /// Number of the newest round held (rounds count from 1 per channel), if any.
    pub fn latest_round(&self) -> Option<u64> {
        self.deliveries.last().map(|d| d.round)
    }

    /// Ask the processor for the memory a delivery at `epoch` will write (the next delivery and
    /// pick slots), for a loop that delivers to many in-boxes one after the other: their
    /// buffers lie far apart in memory, and a delivery is too short to hide a miss.
    pub(crate) fn prefetch(&self, epoch: u64) {
        let at = |len: usize| if self.epoch == epoch { len } else { 0 };
        super::prefetch(self.deliveries.as_ptr().wrapping_add(at(self.deliveries.len())));
        super::prefetch(self.picks.as_ptr().wrapping_add(at(self.picks.len())));
    }

    /// Drop old rounds if the control phase has run since the last delivery (`epoch` differs),
    /// their references handed back to `batch`.
    fn begin(&mut self, epoch: u64, batch: &BatchRef) {
        if self.epoch != epoch {
            for delivery in self.deliveries.drain(..) {
                batch.take_back(delivery.batch);
            }
            self.picks.clear();
            self.epoch = epoch;
        }
    }

    /// Keep `delivery`, growing the list from one place by doubling rather than from the
    /// standard four: an in-box mostly holds one round between two control ticks, and four
    /// places of a delivery were 24 MB of every 32 MB the in-boxes of 100,000 vehicles held.
    fn push(&mut self, delivery: Delivery) {
        if self.deliveries.len() == self.deliveries.capacity() {
            self.deliveries.reserve_exact(self.deliveries.capacity().max(1));
        }
        self.deliveries.push(delivery);
    }

    /// Deliver the whole `batch` except the messages of `exclude` (the network channel).
    pub(crate) fn deliver_all_but(&mut self, epoch: u64, round: u64, batch: &BatchRef, exclude: VehicleId) {
        self.begin(epoch, batch);
        self.push(Delivery { round, batch: batch.lend(), exclude, selection: Selection::AllBut });
    }

    /// Deliver the whole `batch` (sorted by sender) except the messages of `exclude` and the
    /// positions `lost` yields, counted among the `others` messages that are not `exclude`'s
    /// (the network channel with constant loss; the caller has found them). `lost` must sample
    /// from exactly that many messages.
    pub(crate) fn deliver_all_but_lost(
        &mut self,
        epoch: u64,
        round: u64,
        batch: &BatchRef,
        (exclude, others): (VehicleId, usize),
        lost: OrderedSample,
    ) {
        self.begin(epoch, batch);
        let kept = others - lost.remaining() as usize;
        self.push(Delivery { round, batch: batch.lend(), exclude, selection: Selection::AllButLost { lost, kept } });
    }

    /// Deliver the batch entries whose indices `picks` yields (the wifi channel).
    pub(crate) fn deliver_picks(
        &mut self,
        epoch: u64,
        round: u64,
        batch: &BatchRef,
        exclude: VehicleId,
        picks: impl Iterator<Item = u32>,
    ) {
        self.begin(epoch, batch);
        let start = self.picks.len();
        self.picks.extend(picks);
        let range = start..self.picks.len();
        self.push(Delivery { round, batch: batch.lend(), exclude, selection: Selection::Picks(range) });
    }
}

impl<'a> IntoIterator for &'a Inbox {
    type Item = &'a Message;
    type IntoIter = InboxIter<'a>;
    fn into_iter(self) -> InboxIter<'a> {
        self.iter()
    }
}

/// Iterator over an [`Inbox`].
#[derive(Debug)]
pub struct InboxIter<'a> {
    inbox: &'a Inbox,
    delivery: usize,
    k: usize,
    /// In an `AllButLost` delivery: the lost positions not yet passed, the next of them
    /// (`u32::MAX` when none is left) and how many of the receiver's others were passed.
    lost: OrderedSample,
    next_lost: u32,
    others: u32,
}

impl<'a> InboxIter<'a> {
    fn at(inbox: &'a Inbox, delivery: usize) -> InboxIter<'a> {
        let mut it = InboxIter { inbox, delivery, k: 0, lost: OrderedSample::empty(), next_lost: u32::MAX, others: 0 };
        it.enter();
        it
    }

    /// Start the delivery `self.delivery` at its first entry.
    fn enter(&mut self) {
        self.k = 0;
        if let Some(Delivery { selection: Selection::AllButLost { lost, .. }, .. }) =
            self.inbox.deliveries.get(self.delivery)
        {
            self.lost = *lost;
            self.next_lost = self.lost.next().unwrap_or(u32::MAX);
            self.others = 0;
        }
    }
}

impl<'a> Iterator for InboxIter<'a> {
    type Item = &'a Message;
    fn next(&mut self) -> Option<&'a Message> {
        loop {
            let d = self.inbox.deliveries.get(self.delivery)?;
            match &d.selection {
                Selection::Picks(r) => {
                    if self.k < r.len() {
                        let index = self.inbox.picks[r.start + self.k] as usize;
                        self.k += 1;
                        return Some(&d.batch[index]);
                    }
                }
                Selection::AllBut => {
                    while self.k < d.batch.len() {
                        let m = &d.batch[self.k];
                        self.k += 1;
                        if m.sender != d.exclude {
                            return Some(m);
                        }
                    }
                }
                Selection::AllButLost { .. } => {
                    while self.k < d.batch.len() {
                        let m = &d.batch[self.k];
                        self.k += 1;
                        if m.sender == d.exclude {
                            continue;
                        }
                        let position = self.others;
                        self.others += 1;
                        if position == self.next_lost {
                            self.next_lost = self.lost.next().unwrap_or(u32::MAX);
                            continue;
                        }
                        return Some(m);
                    }
                }
            }
            self.delivery += 1;
            self.enter();
        }
    }
}

/// A vehicle's V2V mailbox: out-boxes it writes, in-boxes the V2V rounds fill.
#[derive(Component, Debug, Clone)]
pub struct Mailbox {
    owner: VehicleId,
    /// Messages waiting for the next network round.
    pub network_out: Vec<Message>,
    /// Network messages received (see the module docs for how long they stay).
    pub network_in: Inbox,
    /// Messages waiting for the next wifi round.
    pub wifi_out: Vec<Message>,
    /// Wifi messages received.
    pub wifi_in: Inbox,
}

impl Mailbox {
    /// An empty mailbox of vehicle `owner`.
    pub fn new(owner: VehicleId) -> Mailbox {
        Mailbox {
            owner,
            network_out: Vec::new(),
            network_in: Inbox::default(),
            wifi_out: Vec::new(),
            wifi_in: Inbox::default(),
        }
    }

    /// The vehicle this mailbox belongs to.
    pub fn owner(&self) -> VehicleId {
        self.owner
    }

    /// Queue `payload` on `channel`, written at `now`; it leaves at the channel's next round.
    /// `payload` is a [`Payload`] or an `Arc` of any value (shared by the receivers).
    pub fn send(&mut self, channel: Channel, now: SimTime, payload: impl Into<Payload>) {
        let message = Message { sender: self.owner, sent_at: now, channel, payload: payload.into() };
        let out = match channel {
            Channel::Network => &mut self.network_out,
            Channel::Wifi => &mut self.wifi_out,
        };
        // Mostly one message a round (a beacon), and the out-box keeps its place between
        // rounds: room for one, not the standard four (120 bytes a vehicle and channel, 24 MB
        // of fresh memory at 100,000 vehicles); more grows it as usual.
        if out.capacity() == 0 {
            out.reserve_exact(1);
        }
        out.push(message);
    }

    /// The in-box of `channel`.
    pub fn inbox(&self, channel: Channel) -> &Inbox {
        match channel {
            Channel::Network => &self.network_in,
            Channel::Wifi => &self.wifi_in,
        }
    }

    /// The in-box of `channel`, to deliver into.
    pub(crate) fn inbox_mut(&mut self, channel: Channel) -> &mut Inbox {
        match channel {
            Channel::Network => &mut self.network_in,
            Channel::Wifi => &mut self.wifi_in,
        }
    }

    /// Queue a message of type `T` on `channel` (wraps it in the shared [`Payload`]); it leaves
    /// at the channel's next round.
    pub fn send_typed<T: Any + Send + Sync>(&mut self, channel: Channel, now: SimTime, message: T) {
        self.send(channel, now, Payload::new(message));
    }

    /// Queue a small `Copy` value on `channel`: held inline in the message when it fits
    /// ([`Payload::copied`]: no allocation, no reference count), shared otherwise. Read it as
    /// any other message. It leaves at the channel's next round.
    pub fn send_copy<T: Copy + Any + Send + Sync>(&mut self, channel: Channel, now: SimTime, message: T) {
        self.send(channel, now, Payload::copied(message));
    }

    /// Replace this vehicle's queued messages of type `T` on `channel` with `message`: for
    /// beacons, of which only the newest matters.
    pub fn send_latest<T: Any + Send + Sync>(&mut self, channel: Channel, now: SimTime, message: T) {
        let out = match channel {
            Channel::Network => &mut self.network_out,
            Channel::Wifi => &mut self.wifi_out,
        };
        out.retain(|m| m.payload::<T>().is_none());
        self.send_typed(channel, now, message);
    }

    /// The received messages of type `T` on `channel`, with their senders and send times,
    /// oldest round first (messages of other types are skipped).
    pub fn received<T: Any>(&self, channel: Channel) -> impl Iterator<Item = (VehicleId, SimTime, &T)> + '_ {
        self.inbox(channel).iter().filter_map(|m| Some((m.sender, m.sent_at, m.payload::<T>()?)))
    }

    /// The newest received message of type `T` from `sender` on `channel`, if any.
    pub fn latest_from<T: Any>(&self, channel: Channel, sender: VehicleId) -> Option<(SimTime, &T)> {
        self.received::<T>(channel).filter(|(s, _, _)| *s == sender).map(|(_, t, m)| (t, m)).last()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::random::key;

    #[test]
    fn an_out_box_makes_room_for_one_beacon_and_grows_for_more() {
        let mut mailbox = Mailbox::new(VehicleId(1));
        mailbox.send_copy(Channel::Wifi, SimTime(0), 1.5f64);
        mailbox.send_copy(Channel::Network, SimTime(0), 2.5f64);
        assert_eq!((mailbox.wifi_out.capacity(), mailbox.network_out.capacity()), (1, 1));
        // Emptied each round, it keeps its room.
        mailbox.wifi_out.pop();
        mailbox.send_copy(Channel::Wifi, SimTime(1), 3.5f64);
        assert_eq!(mailbox.wifi_out.capacity(), 1);
        for k in 0..5 {
            mailbox.send_copy(Channel::Wifi, SimTime(1), f64::from(k));
        }
        assert_eq!(mailbox.wifi_out.len(), 6);
        let sent: Vec<f64> = mailbox.wifi_out.iter().filter_map(|m| m.payload::<f64>().copied()).collect();
        assert_eq!(sent, [3.5, 0.0, 1.0, 2.0, 3.0, 4.0]);
    }

    fn batch(senders: &[i32]) -> BatchRef {
        let messages: Arc<[Message]> = senders
            .iter()
            .enumerate()
            .map(|(i, &s)| Message {
                sender: VehicleId(s),
                sent_at: SimTime(i as u64),
                channel: Channel::Network,
                payload: Payload::copied(i),
            })
            .collect();
        BatchRef::new(&messages)
    }

    #[test]
    fn rounds_lend_and_take_back_references_in_bulk_and_each_batch_goes_with_its_last_reader() {
        // More receivers than a block of lent references; a third of them skip each round, so
        // in-boxes hold references to three rounds at once when the next one is delivered.
        let rounds: Vec<Arc<[Message]>> = (0..4)
            .map(|r| {
                (0..3)
                    .map(|i| Message {
                        sender: VehicleId(i),
                        sent_at: SimTime(r),
                        channel: Channel::Wifi,
                        payload: Payload::copied(r as usize * 10 + i as usize),
                    })
                    .collect()
            })
            .collect();
        let mut inboxes = vec![Inbox::default(); 2 * LEND_BLOCK + 77];
        let held = |inboxes: &[Inbox], r: usize| inboxes.iter().any(|i| i.latest_round() == Some(r as u64 + 1));
        for (r, batch) in rounds.iter().enumerate() {
            let shared = BatchRef::new(batch);
            for (k, inbox) in inboxes.iter_mut().enumerate() {
                if (k + r) % 3 != 0 {
                    inbox.deliver_picks(r as u64 + 1, r as u64 + 1, &shared, VehicleId(-1), [k as u32 % 3].into_iter());
                }
            }
            drop(shared);
            for (k, inbox) in inboxes.iter().enumerate() {
                if (k + r) % 3 != 0 {
                    let got: Vec<usize> = inbox.iter().map(|m| *m.payload::<usize>().expect("a usize")).collect();
                    assert_eq!(got, [r * 10 + k % 3], "in-box {k}, round {r}");
                }
            }
            // A batch is kept (our reference and its count's) exactly while an in-box holds it.
            for (q, batch) in rounds.iter().enumerate().take(r + 1) {
                assert_eq!(Arc::strong_count(batch), 1 + usize::from(held(&inboxes, q)), "round {q} after {r}");
            }
        }
        let copy = inboxes[4].clone();
        drop(inboxes);
        let kept = copy.latest_round().expect("in-box 4 received") as usize - 1;
        for (q, batch) in rounds.iter().enumerate() {
            assert_eq!(Arc::strong_count(batch), 1 + usize::from(q == kept), "round {q}, the copy holds {kept}");
        }
        drop(copy);
        assert!(rounds.iter().all(|b| Arc::strong_count(b) == 1), "every batch went with its last reader");
    }

    #[test]
    fn an_inbox_keeps_room_for_the_rounds_it_held_not_four() {
        let b = batch(&[-2, -1, 3]);
        let mut inbox = Inbox::default();
        inbox.deliver_all_but(1, 1, &b, VehicleId(-1));
        assert_eq!(inbox.deliveries.capacity(), 1, "one round: one place");
        inbox.deliver_all_but(2, 2, &b, VehicleId(-1)); // a new epoch: the old round goes
        assert_eq!(inbox.deliveries.capacity(), 1);
        for round in 3..6 {
            inbox.deliver_picks(2, round, &b, VehicleId(-1), [0, 2].into_iter());
        }
        assert_eq!(inbox.deliveries.capacity(), 4, "doubling: 1, 2, 4");
        assert_eq!(inbox.len(), 2 + 3 * 2, "every round of the epoch is held");
    }

    #[test]
    fn a_lossy_delivery_yields_the_batch_less_own_less_lost_in_order() {
        // Sorted by sender; the receiver -3 has two messages in the middle.
        let senders = [-9, -7, -7, -5, -3, -3, -2, 1, 4, 4, 6, 8];
        let b = batch(&senders);
        let me = VehicleId(-3);
        let others: Vec<usize> = (0..senders.len()).filter(|&i| senders[i] != me.0).collect();
        for (k, seed) in [(0u32, 1u64), (3, 2), (3, 3), (10, 4)] {
            let lost = OrderedSample::new(key(seed, 1, 2), k, others.len() as u32);
            let lost_positions: Vec<u32> = lost.collect();
            assert_eq!(lost_positions.len(), k as usize);
            let expected: Vec<usize> = others
                .iter()
                .enumerate()
                .filter(|(p, _)| !lost_positions.contains(&(*p as u32)))
                .map(|(_, &i)| i)
                .collect();
            let mut inbox = Inbox::default();
            inbox.deliver_all_but_lost(1, 7, &b, (me, others.len()), lost);
            let got: Vec<usize> =
                inbox.iter().map(|m| *m.payload::<usize>().expect("every test message carries a usize")).collect();
            assert_eq!(got, expected, "{k} lost");
            assert_eq!(inbox.len(), expected.len());
            assert_eq!(inbox.is_empty(), expected.is_empty());
        }
    }

    #[test]
    fn lossy_deliveries_mix_with_others_and_iter_after_restarts_the_draws() {
        let b = batch(&[-4, -3, -2, -1, 0, 1, 2, 3]);
        let me = VehicleId(0);
        let lost = OrderedSample::new(key(9, 9, 9), 3, 7);
        let lost_positions: Vec<u32> = lost.collect();
        let mut inbox = Inbox::default();
        inbox.deliver_all_but_lost(1, 1, &b, (me, 7), lost);
        inbox.deliver_picks(1, 2, &b, me, [1u32, 6].into_iter());
        inbox.deliver_all_but_lost(1, 3, &b, (me, 7), lost);
        inbox.deliver_all_but(1, 4, &b, me);
        let one_round: Vec<usize> =
            (0..7).filter(|p| !lost_positions.contains(&(*p as u32))).map(|p| if p < 4 { p } else { p + 1 }).collect();
        let mut expected = one_round.clone();
        expected.extend([1, 6]);
        expected.extend(one_round.iter().copied());
        expected.extend([0, 1, 2, 3, 5, 6, 7]);
        let got: Vec<usize> =
            inbox.iter().map(|m| *m.payload::<usize>().expect("every test message carries a usize")).collect();
        assert_eq!(got, expected);
        assert_eq!(inbox.len(), expected.len());
        let after: Vec<usize> =
            inbox.iter_after(2).map(|m| *m.payload::<usize>().expect("every test message carries a usize")).collect();
        assert_eq!(after, expected[one_round.len() + 2..].to_vec());
    }
}
