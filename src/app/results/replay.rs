//! `smlworld replay`: redraw a finished run from its `trajectories.csv` and `summary.json`
//! without simulating.
//!
//! [`replay_run`] reads the rows time by time (streaming: memory grows with the vehicle count,
//! not with the run's length) and, for each output asked for, takes the state of every vehicle
//! at the output's times:
//! - frames and GIF at `k / frame_rate` for k = 0, 1, 2, ... (frame k is the state at
//!   t = k / frame_rate, the times at which `run --frames` draws), through the map of
//!   `summary.json` at the same view, so a replay at the run's frame rate draws the run's frames (stop lines in their signals' colours from `lights.csv`, when
//!   the run had traffic lights);
//! - the UDP visualisation stream at 50 Hz of sim time from t = 0 (the times of `run --stream`),
//!   paced to the wall clock times `speed`, so `smlworld view` shows a recorded run live (with
//!   the light states of `lights.csv` in our stream format).
//!
//! A time that falls on a logged row uses that row exactly; a time between two rows interpolates
//! linearly (position, and yaw along the shorter arc). Outputs end at the last logged row: the
//! trajectory log does not hold the state at the run's very end, so `run --frames` has one frame
//! more (the one at t = duration) than its replay.

use std::io::BufRead;
use std::net::SocketAddr;
use std::path::{Path as FsPath, PathBuf};
use std::time::{Duration, Instant};

use glam::DVec2;

use crate::io::viz::{DEFAULT_VIZ_RATE_HZ, StreamFormat, VizLight, VizSender, VizSenderConfig, VizVehicle};
use crate::map::LaneletMap;
use crate::render::{FrameOutput, FrameRecorder, RenderError, VehicleSprite};
use crate::world::SimTime;
use crate::world::TurnSignal;

use super::lights::{LightTimeline, SignalLines};
use crate::app::running::summary::{ReplayInfo, ReplayVehicle};

/// What `smlworld replay` writes or sends, and how.
#[derive(Debug, Clone)]
pub struct ReplayOptions {
    /// Frames and GIF: outputs, size, rate [Hz of sim time], overlay and window (the arguments
    /// `smlworld replay` shares with `run` and `view`).
    pub frame_output: FrameOutput,
    /// Send the vehicles over UDP (2015 visualisation format, 50 Hz of sim time) to this address.
    pub stream: Option<SocketAddr>,
    /// Sim seconds per wall second of the stream (2 = twice as fast as recorded).
    pub speed: f64,
    /// Class names and reference point of the stream (see [`StreamFormat`]).
    pub stream_format: StreamFormat,
    /// Write the run as an MCAP file here (Foxglove schemas, see [`replay_mcap`]).
    pub mcap: Option<PathBuf>,
}

impl Default for ReplayOptions {
    fn default() -> Self {
        ReplayOptions {
            frame_output: FrameOutput::default(),
            stream: None,
            speed: 1.0,
            stream_format: StreamFormat::Smlworld,
            mcap: None,
        }
    }
}

/// What a run's `summary.json` says beyond the `replay` part that frames mark: collisions (the
/// pair and the time) and lane changes (who, when, which way).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReplayMarks {
    /// Collisions: ids of the pair and sim time \[s\].
    pub collisions: Vec<(i32, i32, f64)>,
    /// Lane changes: id, start and end \[s\], and the side the indicator shows.
    pub lane_changes: Vec<(i32, f64, f64, TurnSignal)>,
}

