//! Validation of a parsed scenario file: ranges, unique ids, keys that exclude each other, and
//! controller names (built in or registered).

use std::collections::BTreeMap;
use std::path::Path as FsPath;

use super::ScenarioError;
use super::file::{
    BuiltInController, ControllerConfig, LossConfig, ModelConfig, ScenarioFile, TrafficLanes, TrafficRoute, V2vSection,
    VehicleConfig,
};
use crate::sim::ControllerRegistry;
use crate::sim::params::{MAX_DISTANCE, MAX_GAIN, MAX_SPEED, MAX_TIME, MAX_VEHICLE_SIZE, Range};
use crate::sim::v2v::channel::plugins::ChannelModelRegistry;

/// Builds the errors of one file: each names the key and what is allowed.
struct Checker<'a> {
    path: &'a FsPath,
}

impl Checker<'_> {
    fn invalid(&self, key: String, problem: &str) -> ScenarioError {
        ScenarioError::Invalid { path: self.path.into(), key, problem: problem.into() }
    }

    /// `v` inside `range` (the one place that range is defined), else an error naming `key`.
    fn within(&self, key: String, v: f64, range: Range) -> Result<(), ScenarioError> {
        range.check(&key, v).map_err(|e| self.invalid(key, &e.problem))
    }
}

/// Check values the types cannot: ranges, unique ids, keys that exclude each other, and that
/// every controller is built in or in `controllers` (with parameters it accepts).
pub(super) fn check(file: &ScenarioFile, path: &FsPath, controllers: &ControllerRegistry) -> Result<(), ScenarioError> {
    let c = Checker { path };
    c.within("duration".into(), file.duration, Range::positive(1e9))?;
    c.within("points_per_meter".into(), file.points_per_meter, Range::positive(100.0))?;
    let r = &file.rates;
    for (k, v) in [
        ("dynamics", r.dynamics),
        ("sensors", r.sensors),
        ("control", r.control),
        ("wifi", r.wifi),
        ("network", r.network),
        ("log", r.log),
    ] {
        // At most 1e6 Hz: one tick per microsecond.
        c.within(format!("rates.{k}"), v, Range::positive(1e6))?;
    }
    check_v2v(&c, &file.v2v, controllers.channel_models())?;
    file.emergency.check().map_err(|e| c.invalid(format!("emergency.{}", e.key), &e.problem))?;
    file.junctions.check().map_err(|e| c.invalid(format!("junctions.{}", e.key), &e.problem))?;
    for (k, light) in file.traffic_lights.iter().enumerate() {
        c.within(format!("traffic_lights[{k}].offset"), light.offset, Range::between(-MAX_TIME, MAX_TIME))?;
        if light.program.is_empty() {
            return Err(c.invalid(format!("traffic_lights[{k}].program"), "is empty; give at least one phase"));
        }
        for (i, phase) in light.program.iter().enumerate() {
            c.within(format!("traffic_lights[{k}].program[{i}].duration"), phase.duration, Range::positive(MAX_TIME))?;
        }
    }
    if let Some(lab) = &file.lab {
        lab.check().map_err(|e| c.invalid(format!("lab.{}", e.key), &e.problem))?;
    }
    let mut seen = BTreeMap::new();
    for (i, v) in file.vehicles.iter().enumerate() {
        if let Some(first) = seen.insert(v.id, i) {
            let key = format!("vehicles[{i}] (id {}).id", v.id);
            return Err(c.invalid(key, &format!("is already used by vehicles[{first}]; ids must be unique")));
        }
        check_vehicle(&c, i, v, controllers)?;
    }
    for (k, t) in file.traffic.iter().enumerate() {
        check_traffic(&c, k, t)?;
    }
    for (k, r) in file.rsu.iter().enumerate() {
        c.within(format!("rsu[{k}].range"), r.range, Range::positive(MAX_DISTANCE))?;
        match (&r.at.node, r.at.x, r.at.y) {
            (Some(_), None, None) => {}
            (None, Some(x), Some(y)) => {
                c.within(format!("rsu[{k}].at.x"), x.abs(), Range::non_negative(MAX_DISTANCE))?;
                c.within(format!("rsu[{k}].at.y"), y.abs(), Range::non_negative(MAX_DISTANCE))?;
            }
            _ => {
                return Err(c.invalid(
                    format!("rsu[{k}].at"),
                    "needs either `x` and `y` [m] or `node` (a node id or tag), e.g. at = { x = 1000.0, y = 5.25 }",
                ));
            }
        }
    }
    Ok(())
}

