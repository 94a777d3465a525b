//! `smlworld replay OUT_DIR`: redraw a finished run without simulating (a thin caller of
//! [`smlworld::app::replay_run`]).

use std::path::PathBuf;

use smlworld::app::{ReplayOptions, replay_run};

/// Arguments of `smlworld replay`.
#[derive(Debug, clap::Args)]
pub struct ReplayArgs {
    /// Output folder of a run (holds trajectories.csv and summary.json).
    pub out_dir: PathBuf,
    /// Write an animated GIF of the run.
    #[arg(long, value_name = "FILE.gif")]
    pub gif: Option<PathBuf>,
    /// Write numbered PNG frames into this folder.
    #[arg(long, value_name = "DIR")]
    pub frames: Option<PathBuf>,
    /// Send the vehicles over UDP (2015 visualisation format, 50 Hz of sim time) to ADDR
    /// (default 127.0.0.1:38008), paced to the wall clock, for `smlworld view`.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:38008")]
    pub stream: Option<std::net::SocketAddr>,
    /// Class names and reference point of --stream: `smlworld` (ours: `Car`, `Truck`, ...; x, y the
    /// body centre) or `2015` (what the 2015 viewers draw: `SmartVehicle`, `DummyVehicle`; x, y the
    /// rear-axle point).
    #[arg(long, value_name = "FORMAT", default_value = "smlworld", value_parser = super::run::parse_stream_format)]
    pub stream_format: smlworld::io::viz::StreamFormat,
    /// Sim seconds per wall second of --stream (2 = twice as fast as recorded).
    #[arg(long, default_value_t = 1.0, value_parser = super::range::positive)]
    pub speed: f64,
    /// Draw a time stamp and a legend (classes; real vs virtual) on every frame (default: on the GIF only).
    #[arg(long, conflicts_with = "no_overlay")]
    pub overlay: bool,
    /// No time stamp and legend, not even on the GIF.
    #[arg(long)]
    pub no_overlay: bool,
    /// Frames per second of sim time for --frames and --gif [Hz].
    #[arg(long, default_value_t = 10.0, value_parser = super::range::positive)]
    pub frame_rate: f64,
    /// Frame width [px] for --frames and --gif.
    #[arg(long, default_value_t = 1280, value_parser = super::range::pixels())]
    pub width: u32,
    /// Frame height [px] for --frames and --gif.
    #[arg(long, default_value_t = 720, value_parser = super::range::pixels())]
    pub height: u32,
}

/// Run the subcommand.
pub fn main(args: ReplayArgs) -> anyhow::Result<()> {
    let options = ReplayOptions {
        frames: args.frames,
        gif: args.gif,
        stream: args.stream,
        stream_format: args.stream_format,
        speed: args.speed,
        frame_rate: args.frame_rate,
        width: args.width,
        height: args.height,
        overlay: super::run::overlay(args.overlay, args.no_overlay),
    };
    smlworld::app::interrupt::install();
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
