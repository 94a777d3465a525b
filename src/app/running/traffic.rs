//! Background traffic (`[[traffic]]`): vehicles placed at t = 0 (`count`) and inserted at the
//! route start over time (`rate`, Poisson arrivals), removed (despawned, leaving the `Vehicles`
//! registry) when they reach the end of an open route. Every random choice (desired speed, class,
//! lane, arrival time) is a counter-based draw of (seed, table, vehicle, draw)
//! ([`crate::sim::random::uniform`]), so a run depends on the seed only.
//!
//! A table with `route = "random"` has no lanes of its own: each vehicle draws a trip
//! ([`super::random_trips`]) when it arrives and waits at the start of its origin lanelet until
//! that entry is free; vehicles waiting at different entries do not hold each other up.

use std::sync::Arc;

use bevy_ecs::prelude::{Component, Entity, Local, Mut, Resource, World};
use bevy_ecs::schedule::{IntoScheduleConfigs, SystemSet};
use glam::DVec2;

use super::random_trips::{RandomTrip, RandomTrips};
use super::trips::{Trip, end_trip};
use crate::map::{LaneletId, LaneletMap, Path, Place};
use crate::sim::random::uniform;
use crate::sim::{Control, Plugin, SimBuilder, SimClock, SimSystems};
use crate::vehicles::crossing::safe_stop_speed;
use crate::vehicles::follow_laws::IDM_MAX_BRAKING;
use crate::vehicles::lane_changing::{LaneChangeSystems, LaneIndex};
use crate::vehicles::lane_state::Found;
use crate::vehicles::lanes::PREFETCH_AHEAD;
use crate::vehicles::{
    AccSetup, CruiseSetup, EmergencySettings, FollowLaw, Idm, LaneChangeParams, LaneChanger, LaneMap, LanePosition,
    LeaderFromLanes, PathFollower, PathFollowing, RouteGoal, SmartController, YieldToEmergency,
};
use crate::world::{
    Route, SensorSet, VehicleClass, VehicleId, VehicleModel, VehicleSize, VehicleSpec, VehicleState, WorldError,
    despawn_vehicle, spawn_vehicle,
};

/// Bumper-to-bumper gap a placed or inserted vehicle keeps at least [m].
const MIN_GAP: f64 = 2.0;
/// Time gap used to choose a safe speed for a placed or inserted vehicle [s].
const TIME_GAP: f64 = 1.5;
/// A vehicle this close to the end of its route [m] has left the world.
const LEAVE_AT: f64 = 5.0;

/// Footprint of a traffic vehicle of class `c` \[m\].
pub fn class_size(c: VehicleClass) -> VehicleSize {
    match c {
        VehicleClass::Truck => VehicleSize { length: 12.0, width: 2.5 },
        VehicleClass::Bus => VehicleSize { length: 12.0, width: 2.55 },
        VehicleClass::Motorcycle => VehicleSize { length: 2.2, width: 0.8 },
        VehicleClass::Bicycle => VehicleSize { length: 1.8, width: 0.6 },
        VehicleClass::Emergency => VehicleSize { length: 5.5, width: 2.0 },
        VehicleClass::Car => VehicleSize::default(),
    }
}

/// One start lane of a traffic table: its lanelet, where the path enters it, and the path.
#[derive(Debug, Clone)]
pub struct TrafficLane {
    /// Lanelet index of the path's start.
    pub lanelet: u32,
    /// Arc length of the path's start on that lanelet \[m\].
    pub entry_s: f64,
    /// The path (a loop, or to the destination).
    pub path: Arc<Path>,
}

/// One `[[traffic]]` table, resolved.
#[derive(Debug, Clone)]
pub struct TrafficSource {
    /// Table index (the random stream).
    pub stream: u64,
    /// Start lanes.
    pub lanes: Vec<TrafficLane>,
    /// Where the routes go.
    pub goal: RouteGoal,
    /// Arrivals per second [1/s] (0: none).
    pub rate_per_s: f64,
    /// No insertion after this time \[s\].
    pub until: f64,
    /// Desired speed range [m/s].
    pub speed: [f64; 2],
    /// Classes with cumulative shares (the last is 1).
    pub classes: Vec<(VehicleClass, f64)>,
    /// Controller (default IDM).
    pub controller: Option<SmartController>,
    /// Lane changes.
    pub lane_change: Option<LaneChangeParams>,
    /// Dynamics model.
    pub model: VehicleModel,
    /// Sensors.
    pub sensors: SensorSet,
    /// Whether its vehicles find their leader in the lane index along their routes
    /// ([`crate::vehicles::LeaderFromLanes`]) instead of among their sensors' readings.
    pub leader_from_lanes: bool,
    /// Noise, dropout and occlusion of its sensors.
    pub sensor_errors: crate::world::SensorErrors,
    /// Make way for emergency vehicles (when the scenario has one).
    pub yield_to_emergency: bool,
    /// Next id to give.
    pub next_id: i32,
    /// What `next_id` moves by after each vehicle: -1 for the default negative (virtual) ids,
    /// which count down from -1000, +1 for ids counting up from an explicit `id_start`.
    pub id_step: i32,
    /// Vehicles drawn so far (the random index).
    pub drawn: u64,
    /// Next arrival time \[s\].
    pub next_time: f64,
    /// Arrivals waiting for a free entry.
    pub queue: u64,
    /// Random routes (`route = "random"`): the lanelets trips are drawn from; `lanes` is then
    /// empty and `goal` unused (each vehicle heads for its own destination).
    pub random: Option<Arc<RandomTrips>>,
    /// Random-route arrivals waiting for their entry, in arrival order: (vehicle index, trip).
    pub pending: Vec<(u64, RandomTrip)>,
    /// Random trips only: at its destination a vehicle draws a new trip from there instead of
    /// leaving (`on_arrival = "new_trip"`).
    pub renew: bool,
    /// Departure times \[s\], sorted (SUMO demand, [`crate::map::sumo::demand`]): a vehicle
    /// arrives at each, besides the `rate` arrivals.
    pub schedule: Vec<f64>,
    /// Departures of `schedule` that have arrived so far.
    pub scheduled: usize,
    /// Body length \[m\] in place of the class's (a SUMO `vType` length).
    pub length: Option<f64>,
    /// Speed on entry [m/s] at most this (a SUMO `departSpeed`); `None`: the desired speed.
    pub depart_speed: Option<f64>,
}

