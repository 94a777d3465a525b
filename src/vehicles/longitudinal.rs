//! The longitudinal pipeline shared by the speed controllers: find the vehicle ahead on the
//! route, let the controllers agree on one acceleration, turn it into a model command.
//!
//! Each control tick, after the path follower has steered ([`crate::vehicles::follow_paths`]),
//! the steps run as the chained sets of [`LongitudinalSystems`]:
//! 1. [`LongitudinalSystems::FindLeader`]: [`find_leaders`] resets [`Longitudinal::accel`] to "no demand" and finds the nearest
//!    vehicle ahead on the vehicle's own route from its sensor readings;
//! 2. [`LongitudinalSystems::Demand`]: a speed controller ([`crate::vehicles::control_cruise`],
//!    [`crate::vehicles::control_acc`], a student's) writes the acceleration it wants into
//!    [`Longitudinal::accel`]; [`LongitudinalSystems::Cooperate`]: cooperative laws
//!    ([`crate::vehicles::control_platoon`]) may replace it with what the platoon agreed;
//! 3. [`LongitudinalSystems::Limit`]: limiters ([`crate::vehicles::yield_at_crossings`],
//!    [`crate::vehicles::brake_for_emergencies`]) may only lower it ([`Longitudinal::limit`]);
//! 4. [`LongitudinalSystems::Actuate`]: [`actuate_longitudinal`] turns it into a throttle (acceleration model) or a speed command
//!    (kinematic model), never exceeding the route's target speed. A vehicle nobody asked
//!    anything of keeps the path follower's command;
//! 5. [`LongitudinalSystems::Report`]: what was finally asked for is told to others (platoon
//!    beacons).
//!
//! A controller written this way (demand in `Demand`, never touching `ControlCommand`) works
//! on both vehicle models and combines with every limiter.

use bevy_ecs::prelude::{Component, Query, Res, Resource};
use bevy_ecs::schedule::{IntoScheduleConfigs, SystemSet};
use glam::DVec2;

use crate::map::Path;
use crate::sim::SimBuilder;
use crate::sim::{Control, SimClock, SimSystems};
use crate::world::{
    AccelerationUnicycle, ControlCommand, Detection, KinematicUnicycle, Route, SensorReadings, VehicleId, VehicleSize,
    VehicleState,
};

use super::PathFollower;
use super::lane_changing::{LaneChanger, LaneCrossings};

/// The steps of the longitudinal pipeline as system sets of the [`Control`] schedule, chained in
/// this order inside [`SimSystems::Control`] and after the path follower's steering. A speed
/// controller of your own goes into [`LongitudinalSystems::Demand`].
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LongitudinalSystems {
    /// Reset the demand and find each vehicle's leader on its route ([`find_leaders`]).
    FindLeader,
    /// Speed controllers write the acceleration they want ([`Longitudinal::accel`]).
    Demand,
    /// Cooperative laws (platooning) may replace the demand with the platoon's.
    Cooperate,
    /// Limiters (intersections, emergency braking) may only lower it ([`Longitudinal::limit`]).
    Limit,
    /// Turn the demand into the model's command ([`actuate_longitudinal`]).
    Actuate,
    /// Tell others what was finally asked for (V2V beacons).
    Report,
}

/// Steering and the route's target speed: the path follower, before the longitudinal pipeline
/// (it writes [`ControlCommand::speed`], which [`find_leaders`] takes as the route's speed).
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct SteeringSystems;

/// The vehicle ahead on the same route, as the sensors see it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LeaderGap {
    /// Its id.
    pub id: VehicleId,
    /// Arc length from our centre to its centre along our route [m].
    pub distance: f64,
    /// Bumper-to-bumper gap [m]: `distance` minus our own length. Sensors report centres, not
    /// lengths, so this assumes the leader is as long as we are; raise the standstill distance
    /// when following longer vehicles.
    pub gap: f64,
    /// Its speed along our route [m/s].
    pub speed: f64,
    /// Its acceleration along our route [m/s²], from the change of `speed` since the last tick
    /// (0 when the leader just changed).
    pub acceleration: f64,
}

