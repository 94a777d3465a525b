//! `smlworld run`: run a scenario headless or in real time; write trajectories.csv and summary.json
//! (a thin caller of [`smlworld::app::run_scenario`]).

use std::path::PathBuf;

use smlworld::app::{RunOptions, run_scenario};

/// Arguments of `smlworld run`.
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Scenario file (TOML).
    pub scenario: PathBuf,
    /// Sim time to run [s] (default: the scenario's `duration`).
    #[arg(long, value_parser = super::range::positive)]
    pub duration: Option<f64>,
    /// Pace the run to the wall clock instead of running as fast as possible.
    #[arg(long)]
    pub realtime: bool,
    /// Sim seconds per wall second in a real-time run.
    #[arg(long, default_value_t = 1.0, requires = "realtime", value_parser = super::range::positive)]
    pub speed: f64,
    /// Output folder for trajectories.csv and summary.json (created if missing).
    #[arg(long, default_value = "out")]
    pub out: PathBuf,
    /// Trajectory log rate [Hz] (default: the scenario's `rates.log`).
    #[arg(long, value_parser = super::range::rate_hz)]
    pub log_rate: Option<f64>,
    /// Frames and GIF of the bird's-eye view.
    #[command(flatten)]
    pub frame_output: smlworld::render::FrameOutput,
    /// Draw radar cones and velodyne circles in the frames.
    #[arg(long)]
    pub sensor_ranges: bool,
    /// Stream the vehicles over UDP (the 2015 lab's packet layout, 50 Hz; class names and
    /// reference point as --stream-format says) to ADDR (default 127.0.0.1:38008) for `smlworld view`.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:38008")]
    pub stream: Option<std::net::SocketAddr>,
    /// Class names and reference point of --stream: `smlworld` (ours: `Car`, `Truck`, ...; x, y the
    /// body centre) or `2015` (what the 2015 viewers draw: `SmartVehicle`, `DummyVehicle`; x, y the
    /// rear-axle point).
    #[arg(long, value_name = "FORMAT", default_value = "smlworld", value_parser = parse_stream_format)]
    pub stream_format: smlworld::io::viz::StreamFormat,
    /// MCAP recording and the Foxglove live view.
    #[command(flatten)]
    pub foxglove: smlworld::app::results::foxglove::FoxgloveOutput,
    /// Write figures (speed, gaps, platoons, lateral deviation, trace; PNG + SVG) into OUT/plots.
    #[arg(long)]
    pub plots: bool,
    /// Replace the scenario's `seed`.
    #[arg(long)]
    pub seed: Option<u64>,
    /// Most threads the per-vehicle systems use; above 1 they split at any vehicle count (the
    /// results are the same bits for any N). Default: the machine's cores, at most 4, from
    /// 2,000 vehicles on.
    #[arg(long, value_name = "N", value_parser = super::range::threads())]
    pub threads: Option<usize>,
    /// Override a scenario key (repeatable, applied in order): dotted keys, an index or `*` for
    /// the elements of an array, the value as TOML (`--set 'vehicles.*.speed=12.5'`,
    /// `--set traffic.0.count=80`, `--set v2v.wifi.loss=0.1`).
    #[arg(long = "set", value_name = "KEY=VALUE", value_parser = parse_set)]
    pub set: Vec<(String, toml::Value)>,
}

/// `--set KEY=VALUE` (see [`smlworld::app::running::scenario::parse_override`]).
pub fn parse_set(text: &str) -> Result<(String, toml::Value), String> {
    smlworld::app::running::scenario::parse_override(text)
}

/// Run the subcommand.
pub fn main(args: RunArgs) -> anyhow::Result<()> {
    let options = RunOptions {
        out: args.out,
        duration: args.duration,
        realtime: args.realtime,
        speed: args.speed,
        log_rate: args.log_rate,
        frame_output: args.frame_output,
        sensor_ranges: args.sensor_ranges,
        stream: args.stream,
        stream_format: args.stream_format,
        progress: true,
        plots: args.plots,
        plugins: Vec::new(),
        seed: args.seed,
        foxglove: args.foxglove,
        overrides: args.set,
        threads: args.threads,
    };
    // Ctrl-C / SIGTERM: the run stops after its step and writes what it has (exit 130 / 143).
    smlworld::app::running::interrupt::install();
    run_scenario(args.scenario, options)?;
    Ok(())
}

/// `--stream-format smlworld|2015` (see [`smlworld::io::viz::StreamFormat`]).
pub fn parse_stream_format(text: &str) -> Result<smlworld::io::viz::StreamFormat, String> {
    text.parse()
}
