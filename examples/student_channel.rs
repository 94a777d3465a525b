//! A complete channel model in one file: copy it to start your own.
//!
//! `LogDistance` is the textbook log-distance path loss with log-normal shadowing: the power a
//! receiver gets is `P_rx = P_tx - PL(1 m) - 10 n log10(d / 1 m) + X` [dBm], with `X` normal of
//! standard deviation `σ` [dB] drawn anew for each reception; the message arrives when `P_rx` is
//! at least the receiver's sensitivity. So a reception at distance `d` is delivered with
//! probability `Φ((P_tx - PL(1 m) - 10 n log10 d - sensitivity) / σ)` ([`LogDistance::delivery_ratio`]).
//! Its plugin registers it under a name, so `scenarios/student_channel.toml` names it like a
//! built-in model: `[v2v.wifi] loss = { model = "log_distance", exponent = 3.0, ... }`.
//!
//! Run it: `cargo run --release --example student_channel [SCENARIO] [OUT_DIR]`
//! (default `scenarios/student_channel.toml`, `out/student_channel`): it writes
//! `trajectories.csv` and `summary.json` like `smlworld run`.

use smlworld::prelude::*;
use smlworld::sim::{ChannelLossModel, LinkContext};

/// The model's parameters, read from the channel's `loss` table.
#[derive(serde::Deserialize, Debug, Clone, Copy)]
#[serde(deny_unknown_fields)]
pub struct LogDistance {
    /// Transmit power [dBm].
    pub tx_power_dbm: f64,
    /// Path loss at the reference distance of 1 m [dB].
    pub loss_at_1m_db: f64,
    /// Path-loss exponent [-]: 2 in free space, 2.7-3.5 between vehicles in traffic.
    pub exponent: f64,
    /// Standard deviation of the shadowing [dB]; 0 makes the range a sharp edge.
    pub shadowing_sd_db: f64,
    /// Weakest power the receiver decodes [dBm].
    pub sensitivity_dbm: f64,
}

impl LogDistance {
    /// Mean received power at `distance` [m] (closer than 1 m counts as 1 m) [dBm].
    pub fn mean_power_dbm(&self, distance: f64) -> f64 {
        self.tx_power_dbm - self.loss_at_1m_db - 10.0 * self.exponent * distance.max(1.0).log10()
    }

    /// Probability that a reception at `distance` [m] is delivered [-].
    pub fn delivery_ratio(&self, distance: f64) -> f64 {
        let margin = self.mean_power_dbm(distance) - self.sensitivity_dbm;
        if self.shadowing_sd_db == 0.0 {
            return if margin >= 0.0 { 1.0 } else { 0.0 };
        }
        normal_cdf(margin / self.shadowing_sd_db)
    }
}

/// The standard normal distribution function, by the complementary error function of Numerical
/// Recipes (`erfcc`, fractional error below 1.2e-7).
pub fn normal_cdf(x: f64) -> f64 {
    let z = x.abs() / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -z * z - 1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98 + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    let erfc = t * poly.exp();
    if x >= 0.0 { 1.0 - 0.5 * erfc } else { 0.5 * erfc }
}

impl ChannelLossModel for LogDistance {
    fn check(&self) -> Result<(), (String, String)> {
        if !(self.exponent.is_finite() && self.exponent > 0.0) {
            return Err(("exponent".into(), format!("must be positive, got {}", self.exponent)));
        }
        if !(self.shadowing_sd_db.is_finite() && self.shadowing_sd_db >= 0.0) {
            return Err(("shadowing_sd_db".into(), format!("must be zero or more [dB], got {}", self.shadowing_sd_db)));
        }
        Ok(())
    }

    /// Delivered (no extra delay) when the shadowed power reaches the sensitivity. The draw is
    /// the reception's own counter-based word, so any thread count gives the same fates.
    fn deliver(&self, link: &LinkContext, _state: &mut u64) -> Option<f64> {
        let shadowing = self.shadowing_sd_db * link.words().normal();
        (self.mean_power_dbm(link.distance) + shadowing >= self.sensitivity_dbm).then_some(0.0)
    }
}

/// The plugin: registers the model's name.
pub struct LogDistancePlugin;

impl Plugin for LogDistancePlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.register_channel_model::<LogDistance>("log_distance");
    }
}

/// Run the scenario named on the command line (default `scenarios/student_channel.toml`).
pub fn main() {
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    let _ = tracing_subscriber::fmt().with_writer(std::io::stderr).with_ansi(ansi).try_init();
    let mut args = std::env::args().skip(1);
    let scenario = args.next().unwrap_or_else(|| "scenarios/student_channel.toml".into());
    let out = args.next().unwrap_or_else(|| "out/student_channel".into());
    match run_scenario(scenario.as_str(), RunOptions::default().out(&out).plugin(LogDistancePlugin)) {
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
