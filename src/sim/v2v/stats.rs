//! What the V2V rounds count: per channel ([`ChannelStats`]), per link ([`V2vLinks`]) and in all
//! ([`V2vStats`]).

use bevy_ecs::prelude::Resource;
use std::collections::HashMap;

use crate::sim::v2v::channel::LinkState;
use crate::world::{VehicleId, Vehicles};

/// Delay histogram resolution [µs] and length: 0.5 ms bins up to 5 s (the last bin holds more).
pub(super) const DELAY_BIN_US: u64 = 500;
pub(super) const DELAY_BINS: usize = 10_000;

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
    pub(super) delay_bins: Vec<u64>,
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
    pub(super) fn add_delay(&mut self, delay_us: u64) -> usize {
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
    pub(super) fn absorb(&mut self, other: &mut ChannelStats, bins: (usize, usize)) {
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
    pub(super) wifi: HashMap<(VehicleId, VehicleId), LinkState>,
    pub(super) network: HashMap<(VehicleId, VehicleId), LinkState>,
    /// Prune when this many links are held (see [`V2vLinks::prune`]).
    pub(super) prune_at: usize,
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
    pub(super) fn prune(&mut self, registry: &Vehicles) {
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
pub(super) const MIN_PRUNE: usize = 1024;
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
