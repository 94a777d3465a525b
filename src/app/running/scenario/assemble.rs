//! Assembly: a checked scenario into a [`SimBuilder`] (rates, seed, built-in plugins, routes,
//! vehicles with their controllers, the lab).

use std::collections::BTreeMap;
use std::sync::Arc;

use glam::DVec2;

use super::commonroad::{GoalMonitor, add_goal_monitor, spawn_obstacles};
use super::file::{
    BuiltInController, ChannelSection, ControllerConfig, ModelConfig, NodeRef, ObstaclesMode, RouteConfig,
    SensorsConfig, StartConfig, TrafficLanes, TrafficRoute, VehicleConfig,
};
use super::lab::add_lab_plugins;
use super::{Scenario, ScenarioError};
use crate::app::running::metrics::MetricsPlugin;
use crate::app::running::random_trips::RandomTrips;
use crate::app::running::traffic::{Traffic, TrafficLane, TrafficPlugin, TrafficSource, place, place_random};
use crate::app::running::trips::{Trip, TripsPlugin};
use crate::map::{LaneletId, MapError, Path, RouteOptions};
use crate::sim::{
    Control, Dynamics, Network, Sensors, SimBuilder, SimSeed, V2vConfig, V2vPlugin, Wifi, default_plugins,
};
use crate::vehicles::Side;
use crate::vehicles::lane_changing::LanePaths;
use crate::vehicles::{EmergencySettings, EmergencyVehicle, EmergencyVehiclePlugin, YieldToEmergency};
use crate::vehicles::{
    FollowLaw, Idm, LaneChangePlugin, LaneChanger, LaneMap, LanePosition, LanesPlugin, Longitudinal, PathFollower,
    PathFollowing, PathFollowingPlugin, RouteGoal, SmartController, smart_vehicles,
};
use crate::vehicles::{GcdcPlugin, Rsu};
use crate::world::{
    AccelerationUnicycle, KinematicUnicycle, Radar, SensorErrors, SensorSet, VehicleClass, VehicleId, VehicleModel,
    VehicleSize, VehicleSpec, VehicleState, Velodyne,
};

/// A start pose farther than this from its route's centre line is warned about at load time [m]
/// (half a 4 m lane: the vehicle would start beside its lane).
const START_OFF_ROUTE: f64 = 2.0;
/// The same for a start node [m]: route nodes lie on a lane's bound (the 2015 convention), half
/// a lane from the centre line, so only a node more than a lane away is off the route.
const START_NODE_OFF_ROUTE: f64 = 4.5;
/// The dynamics model of a `model` table.
fn model_of(m: ModelConfig) -> VehicleModel {
    match m {
        ModelConfig::Kinematic { wheelbase, max_steering } => {
            VehicleModel::Kinematic(KinematicUnicycle { wheelbase, max_steering })
        }
        ModelConfig::Acceleration { wheelbase, mass, drag, max_steering } => {
            VehicleModel::Acceleration(AccelerationUnicycle { wheelbase, mass, drag, max_steering })
        }
        ModelConfig::None => VehicleModel::None,
    }
}

/// The sensors of a `sensors` table.
fn sensors_of(s: &SensorsConfig) -> SensorSet {
    SensorSet {
        radar: s.radar.map(|r| Radar { angle: r.angle_deg.to_radians(), range: r.range }),
        velodyne: s.velodyne.map(|r| Velodyne { range: r.range }),
        omniscient: s.omniscient,
    }
}

/// The errors of a `sensors` table's radar and velodyne.
fn sensor_errors_of(s: &SensorsConfig) -> SensorErrors {
    SensorErrors {
        radar: s.radar.map_or_else(Default::default, |r| r.noise.with(r.dropout, r.occlusion)),
        velodyne: s.velodyne.map_or_else(Default::default, |v| v.noise.with(v.dropout, v.occlusion)),
    }
}

/// Whether vehicle `v` drives the `gcdc` controller.
fn is_gcdc(v: &VehicleConfig) -> bool {
    matches!(v.controller.as_ref().and_then(ControllerConfig::smart), Some(SmartController::Gcdc(_)))
}

/// The neighbour of lanelet `i` on `side` (whatever the line between them).
fn side_of(lanes: &LaneMap, i: u32, side: Side) -> Option<u32> {
    crate::vehicles::lane_changing::neighbour(lanes, i, side)
}

impl Scenario {
    /// A builder with the scenario's rates, seed, built-in plugins (dynamics, sensors, V2V, path
    /// following, the smart-vehicle controllers, metrics) and vehicles; add your own plugins,
    /// then `build()`. A scenario that names registered controllers needs
    /// [`Scenario::assemble`] on a builder that holds their plugins.
    pub fn builder(&self) -> Result<SimBuilder, ScenarioError> {
        let mut b = SimBuilder::new();
        self.assemble(&mut b)?;
        Ok(b)
    }

