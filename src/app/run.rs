//! One call that does what `smlworld run` does: [`run_scenario`] loads a scenario (with the
//! controllers your plugins register), runs it headless or in real time, and writes
//! `trajectories.csv`, `trips.csv`, `summary.json` and optional frames, GIF and UDP stream.
//!
//! ```no_run
//! use smlworld::prelude::*;
//!
//! let summary = run_scenario("scenarios/highway.toml", RunOptions::default().out("out/highway")).expect("the shipped scenario runs");
//! println!("{} vehicles, {:.1}x real time", summary.vehicles, summary.real_time_factor);
//! ```

use std::io::IsTerminal;
use std::net::SocketAddr;
use std::path::{Path as FsPath, PathBuf};

use crate::io::lab::VizStreamPlugin;
use crate::io::viz::DEFAULT_VIZ_RATE_HZ;
use crate::render::{FrameOutput, FrameRecorder, RenderError, VehicleSprite};
use crate::sim::{Parallelism, Plugin, Sim, SimBuilder};
use bevy_ecs::schedule::IntoScheduleConfigs;

use super::results::output::{TrajectoryLog, TrajectoryLogPlugin};
use super::running::runner::{RealtimeRunner, RunReport};
use super::running::scenario::{Scenario, ScenarioError};
use super::running::summary::RunSummary;

/// What to run: a scenario file, or a scenario already loaded.
pub enum ScenarioSource {
    /// A scenario file (TOML), loaded with the controllers the run's plugins register.
    File(PathBuf),
    /// A scenario already parsed (with [`Scenario::load_with`] if it names registered controllers).
    Loaded(Box<Scenario>),
}

impl From<&str> for ScenarioSource {
    fn from(path: &str) -> Self {
        ScenarioSource::File(path.into())
    }
}

impl From<&FsPath> for ScenarioSource {
    fn from(path: &FsPath) -> Self {
        ScenarioSource::File(path.into())
    }
}

impl From<PathBuf> for ScenarioSource {
    fn from(path: PathBuf) -> Self {
        ScenarioSource::File(path)
    }
}

impl From<Scenario> for ScenarioSource {
    fn from(scenario: Scenario) -> Self {
        ScenarioSource::Loaded(Box::new(scenario))
    }
}

/// How to run a scenario and what to write; the defaults are those of `smlworld run`.
pub struct RunOptions {
    /// Output folder for `trajectories.csv`, `trips.csv` and `summary.json` (created if missing).
    pub out: PathBuf,
    /// Sim time to run \[s\] (default: the scenario's `duration`).
    pub duration: Option<f64>,
    /// Pace the run to the wall clock instead of running as fast as possible.
    pub realtime: bool,
    /// Sim seconds per wall second in a real-time run.
    pub speed: f64,
    /// Trajectory log rate \[Hz\] (default: the scenario's `rates.log`).
    pub log_rate: Option<f64>,
    /// Frames and GIF of the bird's-eye view: outputs, size, rate, overlay and window (the
    /// arguments `smlworld run` shares with `replay` and `view`).
    pub frame_output: FrameOutput,
    /// Draw radar cones and velodyne circles in the frames.
    pub sensor_ranges: bool,
    /// Stream the vehicles over UDP (2015 visualisation format) to this address.
    pub stream: Option<SocketAddr>,
    /// Class names and reference point of the stream (see [`crate::io::viz::StreamFormat`]).
    pub stream_format: crate::io::viz::StreamFormat,
    /// Show a progress bar on a terminal for runs of 30 sim s or more.
    pub progress: bool,
    /// Write the figures of `smlworld plot` into `out/plots` at the end of the run.
    pub plots: bool,
    /// Your plugins (controllers they register can be named in the scenario), added before the
    /// scenario's built-in plugins and vehicles.
    pub plugins: Vec<Box<dyn Plugin>>,
    /// Replaces the scenario's `seed` [-].
    pub seed: Option<u64>,
    /// MCAP recording and the Foxglove live view (`--mcap`, `--mcap-images`, `--foxglove`).
    pub foxglove: super::results::foxglove::FoxgloveOutput,
    /// Dotted-key overrides of the scenario file, applied in order before it is checked (see
    /// [`super::running::scenario::overrides`]); needs a scenario file, not a loaded scenario.
    pub overrides: Vec<(String, toml::Value)>,
    /// Most threads the per-vehicle systems use; above 1 they split the vehicles at any vehicle
    /// count (default: [`Parallelism::default`], which splits from 2,000 vehicles on). The
    /// results are the same bits for any value.
    pub threads: Option<usize>,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            out: PathBuf::from("out"),
            duration: None,
            realtime: false,
            speed: 1.0,
            log_rate: None,
            frame_output: FrameOutput::default(),
            sensor_ranges: false,
            stream: None,
            stream_format: crate::io::viz::StreamFormat::Smlworld,
            progress: true,
            plots: false,
            plugins: Vec::new(),
            seed: None,
            foxglove: Default::default(),
            overrides: Vec::new(),
            threads: None,
        }
    }
}

