//! The settings of the V2V channels: the wifi range and each channel's model.

use bevy_ecs::prelude::Resource;

use crate::sim::v2v::channel::ChannelModel;

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