    /// Set up `b`, which may already hold plugins of the user's (and the controllers they
    /// registered): the scenario's rates and seed, the built-in plugins, the vehicles with their
    /// routes and controllers, and the lab bridges.
    pub fn assemble(&self, b: &mut SimBuilder) -> Result<(), ScenarioError> {
        let rates = self.rates();
        b.set_rate(Sensors, rates.sensors)
            .set_rate(Wifi, rates.wifi)
            .set_rate(Network, rates.network)
            .set_rate(Control, rates.control)
            .set_rate(Dynamics, rates.dynamics);
        b.insert_resource(SimSeed(self.file.seed));
        b.add_plugin(default_plugins);
        let v2v = &self.file.v2v;
        let models = b.controllers().channel_models();
        let model = |name: &str, ch: &ChannelSection| {
            ch.model(models).map_err(|(key, problem)| self.invalid(format!("v2v.{name}.{key}"), problem))
        };
        let (wifi, network) = (model("wifi", &v2v.wifi)?, model("network", &v2v.network)?);
        b.add_plugin(V2vPlugin { config: V2vConfig { wifi_range: v2v.range(), wifi, network } });
        b.add_plugin(PathFollowingPlugin);
        b.add_plugin(smart_vehicles).add_plugin(MetricsPlugin::default()).add_plugin(TripsPlugin);
        if let Some(map) = &self.map {
            b.add_plugin(LanesPlugin { map: Arc::clone(map) });
            b.add_plugin(LaneChangePlugin { points_per_meter: self.file.points_per_meter });
            b.add_plugin(self.junctions_plugin(map));
            if self.file.vehicles.iter().any(|v| v.class == VehicleClass::Emergency) {
                b.add_plugin(EmergencyVehiclePlugin { settings: self.file.emergency });
            }
            if self.file.vehicles.iter().any(is_gcdc) || !self.file.rsu.is_empty() {
                b.add_plugin(GcdcPlugin { rsus: self.rsus(map)? });
            }
        } else if !self.file.rsu.is_empty() {
            return Err(self.invalid("rsu".into(), "needs a `map` in the scenario"));
        }
        let mut routes: BTreeMap<String, Arc<Path>> = BTreeMap::new();
        for (i, v) in self.file.vehicles.iter().enumerate() {
            let key = |k: &str| format!("vehicles[{i}] (id {}).{k}", v.id);
            let route = match &v.route {
                Some(r) => {
                    let changes = v.lane_change.0.is_some() || is_gcdc(v);
                    Some(self.route(r, changes, &mut routes, &key)?)
                }
                None => None,
            };
            self.spawn(b, v, route, &key)?;
        }
        self.traffic(b, &mut routes)?;
        if let (Some(sc), Some(map)) = (&self.commonroad, &self.map) {
            let obstacles = if self.file.obstacles == Some(ObstaclesMode::Replay) {
                spawn_obstacles(b, sc).map_err(|e| self.invalid("obstacles".into(), e))?
            } else {
                0
            };
            let egos: Vec<(VehicleId, i64)> =
                self.file.vehicles.iter().filter_map(|v| Some((VehicleId(v.id), v.planning_problem?))).collect();
            if obstacles > 0 || !egos.is_empty() {
                add_goal_monitor(b, GoalMonitor::new(sc, Arc::clone(map), &egos, obstacles));
            }
        }
        if let Some(lab) = &self.file.lab {
            add_lab_plugins(b, lab, self.map.as_deref())
                .map_err(|e| self.invalid(format!("lab.{}", e.key), e.problem))?;
        }
        Ok(())
    }

    /// The roadside units of `[[rsu]]`, placed on `map` (ids from `i32::MIN` up: not vehicles).
    fn rsus(&self, map: &crate::map::LaneletMap) -> Result<Vec<Rsu>, ScenarioError> {
        let mut rsus = Vec::new();
        for (k, r) in self.file.rsu.iter().enumerate() {
            let key = format!("rsu[{k}].at");
            let position = match (&r.at.node, r.at.x.zip(r.at.y)) {
                (Some(n), _) => {
                    let ids = map.place_nodes(&n.place()).map_err(|e| ScenarioError::Route {
                        path: self.path.clone(),
                        key: key.clone(),
                        source: Box::new(e),
                    })?;
                    ids.first()
                        .and_then(|id| map.nodes.get(id))
                        .map(|n| n.position)
                        .ok_or_else(|| self.invalid(key.clone(), "names no node of the map"))?
                }
                (None, Some((x, y))) => DVec2::new(x, y),
                (None, None) => return Err(self.invalid(key, "needs either `x` and `y` [m] or `node`")),
            };
            rsus.push(Rsu { id: VehicleId(i32::MIN + k as i32), position, range: r.range, message: r.message });
        }
        Ok(rsus)
    }

