//! Assembly: a checked scenario into a [`SimBuilder`] (rates, seed, built-in plugins, routes,
//! vehicles with their controllers, the lab).

use std::collections::BTreeMap;
use std::sync::Arc;

use glam::DVec2;

use super::commonroad::{GoalMonitor, add_goal_monitor, spawn_obstacles};
use super::file::{
    BuiltInController, ControllerConfig, ModelConfig, NodeRef, ObstaclesMode, RouteConfig, StartConfig, VehicleConfig,
};
use super::lab::add_lab_plugins;
use super::{Scenario, ScenarioError};
use crate::app::metrics::MetricsPlugin;
use crate::map::{Path, RouteOptions};
use crate::sim::{
    Control, Dynamics, Network, Sensors, SimBuilder, SimSeed, V2vConfig, V2vPlugin, Wifi, default_plugins,
};
use crate::vehicles::{Longitudinal, PathFollower, PathFollowing, PathFollowingPlugin, smart_vehicles};
use crate::world::{
    AccelerationUnicycle, KinematicUnicycle, Radar, SensorSet, VehicleId, VehicleModel, VehicleSize, VehicleSpec,
    VehicleState, Velodyne,
};

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
        b.add_plugin(V2vPlugin {
            config: V2vConfig { wifi_range: v2v.range(), wifi: v2v.wifi.model(), network: v2v.network.model() },
        });
        b.add_plugin(PathFollowingPlugin);
        b.add_plugin(smart_vehicles).add_plugin(MetricsPlugin::default());
        let mut routes: BTreeMap<String, Arc<Path>> = BTreeMap::new();
        for (i, v) in self.file.vehicles.iter().enumerate() {
            let key = |k: &str| format!("vehicles[{i}] (id {}).{k}", v.id);
            let route = match &v.route {
                Some(r) => Some(self.route(r, &mut routes, &key)?),
                None => None,
            };
            self.spawn(b, v, route, &key)?;
        }
        if let (Some(sc), Some(map)) = (&self.commonroad, &self.map) {
            let obstacles = if self.file.obstacles == Some(ObstaclesMode::Replay) {
                spawn_obstacles(b, sc).map_err(|e| self.invalid("obstacles".into(), e))?;
                sc.obstacles.len()
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

    /// The path of route `r`, computed once per distinct route and shared.
    fn route(
        &self,
        r: &RouteConfig,
        routes: &mut BTreeMap<String, Arc<Path>>,
        key: &dyn Fn(&str) -> String,
    ) -> Result<Arc<Path>, ScenarioError> {
        let map = self.map.as_ref().ok_or_else(|| self.invalid(key("route"), "needs a `map` in the scenario"))?;
        let name = format!("{r:?}");
        if let Some(p) = routes.get(&name) {
            return Ok(Arc::clone(p));
        }
        let opts = RouteOptions { points_per_meter: self.file.points_per_meter };
        let route_err = |e| ScenarioError::Route { path: self.path.clone(), key: key("route"), source: Box::new(e) };
        let p = Arc::new(match (&r.closed_loop, &r.from, &r.to) {
            (Some(n), _, _) => map.closed_loop_at(&n.place(), &opts).map_err(route_err)?,
            (None, Some(a), Some(b)) => map.route_places(&a.place(), &b.place(), &opts).map_err(route_err)?,
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
        spec.model = match v.model {
            ModelConfig::Kinematic { wheelbase, max_steering } => {
                VehicleModel::Kinematic(KinematicUnicycle { wheelbase, max_steering })
            }
            ModelConfig::Acceleration { wheelbase, mass, drag, max_steering } => {
                VehicleModel::Acceleration(AccelerationUnicycle { wheelbase, mass, drag, max_steering })
            }
            ModelConfig::None => VehicleModel::None,
        };
        spec.sensors = SensorSet {
            radar: v.sensors.radar.map(|r| Radar { angle: r.angle_deg.to_radians(), range: r.range }),
            velodyne: v.sensors.velodyne.map(|r| Velodyne { range: r.range }),
            omniscient: v.sensors.omniscient,
        };
        spec.mailbox = v.mailbox;
        spec.route = route;
        let entity = b.spawn_vehicle(spec).map_err(|e| self.invalid(key("id"), e.to_string()))?;
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
        Ok(())
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
            let along = route.map_or(0.0, |r| r.project(s.position).s);
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
                    let projection = r.project(p);
                    (projection.heading, projection.s)
                });
                (p, start.yaw.unwrap_or(heading), along)
            }
            (Some(r), at, None) => {
                let base = match at {
                    Some(n) => r.project(node_position(n)?).s,
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
