//! A simulation driven step by step from another program (the Python package `smlworld` is
//! built on it): load a scenario with overrides, advance it by any sim time, read all states into
//! flat arrays, read one vehicle's sensor readings, set commands for many vehicles at once,
//! send and receive V2V bytes, and summarise the run as `summary.json` does.
//!
//! ```no_run
//! use smlworld::app::Session;
//!
//! let mut s = Session::from_scenario("scenarios/platoon_brake.toml".as_ref(), Some(3), &[]).expect("the shipped scenario loads");
//! s.step(1.0);
//! let mut states = Default::default();
//! s.states_into(&mut states);
//! println!("{} vehicles at t = {} s", states.id.len(), s.time());
//! ```
//!
//! Every call is O(N) in the vehicles it touches; nothing here changes what the simulation
//! computes (a session stepped in any chunks gives the trajectories of `smlworld run`).

use std::path::Path as FsPath;
use std::sync::Arc;
use std::time::Instant;

use bevy_ecs::prelude::{Component, Query, Res, World};
use bevy_ecs::schedule::IntoScheduleConfigs;

use crate::map::LaneletMap;
use crate::render::{FrameOutput, FrameRecorder, Overlay};
use crate::sim::{Control, Sim, SimClock, SimSystems};
use crate::vehicles::{JunctionNetwork, Longitudinal, LongitudinalSystems, TrafficLights};
use crate::world::{
    AccelerationUnicycle, Channel, ControlCommand, Inbox, KinematicUnicycle, Mailbox, SensorReadings, SimTime,
    VehicleId, VehicleState, Vehicles,
};

use super::runner::RunReport;
use super::scenario::{Scenario, ScenarioError};
use super::signals::{MeasureQuery, SignalLayout, SignalMeasures, WaitingMemory, accumulate_waiting, measure};
use super::summary::RunSummary;

/// What a session call can reject (the message names the key, id or argument and what is allowed).
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// The scenario could not be loaded or assembled.
    #[error(transparent)]
    Scenario(#[from] ScenarioError),
    /// A bad argument (unknown id, wrong length, NaN, bad override ...).
    #[error("{0}")]
    Argument(String),
}

fn arg<T>(message: String) -> Result<T, SessionError> {
    Err(SessionError::Argument(message))
}

/// The payload type of V2V messages sent through [`Session::send`]: raw bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Bytes(pub Vec<u8>);

/// Most byte messages [`Session::inbox`] keeps per vehicle and channel between two calls; past
/// it the oldest are dropped first (with one warning per vehicle and channel).
pub const INBOX_CAPACITY: usize = 10_000;

/// Byte messages received by one vehicle on one channel since [`Session::inbox`] last read them.
#[derive(Debug, Default)]
struct ByteQueue {
    /// Newest V2V round already copied (rounds count from 1 per channel).
    last_round: u64,
    messages: std::collections::VecDeque<(i32, Vec<u8>)>,
    dropped: u64,
}

impl ByteQueue {
    /// Copy the byte messages of rounds not copied yet out of `inbox`.
    fn collect(&mut self, owner: VehicleId, channel: &str, inbox: &Inbox) {
        for m in inbox.iter_after(self.last_round) {
            if let Some(b) = m.payload::<Bytes>() {
                if self.messages.len() == INBOX_CAPACITY {
                    self.messages.pop_front();
                    if self.dropped == 0 {
                        tracing::warn!(
                            "vehicle {} holds {INBOX_CAPACITY} unread {channel} messages: dropping the oldest; call inbox() more often",
                            owner.0
                        );
                    }
                    self.dropped += 1;
                }
                self.messages.push_back((m.sender.0, b.0.clone()));
            }
        }
        self.last_round = self.last_round.max(inbox.latest_round().unwrap_or(0));
    }
}

/// The unread byte messages of a vehicle whose in-box Python reads ([`Session::inbox`]): filled
/// at every control tick, because a V2V in-box holds only the rounds since the last one.
#[derive(Component, Debug, Default)]
struct ByteInbox {
    wifi: ByteQueue,
    network: ByteQueue,
}

impl ByteInbox {
    fn collect(&mut self, mailbox: &Mailbox) {
        self.wifi.collect(mailbox.owner(), "wifi", &mailbox.wifi_in);
        self.network.collect(mailbox.owner(), "network", &mailbox.network_in);
    }
}

