//! `smlworld bench`: the whole simulation with N vehicles, every module on; prints JSON naming
//! the map, vehicles, sensors, rates, threads and each module's share of the wall time.

use smlworld::app::running::bench::BenchWorld;
use smlworld::app::running::soak::soak;
use smlworld::sim::Parallelism;

/// Arguments of `smlworld bench`.
#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// Number of vehicles.
    #[arg(long, default_value_t = 1000, value_parser = super::range::count::<usize>(1, super::range::MAX_VEHICLES))]
    pub vehicles: usize,
    /// Sim time to run [s].
    #[arg(long, default_value_t = 10.0, value_parser = super::range::positive)]
    pub duration: f64,
    /// Most threads of the per-vehicle systems; above 1 they split at any vehicle count
    /// (default: the machine's cores, at most 4, from 2,000 vehicles on).
    #[arg(long, value_parser = super::range::threads())]
    pub threads: Option<usize>,
    /// Soak test: run for this many seconds of WALL time, sampling the process's memory (RSS),
    /// and report whether it stayed flat after the warm-up (the first minute). The soak world
    /// drives IDM with lane changes and churns traffic: every 10 s of sim time 5 % of the
    /// vehicles leave and as many new ones enter.
    #[arg(long, value_name = "SECONDS", value_parser = super::range::positive)]
    pub soak: Option<f64>,
    /// Memory sample interval of --soak [s of wall time].
    #[arg(long, default_value_t = 10.0, requires = "soak", value_parser = super::range::positive)]
    pub sample_every: f64,
    /// Every vehicle drives the IDM and changes lanes (MOBIL) instead of plain path following.
    #[arg(long)]
    pub lane_change: bool,
    /// Every vehicle's V2V (wifi: 10 % loss, 10 ms delay, 5 ms jitter; network: 10 % loss) and
    /// radar (noise 0.2 m, 0.5°, 0.1 m/s; 2 % dropout) degraded, seed 1 (issue 21).
    #[arg(long)]
    pub degraded: bool,
    /// Share of the vehicles that also carry the student camera of examples/student_sensor.rs
    /// (a plugin sensor: 90°, 80 m, occlusion), spread evenly along the road [0, 1]
    #[arg(long, default_value_t = 0.0, value_name = "SHARE")]
    pub plugin_sensor_share: f64,
    /// Routing benchmark instead of the simulation: route --routes random node pairs (drawn with
    /// --seed among the nodes on a drivable lanelet's right bound) of this map with A*; prints
    /// `routes_per_second`.
    #[arg(long, value_name = "MAP", conflicts_with_all = ["soak", "lane_change", "degraded", "map_load"])]
    pub routing: Option<std::path::PathBuf>,
    /// Routes of --routing.
    #[arg(long, default_value_t = 1000, requires = "routing", value_parser = super::range::count::<usize>(1, 10_000_000))]
    pub routes: usize,
    /// Seed of the --routing pairs.
    #[arg(long, default_value_t = 1, requires = "routing")]
    pub seed: u64,
    /// Map-loading benchmark instead of the simulation: load this map 3 times; prints
    /// `mb_per_second` (of the median load).
    #[arg(long, value_name = "MAP", conflicts_with_all = ["soak", "lane_change", "degraded"])]
    pub map_load: Option<std::path::PathBuf>,
    /// A town at full stack: a generated 20 x 20 grid (200 m blocks, 2 lanes each way, traffic
    /// lights) with --vehicles cars (default 10,000 here) on random trips, each drawing a new
    /// trip when it arrives. Prints the real-time factor as JSON.
    #[arg(long, conflicts_with_all = ["soak", "lane_change", "degraded", "routing", "map_load", "render"])]
    pub city: bool,
    /// --city: blocks per side of the grid.
    #[arg(long, default_value_t = 20, requires = "city", value_parser = super::range::count::<usize>(2, 200))]
    pub city_rows: usize,
    /// After the simulation bench, draw its world at WIDTHxHEIGHT px (e.g. 1920x1080) 10 times
    /// with the bird's-eye renderer (whole-map view) and add `render_ms_per_frame` (the median)
    /// and `render` (every frame's time, the adapter) to the JSON.
    #[arg(long, value_name = "WxH", conflicts_with = "soak", value_parser = smlworld::app::running::bench_render::parse_size)]
    pub render: Option<(u32, u32)>,
}