impl RunOptions {
    /// Add a plugin of yours (for example one that registers a controller).
    pub fn plugin(mut self, plugin: impl Plugin + 'static) -> Self {
        self.plugins.push(Box::new(plugin));
        self
    }

    /// Set the output folder.
    pub fn out(mut self, out: impl Into<PathBuf>) -> Self {
        self.out = out.into();
        self
    }

    /// Set the sim time to run \[s\].
    pub fn duration(mut self, seconds: f64) -> Self {
        self.duration = Some(seconds);
        self
    }
}

/// What can stop a run.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The scenario could not be loaded or assembled.
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    /// An option is out of range (the message names it and what is allowed).
    #[error("{0}")]
    Option(String),
    /// An output file or folder could not be written.
    #[error("cannot write {path}: {source}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// Frames or the GIF could not be drawn or written.
    #[error("recording frames: {0}")]
    Render(#[from] RenderError),
    /// The UDP stream could not be opened.
    #[error("--stream: {0}")]
    Stream(String),
    /// The MCAP recording or the Foxglove live server failed.
    #[error(transparent)]
    Foxglove(#[from] super::results::foxglove::FoxgloveError),
    /// The figures of `--plots` could not be drawn.
    #[error("--plots: {0}")]
    Plot(String),
}

fn check_option(ok: bool, message: impl FnOnce() -> String) -> Result<(), RunError> {
    if ok { Ok(()) } else { Err(RunError::Option(message())) }
}

/// Run a scenario as `smlworld run` does and write its outputs into `options.out`; returns
/// what was written to `summary.json`.
pub fn run_scenario(source: impl Into<ScenarioSource>, options: RunOptions) -> Result<RunSummary, RunError> {
    let mut builder = SimBuilder::new();
    for plugin in &options.plugins {
        plugin.build(&mut builder);
    }
    let scenario = match source.into() {
        ScenarioSource::File(path) => super::running::scenario::load_with_overrides(
            &path,
            options.seed,
            &options.overrides,
            builder.controllers(),
        )?,
        ScenarioSource::Loaded(s) => {
            check_option(options.overrides.is_empty(), || {
                format!("overrides (--set) change a scenario file; {} is already loaded", s.path.display())
            })?;
            let mut s = *s;
            if let Some(seed) = options.seed {
                s.file.seed = seed;
            }
            s
        }
    };
    check_option(options.threads != Some(0), || "--threads must be at least 1, got 0".to_string())?;
    let duration = options.duration.unwrap_or(scenario.file.duration);
    check_option(duration.is_finite() && duration > 0.0, || {
        format!("--duration must be a positive number of seconds, got {duration}")
    })?;
    check_option(options.speed.is_finite() && options.speed > 0.0, || {
        format!("--speed must be a positive factor, got {}", options.speed)
    })?;
    let log_rate = options.log_rate.unwrap_or(scenario.file.rates.log);
    check_option(log_rate.is_finite() && log_rate > 0.0 && log_rate <= 1e6, || {
        format!("--log-rate must be in (0, 1e6] Hz, got {log_rate}")
    })?;
    // Motion capture measures the lab in wall-clock time: such a scenario runs in real time.
    let wall_clock = scenario.file.lab.as_ref().is_some_and(|l| l.needs_wall_clock());
    check_option(!wall_clock || options.speed == 1.0, || {
        "--speed must be 1 with motion capture (`[lab] mocap`): the lab runs in real time".to_string()
    })?;
    let realtime = options.realtime || wall_clock;
    if wall_clock && !options.realtime {
        tracing::info!("the scenario uses motion capture: running in real time");
    }
    let mut recorder = recorder(&scenario, &options)?;

    scenario.assemble(&mut builder)?;
    if let Some(threads) = options.threads {
        builder.insert_resource(Parallelism::split(threads));
    }
    std::fs::create_dir_all(&options.out).map_err(|source| RunError::Io { path: options.out.clone(), source })?;
    // Outputs are written beside their final names and renamed into place only when the run
    // has ended, so a failed run never truncates the previous run's results.
    let csv_path = options.out.join("trajectories.csv");
    let csv_tmp = options.out.join(".trajectories.csv.partial");
    let csv = std::fs::File::create(&csv_tmp).map_err(|source| RunError::Io { path: csv_tmp.clone(), source })?;
    let mut outputs = PendingOutputs(vec![csv_tmp.clone()]);
    if let Some(addr) = options.stream {
        let plugin = VizStreamPlugin::new(addr, DEFAULT_VIZ_RATE_HZ)
            .map_err(|e| RunError::Stream(e.to_string()))?
            .with_format(options.stream_format);
        builder.add_plugin(plugin);
        builder.add_systems(crate::io::lab::Stream, signal_lane_changes.before(crate::io::lab::stream_vehicles));
        builder.add_systems(
            crate::io::lab::Stream,
            super::results::lights::stream_lights.before(crate::io::lab::stream_vehicles),
        );
        tracing::info!(
            "streaming the vehicles to udp://{addr} at {DEFAULT_VIZ_RATE_HZ} Hz (watch with `smlworld view`)"
        );
        if !realtime {
            tracing::warn!("--stream without --realtime: the stream runs at sim time, as fast as the run goes");
        }
    }
    builder.insert_resource(TrajectoryLog::new(Box::new(std::io::BufWriter::new(csv))));
    builder.add_plugin(TrajectoryLogPlugin { rate: log_rate });
    builder.add_plugin(super::results::lights::LightLogPlugin);
    let mcap = super::results::foxglove::mcap_path(
        options.foxglove.mcap.as_deref(),
        scenario.file.output.mcap.as_deref(),
        &options.out,
    );
    if mcap.is_some() || options.foxglove.foxglove.is_some() {
        use super::results::foxglove::{FoxgloveRecordPlugin, FoxgloveRecorder};
        builder.insert_resource(FoxgloveRecorder::open(&options.foxglove, mcap.as_deref(), scenario.map.clone())?);
        builder.add_plugin(FoxgloveRecordPlugin { images: options.foxglove.mcap_images, map: scenario.map.clone() });
    }
    let mut sim = builder.build();
    if let Some(id) = options.frame_output.follow.filter(|_| recorder.is_some()) {
        let vehicles = sim.world().resource::<crate::world::Vehicles>();
        let ids: Vec<i32> = vehicles.iter().map(|(v, _)| v.0).collect();
        check_option(ids.contains(&id), || {
            format!(
                "--follow {id}: {} has no vehicle {id} at the start (its vehicles: {})",
                scenario.path.display(),
                ids.iter().map(i32::to_string).collect::<Vec<_>>().join(", ")
            )
        })?;
    }

    let report = drive(&mut sim, &options, duration, realtime, recorder.as_mut())?;
    if let Some(rec) = &recorder {
        let f = &options.frame_output;
        let to: Vec<String> = f.frames.iter().chain(&f.gif).chain(&f.video).map(|p| p.display().to_string()).collect();
        tracing::info!("recorded {} frames at {} Hz into {}", rec.frames(), f.frame_rate, to.join(" and "));
    }
    if let Some(rec) = recorder {
        rec.finish()?;
    }
    super::results::output::log_final_state(&mut sim);
    super::results::foxglove::record_final_state(&mut sim);
    sim.world_mut()
        .resource_mut::<TrajectoryLog>()
        .finish()
        .map_err(|source| RunError::Io { path: csv_tmp.clone(), source })?;

    let mut summary = RunSummary::new(&sim, &report);
    if let Some(merge) = summary.metrics.as_mut().and_then(|m| m.merge.as_mut())
        && !summary.interrupted
        && let Some(log) = sim.world().get_resource::<crate::vehicles::MergeLog>()
    {
        merge.delay_s = merge_baseline(&scenario, &options, duration, log)?;
    }
    let map_path = scenario_map_path(&scenario);
    summary.replay = Some(super::running::summary::ReplayInfo::of(sim.world_mut(), map_path, log_rate));
    let summary_path = options.out.join("summary.json");
    let summary_tmp = options.out.join(".summary.json.partial");
    outputs.0.push(summary_tmp.clone());
    let json = serde_json::to_string_pretty(&summary.to_json())
        .map_err(|e| RunError::Io { path: summary_path.clone(), source: std::io::Error::other(e) })?;
    std::fs::write(&summary_tmp, format!("{json}\n"))
        .map_err(|source| RunError::Io { path: summary_tmp.clone(), source })?;
    // One row per vehicle that drove a route (SUMO's tripinfo), from the same records as
    // `metrics.trips`.
    let trips_path = options.out.join("trips.csv");
    let trips_tmp = options.out.join(".trips.csv.partial");
    outputs.0.push(trips_tmp.clone());
    let trips = super::running::trips::trips_csv(&super::running::trips::trip_records(sim.world()));
    std::fs::write(&trips_tmp, trips).map_err(|source| RunError::Io { path: trips_tmp.clone(), source })?;
    // Every signal change (`smlworld replay` draws the stop lines from it); a run without lights
    // removes an earlier run's file, so a replay never draws lights that were not there.
    let lights_path = options.out.join("lights.csv");
    let lights_tmp = options.out.join(".lights.csv.partial");
    let lights = sim.world().get_resource::<super::results::lights::LightLog>().and_then(|l| l.csv());
    let mut renames = vec![(&csv_tmp, &csv_path), (&trips_tmp, &trips_path), (&summary_tmp, &summary_path)];
    match &lights {
        Some(text) => {
            outputs.0.push(lights_tmp.clone());
            std::fs::write(&lights_tmp, text).map_err(|source| RunError::Io { path: lights_tmp.clone(), source })?;
            renames.insert(2, (&lights_tmp, &lights_path));
        }
        None => match std::fs::remove_file(&lights_path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(RunError::Io { path: lights_path.clone(), source: e });
            }
            _ => {}
        },
    }
    for (tmp, path) in renames {
        std::fs::rename(tmp, path).map_err(|source| RunError::Io { path: path.clone(), source })?;
    }
    outputs.keep();
    if let Some(rec) = sim.world_mut().remove_resource::<super::results::foxglove::FoxgloveRecorder>()
        && let Some(path) = rec.finish(Some(&summary.to_json()), sim.now().0)?
    {
        tracing::info!("wrote {}", path.display());
    }
    if options.plots {
        let dir = options.out.join("plots");
        let written = super::results::plot::plot_run(&options.out, &dir).map_err(|e| RunError::Plot(e.to_string()))?;
        tracing::info!("wrote {} figures (PNG + SVG) into {}", written.len(), dir.display());
    }
    if summary.interrupted {
        tracing::warn!(
            "interrupted at sim time {:.3} s: wrote what ran so far into {} (summary.json says \"interrupted\": true)",
            summary.sim_seconds,
            options.out.display()
        );
        return Ok(summary);
    }
    let worst = summary.max_distance_to_centre_line.values().copied().fold(0.0, f64::max);
    // Runs on a map count their lane changes (issue 19).
    let lane_changes = summary
        .metrics
        .as_ref()
        .and_then(|m| m.lane_change_summary)
        .map_or(String::new(), |l| format!(", lane changes {} ({} aborted)", l.count, l.aborted));
    let collisions = summary.metrics.as_ref().map_or(0, |m| m.collision_count);
    tracing::info!(
        "{}, {:.1} sim s in {:.2} wall s ({:.1}x real time), {}, seed {}, max distance to centre line {:.3} m{lane_changes}; wrote {} and {}",
        vehicles_text(&summary),
        summary.sim_seconds,
        summary.wall_seconds,
        summary.real_time_factor,
        collisions_text(collisions, std::io::stderr().is_terminal()),
        summary.seed,
        worst,
        csv_path.display(),
        summary_path.display()
    );
    Ok(summary)
}

