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

use std::collections::BTreeMap;

use bevy_ecs::prelude::{Component, Local, Query, Res, Resource};
use bevy_ecs::schedule::{IntoScheduleConfigs, SystemSet};
use glam::DVec2;

use crate::map::{LaneletId, Path};
use crate::sim::SimBuilder;
use crate::sim::{Control, Parallelism, SimClock, SimSystems};
use crate::world::prefetch_bytes;
use crate::world::{
    AccelerationUnicycle, ControlCommand, Detection, KinematicUnicycle, Route, SensorReadings, VehicleId, VehicleSize,
    VehicleState,
};

use super::PathFollower;
use super::lane_state::{Found, IndexEntry, LaneChanger, LaneCrossings, LaneIndex, first_at_or_after};
use super::lanes::{LaneMap, LanePosition, LanePositionsAt, PREFETCH_AHEAD, forward_speed};

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

pub use super::follow_laws::LeaderGap;

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
    /// Largest lateral offset \[m\] of a detection from our route for it to count as "on our
    /// route"; about half a lane width.
    pub lane_half_width: f64,
    /// Whether emergency braking overrides the controllers this tick.
    pub emergency: bool,
    /// The leader's own length \[m\] where the leader search knew it (the lane index), so a
    /// controller need not look the vehicle up.
    pub leader_length: Option<f64>,
}

impl Default for Longitudinal {
    fn default() -> Self {
        Longitudinal {
            accel: f64::NAN,
            route_speed: 0.0,
            leader: None,
            lane_half_width: 1.75,
            emergency: false,
            leader_length: None,
        }
    }
}

impl Longitudinal {
    /// Lower the demand to at most `accel` [m/s²] (a limiter); sets it if nobody had.
    pub fn limit(&mut self, accel: f64) {
        self.accel = self.accel.min(accel);
    }
}

/// The nearest detection that lies on `path` ahead of arc length `s` \[m\] (within
/// `lane_half_width` \[m\] of the centre line), as a [`LeaderGap`] with zero acceleration.
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
    leader_on_path_with(path, s, position, own_length, detections, lane_half_width, |_| false, |_| false)
}

/// [`leader_on_path`], where a detection for which `crossing(id)` holds (a vehicle changing
/// into or out of this lane) counts up to three half widths from the centre line: while it
/// crosses, a vehicle is in both lanes; one for which `elsewhere(id)` holds (on a bridge above
/// or a road below, [`crate::map::junctions::Junctions::levels_apart`]) is passed over, asked only of
/// a detection that would otherwise lead.
#[allow(clippy::too_many_arguments)]
pub fn leader_on_path_with(
    path: &Path,
    s: f64,
    position: DVec2,
    own_length: f64,
    detections: &[Detection],
    lane_half_width: f64,
    crossing: impl Fn(VehicleId) -> bool,
    elsewhere: impl Fn(VehicleId) -> bool,
) -> Option<LeaderGap> {
    if path.points.len() < 2 {
        return None;
    }
    for d in detections {
        let r = d.position.distance(position);
        // On the path: within half a lane of its centre line, or three half lanes for a vehicle
        // crossing into or out of it.
        let reach = if crossing(d.id) { lane_half_width.max(3.0 * lane_half_width) } else { lane_half_width };
        let window = 0.3 * r + 5.0;
        // Every path point of the window lies within `window` (its arc length) of the point at
        // s + r, so a detection farther than that plus `reach` from it projects onto none: an
        // exact test that skips the projection for the vehicles on crossing streets of a town.
        let centre = path.sample_point(s + r);
        let bound = window + reach + 2.0 * path.spacing();
        if d.position.distance_squared(centre) > bound * bound {
            continue;
        }
        // Walked from s + r to the nearest segment (a few segments: along a lane the distance
        // has one minimum near there), the window searched only when the walk leaves it.
        let Some((p_s, _, _, direction)) = path.near_within(d.position, s + r, window, reach) else { continue };
        let mut ahead = p_s - s;
        if path.closed {
            ahead = ahead.rem_euclid(path.length);
            if ahead > 0.5 * path.length {
                continue;
            }
        }
        if ahead <= 0.0 || elsewhere(d.id) {
            continue;
        }
        let speed = d.velocity.dot(direction);
        return Some(LeaderGap { id: d.id, distance: ahead, gap: ahead - own_length, speed, acceleration: 0.0 });
    }
    None
}

