//! A complete sensor in one file: copy it to start your own.
//!
//! `Camera` sees the vehicles within `range` [m] inside a field of view of `fov_deg` around its
//! heading, each hidden when a nearer vehicle it sees covers it, with the built-in sensors'
//! noise and dropout. Its plugin registers it under a name, so `scenarios/student_sensor.toml`
//! puts it on a vehicle like a built-in sensor: `sensors = { camera = { fov_deg = 90.0, range = 80.0 } }`;
//! its detections go into the vehicle's `SensorReadings`, named `"camera"`.
//! Run it: `cargo run --release --example student_sensor [SCENARIO] [OUT_DIR]`
//! (default `scenarios/student_sensor.toml`, `out/student_sensor`).

use smlworld::prelude::*;
use smlworld::sim::{Cone, PluginSense, PluginSensorSystems, ScenarioSensor, Sensor};
use smlworld::world::SensorError;

/// The camera's parameters, read from its table in the vehicle's `sensors`.
#[derive(serde::Deserialize, Debug, Clone, Copy)]
#[serde(deny_unknown_fields)]
pub struct Camera {
    /// Full opening angle of the field of view [deg].
    pub fov_deg: f64,
    /// Farthest it sees [m].
    pub range: f64,
    /// Whether a vehicle behind a nearer one is hidden (default true).
    #[serde(default = "yes")]
    pub occlusion: bool,
    /// Standard deviation of the range error [m] (default 0).
    #[serde(default)]
    pub range_sd: f64,
    /// Probability that a visible vehicle is missed [-] (default 0).
    #[serde(default)]
    pub dropout: f64,
}

fn yes() -> bool {
    true
}

impl ScenarioSensor for Camera {
    fn check(&self) -> Result<(), (String, String)> {
        let (fov, range, sd, dropout) = (self.fov_deg, self.range, self.range_sd, self.dropout);
        let rules = [
            (fov > 0.0 && fov <= 360.0, "fov_deg", "in (0, 360] degrees", fov),
            (range.is_finite() && range > 0.0, "range", "a positive distance [m]", range),
            (sd.is_finite() && sd >= 0.0, "range_sd", "zero or more [m]", sd),
            ((0.0..=1.0).contains(&dropout), "dropout", "a probability", dropout),
        ];
        match rules.into_iter().find(|rule| !rule.0) {
            Some((_, key, what, got)) => Err((key.into(), format!("must be {what}, got {got}"))),
            None => Ok(()),
        }
    }
    fn range(&self) -> f64 {
        self.range
    }
}

/// Every sensor tick, for each camera (on the simulator's threads): the neighbours within range
/// inside the field of view (O(k) from the shared grid), nearest first, kept when not hidden,
/// then dropout and noise.
pub fn sense_cameras(
    mut sense: PluginSense,
    mut cameras: Query<(&VehicleId, &VehicleState, &Sensor<Camera>, &mut SensorReadings)>,
) {
    sense.each(cameras.iter_mut(), |(&me, state, camera, mut readings), cx| {
        let from = state.position;
        let view = Cone::new(DVec2::from_angle(state.yaw), camera.fov_deg.to_radians());
        let draws = cx.draws(camera.name);
        let error = SensorError { range_sd: camera.range_sd, dropout: camera.dropout, ..Default::default() };
        let counts = cx.stats.of(camera.name);
        // Those in the field of view, nearest first.
        cx.nearby.around_where(me, from, camera.range, |rel, d2| view.contains(rel, d2), cx.found);
        cx.occlusion.clear();
        let kept = cx.found.iter().filter(|n| n.id != me).filter_map(|n| {
            if camera.occlusion && cx.occlusion.hidden(from, n) {
                counts.missed_by_occlusion += 1;
                return None;
            }
            let mut detection = n.detection(camera.name);
            if !draws.apply(&error, me, from, &mut detection) {
                counts.missed_by_dropout += 1;
                return None;
            }
            counts.detections += 1;
            Some(detection)
        });
        readings.set_sensor(camera.name, kept);
    });
}

/// The plugin: registers the sensor's name and adds its system.
pub struct CameraPlugin;

impl Plugin for CameraPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.register_sensor::<Camera>("camera");
        sim.add_systems(Sensors, sense_cameras.in_set(PluginSensorSystems::Sense));
    }
}

/// Run the scenario named on the command line (default `scenarios/student_sensor.toml`).
pub fn main() {
    let mut args = std::env::args().skip(1);
    let scenario = args.next().unwrap_or_else(|| "scenarios/student_sensor.toml".into());
    let out = args.next().unwrap_or_else(|| "out/student_sensor".into());
    match run_scenario(scenario.as_str(), RunOptions::default().out(&out).plugin(CameraPlugin)) {
        Ok(summary) => {
            println!("{} vehicles, {:.0} sim s; wrote {out}/summary.json", summary.vehicles, summary.sim_seconds)
        }
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}
