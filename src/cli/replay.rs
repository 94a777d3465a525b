//! `smlworld replay OUT_DIR`: redraw a finished run without simulating (a thin caller of
//! [`smlworld::app::replay_run`]).

use std::path::PathBuf;

use smlworld::app::{ReplayOptions, replay_run};

/// Arguments of `smlworld replay`.
#[derive(Debug, clap::Args)]
pub struct ReplayArgs {
    /// Output folder of a run (holds trajectories.csv and summary.json).
    pub out_dir: PathBuf,
    /// Frames and GIF of the bird's-eye view.
    #[command(flatten)]
    pub frame_output: smlworld::render::FrameOutput,
    /// Send the vehicles over UDP (the 2015 lab's packet layout, 50 Hz of sim time; class names
    /// and reference point as --stream-format says) to ADDR (default 127.0.0.1:38008), paced to
    /// the wall clock, for `smlworld view`.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:38008")]
    pub stream: Option<std::net::SocketAddr>,
    /// Class names and reference point of --stream: `smlworld` (ours: `Car`, `Truck`, ...; x, y the
    /// body centre) or `2015` (what the 2015 viewers draw: `SmartVehicle`, `DummyVehicle`; x, y the
    /// rear-axle point).
    #[arg(long, value_name = "FORMAT", default_value = "smlworld", value_parser = super::run::parse_stream_format)]
    pub stream_format: smlworld::io::viz::StreamFormat,
    /// Write the run as an MCAP file (Foxglove schemas, zstd chunks, indexed) to FILE.
    #[arg(long, value_name = "FILE")]
    pub mcap: Option<PathBuf>,
    /// Sim seconds per wall second of --stream (2 = twice as fast as recorded).
    #[arg(long, default_value_t = 1.0, value_parser = super::range::positive)]
    pub speed: f64,
}

/// Run the subcommand.
pub fn main(args: ReplayArgs) -> anyhow::Result<()> {
    let options = ReplayOptions {
        frame_output: args.frame_output,
        stream: args.stream,
        stream_format: args.stream_format,
        speed: args.speed,
        mcap: args.mcap,
    };
    smlworld::app::running::interrupt::install();
    let report = replay_run(&args.out_dir, &options)?;
    let what = if report.interrupted { "interrupted after" } else { "replayed" };
    tracing::info!(
        "{what} {} rows of {}: {} frames drawn, {} stream frames sent",
        report.rows,
        args.out_dir.display(),
        report.frames,
        report.datagram_frames
    );
    Ok(())
}