/// A vehicle that finds its leader in the lane index ([`LaneIndex`]) along its route
/// ([`leader_along_route`]) instead of among its sensor readings: traffic from SUMO demand,
/// which carries no radar (sensing every vehicle around, every tick, only to pick the one
/// ahead on its own lane was most of a SUMO step). The leader is the vehicle the radar would
/// pick where the radar saw one on the route's lanes; out to the default radar's range
/// ([`LEADER_RANGE`]) along the lane.
#[derive(Component, Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LeaderFromLanes;

/// How far along its route \[m\] a [`LeaderFromLanes`] vehicle looks for its leader: the
/// default radar's range ([`crate::world::Radar::default`]), which it replaces.
pub const LEADER_RANGE: f64 = 100.0;

/// Nearest vehicle other than `me` ahead of arc length `s` \[m\] on lanelet `i` along `route`
/// (lanelet by lanelet as the route goes), within `range` \[m\] along the lanes: a vehicle
/// indexed on one of the route's lanelets, or on a stretch of another that lies on the lane
/// ([`LaneMap::overlaps`]: a junction's turns from one lane, lanes that join), where a radar
/// would see it on the route's path. Where `i` is not on the route (a vehicle in a junction
/// located on a turn that shares its first metres with its own), the route lanelet it
/// overlaps; else the lanes' first successors ([`LaneIndex::ahead`]). O(lanelets looked at ·
/// log k) for k vehicles on one, allocation free.
pub fn leader_along_route(
    index: &LaneIndex,
    lanes: &LaneMap,
    route: &Path,
    i: u32,
    s: f64,
    me: VehicleId,
    range: f64,
) -> Option<Found> {
    let ids = &route.lanelets;
    let own = lanes.id(i);
    let start = match ids.iter().position(|&id| id == own) {
        Some(k) => Some((k, i, s)),
        // On a lanelet beside the route's where the two share the lane.
        None => ids.iter().enumerate().find_map(|(k, id)| {
            let j = lanes.map.lanelet_index(*id)? as u32;
            let o = lanes.overlaps(j).iter().find(|o| o.lanelet == i && o.from <= s && s <= o.to)?;
            Some((k, j, s + o.shift))
        }),
    };
    let Some((mut k, mut j, s)) = start else {
        return index.ahead(lanes, i, s, me).filter(|f| f.distance <= range);
    };
    let found = |e: &IndexEntry, distance: f64| Found { distance, speed: e.speed, length: e.length, id: e.id };
    // Distance from the asking point to the start of lanelet `j` (after the first one).
    let mut base = 0.0;
    let mut first = true;
    for _ in 0..ids.len().max(1) {
        // Ahead on the lane: at arc length `at` or later of lanelet `j`.
        let at = if first { s } else { f64::NEG_INFINITY };
        let distance = |lane_s: f64| if first { lane_s - s } else { base + lane_s };
        let list = index.on(j);
        let from = if first { first_at_or_after(list, s, lanes.per_length(j)) } else { 0 };
        let mut best = list[from..].iter().find(|e| e.id != me).map(|e| found(e, distance(e.s)));
        for o in lanes.overlaps(j) {
            let list = index.on(o.lanelet);
            let lo = o.from.max(at - o.shift);
            let from = first_at_or_after(list, lo, lanes.per_length(o.lanelet));
            let hit = list[from..].iter().take_while(|e| e.s <= o.to).find(|e| e.id != me);
            if let Some(e) = hit {
                let d = distance(e.s + o.shift);
                if best.is_none_or(|b| d < b.distance || (d == b.distance && e.id < b.id)) {
                    best = Some(found(e, d));
                }
            }
        }
        if let Some(b) = best {
            return (b.distance <= range).then_some(b);
        }
        base = if first { lanes.length(j) - s } else { base + lanes.length(j) };
        first = false;
        if base > range {
            return None;
        }
        k += 1;
        if k == ids.len() {
            if !route.closed {
                return None;
            }
            k = 0;
        }
        j = lanes.next_on_route(j, ids[k])?;
    }
    None
}

/// One ECS table's vehicles as [`find_leaders`] reads them: slices of the same rows (bevy's
/// contiguous access; an optional component is in all of a table's rows or in none).
#[derive(Clone, Copy)]
struct LeaderTable<'a> {
    ids: &'a [VehicleId],
    positions: Option<&'a [LanePosition]>,
    states: &'a [VehicleState],
    sizes: &'a [VehicleSize],
    routes: &'a [Route],
    followers: &'a [PathFollower],
    commands: &'a [ControlCommand],
    readings: Option<&'a [SensorReadings]>,
    changers: Option<&'a [LaneChanger]>,
    by_lane: Option<&'a [LeaderFromLanes]>,
}

