//! A complete controller in one file: copy it to start your own.
//!
//! `Cautious` keeps a bumper-to-bumper gap [m] to the vehicle ahead on its route and cruises
//! when the road is free. Its plugin registers it under a name, so `scenarios/student.toml`
//! names it like a built-in controller: `controller = { type = "my_cautious", gap = 25.0 }`.
//! It writes only its acceleration demand (`Longitudinal::accel`, in `LongitudinalSystems::Demand`);
//! steering, emergency braking and turning the demand into throttle or speed come from the
//! simulator, so it brakes on the kinematic and the acceleration model alike.
//!
//! Run it: `cargo run --release --example student_controller [SCENARIO] [OUT_DIR]`
//! (default `scenarios/student.toml`, `out/student`): it writes `trajectories.csv` and
//! `summary.json` like `smlworld run`.

use smlworld::prelude::*;

/// The controller's parameters, read from the scenario's `controller` table.
#[derive(Component, serde::Deserialize, Debug, Clone, Copy)]
#[serde(deny_unknown_fields)]
pub struct Cautious {
    /// Bumper-to-bumper gap it keeps to the vehicle ahead [m].
    pub gap: f64,
    /// Cruise speed when nobody is ahead [m/s].
    #[serde(default = "default_speed")]
    pub speed: f64,
}

fn default_speed() -> f64 {
    10.0
}

impl ScenarioController for Cautious {
    fn check(&self) -> Result<(), (String, String)> {
        match (self.gap.is_finite() && self.gap > 0.0, self.speed.is_finite() && self.speed >= 0.0) {
            (false, _) => Err(("gap".into(), format!("must be a positive distance [m], got {}", self.gap))),
            (_, false) => Err(("speed".into(), format!("must be zero or more [m/s], got {}", self.speed))),
            _ => Ok(()),
        }
    }
    fn cruise_speed(&self) -> Option<f64> {
        Some(self.speed)
    }
    fn attach(&self, vehicle: &mut EntityWorldMut<'_>) {
        vehicle.insert(*self);
    }
}

/// Every control tick: a spring on the gap error plus a damper on the speed difference [m/s²].
pub fn keep_gap(mut vehicles: Query<(&VehicleState, &Cautious, &mut Longitudinal)>) {
    for (state, me, mut lon) in &mut vehicles {
        let v = state.speed();
        let cruise = 0.5 * (lon.route_speed - v);
        let follow = lon.leader.map_or(f64::INFINITY, |l| 0.3 * (l.gap - me.gap) + 1.0 * (l.speed - v));
        lon.accel = cruise.min(follow).clamp(-6.0, 2.0);
    }
}

/// The plugin: registers the controller's name and adds its system.
pub struct CautiousPlugin;

impl Plugin for CautiousPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.register_controller::<Cautious>("my_cautious");
        sim.add_systems(Control, keep_gap.in_set(LongitudinalSystems::Demand));
    }
}

/// Run the scenario named on the command line (default `scenarios/student.toml`) with the plugin.
pub fn main() {
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let _ = tracing_subscriber::fmt().with_writer(std::io::stderr).with_ansi(ansi).try_init();
    let mut args = std::env::args().skip(1);
    let scenario = args.next().unwrap_or_else(|| "scenarios/student.toml".into());
    let out = args.next().unwrap_or_else(|| "out/student".into());
    match run_scenario(scenario.as_str(), RunOptions::default().out(&out).plugin(CautiousPlugin)) {
        Ok(summary) => println!(
            "{} vehicles, {:.0} sim s; wrote {out}/trajectories.csv and summary.json",
            summary.vehicles, summary.sim_seconds
        ),
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1);
        }
    }
}
