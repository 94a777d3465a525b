//! `smlworld bench --soak SECONDS`: the benchmark world run for a wall-clock time while the
//! process's resident memory is sampled, to show that a long run does not grow: memory after the
//! warm-up stays within [`FLAT_TOLERANCE`] of what it was at the end of the warm-up.

use std::time::{Duration, Instant};

use crate::sim::Parallelism;

use super::bench::{BenchError, BenchWorld};

/// Largest growth of resident memory after the warm-up that still counts as flat [-] (5 %).
pub const FLAT_TOLERANCE: f64 = 0.05;

/// The warm-up [s of wall time]: the first minute, or a third of a shorter soak.
pub fn warm_up(wall_seconds: f64) -> f64 {
    60f64.min(wall_seconds / 3.0)
}

/// One sample of a soak.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct SoakSample {
    /// Wall time since the start of the run [s].
    pub wall_s: f64,
    /// Sim time reached [s].
    pub sim_s: f64,
    /// Resident memory of the process [MB].
    pub rss_mb: f64,
}

/// What a soak measured: printed as JSON by `smlworld bench --soak`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SoakReport {
    /// Number of vehicles.
    pub vehicles: usize,
    /// Wall time asked for [s].
    pub wall_seconds: f64,
    /// Sim time run [s].
    pub sim_seconds: f64,
    /// Warm-up excluded from the flatness check [s of wall time].
    pub warm_up_s: f64,
    /// Resident memory at the end of the warm-up [MB].
    pub rss_after_warm_up_mb: f64,
    /// Largest resident memory after the warm-up [MB].
    pub rss_max_after_warm_up_mb: f64,
    /// `rss_max_after_warm_up_mb / rss_after_warm_up_mb - 1` [-].
    pub growth: f64,
    /// `growth <= FLAT_TOLERANCE`.
    pub flat: bool,
    /// Whether Ctrl-C or SIGTERM ended the soak early.
    pub interrupted: bool,
    /// Every sample, in time order.
    pub samples: Vec<SoakSample>,
}

/// Resident memory of this process now [MB] (Linux `VmRSS`), if known.
pub fn rss_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// Run `world` for `wall_seconds` of wall time, sampling memory every `every` [s] (`on_sample`
/// sees each sample as it is taken, e.g. to print progress).
pub fn soak(
    world: &BenchWorld,
    wall_seconds: f64,
    every: f64,
    parallelism: Option<Parallelism>,
    mut on_sample: impl FnMut(&SoakSample),
) -> Result<SoakReport, BenchError> {
    let mut builder = world.builder()?;
    builder.insert_resource(parallelism.unwrap_or_default());
    let mut sim = builder.build();
    let start = Instant::now();
    let end = Duration::from_secs_f64(wall_seconds);
    let mut next_sample = Duration::ZERO;
    let mut samples = Vec::new();
    let mut interrupted = false;
    let mut sample = |sim_s: f64, wall: Duration, samples: &mut Vec<SoakSample>| {
        let s = SoakSample { wall_s: wall.as_secs_f64(), sim_s, rss_mb: rss_mb().unwrap_or(0.0) };
        on_sample(&s);
        samples.push(s);
    };
    loop {
        let wall = start.elapsed();
        if wall >= next_sample {
            sample(sim.now().as_secs(), wall, &mut samples);
            next_sample += Duration::from_secs_f64(every);
        }
        if wall >= end {
            break;
        }
        let report = super::run_headless(&mut sim, 0.5, 0.5, |_| {});
        if report.interrupted {
            interrupted = true;
            sample(sim.now().as_secs(), start.elapsed(), &mut samples);
            break;
        }
    }
    let warm = warm_up(wall_seconds);
    let after: Vec<&SoakSample> = samples.iter().filter(|s| s.wall_s >= warm).collect();
    let base = after.first().map_or(0.0, |s| s.rss_mb);
    let max = after.iter().map(|s| s.rss_mb).fold(base, f64::max);
    let growth = if base > 0.0 { max / base - 1.0 } else { 0.0 };
    Ok(SoakReport {
        vehicles: world.vehicles,
        wall_seconds,
        sim_seconds: sim.now().as_secs(),
        warm_up_s: warm,
        rss_after_warm_up_mb: base,
        rss_max_after_warm_up_mb: max,
        growth,
        flat: growth <= FLAT_TOLERANCE,
        interrupted,
        samples,
    })
}