/// What every vehicle's leader search reads besides its own components.
#[derive(Clone, Copy)]
struct LeaderShared<'a> {
    dt: f64,
    crossings: Option<&'a BTreeMap<VehicleId, (LaneletId, LaneletId)>>,
    lanes: Option<(&'a LaneIndex, &'a LaneMap)>,
    /// The map's junctions, for the lanelets that cross on other levels (`None` without a lane
    /// index or where no lanelets do).
    junctions: Option<&'a crate::map::junctions::Junctions>,
}

/// Reset the demand and find each vehicle's leader on its route (split over threads; each
/// vehicle's result depends only on its own components, so any thread count gives the same bits).
#[allow(clippy::type_complexity)]
pub fn find_leaders(
    clock: Res<SimClock>,
    crossings: Option<Res<LaneCrossings>>,
    parallelism: Option<Res<Parallelism>>,
    index: Option<Res<LaneIndex>>,
    lane_map: Option<Res<LaneMap>>,
    mut vehicles: Query<(
        &VehicleId,
        Option<&LanePosition>,
        &VehicleState,
        &VehicleSize,
        &Route,
        &PathFollower,
        &ControlCommand,
        Option<&SensorReadings>,
        &mut Longitudinal,
        Option<&LaneChanger>,
        Option<&LeaderFromLanes>,
    )>,
    mut scratch: Local<Vec<()>>,
) {
    let crossings = crossings.as_deref().map(|c| &c.0).filter(|c| !c.is_empty());
    let lanes = index.as_deref().zip(lane_map.as_deref());
    let junctions = lanes.map(|(_, m)| m.map.junctions()).filter(|j| j.any_levels_apart());
    let shared = LeaderShared { dt: clock.dt, crossings, lanes, junctions: junctions.as_deref() };
    let parallelism = parallelism.as_deref().copied().unwrap_or_else(Parallelism::single);
    // Table by table, straight in the ECS tables' slices: no list of the query's items is
    // gathered first (a serial pass over every vehicle).
    if let Ok(tables) = vehicles.contiguous_iter_mut() {
        for (ids, positions, states, sizes, routes, followers, commands, readings, mut lons, changers, by_lane) in
            tables
        {
            let table =
                LeaderTable { ids, positions, states, sizes, routes, followers, commands, readings, changers, by_lane };
            parallelism.for_each_chunk_at(&mut lons, &mut scratch, |start, lons, _| {
                for (k, lon) in lons.iter_mut().enumerate() {
                    // The detections a vehicle a few places on will scan: far apart on a big
                    // world. The leader is mostly among the nearest few: the first four cache lines.
                    // Two steps ahead: the route prefetch below reads the nearest one.
                    if let Some(r) = readings.and_then(|r| r.get(start + k + 2 * PREFETCH_AHEAD)) {
                        prefetch_bytes(r.0.as_ptr().cast(), std::mem::size_of_val(&r.0[..]).min(256));
                    }
                    // Its own entry in the lane index, where its leader search starts.
                    if let (Some((index, _)), Some(id)) = (shared.lanes, ids.get(start + k + PREFETCH_AHEAD)) {
                        index.prefetch_own(*id);
                    }
                    // A vehicle that searches its route (not a lane changer): its route's fields,
                    // then its points where the nearest detection projects (each vehicle owns
                    // its route in a town: two dependent misses, overlapped this way).
                    if changers.is_none() {
                        prefetch_route(table, start + k + PREFETCH_AHEAD, start + k + 2 * PREFETCH_AHEAD);
                    }
                    leader_of(shared, table, start + k, lon);
                }
            });
        }
        return;
    }
    // Only if a component were stored sparsely (none is): one at a time.
    for (id, pos, state, size, route, follower, command, readings, mut lon, changer, by_lane) in &mut vehicles {
        let table = LeaderTable {
            ids: std::slice::from_ref(id),
            positions: pos.map(std::slice::from_ref),
            states: std::slice::from_ref(state),
            sizes: std::slice::from_ref(size),
            routes: std::slice::from_ref(route),
            followers: std::slice::from_ref(follower),
            commands: std::slice::from_ref(command),
            readings: readings.map(std::slice::from_ref),
            changers: changer.map(std::slice::from_ref),
            by_lane: by_lane.map(std::slice::from_ref),
        };
        leader_of(shared, table, 0, &mut lon);
    }
}

