//! Scheduled systems: clock, multi-rate scheduler, dynamics models, sensors and V2V.
//!
//! Each module is one bevy_ecs [`bevy_ecs::schedule::Schedule`] with its own rate, named by a
//! schedule label ([`Sensors`], [`Wifi`], [`Network`], [`Control`], [`Dynamics`]); the
//! [`Scheduler`] always runs the one due earliest, ties in [`Phase`] order
//! (sense -> communicate -> control -> dynamics). The systems of each module are plain functions
//! over the components of [`crate::world`]; the model and geometry maths are pure functions.
//! Within a schedule, systems say which phase they belong to with the [`SimSystems`] sets.
//!
//! [`Plugin`], [`SimBuilder`] and [`Sim`] live here, at the bottom of the plugin layers, so
//! every plugin (dynamics, sensors, V2V here; controllers in `vehicles`; bridges in `io`; a
//! student's) imports them downward.

mod builder;
/// The channel models, where students found them before they moved into [`v2v`].
pub use v2v::channel;
/// The plugin API of channel models, where students found it before it moved into [`v2v`].
pub use v2v::channel::plugins as channel_models;
pub mod controllers;
pub mod dynamics;
pub mod grid;
pub mod parallel;
pub mod params;
/// Counter-based randomness (it lives in `world`, whose in-boxes draw lost receptions lazily).
pub use crate::world::random;
pub mod recorded;
mod schedule;
pub mod sensors;
/// The plugin API of sensors, where students found it before [`sensors`] became a folder.
pub use sensors::plugins as sensor_plugins;
pub mod trig;
pub mod v2v;

pub use builder::{Plugin, Sim, SimBuilder, SimSeed, default_plugins};
pub use controllers::{AttachController, BUILT_IN_CONTROLLERS, ControllerRegistry, ScenarioController};
pub use dynamics::{DynamicsPlugin, step_acceleration_unicycle, step_kinematic_unicycle};
pub use grid::{Candidates, GridEntry, GridPoint, SpatialGrid};
pub use parallel::{Padded, Parallelism};
pub use recorded::{RecordedSample, RecordedTrajectory, recorded_trajectories};
pub use schedule::{
    Control, ControlEpoch, DuplicateModule, Dynamics, Network, Phase, Rates, Scheduler, Sensors, SimClock, SimSystems,
    Wifi, WifiRate,
};
pub use sensors::plugins::{
    Nearby, Neighbour, Occlusion, PluginDraws, PluginScratch, PluginSense, PluginSensorStats, PluginSensorSystems,
    ScenarioSensor, Sensing, Sensor,
};
pub use sensors::{Cone, SensorStats, SensorsPlugin, in_radar_cone};
pub use v2v::channel::plugins::{ChannelLossModel, ChannelModelRegistry, LinkContext};
pub use v2v::{ChannelStats, DelayedMessages, V2vChannelStats, V2vConfig, V2vLinks, V2vPlugin, V2vStats};
