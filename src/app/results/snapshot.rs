//! What the MCAP/Foxglove and ROS 2 sinks read of one log tick: the vehicles' states and the
//! events since the last tick (plain data, no encoding), so each sink's encoder depends on it
//! and not on the other's.

use glam::DVec2;

use crate::world::{TurnSignal, VehicleClass};

/// One vehicle at one log tick: what every sink reads.
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleSnapshot {
    /// Vehicle id.
    pub id: i32,
    /// Centre of the body \[m\].
    pub position: DVec2,
    /// Heading \[rad\], counter-clockwise from east.
    pub yaw: f64,
    /// Velocity [m/s].
    pub velocity: DVec2,
    /// Acceleration the controllers asked for [m/s²]; NaN when unknown.
    pub accel: f64,
    /// Lanelet under the reference point, if any.
    pub lanelet: Option<i64>,
    /// Signed offset from that lanelet's centre line \[m\], left positive.
    pub lane_offset: Option<f64>,
    /// Body length \[m\].
    pub length: f64,
    /// Body width \[m\].
    pub width: f64,
    /// Class (picks the colour).
    pub class: VehicleClass,
    /// Its state comes from the lab (drawn solid; virtual ones translucent).
    pub real: bool,
    /// Turn signal while changing lanes.
    pub signal: TurnSignal,
    /// What drives it now: `lab`, `emergency_braking`, `yielding` (making way for an emergency
    /// vehicle), `lane_change`, `following`, `cruise`,
    /// `none`.
    pub mode: &'static str,
}

/// Every vehicle at one log tick, in id order.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Snapshot {
    /// Sim time \[µs\].
    pub t_us: u64,
    /// The vehicles, ascending id.
    pub vehicles: Vec<VehicleSnapshot>,
}

/// One line of `/events`.
#[derive(Debug, Clone, PartialEq)]
pub struct Event {
    /// Sim time \[µs\].
    pub t_us: u64,
    /// `foxglove.Log` level: 2 info, 3 warning.
    pub level: i32,
    /// What kind (`collision`, `lane_change`, `merge`, `emergency`, `light`, `vehicle`).
    pub name: &'static str,
    /// The line.
    pub message: String,
}

impl Event {
    /// An `info` line (`foxglove.Log` level 2) at `t_us` \[µs\].
    pub fn info(t_us: u64, name: &'static str, message: String) -> Event {
        Event { t_us, level: 2, name, message }
    }

    /// A `warning` line (`foxglove.Log` level 3) at `t_us` \[µs\].
    pub fn warning(t_us: u64, name: &'static str, message: String) -> Event {
        Event { t_us, level: 3, name, message }
    }
}
