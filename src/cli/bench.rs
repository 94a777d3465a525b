//! `smlworld bench`: the whole simulation with N vehicles, every module on; prints JSON.

use smlworld::app::bench::BenchWorld;
use smlworld::sim::{Dynamics, Parallelism};

/// Arguments of `smlworld bench`.
#[derive(Debug, clap::Args)]
pub struct BenchArgs {
    /// Number of vehicles.
    #[arg(long, default_value_t = 1000)]
    pub vehicles: usize,
    /// Sim time to run [s].
    #[arg(long, default_value_t = 10.0)]
    pub duration: f64,
    /// Threads of the per-vehicle systems (default: the machine's cores, at most 4).
    #[arg(long)]
    pub threads: Option<usize>,
}

/// What `smlworld bench` prints.
#[derive(Debug, serde::Serialize)]
struct BenchReport {
    /// Number of vehicles.
    vehicles: usize,
    /// Sim time run [s].
    sim_seconds: f64,
    /// Wall time of the run, set-up excluded [s].
    wall_seconds: f64,
    /// Sim seconds per wall second.
    real_time_factor: f64,
    /// Vehicle dynamics steps (vehicles x dynamics ticks) per wall second.
    vehicle_steps_per_second: f64,
    /// Peak resident memory of the process [MB].
    peak_rss_mb: Option<f64>,
}

/// Peak resident memory of this process [MB] (Linux `VmHWM`), if known.
fn peak_rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
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
    let world = BenchWorld { vehicles: args.vehicles, ..Default::default() };
    let setup = std::time::Instant::now();
    let mut builder = world.builder()?;
    if let Some(threads) = args.threads {
        anyhow::ensure!(threads > 0, "--threads must be at least 1, got 0");
        builder.insert_resource(Parallelism { threads, ..Default::default() });
    }
    let mut sim = builder.build();
    tracing::debug!("set up {} vehicles in {:.2} s", args.vehicles, setup.elapsed().as_secs_f64());
    let wall = std::time::Instant::now();
    sim.run_for(args.duration);
    let wall_seconds = wall.elapsed().as_secs_f64();
    let steps = sim.scheduler().ticks(Dynamics).unwrap_or(0) as f64 * args.vehicles as f64;
    let report = BenchReport {
        vehicles: args.vehicles,
        sim_seconds: args.duration,
        wall_seconds,
        real_time_factor: args.duration / wall_seconds,
        vehicle_steps_per_second: steps / wall_seconds,
        peak_rss_mb: peak_rss_mb(),
    };
    println!("{}", serde_json::to_string(&report)?);
    Ok(())
}
