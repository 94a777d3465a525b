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
use super::lanes::PREFETCH_AHEAD;
use super::longitudinal::SteeringSystems;
use crate::map::Path;
use crate::map::path::{LANES, Walked, along_segment, groups_of_four, per_lane, walk_four};
use crate::sim::grid::{Pass, vectorised};
use crate::sim::trig::{atan_polynomial, is_small, small_atan};
use crate::sim::{Control, Parallelism, SimClock, SimSystems};
use crate::world::{AccelerationUnicycle, ControlCommand, KinematicUnicycle, Route, VehicleState};
use glam::DVec2;

/// Parameters of the path follower.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct PathFollowing {
    /// Cruise speed [m/s].
    pub speed: f64,
    /// Shortest look-ahead distance \[m\]; raising it smooths steering but cuts corners more.
    pub lookahead_min: f64,
    /// Look-ahead time \[s\]: the look-ahead distance is max(`lookahead_min`, speed · this), and
    /// never shorter than a control step's travel ([`PathFollowing::lookahead`]).
    pub lookahead_time: f64,
    /// Speed error gain of the throttle controller [1/s] (acceleration model only); raising it
    /// reaches the cruise speed faster.
    pub speed_gain: f64,
    /// Deceleration used to stop at the end of an open route [m/s²].
    pub stop_deceleration: f64,
}

impl PathFollowing {
    /// Look-ahead distance \[m\] at `speed` [m/s], `previous` [m/s] the speed at the last
    /// control tick, with control steps of `dt` \[s\]: max(`lookahead_min`, `lookahead_time` ·
    /// |speed|), and at least 1.5 times the coming step's travel, its speed extrapolated from the
    /// last step's rise (`(|speed| + max(0, speed − previous)) · dt`; NaN `previous`: no rise).
    ///
    /// Pure pursuit steers onto the arc through the look-ahead point and the steering is held
    /// for the step. Per step of travel `d` against a look-ahead `L`, the lateral and heading
    /// errors on a straight path evolve by a matrix whose eigenvalues have product (1 − d/L)²
    /// and sum 2 − 2d/L − (d/L)²: damped for d/L up to about 0.75, an undamped side-to-side
    /// swing at d = L, divergent beyond. At SUMO's 1 s step (a signal env) vehicles drove 14 m a
    /// step against a 7 m look-ahead and swung off their lanes, and at d = L (4 m a step out of
    /// a turn) swung by a metre; d/L = 2/3 damps the error to a third a step. At 20 Hz the
    /// step's term is never the longest of the three below 53 m/s.
    #[inline(always)]
    pub fn lookahead(&self, speed: f64, previous: f64, dt: f64) -> f64 {
        let rise = (speed - previous).max(0.0);
        let travel = (speed.abs() + rise) * dt;
        self.lookahead_min.max(self.lookahead_time * speed.abs()).max(1.5 * travel)
    }
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
    /// Arc length of the vehicle's projection on its route at the last tick \[m\].
    pub s: f64,
    /// Largest distance to the route's centre line seen so far \[m\].
    pub max_offset: f64,
    /// Speed along the heading at the last tick [m/s] (NaN before the first).
    speed: f64,
    tracking: bool,
}

impl PathFollower {
    /// A follower that has not run yet (its first tick projects onto the whole route, O(route)).
    pub fn new(params: PathFollowing) -> PathFollower {
        PathFollower { params, s: 0.0, max_offset: 0.0, speed: f64::NAN, tracking: false }
    }

    /// A follower whose vehicle is known to start near arc length `s` \[m\] of its route, so even
    /// its first tick searches only around there.
    pub fn starting_at(params: PathFollowing, s: f64) -> PathFollower {
        PathFollower { params, s, max_offset: 0.0, speed: f64::NAN, tracking: true }
    }
}

/// A sideways shift inside the lane \[m\], positive to the left, that the path follower adds to
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

