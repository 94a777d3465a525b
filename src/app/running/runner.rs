//! Runners: headless (as fast as possible) and real time (paced to the wall clock).
//!
//! Both run the same fixed steps in the same order, so they give the same results bit for bit;
//! the real-time runner only waits between steps, and when it falls behind it logs a
//! rate-limited warning naming the module and the lag, then catches up without skipping a step.
//! "Behind" compares sim time with the wall clock times the speed: a step that starts late
//! because a sleep overslept or the machine was busy for a moment is no warning as long as the
//! run catches up (waits again) within [`RealtimeRunner::tolerance`]; only a run that stays
//! behind that long, by more than a period of the module, cannot keep its rate.

use std::time::{Duration, Instant};

use crate::world::SimTime;

use crate::sim::Sim;

/// What a run did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunReport {
    /// Sim time covered \[s\].
    pub sim_seconds: f64,
    /// Wall-clock time taken \[s\].
    pub wall_seconds: f64,
    /// Rate warnings logged during this run.
    pub rate_warnings: u64,
    /// Largest lag behind the wall clock seen \[s\] (0 for headless runs).
    pub max_lag_seconds: f64,
    /// The run stopped early on Ctrl-C or SIGTERM ([`super::interrupt`]); `sim_seconds` is the
    /// sim time it reached.
    pub interrupted: bool,
}

/// Run headless for `seconds` \[s\], calling `progress` after every `chunk` \[s\] of sim time. A stop
/// signal ([`super::interrupt::requested`]) ends the run after the step that is running.
pub fn run_headless(sim: &mut Sim, seconds: f64, chunk: f64, mut progress: impl FnMut(&Sim)) -> RunReport {
    let wall = Instant::now();
    let start = sim.now();
    let end = SimTime(start.0 + SimTime::from_secs(seconds).0);
    let step = SimTime::from_secs(chunk).0.max(1);
    let mut t = start;
    let mut interrupted = false;
    'run: while t < end {
        t = SimTime((t.0 + step).min(end.0));
        // The same ticks as `sim.run_until(t)`, with a look at the stop flag before each.
        while let Some((_, due, _, _)) = sim.scheduler.peek() {
            if due >= t {
                break;
            }
            if super::interrupt::requested().is_some() {
                interrupted = true;
                break 'run;
            }
            sim.step();
        }
        sim.run_until(t);
        progress(sim);
    }
    RunReport {
        sim_seconds: if interrupted { SimTime(sim.now().0 - start.0).as_secs() } else { seconds },
        wall_seconds: wall.elapsed().as_secs_f64(),
        rate_warnings: 0,
        max_lag_seconds: 0.0,
        interrupted,
    }
}

/// Paces a [`Sim`] to the wall clock times `speed`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RealtimeRunner {
    /// Sim seconds per wall second (1 = real time, 2 = twice as fast).
    pub speed: f64,
    /// At most one rate warning per this wall time \[s\].
    pub warn_interval: f64,
    /// Wall time \[s\] the run may stay behind the scaled wall clock without catching up before
    /// it counts as not keeping its rate (what an oversleeping `sleep` or a busy moment of the
    /// machine costs is no warning).
    pub tolerance: f64,
}

impl Default for RealtimeRunner {
    fn default() -> Self {
        RealtimeRunner { speed: 1.0, warn_interval: 1.0, tolerance: 0.2 }
    }
}

impl RealtimeRunner {
    /// Real time scaled by `speed` (> 0; anything else counts as 1).
    pub fn new(speed: f64) -> RealtimeRunner {
        let speed = if speed.is_finite() && speed > 0.0 { speed } else { 1.0 };
        RealtimeRunner { speed, ..Default::default() }
    }

    /// Run for `seconds` \[s\] of sim time, calling `progress` after every `chunk` \[s\] of sim time.
    pub fn run(&self, sim: &mut Sim, seconds: f64, chunk: f64, mut progress: impl FnMut(&Sim)) -> RunReport {
        let wall = Instant::now();
        let start = sim.now();
        let end = SimTime(start.0 + SimTime::from_secs(seconds).0);
        let chunk = SimTime::from_secs(chunk).0.max(1);
        let mut next_progress = start.0 + chunk;
        let mut last_warning: Option<Instant> = None;
        let mut warnings = 0;
        let mut max_lag: f64 = 0.0;
        let mut interrupted = false;
        // Since when (wall clock) every step has started late, without a wait in between.
        let mut behind_since: Option<Instant> = None;
        while let Some((_, due, name, period)) = sim.scheduler.peek() {
            if due >= end {
                break;
            }
            if super::interrupt::requested().is_some() {
                interrupted = true;
                break;
            }
            let target = Duration::from_secs_f64((due.0 - start.0) as f64 * 1e-6 / self.speed);
            let elapsed = wall.elapsed();
            if elapsed < target {
                behind_since = None;
                std::thread::sleep(target - elapsed);
            } else {
                let lag = (elapsed - target).as_secs_f64();
                max_lag = max_lag.max(lag);
                let since = *behind_since.get_or_insert_with(Instant::now);
                let quiet = last_warning.is_some_and(|w| w.elapsed().as_secs_f64() < self.warn_interval);
                let stays_behind = since.elapsed().as_secs_f64() >= self.tolerance;
                if lag > period / self.speed && stays_behind && !quiet {
                    tracing::warn!(
                        "module {name} cannot keep its rate ({:.1} Hz): {:.3} s behind the wall clock at sim time {due}; catching up with fixed steps",
                        1.0 / period,
                        lag
                    );
                    last_warning = Some(Instant::now());
                    warnings += 1;
                }
            }
            sim.step();
            while due.0 >= next_progress {
                progress(sim);
                next_progress += chunk;
            }
        }
        if !interrupted {
            sim.run_until(end);
        }
        progress(sim);
        sim.rate_warnings += warnings;
        RunReport {
            sim_seconds: if interrupted { SimTime(sim.now().0 - start.0).as_secs() } else { seconds },
            wall_seconds: wall.elapsed().as_secs_f64(),
            rate_warnings: warnings,
            max_lag_seconds: max_lag,
            interrupted,
        }
    }
}
