//! A round's shared batch: every out-going message of a channel sorted by sender, each
//! receiver's own messages found in it, and the batch released on the threads.

use std::mem::ManuallyDrop;
use std::sync::Arc;

use crate::sim::Parallelism;
use crate::world::{Mailbox, Message, SimTime, VehicleId, VehicleState};

/// Sort by sender id, keeping each sender's own order (stable).
pub(super) fn into_batch(buffer: &mut Vec<Message>) -> Arc<[Message]> {
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
pub(super) fn join_batch(
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
pub(super) fn round_order(chunks: &[Outgoing]) -> Option<bool> {
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
pub(super) fn common_sent_at(batch: &[Message]) -> Option<SimTime> {
    batch.first().map(|m| m.sent_at).filter(|&t| batch.iter().all(|m| m.sent_at == t))
}
/// The messages of `owner` in `batch` (sorted by sender): looked for first as one message
/// beside `hint`, the start of the previous receiver's (receivers in query order are mostly the
/// senders in id order, rising or falling, one beacon each), else by two binary searches over
/// the batch (a probe per halving, most of them cache misses, per receiver: most of a perfect
/// network round's time at 10,000 vehicles). Sets `hint` to the start found.
pub(super) fn own_messages(batch: &[Message], owner: VehicleId, hint: &mut usize) -> std::ops::Range<usize> {
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
/// A vehicle that sends this wifi round.
#[derive(Debug, Clone, Copy)]
pub(super) struct Sender {
    pub(super) id: VehicleId,
    /// Where it sends from [m].
    pub(super) position: glam::DVec2,
    /// How many messages it sends.
    pub(super) count: u32,
    /// Its place in the query.
    pub(super) place: u32,
}

/// [`WifiScratch::sender_of`] of a vehicle that sends nothing.
pub(super) const NOT_SENDING: u32 = u32::MAX;
/// The messages of one chunk of out-boxes and who sent them, in query order.
/// On cache lines of its own (see [`crate::sim::parallel::Padded`]).
#[derive(Default)]
#[repr(align(128))]
pub(super) struct Outgoing {
    pub(super) senders: Vec<Sender>,
    pub(super) messages: Vec<Message>,
    /// The senders' ids rise (strictly), as [`Outgoing::take`] left them.
    pub(super) rising: bool,
    /// The senders' ids fall (strictly) and each sent one message.
    pub(super) falling: bool,
    /// Earliest and latest send time of `messages` [µs] (none: `u64::MAX`, 0).
    pub(super) sent: (u64, u64),
}

impl Outgoing {
    /// Empty the wifi out-boxes of `boxes` (at `states`, places `start..` in the query) into this.
    pub(super) fn take(&mut self, start: usize, states: &[VehicleState], boxes: &mut [Mailbox]) {
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
    pub(super) fn note_order(&mut self) {
        let ids = || self.senders.windows(2).map(|w| (w[0].id, w[1].id));
        self.rising = ids().all(|(a, b)| a < b);
        self.falling = self.messages.len() == self.senders.len() && ids().all(|(a, b)| a > b);
    }
}
/// Let go of `batch`; if this was its last reference, drop its messages split over the
/// threads of `parallelism`, each thread a contiguous chunk.
///
/// A round's batch was freed by the in-box that dropped it last, inside the next round's
/// parallel section: ten thousand payloads (each an allocation) freed on one thread, about
/// 0.2 ms while the other threads waited. Chunks of a batch (sorted by sender) are mostly the
/// payloads the same thread allocated when its chunk of vehicles sent them.
pub(super) fn release(batch: Arc<[Message]>, parallelism: Parallelism) {
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