/// `N vehicles` for the closing line; with background traffic `N vehicles inserted, M still
/// present` (a lane-drop run whose vehicles all left said `0 vehicles`).
pub fn vehicles_text(summary: &RunSummary) -> String {
    match summary.metrics.as_ref().and_then(|m| m.traffic) {
        Some(t) => format!("{} traffic vehicles inserted, {} vehicles still present", t.inserted, summary.vehicles),
        None => format!("{} vehicles", summary.vehicles),
    }
}

/// `collisions N` for the closing line; in bold red when there were any and `colour` (stderr is
/// a terminal: a log file or pipe gets no escape codes).
pub fn collisions_text(n: usize, colour: bool) -> String {
    if colour && n > 0 { format!("\x1b[1;31mcollisions {n}\x1b[0m") } else { format!("collisions {n}") }
}

/// Temporary output files of a run, removed if the run ends early with an error (dropped before
/// [`PendingOutputs::keep`]).
struct PendingOutputs(Vec<PathBuf>);

impl PendingOutputs {
    /// The run finished and renamed its outputs: nothing to clean up.
    fn keep(mut self) {
        self.0.clear();
    }
}

impl Drop for PendingOutputs {
    fn drop(&mut self) {
        for path in &self.0 {
            let _ = std::fs::remove_file(path);
        }
    }
}

