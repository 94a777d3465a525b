//! ECS data: vehicle components, resources, the vehicle registry and spawning.
//!
//! A vehicle is an entity carrying a [`VehicleId`], a [`VehicleState`], a [`ControlCommand`],
//! its [`VehicleSize`] and [`VehicleClass`], and optionally a dynamics model
//! ([`KinematicUnicycle`] or [`AccelerationUnicycle`]), sensors ([`Radar`], [`Velodyne`],
//! [`Omniscient`]) with their [`SensorReadings`], a [`Mailbox`] and a [`Route`]. The
//! [`Vehicles`] resource maps ids to entities; [`spawn_vehicle`] is the one way in.

mod mailbox;
mod models;
pub mod random;
mod registry;
mod sensors;
mod time;
mod vehicle;

pub use mailbox::{Channel, Inbox, InboxIter, Mailbox, Message, Payload};
pub use models::{AccelerationUnicycle, KinematicUnicycle, VehicleModel};
pub use registry::{SensorSet, VehicleSpec, Vehicles, WorldError, despawn_vehicle, spawn_vehicle};
pub use sensors::{Detection, Omniscient, Radar, SensorError, SensorErrors, SensorReadings, Velodyne};
pub use time::SimTime;
pub use vehicle::{ControlCommand, Route, Stationary, TurnSignal, VehicleClass, VehicleId, VehicleSize, VehicleState};