    /// The path of route `r`, computed once per distinct route and shared. A vehicle that
    /// changes lanes (`lane_changes`) on a `from`/`to` route that no lane joins drives its start
    /// lane to where it ends, and its lane-change plugin makes the changes (mandatory ones, as at
    /// a lane drop) where a route with lane changes exists ([`crate::map::LaneletMap::route_to_lane_end`]).
    fn route(
        &self,
        r: &RouteConfig,
        lane_changes: bool,
        routes: &mut BTreeMap<String, Arc<Path>>,
        key: &dyn Fn(&str) -> String,
    ) -> Result<Arc<Path>, ScenarioError> {
        let map = self.map.as_ref().ok_or_else(|| self.invalid(key("route"), "needs a `map` in the scenario"))?;
        let name = format!("{r:?} {lane_changes}");
        if let Some(p) = routes.get(&name) {
            return Ok(Arc::clone(p));
        }
        let opts = RouteOptions { points_per_meter: self.file.points_per_meter };
        let route_err = |e| ScenarioError::Route { path: self.path.clone(), key: key("route"), source: Box::new(e) };
        let p = Arc::new(match (&r.closed_loop, &r.from, &r.to) {
            (Some(n), _, _) => map.closed_loop_at(&n.place(), &opts).map_err(route_err)?,
            (None, Some(a), Some(b)) if r.via.is_empty() => match map.route_places(&a.place(), &b.end_place(), &opts) {
                Err(MapError::NoRoute { .. }) if lane_changes => {
                    map.route_to_lane_end(&a.place(), &b.end_place(), &opts).map_err(route_err)?
                }
                found => found.map_err(route_err)?,
            },
            (None, Some(a), Some(b)) => {
                let stops: Vec<&NodeRef> = std::iter::once(a).chain(&r.via).chain(std::iter::once(b)).collect();
                let mut legs = Vec::with_capacity(stops.len() - 1);
                for (k, w) in stops.windows(2).enumerate() {
                    // Each leg starts where the last one ended (an OpenDRIVE lane's end).
                    let start = if k == 0 { w[0].place() } else { w[0].end_place() };
                    legs.push(map.route_places(&start, &w[1].end_place(), &opts).map_err(route_err)?);
                }
                join_legs(&legs, opts.points_per_meter)
            }
            _ => return Err(self.invalid(key("route"), "needs `loop` or both `from` and `to`")),
        });
        routes.insert(name, Arc::clone(&p));
        Ok(p)
    }