/// Per-vehicle longitudinal state: what the controllers of this tick asked for.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
pub struct Longitudinal {
    /// Acceleration asked for this tick [m/s²]; NaN until a controller writes it.
    pub accel: f64,
    /// Target speed of the route at this point [m/s]: the path follower's cruise speed, lowered
    /// near the end of an open route.
    pub route_speed: f64,
    /// The vehicle ahead on the route, if the sensors see one.
    pub leader: Option<LeaderGap>,
    /// Largest lateral offset [m] of a detection from our route for it to count as "on our
    /// route"; about half a lane width.
    pub lane_half_width: f64,
    /// Whether emergency braking overrides the controllers this tick.
    pub emergency: bool,
}

impl Default for Longitudinal {
    fn default() -> Self {
        Longitudinal { accel: f64::NAN, route_speed: 0.0, leader: None, lane_half_width: 1.75, emergency: false }
    }
}

impl Longitudinal {
    /// Lower the demand to at most `accel` [m/s²] (a limiter); sets it if nobody had.
    pub fn limit(&mut self, accel: f64) {
        self.accel = self.accel.min(accel);
    }
}

/// The nearest detection that lies on `path` ahead of arc length `s` [m] (within
/// `lane_half_width` [m] of the centre line), as a [`LeaderGap`] with zero acceleration.
/// `detections` must be sorted nearest first (as [`SensorReadings`] are). O(window) per
/// detection looked at; stops at the first one on the path.
pub fn leader_on_path(
    path: &Path,
    s: f64,
    position: DVec2,
    own_length: f64,
    detections: &[Detection],
    lane_half_width: f64,
) -> Option<LeaderGap> {
    leader_on_path_with(path, s, position, own_length, detections, lane_half_width, |_| false)
}

/// [`leader_on_path`], where a detection for which `crossing(id)` holds (a vehicle changing
/// into or out of this lane) counts up to three half widths from the centre line: while it
/// crosses, a vehicle is in both lanes.
pub fn leader_on_path_with(
    path: &Path,
    s: f64,
    position: DVec2,
    own_length: f64,
    detections: &[Detection],
    lane_half_width: f64,
    crossing: impl Fn(VehicleId) -> bool,
) -> Option<LeaderGap> {
    if path.points.len() < 2 {
        return None;
    }
    for d in detections {
        let r = d.position.distance(position);
        let p = path.project_near(d.position, s + r, 0.3 * r + 5.0);
        if p.lateral.abs() > lane_half_width && !(p.lateral.abs() <= 3.0 * lane_half_width && crossing(d.id)) {
            continue;
        }
        let mut ahead = p.s - s;
        if path.closed {
            ahead = ahead.rem_euclid(path.length);
            if ahead > 0.5 * path.length {
                continue;
            }
        }
        if ahead <= 0.0 {
            continue;
        }
        let speed = d.velocity.dot(DVec2::from_angle(p.heading));
        return Some(LeaderGap { id: d.id, distance: ahead, gap: ahead - own_length, speed, acceleration: 0.0 });
    }
    None
}

