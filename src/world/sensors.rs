//! Sensor components (their presence turns them on) and the readings they produce.

use bevy_ecs::prelude::Component;
use glam::DVec2;

use super::VehicleId;

/// Radar: a cone ahead of the vehicle.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
pub struct Radar {
    /// Full opening angle of the cone [rad], centred on the heading (default 60° = π/3).
    pub angle: f64,
    /// Range [m] (inclusive).
    pub range: f64,
}

impl Default for Radar {
    fn default() -> Self {
        Radar { angle: std::f64::consts::FRAC_PI_3, range: 100.0 }
    }
}

/// "Velodyne": a full circle around the vehicle.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
pub struct Velodyne {
    /// Range [m] (inclusive).
    pub range: f64,
}

impl Default for Velodyne {
    fn default() -> Self {
        Velodyne { range: 50.0 }
    }
}

/// Omniscient sensor: detects every other vehicle (O(N) per vehicle: use sparingly).
#[derive(Component, Debug, Clone, Copy, Default, PartialEq)]
pub struct Omniscient;

/// One detected vehicle: the seed's (id, x, y, ẋ, ẏ), ground truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detection {
    /// Id of the detected vehicle.
    pub id: VehicleId,
    /// Its position [m].
    pub position: DVec2,
    /// Its velocity [m/s].
    pub velocity: DVec2,
}

/// Everything a vehicle's sensors saw at the last sensor tick, nearest first (ties by id).
/// The union over all its sensors; a vehicle never detects itself.
#[derive(Component, Debug, Clone, Default, PartialEq)]
pub struct SensorReadings(pub Vec<Detection>);