/// Control-phase system: keep what the read in-boxes received this tick.
fn collect_byte_inboxes(mut q: Query<(&Mailbox, &mut ByteInbox)>) {
    for (mailbox, mut queue) in &mut q {
        queue.collect(mailbox);
    }
}

/// Commands set from outside ([`Session::set_commands`]): they replace what the vehicle's own
/// controller wrote, at every control tick after all controllers ran, until cleared.
#[derive(Component, Debug, Clone, Copy, Default, PartialEq)]
pub struct CommandOverride {
    /// Throttle \[N\].
    pub throttle: Option<f64>,
    /// Steering \[rad\].
    pub steering: Option<f64>,
    /// Speed [m/s].
    pub speed: Option<f64>,
}

impl CommandOverride {
    /// Write the set fields over `c`'s.
    pub fn apply(&self, c: &mut ControlCommand) {
        if let Some(t) = self.throttle {
            c.throttle = t;
        }
        if let Some(s) = self.steering {
            c.steering = s;
        }
        if let Some(v) = self.speed {
            c.speed = v;
        }
    }
}

/// Control-phase system: overrides win over the controllers (runs after [`SimSystems::Control`]).
fn apply_overrides(mut q: Query<(&CommandOverride, &mut ControlCommand)>) {
    for (o, mut c) in &mut q {
        o.apply(&mut c);
    }
}

/// Control-phase system, after the longitudinal pipeline decided and before it reports: a
/// vehicle whose commands are set from outside tells the others (V2V beacons) the acceleration
/// those commands give, not what its own controller asked for (issue 22 item 5: CACC followers
/// of a Python-driven leader must brake with it). Acceleration model: `(throttle - drag v) /
/// mass`; kinematic model: `(speed - v) / dt` [m/s²].
#[allow(clippy::type_complexity)]
fn report_overridden_accel(
    clock: Res<SimClock>,
    mut q: Query<(
        &CommandOverride,
        &ControlCommand,
        &VehicleState,
        &mut Longitudinal,
        Option<&AccelerationUnicycle>,
        Option<&KinematicUnicycle>,
    )>,
) {
    for (o, command, state, mut lon, acceleration, kinematic) in &mut q {
        let mut c = *command;
        o.apply(&mut c);
        let v = state.speed().max(0.0);
        let accel = match (acceleration, kinematic) {
            (Some(m), None) if m.mass > 0.0 => (c.throttle - m.drag * v) / m.mass,
            _ if clock.dt > 0.0 => (c.speed - v) / clock.dt,
            _ => continue,
        };
        if accel.is_finite() {
            lon.accel = accel;
        }
    }
}

/// All vehicles' states as columns, sorted by id (see [`Session::states_into`]).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StateColumns {
    /// Vehicle ids, ascending.
    pub id: Vec<i32>,
    /// Position x \[m\].
    pub x: Vec<f64>,
    /// Position y \[m\].
    pub y: Vec<f64>,
    /// Heading \[rad\].
    pub yaw: Vec<f64>,
    /// Velocity x [m/s].
    pub vx: Vec<f64>,
    /// Velocity y [m/s].
    pub vy: Vec<f64>,
    /// Id of the lanelet under the reference point (NaN off the road or without a map).
    pub lanelet: Vec<f64>,
    /// Signed offset from that lanelet's centre line \[m\], left positive (NaN off the road).
    pub lane_offset: Vec<f64>,
}

pub use super::scenario::apply_override;

/// Load a scenario file with `overrides` (dotted keys, `*` for every element of an array, see
/// [`super::scenario::overrides`]) and an optional seed applied before it is checked; errors
/// name the file, line and key.
pub fn load_scenario_with_overrides(
    path: &FsPath,
    seed: Option<u64>,
    overrides: &[(String, toml::Value)],
) -> Result<Scenario, SessionError> {
    Ok(super::scenario::load_with_overrides(path, seed, overrides, &Default::default())?)
}

/// What one signalised junction shows ([`Session::traffic_lights`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LightState {
    /// Junction id (from 1, as `smlworld map info` lists them).
    pub junction: u32,
    /// One character per link in link order: `G` green with priority, `g` green yielding, `y`
    /// yellow, `r` red.
    pub state: String,
    /// Index of the program's phase shown (0-based); `None` while a state set by
    /// [`Session::set_phase`] is held.
    pub phase: Option<usize>,
    /// The lanelet of each link, in the order of `state`'s characters.
    pub lanelets: Vec<i64>,
}

