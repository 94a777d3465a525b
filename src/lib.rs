//! SML World: a simulator for autonomous and cooperative driving research.
//!
//! Modules, with dependencies pointing one way (no cycles):
//! - [`map`]: lanelet road maps from JOSM/OSM XML, projection, routing, map generation;
//! - [`world`]: ECS data (vehicles as entities, their state, sensors, mailboxes);
//! - [`sim`]: clock, multi-rate scheduler, dynamics, sensors and V2V systems;
//! - [`vehicles`]: controllers as plugins;
//! - [`render`]: off-screen wgpu bird's-eye renderer;
//! - [`io`]: bridges to the lab (UDP stream, motion capture, trucks);
//! - [`app`]: sim builder, plugins, scenarios and runners.
pub mod app;
pub mod io;
pub mod map;
pub mod render;
pub mod sim;
pub mod vehicles;
pub mod world;

/// The names most users need: `use smlworld::prelude::*;`.
pub mod prelude {
    pub use crate::app::{Plugin, RealtimeRunner, Sim, SimBuilder, SimSeed, default_plugins, run_headless};
    pub use crate::map::{LaneletMap, Path};
    pub use crate::sim::{
        Control, Dynamics, DynamicsPlugin, Network, Phase, Rates, Sensors, SensorsPlugin, SimClock, V2vConfig,
        V2vPlugin, V2vStats, Wifi,
    };
    pub use crate::vehicles::{PathFollower, PathFollowing, PathFollowingPlugin};
    pub use crate::world::{
        AccelerationUnicycle, Channel, ControlCommand, Detection, KinematicUnicycle, Mailbox, Message, Omniscient,
        Payload, Radar, Route, SensorReadings, SensorSet, SimTime, VehicleClass, VehicleId, VehicleModel, VehicleSize,
        VehicleSpec, VehicleState, Vehicles, Velodyne,
    };
    pub use glam::DVec2;
}
