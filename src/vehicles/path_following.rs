//! Path following: pure pursuit steering plus a speed controller along a vehicle's [`Route`].
//!
//! Pure pursuit steers onto the arc through the point one look-ahead distance ahead on the path;
//! on a circle it is exact for the unicycle models, so the only tracking error comes from changes
//! of curvature. Progress along the path is tracked with [`crate::map::Path::project_near`]
//! around the last projection, O(1) per tick.

use bevy_ecs::prelude::{Component, Local, Query, Res};

use crate::sim::{Plugin, SimBuilder};
use bevy_ecs::schedule::IntoScheduleConfigs;

use super::lane_state::LaneChanger;
use super::longitudinal::SteeringSystems;
use crate::sim::trig::small_atan;
use crate::sim::{Control, Parallelism, SimClock, SimSystems};
use crate::world::{AccelerationUnicycle, ControlCommand, KinematicUnicycle, Route, VehicleState};
use glam::DVec2;

/// Parameters of the path follower.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct PathFollowing {
    /// Cruise speed [m/s].
    pub speed: f64,
    /// Shortest look-ahead distance [m]; raising it smooths steering but cuts corners more.
    pub lookahead_min: f64,
    /// Look-ahead time [s]: the look-ahead distance is max(`lookahead_min`, speed · this).
    pub lookahead_time: f64,
    /// Speed error gain of the throttle controller [1/s] (acceleration model only); raising it
    /// reaches the cruise speed faster.
    pub speed_gain: f64,
    /// Deceleration used to stop at the end of an open route [m/s²].
    pub stop_deceleration: f64,
}

impl Default for PathFollowing {
    fn default() -> Self {
        PathFollowing { speed: 10.0, lookahead_min: 4.0, lookahead_time: 0.5, speed_gain: 1.0, stop_deceleration: 2.0 }
    }
}

/// Per-vehicle state of the path follower.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
pub struct PathFollower {
    /// Parameters.
    pub params: PathFollowing,
    /// Arc length of the vehicle's projection on its route at the last tick [m].
    pub s: f64,
    /// Largest distance to the route's centre line seen so far [m].
    pub max_offset: f64,
    tracking: bool,
}

impl PathFollower {
    /// A follower that has not run yet (its first tick projects onto the whole route, O(route)).
    pub fn new(params: PathFollowing) -> PathFollower {
        PathFollower { params, s: 0.0, max_offset: 0.0, tracking: false }
    }

    /// A follower whose vehicle is known to start near arc length `s` [m] of its route, so even
    /// its first tick searches only around there.
    pub fn starting_at(params: PathFollowing, s: f64) -> PathFollower {
        PathFollower { params, s, max_offset: 0.0, tracking: true }
    }
}

/// A sideways shift inside the lane [m], positive to the left, that the path follower adds to
/// its route (and to a lane change's profile): set by cooperative plugins, e.g. moving aside for
/// an emergency vehicle ([`super::emergency_vehicle`]). 0 follows the route's centre line.
#[derive(Component, Debug, Clone, Copy, Default, PartialEq)]
pub struct LateralShift(pub f64);

/// What a chunk of path-following vehicles reads: slices of one ECS table from `start` on,
/// beside the chunk's followers and commands (the optional components' slices when the table
/// has them).
#[derive(Clone, Copy)]
struct FollowingTable<'a> {
    states: &'a [VehicleState],
    routes: &'a [Route],
    kinematic: Option<&'a [KinematicUnicycle]>,
    acceleration: Option<&'a [AccelerationUnicycle]>,
    changers: Option<&'a [LaneChanger]>,
    shifts: Option<&'a [LateralShift]>,
}

