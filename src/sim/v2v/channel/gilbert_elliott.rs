//! The Gilbert-Elliott model: bursts of loss, a two-state Markov chain per link.

use serde::Deserialize;

use super::plugins::{ChannelLossModel, LinkContext, LossModel, probability};
use super::{Burst, Loss};

/// `loss = { model = "gilbert_elliott", p_enter = 0.01, p_leave = 0.2, loss_in_burst = 1.0 }`:
/// per link a good/bad Markov chain stepped once per message (the same as the channel's
/// `burst = { ... }` key).
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GilbertElliott {
    /// Probability per message of going from the good to the bad state [-].
    pub p_enter: f64,
    /// Probability per message of leaving the bad state [-]; mean burst length `1 / p_leave`.
    pub p_leave: f64,
    /// Loss probability in the bad state [-] (default 1).
    #[serde(default = "one")]
    pub loss_in_burst: f64,
}

fn one() -> f64 {
    1.0
}

impl ChannelLossModel for GilbertElliott {
    fn check(&self) -> Result<(), (String, String)> {
        probability("p_enter", self.p_enter)?;
        if !(self.p_leave > 0.0 && self.p_leave <= 1.0) {
            return Err(("p_leave".into(), format!("must be in (0, 1], got {}", self.p_leave)));
        }
        probability("loss_in_burst", self.loss_in_burst)
    }
    fn deliver(&self, link: &LinkContext, state: &mut u64) -> Option<f64> {
        let mut words = link.words();
        let flip = words.uniform();
        let bad = if *state == 1 { flip >= self.p_leave } else { flip < self.p_enter };
        *state = u64::from(bad);
        (!bad || words.uniform() >= self.loss_in_burst).then_some(0.0)
    }
    fn keeps_link_state(&self) -> bool {
        true
    }
    fn uses_distance(&self) -> bool {
        false
    }
    fn into_loss(self) -> LossModel {
        let burst = Burst { p_enter: self.p_enter, p_leave: self.p_leave, loss_in_burst: self.loss_in_burst };
        LossModel { loss: Loss::Constant(0.0), burst: Some(burst) }
    }
}