    /// Spawn vehicle `v` with its model, sensors, route and controller.
    fn spawn(
        &self,
        b: &mut SimBuilder,
        v: &VehicleConfig,
        route: Option<Arc<Path>>,
        key: &dyn Fn(&str) -> String,
    ) -> Result<(), ScenarioError> {
        let (state, along) = self.start_state(v, route.as_deref(), key)?;
        let mut spec = VehicleSpec::new(crate::world::VehicleId(v.id), state);
        spec.class = v.class;
        let d = VehicleSize::default();
        spec.size = VehicleSize { length: v.length.unwrap_or(d.length), width: v.width.unwrap_or(d.width) };
        spec.model = model_of(v.model);
        spec.sensors = sensors_of(&v.sensors);
        spec.sensor_errors = sensor_errors_of(&v.sensors);
        spec.mailbox = v.mailbox;
        let trip =
            route.as_deref().filter(|r| !r.closed).map(|r| Trip::new(0.0, (r.length - along).max(0.0), state.speed()));
        spec.route = route;
        let entity = b.spawn_vehicle(spec).map_err(|e| self.invalid(key("id"), e.to_string()))?;
        if let Some(trip) = trip {
            b.world_mut().entity_mut(entity).insert(trip);
        }
        for (name, params) in &v.sensors.plugins {
            let sensor = match b.controllers().sensors().parse(name, params.clone()) {
                Some(Ok(sensor)) => sensor,
                Some(Err(e)) => return Err(self.invalid(key(&format!("sensors.{name}.{}", e.key)), e.problem)),
                None => {
                    let known = b.controllers().sensors().known_list();
                    let problem =
                        format!("names no known sensor: `{name}` (known: {known}); add the plugin that registers it");
                    return Err(self.invalid(key(&format!("sensors.{name}")), problem));
                }
            };
            sensor.attach(&mut b.world_mut().entity_mut(entity));
        }
        match &v.controller {
            Some(ControllerConfig::BuiltIn(BuiltInController::PathFollowing {
                speed,
                lookahead_min,
                lookahead_time,
                speed_gain,
            })) => {
                let params = PathFollowing {
                    speed: *speed,
                    lookahead_min: *lookahead_min,
                    lookahead_time: *lookahead_time,
                    speed_gain: *speed_gain,
                    ..Default::default()
                };
                b.world_mut().entity_mut(entity).insert(PathFollower::starting_at(params, along));
            }
            Some(c @ ControllerConfig::BuiltIn(_)) => {
                if let Some(smart) = c.smart() {
                    smart.attach(b.world_mut(), entity);
                }
            }
            Some(ControllerConfig::Registered { name, params }) => {
                let parsed = b.controllers().parse(name, params.clone());
                let controller = match parsed {
                    Some(Ok(c)) => c,
                    Some(Err(e)) => return Err(self.invalid(key("controller"), e.problem)),
                    None => {
                        return Err(self.invalid(
                            key("controller.type"),
                            format!(
                                "names no known controller: `{name}` (known: {}); add the plugin that registers it",
                                b.controllers().known_list()
                            ),
                        ));
                    }
                };
                let speed = controller.cruise_speed().unwrap_or(PathFollowing::default().speed);
                let follower = PathFollower::starting_at(PathFollowing { speed, ..Default::default() }, along);
                let mut vehicle = b.world_mut().entity_mut(entity);
                vehicle.insert((follower, Longitudinal::default()));
                controller.attach(&mut vehicle);
            }
            None => {}
        }
        if let Some(lanes) = b.world_mut().get_resource::<LaneMap>() {
            let lane = LanePosition::of(lanes, &state);
            b.world_mut().entity_mut(entity).insert(lane);
        }
        // A gcdc vehicle changes lanes through the lane-change plugin: the defaults without a table.
        let lane_change = v.lane_change.0.or_else(|| is_gcdc(v).then(Default::default));
        if let (Some(params), Some(r)) = (lane_change, &v.route) {
            let speed =
                b.world_mut().get::<PathFollower>(entity).map_or(PathFollowing::default().speed, |f| f.params.speed);
            let law = match v.controller.as_ref().and_then(ControllerConfig::smart) {
                Some(SmartController::Idm(p)) => FollowLaw::Idm(p),
                Some(SmartController::Acc(a)) => FollowLaw::Acc(a.acc, a.speed),
                Some(SmartController::Gcdc(_)) => match b.world_mut().get::<crate::vehicles::GcdcVehicle>(entity) {
                    Some(g) => FollowLaw::Acc(g.law(), g.merge.speed.unwrap_or(speed).max(speed)),
                    None => FollowLaw::Idm(Idm { speed: speed.max(0.1), ..Idm::default() }),
                },
                _ => FollowLaw::Idm(Idm { speed: speed.max(0.1), ..Idm::default() }),
            };
            let goal = match &r.to {
                Some(to) if r.closed_loop.is_none() => RouteGoal::To(to.end_place()),
                _ => RouteGoal::Loop,
            };
            b.world_mut().entity_mut(entity).insert(LaneChanger::new(params, law, goal));
        }
        if b.world_mut().contains_resource::<EmergencySettings>() {
            if v.class == VehicleClass::Emergency {
                let desired_speed = b
                    .world_mut()
                    .get::<PathFollower>(entity)
                    .map_or(PathFollowing::default().speed, |f| f.params.speed);
                b.world_mut().entity_mut(entity).insert(EmergencyVehicle { desired_speed });
            } else if v.yield_to_emergency {
                b.world_mut().entity_mut(entity).insert(YieldToEmergency::default());
            }
        }
        Ok(())
    }

