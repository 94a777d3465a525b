//! `smlworld run`: run a scenario headless or in real time; write trajectories.csv and summary.json.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::Context;
use smlworld::app::{RealtimeRunner, RunSummary, Scenario, TrajectoryLog, TrajectoryLogPlugin, run_headless};
use smlworld::io::lab::VizStreamPlugin;
use smlworld::io::viz::DEFAULT_VIZ_RATE_HZ;
use smlworld::render::{FrameRecorder, RecorderOptions};

/// Arguments of `smlworld run`.
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// Scenario file (TOML).
    pub scenario: PathBuf,
    /// Sim time to run [s] (default: the scenario's `duration`).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Pace the run to the wall clock instead of running as fast as possible.
    #[arg(long)]
    pub realtime: bool,
    /// Sim seconds per wall second in a real-time run.
    #[arg(long, default_value_t = 1.0, requires = "realtime")]
    pub speed: f64,
    /// Output folder for trajectories.csv and summary.json (created if missing).
    #[arg(long, default_value = "out")]
    pub out: PathBuf,
    /// Trajectory log rate [Hz] (default: the scenario's `rates.log`).
    #[arg(long)]
    pub log_rate: Option<f64>,
    /// Write numbered PNG frames of the bird's-eye view into this folder.
    #[arg(long, value_name = "DIR")]
    pub frames: Option<PathBuf>,
    /// Write an animated GIF of the run.
    #[arg(long, value_name = "FILE.gif")]
    pub gif: Option<PathBuf>,
    /// Frames per second of sim time for --frames and --gif [Hz]; does not change the results.
    #[arg(long, default_value_t = 10.0)]
    pub frame_rate: f64,
    /// Frame width [px] for --frames and --gif.
    #[arg(long, default_value_t = 1280)]
    pub width: u32,
    /// Frame height [px] for --frames and --gif.
    #[arg(long, default_value_t = 720)]
    pub height: u32,
    /// Draw radar cones and velodyne circles in the frames.
    #[arg(long)]
    pub sensor_ranges: bool,
    /// Stream the vehicles over UDP (2015 visualisation format, 50 Hz) to ADDR (default
    /// 127.0.0.1:38008) for `smlworld view`.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:38008")]
    pub stream: Option<std::net::SocketAddr>,
}