impl FollowingTable<'_> {
    /// The wheelbase [m] of vehicle `i`'s model (2.8 m without one).
    #[inline(always)]
    fn wheelbase(&self, i: usize) -> f64 {
        let kinematic = self.kinematic.map(|m| m[i].wheelbase);
        kinematic.or(self.acceleration.map(|m| m[i].wheelbase)).unwrap_or(2.8)
    }

    /// Vehicle `i`'s [`LateralShift`] [m] (0 without one).
    #[inline(always)]
    fn shift(&self, i: usize) -> f64 {
        self.shifts.map_or(0.0, |s| s[i].0)
    }
}

/// A group's followers and commands as arrays of [`LANES`], if there are exactly that many.
#[inline(always)]
fn group_of_four<'a>(
    followers: &'a mut [PathFollower],
    commands: &'a mut [ControlCommand],
) -> Option<(&'a mut [PathFollower; LANES], &'a mut [ControlCommand; LANES])> {
    Some((followers.try_into().ok()?, commands.try_into().ok()?))
}

/// Steer a contiguous chunk of vehicles (items `start..` of `table`); `dt` is the control
/// step [s]. Four at a time where [`follow_four`] can (in vector code where the processor has
/// AVX2), else one at a time ([`follow_one_by_one`]).
fn follow_chunk(
    table: FollowingTable<'_>,
    start: usize,
    followers: &mut [PathFollower],
    commands: &mut [ControlCommand],
    dt: f64,
) {
    vectorised(FollowPass { table, start, followers, commands, dt });
}

/// [`follow_chunk`] as a [`Pass`].
struct FollowPass<'a, 'b> {
    table: FollowingTable<'a>,
    start: usize,
    followers: &'b mut [PathFollower],
    commands: &'b mut [ControlCommand],
    dt: f64,
}

impl Pass for FollowPass<'_, '_> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        let FollowPass { table, start, followers, commands, dt } = self;
        let n = followers.len().min(commands.len());
        // Two groups of four at a time, their stages taking turns ([`follow_two_fours`]); a last
        // group of four or fewer alone.
        let pairs = n / (2 * LANES) * (2 * LANES);
        for k in (0..pairs).step_by(2 * LANES) {
            prefetch_changers(table, start + k, 2 * LANES);
            prefetch_routes(table, start, followers, k, 2 * LANES);
            let (f, c) = (&mut followers[k..k + 2 * LANES], &mut commands[k..k + 2 * LANES]);
            let ((f1, f2), (c1, c2)) = (f.split_at_mut(LANES), c.split_at_mut(LANES));
            let (done1, done2) = follow_two_fours(table, start + k, (f1, c1), (f2, c2), dt);
            if !done1 {
                follow_one_by_one(table, start + k, f1, c1, dt);
            }
            if !done2 {
                follow_one_by_one(table, start + k + LANES, f2, c2, dt);
            }
        }
        for r in groups_of_four(n - pairs) {
            let r = pairs + r.start..pairs + r.end;
            prefetch_changers(table, start + r.start, r.len());
            prefetch_routes(table, start, followers, r.start, r.len());
            let (k, followers, commands) = (r.start, &mut followers[r.clone()], &mut commands[r]);
            if !follow_four(table, start + k, followers, commands, dt) {
                follow_one_by_one(table, start + k, followers, commands, dt);
            }
        }
    }
}

/// What the `count` vehicles a few places on from the chunk's item `at` read of their routes
/// (`followers` is the chunk, which starts at the table's item `start`): the points about
/// where they are and about their look-ahead points, and, twice as far on, the routes' own
/// fields that those reads need. In a town every vehicle owns its 2-3 km route: without these
/// hints each read was a cache miss, one after the other. Hints only: no effect on any result.
#[inline(always)]
fn prefetch_routes(table: FollowingTable<'_>, start: usize, followers: &[PathFollower], at: usize, count: usize) {
    for k in at + 2 * PREFETCH_AHEAD..at + 2 * PREFETCH_AHEAD + count {
        if let Some(route) = table.routes.get(start + k) {
            crate::world::prefetch_value(&*route.0);
        }
    }
    for k in at + PREFETCH_AHEAD..at + PREFETCH_AHEAD + count {
        let (Some(route), Some(state), Some(follower)) =
            (table.routes.get(start + k), table.states.get(start + k), followers.get(k))
        else {
            break;
        };
        let params = follower.params;
        let ahead = params.lookahead_min.max(params.lookahead_time * state.velocity.length());
        crate::world::prefetch_all(route.0.points_near(follower.s));
        crate::world::prefetch_all(route.0.points_near(follower.s + ahead));
    }
}