impl TrafficSource {
    /// Footprint of a vehicle of class `c` of this table \[m\].
    pub fn size(&self, c: VehicleClass) -> VehicleSize {
        let size = class_size(c);
        VehicleSize { length: self.length.unwrap_or(size.length), ..size }
    }
}

/// A traffic vehicle (its table index).
#[derive(Component, Debug, Clone, Copy, PartialEq, Eq)]
pub struct TrafficVehicle(pub usize);

/// All traffic tables and what they did.
#[derive(Resource, Debug, Clone, Default)]
pub struct Traffic {
    /// The tables.
    pub sources: Vec<TrafficSource>,
    /// The scenario's seed.
    pub seed: u64,
    /// Vehicles placed or inserted.
    pub inserted: u64,
    /// Vehicles removed at the end of their route.
    pub removed: u64,
    /// Most arrivals waiting at once for a free entry.
    pub waiting_max: u64,
    /// Largest distance to its route's centre line \[m\] of every vehicle removed so far, by id
    /// (ids are never reused in a run): `summary.json` reports every vehicle that drove.
    pub departed_max_offset: std::collections::BTreeMap<i32, f64>,
}

/// Keep the largest distance to the centre line of vehicle `id` (`entity`), about to be removed.
fn remember_departure(world: &World, traffic: &mut Traffic, id: VehicleId, entity: Entity) {
    if let Some(f) = world.get::<PathFollower>(entity) {
        traffic.departed_max_offset.insert(id.0, f.max_offset);
    }
}

/// `metrics.traffic` of `summary.json`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct TrafficSummary {
    /// Vehicles placed or inserted.
    pub inserted: u64,
    /// Vehicles removed at the end of their route.
    pub removed: u64,
    /// Most arrivals waiting at once for a free entry.
    pub waiting_max: u64,
}

/// `metrics.throughput` of `summary.json`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Throughput {
    /// Vehicles that left at their route's end.
    pub vehicles_out: u64,
    /// The same per hour of sim time [veh/h].
    pub per_hour: f64,
}

/// What one vehicle draws: desired speed [m/s], class, lane index.
fn draw(seed: u64, src: &TrafficSource, k: u64) -> (f64, VehicleClass, usize) {
    let [lo, hi] = src.speed;
    let v0 = lo + (hi - lo) * uniform(seed, src.stream, k, 0);
    let u = uniform(seed, src.stream, k, 1);
    let class = src.classes.iter().find(|c| u < c.1).or(src.classes.last()).map_or(VehicleClass::Car, |c| c.0);
    let lane = (uniform(seed, src.stream, k, 2) * src.lanes.len() as f64) as usize;
    (v0, class, lane.min(src.lanes.len().saturating_sub(1)))
}

/// Spawn one traffic vehicle of table `index` on `lane` at arc length `s` \[m\] with initial speed
/// `v` [m/s] and desired speed `v0` [m/s], heading for `goal` (where its lane changes may lead);
/// its [`Trip`] departs now.
#[allow(clippy::too_many_arguments)]
pub fn spawn_traffic_vehicle(
    world: &mut World,
    src: &TrafficSource,
    index: usize,
    id: VehicleId,
    lane: &TrafficLane,
    goal: &RouteGoal,
    s: f64,
    v: f64,
    v0: f64,
    class: VehicleClass,
) -> Result<(), WorldError> {
    let now = world.get_resource::<SimClock>().map_or(0.0, |c| c.now.as_secs());
    let (p, heading) = lane.path.sample(s);
    let state = VehicleState::new(p, heading, v);
    let mut spec = VehicleSpec::new(id, state);
    spec.class = class;
    spec.size = src.size(class);
    spec.model = src.model;
    spec.sensors = src.sensors;
    spec.sensor_errors = src.sensor_errors;
    spec.route = Some(Arc::clone(&lane.path));
    let entity = spawn_vehicle(world, spec)?;
    let smart = match src.controller {
        Some(SmartController::Idm(p)) => SmartController::Idm(Idm { speed: v0, ..p }),
        Some(SmartController::Acc(a)) => SmartController::Acc(AccSetup { speed: v0, ..a }),
        Some(SmartController::Cruise(c)) => SmartController::Cruise(CruiseSetup { speed: v0, ..c }),
        Some(other @ (SmartController::Platoon(_) | SmartController::Gcdc(_))) => other,
        None => SmartController::Idm(Idm { speed: v0, ..Idm::default() }),
    };
    smart.attach(world, entity);
    // Through traffic does not brake for the end of its route: it leaves the world there.
    let follow = PathFollowing { speed: v0, stop_deceleration: 50.0, ..PathFollowing::default() };
    let lane_pos = world.get_resource::<LaneMap>().map(|lanes| LanePosition::of(lanes, &state));
    let mut e = world.entity_mut(entity);
    let route_length = if lane.path.closed { lane.path.length } else { (lane.path.length - s).max(0.0) };
    e.insert((PathFollower::starting_at(follow, s), TrafficVehicle(index), Trip::new(now, route_length, v)));
    if let Some(l) = lane_pos {
        e.insert(l);
    }
    if let Some(params) = src.lane_change {
        let law = match smart {
            SmartController::Acc(a) => FollowLaw::Acc(a.acc, a.speed),
            SmartController::Idm(p) => FollowLaw::Idm(p),
            _ => FollowLaw::Idm(Idm { speed: v0.max(0.1), ..Idm::default() }),
        };
        e.insert(LaneChanger::new(params, law, goal.clone()));
    }
    if src.leader_from_lanes {
        e.insert(LeaderFromLanes);
    }
    if src.yield_to_emergency && e.world().contains_resource::<EmergencySettings>() {
        e.insert(YieldToEmergency::default());
    }
    Ok(())
}

