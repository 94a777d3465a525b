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