/// What the `count` vehicles a few places on from item `at` read first: whether their lane
/// changer has a manoeuvre under way (one byte of a large component, a line of its own per
/// vehicle).
#[inline(always)]
fn prefetch_changers(table: FollowingTable<'_>, at: usize, count: usize) {
    if let Some(changers) = table.changers {
        for ahead in changers.iter().skip(at + PREFETCH_AHEAD).take(count) {
            crate::world::prefetch(std::ptr::from_ref(&ahead.active).cast::<u8>());
        }
    }
}

/// [`follow_four`] for the two groups of four at items `start..start + 4` and
/// `start + 4..start + 8`, stage by stage in turns: each group's tick is a chain of divisions
/// and route-point loads longer than the processor looks ahead, so one group after the other
/// waited on each link of the chain; in turns, the second group's links wait beside the first's.
/// Each group gives the bits [`follow_four`] gives it (the same stages); returns which groups
/// were done (the others wrote nothing).
#[inline(always)]
fn follow_two_fours(
    table: FollowingTable<'_>,
    start: usize,
    (f1, c1): (&mut [PathFollower], &mut [ControlCommand]),
    (f2, c2): (&mut [PathFollower], &mut [ControlCommand]),
    dt: f64,
) -> (bool, bool) {
    let (Some((f1, c1)), Some((f2, c2))) = (group_of_four(f1, c1), group_of_four(f2, c2)) else {
        return (false, false);
    };
    let a1 = start_four(table, start, f1, dt);
    let a2 = start_four(table, start + LANES, f2, dt);
    let w1 = a1.as_ref().and_then(walk_from);
    let w2 = a2.as_ref().and_then(walk_from);
    let l1 = a1.as_ref().zip(w1).and_then(|(a, w)| look_ahead(a, w, f1));
    let l2 = a2.as_ref().zip(w2).and_then(|(a, w)| look_ahead(a, w, f2));
    let s1 = a1.as_ref().zip(l1.as_ref()).and_then(|(a, l)| steer_four(table, start, a, l));
    let s2 = a2.as_ref().zip(l2.as_ref()).and_then(|(a, l)| steer_four(table, start + LANES, a, l));
    let done1 = match (a1, l1, s1) {
        (Some(a), Some(l), Some(steering)) => {
            write_four(table, start, &a, &l, steering, f1, c1);
            true
        }
        _ => false,
    };
    let done2 = match (a2, l2, s2) {
        (Some(a), Some(l), Some(steering)) => {
            write_four(table, start + LANES, &a, &l, steering, f2, c2);
            true
        }
        _ => false,
    };
    (done1, done2)
}

/// [`follow_one_by_one`] for four vehicles at once, when all four take its common path: no
/// lane change under way, no lateral shift, tracking, the walk along the route ending on the
/// segment at the hint or one step from it ([`walk_four`]), the look-ahead point less than a
/// lap past the loop's end, and a steering small enough for the polynomial.
/// Then it writes what the one-at-a-time code writes, bit for bit (the same operations in the
/// same order, lane by lane: [`walk_four`] and [`along_segment`] are the path's own), and returns
/// true; else it writes nothing and returns false.
///
/// A vehicle's tick is a chain of divisions (the walk's start, its projections, the look-ahead
/// sample, the pure-pursuit curvature) between loads of route
/// points: one at a time it waits on the divider; in vector code four vehicles share each
/// division, as in the kinematic steps ([`crate::sim::dynamics`]). The loads stay next to the
/// arithmetic that needs them (a pass over the whole chunk for each stage was twice as slow:
/// the points had left the cache by the second pass). Its stages ([`start_four`],
/// [`walk_from`], [`look_ahead`], [`steer_four`], [`write_four`]) also serve two groups in
/// turns ([`follow_two_fours`]).
#[inline(always)]
fn follow_four(
    table: FollowingTable<'_>,
    start: usize,
    followers: &mut [PathFollower],
    commands: &mut [ControlCommand],
    dt: f64,
) -> bool {
    let Some((followers, commands)) = group_of_four(followers, commands) else { return false };
    let Some(a) = start_four(table, start, followers, dt) else { return false };
    let Some(walked) = walk_from(&a) else { return false };
    let Some(l) = look_ahead(&a, walked, followers) else { return false };
    let Some(steering) = steer_four(table, start, &a, &l) else { return false };
    write_four(table, start, &a, &l, steering, followers, commands);
    true
}