/// Reset the demand and find each vehicle's leader on its route.
#[allow(clippy::type_complexity)]
pub fn find_leaders(
    clock: Res<SimClock>,
    crossings: Option<Res<LaneCrossings>>,
    mut vehicles: Query<(
        &VehicleState,
        &VehicleSize,
        &Route,
        &PathFollower,
        &ControlCommand,
        Option<&SensorReadings>,
        &mut Longitudinal,
        Option<&LaneChanger>,
    )>,
) {
    let crossings = crossings.as_deref().map(|c| &c.0).filter(|c| !c.is_empty());
    for (state, size, route, follower, command, readings, mut lon, changer) in &mut vehicles {
        let previous = lon.leader;
        lon.accel = f64::NAN;
        lon.emergency = false;
        lon.route_speed = command.speed;
        let detections = readings.map_or(&[][..], |r| &r.0[..]);
        let mut leader = match crossings {
            None => leader_on_path(&route.0, follower.s, state.position, size.length, detections, lon.lane_half_width),
            Some(c) => {
                let lanes = &route.0.lanelets;
                let crossing = |id: VehicleId| c.get(&id).is_some_and(|(a, b)| lanes.contains(a) || lanes.contains(b));
                leader_on_path_with(
                    &route.0,
                    follower.s,
                    state.position,
                    size.length,
                    detections,
                    lon.lane_half_width,
                    crossing,
                )
            }
        };
        // While changing lanes the vehicle is in both: the nearer leader of the old lane counts too.
        if let Some(m) = changer.and_then(|c| c.active.as_ref()) {
            let old =
                leader_on_path(&m.old_route, m.old_s, state.position, size.length, detections, lon.lane_half_width);
            if old.is_some_and(|o| leader.is_none_or(|l| o.distance < l.distance)) {
                leader = old;
            }
        }
        if let (Some(l), Some(p)) = (leader.as_mut(), previous)
            && l.id == p.id
            && clock.dt > 0.0
        {
            l.acceleration = (l.speed - p.speed) / clock.dt;
        }
        lon.leader = leader;
    }
}

/// Gain [1/s] that brings a vehicle faster than its route's target speed back down to it.
pub const ROUTE_SPEED_GAIN: f64 = 2.0;

/// Turn the agreed acceleration into the model's command: throttle = m·a + c·v for the
/// acceleration model (so v̇ = a at the current speed), speed = v + a·dt for the kinematic one.
/// Above the route's target speed ([`Longitudinal::route_speed`]: the path follower's cruise
/// speed, lowered to stop at the end of an open route) the acceleration is capped at
/// [`ROUTE_SPEED_GAIN`] · (route speed − v), so vehicles stop where their route ends.
#[allow(clippy::type_complexity)]
pub fn actuate_longitudinal(
    clock: Res<SimClock>,
    mut vehicles: Query<(
        &VehicleState,
        &Longitudinal,
        &mut ControlCommand,
        Option<&AccelerationUnicycle>,
        Option<&KinematicUnicycle>,
    )>,
) {
    for (state, lon, mut command, acceleration, kinematic) in &mut vehicles {
        if lon.accel.is_nan() {
            continue;
        }
        let v = state.speed().max(0.0);
        // Never faster than the route's target speed (it stops at the end of an open route).
        let accel =
            if v > lon.route_speed { lon.accel.min(ROUTE_SPEED_GAIN * (lon.route_speed - v)) } else { lon.accel };
        if let Some(m) = acceleration {
            command.throttle = m.mass * accel + m.drag * v;
        }
        if kinematic.is_some() || acceleration.is_none() {
            command.speed = (v + accel * clock.dt).max(0.0);
        } else {
            command.speed = v;
        }
    }
}

/// Marks that the pipeline's systems are in the [`Control`] schedule (each controller plugin
/// installs them once).
#[derive(Resource, Debug, Clone, Copy, Default)]
pub struct LongitudinalInstalled;

/// Chain the [`LongitudinalSystems`] sets after [`SteeringSystems`] inside
/// [`SimSystems::Control`] and add [`find_leaders`] and [`actuate_longitudinal`] to the
/// [`Control`] schedule, once (every speed controller's plugin calls it).
pub fn install_longitudinal(sim: &mut SimBuilder) {
    if sim.world_mut().contains_resource::<LongitudinalInstalled>() {
        return;
    }
    sim.insert_resource(LongitudinalInstalled);
    sim.configure_sets(
        Control,
        (
            SteeringSystems,
            LongitudinalSystems::FindLeader,
            LongitudinalSystems::Demand,
            LongitudinalSystems::Cooperate,
            LongitudinalSystems::Limit,
            LongitudinalSystems::Actuate,
            LongitudinalSystems::Report,
        )
            .chain()
            .in_set(SimSystems::Control),
    );
    sim.add_systems(
        Control,
        (
            find_leaders.in_set(LongitudinalSystems::FindLeader),
            actuate_longitudinal.in_set(LongitudinalSystems::Actuate),
        ),
    );
}
