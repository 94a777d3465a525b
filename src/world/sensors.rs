//! Sensor components (their presence turns them on) and the readings they produce.

use bevy_ecs::prelude::Component;
use glam::DVec2;

use super::VehicleId;

/// Radar: a cone ahead of the vehicle.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
pub struct Radar {
    /// Full opening angle of the cone \[rad\], centred on the heading (default 60° = π/3).
    pub angle: f64,
    /// Range \[m\] (inclusive).
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
    /// Range \[m\] (inclusive).
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

/// What makes one sensor imperfect (issue 21; all off by default, so a sensor is ground truth).
/// Random draws are counter-based ([`crate::sim::random`]) keyed by (seed, sensor, observer,
/// target, tick): the same for any thread count.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SensorError {
    /// Standard deviation of the Gaussian error of the range to the target's centre \[m\].
    pub range_sd: f64,
    /// Standard deviation of the Gaussian error of the bearing to the target's centre \[rad\].
    pub bearing_sd: f64,
    /// Standard deviation of the Gaussian error of each velocity component (x, y) [m/s].
    pub speed_sd: f64,
    /// Probability that a detection is missed [-], drawn per observer, target and tick.
    pub dropout: f64,
    /// Whether a target whose angular extent (its footprint seen from the sensor) lies inside
    /// the extent of one nearer target is not seen.
    pub occlusion: bool,
}

impl SensorError {
    /// Whether it changes nothing (no noise, no dropout, no occlusion).
    pub fn is_perfect(&self) -> bool {
        *self == SensorError::default()
    }

    /// Whether it adds noise to what it sees.
    pub fn is_noisy(&self) -> bool {
        self.range_sd > 0.0 || self.bearing_sd > 0.0 || self.speed_sd > 0.0
    }
}

/// The errors of a vehicle's radar and velodyne; without this component both are perfect.
#[derive(Component, Debug, Clone, Copy, Default, PartialEq)]
pub struct SensorErrors {
    /// Errors of the radar.
    pub radar: SensorError,
    /// Errors of the velodyne.
    pub velodyne: SensorError,
}

impl SensorErrors {
    /// Whether both sensors are perfect (then the component is not needed).
    pub fn is_perfect(&self) -> bool {
        self.radar.is_perfect() && self.velodyne.is_perfect()
    }
}

/// One detected vehicle: the seed's (id, x, y, ẋ, ẏ), ground truth unless [`SensorErrors`] add
/// noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Detection {
    /// Id of the detected vehicle.
    pub id: VehicleId,
    /// Its position \[m\].
    pub position: DVec2,
    /// Its velocity [m/s].
    pub velocity: DVec2,
    /// The name of the sensor that saw it: `"radar"`, `"velodyne"` (a target both reach is the
    /// radar's unless the radar dropped it), `"omniscient"`, or a plugin sensor's registered name.
    pub sensor: &'static str,
}

/// Everything a vehicle's sensors saw at the last sensor tick: the built-in sensors' detections
/// nearest first (ties by id), one per target; then each plugin sensor's, in the order it wrote
/// them. A vehicle never detects itself.
#[derive(Component, Debug, Clone, Default, PartialEq)]
pub struct SensorReadings(pub Vec<Detection>);