/// What [`follow_four`]'s first stage ([`start_four`]) reads and works out for its four
/// vehicles.
struct Starting<'a> {
    paths: [&'a Path; LANES],
    facing: [DVec2; LANES],
    position: [DVec2; LANES],
    spacing: [f64; LANES],
    speed: [f64; LANES],
    window: [f64; LANES],
    hint: [f64; LANES],
    dt: f64,
}

/// [`follow_four`]'s first stage: whether all four take the common path so far, and where
/// their walks along the route start.
#[inline(always)]
fn start_four<'a>(
    table: FollowingTable<'a>,
    start: usize,
    followers: &[PathFollower; LANES],
    dt: f64,
) -> Option<Starting<'a>> {
    let states = table.states.get(start..start + LANES)?;
    let routes = table.routes.get(start..start + LANES)?;
    let changing = |l: usize| table.changers.is_some_and(|c| c[start + l].active.is_some());
    let paths: [&Path; LANES] = per_lane(|l| &*routes[l].0);
    let mut common = true;
    for (l, follower) in followers.iter().enumerate() {
        // What `follow_one_by_one` adds to the route's offset: the manoeuvre's (none) and the
        // shift. (A route too short to steer along fails `walk_four`.)
        common &= follower.tracking && !changing(l) && 0.0 + table.shift(start + l) == 0.0;
    }
    if !common {
        return None;
    }
    let facing: [DVec2; LANES] = per_lane(|l| states[l].heading());
    let position: [DVec2; LANES] = per_lane(|l| states[l].position);
    let spacing: [f64; LANES] = per_lane(|l| paths[l].spacing());
    let (mut speed, mut window, mut hint) = ([0.0; LANES], [0.0; LANES], [0.0; LANES]);
    for l in 0..LANES {
        // `follow_one_by_one`'s prediction and `Path::locate_walking`'s window.
        speed[l] = states[l].velocity.dot(facing[l]);
        window[l] = speed[l].abs() * dt + spacing[l];
        hint[l] = followers[l].s + speed[l] * dt;
    }
    Some(Starting { paths, facing, position, spacing, speed, window, hint, dt })
}

/// [`follow_four`]'s second stage: the walks along the routes ([`walk_four`]).
#[inline(always)]
fn walk_from(a: &Starting<'_>) -> Option<Walked> {
    walk_four(a.paths, a.position, a.hint, a.window)
}

/// What [`follow_four`]'s third stage ([`look_ahead`]) works out: where the vehicles are on
/// their routes and the route segments their look-ahead points lie on.
struct Aim {
    s: [f64; LANES],
    lateral: [f64; LANES],
    sample: [f64; LANES],
    index: [f64; LANES],
    ax: [f64; LANES],
    ay: [f64; LANES],
    bx: [f64; LANES],
    by: [f64; LANES],
}