/// Run `sim` for `duration` [s], recording frames and showing progress; the chunk only decides
/// when the callback runs, never what the simulation computes.
fn drive(
    sim: &mut Sim,
    options: &RunOptions,
    duration: f64,
    realtime: bool,
    mut recorder: Option<&mut FrameRecorder>,
) -> Result<RunReport, RunError> {
    let mut record_error = None;
    let chunk = if recorder.is_some() { 1.0 / options.frame_output.frame_rate } else { 1.0 };
    let mut marks = FrameMarks::default();
    let bar = super::progress::sim_time_bar(duration, options.progress && duration >= 30.0);
    // Frame k shows the state at t = k / frame rate from t = 0 (issue 61: frame 0 showed the
    // first chunk's end, and no frame the start).
    if let Some(rec) = recorder.as_mut()
        && let Err(e) = marks.record(rec, sim.world(), options.sensor_ranges)
    {
        record_error = Some(e);
    }
    let progress = |sim: &Sim| {
        if let Some(rec) = recorder.as_mut().filter(|_| record_error.is_none())
            && let Err(e) = marks.record(rec, sim.world(), options.sensor_ranges)
        {
            record_error = Some(e);
        }
        if let Some(bar) = &bar {
            super::progress::set_progress(bar, sim.now().as_secs(), duration);
        }
    };
    let report = if realtime {
        RealtimeRunner::new(options.speed).run(sim, duration, chunk, progress)
    } else {
        super::running::runner::run_headless(sim, duration, chunk, progress)
    };
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    match record_error {
        Some(e) => Err(RunError::Render(e)),
        None => Ok(report),
    }
}

