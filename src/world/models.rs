//! Dynamics model components: their presence picks the model a vehicle is integrated with.

use bevy_ecs::prelude::Component;

/// Kinematic unicycle with a speed command (seed §4.2.1): ẋ = v cos θ, ẏ = v sin θ,
/// θ̇ = v / L · tan φ, with v the commanded speed and φ the steering angle.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
pub struct KinematicUnicycle {
    /// Wheelbase L \[m\]; a longer one turns wider for the same steering.
    pub wheelbase: f64,
    /// Steering limit \[rad\]; commands beyond ±this are clamped.
    pub max_steering: f64,
}

impl Default for KinematicUnicycle {
    fn default() -> Self {
        KinematicUnicycle { wheelbase: 2.8, max_steering: 0.5 }
    }
}

/// Acceleration-based unicycle (seed §4.2.2): v̇ = (throttle − c·v) / m, heading as in
/// [`KinematicUnicycle`]. Braking (negative throttle) stops at zero speed, never reverses.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
pub struct AccelerationUnicycle {
    /// Wheelbase L \[m\]; a longer one turns wider for the same steering.
    pub wheelbase: f64,
    /// Mass m \[kg\]; a heavier vehicle responds more slowly to throttle.
    pub mass: f64,
    /// Linear drag coefficient c [N s/m]; top speed for a throttle u is u / c.
    pub drag: f64,
    /// Steering limit \[rad\]; commands beyond ±this are clamped.
    pub max_steering: f64,
}

impl Default for AccelerationUnicycle {
    fn default() -> Self {
        AccelerationUnicycle { wheelbase: 2.8, mass: 1000.0, drag: 50.0, max_steering: 0.5 }
    }
}

/// Which dynamics model a spawned vehicle gets (none for real vehicles, whose state a bridge sets).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum VehicleModel {
    /// No dynamics: the state is written by someone else (a bridge, a test).
    None,
    /// [`KinematicUnicycle`].
    Kinematic(KinematicUnicycle),
    /// [`AccelerationUnicycle`].
    Acceleration(AccelerationUnicycle),
}

impl Default for VehicleModel {
    fn default() -> Self {
        VehicleModel::Kinematic(KinematicUnicycle::default())
    }
}
