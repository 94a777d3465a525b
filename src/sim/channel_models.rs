//! Channel models by name: the trait a student's loss model implements
//! ([`ChannelLossModel`]), and the registry from a scenario's
//! `loss = { model = "NAME", ... }` (in `[v2v.wifi]` or `[v2v.network]`) to a model. The
//! built-in models, `constant`, `distance` and `gilbert_elliott`, are registered through it like
//! a plugin's; they hand the runtime their specialised form ([`ChannelLossModel::into_loss`]), so
//! the V2V rounds keep their fast paths for them.
//!
//! ```
//! use smlworld::prelude::*;
//! use smlworld::sim::channel_models::{ChannelLossModel, LinkContext};
//!
//! /// Lost beyond `reach` [m], delivered within.
//! #[derive(serde::Deserialize)]
//! #[serde(deny_unknown_fields)]
//! struct Cliff {
//!     reach: f64,
//! }
//!
//! impl ChannelLossModel for Cliff {
//!     fn deliver(&self, link: &LinkContext, _state: &mut u64) -> Option<f64> {
//!         (link.distance <= self.reach).then_some(0.0)
//!     }
//! }
//!
//! let mut sim = SimBuilder::new();
//! sim.register_channel_model::<Cliff>("cliff");
//! assert!(sim.controllers().channel_models().contains("cliff"));
//! ```

use std::collections::BTreeMap;

use serde::Deserialize;

use super::channel::{Burst, Loss};
pub use super::channel::{ChannelLossModel, LinkContext, LossModel, PluginLoss};
use super::params::{ControllerParamError, parse_plugin_params};

/// `Err((key, problem))` unless `p` is a probability.
fn probability(key: &str, p: f64) -> Result<(), (String, String)> {
    if (0.0..=1.0).contains(&p) {
        Ok(())
    } else {
        Err((key.into(), format!("must be a probability in [0, 1], got {p}")))
    }
}

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

/// The built-in channel models' names, registered in every [`ChannelModelRegistry`].
pub const BUILT_IN_CHANNEL_MODELS: [&str; 3] = ["constant", "distance", "gilbert_elliott"];

type Parse = fn(toml::Table) -> Result<LossModel, ControllerParamError>;

fn parse_as<M: ChannelLossModel>(params: toml::Table) -> Result<LossModel, ControllerParamError> {
    Ok(parse_plugin_params::<M>(params, M::check)?.into_loss())
}

/// A channel model's name is taken already.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("channel model name `{0}` is taken (built in or registered twice): register it under another name")]
pub struct DuplicateChannelModel(pub String);

/// Channel models by name (in name order): the built-in ones and those plugins registered.
#[derive(Clone)]
pub struct ChannelModelRegistry {
    entries: BTreeMap<String, Parse>,
}

impl Default for ChannelModelRegistry {
    /// The built-in models.
    fn default() -> Self {
        let mut r = ChannelModelRegistry { entries: BTreeMap::new() };
        r.entries.insert("constant".into(), parse_as::<ConstantLoss>);
        r.entries.insert("distance".into(), parse_as::<DistanceLoss>);
        r.entries.insert("gilbert_elliott".into(), parse_as::<GilbertElliott>);
        r
    }
}

impl std::fmt::Debug for ChannelModelRegistry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.entries.keys()).finish()
    }
}

impl ChannelModelRegistry {
    /// Register `M` under `name`; a name taken already (a built-in one too) is an error.
    pub fn register<M: ChannelLossModel>(&mut self, name: &str) -> Result<(), DuplicateChannelModel> {
        if self.entries.contains_key(name) {
            return Err(DuplicateChannelModel(name.to_string()));
        }
        self.entries.insert(name.to_string(), parse_as::<M>);
        Ok(())
    }

    /// Whether `name` is known.
    pub fn contains(&self, name: &str) -> bool {
        self.entries.contains_key(name)
    }

    /// Known names, in order.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.entries.keys().map(String::as_str)
    }

    /// Parse and check `params` (the `loss` table without `model`) as model `name`; `None` when
    /// no such model is known.
    pub fn parse(&self, name: &str, params: toml::Table) -> Option<Result<LossModel, ControllerParamError>> {
        self.entries.get(name).map(|parse| parse(params))
    }

    /// "constant, distance, ..." for error messages.
    pub fn known_list(&self) -> String {
        self.names().collect::<Vec<_>>().join(", ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world::VehicleId;

    fn table(text: &str) -> toml::Table {
        text.parse().expect("toml")
    }

    #[test]
    fn the_built_in_models_parse_to_their_fast_forms() {
        let r = ChannelModelRegistry::default();
        let c = r.parse("constant", table("p = 0.25")).unwrap().unwrap();
        assert_eq!(c, LossModel { loss: Loss::Constant(0.25), burst: None });
        let d = r.parse("distance", table("p_at_range = 0.5")).unwrap().unwrap();
        assert_eq!(d.loss, Loss::Distance { p_at_0: 0.0, p_at_range: 0.5 });
        let g = r.parse("gilbert_elliott", table("p_enter = 0.1\np_leave = 0.5")).unwrap().unwrap();
        assert_eq!(g.burst, Some(Burst { p_enter: 0.1, p_leave: 0.5, loss_in_burst: 1.0 }));
        assert!(r.parse("cosmic", toml::Table::new()).is_none());
    }

    #[test]
    fn bad_values_and_keys_are_named() {
        let r = ChannelModelRegistry::default();
        let e = r.parse("constant", table("p = 1.5")).unwrap().unwrap_err();
        assert_eq!(e.key, "p");
        let e = r.parse("distance", table("p_at_range = 0.5\np_at_O = 0.1")).unwrap().unwrap_err();
        assert!(e.problem.contains("p_at_O"), "{e:?}");
        let e = r.parse("gilbert_elliott", table("p_enter = 0.1\np_leave = 0.0")).unwrap().unwrap_err();
        assert_eq!(e.key, "p_leave");
    }

    #[test]
    fn a_name_is_registered_once() {
        let mut r = ChannelModelRegistry::default();
        assert!(r.register::<ConstantLoss>("constant").is_err());
        r.register::<ConstantLoss>("mine").expect("a fresh name");
        assert!(r.register::<ConstantLoss>("mine").is_err());
        assert!(r.known_list().contains("mine"));
    }

    #[test]
    fn the_built_ins_deliver_through_the_trait_as_their_law_says() {
        let link = |k: u64, distance: f64| LinkContext {
            sender: VehicleId(-1),
            receiver: VehicleId(-2),
            distance,
            range: 50.0,
            now_us: 0,
            random: crate::sim::random::mix(k),
        };
        let n = 20_000;
        let share = |m: &dyn Fn(&LinkContext, &mut u64) -> Option<f64>, d: f64| {
            let mut state = 0;
            (0..n).filter(|&k| m(&link(k, d), &mut state).is_some()).count() as f64 / n as f64
        };
        let c = ConstantLoss { p: 0.3 };
        assert!((share(&|l, s| c.deliver(l, s), 0.0) - 0.7).abs() < 0.02);
        let d = DistanceLoss { p_at_0: 0.0, p_at_range: 0.8 };
        assert!((share(&|l, s| d.deliver(l, s), 25.0) - 0.8).abs() < 0.02);
        let g = GilbertElliott { p_enter: 0.05, p_leave: 0.2, loss_in_burst: 1.0 };
        assert!((share(&|l, s| g.deliver(l, s), 0.0) - 0.8).abs() < 0.03);
    }
}