/// A scenario's simulation, stepped by the caller.
pub struct Session {
    sim: Sim,
    /// The off-screen renderer of [`Session::frame`], made at the first call (and again when the
    /// size changes).
    renderer: Option<(u32, u32, FrameRecorder)>,
    /// The stop lines [`Session::frame`] draws in their signals' colours.
    signals: crate::app::results::lights::SignalLines,
    scenario: Scenario,
    wall_seconds: f64,
    start: SimTime,
    /// The lights' layout and the vehicle query of [`Session::signal_measures`], made at its
    /// first call.
    signal_state: Option<(SignalLayout, MeasureQuery)>,
}

impl Session {
    /// Load `path` (with `seed` and `overrides`, see [`load_scenario_with_overrides`]) and build
    /// its simulation at time 0.
    pub fn from_scenario(
        path: &FsPath,
        seed: Option<u64>,
        overrides: &[(String, toml::Value)],
    ) -> Result<Session, SessionError> {
        let scenario = load_scenario_with_overrides(path, seed, overrides)?;
        Session::new(scenario)
    }

    /// Build the simulation of a loaded scenario.
    pub fn new(scenario: Scenario) -> Result<Session, SessionError> {
        let mut b = scenario.builder()?;
        b.add_systems(Control, apply_overrides.after(SimSystems::Control).before(SimSystems::Integrate));
        b.add_systems(Control, collect_byte_inboxes.after(SimSystems::Control));
        b.add_systems(
            Control,
            report_overridden_accel.after(LongitudinalSystems::Actuate).before(LongitudinalSystems::Report),
        );
        let mut sim = b.build();
        // Waiting times are what a traffic-signal environment rewards (issue 55): counted
        // where there are lights to learn.
        if sim.world().get_resource::<TrafficLights>().is_some_and(|l| !l.controllers.is_empty())
            && let Some(schedule) = sim.scheduler_mut().schedule_mut(crate::sim::Dynamics)
        {
            schedule.add_systems(accumulate_waiting.after(SimSystems::Integrate));
        }
        let start = sim.now();
        Ok(Session {
            sim,
            renderer: None,
            signals: Default::default(),
            scenario,
            wall_seconds: 0.0,
            start,
            signal_state: None,
        })
    }

    /// The simulation.
    pub fn sim(&self) -> &Sim {
        &self.sim
    }

    /// The simulation, mutably.
    pub fn sim_mut(&mut self) -> &mut Sim {
        &mut self.sim
    }

    /// Stop recording the summary's metrics (collisions, follower gaps, platoon speeds, route
    /// deviation) from now on, for callers that never read them: a learning environment checks
    /// its own collisions, and the metrics take about a third of each tick of a small scenario.
    /// The metrics only read the states, so every trajectory stays the same, bit for bit;
    /// [`Session::summary`] reports what was recorded before the call.
    pub fn stop_metrics(&mut self) {
        use super::metrics::{record_metrics, record_route_deviation};
        use bevy_ecs::schedule::ScheduleCleanupPolicy;
        // The schedule needs the world while both are borrowed from the Sim: lend it a
        // placeholder for the moment.
        let mut world = std::mem::take(self.sim.world_mut());
        if let Some(schedule) = self.sim.scheduler_mut().schedule_mut(crate::sim::Dynamics) {
            for result in [
                schedule.remove_systems_in_set(record_metrics, &mut world, ScheduleCleanupPolicy::RemoveSystemsOnly),
                schedule.remove_systems_in_set(
                    record_route_deviation,
                    &mut world,
                    ScheduleCleanupPolicy::RemoveSystemsOnly,
                ),
            ] {
                if let Err(e) = result {
                    tracing::warn!("stop_metrics: {e}");
                }
            }
        }
        *self.sim.world_mut() = world;
    }

    /// The scenario.
    pub fn scenario(&self) -> &Scenario {
        &self.scenario
    }

    /// The scenario's map, if it names one.
    pub fn map(&self) -> Option<&Arc<LaneletMap>> {
        self.scenario.map.as_ref()
    }

    /// Sim time \[s\].
    pub fn time(&self) -> f64 {
        self.sim.now().as_secs()
    }