/// Longest body of the classes a table may draw \[m\].
pub fn longest(src: &TrafficSource) -> f64 {
    src.classes.iter().map(|c| class_size(c.0).length).fold(0.0, f64::max)
}

/// Place `count` vehicles of table `index` at t = 0: round-robin over its lanes, one after the
/// other along each (a random phase per lane) with equal bumper-to-bumper gaps, each at a speed
/// it can stop from in the gap ahead. `Err` says how many fit.
pub fn place(world: &mut World, traffic: &mut Traffic, index: usize, count: usize) -> Result<(), String> {
    let seed = traffic.seed;
    let src = &mut traffic.sources[index];
    let lanes = src.lanes.len().max(1);
    let usable =
        |lane: &TrafficLane| if lane.path.closed { lane.path.length } else { (lane.path.length - 40.0).max(0.0) };
    // Draw first: lane l gets vehicles l, l + lanes, ...
    let drawn: Vec<(f64, VehicleClass)> = (0..count as u64)
        .map(|k| {
            let (v0, class, _) = draw(seed, src, src.drawn + k);
            (v0, class)
        })
        .collect();
    let mut fits = 0usize;
    let mut too_many = false;
    for (l, lane) in src.lanes.iter().enumerate() {
        let mine: Vec<f64> = drawn.iter().skip(l).step_by(lanes).map(|d| class_size(d.1).length + MIN_GAP).collect();
        let need: f64 = mine.iter().sum();
        too_many |= need > usable(lane);
        let mean = if mine.is_empty() { longest(src) + MIN_GAP } else { need / mine.len() as f64 };
        fits += (usable(lane) / mean).floor() as usize;
    }
    if too_many {
        return Err(format!(
            "{count} vehicles do not fit on the {lanes} lane(s) of this route with {MIN_GAP} m between them: about {fits} do; lower `count`, use more `lanes`, shorter `classes` or a longer route"
        ));
    }
    for (l, lane) in src.lanes.iter().enumerate() {
        let mine: Vec<(f64, VehicleClass)> = drawn.iter().skip(l).step_by(lanes).copied().collect();
        if mine.is_empty() {
            continue;
        }
        let bodies: f64 = mine.iter().map(|d| class_size(d.1).length).sum();
        let gap = (usable(lane) - bodies) / mine.len() as f64;
        let phase = uniform(seed, src.stream, u64::MAX - l as u64, 0) * (gap - MIN_GAP).max(0.0) * 0.5;
        let mut s = phase;
        for &(v0, class) in &mine {
            let half = 0.5 * class_size(class).length;
            s += half;
            let v = v0.min(((gap - MIN_GAP) / TIME_GAP).max(0.0));
            let id = VehicleId(src.next_id);
            src.next_id += src.id_step;
            spawn_traffic_vehicle(world, src, index, id, lane, &src.goal, s, v, v0, class)
                .map_err(|e| e.to_string())?;
            s += half + gap;
        }
    }
    src.drawn += count as u64;
    traffic.inserted += count as u64;
    Ok(())
}

/// The traffic systems' set in the [`Control`] schedule, before the lane changes.
#[derive(SystemSet, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct TrafficSystems;