/// The checks of one `[[traffic]]` table (index `k`).
fn check_traffic(c: &Checker<'_>, k: usize, t: &super::file::TrafficConfig) -> Result<(), ScenarioError> {
    let key = |s: &str| format!("traffic[{k}].{s}");
    match &t.route {
        TrafficRoute::Fixed(r) => match (&r.closed_loop, &r.from, &r.to) {
            (Some(_), None, None) if r.via.is_empty() => {}
            (None, Some(_), Some(_)) => {}
            (Some(_), None, None) => return Err(c.invalid(key("route.via"), "needs `from` and `to`, not `loop`")),
            _ => {
                return Err(c.invalid(
                    key("route"),
                    "needs either `loop = NODE` or both `from = NODE` and `to = NODE`, or is \"random\"",
                ));
            }
        },
        TrafficRoute::Random if t.lanes != TrafficLanes::All => {
            return Err(
                c.invalid(key("lanes"), "names start lanes of a fixed route; random traffic starts on any lane")
            );
        }
        TrafficRoute::Random => {}
    }
    c.within(key("rate"), t.rate, Range::non_negative(1e6))?;
    if t.count == 0 && t.rate == 0.0 {
        return Err(
            c.invalid(key("count"), "and `rate` are both 0: set `count` (vehicles at t = 0) and/or `rate` [veh/h]")
        );
    }
    if let Some(u) = t.until {
        c.within(key("until"), u, Range::non_negative(1e9))?;
    }
    if let Some(v) = t.min_speed_limit {
        if t.route != TrafficRoute::Random {
            return Err(
                c.invalid(key("min_speed_limit"), "keeps random trips on fast roads: it needs `route = \"random\"`")
            );
        }
        c.within(key("min_speed_limit"), v, Range::non_negative(MAX_SPEED))?;
    }
    let [lo, hi] = t.speed;
    c.within(key("speed[0]"), lo, Range::positive(MAX_SPEED))?;
    c.within(key("speed[1]"), hi, Range::positive(MAX_SPEED))?;
    if lo > hi {
        return Err(c.invalid(key("speed"), &format!("is [low, high] [m/s]: {lo} is above {hi}")));
    }
    for (class, w) in &t.classes {
        c.within(key(&format!("classes.{}", format!("{class:?}").to_lowercase())), *w, Range::non_negative(1e9))?;
    }
    if t.classes.values().sum::<f64>() <= 0.0 {
        return Err(c.invalid(key("classes"), "needs a share above 0, e.g. { car = 1.0 }"));
    }
    if let Some(name) = t.sensors.plugins.keys().next() {
        return Err(c.invalid(
            key(&format!("sensors.{name}")),
            "is not a built-in sensor (radar, velodyne, omniscient): traffic takes built-in sensors only; put a plugin sensor on a [[vehicles]] entry",
        ));
    }
    if let Some(r) = t.sensors.radar {
        check_sensor_errors(c, &key("sensors.radar"), &r.noise, r.dropout)?;
    }
    if let Some(r) = t.sensors.velodyne {
        check_sensor_errors(c, &key("sensors.velodyne"), &r.noise, r.dropout)?;
    }
    if let Some(p) = &t.lane_change.0 {
        p.check().map_err(|e| c.invalid(key(&format!("lane_change.{}", e.key)), &e.problem))?;
    }
    match &t.controller {
        None => {}
        Some(controller) => {
            let smart = controller.smart().filter(|s| {
                !matches!(s, crate::vehicles::SmartController::Platoon(_) | crate::vehicles::SmartController::Gcdc(_))
            });
            let Some(smart) = smart else {
                return Err(
                    c.invalid(key("controller.type"), "traffic drives `idm` (the default), `acc` or `cruise_control`")
                );
            };
            smart.check().map_err(|(k2, problem)| c.invalid(key(&format!("controller.{k2}")), &problem))?;
        }
    }
    let sees = t.sensors.radar.is_some() || t.sensors.velodyne.is_some() || t.sensors.omniscient;
    let follows = t.controller.as_ref().and_then(ControllerConfig::smart).is_none_or(|s| s.needs_sensing_ahead());
    if follows && !sees {
        return Err(c.invalid(
            key("sensors"),
            "the traffic's controller needs a sensor that sees the vehicle ahead; add one, e.g. `sensors = { radar = { angle_deg = 60.0, range = 100.0 } }`",
        ));
    }
    Ok(())
}