    /// Advance sim time by `dt` \[s\] through the normal multi-rate schedule (every tick due before
    /// the new time runs).
    pub fn step(&mut self, dt: f64) -> Result<(), SessionError> {
        if !(dt.is_finite() && dt >= 0.0) {
            return arg(format!("dt must be a finite number of seconds >= 0, got {dt}"));
        }
        let wall = Instant::now();
        self.sim.run_for(dt);
        // Lane positions are found where they are read; the state arrays read them now.
        crate::vehicles::refresh_lane_positions(self.sim.world_mut());
        self.wall_seconds += wall.elapsed().as_secs_f64();
        Ok(())
    }

    /// [`Session::step`] that stops early, right after the first module tick after which
    /// `stop(world)` holds (the Python package stops at a controller callback that raised):
    /// `Ok(true)` then, with the clock at that tick.
    pub fn step_until(&mut self, dt: f64, mut stop: impl FnMut(&World) -> bool) -> Result<bool, SessionError> {
        if !(dt.is_finite() && dt >= 0.0) {
            return arg(format!("dt must be a finite number of seconds >= 0, got {dt}"));
        }
        let wall = Instant::now();
        let end = SimTime(self.sim.now().0 + SimTime::from_secs(dt).0);
        let mut stopped = false;
        while self.sim.scheduler().peek().is_some_and(|(_, due, _, _)| due < end) {
            self.sim.step();
            if stop(self.sim.world()) {
                stopped = true;
                break;
            }
        }
        if !stopped {
            self.sim.run_until(end);
        }
        crate::vehicles::refresh_lane_positions(self.sim.world_mut());
        self.wall_seconds += wall.elapsed().as_secs_f64();
        Ok(stopped)
    }

    /// The bird's-eye view of the whole map with the vehicles as they are now, `width` x `height`
    /// RGBA pixels (row-major, 4 bytes per pixel), from the off-screen renderer; a red ring
    /// marks vehicles whose footprints overlap (for a few seconds after they met).
    pub fn frame(&mut self, width: u32, height: u32) -> Result<Vec<u8>, SessionError> {
        if !(16..=8192).contains(&width) || !(16..=8192).contains(&height) {
            return arg(format!("frame size must be 16..=8192 px each way, got {width} x {height}"));
        }
        if self.renderer.as_ref().is_none_or(|(w, h, _)| (*w, *h) != (width, height)) {
            let Some(map) = self.scenario.map.as_ref() else {
                return arg(format!(
                    "frame draws the scenario's map, but {} names no `map`",
                    self.scenario.path.display()
                ));
            };
            let opts = FrameOutput { width, height, overlay: Overlay::None, ..FrameOutput::default() };
            let rec = FrameRecorder::new(map, &opts).map_err(|e| SessionError::Argument(format!("renderer: {e}")))?;
            self.renderer = Some((width, height, rec));
        }
        let Some((_, _, rec)) = self.renderer.as_mut() else {
            return arg("renderer: not available".to_string());
        };
        rec.set_signals(self.signals.from_world(self.sim.world()));
        // Vehicles that overlap now get the red collision ring: a learning environment stops the
        // metrics that record collision events (issue 61 §2: PlatoonFollow's frame at a
        // collision showed the cars overlapping and no ring).
        let image = rec
            .render_marking_overlaps(self.sim.world())
            .map_err(|e| SessionError::Argument(format!("renderer: {e}")))?;
        Ok(image.into_raw())
    }

    /// What every signalised junction shows now, by junction id (empty without traffic lights).
    pub fn traffic_lights(&self) -> Vec<LightState> {
        let world = self.sim.world();
        let (Some(lights), Some(network)) =
            (world.get_resource::<TrafficLights>(), world.get_resource::<JunctionNetwork>())
        else {
            return Vec::new();
        };
        lights
            .controllers
            .iter()
            .map(|c| LightState {
                junction: c.junction + 1,
                state: lights.state_of(c.junction).unwrap_or_default(),
                phase: c.manual.is_none().then_some(c.phase),
                lanelets: network
                    .junctions
                    .list
                    .get(c.junction as usize)
                    .map_or_else(Vec::new, |j| j.links.iter().map(|l| l.lanelet.0).collect()),
            })
            .collect()
    }

