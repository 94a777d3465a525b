//! The constant loss model: each reception lost with the same probability.

use serde::Deserialize;

use super::Loss;
use super::plugins::{ChannelLossModel, LinkContext, LossModel, probability};

/// `loss = { model = "constant", p = 0.1 }` (the same as `loss = 0.1`): each reception lost
/// with probability `p` (Bernoulli, Plexe's frame error rate).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConstantLoss {
    /// Loss probability per reception [-].
    pub p: f64,
}

impl ChannelLossModel for ConstantLoss {
    fn check(&self) -> Result<(), (String, String)> {
        probability("p", self.p)
    }
    fn deliver(&self, link: &LinkContext, _state: &mut u64) -> Option<f64> {
        (link.words().uniform() >= self.p).then_some(0.0)
    }
    fn uses_distance(&self) -> bool {
        false
    }
    fn into_loss(self) -> LossModel {
        LossModel { loss: Loss::Constant(self.p), burst: None }
    }
}