/// Remove vehicles at the end of their route (ending their trips), then insert the arrivals
/// whose entry is free.
pub fn run_traffic(world: &mut World, mut longest: Local<Option<(Arc<LaneletMap>, f64)>>, mut due: Local<Vec<f64>>) {
    let t = world.resource::<SimClock>().now.as_secs();
    let dt = world.resource::<SimClock>().dt;
    let mut leaving: Vec<(VehicleId, Entity)> = Vec::new();
    let mut q = world.query::<(
        Entity,
        &VehicleId,
        &Route,
        &PathFollower,
        &TrafficVehicle,
        Option<&LaneChanger>,
        Option<&Trip>,
        &VehicleState,
    )>();
    let random: Vec<bool> = world.resource::<Traffic>().sources.iter().map(|s| s.random.is_some()).collect();
    let renew: Vec<bool> = world.resource::<Traffic>().sources.iter().map(|s| s.renew).collect();
    let map = world.get_resource::<LaneMap>().map(|l| Arc::clone(&l.map));
    // No vehicle farther than the map's longest lanelet from its route's end is on its
    // destination lanelet: found without reading the route's lanelets, the map's id index and
    // the lanelet (three dependent cache misses a vehicle: a tenth of a 10,000-vehicle town's
    // time on one thread, serial). Kept while the map is the same.
    let longest = map.as_ref().map(|map| match &*longest {
        Some((seen, length)) if Arc::ptr_eq(seen, map) => *length,
        _ => {
            let length = map.lanelets.iter().fold(0.0, |m: f64, l| m.max(l.length));
            *longest = Some((Arc::clone(map), length));
            length
        }
    });
    let mut renewing: Vec<(VehicleId, Entity, usize)> = Vec::new();
    let mut next_begins: Vec<(VehicleId, Entity)> = Vec::new();
    // A vehicle a few places on: its route's fields (its own, behind an `Arc`: a cache miss
    // each in a town, on one thread) fetched while this one is looked at.
    q.update_archetypes(world);
    let mut ahead = q.iter_manual(world).skip(PREFETCH_AHEAD);
    for (entity, id, route, follower, table, changer, trip, state) in q.iter_manual(world) {
        if let Some((_, _, route, ..)) = ahead.next() {
            crate::world::prefetch_value(&*route.0);
        }
        // A lane that ends holds a vehicle back for its change, except on a random trip, whose
        // route ends at its destination (it has arrived, with or without a lane beside it). So
        // does an aborted change (its route is the old lane's again); a change under way is
        // already on the new lane's route, which leads to the destination: at its end the
        // vehicle has arrived (held there, it stood past the end of the road for good:
        // opendrive_merge.toml, a change started in the last metres of road 0).
        let trip_table = random.get(table.0).copied().unwrap_or(false);
        let mandatory = changer
            .is_some_and(|c| (c.lane_end.is_some() && !trip_table) || c.active.as_ref().is_some_and(|m| m.aborted));
        if route.0.closed || mandatory {
            continue;
        }
        let remaining = route.0.length - follower.s;
        if !renew.get(table.0).copied().unwrap_or(false) {
            // Leaves now when this step would carry it past the leaving point: at a coarse step
            // (SUMO's 1 s, 14 m a step) it stood a step past the end of its road otherwise,
            // off every lane, halting in the env's counts (SUMO removes it within the step).
            if remaining < LEAVE_AT + state.speed() * dt {
                leaving.push((*id, entity));
            }
            continue;
        }
        // A town's vehicle draws its next trip as it enters its destination lanelet, so that
        // its route runs on past the trip's end while it can still stop for what lies there (a
        // trip ending at a stop line at speed ran the red when its next trip began at the
        // line); its trip ends, and the next begins, at the old route's end. (Not a lane
        // changer: a change would swap its route for a lane's before the trip's end.)
        let ends_at = trip.and_then(|t| t.ends_at).filter(|&end| end < route.0.length);
        match ends_at {
            Some(end) if end - follower.s < LEAVE_AT => next_begins.push((*id, entity)),
            Some(_) => {}
            None if remaining < LEAVE_AT => renewing.push((*id, entity, table.0)),
            None if changer.is_none()
                && trip.is_some_and(|t| t.ends_at.is_none())
                && longest.is_some_and(|l| remaining <= l)
                && on_destination(map.as_deref(), route, remaining) =>
            {
                renewing.push((*id, entity, table.0))
            }
            None => {}
        }
    }
    renewing.sort();
    for (id, entity, table) in renewing {
        renew_trip(world, id, entity, table, t);
    }
    next_begins.sort();
    for (id, entity) in next_begins {
        begin_next_trip(world, id, entity, t);
    }
    leaving.sort();
    world.resource_scope(|world, mut traffic: Mut<Traffic>| {
        for (id, entity) in leaving {
            end_trip(world, id, entity, t);
            remember_departure(world, &mut traffic, id, entity);
            if despawn_vehicle(world, id).is_ok() {
                traffic.removed += 1;
            }
        }
        let seed = traffic.seed;
        let Traffic { sources, inserted, waiting_max, .. } = &mut *traffic;
        // One vehicle per entry lanelet and tick, over all tables: the lane index does not show
        // this tick's insertions yet (two tables starting on one lanelet would insert on top of
        // each other).
        let mut used: Vec<u32> = Vec::new();
        // When each table next has a vehicle to insert \[s\] (-inf: now, or may have; only this
        // system changes a table's queue and times during a run): a tick looks only at those
        // due, in one pass over a compact list. A SUMO demand file is a table a route, 12,858 on
        // the 20 x 20 grid: reading every table every tick was a cache miss each, on one thread.
        if due.len() != sources.len() {
            *due = vec![f64::NEG_INFINITY; sources.len()];
        }
        for (index, src) in sources.iter_mut().enumerate() {
            if due[index] > t {
                continue;
            }
            if src.random.is_some() {
                *inserted += insert_random(world, seed, index, src, t, dt, &mut used);
                *waiting_max = (*waiting_max).max(src.queue);
                continue;
            }
            while src.schedule.get(src.scheduled).is_some_and(|&d| d <= t) {
                src.scheduled += 1;
                src.queue += 1;
            }
            if src.rate_per_s > 0.0 {
                while src.next_time <= t && src.next_time <= src.until {
                    src.queue += 1;
                    let u = uniform(seed, src.stream, src.drawn + src.queue, 3);
                    src.next_time += -(1.0 - u).ln() / src.rate_per_s;
                }
            }
            while src.queue > 0 {
                let k = src.drawn;
                let (v0, class, first) = draw(seed, src, k);
                let length = src.size(class).length;
                let mut placed = false;
                for n in 0..src.lanes.len() {
                    let l = (first + n) % src.lanes.len();
                    if used.contains(&src.lanes[l].lanelet) {
                        continue;
                    }
                    let lane = src.lanes[l].clone();
                    // Checked at the speed it enters with (SUMO's `departSpeed`, 0 by default):
                    // a vehicle coming through the junction behind leaves room for one entering
                    // at 13.9 m/s, not for one entering standing (issue 54: turners drove into
                    // vehicles inserted standing at the start of their exit lane).
                    let entering = src.depart_speed.map_or(v0, |d| v0.min(d));
                    let Some(v) = entry_speed(world, &lane, entering, length, dt) else { continue };
                    let id = VehicleId(src.next_id);
                    if spawn_traffic_vehicle(world, src, index, id, &lane, &src.goal, 0.0, v, v0, class).is_ok() {
                        src.next_id += src.id_step;
                        src.drawn += 1;
                        src.queue -= 1;
                        *inserted += 1;
                        used.push(lane.lanelet);
                        placed = true;
                    }
                    break;
                }
                if !placed {
                    break;
                }
            }
            *waiting_max = (*waiting_max).max(src.queue);
            due[index] = if src.queue > 0 {
                f64::NEG_INFINITY
            } else {
                let scheduled = src.schedule.get(src.scheduled).copied().unwrap_or(f64::INFINITY);
                let drawn =
                    if src.rate_per_s > 0.0 && src.next_time <= src.until { src.next_time } else { f64::INFINITY };
                scheduled.min(drawn)
            };
        }
    });
}

/// Whether a vehicle `remaining` \[m\] before the end of `route` is on the route's last
/// lanelet (its destination).
fn on_destination(map: Option<&LaneletMap>, route: &Route, remaining: f64) -> bool {
    let (Some(map), Some(&last)) = (map, route.0.lanelets.last()) else { return false };
    map.lanelet_index(last).is_some_and(|i| remaining <= map.lanelets[i].length)
}

