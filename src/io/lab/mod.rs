//! ECS plugins that connect a simulation to the lab: visualisation stream out, motion capture
//! in, real-truck status lines out, plus the counters that show real and virtual vehicles meet.
//!
//! The protocol code lives in [`crate::io::viz`], [`crate::io::qualisys`],
//! [`crate::io::mock_mocap`] and [`crate::io::trucks`]; this module only copies world state in
//! and out of it, each bridge as a [`crate::sim::Plugin`]:
//! - [`VizStreamPlugin`]: sends every vehicle over UDP in its own module (default 50 Hz);
//! - [`MocapPlugin`]: each dynamics tick, polls the Qualisys client and writes tracked bodies
//!   into the [`VehicleState`] of the real vehicles (id >= 0, no
//!   dynamics model); a body lost for longer than the timeout marks its vehicle stale
//!   ([`MocapTrack::stale`]), it is never deleted;
//! - [`TruckPlugin`]: one TCP server per real vehicle (port base + id) fed at 20 Hz with the
//!   2015 line: gap to the leader on the same lane, desired gap, lane, offset;
//! - [`RealVehicleStatsPlugin`]: real vehicles broadcast a [`RealVehicleBeacon`] every wifi
//!   round, and the counters of [`RealVehicleStats`] show how often virtual vehicles detected
//!   them with their sensors and heard them over V2V.
//!
//! The scenario's `[lab]` section that configures these bridges is read and wired up by
//! `crate::app::running::scenario::lab` (the app layer); this module knows nothing of scenario files.
//! With `mock = true` there, the run starts a [`crate::io::mock_mocap::MockMocapServer`]
//! in-process whose bodies follow the script of [`ring_script`].

mod mocap;
mod stats;
mod stream;
mod trucks;

use std::collections::BTreeMap;

use crate::io::mock_mocap::{Keyframe, MocapScript};
use crate::map::Path;
use crate::world::VehicleState;

pub use mocap::{MocapBridge, MocapPlugin, MocapTrack, apply_mocap};
pub use stats::{
    LabSummary, RealVehicleBeacon, RealVehicleStats, RealVehicleStatsPlugin, RealVehicleSummary, beacon_real_vehicles,
    count_real_detections, count_real_messages,
};
pub use stream::{Stream, VizStream, VizStreamPlugin, stream_vehicles};
pub use trucks::{LaneIndex, TruckBridge, TruckLine, TruckPlugin, Trucks, leader_gap, publish_trucks};

/// A mock motion-capture script in which each body number (1-based, as QTM numbers them) drives
/// its vehicle's `path` from its state's position at its state's speed, one lap (or to the
/// path's end), keyframes every `step` \[m\];
/// positions in lab millimetres (world metres / `scale` * 1000), yaw in degrees. A vehicle that
/// stands still gets one keyframe. The script loops with the longest lap's period.
pub fn ring_script<'a>(
    vehicles: impl IntoIterator<Item = (u32, VehicleState, &'a Path)>,
    scale: f64,
    step: f64,
) -> MocapScript {
    let mut bodies: BTreeMap<u32, Vec<Keyframe>> = BTreeMap::new();
    let mm = 1000.0 / scale;
    for (body, state, path) in vehicles {
        let s0 = path.project(state.position).s;
        let speed = state.speed().abs();
        let pose = |s: f64| {
            let (p, heading) = path.sample(s);
            [p.x * mm, p.y * mm, 0.0, 0.0, 0.0, heading.to_degrees()]
        };
        let frames = bodies.entry(body).or_default();
        let span = if path.closed { path.length } else { (path.length - s0).max(0.0) };
        if speed <= 0.0 || span <= 0.0 {
            frames.push(Keyframe { t_s: 0.0, pose: pose(s0) });
            continue;
        }
        let n = (span / step).ceil().max(1.0) as usize;
        for i in 0..=n {
            let ds = span * i as f64 / n as f64;
            frames.push(Keyframe { t_s: ds / speed, pose: pose(s0 + ds) });
        }
    }
    MocapScript::Keyframes(bodies)
}
