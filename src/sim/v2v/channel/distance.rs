//! The distance loss model: the loss probability rises with the square of the distance.

use serde::Deserialize;

use super::Loss;
use super::plugins::{ChannelLossModel, LinkContext, LossModel, probability};

/// `loss = { model = "distance", p_at_0 = 0.01, p_at_range = 0.5 }`: loss
/// `p_at_0 + (p_at_range - p_at_0) (d / range)²`, clamped to [0, 1].
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DistanceLoss {
    /// Loss probability next to the sender [-].
    #[serde(default)]
    pub p_at_0: f64,
    /// Loss probability at the channel's range [-].
    pub p_at_range: f64,
}

impl ChannelLossModel for DistanceLoss {
    fn check(&self) -> Result<(), (String, String)> {
        probability("p_at_0", self.p_at_0)?;
        probability("p_at_range", self.p_at_range)
    }
    fn deliver(&self, link: &LinkContext, _state: &mut u64) -> Option<f64> {
        let u = if link.range > 0.0 { (link.distance / link.range).min(1.0) } else { 1.0 };
        let p = (self.p_at_0 + (self.p_at_range - self.p_at_0) * u * u).clamp(0.0, 1.0);
        (link.words().uniform() >= p).then_some(0.0)
    }
    fn into_loss(self) -> LossModel {
        LossModel { loss: Loss::Distance { p_at_0: self.p_at_0, p_at_range: self.p_at_range }, burst: None }
    }
}
