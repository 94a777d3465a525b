//! `smlworld bench`: the whole simulation with N vehicles, every module on; prints JSON naming
//! the map, vehicles, sensors, rates, threads and each module's share of the wall time.

use smlworld::app::bench::BenchWorld;
use smlworld::sim::Parallelism;

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
    /// Every vehicle drives the IDM and changes lanes (MOBIL) instead of plain path following.
    #[arg(long)]
    pub lane_change: bool,
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
    let world = BenchWorld { vehicles: args.vehicles, lane_change: args.lane_change, ..Default::default() };
    let parallelism = args.threads.map(|threads| Parallelism { threads, ..Default::default() });
    let report = world.run(args.duration, parallelism)?;
    println!("{}", serde_json::to_string(&report)?);
    Ok(())
}