    /// Show `state` (one character per link: `G`, `g`, `y`, `r`) at the junction with id
    /// `junction` (from 1) from now on, instead of its program, until set again; the vehicles
    /// see it at the next control tick. An error names the junction or the state's problem and
    /// what is allowed (the signalised junctions, the number of links, the characters).
    pub fn set_phase(&mut self, junction: u32, state: &str) -> Result<(), SessionError> {
        let signalised: Vec<u32> = self.traffic_lights().iter().map(|l| l.junction).collect();
        let Some(mut lights) =
            self.sim.world_mut().get_resource_mut::<TrafficLights>().filter(|_| !signalised.is_empty())
        else {
            return arg(format!(
                "set_phase: {} has no traffic lights (its map has no signalised junction and no \
                 `[[traffic_lights]]` table)",
                self.scenario.path.display()
            ));
        };
        if !signalised.contains(&junction) {
            return arg(format!(
                "set_phase: junction {junction} has no traffic light; the signalised junctions are {}",
                signalised.iter().map(u32::to_string).collect::<Vec<_>>().join(", ")
            ));
        }
        lights
            .set_state(junction - 1, state)
            .map_err(|m| SessionError::Argument(format!("set_phase: junction {junction}: {m}")))
    }

    /// Every traffic light's program and controlled lanes (see [`SignalLayout`]); empty without
    /// lights.
    pub fn signal_layout(&mut self) -> &SignalLayout {
        &self.signal_parts().0
    }

    /// Measure every light's lanes and the system now, into `out` (see [`SignalMeasures`]):
    /// one pass over the vehicles.
    pub fn signal_measures(&mut self, out: &mut SignalMeasures) {
        let now = self.time();
        self.signal_parts();
        if let Some((layout, query)) = self.signal_state.as_mut() {
            measure(self.sim.world_mut(), query, layout, now, out);
        }
    }

    /// Remember waiting for `seconds` \[s\] (SUMO's `--waiting-time-memory`, default 1000 s as
    /// sumo-rl sets it); an error for a value that is not a positive finite number.
    pub fn set_waiting_memory(&mut self, seconds: f64) -> Result<(), SessionError> {
        if !(seconds.is_finite() && seconds > 0.0) {
            return arg(format!("waiting_time_memory must be a positive number of seconds, got {seconds}"));
        }
        self.sim.world_mut().insert_resource(WaitingMemory(seconds));
        Ok(())
    }

    fn signal_parts(&mut self) -> &(SignalLayout, MeasureQuery) {
        let world = self.sim.world_mut();
        self.signal_state.get_or_insert_with(|| {
            let layout = match (world.get_resource::<TrafficLights>(), world.get_resource::<JunctionNetwork>()) {
                (Some(lights), Some(network)) => SignalLayout::new(lights, network),
                _ => SignalLayout::default(),
            };
            (layout, world.query())
        })
    }

    /// Advance by `duration` \[s\] and summarise everything run so far as `summary.json` does.
    pub fn run(&mut self, duration: f64) -> Result<RunSummary, SessionError> {
        self.step(duration)?;
        Ok(self.summary())
    }

    /// The summary of everything run so far (the content of `summary.json`).
    pub fn summary(&self) -> RunSummary {
        let report = RunReport {
            sim_seconds: SimTime(self.sim.now().0 - self.start.0).as_secs(),
            wall_seconds: self.wall_seconds,
            rate_warnings: 0,
            max_lag_seconds: 0.0,
            interrupted: false,
        };
        RunSummary::new(&self.sim, &report)
    }

    /// Every vehicle's state, sorted by id, into `out` (its vectors are reused).
    pub fn states_into(&self, out: &mut StateColumns) {
        for v in
            [&mut out.x, &mut out.y, &mut out.yaw, &mut out.vx, &mut out.vy, &mut out.lanelet, &mut out.lane_offset]
        {
            v.clear();
        }
        out.id.clear();
        for (id, s) in self.sim.states() {
            out.id.push(id.0);
            out.x.push(s.position.x);
            out.y.push(s.position.y);
            out.yaw.push(s.yaw);
            out.vx.push(s.velocity.x);
            out.vy.push(s.velocity.y);
            let lane = self
                .sim
                .entity(id)
                .and_then(|e| self.sim.world().get::<crate::vehicles::LanePosition>(e))
                .and_then(|l| Some((l.lanelet?.0 as f64, l.offset)));
            out.lanelet.push(lane.map_or(f64::NAN, |l| l.0));
            out.lane_offset.push(lane.map_or(f64::NAN, |l| l.1));
        }
    }