/// `metrics.merge.delay_s`: run the scenario again, headless and without outputs, without the
/// mergers of `log` (platoon B), and compare (see [`crate::vehicles::MergeSummary::delay_s`]).
/// The run is as cheap as the scenario itself (a merge run takes well under a second).
fn merge_baseline(
    scenario: &Scenario,
    options: &RunOptions,
    duration: f64,
    log: &crate::vehicles::MergeLog,
) -> Result<Option<f64>, RunError> {
    let mergers: std::collections::BTreeSet<i32> =
        log.participants.iter().filter(|(_, p)| p.0).map(|(id, _)| id.0).collect();
    let mut without_b = scenario.clone();
    without_b.file.vehicles.retain(|v| !mergers.contains(&v.id));
    let mut builder = SimBuilder::new();
    for plugin in &options.plugins {
        plugin.build(&mut builder);
    }
    without_b.assemble(&mut builder)?;
    let mut sim = builder.build();
    super::running::runner::run_headless(&mut sim, duration, 1.0, |_| {});
    Ok(sim.world().get_resource::<crate::vehicles::MergeLog>().and_then(|base| log.delay_against(base)))
}

/// The frame recorder when frames, a GIF or a video are asked for.
fn recorder(scenario: &Scenario, options: &RunOptions) -> Result<Option<FrameRecorder>, RunError> {
    let frames = &options.frame_output;
    if !frames.any() {
        return Ok(None);
    }
    frames.check().map_err(RunError::Option)?;
    let Some(map) = scenario.map.as_ref() else {
        return Err(RunError::Option(format!(
            "--frames/--gif/--video draw the scenario's map, but {} names no `map`",
            scenario.path.display()
        )));
    };
    Ok(Some(FrameRecorder::new(map, frames)?.with_sensor_ranges(options.sensor_ranges)))
}

