//! The progress bar of long runs and replays on a terminal (`indicatif`), with an estimate of
//! the time left that waits for a warm-up: the first chunk of a run (start-up, first frames,
//! page faults) says nothing about the rest, and an estimate from it read "eta 6m" for a 6 s run.

use std::io::IsTerminal;
use std::time::Duration;

/// Wall time \[s\] a bar runs before it estimates the time left.
pub const ETA_WARMUP_S: f64 = 2.0;
/// Fraction of the work done before the bar estimates the time left.
pub const ETA_WARMUP_FRACTION: f64 = 0.02;

/// The time left after `elapsed` with `fraction` (0..=1) of the work done, at the mean pace so
/// far, as the bar shows it (`12s`, `3m`); `…` during the warm-up ([`ETA_WARMUP_S`] and
/// [`ETA_WARMUP_FRACTION`]) or when nothing is known.
pub fn eta_text(elapsed: Duration, fraction: f64) -> String {
    let secs = elapsed.as_secs_f64();
    if !(fraction.is_finite() && secs.is_finite()) || secs < ETA_WARMUP_S || fraction < ETA_WARMUP_FRACTION {
        return "…".to_string();
    }
    let left = secs * (1.0 - fraction.min(1.0)) / fraction;
    format!("{:#}", indicatif::HumanDuration(Duration::from_secs_f64(left.max(0.0))))
}

/// A bar over `total` \[s\] of sim time, drawn on stderr when it is a terminal and `show`; `None`
/// otherwise. Positions are milliseconds of sim time ([`set_progress`]).
pub fn sim_time_bar(total: f64, show: bool) -> Option<indicatif::ProgressBar> {
    if !(show && std::io::stderr().is_terminal() && total.is_finite() && total > 0.0) {
        return None;
    }
    let bar = indicatif::ProgressBar::new((total * 1000.0).round() as u64);
    let style = indicatif::ProgressStyle::with_template("{bar:40} {msg} sim s, {elapsed} elapsed, eta {smlworld_eta}")
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
        .with_key("smlworld_eta", |state: &indicatif::ProgressState, w: &mut dyn std::fmt::Write| {
            let _ = w.write_str(&eta_text(state.elapsed(), f64::from(state.fraction())));
        });
    bar.set_style(style);
    Some(bar)
}

/// Show sim time `t` \[s\] of `total` on `bar`.
pub fn set_progress(bar: &indicatif::ProgressBar, t: f64, total: f64) {
    bar.set_position((t * 1000.0).round() as u64);
    bar.set_message(format!("{t:.0}/{total:.0}"));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_estimate_during_the_warm_up() {
        // The first chunk of a 6 s run: 0.1 s for 1/600 of it would say "eta 60s" or worse.
        assert_eq!(eta_text(Duration::from_millis(100), 1.0 / 600.0), "…");
        assert_eq!(eta_text(Duration::from_secs(5), 0.001), "…", "too little done");
        assert_eq!(eta_text(Duration::from_secs(1), 0.5), "…", "too early");
        assert_eq!(eta_text(Duration::from_secs(3), f64::NAN), "…");
    }

    #[test]
    fn after_the_warm_up_the_mean_pace_estimates() {
        assert_eq!(eta_text(Duration::from_secs(3), 0.5), "3s");
        assert_eq!(eta_text(Duration::from_secs(10), 0.25), "30s");
        assert_eq!(eta_text(Duration::from_secs(10), 1.0), "0s");
    }
}
