//! `smlworld bench --city`: a town at full stack (issue 53 item 8). A generated grid of
//! `rows` x `rows` blocks of `block` m, `lanes` lanes each way, traffic lights at every junction
//! of three or four arms, and `vehicles` cars on random trips, each drawing a new trip when it
//! arrives (`on_arrival = "new_trip"`), so the town's traffic never thins: IDM, radar, V2V,
//! right of way, lights, lane positions, all as a scenario runs them. Reports the real-time
//! factor of the simulated seconds after the set-up (map, junctions, 10,000 first routes).

use std::path::PathBuf;
use std::time::Instant;

use crate::map::generate::{self, GridParams, JunctionMarks};
use crate::sim::Parallelism;
use crate::world::SimTime;

use super::scenario::Scenario;

/// The town of `smlworld bench --city`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CityBench {
    /// Blocks per side (the issue's 20).
    pub rows: usize,
    /// Distance between junction centres \[m\] (200).
    pub block: f64,
    /// Lanes per direction (2).
    pub lanes: usize,
    /// Vehicles driving at once (10,000).
    pub vehicles: usize,
    /// Seed of the trips.
    pub seed: u64,
    /// Route points per metre (scenario key `points_per_meter`). A town's routes are long (2.7 km
    /// on average on the 20 x 20 grid) and every vehicle owns its own: at the scenario default of
    /// 5 the 10,000 routes took 2.7 GB and the stepping waited on memory. 1 point a metre still
    /// follows a junction's turns (radius 10 m or more) within 1.3 cm.
    pub points_per_meter: f64,
}

impl Default for CityBench {
    fn default() -> Self {
        CityBench { rows: 20, block: 200.0, lanes: 2, vehicles: 10_000, seed: 1, points_per_meter: 1.0 }
    }
}

/// What `bench --city` measured.
#[derive(Debug, Clone, serde::Serialize)]
pub struct CityReport {
    /// Blocks per side.
    pub rows: usize,
    /// Lanes per direction.
    pub lanes: usize,
    /// Vehicles placed at the start.
    pub vehicles: usize,
    /// Vehicles in the world at the end.
    pub vehicles_at_end: usize,
    /// Junctions of the town (with conflicts).
    pub junctions: usize,
    /// Simulated time \[s\].
    pub sim_seconds: f64,
    /// Wall time of the simulated seconds \[s\] (set-up excluded).
    pub wall_seconds: f64,
    /// Wall time of the set-up: map, junctions, first routes, placing \[s\].
    pub setup_seconds: f64,
    /// CPU time of the process during the simulated seconds \[s\] (all threads): steadier than
    /// the wall time on a loaded machine.
    pub cpu_seconds: Option<f64>,
    /// sim_seconds / wall_seconds.
    pub real_time_factor: f64,
    /// Vehicle updates per second of wall time (vehicles x dynamics steps / wall).
    pub vehicle_updates_per_s: f64,
    /// Threads the per-vehicle work was split over.
    pub threads: usize,
    /// Trips finished (a vehicle reaching its destination and drawing the next).
    pub trips_finished: u64,
    /// Collisions during the run.
    pub collisions: usize,
    /// Where the wall time went, module by module (as `bench` reports it).
    pub modules: Vec<super::bench::ModuleTime>,
}

/// A bench's failure, named.
#[derive(Debug, thiserror::Error)]
pub enum CityBenchError {
    /// The map could not be generated or written.
    #[error("bench --city: cannot write the town map {path}: {reason}")]
    Map {
        /// Where.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// The scenario was refused (a bug: the text is ours).
    #[error("bench --city: {0}")]
    Scenario(#[from] crate::app::ScenarioError),
}

impl CityBench {
    /// Run the town for `duration` sim seconds on `parallelism` (default: the scenario default).
    pub fn run(&self, duration: f64, parallelism: Option<Parallelism>) -> Result<CityReport, CityBenchError> {
        let setup = Instant::now();
        let dir = std::env::temp_dir().join(format!("smlworld-bench-city-{}", std::process::id()));
        let map_err = |reason: String| CityBenchError::Map { path: dir.join("town.osm"), reason };
        std::fs::create_dir_all(&dir).map_err(|e| map_err(e.to_string()))?;
        let map_path = dir.join("town.osm");
        let params = GridParams {
            rows: self.rows,
            cols: self.rows,
            block: self.block,
            lanes: self.lanes,
            control: JunctionMarks { traffic_lights: true, major: None },
            ..GridParams::default()
        };
        let text = generate::grid_city(&params).map_err(|e| map_err(e.to_string()))?;
        std::fs::write(&map_path, text).map_err(|e| map_err(e.to_string()))?;
        let scenario_text = format!(
            r#"seed = {seed}
duration = {duration}
map = "{map}"
points_per_meter = {ppm}

[[traffic]]
route = "random"
count = {n}
speed = [10.0, 14.0]
classes = {{ car = 1.0 }}
lane_change = false
on_arrival = "new_trip"
"#,
            seed = self.seed,
            map = map_path.display(),
            n = self.vehicles,
            ppm = self.points_per_meter,
        );
        let scenario = Scenario::parse_str(&scenario_text, &dir.join("city.toml"))?;
        let mut builder = scenario.builder()?;
        if let Some(p) = parallelism {
            builder.insert_resource(p);
        }
        let mut sim = builder.build();
        let _ = std::fs::remove_dir_all(&dir);
        let junctions = sim.world().get_resource::<crate::vehicles::JunctionNetwork>().map_or(0, |n| n.junctions.len());
        let threads = sim.world().get_resource::<Parallelism>().map_or(1, |p| p.threads_for(self.vehicles));
        let setup_seconds = setup.elapsed().as_secs_f64();
        sim.scheduler_mut().set_timing(true);
        let cpu = super::bench::process_cpu_seconds();
        let wall = Instant::now();
        sim.run_until(SimTime::from_secs(duration));
        let wall_seconds = wall.elapsed().as_secs_f64().max(1e-9);
        let cpu_seconds = cpu.zip(super::bench::process_cpu_seconds()).map(|(a, b)| b - a);
        let world = sim.world();
        let vehicles_at_end = world.resource::<crate::world::Vehicles>().len();
        let trips_finished = world.get_resource::<super::trips::TripLog>().map_or(0, |l| l.finished.len() as u64);
        let collisions = world.get_resource::<super::metrics::Metrics>().map_or(0, |m| m.summary().collision_count);
        let dynamics_rate = scenario.rates().dynamics;
        let modules = sim
            .scheduler()
            .module_times()
            .map(|(name, seconds)| super::bench::ModuleTime {
                module: name.to_string(),
                seconds,
                share: seconds / wall_seconds,
            })
            .collect();
        Ok(CityReport {
            rows: self.rows,
            lanes: self.lanes,
            vehicles: self.vehicles,
            vehicles_at_end,
            junctions,
            sim_seconds: duration,
            wall_seconds,
            setup_seconds,
            cpu_seconds,
            real_time_factor: duration / wall_seconds,
            vehicle_updates_per_s: self.vehicles as f64 * duration * dynamics_rate / wall_seconds,
            threads,
            trips_finished,
            collisions,
            modules,
        })
    }
}
