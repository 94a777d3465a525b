//! Controllers a scenario file can name: a registry from `controller = { type = "NAME", .. }` to
//! a parameter type of a plugin's, so a student's controller is named exactly like a built-in one.
//!
//! ```
//! use smlworld::prelude::*;
//!
//! #[derive(serde::Deserialize, Component, Clone, Copy)]
//! #[serde(deny_unknown_fields)]
//! struct Cautious {
//!     /// Gap to keep [m].
//!     gap: f64,
//! }
//!
//! impl ScenarioController for Cautious {
//!     fn attach(&self, vehicle: &mut EntityWorldMut<'_>) {
//!         vehicle.insert(*self);
//!     }
//! }
//!
//! let mut sim = SimBuilder::new();
//! sim.register_controller::<Cautious>("my_cautious");
//! assert!(sim.controllers().contains("my_cautious"));
//! ```

use std::collections::BTreeMap;

use bevy_ecs::prelude::EntityWorldMut;
use serde::de::DeserializeOwned;

use super::params::parse_plugin_params;
use super::sensor_plugins::SensorRegistry;
use super::v2v::channel::plugins::ChannelModelRegistry;

/// Names of the controllers the scenario format has built in; a plugin cannot register them.
pub const BUILT_IN_CONTROLLERS: [&str; 6] = ["path_following", "cruise_control", "acc", "platoon", "idm", "gcdc"];

/// A controller that scenario files can name. Its parameters are the keys of the scenario's
/// `controller` table other than `type` (deserialised with serde, so `#[serde(default)]` and
/// `deny_unknown_fields` work as usual).
///
/// A vehicle given such a controller also gets the path follower on its route (steering, and
/// [`ScenarioController::cruise_speed`] as the route's target speed) and the longitudinal
/// pipeline's state, so the controller only writes its acceleration demand
/// (`crate::vehicles::Longitudinal::accel` in `LongitudinalSystems::Demand`).
pub trait ScenarioController: DeserializeOwned + Send + Sync + 'static {
    /// Check the values after parsing: `Err((key, problem))` names the key (relative to the
    /// `controller` table) and what is allowed. The default accepts everything.
    fn check(&self) -> Result<(), (String, String)> {
        Ok(())
    }

    /// Cruise speed [m/s] of the path follower that steers the vehicle (`None`: its default).
    fn cruise_speed(&self) -> Option<f64> {
        None
    }

    /// Insert the controller's components on the vehicle.
    fn attach(&self, vehicle: &mut EntityWorldMut<'_>);
}

/// A parsed, checked controller of a registered type, ready to attach to a vehicle.
pub trait AttachController: Send + Sync {
    /// See [`ScenarioController::cruise_speed`].
    fn cruise_speed(&self) -> Option<f64>;
    /// See [`ScenarioController::attach`].
    fn attach(&self, vehicle: &mut EntityWorldMut<'_>);
}

impl<C: ScenarioController> AttachController for C {
    fn cruise_speed(&self) -> Option<f64> {
        ScenarioController::cruise_speed(self)
    }
    fn attach(&self, vehicle: &mut EntityWorldMut<'_>) {
        ScenarioController::attach(self, vehicle)
    }
}

pub use super::params::ControllerParamError;

type Parse = fn(toml::Table) -> Result<Box<dyn AttachController>, ControllerParamError>;

fn parse_as<C: ScenarioController>(params: toml::Table) -> Result<Box<dyn AttachController>, ControllerParamError> {
    Ok(Box::new(parse_plugin_params::<C>(params, C::check)?))
}

/// A name is taken already.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("controller name `{0}` is taken (built in or registered twice): register it under another name")]
pub struct DuplicateController(pub String);

/// The names scenario files can use for plugins' types: controllers registered by plugins (by
/// name, in name order), the channel models ([`ControllerRegistry::channel_models`]) and the
/// sensors ([`ControllerRegistry::sensors`]).
#[derive(Clone, Default)]
pub struct ControllerRegistry {
    entries: BTreeMap<String, Parse>,
    channel_models: ChannelModelRegistry,
    sensors: SensorRegistry,
}

impl std::fmt::Debug for ControllerRegistry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.entries.keys()).finish()
    }
}

impl ControllerRegistry {
    /// Register `C` under `name`; a built-in name or one registered already is an error.
    pub fn register<C: ScenarioController>(&mut self, name: &str) -> Result<(), DuplicateController> {
        if BUILT_IN_CONTROLLERS.contains(&name) || self.entries.contains_key(name) {
            return Err(DuplicateController(name.to_string()));
        }
        self.entries.insert(name.to_string(), parse_as::<C>);
        Ok(())
    }

    /// The channel models scenario files can name (`loss = { model = "NAME", .. }`): the
    /// built-in ones and those plugins registered.
    pub fn channel_models(&self) -> &ChannelModelRegistry {
        &self.channel_models
    }

    /// [`ControllerRegistry::channel_models`], to register one
    /// ([`crate::sim::SimBuilder::register_channel_model`]).
    pub fn channel_models_mut(&mut self) -> &mut ChannelModelRegistry {
        &mut self.channel_models
    }

    /// The sensors plugins registered (`sensors = { NAME = { .. } }`).
    pub fn sensors(&self) -> &SensorRegistry {
        &self.sensors
    }

    /// [`ControllerRegistry::sensors`], to register one ([`crate::sim::SimBuilder::register_sensor`]).
    pub fn sensors_mut(&mut self) -> &mut SensorRegistry {
        &mut self.sensors
    }

    /// Whether `name` is registered.
    pub fn contains(&self, name: &str) -> bool {
        self.entries.contains_key(name)
    }

    /// Registered names, in order.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.entries.keys().map(String::as_str)
    }

    /// Parse and check `params` (the `controller` table without `type`) as controller `name`;
    /// `None` when no such controller is registered.
    pub fn parse(
        &self,
        name: &str,
        params: toml::Table,
    ) -> Option<Result<Box<dyn AttachController>, ControllerParamError>> {
        self.entries.get(name).map(|parse| parse(params))
    }

    /// "known controllers: ..." for error messages: built-ins first, then registered ones.
    pub fn known_list(&self) -> String {
        let registered: Vec<&str> = self.names().collect();
        let mut s = format!("built in: {}", BUILT_IN_CONTROLLERS.join(", "));
        if registered.is_empty() {
            s.push_str("; none registered by plugins");
        } else {
            s.push_str(&format!("; registered by plugins: {}", registered.join(", ")));
        }
        s
    }
}