/// The checks of one `[[vehicles]]` entry (index `i`).
/// `[v2v]`: one range key, probabilities in [0, 1], delays in [0, 60 s].
fn check_v2v(c: &Checker, v2v: &V2vSection, models: &ChannelModelRegistry) -> Result<(), ScenarioError> {
    if let (Some(_), Some(_)) = (v2v.wifi_range, v2v.wifi.range) {
        return Err(c.invalid("v2v.wifi_range".into(), "and `v2v.wifi.range` both set the wifi range; keep one"));
    }
    if v2v.network.range.is_some() {
        return Err(c.invalid("v2v.network.range".into(), "does not exist: the network channel reaches every vehicle"));
    }
    c.within("v2v.wifi.range".into(), v2v.range(), Range::non_negative(MAX_DISTANCE))?;
    for (name, ch) in [("wifi", &v2v.wifi), ("network", &v2v.network)] {
        if let LossConfig::Constant(p) = ch.loss {
            c.within(format!("v2v.{name}.loss"), p, Range::non_negative(1.0))?;
        }
        if let Some(b) = ch.burst {
            c.within(format!("v2v.{name}.burst.p_enter"), b.p_enter, Range::non_negative(1.0))?;
            c.within(format!("v2v.{name}.burst.p_leave"), b.p_leave, Range::positive(1.0))?;
            c.within(format!("v2v.{name}.burst.loss_in_burst"), b.loss_in_burst, Range::non_negative(1.0))?;
        }
        c.within(format!("v2v.{name}.delay_ms"), ch.delay_ms, Range::non_negative(60_000.0))?;
        c.within(format!("v2v.{name}.jitter_ms"), ch.jitter_ms, Range::non_negative(60_000.0))?;
        ch.model(models).map_err(|(key, problem)| c.invalid(format!("v2v.{name}.{key}"), &problem))?;
    }
    Ok(())
}