    /// Ask vehicle `id` (which needs a `lane_change` table) to change lanes to `side` (`"left"`
    /// or `"right"`): `Ok(false)` when the map forbids it (no lane there, or a solid line), a
    /// change is already under way, or the target gap is closed now; `Ok(true)` when the
    /// lane-change plugin takes the request, which it carries out with MOBIL's safety check
    /// (dropping it if the gap closes before it can start).
    pub fn change_lane(&mut self, id: i32, side: &str) -> Result<bool, SessionError> {
        use crate::vehicles::lane_changing::{LaneIndex, allowed, target_gap_closed};
        use crate::vehicles::{LaneChanger, LaneMap, LanePosition, Side};
        let side = match side {
            "left" => Side::Left,
            "right" => Side::Right,
            other => return arg(format!("side must be \"left\" or \"right\", got {other:?}")),
        };
        let e = self.entity(id)?;
        let world = self.sim.world();
        let Some(changer) = world.get::<LaneChanger>(e) else {
            return arg(format!(
                "vehicle {id} has no `lane_change` table; add `lane_change = true` to it in the scenario"
            ));
        };
        if changer.active.is_some() {
            return Ok(false);
        }
        let (Some(lanes), Some(pos)) = (world.get_resource::<LaneMap>(), world.get::<LanePosition>(e)) else {
            return Ok(false);
        };
        let Some(i) = pos.on() else { return Ok(false) };
        let Some(j) = allowed(lanes, i, side) else { return Ok(false) };
        if let Some(index) = world.get_resource::<LaneIndex>() {
            let me = VehicleId(id);
            let s_j = pos.s * lanes.length(j) / lanes.length(i).max(1e-9);
            let v = world.get::<crate::world::VehicleState>(e).map_or(0.0, |s| s.speed());
            let length = world.get::<crate::world::VehicleSize>(e).map_or(4.12, |s| s.length);
            let closed = target_gap_closed(
                &changer.law,
                changer.params.safe_deceleration,
                v,
                length,
                index.ahead(lanes, j, s_j, me),
                index.behind(lanes, j, s_j, me),
            );
            if closed {
                return Ok(false);
            }
        }
        if let Some(mut c) = self.sim.world_mut().get_mut::<LaneChanger>(e) {
            c.request = Some(side);
        }
        Ok(true)
    }

    fn entity(&self, id: i32) -> Result<bevy_ecs::entity::Entity, SessionError> {
        match self.sim.entity(VehicleId(id)) {
            Some(e) => Ok(e),
            None => {
                let ids: Vec<i32> = self.sim.world().resource::<Vehicles>().iter().map(|(id, _)| id.0).collect();
                arg(format!("unknown vehicle id {id}; the scenario has ids {ids:?}"))
            }
        }
    }

    /// What vehicle `id`'s sensors saw at the last sensor tick, nearest first, as rows
    /// `[id, x, y, vx, vy]` [-, m, m, m/s, m/s].
    pub fn readings(&self, id: i32) -> Result<Vec<[f64; 5]>, SessionError> {
        let e = self.entity(id)?;
        let readings = self.sim.world().get::<SensorReadings>(e);
        Ok(readings
            .map(|r| {
                r.0.iter().map(|d| [d.id.0 as f64, d.position.x, d.position.y, d.velocity.x, d.velocity.y]).collect()
            })
            .unwrap_or_default())
    }

