//! V2V: the network round (everyone but the sender) and the wifi round (senders within range).
//!
//! A round takes every out-going message of its channel, sorts them by sender id (so the order
//! never depends on entity layout) into one shared batch, and hands each receiver the batch plus
//! which entries are for it: the payloads are never copied. Wifi finds senders in range with a
//! spatial grid (O(N) per round).

use std::sync::Arc;

use bevy_ecs::prelude::{Local, Query, Res, ResMut, Resource};

use super::{Plugin, SimBuilder};
use crate::world::{Mailbox, Message, VehicleId, VehicleState};

use bevy_ecs::schedule::IntoScheduleConfigs;

use super::{ControlEpoch, GridEntry, Network, SimSystems, SpatialGrid, Wifi};

/// Settings of the V2V channels.
#[derive(Resource, Debug, Clone, Copy, PartialEq)]
pub struct V2vConfig {
    /// Wifi range [m], inclusive: a receiver exactly this far from a sender still hears it.
    pub wifi_range: f64,
}

impl Default for V2vConfig {
    fn default() -> Self {
        V2vConfig { wifi_range: 50.0 }
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

/// Network round: every mailbox's in-box gets every message but its own.
pub fn deliver_network(
    epoch: Res<ControlEpoch>,
    mut stats: ResMut<V2vStats>,
    mut mailboxes: Query<&mut Mailbox>,
    mut buffer: Local<Vec<Message>>,
) {
    stats.network_rounds += 1;
    let round = stats.network_rounds;
    for mut mailbox in &mut mailboxes {
        if !mailbox.network_out.is_empty() {
            buffer.append(&mut mailbox.network_out);
        }
    }
    let batch = into_batch(&mut buffer);
    stats.network_sent += batch.len() as u64;
    let mut delivered = 0;
    for mut mailbox in &mut mailboxes {
        let owner = mailbox.owner();
        let own = batch.partition_point(|m| m.sender < owner)..batch.partition_point(|m| m.sender <= owner);
        delivered += (batch.len() - own.len()) as u64;
        mailbox.network_in.deliver_all_but(epoch.0, round, &batch, owner);
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
}

/// Wifi round: each mailbox's in-box gets the messages of the senders within range (inclusive).
pub fn deliver_wifi(
    config: Res<V2vConfig>,
    epoch: Res<ControlEpoch>,
    mut stats: ResMut<V2vStats>,
    mut mailboxes: Query<(&VehicleState, &mut Mailbox)>,
    mut scratch: Local<WifiScratch>,
) {
    stats.wifi_rounds += 1;
    let round = stats.wifi_rounds;
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
        let picks = s.heard.iter().flat_map(|&i| {
            let start = starts[i as usize];
            start..start + senders[i as usize].2
        });
        delivered += s.heard.iter().map(|&i| senders[i as usize].2 as u64).sum::<u64>();
        mailbox.wifi_in.deliver_picks(epoch.0, round, &batch, owner, picks);
    }
    stats.wifi_delivered += delivered;
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
        sim.add_systems(Network, deliver_network.in_set(SimSystems::Communicate));
        sim.add_systems(Wifi, deliver_wifi.in_set(SimSystems::Communicate));
    }
}