/// Hint to the processor what [`leader_of`] will read of the route of row `near` of `table`
/// (its points about the nearest detection's distance ahead, where the search looks first) and
/// of the route of row `far` (the route's own fields, which the first needs): no effect on any
/// result.
#[inline(always)]
fn prefetch_route(table: LeaderTable<'_>, near: usize, far: usize) {
    if let Some(route) = table.routes.get(far) {
        crate::world::prefetch_value(&*route.0);
    }
    let (Some(route), Some(state), Some(follower)) =
        (table.routes.get(near), table.states.get(near), table.followers.get(near))
    else {
        return;
    };
    let first = table.readings.and_then(|r| r.get(near)).and_then(|r| r.0.first());
    if let Some(d) = first {
        crate::world::prefetch_all(route.0.points_near(follower.s + d.position.distance(state.position)));
    }
}

/// [`find_leaders`] for row `n` of `table`.
#[inline(always)]
fn leader_of(shared: LeaderShared<'_>, table: LeaderTable<'_>, n: usize, lon: &mut Longitudinal) {
    let LeaderShared { dt, crossings, lanes, junctions } = shared;
    let (id, size, command) = (&table.ids[n], &table.sizes[n], &table.commands[n]);
    let pos = table.positions.map(|p| &p[n]);
    let readings = table.readings.map(|r| &r[n]);
    let changer = table.changers.map(|c| &c[n]);
    // No sensors: the leader along the route from the lane index (a lane change under way:
    // the lane changers' search below, every vehicle counted as seen).
    let by_lane = table.by_lane.is_some();
    if by_lane && changer.is_none_or(|c| c.active.is_none()) {
        let found = match (lanes, pos.and_then(|p| p.on().map(|i| (i, p.s)))) {
            (Some((index, map)), Some((i, s))) => {
                leader_along_route(index, map, &table.routes[n].0, i, s, *id, LEADER_RANGE)
            }
            _ => None,
        };
        let leader = found.map(|f| LeaderGap {
            id: f.id,
            distance: f.distance,
            gap: f.distance - size.length,
            speed: f.speed,
            acceleration: 0.0,
        });
        set_leader(dt, lon, command, leader);
        lon.leader_length = found.map(|f| f.length);
        return;
    }
    // A lane changer's leader comes from the lane index (the vehicle ahead in its lane,
    // crossing vehicles in both lanes) among those its sensors detect.
    let in_lane = match (lanes, changer, pos.and_then(|p| p.on().map(|i| (i, p.s)))) {
        (Some((index, map)), Some(_), Some((i, s))) => Some((index, map, i, s)),
        _ => None,
    };
    match in_lane {
        Some((index, map, i, s)) => {
            let detections = readings.map_or(&[][..], |r| &r.0[..]);
            // The detection of the vehicle found, kept from the search (one scan).
            let matched = std::cell::Cell::new(None);
            let seen = |other: VehicleId| match detections.iter().find(|d| d.id == other) {
                _ if by_lane => true,
                Some(d) => {
                    matched.set(Some(d));
                    true
                }
                None => false,
            };
            let found = index.ahead_along(map, i, s, *id, &table.routes[n].0.lanelets, seen);
            let leader = found.map(|f| {
                let d = matched.get().filter(|d| d.id == f.id);
                // The speed as sensed: the detection's velocity along its own motion.
                let speed = d.map_or(f.speed, |d| d.velocity.length());
                LeaderGap { id: f.id, distance: f.distance, gap: f.distance - size.length, speed, acceleration: 0.0 }
            });
            set_leader(dt, lon, command, leader);
            lon.leader_length = found.map(|f| f.length);
        }
        None => {
            let (state, route, follower) = (&table.states[n], &table.routes[n], &table.followers[n]);
            // A detection on another level than the vehicle's own lanelet (an OpenDRIVE bridge)
            // does not lead it, though it crosses its path on the plane.
            let own = pos.and_then(|p| p.on());
            let elsewhere = |other: VehicleId| match (lanes, junctions, own) {
                (Some((index, _)), Some(junctions), Some(i)) => {
                    index.lanelet_of(other).is_some_and(|j| junctions.levels_apart(i as usize, j as usize))
                }
                _ => false,
            };
            find_leader(dt, crossings, state, size, route, follower, command, readings, lon, changer, elsewhere)
        }
    }
}