/// A vehicle of random table `table` on its destination lanelet: it drives on along a new random
/// trip drawn from there (the table's next vehicle index, so the draws stay counter-based). Drawn
/// on entering the lanelet, the trip goes on as it was and ends at the old route's end (its
/// [`Trip::ends_at`] on the new route; [`begin_next_trip`] starts the next there); drawn at the
/// end, the trip ends now (trips.csv). At the end, a vehicle for which none is found is removed
/// like any arrival; before it, it drives on to the end and tries once more there.
fn renew_trip(world: &mut World, id: VehicleId, entity: Entity, table: usize, t: f64) {
    let (Some(route), Some(follower)) = (world.get::<Route>(entity), world.get::<PathFollower>(entity).copied()) else {
        return;
    };
    let old = Arc::clone(&route.0);
    let remaining = old.length - follower.s;
    let at_end = remaining < LEAVE_AT;
    if at_end {
        end_trip(world, id, entity, t);
    }
    let (seed, stream, k, trips) = {
        let mut traffic = world.resource_mut::<Traffic>();
        let seed = traffic.seed;
        let src = &mut traffic.sources[table];
        let k = src.drawn;
        src.drawn += 1;
        (seed, src.stream, k, src.random.clone())
    };
    let (Some(trips), Some(map)) = (trips, world.get_resource::<LaneMap>().map(|l| Arc::clone(&l.map))) else { return };
    let Some(&last) = old.lanelets.last() else { return };
    let Some(trip) = trips.trip_from(&map, last, seed, stream, k) else {
        if !at_end {
            if let Some(mut trip) = world.get_mut::<Trip>(entity) {
                trip.ends_at = Some(old.length);
            }
            return;
        }
        world.resource_scope(|world, mut traffic: Mut<Traffic>| remember_departure(world, &mut traffic, id, entity));
        if despawn_vehicle(world, id).is_ok() {
            world.resource_mut::<Traffic>().removed += 1;
        }
        return;
    };
    // Where the vehicle is on the new route: as far before its first lanelet's end as it was
    // before the old route's end.
    let first_len = map.lanelet_index(last).map_or(0.0, |i| map.lanelets[i].length);
    let s = (first_len - remaining).clamp(0.0, trip.path.length);
    let speed = world.get::<VehicleState>(entity).map_or(0.0, VehicleState::speed);
    let length = trip.path.length - s;
    let mut e = world.entity_mut(entity);
    e.insert((Route(trip.path), PathFollower::starting_at(follower.params, s)));
    if at_end {
        e.insert(Trip::new(t, length, speed));
        world.resource_mut::<Traffic>().removed += 1;
    } else if let Some(mut trip) = e.get_mut::<Trip>() {
        trip.ends_at = Some(s + remaining);
    }
}

/// A vehicle at the end of a trip whose next was drawn before it ([`renew_trip`]): the trip
/// ends (trips.csv) and the next, already on its route, departs now.
fn begin_next_trip(world: &mut World, id: VehicleId, entity: Entity, t: f64) {
    end_trip(world, id, entity, t);
    let (Some(route), Some(follower)) = (world.get::<Route>(entity), world.get::<PathFollower>(entity)) else {
        return;
    };
    let length = route.0.length - follower.s;
    let speed = world.get::<VehicleState>(entity).map_or(0.0, VehicleState::speed);
    world.entity_mut(entity).insert(Trip::new(t, length, speed));
    world.resource_mut::<Traffic>().removed += 1;
}

/// Where the lane changes of a vehicle on a trip to `destination` may lead: lanes that reach
/// the end of that lanelet (the last node of its right bound).
fn trip_goal(map: &LaneletMap, destination: LaneletId) -> RouteGoal {
    map.lanelet_index(destination)
        .and_then(|i| map.lanelets[i].right_nodes.last().copied())
        .map_or(RouteGoal::Loop, |node| RouteGoal::To(Place::Node(node)))
}

/// The lane a random trip enters on: the start of its origin lanelet.
fn trip_lane(map: &LaneletMap, trip: &RandomTrip) -> Option<TrafficLane> {
    let lanelet = map.lanelet_index(trip.origin)? as u32;
    Some(TrafficLane { lanelet, entry_s: 0.0, path: Arc::clone(&trip.path) })
}

/// The arrivals of random table `index` (`src`) up to `t` [s]: each draws its trip and waits at
/// the start of its origin lanelet; every waiting vehicle whose entry is free enters (one per
/// origin lanelet and tick: the lane index does not show this tick's insertions yet), the others
/// keep waiting without holding anyone up (`dt`: the control step [s]). Returns how many entered.
fn insert_random(
    world: &mut World,
    seed: u64,
    index: usize,
    src: &mut TrafficSource,
    t: f64,
    dt: f64,
    used: &mut Vec<u32>,
) -> u64 {
    let (Some(trips), Some(map)) = (src.random.clone(), world.get_resource::<LaneMap>().map(|l| Arc::clone(&l.map)))
    else {
        return 0;
    };
    if src.rate_per_s > 0.0 {
        while src.next_time <= t && src.next_time <= src.until {
            let k = src.drawn;
            src.drawn += 1;
            src.next_time += -(1.0 - uniform(seed, src.stream, k, 3)).ln() / src.rate_per_s;
            match trips.trip(&map, seed, src.stream, k) {
                Some(trip) => src.pending.push((k, trip)),
                None => tracing::warn!(
                    "traffic[{index}]: vehicle {k} found no route of at least {} m in {} random origin and destination pairs; skipped",
                    super::random_trips::MIN_TRIP_M,
                    super::random_trips::TRIES
                ),
            }
        }
    }
    let mut pending = std::mem::take(&mut src.pending);
    let mut entered = 0;
    pending.retain(|(k, trip)| {
        let Some(lane) = trip_lane(&map, trip) else { return false };
        if used.contains(&lane.lanelet) {
            return true;
        }
        let (v0, class, _) = draw(seed, src, *k);
        let Some(v) = entry_speed(world, &lane, v0, class_size(class).length, dt) else { return true };
        let goal = trip_goal(&map, trip.destination);
        let id = VehicleId(src.next_id);
        if spawn_traffic_vehicle(world, src, index, id, &lane, &goal, 0.0, v, v0, class).is_err() {
            return true;
        }
        src.next_id += src.id_step;
        entered += 1;
        used.push(lane.lanelet);
        false
    });
    src.pending = pending;
    src.queue = src.pending.len() as u64;
    entered
}