    /// Resolve the `[[traffic]]` tables and place their `count` vehicles (after the vehicles).
    fn traffic(&self, b: &mut SimBuilder, routes: &mut BTreeMap<String, Arc<Path>>) -> Result<(), ScenarioError> {
        if self.file.traffic.is_empty() && self.demand.is_none() {
            return Ok(());
        }
        let Some(lanes) = b.world_mut().get_resource::<LaneMap>().cloned() else {
            return Err(self.invalid("traffic".into(), "needs a `map` in the scenario"));
        };
        b.add_plugin(TrafficPlugin);
        let mut paths = LanePaths::new(self.file.points_per_meter);
        let mut traffic = Traffic { seed: self.file.seed, ..Traffic::default() };
        let mut ranges: Vec<(i64, i64, usize)> = Vec::new();
        // Traffic is virtual: by default its ids count down from -1000, below every vehicle's
        // id (so the default never clashes), each later table a thousand lower.
        let lowest = self.file.vehicles.iter().map(|v| i64::from(v.id)).min().unwrap_or(0);
        let mut next_default: i64 = (-1000_i64).min((lowest - 1).div_euclid(1000) * 1000);
        for (k, t) in self.file.traffic.iter().enumerate() {
            let key = |s: &str| format!("traffic[{k}].{s}");
            let mut lane_list = Vec::new();
            let mut goal = RouteGoal::Loop;
            let mut random = None;
            match &t.route {
                TrafficRoute::Random => {
                    let trips = match t.min_speed_limit {
                        None => RandomTrips::new(&lanes.map, self.file.points_per_meter),
                        Some(min) => RandomTrips::on_fast_roads(&lanes.map, self.file.points_per_meter, min),
                    };
                    if trips.is_empty() {
                        let why = match t.min_speed_limit {
                            None => "is \"random\" but the map has no drivable lanelet".to_string(),
                            Some(min) => format!(
                                "is \"random\" with `min_speed_limit = {min}` [m/s] but no drivable lanelet has a `speed_limit` tag that high"
                            ),
                        };
                        return Err(self.invalid(key("route"), why));
                    }
                    random = Some(Arc::new(trips));
                }
                TrafficRoute::Fixed(r) => {
                    goal = self.traffic_lanes(t, r, &lanes, &mut paths, routes, &mut lane_list, &key)?;
                }
            }
            let total: f64 = t.classes.values().sum();
            let mut acc = 0.0;
            let classes = t
                .classes
                .iter()
                .filter(|c| *c.1 > 0.0)
                .map(|(c, w)| {
                    acc += w / total;
                    (*c, acc)
                })
                .collect();
            let controller = t.controller.as_ref().and_then(ControllerConfig::smart);
            let duration = t.until.unwrap_or(self.file.duration).min(self.file.duration);
            let most = t.count as i64 + (t.rate * duration / 3600.0 * 3.0).ceil() as i64 + 20;
            // Ids `start`, `start + step`, ...: the range [first, last) holds every one.
            let (start, step) = t.id_start.map_or((next_default, -1), |s| (i64::from(s), 1));
            let (first, last) = if step > 0 { (start, start + most) } else { (start - most + 1, start + 1) };
            if last > i64::from(i32::MAX) || first < i64::from(i32::MIN) {
                return Err(self.invalid(key("id_start"), "leaves no room for the ids this table needs; lower it"));
            }
            if let Some(v) = self.file.vehicles.iter().find(|v| (first..last).contains(&i64::from(v.id))) {
                return Err(self.invalid(
                    key("id_start"),
                    format!(
                        "traffic ids {first}..{last} clash with vehicle id {}; set `id_start` so that the range is free (e.g. {})",
                        v.id,
                        self.file.vehicles.iter().map(|v| i64::from(v.id)).max().unwrap_or(0).max(0) + 1000
                    ),
                ));
            }
            if let Some(&(a, b2, other)) = ranges.iter().find(|(a, b2, _)| first < *b2 && *a < last) {
                return Err(self.invalid(
                    key("id_start"),
                    format!("traffic ids {first}..{last} overlap those of traffic[{other}] ({a}..{b2}); set `id_start` apart"),
                ));
            }
            ranges.push((first, last, k));
            next_default = next_default.min((first - 1).div_euclid(1000) * 1000);
            traffic.sources.push(TrafficSource {
                stream: k as u64,
                lanes: lane_list,
                goal,
                rate_per_s: t.rate / 3600.0,
                until: duration,
                speed: t.speed,
                classes,
                controller,
                lane_change: t.lane_change.0,
                model: model_of(t.model),
                sensors: sensors_of(&t.sensors),
                leader_from_lanes: false,
                sensor_errors: sensor_errors_of(&t.sensors),
                yield_to_emergency: t.yield_to_emergency,
                next_id: start as i32,
                id_step: step,
                drawn: 0,
                next_time: 0.0,
                queue: 0,
                random,
                pending: Vec::new(),
                renew: t.on_arrival == super::file::OnArrival::NewTrip,
                schedule: Vec::new(),
                scheduled: 0,
                length: None,
                depart_speed: None,
            });
            if t.count > 0 {
                let placed = if t.route == TrafficRoute::Random {
                    place_random(b.world_mut(), &mut traffic, k, t.count)
                } else {
                    place(b.world_mut(), &mut traffic, k, t.count)
                };
                placed.map_err(|e| self.invalid(key("count"), e))?;
            }
        }
        if let Some(demand) = &self.demand {
            let start = next_default;
            if let Some(v) = self.file.vehicles.iter().find(|v| i64::from(v.id) <= start) {
                return Err(self.invalid(
                    "demand".into(),
                    format!(
                        "vehicle id {} lies in the ids of the SUMO demand (from {start} down); use ids above it",
                        v.id
                    ),
                ));
            }
            sumo_demand(demand, &lanes.map, &mut traffic, start, self.file.points_per_meter);
        }
        b.insert_resource(traffic);
        Ok(())
    }

