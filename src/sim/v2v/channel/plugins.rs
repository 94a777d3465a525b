//! Channel models by name: the trait a student's loss model implements
//! ([`ChannelLossModel`]), what the runtime holds of it ([`PluginLoss`]), and the registry from a
//! scenario's `loss = { model = "NAME", ... }` (in `[v2v.wifi]` or `[v2v.network]`) to a model.
//! The built-in models, `constant`, `distance` and `gilbert_elliott`, are registered through it
//! like a plugin's; they hand the runtime their specialised form ([`ChannelLossModel::into_loss`]),
//! so the V2V rounds keep their fast paths for them.
//!
//! ```
//! use smlworld::prelude::*;
//! use smlworld::sim::{ChannelLossModel, LinkContext};
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
use std::sync::Arc;

use serde::de::DeserializeOwned;

use super::{Burst, Loss};
pub use super::{ConstantLoss, DistanceLoss, GilbertElliott};
use crate::sim::params::{ControllerParamError, parse_plugin_params};
use crate::sim::random::Words;
use crate::world::VehicleId;

/// One reception, as a channel model sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LinkContext {
    /// Who sent the message.
    pub sender: VehicleId,
    /// Who would receive it.
    pub receiver: VehicleId,
    /// Sender-receiver distance at the round \[m\] (0 when the model says it does not use it,
    /// [`ChannelLossModel::uses_distance`]).
    pub distance: f64,
    /// The channel's range \[m\] (the network channel is told the wifi range).
    pub range: f64,
    /// The round's sim time \[µs\].
    pub now_us: u64,
    /// A random word of this reception: a pure function of (seed, channel, round, sender,
    /// receiver, message index), independent of the draws the channel's delay and bursts use,
    /// so any thread count gives the same fates.
    pub random: u64,
}

impl LinkContext {
    /// Random words and numbers from [`LinkContext::random`] (uniforms, normals), each a pure
    /// function of the reception: `link.words().uniform()`, `link.words().normal()`.
    pub fn words(&self) -> Words {
        Words::new(self.random)
    }
}

/// A channel model a scenario can name: `loss = { model = "NAME", ... }`, its other keys
/// deserialised into the type (so `#[serde(default)]` and `deny_unknown_fields` work as usual).
///
/// The model is a pure function of the reception ([`LinkContext`]: sender, receiver, distance,
/// time and a counter-based random word) and, for a model with memory, of one word of state per
/// link that the runtime keeps for it ([`ChannelLossModel::keeps_link_state`]). The channel's
/// `delay_ms` and `jitter_ms` (and `burst`) apply on top of it.
pub trait ChannelLossModel: DeserializeOwned + Send + Sync + 'static {
    /// Check the values after parsing: `Err((key, problem))` names the key (relative to the
    /// `loss` table) and what is allowed. The default accepts everything.
    fn check(&self) -> Result<(), (String, String)> {
        Ok(())
    }

    /// The fate of one reception: `None` when lost, else its extra delay \[ms\] (counted only when
    /// [`ChannelLossModel::delays`] says so). `state` is this link's word (0 on a fresh link),
    /// kept between messages when [`ChannelLossModel::keeps_link_state`] says so.
    fn deliver(&self, link: &LinkContext, state: &mut u64) -> Option<f64>;

    /// Whether [`ChannelLossModel::deliver`] reads or writes its link's `state` (the runtime then
    /// keeps a word per link and runs the round on one thread, in a fixed order).
    fn keeps_link_state(&self) -> bool {
        false
    }

    /// Whether [`ChannelLossModel::deliver`] gives delays (otherwise they are taken as 0).
    fn delays(&self) -> bool {
        false
    }

    /// Whether [`ChannelLossModel::deliver`] reads the distance (otherwise it is given 0 and the
    /// runtime does not look positions up).
    fn uses_distance(&self) -> bool {
        true
    }

    /// How the runtime runs the model: by default through [`ChannelLossModel::deliver`]. The
    /// built-in models return their specialised form instead (the same law, with the V2V
    /// rounds' fast paths).
    fn into_loss(self) -> LossModel
    where
        Self: Sized,
    {
        LossModel { loss: Loss::Plugin(PluginLoss(Arc::new(self))), burst: None }
    }
}

/// The object-safe part of [`ChannelLossModel`] the runtime calls.
trait DynLoss: Send + Sync {
    fn dyn_deliver(&self, link: &LinkContext, state: &mut u64) -> Option<f64>;
    fn dyn_keeps_link_state(&self) -> bool;
    fn dyn_delays(&self) -> bool;
    fn dyn_uses_distance(&self) -> bool;
}

impl<M: ChannelLossModel> DynLoss for M {
    fn dyn_deliver(&self, link: &LinkContext, state: &mut u64) -> Option<f64> {
        self.deliver(link, state)
    }
    fn dyn_keeps_link_state(&self) -> bool {
        self.keeps_link_state()
    }
    fn dyn_delays(&self) -> bool {
        self.delays()
    }
    fn dyn_uses_distance(&self) -> bool {
        self.uses_distance()
    }
}

/// A plugin's channel model, shared by the rounds ([`Loss::Plugin`]). Two are equal when they
/// are the same instance.
#[derive(Clone)]
pub struct PluginLoss(Arc<dyn DynLoss>);

impl PluginLoss {
    /// A model of a plugin's, to put into a [`super::ChannelModel`] by hand.
    pub fn new<M: ChannelLossModel>(model: M) -> PluginLoss {
        PluginLoss(Arc::new(model))
    }

    /// See [`ChannelLossModel::deliver`].
    #[inline]
    pub fn deliver(&self, link: &LinkContext, state: &mut u64) -> Option<f64> {
        self.0.dyn_deliver(link, state)
    }

    /// See [`ChannelLossModel::keeps_link_state`].
    pub fn keeps_link_state(&self) -> bool {
        self.0.dyn_keeps_link_state()
    }

    /// See [`ChannelLossModel::delays`].
    pub fn delays(&self) -> bool {
        self.0.dyn_delays()
    }

    /// See [`ChannelLossModel::uses_distance`].
    pub fn uses_distance(&self) -> bool {
        self.0.dyn_uses_distance()
    }
}

impl PartialEq for PluginLoss {
    fn eq(&self, other: &PluginLoss) -> bool {
        Arc::ptr_eq(&self.0, &other.0)
    }
}

impl std::fmt::Debug for PluginLoss {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("PluginLoss(..)")
    }
}

/// A parsed, checked loss model: what a channel's `loss` table gives.
#[derive(Debug, Clone, PartialEq)]
pub struct LossModel {
    /// The loss before bursts.
    pub loss: Loss,
    /// Bursts, for the Gilbert-Elliott model.
    pub burst: Option<Burst>,
}

/// `Err((key, problem))` unless `p` is a probability.
pub(super) fn probability(key: &str, p: f64) -> Result<(), (String, String)> {
    if (0.0..=1.0).contains(&p) {
        Ok(())
    } else {
        Err((key.into(), format!("must be a probability in [0, 1], got {p}")))
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