/// Read the collisions and lane changes of `OUT_DIR/summary.json` (`metrics.collisions`,
/// `metrics.lane_changes`; none when the run wrote no metrics).
pub fn read_replay_marks(out_dir: &FsPath) -> Result<ReplayMarks, ReplayError> {
    let path = out_dir.join("summary.json");
    let text = std::fs::read_to_string(&path).map_err(|source| ReplayError::Io { path: path.clone(), source })?;
    let value: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| ReplayError::Summary { path: path.clone(), message: format!("not JSON: {e}") })?;
    let mut marks = ReplayMarks::default();
    let bad = |what: &str, i: usize| ReplayError::Summary {
        path: path.clone(),
        message: format!("`metrics.{what}[{i}]` lacks a field or has one of the wrong type"),
    };
    let metrics = &value["metrics"];
    for (i, c) in metrics["collisions"].as_array().into_iter().flatten().enumerate() {
        let id = |k: &str| c[k].as_i64().and_then(|v| i32::try_from(v).ok());
        match (id("a"), id("b"), c["t"].as_f64()) {
            (Some(a), Some(b), Some(t)) => marks.collisions.push((a, b, t)),
            _ => return Err(bad("collisions", i)),
        }
    }
    for (i, l) in metrics["lane_changes"].as_array().into_iter().flatten().enumerate() {
        let id = l["id"].as_i64().and_then(|v| i32::try_from(v).ok());
        let side = match (l["direction"].as_str(), l["aborted"].as_bool()) {
            // An aborted change shows its first direction throughout: the summary does not say
            // when it turned back.
            (Some("left"), Some(_)) => TurnSignal::Left,
            (Some("right"), Some(_)) => TurnSignal::Right,
            _ => return Err(bad("lane_changes", i)),
        };
        match (id, l["t_start"].as_f64(), l["t_end"].as_f64()) {
            (Some(id), Some(t0), Some(t1)) => marks.lane_changes.push((id, t0, t1, side)),
            _ => return Err(bad("lane_changes", i)),
        }
    }
    Ok(marks)
}

/// The sim time a run covered [s] (`sim_seconds` of `OUT_DIR/summary.json`), if it says.
fn run_sim_seconds(out_dir: &FsPath) -> Option<f64> {
    let text = std::fs::read_to_string(out_dir.join("summary.json")).ok()?;
    serde_json::from_str::<serde_json::Value>(&text).ok()?["sim_seconds"].as_f64()
}

/// What a replay did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ReplayReport {
    /// Frames drawn (PNG and/or GIF).
    pub frames: u64,
    /// Stream frames sent.
    pub datagram_frames: u64,
    /// Rows of `trajectories.csv` read.
    pub rows: u64,
    /// Whether Ctrl-C or SIGTERM stopped the replay early (the GIF holds the frames drawn so far).
    pub interrupted: bool,
}

