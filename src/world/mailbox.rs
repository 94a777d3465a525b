//! V2V mailboxes: out-boxes a controller fills, in-boxes the V2V rounds fill with shared batches.
//!
//! A round collects every out-going message of a channel into one batch (`Arc<[Message]>`) and
//! hands each receiver the batch plus which entries are for it, so a broadcast to N vehicles
//! copies neither the messages nor their payloads. An in-box keeps every round delivered since
//! the control phase last ran: a controller faster than V2V sees the same round again (check
//! [`Inbox::latest_round`]), a slower one sees all rounds it missed. Out-boxes keep what is
//! written between rounds until the next round of their channel takes it.

use std::any::Any;
use std::ops::Range;
use std::sync::Arc;

use bevy_ecs::prelude::Component;

use super::{SimTime, VehicleId};

/// Any value a vehicle sends; shared, never copied per receiver.
pub type Payload = Arc<dyn Any + Send + Sync>;

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

/// One round's delivery into an in-box: a shared batch and which of its entries are for us.
#[derive(Debug, Clone)]
struct Delivery {
    round: u64,
    batch: Arc<[Message]>,
    /// Messages from this sender are skipped (the receiver's own).
    exclude: VehicleId,
    /// `None`: every message of the batch (but `exclude`'s); `Some(r)`: the batch indices in
    /// `Inbox::picks[r]`.
    picks: Option<Range<usize>>,
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
        InboxIter { inbox: self, delivery: 0, k: 0 }
    }

    /// The messages of rounds numbered above `round` only (what a controller that remembers the
    /// last round it read has not seen yet).
    pub fn iter_after(&self, round: u64) -> InboxIter<'_> {
        let delivery = self.deliveries.partition_point(|d| d.round <= round);
        InboxIter { inbox: self, delivery, k: 0 }
    }

    /// Number of received messages.
    pub fn len(&self) -> usize {
        self.deliveries
            .iter()
            .map(|d| match &d.picks {
                Some(r) => r.len(),
                None => d.batch.iter().filter(|m| m.sender != d.exclude).count(),
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

    /// Drop old rounds if the control phase has run since the last delivery (`epoch` differs).
    fn begin(&mut self, epoch: u64) {
        if self.epoch != epoch {
            self.deliveries.clear();
            self.picks.clear();
            self.epoch = epoch;
        }
    }

    /// Deliver the whole `batch` except the messages of `exclude` (the network channel).
    pub(crate) fn deliver_all_but(&mut self, epoch: u64, round: u64, batch: &Arc<[Message]>, exclude: VehicleId) {
        self.begin(epoch);
        self.deliveries.push(Delivery { round, batch: Arc::clone(batch), exclude, picks: None });
    }

    /// Deliver the batch entries whose indices `picks` yields (the wifi channel).
    pub(crate) fn deliver_picks(
        &mut self,
        epoch: u64,
        round: u64,
        batch: &Arc<[Message]>,
        exclude: VehicleId,
        picks: impl Iterator<Item = u32>,
    ) {
        self.begin(epoch);
        let start = self.picks.len();
        self.picks.extend(picks);
        let range = start..self.picks.len();
        self.deliveries.push(Delivery { round, batch: Arc::clone(batch), exclude, picks: Some(range) });
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
}

impl<'a> Iterator for InboxIter<'a> {
    type Item = &'a Message;
    fn next(&mut self) -> Option<&'a Message> {
        loop {
            let d = self.inbox.deliveries.get(self.delivery)?;
            match &d.picks {
                Some(r) => {
                    if self.k < r.len() {
                        let index = self.inbox.picks[r.start + self.k] as usize;
                        self.k += 1;
                        return Some(&d.batch[index]);
                    }
                }
                None => {
                    while self.k < d.batch.len() {
                        let m = &d.batch[self.k];
                        self.k += 1;
                        if m.sender != d.exclude {
                            return Some(m);
                        }
                    }
                }
            }
            self.delivery += 1;
            self.k = 0;
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
    pub fn send(&mut self, channel: Channel, now: SimTime, payload: Payload) {
        let message = Message { sender: self.owner, sent_at: now, channel, payload };
        match channel {
            Channel::Network => self.network_out.push(message),
            Channel::Wifi => self.wifi_out.push(message),
        }
    }

    /// The in-box of `channel`.
    pub fn inbox(&self, channel: Channel) -> &Inbox {
        match channel {
            Channel::Network => &self.network_in,
            Channel::Wifi => &self.wifi_in,
        }
    }

    /// Queue a message of type `T` on `channel` (wraps it in the shared [`Payload`]); it leaves
    /// at the channel's next round.
    pub fn send_typed<T: Any + Send + Sync>(&mut self, channel: Channel, now: SimTime, message: T) {
        self.send(channel, now, Arc::new(message));
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