/// Run the subcommand.
pub fn main(args: BenchArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.vehicles > 0 && args.vehicles < i32::MAX as usize,
        "--vehicles must be at least 1, got {}",
        args.vehicles
    );
    anyhow::ensure!(
        args.duration.is_finite() && args.duration > 0.0,
        "--duration must be a positive number of seconds, got {}",
        args.duration
    );
    anyhow::ensure!(args.threads != Some(0), "--threads must be at least 1, got 0");
    if let Some(map) = &args.routing {
        let report = smlworld::app::running::bench_map::bench_routing(map, args.routes, args.seed)?;
        println!("{}", serde_json::to_string(&report)?);
        return Ok(());
    }
    if args.city {
        // --vehicles keeps its default of 1,000 for the ring; the town's default is 10,000.
        let vehicles = if std::env::args().any(|a| a == "--vehicles" || a.starts_with("--vehicles=")) {
            args.vehicles
        } else {
            10_000
        };
        let bench =
            smlworld::app::running::bench_city::CityBench { rows: args.city_rows, vehicles, ..Default::default() };
        eprintln!(
            "bench --city: {} x {} blocks, {} vehicles, {} s of sim time (set-up first: map, junctions, routes)",
            bench.rows, bench.rows, bench.vehicles, args.duration
        );
        let report = bench.run(args.duration, args.threads.map(Parallelism::split))?;
        println!("{}", serde_json::to_string(&report)?);
        return Ok(());
    }
    if let Some(map) = &args.map_load {
        let report = smlworld::app::running::bench_map::bench_map_load(map, 3)?;
        println!("{}", serde_json::to_string(&report)?);
        return Ok(());
    }
    // A soak drives the whole stack: IDM, lane changes and traffic churn (vehicles leaving and
    // entering), whether or not --lane-change is given.
    let world = BenchWorld {
        vehicles: args.vehicles,
        lane_change: args.lane_change || args.soak.is_some(),
        degraded: args.degraded,
        plugin_sensor_share: args.plugin_sensor_share,
        ..Default::default()
    };
    anyhow::ensure!(
        (0.0..=1.0).contains(&args.plugin_sensor_share),
        "--plugin-sensor-share must be in [0, 1], got {}",
        args.plugin_sensor_share
    );
    let parallelism = args.threads.map(Parallelism::split);
    smlworld::app::running::interrupt::install();
    if let Some(seconds) = args.soak {
        anyhow::ensure!(
            seconds.is_finite() && seconds > 0.0 && seconds <= 1e6,
            "--soak must be in (0, 1e6] seconds of wall time, got {seconds}"
        );
        anyhow::ensure!(
            args.sample_every.is_finite() && args.sample_every > 0.0 && args.sample_every <= seconds,
            "--sample-every must be in (0, --soak] seconds, got {}",
            args.sample_every
        );
        let report = soak(&world, seconds, args.sample_every, parallelism, |s| {
            eprintln!("soak {:7.1} s wall: sim {:9.1} s, RSS {:7.1} MB", s.wall_s, s.sim_s, s.rss_mb);
        })?;
        println!("{}", serde_json::to_string(&report)?);
        return Ok(());
    }
    let report = world.run(args.duration, parallelism)?;
    let Some((width, height)) = args.render else {
        println!("{}", serde_json::to_string(&report)?);
        return Ok(());
    };
    let render = smlworld::app::running::bench_render::bench_render(&world, width, height, parallelism)?;
    let mut json = serde_json::to_value(&report)?;
    if let Some(object) = json.as_object_mut() {
        object.insert("render_ms_per_frame".into(), serde_json::json!(render.median_ms));
        object.insert("render".into(), serde_json::to_value(&render)?);
    }
    println!("{}", serde_json::to_string(&json)?);
    Ok(())
}