    /// The start lanes of traffic table `t` on the fixed route `r` (into `lanes_out`), and where
    /// its vehicles head for.
    #[allow(clippy::too_many_arguments)]
    fn traffic_lanes(
        &self,
        t: &super::file::TrafficConfig,
        r: &RouteConfig,
        lanes: &LaneMap,
        paths: &mut LanePaths,
        routes: &mut BTreeMap<String, Arc<Path>>,
        lanes_out: &mut Vec<TrafficLane>,
        key: &dyn Fn(&str) -> String,
    ) -> Result<RouteGoal, ScenarioError> {
        let changes = t.lane_change.0.is_some();
        let route = self.route(r, changes, routes, key)?;
        let goal = match (&r.closed_loop, &r.to) {
            (None, Some(to)) => RouteGoal::To(to.end_place()),
            _ => RouteGoal::Loop,
        };
        let locate = |p: &Path| lanes.locate(p.points[0], None, 0.0).map(|(i, s, _)| (i, s));
        let Some((start, start_s)) = locate(&route) else {
            return Err(self.invalid(key("route"), "starts off every lanelet of the map"));
        };
        match &t.lanes {
            TrafficLanes::All => {
                lanes_out.push(TrafficLane { lanelet: start, entry_s: start_s, path: Arc::clone(&route) });
                for side in [Side::Left, Side::Right] {
                    let mut i = start;
                    while let Some(j) = side_of(lanes, i, side) {
                        if lanes_out.iter().any(|l| l.lanelet == j) {
                            break;
                        }
                        let path = paths.path(lanes, j, &goal).ok_or_else(|| {
                            self.invalid(key("lanes"), "a lane beside the route's has no path to drive")
                        })?;
                        lanes_out.push(TrafficLane { lanelet: j, entry_s: 0.0, path });
                        i = j;
                    }
                }
            }
            TrafficLanes::Tags(tags) => {
                for tag in tags {
                    let lane_route = match &r.closed_loop {
                        Some(_) => {
                            RouteConfig { closed_loop: Some(tag.clone()), from: None, to: None, via: Vec::new() }
                        }
                        None => RouteConfig {
                            closed_loop: None,
                            from: Some(tag.clone()),
                            to: r.to.clone(),
                            via: r.via.clone(),
                        },
                    };
                    let path = self.route(&lane_route, changes, routes, &|_| key("lanes"))?;
                    let Some((i, s)) = locate(&path) else {
                        return Err(self.invalid(key("lanes"), "a lane starts off every lanelet of the map"));
                    };
                    lanes_out.push(TrafficLane { lanelet: i, entry_s: s, path });
                }
            }
        }
        Ok(goal)
    }

    /// Project vehicle `v`'s start point `p` on its route `r`, warning at load time when it lies
    /// more than `limit` [m] from the route's centre line (the vehicle would start beside its
    /// lane, or somewhere else than at its node).
    fn project_start(
        &self,
        v: &VehicleConfig,
        r: &Path,
        p: DVec2,
        what: &str,
        limit: f64,
    ) -> crate::map::PathProjection {
        let projection = r.project(p);
        if projection.lateral.abs() > limit {
            tracing::warn!(
                "{}: vehicle {}: {what} lies {:.1} m off its route (nearest route point ({:.1}, {:.1}) m); check `start` and `route`",
                self.path.display(),
                v.id,
                projection.lateral.abs(),
                projection.point.x,
                projection.point.y
            );
        }
        projection
    }