/// Place `count` vehicles of random table `index` at t = 0: each on its own random trip at a
/// random point of its origin lanelet, at least `MIN_GAP` + 2 m (bumper to bumper, in a
/// straight line) from every other, at a speed it can stop from in the distance to the nearest
/// (`TIME_GAP`). `Err` says how many fit.
pub fn place_random(world: &mut World, traffic: &mut Traffic, index: usize, count: usize) -> Result<(), String> {
    let seed = traffic.seed;
    let src = &mut traffic.sources[index];
    let (Some(trips), Some(map)) = (src.random.clone(), world.get_resource::<LaneMap>().map(|l| Arc::clone(&l.map)))
    else {
        return Err("random routes need a map".into());
    };
    // (trip, lane, s [m], position [m], half length [m], desired speed [m/s], class)
    let mut chosen: Vec<(RandomTrip, TrafficLane, f64, DVec2, f64, f64, VehicleClass)> = Vec::with_capacity(count);
    // The map is full when this many draws in a row find no room.
    const MISSES: u64 = 500;
    let mut misses = 0;
    let mut k = src.drawn;
    // Draw k's trip depends on k alone: routed in batches over the cores (rayon), then taken in
    // order of k as one at a time would (10,000 trips on a 20 x 20 town were most of its
    // set-up); a batch's trips past the last one placed are dropped.
    let mut batch: std::collections::VecDeque<Option<(RandomTrip, TrafficLane)>> = Default::default();
    while chosen.len() < count {
        if batch.is_empty() {
            use rayon::prelude::*;
            let size = (count - chosen.len()).clamp(16, 1024) as u64;
            let (stream, map) = (src.stream, &map);
            batch = (k..k + size)
                .into_par_iter()
                .map(|k| trips.trip(map, seed, stream, k).and_then(|t| trip_lane(map, &t).map(|l| (t, l))))
                .collect::<Vec<_>>()
                .into();
        }
        let drawn = batch.pop_front().flatten();
        if misses >= MISSES {
            return Err(format!(
                "{count} random vehicles do not fit on the map with {MIN_GAP} m + 2 m between them: {} did before {MISSES} draws in a row found no room; lower `count`",
                chosen.len()
            ));
        }
        misses += 1;
        let Some((trip, lane)) = drawn else {
            k += 1;
            continue;
        };
        let (v0, class, _) = draw(seed, src, k);
        let half = 0.5 * class_size(class).length;
        let room = trips.start_room(lane.lanelet as usize, map.lanelets[lane.lanelet as usize].length);
        let first = room.min(trip.path.length);
        let s = if first > 2.0 * half {
            half + uniform(seed, src.stream, k, 4) * (first - 2.0 * half)
        } else {
            0.5 * first
        };
        let (p, _) = trip.path.sample(s);
        k += 1;
        if chosen.iter().all(|c| p.distance(c.3) >= half + c.4 + MIN_GAP + 2.0) {
            chosen.push((trip, lane, s, p, half, v0, class));
            misses = 0;
        }
    }
    for (n, (trip, lane, s, p, half, v0, class)) in chosen.iter().enumerate() {
        let nearest = chosen
            .iter()
            .enumerate()
            .filter(|(m, _)| *m != n)
            .map(|(_, c)| p.distance(c.3) - half - c.4)
            .fold(f64::INFINITY, f64::min);
        let v = v0.min(((nearest - MIN_GAP) / TIME_GAP).max(0.0));
        let id = VehicleId(src.next_id);
        src.next_id += src.id_step;
        let goal = trip_goal(&map, trip.destination);
        spawn_traffic_vehicle(world, src, index, id, lane, &goal, *s, v, *v0, *class).map_err(|e| e.to_string())?;
    }
    src.drawn = k;
    traffic.inserted += count as u64;
    Ok(())
}

/// Braking an inserted vehicle is assumed to manage [m/s²] (SUMO's default `decel` of a
/// passenger car, what its insertion assumes).
const ENTRY_DECEL: f64 = 4.5;
/// Acceleration [m/s²] an inserted vehicle may reach in its first step, before its sensors see
/// anyone: above SUMO's default `accel` (2.6) and our controllers' defaults.
const STEP_ACCEL: f64 = 3.0;

/// Distance \[m\] a vehicle at `v` [m/s] when the lane index was built covers at least until
/// it stands, braking as hard as the IDM does ([`IDM_MAX_BRAKING`]) from then on in steps of
/// `dt` \[s\] (each step's speed held over it; the continuous `v² / 2b` for `dt <= 0`).
fn least_stopping_distance(v: f64, dt: f64) -> f64 {
    if v <= 0.0 {
        return 0.0;
    }
    if dt <= 0.0 {
        return v * v / (2.0 * IDM_MAX_BRAKING);
    }
    let b = IDM_MAX_BRAKING * dt;
    // Speeds v − b, v − 2b, … while positive, each held for dt.
    let n = (v / b).ceil() - 1.0;
    (n * v - b * n * (n + 1.0) / 2.0).max(0.0) * dt
}