fn check_vehicle(
    c: &Checker<'_>,
    i: usize,
    v: &VehicleConfig,
    controllers: &ControllerRegistry,
) -> Result<(), ScenarioError> {
    let key = |k: &str| format!("vehicles[{i}] (id {}).{k}", v.id);
    let size = Range::positive(MAX_VEHICLE_SIZE);
    if let Some(l) = v.length {
        c.within(key("length"), l, size)?;
    }
    if let Some(w) = v.width {
        c.within(key("width"), w, size)?;
    }
    c.within(key("speed"), v.speed, Range::non_negative(MAX_SPEED))?;
    let steering = Range::non_negative(std::f64::consts::FRAC_PI_2);
    match v.model {
        ModelConfig::Kinematic { wheelbase, max_steering } => {
            c.within(key("model.wheelbase"), wheelbase, size)?;
            c.within(key("model.max_steering"), max_steering, steering)?;
        }
        ModelConfig::Acceleration { wheelbase, mass, drag, max_steering } => {
            c.within(key("model.wheelbase"), wheelbase, size)?;
            c.within(key("model.mass"), mass, Range::between(0.1, 1e6))?;
            c.within(key("model.drag"), drag, Range::non_negative(1e6))?;
            c.within(key("model.max_steering"), max_steering, steering)?;
        }
        ModelConfig::None => {}
    }
    if let Some(route) = &v.route {
        match (&route.closed_loop, &route.from, &route.to) {
            (Some(_), None, None) if route.via.is_empty() => {}
            (None, Some(_), Some(_)) => {}
            (Some(_), None, None) => return Err(c.invalid(key("route.via"), "needs `from` and `to`, not `loop`")),
            _ => {
                return Err(c.invalid(
                    key("route"),
                    "needs either `loop = NODE` or both `from = NODE` and `to = NODE` (NODE: a node id or a tag value)",
                ));
            }
        }
    }
    if let Some(s) = &v.start {
        if s.x.is_some() != s.y.is_some() {
            return Err(c.invalid(key("start"), "needs both `x` and `y` [m], or neither"));
        }
        if s.at.is_some() && s.x.is_some() {
            return Err(c.invalid(key("start"), "takes either `at = NODE` or `x`/`y`, not both"));
        }
        if s.offset.is_some() && v.route.is_none() {
            return Err(c.invalid(key("start.offset"), "is a distance along the route: add a `route`"));
        }
        if s.offset.is_some() && s.x.is_some() {
            return Err(c.invalid(key("start.offset"), "cannot be combined with `x`/`y`"));
        }
        let position = Range::between(-MAX_DISTANCE, MAX_DISTANCE);
        for (k, value) in [("start.offset", s.offset), ("start.x", s.x), ("start.y", s.y)] {
            if let Some(value) = value {
                c.within(key(k), value, position)?;
            }
        }
        if let Some(yaw) = s.yaw {
            c.within(key("start.yaw"), yaw, Range::between(-1e3, 1e3))?;
        }
    }
    for (name, params) in &v.sensors.plugins {
        let at = key(&format!("sensors.{name}"));
        match controllers.sensors().parse(name, params.clone()) {
            None => {
                return Err(c.invalid(
                    at,
                    &format!(
                        "names no known sensor: `{name}` (known: {}); a sensor of your own must be registered by its plugin (SimBuilder::register_sensor) before the scenario is loaded",
                        controllers.sensors().known_list()
                    ),
                ));
            }
            Some(Ok(_)) => {}
            Some(Err(e)) if e.key.is_empty() => return Err(c.invalid(at, &e.problem)),
            Some(Err(e)) => return Err(c.invalid(format!("{at}.{}", e.key), &e.problem)),
        }
    }
    if let Some(r) = v.sensors.radar {
        if !(r.angle_deg > 0.0 && r.angle_deg <= 360.0) {
            return Err(c.invalid(
                key("sensors.radar.angle_deg"),
                &format!("must be in (0, 360] degrees, got {}", r.angle_deg),
            ));
        }
        c.within(key("sensors.radar.range"), r.range, Range::non_negative(MAX_DISTANCE))?;
        check_sensor_errors(c, &key("sensors.radar"), &r.noise, r.dropout)?;
    }
    if let Some(r) = v.sensors.velodyne {
        c.within(key("sensors.velodyne.range"), r.range, Range::non_negative(MAX_DISTANCE))?;
        check_sensor_errors(c, &key("sensors.velodyne"), &r.noise, r.dropout)?;
    }
    if let Some(p) = &v.lane_change.0 {
        p.check().map_err(|e| c.invalid(key(&format!("lane_change.{}", e.key)), &e.problem))?;
        if v.route.is_none() {
            return Err(c.invalid(key("lane_change"), "needs a `route` (lanes are changed along it)"));
        }
    }
    // The controller's own values first (the more specific error), then what it needs.
    if let Some(controller) = &v.controller {
        check_controller(c, v, controller, controllers, &key)?;
    }
    if let Some(smart) = v.controller.as_ref().and_then(ControllerConfig::smart)
        && smart.needs_sensing_ahead()
        && v.sensors.radar.is_none()
        && v.sensors.velodyne.is_none()
        && !v.sensors.omniscient
    {
        return Err(c.invalid(
            key("sensors"),
            &format!(
                "controller `{}` needs a sensor that sees the vehicle ahead, and this vehicle has none (it would drive into it); add one, e.g. `sensors = {{ radar = {{ angle_deg = 60.0, range = 100.0 }} }}` (or `velodyne = {{ range = 50.0 }}`, or `omniscient = true`)",
                smart.type_name()
            ),
        ));
    }
    Ok(())
}

