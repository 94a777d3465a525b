//! Traffic lights in a run's outputs and pictures: `lights.csv` (written while the run goes, read
//! back by `smlworld replay`), the stop lines that frames draw in their signals' colours, and
//! the states the visualisation stream carries ([`stream_lights`]).
//!
//! `lights.csv` has the header `t,junction,state` [s, id, one character per link]: one row per
//! signalised junction at the first control tick (t = 0) and one more each time a junction's
//! state changes (a program's phase, or `Sim.set_phase` from Python), junctions in id order
//! within a tick. The state at time `t` is that of the junction's last row at or before `t`.
//! Junction ids and link order are those of `smlworld map info`.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use bevy_ecs::prelude::{Res, ResMut, Resource, World};
use bevy_ecs::schedule::IntoScheduleConfigs;
use glam::DVec2;

use super::output::{Fixed, TIME_DECIMALS};
use crate::io::lab::VizStream;
use crate::io::viz::VizLight;
use crate::map::LaneletMap;
use crate::render::{SignalLine, stop_lines};
use crate::sim::{Control, Plugin, SimBuilder, SimClock};
use crate::vehicles::{JunctionNetwork, LongitudinalSystems, TrafficLights};

/// Header of `lights.csv`.
pub const LIGHTS_CSV_HEADER: &str = "t,junction,state";

/// The rows of `lights.csv` collected during a run (see the module docs).
#[derive(Resource, Debug, Default)]
pub struct LightLog {
    text: String,
    /// Every link's signal at the last row written (the layout of [`TrafficLights::state`]).
    last: Vec<u8>,
    /// [`TrafficLights::changes`] when last looked at (`None`: never).
    seen: Option<u64>,
}

impl LightLog {
    /// The whole `lights.csv` (header and rows), or `None` when the run had no traffic light.
    pub fn csv(&self) -> Option<String> {
        (!self.text.is_empty()).then(|| format!("{LIGHTS_CSV_HEADER}\n{}", self.text))
    }
}

/// The characters a light controller shows now, in its junction's link order.
fn shown(lights: &TrafficLights, junction: u32, links: usize) -> &[u8] {
    shown_bytes(&lights.state, &lights.first_link, junction, links)
}

/// Number of links a light controller drives (its program's states, or the state held).
fn links_of(c: &crate::vehicles::right_of_way::LightController) -> usize {
    c.manual.as_ref().map(String::len).or_else(|| c.program.first().map(|p| p.state.len())).unwrap_or(0)
}

/// Append a row to the [`LightLog`] for every junction whose state changed since the last call
/// (every junction on the first call). O(links) when something changed, O(1) otherwise.
pub fn log_light_changes(clock: Res<SimClock>, lights: Option<Res<TrafficLights>>, mut log: ResMut<LightLog>) {
    let Some(lights) = lights else { return };
    if log.seen == Some(lights.changes) {
        return;
    }
    let t = clock.now.as_secs();
    let first_time = log.seen.is_none();
    let LightLog { text, last, seen } = &mut *log;
    for c in &lights.controllers {
        let n = links_of(c);
        let now = shown(&lights, c.junction, n);
        let before = shown_bytes(last, &lights.first_link, c.junction, n);
        if first_time || now != before {
            let _ = writeln!(text, "{},{},{}", Fixed(t, TIME_DECIMALS), c.junction + 1, String::from_utf8_lossy(now));
        }
    }
    last.clone_from(&lights.state);
    *seen = Some(lights.changes);
}

/// The characters of `links` links from junction `junction`'s first link in `state`.
fn shown_bytes<'a>(state: &'a [u8], first_link: &[u32], junction: u32, links: usize) -> &'a [u8] {
    let first = first_link.get(junction as usize).map_or(0, |&f| f as usize);
    state.get(first..first + links).unwrap_or(&[])
}

/// Copy what every signalised junction shows into the visualisation stream's
/// [`VizStream::lights`] (sent before each frame in our format), reusing its strings.
pub fn stream_lights(lights: Option<Res<TrafficLights>>, stream: Option<ResMut<VizStream>>) {
    let (Some(lights), Some(mut stream)) = (lights, stream) else { return };
    let out = &mut stream.lights;
    out.resize_with(lights.controllers.len(), || VizLight { junction: 0, state: String::new() });
    for (c, l) in lights.controllers.iter().zip(out.iter_mut()) {
        l.junction = c.junction + 1;
        l.state.clear();
        l.state.extend(shown(&lights, c.junction, links_of(c)).iter().map(|&b| char::from(b)));
    }
}