/// The speed [m/s] a vehicle of `length` [m] wanting `v0` [m/s] may enter `lane` at, or `None`
/// when the entry is blocked (by the vehicles of the last lane index), with control steps of
/// `dt` \[s\].
///
/// The index is a step old and the new vehicle sees nobody until its sensors run next step, so
/// it drives its first step blind (accelerating on a free road): at a coarse step (SUMO's 1 s)
/// the leader's speed in the index (it may have braked since, by up to [`IDM_MAX_BRAKING`]) and
/// a whole step's travel count. The entry speed is bounded so that the speed of that blind step
/// (the entry speed plus up to [`STEP_ACCEL`] · dt) is one the vehicle can still stop from
/// behind where that leader stops at the latest ([`safe_stop_speed`] at [`ENTRY_DECEL`]), and a
/// vehicle coming from behind must have room for the step it drives before it sees the new one. (A vehicle entered
/// at 13.9 m/s 8.9 m behind a leader the index showed at 13.9 m/s that had braked to 4.9 m/s:
/// it drove onto it.) At 20 Hz both bounds are far from binding.
fn entry_speed(world: &World, lane: &TrafficLane, v0: f64, length: f64, dt: f64) -> Option<f64> {
    let (Some(lanes), Some(index)) = (world.get_resource::<LaneMap>(), world.get_resource::<LaneIndex>()) else {
        return Some(v0);
    };
    let nobody = VehicleId(i32::MIN);
    let mut v = v0;
    if let Some(a) = index.ahead(lanes, lane.lanelet, lane.entry_s, nobody) {
        let gap = a.distance - 0.5 * (a.length + length);
        if gap < MIN_GAP + 2.0 {
            return None;
        }
        v = v.min(((gap - MIN_GAP) / TIME_GAP).max(a.speed));
        // Its blind first step may also accelerate (up to STEP_ACCEL): that step's speed must
        // be one it can stop from.
        let room = gap - MIN_GAP + least_stopping_distance(a.speed, dt);
        let blind = safe_stop_speed(room, ENTRY_DECEL, dt) - STEP_ACCEL * dt;
        if blind < 0.0 {
            return None;
        }
        v = v.min(blind);
    }
    let reaction = 0.5f64.max(dt);
    let blocks = |b: Found, v: f64| {
        let gap = b.distance - 0.5 * (b.length + length);
        gap < MIN_GAP + TIME_GAP * (b.speed - v).max(0.0) + reaction * b.speed + STEP_ACCEL * dt * dt
    };
    let own = index.behind(lanes, lane.lanelet, lane.entry_s, nobody);
    if own.is_some_and(|b| blocks(b, v)) {
        return None;
    }
    // Behind the entry on every lanelet leading into it, not only the first: at a junction's
    // exit, the vehicles turning in from each arm.
    if own.is_none_or(|b| b.distance > lane.entry_s) {
        // Positions may lie a little past a lanelet's end (the index keeps them there): look
        // from 1 m beyond it.
        for &p in &lanes.predecessors[lane.lanelet as usize] {
            let found = index.behind(lanes, p, lanes.length(p) + 1.0, nobody);
            if found.is_some_and(|b| blocks(Found { distance: b.distance - 1.0 + lane.entry_s, ..b }, v)) {
                return None;
            }
            // One on a sibling's first metres, which lie on this lane (lanes that part start as
            // one, and the index may show a vehicle on either: a straight link's vehicles on
            // the U-turn drawn over its start), is on its way here too.
            for &(k, overlap) in lanes.siblings(p) {
                let coming = index.on(k).iter().take_while(|e| e.s < overlap).any(|e| {
                    let b = Found {
                        distance: lanes.length(p) - e.s + lane.entry_s,
                        speed: e.speed,
                        length: e.length,
                        id: e.id,
                    };
                    blocks(b, v)
                });
                if coming {
                    return None;
                }
            }
        }
    }
    // Lanes that pass over the start where the vehicle enters (a U-turn drawn wide round a
    // junction sweeps over an exit's start on its far side): nobody enters where one of their
    // vehicles is passing or about to pass. Only at a lane's start, where SUMO departures and
    // random trips enter (an entry along a lane is away from junctions).
    if lane.entry_s == 0.0 {
        for &(k, s_k) in lanes.crossing_start(lane.lanelet) {
            let coming = index.on(k).iter().take_while(|e| e.s < s_k + 0.5 * e.length + MIN_GAP).any(|e| {
                let b = Found { distance: s_k - e.s, speed: e.speed, length: e.length, id: e.id };
                b.distance < 0.5 * e.length + MIN_GAP || blocks(b, v)
            });
            if coming {
                return None;
            }
        }
    }
    Some(v.max(0.0))
}

/// Background traffic: the [`Traffic`] resource and [`run_traffic`] each control tick.
#[derive(Debug, Clone, Copy, Default)]
pub struct TrafficPlugin;