/// Run the subcommand.
pub fn main(args: RunArgs) -> anyhow::Result<()> {
    let scenario = Scenario::load(&args.scenario)?;
    let duration = args.duration.unwrap_or(scenario.file.duration);
    anyhow::ensure!(
        duration.is_finite() && duration > 0.0,
        "--duration must be a positive number of seconds, got {duration}"
    );
    anyhow::ensure!(
        args.speed.is_finite() && args.speed > 0.0,
        "--speed must be a positive factor, got {}",
        args.speed
    );
    let log_rate = args.log_rate.unwrap_or(scenario.file.rates.log);
    anyhow::ensure!(
        log_rate.is_finite() && log_rate > 0.0 && log_rate <= 1e6,
        "--log-rate must be in (0, 1e6] Hz, got {log_rate}"
    );
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create the output folder {}", args.out.display()))?;
    let csv_path = args.out.join("trajectories.csv");
    let csv = std::fs::File::create(&csv_path).with_context(|| format!("cannot create {}", csv_path.display()))?;

    // Motion capture measures the lab in wall-clock time: such a scenario runs in real time.
    let wall_clock = scenario.file.lab.as_ref().is_some_and(|l| l.needs_wall_clock());
    anyhow::ensure!(
        !wall_clock || args.speed == 1.0,
        "--speed must be 1 with motion capture (`[lab] mocap`): the lab runs in real time"
    );
    let realtime = args.realtime || wall_clock;
    if wall_clock && !args.realtime {
        tracing::info!("the scenario uses motion capture: running in real time");
    }

    let mut builder = scenario.builder()?;
    if let Some(addr) = args.stream {
        builder.add_plugin(VizStreamPlugin::new(addr, DEFAULT_VIZ_RATE_HZ)?);
        tracing::info!(
            "streaming the vehicles to udp://{addr} at {DEFAULT_VIZ_RATE_HZ} Hz (watch with `smlworld view`)"
        );
        if !realtime {
            tracing::warn!("--stream without --realtime: the stream runs at sim time, as fast as the run goes");
        }
    }
    builder.insert_resource(TrajectoryLog::new(Box::new(std::io::BufWriter::new(csv))));
    builder.add_plugin(TrajectoryLogPlugin { rate: log_rate });
    let mut sim = builder.build();
    let mut recorder = recorder(&scenario, &args)?;
    let mut record_error = None;
    // Record at the frame rate; without a recorder report progress every sim second. The chunk
    // only decides when the callback runs, never what the simulation computes.
    let chunk = if recorder.is_some() { 1.0 / args.frame_rate } else { 1.0 };

    let bar = (std::io::stderr().is_terminal() && duration >= 30.0).then(|| {
        let bar = indicatif::ProgressBar::new((duration * 1000.0).round() as u64);
        bar.set_style(
            indicatif::ProgressStyle::with_template("{bar:40} {msg} sim s, {elapsed} elapsed, eta {eta}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar
    });
    let progress = |sim: &smlworld::app::Sim| {
        if let Some(rec) = recorder.as_mut().filter(|_| record_error.is_none()) {
            if let Err(e) = rec.record(sim.world()) {
                record_error = Some(e);
            }
        }
        if let Some(bar) = &bar {
            let t = sim.now().as_secs();
            bar.set_position((t * 1000.0).round() as u64);
            bar.set_message(format!("{t:.0}/{duration:.0}"));
        }
    };
    let report = if realtime {
        RealtimeRunner::new(args.speed).run(&mut sim, duration, chunk, progress)
    } else {
        run_headless(&mut sim, duration, chunk, progress)
    };
    if let Some(e) = record_error {
        return Err(e).context("recording frames");
    }
    if let Some(rec) = &recorder {
        let to: Vec<String> = args.frames.iter().chain(&args.gif).map(|p| p.display().to_string()).collect();
        tracing::info!("recorded {} frames at {} Hz into {}", rec.frames(), args.frame_rate, to.join(" and "));
    }
    drop(recorder);
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    sim.world_mut()
        .resource_mut::<TrajectoryLog>()
        .finish()
        .with_context(|| format!("cannot write {}", csv_path.display()))?;

    let summary = RunSummary::new(&sim, &report);
    let summary_path = args.out.join("summary.json");
    let json = serde_json::to_string_pretty(&summary)?;
    std::fs::write(&summary_path, format!("{json}\n"))
        .with_context(|| format!("cannot write {}", summary_path.display()))?;
    let worst = summary.max_distance_to_centre_line.values().copied().fold(0.0, f64::max);
    tracing::info!(
        "{} vehicles, {:.1} sim s in {:.2} wall s ({:.1}x real time), seed {}, max distance to centre line {:.3} m; wrote {} and {}",
        summary.vehicles,
        summary.sim_seconds,
        summary.wall_seconds,
        summary.real_time_factor,
        summary.seed,
        worst,
        csv_path.display(),
        summary_path.display()
    );
    Ok(())
}

/// The frame recorder when `--frames` or `--gif` is given.
fn recorder(scenario: &Scenario, args: &RunArgs) -> anyhow::Result<Option<FrameRecorder>> {
    if args.frames.is_none() && args.gif.is_none() {
        return Ok(None);
    }
    anyhow::ensure!(
        args.frame_rate.is_finite() && args.frame_rate > 0.0 && args.frame_rate <= 1000.0,
        "--frame-rate must be in (0, 1000] Hz, got {}",
        args.frame_rate
    );
    let map = scenario.map.as_ref().with_context(|| {
        format!("--frames/--gif draw the scenario's map, but {} names no `map`", scenario.path.display())
    })?;
    let opts = RecorderOptions {
        frames_dir: args.frames.clone(),
        gif: args.gif.clone(),
        frame_rate: args.frame_rate,
        width: args.width,
        height: args.height,
        sensor_ranges: args.sensor_ranges,
    };
    Ok(Some(FrameRecorder::new(map, &opts)?))
}