/// [`find_leaders`] for one vehicle.
#[allow(clippy::too_many_arguments)]
fn find_leader(
    dt: f64,
    crossings: Option<&BTreeMap<VehicleId, (LaneletId, LaneletId)>>,
    state: &VehicleState,
    size: &VehicleSize,
    route: &Route,
    follower: &PathFollower,
    command: &ControlCommand,
    readings: Option<&SensorReadings>,
    lon: &mut Longitudinal,
    changer: Option<&LaneChanger>,
    elsewhere: impl Fn(VehicleId) -> bool + Copy,
) {
    let detections = readings.map_or(&[][..], |r| &r.0[..]);
    // A vehicle changing into or out of a lane of this route counts in both lanes.
    let lanes = &route.0.lanelets;
    let crossing = |id: VehicleId| {
        crossings.is_some_and(|c| c.get(&id).is_some_and(|(a, b)| lanes.contains(a) || lanes.contains(b)))
    };
    let mut leader = leader_on_path_with(
        &route.0,
        follower.s,
        state.position,
        size.length,
        detections,
        lon.lane_half_width,
        crossing,
        elsewhere,
    );
    // While changing lanes the vehicle is in both: the nearer leader of the old lane counts too.
    if let Some(m) = changer.and_then(|c| c.active.as_ref()) {
        let old = leader_on_path(&m.old_route, m.old_s, state.position, size.length, detections, lon.lane_half_width);
        if old.is_some_and(|o| leader.is_none_or(|l| o.distance < l.distance)) {
            leader = old;
        }
    }
    set_leader(dt, lon, command, leader);
}

/// Reset the demand to "none", the route speed to the path follower's and store `leader`, its
/// acceleration from the change of its speed since the last tick when it is the same vehicle.
fn set_leader(dt: f64, lon: &mut Longitudinal, command: &ControlCommand, mut leader: Option<LeaderGap>) {
    lon.accel = f64::NAN;
    lon.emergency = false;
    lon.route_speed = command.speed;
    lon.leader_length = None;
    if let (Some(l), Some(p)) = (leader.as_mut(), lon.leader)
        && l.id == p.id
        && dt > 0.0
    {
        l.acceleration = (l.speed - p.speed) / dt;
    }
    lon.leader = leader;
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
    parallelism: Option<Res<Parallelism>>,
    lanes_at: Option<Res<LanePositionsAt>>,
    mut vehicles: Query<(
        &VehicleState,
        &Longitudinal,
        &mut ControlCommand,
        Option<&AccelerationUnicycle>,
        Option<&KinematicUnicycle>,
        Option<&LanePosition>,
    )>,
    mut scratch: Local<Vec<()>>,
) {
    let dt = clock.dt;
    let fresh = LanePositionsAt::fresh(lanes_at.as_deref(), clock.now);
    let parallelism = parallelism.as_deref().copied().unwrap_or_else(Parallelism::single);
    // Table by table, straight in the ECS tables' slices (no list of the query's items gathered
    // first); each vehicle's command depends only on itself: any split gives the same bits.
    if let Ok(tables) = vehicles.contiguous_iter_mut() {
        for (states, lons, mut commands, acceleration, kinematic, positions) in tables {
            parallelism.for_each_chunk_at(&mut commands, &mut scratch, |start, commands, _| {
                for (k, command) in commands.iter_mut().enumerate() {
                    let n = start + k;
                    let (a, kin) = (acceleration.map(|a| &a[n]), kinematic.is_some());
                    actuate(dt, fresh, &states[n], &lons[n], command, a, kin, positions.map(|p| &p[n]));
                }
            });
        }
        return;
    }
    // Only if a component were stored sparsely (none is): one at a time.
    for (state, lon, mut command, a, k, pos) in &mut vehicles {
        actuate(dt, fresh, state, lon, &mut command, a, k.is_some(), pos);
    }
}

/// One vehicle's part of [`actuate_longitudinal`] (`kinematic`: it has a [`KinematicUnicycle`]).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn actuate(
    dt: f64,
    fresh: bool,
    state: &VehicleState,
    lon: &Longitudinal,
    command: &mut ControlCommand,
    acceleration: Option<&AccelerationUnicycle>,
    kinematic: bool,
    pos: Option<&LanePosition>,
) {
    // Vehicles without a demand (NaN) keep their command.
    if lon.accel.is_nan() {
        return;
    }
    let v = forward_speed(state, pos, fresh).max(0.0);
    // Never faster than the route's target speed (it stops at the end of an open route).
    let accel = if v > lon.route_speed { lon.accel.min(ROUTE_SPEED_GAIN * (lon.route_speed - v)) } else { lon.accel };
    if let Some(m) = acceleration {
        command.throttle = m.mass * accel + m.drag * v;
    }
    if kinematic || acceleration.is_none() {
        command.speed = (v + accel * dt).max(0.0);
    } else {
        command.speed = v;
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