    /// The name of the sensor that saw each row of [`Session::readings`] of vehicle `id`, in
    /// the same order: `"radar"`, `"velodyne"`, `"omniscient"` or a plugin sensor's registered
    /// name.
    pub fn reading_sensors(&self, id: i32) -> Result<Vec<&'static str>, SessionError> {
        let e = self.entity(id)?;
        let readings = self.sim.world().get::<SensorReadings>(e);
        Ok(readings.map(|r| r.0.iter().map(|d| d.sensor).collect()).unwrap_or_default())
    }

    /// Set the commands of vehicles `ids`: each given column (throttle \[N\], steering \[rad\],
    /// speed [m/s]) must have one finite value per id; a column left out keeps its value. Checks
    /// everything before changing anything. They act at once and replace what the vehicle's own
    /// controller (if any) writes at every later control tick, until [`Session::clear_commands`].
    pub fn set_commands(
        &mut self,
        ids: &[i32],
        throttle: Option<&[f64]>,
        steering: Option<&[f64]>,
        speed: Option<&[f64]>,
    ) -> Result<(), SessionError> {
        for (name, col) in [("throttle", throttle), ("steering", steering), ("speed", speed)] {
            if let Some(col) = col {
                if col.len() != ids.len() {
                    return arg(format!("{name} has {} values for {} ids; give one per id", col.len(), ids.len()));
                }
                if let Some(i) = col.iter().position(|v| !v.is_finite()) {
                    return arg(format!("{name}[{i}] (vehicle {}) is {}; commands must be finite", ids[i], col[i]));
                }
            }
        }
        let entities = ids.iter().map(|&id| self.entity(id)).collect::<Result<Vec<_>, _>>()?;
        let world = self.sim.world_mut();
        for (i, e) in entities.into_iter().enumerate() {
            let Some(mut entity) = world.get_entity_mut(e).ok().filter(|w| w.contains::<ControlCommand>()) else {
                return arg(format!("vehicle {} takes no commands", ids[i]));
            };
            let mut o = entity.get::<CommandOverride>().copied().unwrap_or_default();
            if let Some(t) = throttle {
                o.throttle = Some(t[i]);
            }
            if let Some(s) = steering {
                o.steering = Some(s[i]);
            }
            if let Some(s) = speed {
                o.speed = Some(s[i]);
            }
            if let Some(mut c) = entity.get_mut::<ControlCommand>() {
                o.apply(&mut c);
            }
            // Overwritten in place once it exists (an insert goes through bevy's bundle
            // machinery: a learning env sets commands at every step).
            match entity.get_mut::<CommandOverride>() {
                Some(mut existing) => *existing = o,
                None => {
                    entity.insert(o);
                }
            }
        }
        Ok(())
    }

    /// Give vehicles `ids` back to their own controllers (drop what [`Session::set_commands`] set).
    pub fn clear_commands(&mut self, ids: &[i32]) -> Result<(), SessionError> {
        let entities = ids.iter().map(|&id| self.entity(id)).collect::<Result<Vec<_>, _>>()?;
        for e in entities {
            self.sim.world_mut().entity_mut(e).remove::<CommandOverride>();
        }
        Ok(())
    }

    fn channel(name: &str) -> Result<Channel, SessionError> {
        match name {
            "wifi" => Ok(Channel::Wifi),
            "network" => Ok(Channel::Network),
            _ => arg(format!("unknown channel `{name}`; use \"wifi\" or \"network\"")),
        }
    }

    /// Queue `payload` from vehicle `id` on `channel` (`"wifi"` or `"network"`); it leaves at the
    /// channel's next V2V round, like a Rust controller's message.
    pub fn send(&mut self, id: i32, channel: &str, payload: Vec<u8>) -> Result<(), SessionError> {
        let channel = Session::channel(channel)?;
        let e = self.entity(id)?;
        let now = self.sim.now();
        let Some(mut mb) = self.sim.world_mut().get_mut::<Mailbox>(e) else {
            return arg(format!("vehicle {id} has no mailbox (`mailbox = false` in the scenario)"));
        };
        mb.send_typed(channel, now, Bytes(payload));
        Ok(())
    }

    /// The byte messages vehicle `id` received on `channel` since the last call for it, oldest
    /// first, as `(sender, bytes)`; messages of other payload types are skipped. The first call
    /// for a vehicle returns what its in-box holds now (the rounds since the last control tick);
    /// from then on every message is kept until read, at most [`INBOX_CAPACITY`] per vehicle and
    /// channel (the oldest dropped first, with a warning).
    pub fn inbox(&mut self, id: i32, channel: &str) -> Result<Vec<(i32, Vec<u8>)>, SessionError> {
        let channel = Session::channel(channel)?;
        let e = self.entity(id)?;
        let world = self.sim.world_mut();
        if world.get::<Mailbox>(e).is_none() {
            return arg(format!("vehicle {id} has no mailbox (`mailbox = false` in the scenario)"));
        }
        if world.get::<ByteInbox>(e).is_none() {
            world.entity_mut(e).insert(ByteInbox::default());
        }
        // The entity's own components, not `world.query`: building a query state at every call
        // was a twentieth of a learning environment's step.
        let mut entity = world.entity_mut(e);
        let Ok((mailbox, mut queue)) = entity.get_components_mut::<(&Mailbox, &mut ByteInbox)>() else {
            return arg(format!("vehicle {id} has no mailbox"));
        };
        queue.collect(mailbox);
        let q = match channel {
            Channel::Wifi => &mut queue.wifi,
            Channel::Network => &mut queue.network,
        };
        Ok(q.messages.drain(..).collect())
    }
}
