//! SML World: a simulator for autonomous and cooperative driving research.
//!
//! Where to start:
//! - [`prelude`]: `use smlworld::prelude::*;` brings the names a program or a plugin needs;
//!   [`app::run_scenario`] runs a scenario file as `smlworld run` does.
//! - Plugins: a controller is a [`sim::Plugin`] registered with
//!   [`sim::ControllerRegistry`]; `examples/student_controller.rs` is a whole one in about 60
//!   lines (`cargo run --release --example student_controller`).
//! - The command line (`smlworld --help`), the README and `docs/` are the user's guide; this reference is
//!   for those who extend the simulator.
//!
//! Modules, with dependencies pointing one way (no cycles):
//! - [`files`]: atomic output files (written aside, renamed into place);
//! - [`map`]: lanelet road maps from JOSM/OSM XML, projection, routing, map generation;
//! - [`world`]: ECS data (vehicles as entities, their state, sensors, mailboxes);
//! - [`sim`]: plugins, the sim builder, clock, multi-rate scheduler, phases as system sets,
//!   dynamics, sensors and V2V systems, the controller registry;
//! - [`vehicles`]: controllers as plugins;
//! - [`render`]: off-screen wgpu bird's-eye renderer;
//! - [`io`]: bridges to the lab (UDP stream, motion capture, trucks);
//! - [`app`]: scenarios, runners and run outputs ([`app::run_scenario`] does what `smlworld run`
//!   does).
//!
//! Layers, lowest first: files < map < world < sim < vehicles, io, render < app < cli (the binary). A
//! module imports only from layers below it (`tests/architecture.rs` checks it); [`sim::Plugin`],
//! [`sim::SimBuilder`] and [`sim::Sim`] sit in `sim` so every plugin imports them downward.
pub mod app;
pub mod files;
pub mod io;
pub mod map;
pub mod range;
pub mod render;
pub mod sim;
pub mod vehicles;
pub mod world;

/// The crate under its own name, so that `examples/student_sensor.rs` (written as a student writes
/// a plugin, against `smlworld::`) compiles inside the benchmark (`bench --plugin-sensor-share`).
extern crate self as smlworld;

/// The names most users need: `use smlworld::prelude::*;` (including the few bevy_ecs names a
/// controller plugin needs, so a student's file needs no other import).
pub mod prelude {
    pub use crate::app::{RealtimeRunner, RunOptions, RunSummary, Scenario, ScenarioError, run_headless, run_scenario};
    pub use crate::map::{LaneletMap, Path};
    pub use crate::sim::{
        Control, ControllerRegistry, Dynamics, DynamicsPlugin, Network, Phase, Plugin, Rates, ScenarioController,
        Sensors, SensorsPlugin, Sim, SimBuilder, SimClock, SimSeed, SimSystems, V2vConfig, V2vPlugin, V2vStats, Wifi,
        default_plugins,
    };
    pub use crate::vehicles::{
        LeaderGap, Longitudinal, LongitudinalSystems, PathFollower, PathFollowing, PathFollowingPlugin, SteeringSystems,
    };
    pub use crate::world::{
        AccelerationUnicycle, Channel, ControlCommand, Detection, KinematicUnicycle, Mailbox, Message, Omniscient,
        Payload, Radar, Route, SensorReadings, SensorSet, SimTime, VehicleClass, VehicleId, VehicleModel, VehicleSize,
        VehicleSpec, VehicleState, Vehicles, Velodyne,
    };
    pub use bevy_ecs::prelude::{Component, EntityWorldMut, Local, Query, Res, ResMut};
    pub use bevy_ecs::schedule::IntoScheduleConfigs;
    pub use glam::DVec2;
}
