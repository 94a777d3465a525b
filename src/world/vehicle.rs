//! Core vehicle components: id, state, command, size, class and route.

use std::sync::Arc;

use bevy_ecs::prelude::Component;
use glam::DVec2;

use crate::map::Path;

/// Unique id of a vehicle. Non-negative ids are real vehicles (scaled trucks, motion-capture
/// bodies) whose state comes from a bridge; negative ids are virtual vehicles.
#[derive(Component, Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize)]
pub struct VehicleId(pub i32);

impl VehicleId {
    /// Whether this id names a real vehicle (id >= 0).
    pub fn is_real(self) -> bool {
        self.0 >= 0
    }

    /// Whether this id names a virtual vehicle (id < 0).
    pub fn is_virtual(self) -> bool {
        self.0 < 0
    }
}

/// A vehicle whose state comes from the lab (a motion-capture body or a real truck): the
/// renderer draws it "real" (solid, dark outline), every other vehicle "virtual" (hatched),
/// whatever the sign of its id.
#[derive(Component, Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LabDriven;

impl std::fmt::Display for VehicleId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// Planar state of a vehicle (the seed's x, y, θ, ẋ, ẏ).
///
/// It remembers the unit vector of the heading it was last given with its yaw
/// ([`VehicleState::new`], or the dynamics after each step, which get it without trigonometry),
/// so sensors, controllers and the next step read the heading without a `sin_cos` each
/// (they were a tenth of a 10,000-vehicle benchmark). Whoever writes `yaw` directly need do
/// nothing: the memory is used only while it belongs to the current yaw, bit for bit.
#[derive(Component, Debug, Clone, Copy)]
pub struct VehicleState {
    /// Position of the vehicle's reference point \[m\], x east, y north.
    pub position: DVec2,
    /// Heading \[rad\], counter-clockwise from east.
    pub yaw: f64,
    /// Velocity [m/s] in world axes (ẋ, ẏ).
    pub velocity: DVec2,
    /// The yaw [rad] whose unit vector `facing` is.
    facing_yaw: f64,
    facing: DVec2,
}

impl Default for VehicleState {
    fn default() -> Self {
        VehicleState::new(DVec2::ZERO, 0.0, 0.0)
    }
}

/// States are equal when position, yaw and velocity are (the remembered heading is not state).
impl PartialEq for VehicleState {
    fn eq(&self, other: &Self) -> bool {
        (self.position, self.yaw, self.velocity) == (other.position, other.yaw, other.velocity)
    }
}

impl VehicleState {
    /// A state at `position` \[m\] heading `yaw` \[rad\] with forward speed `speed` [m/s].
    pub fn new(position: DVec2, yaw: f64, speed: f64) -> VehicleState {
        let facing = DVec2::from_angle(yaw);
        VehicleState { position, yaw, velocity: facing * speed, facing_yaw: yaw, facing }
    }

    /// A state at `position` \[m\] heading `yaw` \[rad\] moving at `velocity` [m/s] (world axes).
    pub fn with_velocity(position: DVec2, yaw: f64, velocity: DVec2) -> VehicleState {
        VehicleState { velocity, ..VehicleState::new(position, yaw, 0.0) }
    }

    /// Unit vector of the heading.
    #[inline]
    pub fn heading(&self) -> DVec2 {
        if self.facing_yaw.to_bits() == self.yaw.to_bits() { self.facing } else { DVec2::from_angle(self.yaw) }
    }

    /// Turn to `yaw` [rad] whose unit vector is `facing`, as a model computed it alongside (by
    /// rotating the last heading, equal to `DVec2::from_angle(yaw)` up to rounding).
    pub(crate) fn turn_to(&mut self, yaw: f64, facing: DVec2) {
        self.yaw = yaw;
        self.facing_yaw = yaw;
        self.facing = facing;
    }

    /// Signed forward speed [m/s]: the velocity projected on the heading (negative when reversing).
    #[inline]
    pub fn speed(&self) -> f64 {
        self.velocity.dot(self.heading())
    }
}