    fn start_state(
        &self,
        v: &VehicleConfig,
        route: Option<&Path>,
        key: &dyn Fn(&str) -> String,
    ) -> Result<(VehicleState, f64), ScenarioError> {
        let problem = v.planning_problem.and_then(|id| {
            self.commonroad.as_ref()?.planning_problems.iter().find(|p| p.id == id).map(|p| p.initial_state)
        });
        if let Some(s) = problem {
            let along = route.map_or(0.0, |r| {
                self.project_start(v, r, s.position, "its planning problem's initial state", START_OFF_ROUTE).s
            });
            return Ok((VehicleState::new(s.position, s.orientation, s.velocity), along));
        }
        let start = v.start.clone().unwrap_or(StartConfig { at: None, offset: None, x: None, y: None, yaw: None });
        let node_position = |n: &NodeRef| -> Result<DVec2, ScenarioError> {
            let map =
                self.map.as_ref().ok_or_else(|| self.invalid(key("start.at"), "needs a `map` in the scenario"))?;
            let ids = map.place_nodes(&n.place()).map_err(|e| ScenarioError::Route {
                path: self.path.clone(),
                key: key("start.at"),
                source: Box::new(e),
            })?;
            ids.first()
                .and_then(|id| map.nodes.get(id))
                .map(|n| n.position)
                .ok_or_else(|| self.invalid(key("start.at"), "names no node of the map"))
        };
        let (position, yaw, along) = match (route, &start.at, start.x.zip(start.y)) {
            (_, None, Some(p)) => {
                let p = DVec2::new(p.0, p.1);
                let (heading, along) = route.map_or((0.0, 0.0), |r| {
                    let projection = self.project_start(v, r, p, "its start `x`, `y`", START_OFF_ROUTE);
                    (projection.heading, projection.s)
                });
                (p, start.yaw.unwrap_or(heading), along)
            }
            (Some(r), at, None) => {
                let base = match at {
                    Some(n) => {
                        let what = format!("its start node `{}`", n.place());
                        self.project_start(v, r, node_position(n)?, &what, START_NODE_OFF_ROUTE).s
                    }
                    None => 0.0,
                };
                let along = base + start.offset.unwrap_or(0.0);
                let (p, heading) = r.sample(along);
                let along = if r.closed { along.rem_euclid(r.length) } else { along.clamp(0.0, r.length) };
                (p, start.yaw.unwrap_or(heading), along)
            }
            (None, Some(n), None) => (node_position(n)?, start.yaw.unwrap_or(0.0), 0.0),
            (None, None, None) => (DVec2::ZERO, start.yaw.unwrap_or(0.0), 0.0),
            (_, Some(_), Some(_)) => return Err(self.invalid(key("start"), "takes either `at` or `x`/`y`, not both")),
        };
        Ok((VehicleState::new(position, yaw, v.speed), along))
    }
}

/// One path through the legs of a route with `via` places, each leg starting where the last
/// ended, resampled at `points_per_meter` [points per metre] (a path's points are equally spaced).
fn join_legs(legs: &[Path], points_per_meter: f64) -> Path {
    let mut points: Vec<DVec2> = Vec::new();
    let mut lanelets: Vec<LaneletId> = Vec::new();
    for leg in legs {
        let skip = usize::from(points.last().zip(leg.points.first()).is_some_and(|(p, q)| p.distance(*q) < 1e-6));
        points.extend_from_slice(&leg.points[skip.min(leg.points.len())..]);
        for &l in &leg.lanelets {
            if lanelets.last() != Some(&l) {
                lanelets.push(l);
            }
        }
    }
    Path::from_points(lanelets, crate::map::routing::resample(&points, points_per_meter), false)
}

/// What makes SUMO vehicles alike enough to share a traffic table: vType index, routes by start
/// lane, departure speed (its bits; `None`: the desired speed).
type DemandKey = (usize, Vec<Vec<LaneletId>>, Option<u64>, Option<BTreeMap<LaneletId, Vec<LaneletId>>>);

/// SUMO's vehicle class as ours (`passenger` and anything we do not model: a car).
fn class_of_sumo(class: &str) -> VehicleClass {
    match class {
        "truck" | "trailer" | "delivery" => VehicleClass::Truck,
        "bus" | "coach" | "tram" => VehicleClass::Bus,
        "motorcycle" | "moped" => VehicleClass::Motorcycle,
        "bicycle" => VehicleClass::Bicycle,
        "emergency" => VehicleClass::Emergency,
        _ => VehicleClass::Car,
    }
}

