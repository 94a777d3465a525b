//! V2V: the network round (everyone but the sender) and the wifi round (senders within range).
//!
//! A round takes every out-going message of its channel, sorts them by sender id (so the order
//! never depends on entity layout) into one shared batch, and hands each receiver the batch plus
//! which entries are for it: the payloads are never copied. Wifi finds senders in range with a
//! spatial grid (O(N) per round), or, when the sensors' neighbour lists still hold everyone
//! within the wifi range (every vehicle in one ECS table with sensors reaching at least as far,
//! nobody moved half their skin since their build), from those lists: no grid to build, a
//! short list per receiver (`sim::grid::lists`). Either way the same receptions.
//!
//! Each channel has a [`ChannelModel`](channel::ChannelModel) (loss, bursts, delay; perfect by default). A lossy channel
//! decides every reception with a seeded draw ([`channel`]); a delaying one queues the
//! reception and [`deliver_delayed`] puts it into the in-box at the first control tick at or
//! after its due time, links never reordered. Wifi stays O(N · neighbours).
//!
//! The network round with a constant, memoryless loss (a [`Loss::Constant`](channel::Loss::Constant) probability, no
//! bursts, no delay: nothing kept per link, nothing depending on distance) costs O(N) per
//! round, not O(N²): for each receiver it draws how many of the batch's other M messages are
//! lost (one [`binomial`](crate::sim::random::binomial) draw) and stores that count with a key; which ones are lost is a
//! uniformly random subset of that size ([`OrderedSample`](crate::sim::random::OrderedSample)), drawn only when the in-box is
//! read. Given its count, the lost set of independent Bernoulli losses is exactly such a
//! subset, so every receiver still loses each reception independently with probability p.
//! The departure from REFERENCE's keying: these draws are keyed by (seed, network stream,
//! receiver, round, draw number) and not per (sender, receiver, tick, index): one draw no
//! longer belongs to one reception. They remain counter-based, so threads, system order and
//! the order of reading change nothing. Every other network model (bursts, distance loss,
//! delay) decides each reception on its own as before, keyed per reception: O(N²) per round.
//!
//! The files: `wifi` and `network` (the rounds), `delayed` (receptions queued until due),
//! `batch` (the shared batch of a round) and `stats`; the channel models are in [`channel`]:
//! the runtime form every channel runs, the built-in models one file each, and the plugin API
//! ([`channel::plugins`]).

use bevy_ecs::prelude::Resource;
use bevy_ecs::schedule::IntoScheduleConfigs;

use crate::sim::grid::lists::{ListFloor, NearWanted};
use crate::sim::{Control, Network, Plugin, SimBuilder, SimSystems, Wifi};

mod batch;
pub mod channel;
mod config;
mod delayed;
mod network;
mod stats;
#[cfg(test)]
mod tests;
mod wifi;

pub use config::V2vConfig;
pub use delayed::{DelayScratch, DelayedMessages, deliver_delayed};
pub use network::{LossyScratch, deliver_network};
pub use stats::{ChannelStats, V2vChannelStats, V2vLinks, V2vStats};
pub use wifi::{WifiScratch, deliver_wifi};

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