/// Collects `lights.csv` during a run: a [`LightLog`] and [`log_light_changes`] in the Control
/// schedule after the lights have advanced (a run without lights writes nothing).
#[derive(Debug, Clone, Copy, Default)]
pub struct LightLogPlugin;

impl Plugin for LightLogPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.insert_resource(LightLog::default());
        // The lights advance before the junction decisions (`Limit`); log what they decided on.
        sim.add_systems(Control, log_light_changes.after(LongitudinalSystems::Limit));
    }
}

/// The stop lines of a map's junctions (computed once) and what they show, as the frames draw
/// them ([`crate::render::FrameRecorder::set_signals`]).
#[derive(Debug, Default)]
pub struct SignalLines {
    /// Stop-line parts by junction index and link ([`stop_lines`]); `None` until first needed.
    geometry: Option<Vec<Vec<(DVec2, DVec2)>>>,
    lines: Vec<SignalLine>,
}

impl SignalLines {
    /// Stop lines of `map` (for a replay or a viewer: junctions under the default rules, whose
    /// ids and link order are those of the run).
    pub fn of_map(map: &LaneletMap) -> SignalLines {
        SignalLines { geometry: Some(stop_lines(map, &map.junctions())), lines: Vec::new() }
    }

    /// The stop lines of the world's traffic lights with what they show now (none without
    /// lights).
    pub fn from_world(&mut self, world: &World) -> &[SignalLine] {
        self.lines.clear();
        let (Some(lights), Some(network)) =
            (world.get_resource::<TrafficLights>(), world.get_resource::<JunctionNetwork>())
        else {
            return &self.lines;
        };
        let geometry = self.geometry.get_or_insert_with(|| stop_lines(&network.map, &network.junctions));
        for c in &lights.controllers {
            let now = shown(lights, c.junction, links_of(c));
            push_lines(&mut self.lines, geometry, c.junction, now);
        }
        &self.lines
    }

    /// The stop lines of junctions `states` (junction id from 1, state) as they show them.
    pub fn from_states<'a>(&mut self, states: impl IntoIterator<Item = (u32, &'a str)>) -> &[SignalLine] {
        self.lines.clear();
        let Some(geometry) = &self.geometry else { return &self.lines };
        for (id, state) in states {
            push_lines(&mut self.lines, geometry, id.wrapping_sub(1), state.as_bytes());
        }
        &self.lines
    }
}

fn push_lines(out: &mut Vec<SignalLine>, geometry: &[Vec<(DVec2, DVec2)>], junction: u32, state: &[u8]) {
    let Some(links) = geometry.get(junction as usize) else { return };
    out.extend(links.iter().zip(state).map(|(&(a, b), &signal)| SignalLine { a, b, signal }));
}

/// What stops reading a run's `lights.csv` (a replay reports it as its own error).
#[derive(Debug, thiserror::Error)]
pub enum LightsError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A row is malformed or does not fit the run's map.
    #[error("{path}:{line}: {message} (expected `t,junction,state` rows in time order, as `smlworld run` writes them)")]
    Row {
        /// The CSV file.
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
}

/// A run's `lights.csv`, replayed in time order.
#[derive(Debug, Clone, Default)]
pub struct LightTimeline {
    /// Rows: time [s], junction id, state.
    rows: Vec<(f64, u32, String)>,
    next: usize,
    current: BTreeMap<u32, String>,
}

impl LightTimeline {
    /// Read `path` (see the module docs); `Ok(None)` when there is no such file (a run without
    /// lights, or one older than `lights.csv`). When `map` is given, every junction must be one
    /// of its junctions and every state as long as its links.
    pub fn read(path: &Path, map: Option<&LaneletMap>) -> Result<Option<LightTimeline>, LightsError> {
        let text = match std::fs::read_to_string(path) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(source) => return Err(LightsError::Io { path: path.to_path_buf(), source }),
        };
        let links: Option<Vec<usize>> = map.map(|m| m.junctions().list.iter().map(|j| j.links.len()).collect());
        parse_lights(&text, path, links.as_deref()).map(Some)
    }

    /// Take every row up to time `t` \[s\].
    pub fn advance_to(&mut self, t: f64) {
        while let Some((_, id, state)) = self.rows.get(self.next).filter(|r| r.0 <= t + 1e-9) {
            self.current.insert(*id, state.clone());
            self.next += 1;
        }
    }

    /// What every junction shows at the time last advanced to: (id, state), by id.
    pub fn states(&self) -> impl Iterator<Item = (u32, &str)> {
        self.current.iter().map(|(id, s)| (*id, s.as_str()))
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// Whether there are no rows.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }
}