/// The checks of a vehicle's `controller` table.
fn check_controller(
    c: &Checker<'_>,
    v: &VehicleConfig,
    controller: &ControllerConfig,
    controllers: &ControllerRegistry,
    key: &dyn Fn(&str) -> String,
) -> Result<(), ScenarioError> {
    match controller {
        ControllerConfig::BuiltIn(BuiltInController::PathFollowing {
            speed,
            lookahead_min,
            lookahead_time,
            speed_gain,
        }) => {
            if v.route.is_none() {
                return Err(c.invalid(key("controller"), "path_following needs a `route` to follow"));
            }
            c.within(key("controller.speed"), *speed, Range::non_negative(MAX_SPEED))?;
            c.within(key("controller.lookahead_min"), *lookahead_min, Range::positive(MAX_DISTANCE))?;
            c.within(key("controller.lookahead_time"), *lookahead_time, Range::non_negative(MAX_TIME))?;
            c.within(key("controller.speed_gain"), *speed_gain, Range::non_negative(MAX_GAIN))
        }
        ControllerConfig::BuiltIn(_) => {
            let Some(smart) = controller.smart() else { return Ok(()) };
            if v.route.is_none() {
                return Err(c.invalid(key("controller"), "needs a `route` to follow"));
            }
            smart.check().map_err(|(k, problem)| c.invalid(key(&format!("controller.{k}")), &problem))
        }
        ControllerConfig::Registered { name, params } => {
            let Some(parsed) = controllers.parse(name, params.clone()) else {
                return Err(c.invalid(
                    key("controller.type"),
                    &format!(
                        "names no known controller: `{name}` (known: {}); a controller of your own must be registered by its plugin (SimBuilder::register_controller) before the scenario is loaded",
                        controllers.known_list()
                    ),
                ));
            };
            if v.route.is_none() {
                return Err(c.invalid(key("controller"), &format!("`{name}` needs a `route` to follow")));
            }
            match parsed {
                Ok(_) => Ok(()),
                Err(e) if e.key.is_empty() => Err(c.invalid(key("controller"), &e.problem)),
                Err(e) => Err(c.invalid(key(&format!("controller.{}", e.key)), &e.problem)),
            }
        }
    }
}

/// A sensor's `noise` standard deviations (range and speed [0, 1e6], bearing [0, 360] degrees)
/// and `dropout` probability [0, 1]; `at` names the sensor's table.
fn check_sensor_errors(
    c: &Checker,
    at: &str,
    noise: &super::file::NoiseConfig,
    dropout: f64,
) -> Result<(), ScenarioError> {
    c.within(format!("{at}.noise.range_sd"), noise.range_sd, Range::non_negative(MAX_DISTANCE))?;
    c.within(format!("{at}.noise.bearing_sd_deg"), noise.bearing_sd_deg, Range::non_negative(360.0))?;
    c.within(format!("{at}.noise.speed_sd"), noise.speed_sd, Range::non_negative(MAX_DISTANCE))?;
    c.within(format!("{at}.dropout"), dropout, Range::non_negative(1.0))
}