/// What a controller asks of the dynamics model this tick. Which fields a model reads depends
/// on the model: [`crate::world::KinematicUnicycle`] reads `speed` and `steering`,
/// [`crate::world::AccelerationUnicycle`] reads `throttle` and `steering`.
#[derive(Component, Debug, Clone, Copy, Default, PartialEq)]
pub struct ControlCommand {
    /// Longitudinal force \[N\]; negative brakes (braking stops at zero speed, never reverses).
    pub throttle: f64,
    /// Steering angle of the front wheels \[rad\], positive turns left; clamped by the model.
    pub steering: f64,
    /// Commanded forward speed [m/s] (speed-controlled models).
    pub speed: f64,
}

/// Marks an obstacle that never moves (a CommonRoad static obstacle: parked vehicle, road
/// boundary, ...). It is a vehicle entity without a model, so sensors see it and the collision
/// metrics count a vehicle driving into it; two stationary obstacles never collide with each
/// other, and it is drawn by the map layer (its outline), not as a vehicle sprite.
#[derive(Component, Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Stationary;

/// A vehicle's turn signal: on while it changes lanes, on the side it moves to. The one
/// indicator type of the crate: the renderer's sprites and the visualisation stream carry it too. The lane-change
/// plugin does not write it (it keeps its own state); whoever shows signals to the outside
/// copies it (the app, for the visualisation stream), and readers such as the stream send it.
#[derive(Component, Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum TurnSignal {
    /// Off.
    #[default]
    Off,
    /// Left.
    Left,
    /// Right.
    Right,
}

impl std::str::FromStr for TurnSignal {
    type Err = ();
    /// `left` or `right` (the visualisation stream's `indicator=` values; off is not sent).
    fn from_str(s: &str) -> Result<TurnSignal, ()> {
        match s {
            "left" => Ok(TurnSignal::Left),
            "right" => Ok(TurnSignal::Right),
            _ => Err(()),
        }
    }
}

/// Footprint of a vehicle \[m\].
#[derive(Component, Debug, Clone, Copy, PartialEq)]
pub struct VehicleSize {
    /// Length along the heading \[m\].
    pub length: f64,
    /// Width across the heading \[m\].
    pub width: f64,
}

impl Default for VehicleSize {
    /// A car of the 2015 simulator: 4.12 m x 1.7 m.
    fn default() -> Self {
        VehicleSize { length: 4.12, width: 1.7 }
    }
}

/// Kind of vehicle, for drawing and for class-specific behaviour.
#[derive(
    Component, Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum VehicleClass {
    /// Passenger car.
    #[default]
    Car,
    /// Truck (the lab's scaled trucks are trucks).
    Truck,
    /// Bus.
    Bus,
    /// Motorcycle.
    Motorcycle,
    /// Bicycle.
    Bicycle,
    /// Emergency vehicle.
    Emergency,
}

impl VehicleClass {
    /// All classes, in declaration order.
    pub const ALL: [VehicleClass; 6] = [
        VehicleClass::Car,
        VehicleClass::Truck,
        VehicleClass::Bus,
        VehicleClass::Motorcycle,
        VehicleClass::Bicycle,
        VehicleClass::Emergency,
    ];

    /// The class name as the 2015 visualisation stream wrote it (`Car`, `Truck`, ...).
    pub fn name(self) -> &'static str {
        match self {
            VehicleClass::Car => "Car",
            VehicleClass::Truck => "Truck",
            VehicleClass::Bus => "Bus",
            VehicleClass::Motorcycle => "Motorcycle",
            VehicleClass::Bicycle => "Bicycle",
            VehicleClass::Emergency => "Emergency",
        }
    }
}

impl std::fmt::Display for VehicleClass {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The path a vehicle is asked to drive (a route or a closed loop from the road module),
/// shared between vehicles on the same lane.
#[derive(Component, Debug, Clone)]
pub struct Route(pub Arc<Path>);