/// One traffic table per SUMO vehicle, flow or trip of `demand` (after the `[[traffic]]`
/// tables, so their random streams stay as they were): its start lanes with their routes, its
/// departure times (probability and Poisson flows drawn from the seed), and an IDM with its
/// `vType`'s parameters; ids count down from `start`.
fn sumo_demand(
    demand: &crate::map::sumo::demand::Demand,
    map: &crate::map::LaneletMap,
    traffic: &mut Traffic,
    start: i64,
    points_per_meter: f64,
) {
    use crate::map::sumo::demand::{DepartSpeed, Departures};
    // Every distinct route's path, built over the cores (rayon) before the tables: a duarouter
    // or randomTrips file has a route a vehicle (12,858 on a 20 x 20 grid, 3 GB of points at 5
    // a metre), and building them one at a time was most of the set-up. Each path depends on
    // its lanelets alone, so the order they are built in changes no bit.
    let paths: BTreeMap<&[LaneletId], Arc<Path>> = {
        use rayon::prelude::*;
        let mut routes: Vec<&[LaneletId]> = demand
            .groups
            .iter()
            .flat_map(|g| g.routes.iter())
            .map(Vec::as_slice)
            .filter(|r| r.first().is_some_and(|l| map.lanelet_index(*l).is_some()))
            .collect();
        routes.sort_unstable();
        routes.dedup();
        let built: Vec<Arc<Path>> =
            routes.par_iter().map(|r| Arc::new(map.path_of_lanelets(r, points_per_meter))).collect();
        routes.into_iter().zip(built).collect()
    };
    let path_of = |lanelets: &[LaneletId]| paths.get(lanelets).map(Arc::clone);
    let seed = traffic.seed;
    let mut next_id = start;
    let first = traffic.sources.len();
    // Vehicles of one type on one route entering alike share a table (a duarouter file has a
    // `<vehicle>` per trip; tables are visited every tick).
    let mut shared: BTreeMap<DemandKey, usize> = BTreeMap::new();
    for g in &demand.groups {
        let depart_speed = match g.depart_speed {
            DepartSpeed::Given(v) => Some(v),
            DepartSpeed::Desired => None,
        };
        let key =
            (g.vtype, g.routes.clone(), depart_speed.map(f64::to_bits), g.lane_route.as_ref().map(|r| r.lanes.clone()));
        if let (Departures::Times(times), Some(&k)) = (&g.departures, shared.get(&key)) {
            let src = &mut traffic.sources[k];
            src.schedule.extend_from_slice(times);
            src.schedule.sort_by(f64::total_cmp);
            continue;
        }
        let stream = traffic.sources.len() as u64;
        let vt = &demand.types[g.vtype];
        let schedule: Vec<f64> = match &g.departures {
            Departures::Times(t) => t.clone(),
            Departures::Probability { begin, end, p } => {
                let n = (end - begin).max(0.0).ceil() as u64;
                (0..n)
                    .filter(|&k| crate::world::random::uniform(seed, stream, k, 5) < *p)
                    .map(|k| begin + k as f64)
                    .collect()
            }
            Departures::Poisson { begin, end, rate } => {
                let mut out = Vec::new();
                let mut t = *begin;
                for k in 0.. {
                    t += -(1.0 - crate::world::random::uniform(seed, stream, k, 5)).ln() / rate;
                    if t >= *end {
                        break;
                    }
                    out.push(t);
                }
                out
            }
        };
        let lanes: Vec<TrafficLane> = g
            .routes
            .iter()
            .filter_map(|r| {
                let lanelet = map.lanelet_index(*r.first()?)? as u32;
                Some(TrafficLane { lanelet, entry_s: 0.0, path: path_of(r)? })
            })
            .collect();
        let v0 = vt.max_speed.min(g.first_speed_limit).max(0.1);
        let idm =
            Idm { speed: v0, time_gap: vt.tau, min_gap: vt.min_gap, accel: vt.accel, decel: vt.decel, delta: vt.delta };
        traffic.sources.push(TrafficSource {
            stream,
            lanes,
            // A route that needs lane changes is driven by the lane-change plugin (mandatory
            // changes into the lanes that continue it).
            goal: g.lane_route.clone().map_or(RouteGoal::Loop, |r| RouteGoal::Lanes(Arc::new(r))),
            rate_per_s: 0.0,
            until: f64::INFINITY,
            speed: [v0, v0],
            classes: vec![(class_of_sumo(&vt.class), 1.0)],
            controller: Some(SmartController::Idm(idm)),
            // Mandatory changes only: a threshold no gain reaches turns MOBIL's discretionary
            // changes off (SUMO's strategic changes are what the route needs; its speed-gain
            // changes, LC2013's, are not modelled here).
            lane_change: g.lane_route.as_ref().map(|_| crate::vehicles::LaneChangeParams {
                threshold: crate::sim::params::MAX_ACCEL,
                ..crate::vehicles::LaneChangeParams::default()
            }),
            model: VehicleModel::default(),
            // No radar: the leader comes from the lane index along the route (the radar that
            // served only to find it was most of a step's cost).
            sensors: sensors_of(&SensorsConfig::default()),
            leader_from_lanes: true,
            sensor_errors: SensorErrors::default(),
            yield_to_emergency: false,
            next_id: next_id as i32,
            id_step: -1,
            drawn: 0,
            next_time: f64::INFINITY,
            queue: 0,
            random: None,
            pending: Vec::new(),
            renew: false,
            schedule,
            scheduled: 0,
            length: Some(vt.length),
            depart_speed,
        });
        if matches!(g.departures, Departures::Times(_)) {
            shared.insert(key, traffic.sources.len() - 1);
        }
    }
    // Ids once every table has its whole schedule: each counts down from where the last ended.
    for src in &mut traffic.sources[first..] {
        src.next_id = next_id as i32;
        next_id -= src.schedule.len() as i64;
    }
}