/// [`follow_four`]'s third stage: the look-ahead samples along the routes.
#[inline(always)]
fn look_ahead(a: &Starting<'_>, walked: Walked, followers: &[PathFollower; LANES]) -> Option<Aim> {
    let (paths, spacing, speed) = (&a.paths, &a.spacing, &a.speed);
    let (s, lateral) = (walked.s, walked.lateral);
    let mut ahead = [0.0; LANES];
    for l in 0..LANES {
        ahead[l] = s[l] + followers[l].params.lookahead(speed[l], followers[l].speed, a.dt);
    }
    // The look-ahead sample (`Path::sample_direction`): wrapped on a loop (at most one lap
    // past its end here, no `fmod`), clamped on an open path.
    let (mut sample, mut at, mut within) = ([0.0; LANES], [0.0; LANES], [true; LANES]);
    for l in 0..LANES {
        let (path, s) = (paths[l], ahead[l]);
        within[l] = !path.closed || (s >= 0.0 && s < 2.0 * path.length);
        let wrapped = if s < path.length { s } else { s - path.length };
        sample[l] = if path.closed { wrapped } else { s.clamp(0.0, path.length) };
        at[l] = sample[l] / spacing[l];
    }
    if within != [true; LANES] {
        return None;
    }
    // The sampled segments' ends, coordinate by coordinate (so the arithmetic below runs four
    // lanes wide).
    let (mut index, mut ax, mut ay, mut bx, mut by) =
        ([0.0; LANES], [0.0; LANES], [0.0; LANES], [0.0; LANES], [0.0; LANES]);
    for l in 0..LANES {
        let i = (at[l] as usize).min(paths[l].segment_count() - 1);
        let (a, b) = paths[l].segment(i);
        (index[l], ax[l], ay[l], bx[l], by[l]) = (i as f64, a.x, a.y, b.x, b.y);
    }
    Some(Aim { s, lateral, sample, index, ax, ay, bx, by })
}

/// [`follow_four`]'s fourth stage: the pure-pursuit steering, if small enough for the
/// polynomial in all four.
#[inline(always)]
fn steer_four(table: FollowingTable<'_>, start: usize, a: &Starting<'_>, aim: &Aim) -> Option<[f64; LANES]> {
    let wheelbase: [f64; LANES] = per_lane(|l| table.wheelbase(start + l));
    let mut steering = [0.0; LANES];
    let mut steers = [true; LANES];
    for l in 0..LANES {
        let (p, q) = (DVec2::new(aim.ax[l], aim.ay[l]), DVec2::new(aim.bx[l], aim.by[l]));
        let (target, _) = along_segment(aim.sample[l], aim.index[l], a.spacing[l], p, q);
        let relative = target - a.position[l];
        let distance2 = relative.length_squared();
        let x = wheelbase[l] * 2.0 * a.facing[l].perp_dot(relative) / distance2;
        steers[l] = (distance2 > 1e-18) & is_small(x);
        steering[l] = atan_polynomial(x);
    }
    (steers == [true; LANES]).then_some(steering)
}

/// [`follow_four`]'s last stage: write the followers and commands.
#[inline(always)]
fn write_four(
    table: FollowingTable<'_>,
    start: usize,
    a: &Starting<'_>,
    aim: &Aim,
    steering: [f64; LANES],
    followers: &mut [PathFollower; LANES],
    commands: &mut [ControlCommand; LANES],
) {
    for l in 0..LANES {
        let follower = &mut followers[l];
        follower.tracking = true;
        follower.s = aim.s[l];
        follower.speed = a.speed[l];
        let planned = 0.0 + table.shift(start + l);
        follower.max_offset = follower.max_offset.max((aim.lateral[l] - planned).abs());
        let acceleration = table.acceleration.map(|m| &m[start + l]);
        let (command, params) = (&mut commands[l], follower.params);
        command.steering = steering[l];
        (command.speed, command.throttle) = speed_command(a.paths[l], &params, acceleration, aim.s[l], a.speed[l]);
    }
}

/// Target speed [m/s] and throttle of a vehicle at arc length `s` [m] of `path` driving at
/// `speed` [m/s]: the cruise speed, less near the end of an open path.
#[inline(always)]
fn speed_command(
    path: &Path,
    p: &PathFollowing,
    acceleration: Option<&AccelerationUnicycle>,
    s: f64,
    speed: f64,
) -> (f64, f64) {
    let mut target_speed = p.speed;
    if !path.closed {
        let remaining = (path.length - s).max(0.0);
        target_speed = target_speed.min((2.0 * p.stop_deceleration * remaining).sqrt());
        if remaining < 0.5 {
            target_speed = 0.0;
        }
    }
    let throttle = match acceleration {
        Some(m) => m.drag * target_speed + m.mass * p.speed_gain * (target_speed - speed),
        None => 0.0,
    };
    (target_speed, throttle)
}