/// What a run's frames mark beyond the vehicles: collisions (a red ring where the pair met, for
/// [`crate::render::COLLISION_RING_SECONDS`]) and lane changes in progress (the indicator).
#[derive(Default)]
struct FrameMarks {
    sprites: Vec<VehicleSprite>,
    /// Stop lines in their signals' colours.
    signals: super::results::lights::SignalLines,
    /// Collisions of [`super::running::metrics::Metrics`] already handed to the recorder.
    collisions_seen: usize,
}

impl FrameMarks {
    fn record(
        &mut self,
        rec: &mut FrameRecorder,
        world: &bevy_ecs::world::World,
        sensors: bool,
    ) -> Result<(), RenderError> {
        crate::render::sprites_from_world(world, sensors, &mut self.sprites);
        let t = world.get_resource::<crate::sim::SimClock>().map_or(0.0, |c| c.now.as_secs());
        if let Some(metrics) = world.get_resource::<super::running::metrics::Metrics>() {
            for c in metrics.collisions.iter().skip(self.collisions_seen) {
                // Where the pair is now: at most one frame (1 / frame rate) after they met
                // (a stationary obstacle has no sprite: its state says where it stands).
                let at = |id: i32| match self.sprites.binary_search_by_key(&id, |s| s.id) {
                    Ok(i) => Some(self.sprites[i].position),
                    Err(_) => world
                        .get_resource::<crate::world::Vehicles>()
                        .and_then(|v| v.get(crate::world::VehicleId(id)))
                        .and_then(|e| world.get::<crate::world::VehicleState>(e))
                        .map(|s| s.position),
                };
                if let (Some(a), Some(b)) = (at(c.a.0), at(c.b.0)) {
                    rec.add_collision((a + b) * 0.5, c.t);
                }
            }
            self.collisions_seen = metrics.collisions.len();
        }
        if let Some(mut q) = world.try_query::<(&crate::world::VehicleId, &crate::vehicles::LaneChanger)>() {
            for (id, changer) in q.iter(world) {
                let indicator = changer.signal();
                if indicator == crate::world::TurnSignal::Off {
                    continue;
                }
                if let Ok(i) = self.sprites.binary_search_by_key(&id.0, |s| s.id) {
                    self.sprites[i].overlays.indicator = indicator;
                }
            }
        }
        rec.set_signals(self.signals.from_world(world));
        rec.record_sprites(&self.sprites, t)
    }
}

/// The turn signal ([`crate::vehicles::LaneChanger::signal`]) of every lane changer as a
/// component, for the visualisation stream. Written only when it changes.
fn signal_lane_changes(
    mut commands: bevy_ecs::system::Commands,
    changers: bevy_ecs::system::Query<(
        bevy_ecs::entity::Entity,
        &crate::vehicles::LaneChanger,
        Option<&crate::world::TurnSignal>,
    )>,
) {
    for (entity, changer, signal) in &changers {
        let now = changer.signal();
        if signal.copied().unwrap_or_default() != now {
            commands.entity(entity).insert(now);
        }
    }
}

/// The scenario's map file, absolute when it exists (so `smlworld replay` finds it from anywhere).
fn scenario_map_path(scenario: &Scenario) -> Option<PathBuf> {
    let name = scenario.file.map.as_ref()?;
    let path = scenario.path.parent().unwrap_or(FsPath::new("")).join(name);
    Some(std::fs::canonicalize(&path).unwrap_or(path))
}