/// Steer a contiguous chunk of vehicles (items `start..` of `table`); `dt` is the control
/// step [s].
fn follow_chunk(
    table: FollowingTable<'_>,
    start: usize,
    followers: &mut [PathFollower],
    commands: &mut [ControlCommand],
    dt: f64,
) {
    for (k, (follower, command)) in followers.iter_mut().zip(commands.iter_mut()).enumerate() {
        let i = start + k;
        let (state, route) = (&table.states[i], &table.routes[i]);
        let kinematic = table.kinematic.map(|m| &m[i]);
        let acceleration = table.acceleration.map(|m| &m[i]);
        let changer = table.changers.map(|c| &c[i]);
        let shift = table.shifts.map(|s| &s[i]);
        let shift = shift.map_or(0.0, |s| s.0);
        let manoeuvre = changer.and_then(|c| c.active.as_ref());
        let path = &route.0;
        if path.points.len() < 2 {
            continue;
        }
        // The heading once, for both the speed and the steering.
        let facing = state.heading();
        let speed = state.velocity.dot(facing);
        let (s, lateral) = if follower.tracking {
            // Since the last tick the vehicle moved about |v| dt [m]: search that far around the
            // predicted arc length, plus a segment either side.
            let window = speed.abs() * dt + path.spacing();
            path.locate_walking(state.position, follower.s + speed * dt, window)
        } else {
            let projection = path.project(state.position);
            (projection.s, projection.lateral)
        };
        let p = follower.params;
        follower.tracking = true;
        follower.s = s;
        // During a lane change the vehicle aims at the profile's offset from the (new) route.
        let planned = manoeuvre.map_or(0.0, |m| m.offset_at(path, s)) + shift;
        follower.max_offset = follower.max_offset.max((lateral - planned).abs());

        let wheelbase = kinematic.map(|m| m.wheelbase).or(acceleration.map(|m| m.wheelbase)).unwrap_or(2.8);
        let lookahead = p.lookahead_min.max(p.lookahead_time * speed.abs());
        let aim = manoeuvre.map_or(0.0, |m| m.offset_at(path, s + lookahead)) + shift;
        let target = if aim != 0.0 {
            let (target, heading) = path.sample(s + lookahead);
            target + DVec2::from_angle(heading).perp() * aim
        } else {
            path.sample_point(s + lookahead)
        };
        let relative = target - state.position;
        // Pure pursuit curvature 2 sin(α) / d, with d sin(α) the cross product of heading and
        // the offset to the target.
        let distance2 = relative.length_squared();
        command.steering =
            if distance2 > 1e-18 { small_atan(wheelbase * 2.0 * facing.perp_dot(relative) / distance2) } else { 0.0 };

        let mut target_speed = p.speed;
        if !path.closed {
            let remaining = (path.length - s).max(0.0);
            target_speed = target_speed.min((2.0 * p.stop_deceleration * remaining).sqrt());
            if remaining < 0.5 {
                target_speed = 0.0;
            }
        }
        command.speed = target_speed;
        command.throttle = match acceleration {
            Some(m) => m.drag * target_speed + m.mass * p.speed_gain * (target_speed - speed),
            None => 0.0,
        };
    }
}

/// Pure pursuit + speed control for every vehicle with a [`Route`] and a [`PathFollower`].
///
/// Table by table, the followers and commands are cut into contiguous chunks over
/// [`Parallelism::threads`] threads, straight in the ECS tables' slices (bevy's contiguous
/// access: no list of the query's items is gathered first); each vehicle's command depends
/// only on its own components, so the split never changes it.
#[allow(clippy::type_complexity)]
pub fn follow_paths(
    clock: Res<SimClock>,
    parallelism: Res<Parallelism>,
    mut vehicles: Query<(
        &VehicleState,
        &Route,
        &mut PathFollower,
        &mut ControlCommand,
        Option<&KinematicUnicycle>,
        Option<&AccelerationUnicycle>,
        Option<&LaneChanger>,
        Option<&LateralShift>,
    )>,
    mut scratch: Local<Vec<()>>,
) {
    let dt = clock.dt;
    if let Ok(tables) = vehicles.contiguous_iter_mut() {
        for (states, routes, mut followers, mut commands, kinematic, acceleration, changers, shifts) in tables {
            let table = FollowingTable { states, routes, kinematic, acceleration, changers, shifts };
            parallelism.for_each_chunk_pair_at(&mut followers, &mut commands, &mut scratch, |start, f, c, _| {
                follow_chunk(table, start, f, c, dt)
            });
        }
        return;
    }
    // Only if a component were stored sparsely (none is): one at a time.
    for (state, route, mut follower, mut command, kinematic, acceleration, changer, shift) in &mut vehicles {
        let table = FollowingTable {
            states: std::slice::from_ref(state),
            routes: std::slice::from_ref(route),
            kinematic: kinematic.map(std::slice::from_ref),
            acceleration: acceleration.map(std::slice::from_ref),
            changers: changer.map(std::slice::from_ref),
            shifts: shift.map(std::slice::from_ref),
        };
        follow_chunk(table, 0, std::slice::from_mut(&mut *follower), std::slice::from_mut(&mut *command), dt);
    }
}

/// The path follower in the [`Control`] schedule.
#[derive(Debug, Clone, Copy, Default)]
pub struct PathFollowingPlugin;

impl Plugin for PathFollowingPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.world_mut().init_resource::<Parallelism>();
        sim.configure_sets(Control, SteeringSystems.in_set(SimSystems::Control));
        sim.add_systems(Control, follow_paths.in_set(SteeringSystems));
    }
}