/// Steer vehicles `start..` of `table` one at a time (see [`follow_chunk`]).
fn follow_one_by_one(
    table: FollowingTable<'_>,
    start: usize,
    followers: &mut [PathFollower],
    commands: &mut [ControlCommand],
    dt: f64,
) {
    for (k, (follower, command)) in followers.iter_mut().zip(commands.iter_mut()).enumerate() {
        let i = start + k;
        let (state, route) = (&table.states[i], &table.routes[i]);
        let acceleration = table.acceleration.map(|m| &m[i]);
        let changer = table.changers.map(|c| &c[i]);
        let shift = table.shift(i);
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

        let wheelbase = table.wheelbase(i);
        let lookahead = p.lookahead(speed, follower.speed, dt);
        follower.speed = speed;
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

        (command.speed, command.throttle) = speed_command(path, &p, acceleration, s, speed);
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::grid::with_avx2;
    use std::sync::Arc;

    /// A loop of radius `r` [m] through `n` points.
    fn circle(r: f64, n: usize) -> Path {
        let points = (0..n).map(|k| DVec2::from_angle(k as f64 * std::f64::consts::TAU / n as f64) * r).collect();
        Path::from_points(Vec::new(), points, true)
    }

    /// Vehicles near `paths` (a few far off their follower's arc length, off the route, not yet
    /// tracking or shifted aside), with their routes, models, followers and shifts.
    #[allow(clippy::type_complexity)]
    fn vehicles(
        n: usize,
    ) -> (
        Vec<VehicleState>,
        Vec<Route>,
        Vec<KinematicUnicycle>,
        Vec<AccelerationUnicycle>,
        Vec<PathFollower>,
        Vec<LateralShift>,
    ) {
        let open = Path::from_polyline(&[DVec2::ZERO, DVec2::new(400.0, 30.0), DVec2::new(800.0, -20.0)], 0.5);
        let paths = [Arc::new(circle(1500.0, 4712)), Arc::new(open), Arc::new(circle(8.0, 12))];
        let mut next = crate::world::random::draws(0x2545_f491_4f6c_dd1d);
        let dt = 0.05;
        let mut out = (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for k in 0..n {
            let path = &paths[match k % 47 {
                0 => 2,
                1..=8 => 1,
                _ => 0,
            }];
            let s = next() * path.length;
            let (point, heading) = path.sample(s);
            // Mostly on the route and along it, as a tracking vehicle is (gentle steering); now
            // and then well off it (steering beyond the polynomial) or far off (another segment
            // nearer than the walk's).
            let offset = (next() - 0.5)
                * match (k % 31, k % 37) {
                    (0, _) => 40.0,
                    (_, 0) => 3.0,
                    _ => 0.01,
                };
            let yaw = heading + (next() - 0.5) * if k % 29 == 0 { 0.1 } else { 1e-4 };
            let speed = 30.0 * next();
            let state = VehicleState::new(point + DVec2::from_angle(heading).perp() * offset, yaw, speed);
            // Where the follower was a tick ago, give or take the dynamics' uneven steps (and
            // now and then much farther, so that the walk goes on or the window is searched).
            let error = (next() - 0.5) * if k % 41 == 0 { 20.0 } else { 1.0 };
            // A look-ahead now and then beyond two laps of the big loop (which only `fmod` wraps).
            let lookahead_min = if k % 59 == 0 { 25_000.0 } else { 4.0 };
            let params = PathFollowing { speed: 15.0 + 10.0 * next(), lookahead_min, ..Default::default() };
            let follower = if k % 43 == 0 {
                PathFollower::new(params)
            } else {
                PathFollower::starting_at(params, s - speed * dt + error)
            };
            out.0.push(state);
            out.1.push(Route(Arc::clone(path)));
            out.2.push(KinematicUnicycle { wheelbase: 2.5 + next(), max_steering: 0.5 });
            out.3.push(AccelerationUnicycle { wheelbase: 2.5 + next(), mass: 1500.0, drag: 30.0, max_steering: 0.5 });
            out.4.push(follower);
            out.5.push(LateralShift(if k % 53 == 0 { 0.5 } else { 0.0 }));
        }
        out
    }

    fn bits(followers: &[PathFollower], commands: &[ControlCommand]) -> Vec<[u64; 6]> {
        let f = followers.iter().zip(commands);
        f.map(|(f, c)| {
            [f.s, f.max_offset, f64::from(u8::from(f.tracking)), c.steering, c.speed, c.throttle].map(f64::to_bits)
        })
        .collect()
    }

    #[test]
    fn four_vehicles_at_once_are_steered_to_the_bits_of_four_one_at_a_time() {
        let n = 4003;
        let (states, routes, kinematic, acceleration, followers, shifts) = vehicles(n);
        let dt = 0.05;
        let tables = [
            FollowingTable {
                states: &states,
                routes: &routes,
                kinematic: Some(&kinematic),
                acceleration: None,
                changers: None,
                shifts: None,
            },
            FollowingTable {
                states: &states,
                routes: &routes,
                kinematic: None,
                acceleration: Some(&acceleration),
                changers: None,
                shifts: Some(&shifts),
            },
        ];
        for table in tables {
            let commands = vec![ControlCommand::default(); n];
            let (mut want_f, mut want_c) = (followers.clone(), commands.clone());
            follow_one_by_one(table, 0, &mut want_f, &mut want_c, dt);
            let want = bits(&want_f, &want_c);
            let (mut plain_f, mut plain_c) = (followers.clone(), commands.clone());
            let pass = FollowPass { table, start: 0, followers: &mut plain_f, commands: &mut plain_c, dt };
            pass.run();
            assert_eq!(bits(&plain_f, &plain_c), want, "scalar code");
            if std::arch::is_x86_feature_detected!("avx2") {
                let (mut f, mut c) = (followers.clone(), commands.clone());
                // SAFETY: the processor has AVX2, checked just above.
                unsafe { with_avx2(FollowPass { table, start: 0, followers: &mut f, commands: &mut c, dt }) };
                assert_eq!(bits(&f, &c), want, "AVX2 code");
            }
            // Both ways were taken: four at once (else this compared nothing new) and one at a
            // time, where `follow_four` must leave the followers and commands as they were.
            let mut taken = 0;
            for g in 0..n / LANES {
                let r = g * LANES..(g + 1) * LANES;
                let (mut f, mut c) = (followers[r.clone()].to_vec(), commands[r.clone()].to_vec());
                if follow_four(table, r.start, &mut f, &mut c, dt) {
                    taken += 1;
                } else {
                    assert_eq!(bits(&f, &c), bits(&followers[r.clone()], &commands[r]), "group {g} changed");
                }
            }
            assert!(taken > n / LANES / 4 && taken < n / LANES, "{taken} of {} groups four at once", n / LANES);
            // Two groups in turns: each group done exactly when `follow_four` does it, to the
            // same bits, and left as it was otherwise, whatever the other group does.
            let mut outcomes = std::collections::BTreeSet::new();
            for g in 0..n / (2 * LANES) {
                let r = g * 2 * LANES..(g + 1) * 2 * LANES;
                let (mut f, mut c) = (followers[r.clone()].to_vec(), commands[r.clone()].to_vec());
                let ((f1, f2), (c1, c2)) = (f.split_at_mut(LANES), c.split_at_mut(LANES));
                let done = follow_two_fours(table, r.start, (f1, c1), (f2, c2), dt);
                outcomes.insert(done);
                for (k, done) in [done.0, done.1].into_iter().enumerate() {
                    let group = r.start + k * LANES..r.start + (k + 1) * LANES;
                    let (mut one_f, mut one_c) = (followers[group.clone()].to_vec(), commands[group.clone()].to_vec());
                    assert_eq!(
                        follow_four(table, group.start, &mut one_f, &mut one_c, dt),
                        done,
                        "group at {}",
                        group.start
                    );
                    let got = bits(&f[k * LANES..(k + 1) * LANES], &c[k * LANES..(k + 1) * LANES]);
                    if done {
                        assert_eq!(got, want[group].to_vec(), "pair {g}, group {k}");
                    } else {
                        assert_eq!(
                            got,
                            bits(&followers[group.clone()], &commands[group]),
                            "pair {g}, group {k} changed"
                        );
                    }
                }
            }
            assert_eq!(outcomes.len(), 4, "every mix of done and not done seen: {outcomes:?}");
        }
    }
}