fn parse_lights(text: &str, path: &Path, links: Option<&[usize]>) -> Result<LightTimeline, LightsError> {
    let err = |line: usize, message: String| LightsError::Row { path: PathBuf::from(path), line, message };
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, h)) if h.trim() == LIGHTS_CSV_HEADER => {}
        other => {
            return Err(err(
                1,
                format!("the header is `{}`, not `{LIGHTS_CSV_HEADER}`", other.map_or("", |(_, h)| h.trim())),
            ));
        }
    }
    let mut rows = Vec::new();
    let mut last_t = f64::NEG_INFINITY;
    for (i, line) in lines {
        let n = i + 1;
        if line.trim().is_empty() {
            continue;
        }
        let mut fields = line.split(',');
        let (Some(t), Some(id), Some(state), None) = (fields.next(), fields.next(), fields.next(), fields.next())
        else {
            return Err(err(n, format!("`{line}` does not have 3 fields")));
        };
        let t: f64 = t
            .trim()
            .parse()
            .ok()
            .filter(|t: &f64| t.is_finite())
            .ok_or_else(|| err(n, format!("time `{t}` is not a number of seconds")))?;
        if t < last_t {
            return Err(err(n, format!("time {t} s comes before the row above ({last_t} s): rows go in time order")));
        }
        last_t = t;
        let id: u32 = id.trim().parse().ok().filter(|&id| id >= 1).ok_or_else(|| {
            err(
                n,
                format!("junction `{id}` is not a junction id (an integer from 1, as `smlworld map info` lists them)"),
            )
        })?;
        let state = state.trim();
        crate::vehicles::right_of_way::check_state(state, state.chars().count()).map_err(|m| err(n, m))?;
        if let Some(links) = links {
            match links.get(id as usize - 1) {
                None => {
                    return Err(err(
                        n,
                        format!(
                            "junction {id} is not on the run's map ({} junctions): was the map changed?",
                            links.len()
                        ),
                    ));
                }
                Some(&k) if k != state.len() => {
                    return Err(err(
                        n,
                        format!(
                            "junction {id} has {k} links on the run's map but the state `{state}` has {} characters: \
                             was the map changed?",
                            state.len()
                        ),
                    ));
                }
                Some(_) => {}
            }
        }
        rows.push((t, id, state.to_string()));
    }
    Ok(LightTimeline { rows, next: 0, current: BTreeMap::new() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_timeline_gives_each_junction_its_last_state() {
        let csv = "t,junction,state\n0,1,GGrr\n0,2,rrGG\n30,1,yyrr\n33,1,rrrr\n";
        let mut t = parse_lights(csv, Path::new("lights.csv"), Some(&[4, 4])).expect("parses");
        t.advance_to(0.0);
        assert_eq!(t.states().collect::<Vec<_>>(), vec![(1, "GGrr"), (2, "rrGG")]);
        t.advance_to(31.0);
        assert_eq!(t.states().collect::<Vec<_>>(), vec![(1, "yyrr"), (2, "rrGG")]);
        t.advance_to(40.0);
        assert_eq!(t.states().next(), Some((1, "rrrr")));
    }

    #[test]
    fn bad_rows_name_the_line_and_the_problem() {
        let bad = |csv: &str| parse_lights(csv, Path::new("lights.csv"), Some(&[4])).unwrap_err().to_string();
        assert!(bad("t,id\n").contains("header"), "{}", bad("t,id\n"));
        assert!(bad("t,junction,state\n0,1,GGr\n").contains("3 characters"));
        assert!(bad("t,junction,state\n0,2,GGrr\n").contains("junction 2 is not on the run's map"));
        assert!(bad("t,junction,state\n0,1,GGxr\n").contains("`x`"));
        assert!(bad("t,junction,state\n5,1,GGrr\n1,1,rrGG\n").contains("lights.csv:3"));
        assert!(bad("t,junction,state\nx,1,GGrr\n").contains("time `x`"));
    }
}