/// What can stop a replay.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// A file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// `summary.json` is not JSON or lacks its `replay` part.
    #[error("{path}: {message}")]
    Summary {
        /// The summary file.
        path: PathBuf,
        /// What is wrong and what to do.
        message: String,
    },
    /// A row of `trajectories.csv` is malformed.
    #[error("{path}:{line}: {message} (expected `t,id,x,y,yaw,vx,vy`, rows in time order)")]
    Row {
        /// The CSV file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// `lights.csv` cannot be read, or a row is malformed or does not fit the run's map.
    #[error(transparent)]
    Lights(#[from] super::lights::LightsError),
    /// The map named in `summary.json` could not be loaded.
    #[error("map {path} (named in summary.json): {message}")]
    Map {
        /// The map file.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// An option is out of range or missing (the message names it and what is allowed).
    #[error("{0}")]
    Option(String),
    /// Frames or the GIF could not be drawn or written.
    #[error("drawing frames: {0}")]
    Render(#[from] RenderError),
    /// The UDP stream could not be opened or sent.
    #[error("--stream: {0}")]
    Stream(String),
    /// The MCAP file could not be written.
    #[error(transparent)]
    Foxglove(#[from] super::foxglove::FoxgloveError),
}

/// Read the `replay` part of `OUT_DIR/summary.json`.
pub fn read_replay_info(out_dir: &FsPath) -> Result<ReplayInfo, ReplayError> {
    let path = out_dir.join("summary.json");
    let text = std::fs::read_to_string(&path).map_err(|source| ReplayError::Io { path: path.clone(), source })?;
    let value: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| ReplayError::Summary { path: path.clone(), message: format!("not JSON: {e}") })?;
    let Some(replay) = value.get("replay") else {
        return Err(ReplayError::Summary {
            path,
            message: "no `replay` part: the run is older than `smlworld replay`; run it again".into(),
        });
    };
    serde_json::from_value(replay.clone())
        .map_err(|e| ReplayError::Summary { path, message: format!("`replay`: {e} (map, log_rate, vehicles)") })
}

/// One logged row: state of one vehicle at one time.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Row {
    id: i32,
    position: DVec2,
    yaw: f64,
}

/// All rows of one logged time.
#[derive(Debug, Default)]
struct Group {
    t_us: u64,
    rows: Vec<Row>,
}

/// Streams `trajectories.csv` one time at a time.
struct TrajectoryReader {
    path: PathBuf,
    lines: std::io::Lines<std::io::BufReader<std::fs::File>>,
    line: usize,
    pending: Option<(u64, Row)>,
    rows: u64,
}

impl TrajectoryReader {
    fn open(path: PathBuf) -> Result<TrajectoryReader, ReplayError> {
        let file = std::fs::File::open(&path).map_err(|source| ReplayError::Io { path: path.clone(), source })?;
        let mut lines = std::io::BufReader::new(file).lines();
        let header = lines.next().transpose().map_err(|source| ReplayError::Io { path: path.clone(), source })?;
        // Runs before the lane columns wrote only the first seven.
        let header = header.as_deref().map(str::trim);
        if header != Some("t,id,x,y,yaw,vx,vy,lanelet,lane_offset") && header != Some("t,id,x,y,yaw,vx,vy") {
            return Err(ReplayError::Row { path, line: 1, message: format!("header is {header:?}") });
        }
        Ok(TrajectoryReader { path, lines, line: 1, pending: None, rows: 0 })
    }

    fn error(&self, message: String) -> ReplayError {
        ReplayError::Row { path: self.path.clone(), line: self.line, message }
    }

    fn next_row(&mut self) -> Result<Option<(u64, Row)>, ReplayError> {
        loop {
            let Some(line) = self.lines.next() else { return Ok(None) };
            self.line += 1;
            let line = line.map_err(|source| ReplayError::Io { path: self.path.clone(), source })?;
            if line.trim().is_empty() {
                continue;
            }
            let f: Vec<&str> = line.trim().split(',').collect();
            if f.len() != 7 && f.len() != 9 {
                return Err(self.error(format!("{} fields", f.len())));
            }
            let num = |i: usize, name: &str| -> Result<f64, ReplayError> {
                f[i].parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite())
                    .ok_or_else(|| self.error(format!("`{name}` = {:?} is not a finite number", f[i])))
            };
            let t = num(0, "t")?;
            if t < 0.0 {
                return Err(self.error(format!("time {t} is negative")));
            }
            let id = f[1].parse::<i32>().map_err(|_| self.error(format!("`id` = {:?} is not an integer", f[1])))?;
            let row = Row { id, position: DVec2::new(num(2, "x")?, num(3, "y")?), yaw: num(4, "yaw")? };
            self.rows += 1;
            return Ok(Some((SimTime::from_secs(t).0, row)));
        }
    }

    /// Fill `group` with the rows of the next logged time; `false` at the end of the file.
    fn next_group(&mut self, group: &mut Group) -> Result<bool, ReplayError> {
        group.rows.clear();
        let first = match self.pending.take() {
            Some(r) => r,
            None => match self.next_row()? {
                Some(r) => r,
                None => return Ok(false),
            },
        };
        if first.0 < group.t_us && self.rows > 1 {
            return Err(self.error(format!("time {} s goes back in time", SimTime(first.0).as_secs())));
        }
        group.t_us = first.0;
        group.rows.push(first.1);
        while let Some((t, row)) = self.next_row()? {
            if t != group.t_us {
                self.pending = Some((t, row));
                break;
            }
            group.rows.push(row);
        }
        group.rows.sort_by_key(|r| r.id);
        Ok(true)
    }
}

/// Angle `a + (b - a) * f` along the shorter arc [rad].
fn lerp_angle(a: f64, b: f64, f: f64) -> f64 {
    let d = (b - a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
    a + d * f
}

/// The states at `t_us`, between `prev` (at or before) and `next` (at or after), into `out`.
fn states_at(prev: &Group, next: &Group, t_us: u64, out: &mut Vec<Row>) {
    out.clear();
    if t_us == next.t_us || next.rows.is_empty() {
        out.extend_from_slice(if t_us == next.t_us { &next.rows } else { &prev.rows });
        return;
    }
    if t_us == prev.t_us || next.t_us <= prev.t_us {
        out.extend_from_slice(&prev.rows);
        return;
    }
    let f = (t_us - prev.t_us) as f64 / (next.t_us - prev.t_us) as f64;
    // Both groups are sorted by id: merge, keeping vehicles known at the earlier time.
    let mut j = 0;
    for a in &prev.rows {
        while j < next.rows.len() && next.rows[j].id < a.id {
            j += 1;
        }
        match next.rows.get(j).filter(|b| b.id == a.id) {
            Some(b) => {
                out.push(Row { id: a.id, position: a.position.lerp(b.position, f), yaw: lerp_angle(a.yaw, b.yaw, f) })
            }
            None => out.push(*a),
        }
    }
}

/// Redraw (and/or re-send) the run in `out_dir` from its `trajectories.csv` and `summary.json`.
pub fn replay_run(out_dir: &FsPath, options: &ReplayOptions) -> Result<ReplayReport, ReplayError> {
    let frames = &options.frame_output;
    if !frames.any() && options.stream.is_none() && options.mcap.is_none() {
        return Err(ReplayError::Option(
            "replay needs at least one of --gif FILE, --video FILE, --frames DIR, --stream [ADDR], --mcap FILE".into(),
        ));
    }
    if let Some(path) = &options.mcap {
        let rows = replay_mcap(out_dir, path)?;
        tracing::info!("wrote {} from {rows} rows", path.display());
        if !frames.any() && options.stream.is_none() {
            return Ok(ReplayReport { rows, ..ReplayReport::default() });
        }
    }
    if !(options.speed.is_finite() && options.speed > 0.0) {
        return Err(ReplayError::Option(format!("--speed must be a positive factor, got {}", options.speed)));
    }
    let drawing = frames.any();
    if drawing {
        frames.check().map_err(ReplayError::Option)?;
    }
    let info = read_replay_info(out_dir)?;
    if let Some(id) = frames.follow.filter(|_| drawing)
        && !info.vehicles.iter().any(|v| v.id == id)
    {
        return Err(ReplayError::Option(format!(
            "--follow {id}: the run in {} has no vehicle {id} (its vehicles: {})",
            out_dir.display(),
            info.vehicles.iter().map(|v| v.id.to_string()).collect::<Vec<_>>().join(", ")
        )));
    }
    let marks = if drawing { read_replay_marks(out_dir)? } else { ReplayMarks::default() };
    let mut collisions_due = marks.collisions.iter().peekable();
    let mut lights: Option<(LightTimeline, SignalLines)> = None;
    let mut recorder = if drawing {
        let Some(map_path) = &info.map else {
            return Err(ReplayError::Option(format!(
                "--frames/--gif/--video draw the run's map, but {} names none (the scenario had no `map`)",
                out_dir.join("summary.json").display()
            )));
        };
        let map = LaneletMap::load(map_path)
            .map_err(|e| ReplayError::Map { path: map_path.clone(), message: e.to_string() })?;
        // The run's signal changes, if it had lights, drawn on the stop lines.
        lights = LightTimeline::read(&out_dir.join("lights.csv"), Some(&map))?
            .map(|timeline| (timeline, SignalLines::of_map(&map)));
        Some(FrameRecorder::new(&map, frames)?)
    } else {
        None
    };
    // The stream sends the run's light states too (our format only), without the map check.
    let mut stream_lights = match options.stream {
        Some(_) if options.stream_format == StreamFormat::Smlworld => {
            LightTimeline::read(&out_dir.join("lights.csv"), None)?
        }
        _ => None,
    };
    let mut viz_lights: Vec<VizLight> = Vec::new();
    let mut sender = match options.stream {
        Some(target) => Some(
            VizSender::new(&VizSenderConfig { target, ..Default::default() })
                .map_err(|e| ReplayError::Stream(e.to_string()))?,
        ),
        None => None,
    };
    let by_id: std::collections::BTreeMap<i32, &ReplayVehicle> = info.vehicles.iter().map(|v| (v.id, v)).collect();

    let frame_step = SimTime::from_secs(1.0 / frames.frame_rate).0.max(1);
    let stream_step = SimTime::from_secs(1.0 / DEFAULT_VIZ_RATE_HZ).0.max(1);
    // Frame k at t = k / frame rate, from t = 0 (as `run` draws them).
    let mut next_frame = 0;
    let mut next_datagram = 0u64;
    let mut reader = TrajectoryReader::open(out_dir.join("trajectories.csv"))?;
    let (mut prev, mut next) = (Group::default(), Group::default());
    let mut states = Vec::new();
    let mut sprites: Vec<VehicleSprite> = Vec::new();
    let mut viz: Vec<VizVehicle> = Vec::new();
    let mut report = ReplayReport::default();
    let wall_start = Instant::now();
    let mut first = true;
    // Progress on a terminal as `run` shows it, over the run's sim time (summary.json).
    let total = run_sim_seconds(out_dir);
    let bar = total.and_then(|total| crate::app::progress::sim_time_bar(total, true));
    while reader.next_group(&mut next)? {
        if let (Some(bar), Some(total)) = (&bar, total) {
            crate::app::progress::set_progress(bar, SimTime(next.t_us).as_secs(), total);
        }
        if crate::app::running::interrupt::requested().is_some() {
            report.interrupted = true;
            break;
        }
        if first {
            prev.t_us = next.t_us;
            prev.rows.clone_from(&next.rows);
            first = false;
        }
        // Every output time in (prev.t, next.t] (and t = 0 for the stream's first frame).
        while recorder.is_some() && next_frame <= next.t_us {
            // Frame k is always t = k / frame rate: before the first row (traffic not yet
            // inserted) it shows no vehicle.
            if next_frame >= prev.t_us {
                states_at(&prev, &next, next_frame, &mut states);
            } else {
                states.clear();
            }
            sprites.clear();
            let t = SimTime(next_frame).as_secs();
            for r in states.iter().filter(|r| !by_id.get(&r.id).is_some_and(|v| v.stationary)) {
                let (class, length, width) =
                    by_id.get(&r.id).map_or(("Car", 4.12, 1.7), |v| (v.class.name(), v.length, v.width));
                let mut sprite = VehicleSprite::new(r.id, r.position, r.yaw, length, width, class);
                sprite.real = by_id.get(&r.id).is_some_and(|v| v.lab);
                sprite.overlays.indicator = marks
                    .lane_changes
                    .iter()
                    .find(|(id, t0, t1, _)| *id == r.id && (*t0..=*t1).contains(&t))
                    .map_or(TurnSignal::Off, |l| l.3);
                sprites.push(sprite);
            }
            if let Some(rec) = recorder.as_mut() {
                // Each collision once its time has come, where the pair is in this frame.
                while let Some((a, b, tc)) = collisions_due.next_if(|c| c.2 <= t + 1e-9) {
                    let at = |id: i32| states.binary_search_by_key(&id, |r| r.id).ok().map(|i| states[i].position);
                    if let (Some(pa), Some(pb)) = (at(*a), at(*b)) {
                        rec.add_collision((pa + pb) * 0.5, *tc);
                    }
                }
                if let Some((timeline, lines)) = lights.as_mut() {
                    timeline.advance_to(t);
                    rec.set_signals(lines.from_states(timeline.states()));
                }
                rec.record_sprites(&sprites, t)?;
            }
            report.frames += 1;
            next_frame += frame_step;
        }
        while let Some(s) = sender.as_mut().filter(|_| next_datagram <= next.t_us) {
            if next_datagram >= prev.t_us {
                states_at(&prev, &next, next_datagram, &mut states);
                viz.clear();
                // In the run's stream order (summary.json lists the vehicles that way).
                let t = SimTime(next_datagram).as_secs();
                for v in info.vehicles.iter().filter(|v| !v.stationary) {
                    if let Ok(i) = states.binary_search_by_key(&v.id, |r| r.id) {
                        let r = states[i];
                        let f = options.stream_format;
                        let p = f.point_from_centre(r.position, r.yaw, v.length);
                        // The indicator of a lane change in progress, in our format only.
                        let indicator = marks
                            .lane_changes
                            .iter()
                            .find(|(id, t0, t1, _)| *id == r.id && (*t0..=*t1).contains(&t))
                            .filter(|_| f == StreamFormat::Smlworld)
                            .map_or(TurnSignal::Off, |l| l.3);
                        viz.push(VizVehicle {
                            id: r.id,
                            x: p.x,
                            y: p.y,
                            yaw_deg: r.yaw.to_degrees(),
                            class_name: f.class_name(r.id, v.class).to_string(),
                            indicator,
                        });
                    }
                }
                let due = wall_start + Duration::from_secs_f64(SimTime(next_datagram).as_secs() / options.speed);
                if let Some(wait) = due.checked_duration_since(Instant::now()) {
                    std::thread::sleep(wait);
                }
                if let Some(timeline) = stream_lights.as_mut() {
                    timeline.advance_to(t);
                    viz_lights.clear();
                    viz_lights.extend(
                        timeline.states().map(|(junction, state)| VizLight { junction, state: state.to_string() }),
                    );
                    s.send_lights(&viz_lights).map_err(|e| ReplayError::Stream(e.to_string()))?;
                }
                s.send(&viz).map_err(|e| ReplayError::Stream(e.to_string()))?;
                report.datagram_frames += 1;
            }
            next_datagram += stream_step;
        }
        std::mem::swap(&mut prev, &mut next);
        next.t_us = prev.t_us;
    }
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    if let Some(rec) = recorder {
        rec.finish()?;
    }
    report.rows = reader.rows;
    if report.rows == 0 {
        return Err(ReplayError::Row {
            path: out_dir.join("trajectories.csv"),
            line: 1,
            message: "no rows: nothing to replay".into(),
        });
    }
    Ok(report)
}

/// `smlworld replay OUT_DIR --mcap FILE`: the MCAP recording of a finished run from its
/// `trajectories.csv` (a `/vehicles`, `/tf` and state message per logged time), `summary.json`
/// (sizes and classes, collisions and lane changes on `/events`, `/metrics`) and map. V2V
/// rounds, light changes and accelerations are not in those files: `/v2v` stays empty and
/// `accel` is null. Returns the rows read.
pub fn replay_mcap(out_dir: &FsPath, path: &FsPath) -> Result<u64, ReplayError> {
    use super::foxglove::{Event, FoxgloveOutput, FoxgloveRecorder, Snapshot, VehicleSnapshot};
    use crate::world::{TurnSignal, VehicleClass};
    use std::collections::BTreeMap;
    use std::io::BufRead;
    use std::sync::Arc;
    let info = read_replay_info(out_dir)?;
    let marks = read_replay_marks(out_dir)?;
    let map = match &info.map {
        Some(p) => Some(Arc::new(
            LaneletMap::load(p).map_err(|e| ReplayError::Map { path: p.clone(), message: e.to_string() })?,
        )),
        None => None,
    };
    let summary: Option<serde_json::Value> =
        std::fs::read_to_string(out_dir.join("summary.json")).ok().and_then(|t| serde_json::from_str(&t).ok());
    let output = FoxgloveOutput { mcap: Some(path.to_path_buf()), ..FoxgloveOutput::default() };
    let mut rec = FoxgloveRecorder::open(&output, Some(path), map)?;
    let by_id: BTreeMap<i32, &super::super::running::summary::ReplayVehicle> =
        info.vehicles.iter().map(|v| (v.id, v)).collect();
    let csv = out_dir.join("trajectories.csv");
    let file = std::fs::File::open(&csv).map_err(|source| ReplayError::Io { path: csv.clone(), source })?;
    let mut lines = std::io::BufReader::new(file).lines();
    let header = lines.next().transpose().map_err(|source| ReplayError::Io { path: csv.clone(), source })?;
    if header.as_deref().map(str::trim) != Some("t,id,x,y,yaw,vx,vy,lanelet,lane_offset") {
        return Err(ReplayError::Row { path: csv, line: 1, message: format!("header is {header:?}") });
    }
    let mut snapshot = Snapshot::default();
    let mut events = Vec::new();
    let mut previous: Vec<i32> = Vec::new();
    let mut rows = 0u64;
    let mut collisions = marks.collisions.iter().peekable();
    let mut flush = |snapshot: &mut Snapshot, rec: &mut FoxgloveRecorder, events: &mut Vec<Event>| {
        snapshot.vehicles.sort_by_key(|v| v.id);
        let t = snapshot.t_us as f64 * 1e-6;
        events.clear();
        while let Some(&&(a, b, tc)) = collisions.peek() {
            if tc > t + 1e-9 {
                break;
            }
            collisions.next();
            events.push(Event::warning(
                crate::world::SimTime::from_secs(tc).0,
                "collision",
                format!("collision: vehicles {a} and {b}"),
            ));
        }
        let ids: Vec<i32> = snapshot.vehicles.iter().map(|v| v.id).collect();
        for id in previous.iter().filter(|id| ids.binary_search(id).is_err()) {
            events.push(Event::info(snapshot.t_us, "vehicle", format!("vehicle {id} left")));
        }
        if rec.ticks() > 0 {
            for id in ids.iter().filter(|id| previous.binary_search(id).is_err()) {
                events.push(Event::info(snapshot.t_us, "vehicle", format!("vehicle {id} appeared")));
            }
        }
        for v in &mut snapshot.vehicles {
            if let Some(&(_, t0, _, side)) =
                marks.lane_changes.iter().find(|l| l.0 == v.id && l.1 <= t + 1e-9 && t < l.2)
            {
                v.signal = side;
                v.mode = "lane_change";
                if (t0 - t).abs() < 0.5 / info.log_rate.max(1e-9) {
                    let dir = if v.signal == TurnSignal::Left { "left" } else { "right" };
                    events.push(Event::info(
                        snapshot.t_us,
                        "lane_change",
                        format!("vehicle {} changes lanes {dir}", v.id),
                    ));
                }
            }
        }
        rec.record(std::mem::take(snapshot), std::mem::take(events));
        previous = ids;
        snapshot.vehicles.clear();
    };
    for (i, line) in lines.enumerate() {
        let line = line.map_err(|source| ReplayError::Io { path: csv.clone(), source })?;
        if line.trim().is_empty() {
            continue;
        }
        let bad = |message: String| ReplayError::Row { path: csv.clone(), line: i + 2, message };
        let f: Vec<&str> = line.trim().split(',').collect();
        if f.len() != 9 {
            return Err(bad(format!("{} fields", f.len())));
        }
        let num = |k: usize| f[k].parse::<f64>().ok().filter(|v| v.is_finite());
        let (Some(t), Ok(id), Some(x), Some(y), Some(yaw), Some(vx), Some(vy)) =
            (num(0), f[1].parse::<i32>(), num(2), num(3), num(4), num(5), num(6))
        else {
            return Err(bad("a number is missing or not finite".into()));
        };
        let t_us = crate::world::SimTime::from_secs(t).0;
        if rows > 0 && t_us != snapshot.t_us {
            if t_us < snapshot.t_us {
                return Err(bad(format!("time {t} s goes back in time")));
            }
            flush(&mut snapshot, &mut rec, &mut events);
        }
        snapshot.t_us = t_us;
        let v = by_id.get(&id);
        snapshot.vehicles.push(VehicleSnapshot {
            id,
            position: DVec2::new(x, y),
            yaw,
            velocity: DVec2::new(vx, vy),
            accel: f64::NAN,
            lanelet: f[7].parse().ok(),
            lane_offset: num(8),
            length: v.map_or(4.12, |v| v.length),
            width: v.map_or(1.7, |v| v.width),
            class: v.map_or_else(VehicleClass::default, |v| v.class),
            real: v.is_some_and(|v| v.lab),
            signal: TurnSignal::Off,
            mode: if v.is_some_and(|v| v.lab) { "lab" } else { "replay" },
        });
        rows += 1;
    }
    if rows > 0 {
        flush(&mut snapshot, &mut rec, &mut events);
    }
    let end = rec.last_t.unwrap_or(0);
    rec.finish(summary.as_ref(), end)?;
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yaw_interpolates_along_the_shorter_arc() {
        let pi = std::f64::consts::PI;
        // From 170 deg to -170 deg the short way passes 180 deg, not 0.
        let mid = lerp_angle(170f64.to_radians(), (-170f64).to_radians(), 0.5);
        assert!((mid.rem_euclid(2.0 * pi) - pi).abs() < 1e-12, "{mid}");
    }

    #[test]
    fn states_between_rows_interpolate_and_rows_are_exact() {
        let row = |id, x: f64| Row { id, position: DVec2::new(x, 0.0), yaw: 0.0 };
        let prev = Group { t_us: 0, rows: vec![row(-2, 0.0), row(-1, 10.0)] };
        let next = Group { t_us: 100_000, rows: vec![row(-2, 1.0), row(-1, 12.0)] };
        let mut out = Vec::new();
        states_at(&prev, &next, 25_000, &mut out);
        assert_eq!(out, vec![row(-2, 0.25), row(-1, 10.5)]);
        states_at(&prev, &next, 100_000, &mut out);
        assert_eq!(out, next.rows);
    }
}