impl Plugin for TrafficPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.world_mut().init_resource::<Traffic>();
        sim.configure_sets(
            Control,
            TrafficSystems.in_set(SimSystems::Control).before(LaneChangeSystems).before(super::trips::TripsSystems),
        );
        sim.add_systems(Control, run_traffic.in_set(TrafficSystems));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A vehicle on a junction link that the lane index shows on a sibling of it (lanes that
    /// part start as one: the one placed first is as good there, and a SUMO turnaround we draw
    /// runs on a straight link's first 10 m) is still behind the exit of that link: nobody
    /// enters the exit's start in front of it. On issue 54's 20x20 grid 19 of the 30 collisions
    /// came within 3 s of an insertion at an exit's start; with this check 14 of 23 (the rest:
    /// U-turners whose loop sweeps over an exit's start on the far side).
    #[test]
    fn nobody_enters_a_junction_exit_in_front_of_one_coming_on_a_sibling_of_its_link() {
        use crate::sim::parallel::Parallelism;
        use crate::vehicles::lane_state::IndexEntry;
        let xml = crate::map::generate::intersection(&crate::map::generate::IntersectionParams::default()).unwrap();
        let map = Arc::new(LaneletMap::parse_str(&xml, std::path::Path::new("intersection")).unwrap());
        let lanes = LaneMap::new(Arc::clone(&map));
        let n = map.lanelets.len();
        // A link with a sibling that lies on it for a few metres, and the exit after it.
        let (link, sibling, overlap) = (0..n as u32)
            .find_map(|i| lanes.siblings(i).iter().find(|&&(_, o)| o > 2.0).map(|&(k, o)| (i, k, o)))
            .expect("the generated intersection has turns that part from one lane");
        let exit = lanes.successors[link as usize][0];
        let lane = TrafficLane {
            lanelet: exit,
            entry_s: 0.0,
            path: Arc::new(Path::from_points(vec![lanes.id(exit)], lanes.centres[exit as usize].points.clone(), false)),
        };
        let mut world = World::new();
        world.insert_resource(lanes);
        // The lane index holding one vehicle on lanelet `on` (none: empty), and the entry then.
        let mut entry = |on: Option<u32>| {
            let mut index = LaneIndex::default();
            let coming =
                on.map(|i| IndexEntry { lanelet: i, s: 0.5 * overlap, speed: 13.9, length: 4.5, id: VehicleId(7) });
            index.rebuild(Parallelism::single(), n, &coming.into_iter().collect::<Vec<_>>());
            world.insert_resource(index);
            entry_speed(&world, &lane, 0.0, 4.5, 0.05)
        };
        assert_eq!(entry(None), Some(0.0), "a free exit");
        assert_eq!(entry(Some(exit)), None, "one standing at the start of the exit");
        assert_eq!(entry(Some(link)), None, "one coming on the link itself");
        assert_eq!(entry(Some(sibling)), None, "one coming on the link, located on its sibling");
    }

    /// Lanelet -20, 100 m east from x = 0, and lanelet -21, 60 m north along x = 0 over -20's
    /// start (both 3.5 m wide; -21's centre line passes -20's start point 31.75 m along it).
    const OVER_A_START: &str = r#"<?xml version='1.0' encoding='UTF-8'?>
<osm version='0.6' generator='JOSM'>
  <node id='-1' lat='59.0' lon='17.0' />
  <node id='-2' lat='59.0' lon='17.001744' />
  <node id='-3' lat='59.0000315' lon='17.0' />
  <node id='-4' lat='59.0000315' lon='17.001744' />
  <node id='-5' lat='58.99973' lon='17.0000305' />
  <node id='-6' lat='59.00027' lon='17.0000305' />
  <node id='-7' lat='58.99973' lon='16.9999695' />
  <node id='-8' lat='59.00027' lon='16.9999695' />
  <way id='-10'><nd ref='-1' /><nd ref='-2' /></way>
  <way id='-11'><nd ref='-3' /><nd ref='-4' /></way>
  <way id='-12'><nd ref='-5' /><nd ref='-6' /></way>
  <way id='-13'><nd ref='-7' /><nd ref='-8' /></way>
  <relation id='-20'>
    <member type='way' ref='-10' role='right' />
    <member type='way' ref='-11' role='left' />
    <tag k='type' v='lanelet' />
  </relation>
  <relation id='-21'>
    <member type='way' ref='-12' role='right' />
    <member type='way' ref='-13' role='left' />
    <tag k='type' v='lanelet' />
  </relation>
</osm>
"#;

    /// Nobody enters a lane's start where a vehicle on a lane that passes over it (neither
    /// leading into it nor parting from it) stands or is about to pass. On issue 54's 20x20
    /// grid, exits whose start a U-turn's loop sweeps over: 12 collisions with this check, 23
    /// without. Before it, only the lane itself, those leading into it and their siblings were
    /// looked at.
    #[test]
    fn nobody_enters_a_lane_start_that_a_vehicle_on_a_lane_passing_over_it_is_on_or_about_to_pass() {
        use crate::sim::parallel::Parallelism;
        use crate::vehicles::lane_state::IndexEntry;
        let map = Arc::new(LaneletMap::parse_str(OVER_A_START, std::path::Path::new("over_a_start.osm")).unwrap());
        let lanes = LaneMap::new(Arc::clone(&map));
        let n = map.lanelets.len();
        let (a, b) =
            (map.lanelet_index(LaneletId(-20)).unwrap() as u32, map.lanelet_index(LaneletId(-21)).unwrap() as u32);
        let s_b = lanes.crossing_start(a).iter().find(|&&(k, _)| k == b).map(|&(_, s)| s);
        assert!(s_b.is_some_and(|s| (s - 31.75).abs() < 1.0), "{:?}", lanes.crossing_start(a));
        assert!(lanes.crossing_start(b).is_empty(), "-20 passes nowhere near -21's start");
        let s_b = s_b.unwrap();
        let lane = TrafficLane {
            lanelet: a,
            entry_s: 0.0,
            path: Arc::new(Path::from_points(vec![LaneletId(-20)], lanes.centres[a as usize].points.clone(), false)),
        };
        let mut world = World::new();
        world.insert_resource(lanes);
        let mut entry = |s: Option<f64>, speed: f64| {
            let mut index = LaneIndex::default();
            let on = s.map(|s| IndexEntry { lanelet: b, s, speed, length: 4.5, id: VehicleId(7) });
            index.rebuild(Parallelism::single(), n, &on.into_iter().collect::<Vec<_>>());
            world.insert_resource(index);
            entry_speed(&world, &lane, 0.0, 4.5, 0.05)
        };
        assert_eq!(entry(None, 0.0), Some(0.0), "nobody on the crossing lane");
        assert_eq!(entry(Some(s_b), 0.0), None, "one standing where the entry is");
        assert_eq!(entry(Some(s_b - 15.0), 10.0), None, "one 15 m before it at 10 m/s");
        assert_eq!(entry(Some(s_b - 25.0), 0.0), Some(0.0), "one standing 25 m before it");
        assert_eq!(entry(Some(s_b + 10.0), 10.0), Some(0.0), "one past it");
    }

    #[test]
    fn the_least_stopping_distance_is_what_braking_at_the_idm_s_limit_covers() {
        // 13.9 m/s at 1 s steps: 4.9 m/s for a step, then standing.
        assert!((least_stopping_distance(13.9, 1.0) - 4.9).abs() < 1e-9);
        assert_eq!(least_stopping_distance(9.0, 1.0), 0.0);
        assert_eq!(least_stopping_distance(0.0, 1.0), 0.0);
        // Step by step at 50 Hz, and the continuous limit.
        let (v, dt) = (13.9, 0.02);
        let mut d = 0.0;
        let mut u = v - IDM_MAX_BRAKING * dt;
        while u > 0.0 {
            d += u * dt;
            u -= IDM_MAX_BRAKING * dt;
        }
        assert!((least_stopping_distance(v, dt) - d).abs() < 1e-9);
        assert!((least_stopping_distance(v, 0.0) - v * v / 18.0).abs() < 1e-12);
    }
}
