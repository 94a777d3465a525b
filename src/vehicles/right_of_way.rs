//! Right of way at junctions and traffic lights, for every vehicle that uses the longitudinal
//! pipeline ([`super::longitudinal`]): a limiter in [`LongitudinalSystems::Limit`], so IDM,
//! cruise, ACC, CACC, GCDC and student controllers get it without a change.
//!
//! Each control tick, for every vehicle whose route reaches a junction ([`crate::map::junctions`])
//! within [`JunctionParams::look_ahead`]:
//! - **curves**: its speed is limited before and on the junction's links so that the lateral
//!   acceleration stays under [`JunctionParams::lateral_accel`] (`v = √(a_lat / κ)`);
//! - **signals**: on red it stops at the stop line (the start of its link) if it can at
//!   [`JunctionParams::red_decel`]; on yellow it stops if it can at
//!   [`JunctionParams::yellow_decel`] (SUMO's rule, [`stops_at_yellow`]), else drives on;
//! - **keep clear**: it does not pass the stop line while the lanelet after the junction has no
//!   room for it (a slow vehicle's rear closer than its length, counting those already driving
//!   in), so junctions do not gridlock;
//! - **conflicts**: for every conflict of its links, every foe on the other link (ground truth of
//!   the vehicles approaching within the look-ahead, as SUMO's junction model knows them): a foe
//!   that is already driving through must have cleared the conflict point [`JunctionParams::time_gap`]
//!   before it arrives, or arrive after it has cleared it by the same gap; a foe with priority
//!   (major road, the vehicle on the right, a `G` against its `g`, the first to arrive) that is
//!   moving must reach the conflict point later than this vehicle clears it plus the gap
//!   ([`accepts_gap`]; SUMO's `jmTimegapMinor`, 1 s, on exact arrival estimates). Otherwise it
//!   stops at the stop line; once it could no longer stop, it goes.
//!
//! Decisions are made one vehicle after another in a fixed order (those inside the junction,
//! then by distance to the stop line, then id), each seeing the decisions before it, so two
//! vehicles never take the same gap in the same tick and the result is the same on any number
//! of threads. Vehicles with a V2V [`CrossingNegotiator`], or whose own negotiation decides
//! their passage ([`JunctionDriver::own_negotiation`], set by the GCDC intersection's), are only
//! foes here. Traffic-light programs are a resource ([`TrafficLights`]) advanced by their own
//! system before the decisions.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use bevy_ecs::prelude::{Commands, Component, Entity, Local, Query, Res, ResMut, Resource, With, Without};
use bevy_ecs::schedule::IntoScheduleConfigs;

use crate::map::junctions::{ConflictKind, Fallback, JunctionRules, Junctions, SignalPhase, Turn, find_junctions};
use crate::map::{JunctionControl, LaneletMap, Path};
use crate::sim::params::{ParamError, Range, check_all};
use crate::sim::{Control, Dynamics, Parallelism, Plugin, SimBuilder, SimClock};
use crate::world::{Route, VehicleId, VehicleSize, VehicleState};

use super::PathFollower;
use super::crossing::{CrossingNegotiator, can_stop_within, stop_before, stop_within_step};
use super::lanes::PREFETCH_AHEAD;
use super::longitudinal::{Longitudinal, LongitudinalSystems, install_longitudinal};

/// Links with a curve speed \[m/s\] below this count in [`JunctionNetwork::crossing_time`].
const CROSSING_SPEED: f64 = 10.0;

/// Half the extent of a conflict area along each link \[m\]: a vehicle "reaches" a conflict
/// point this far before it and has "cleared" it with its rear this far after.
pub const CLEAR: f64 = 2.5;
/// Distance kept between the front bumper and the stop line when stopping [m].
const STOP_MARGIN: f64 = 0.5;
/// Acceleration assumed for a vehicle's own arrival and a foe's earliest arrival [m/s²].
const ACCEL_FAST: f64 = 1.5;
/// Acceleration assumed for a foe that drives through (its latest clearing) [m/s²].
const ACCEL_SLOW: f64 = 1.0;
/// Speed under which a vehicle is waiting [m/s] (SUMO's waiting-time threshold).
pub const WAITING_SPEED: f64 = 0.1;
/// A foe slower than this [m/s] that has not decided to go is waiting and will see us go.
const STANDING: f64 = 0.5;
/// Comfortable deceleration used to stop at a stop line [m/s²].
const STOP_DECEL: f64 = 3.0;
/// A route that leaves a junction and enters it again within this distance [m] passes it once.
const REJOIN: f64 = 20.0;
/// netconvert's `--junctions.limit-turn-speed` [m/s²]: the lateral acceleration of the
/// turnarounds we draw on a SUMO net where the file's shape is too tight to steer.
const NETCONVERT_TURN_ACCEL: f64 = 5.5;
/// Below this rate \[Hz\] of control or dynamics (SUMO's default step is 0.1 s) a vehicle
/// covers a tight turn in a step or two and cannot steer through it at the file's speed: at
/// sumo-rl's 1 s, a right turner took a 3 m turn at 12 m/s and landed 6 m wide, in the oncoming
/// lane.
const COARSE_HZ: f64 = 10.0;

/// The lateral acceleration [m/s²] of a SUMO net's links: the one set, else none (the file's lane
/// speeds) at SUMO's steps and netconvert's 5.5 m/s² at coarser ones (`coarse`).
fn sumo_turn_accel(set: f64, coarse: bool) -> f64 {
    if set > 0.0 {
        set
    } else if coarse {
        NETCONVERT_TURN_ACCEL
    } else {
        0.0
    }
}

/// No signal on a link.
pub const NO_SIGNAL: u8 = b'-';

/// `[junctions]` of a scenario: the junction rules' parameters.
#[derive(Resource, Debug, Clone, Copy, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct JunctionParams {
    /// Rule between equal approaches where the map says nothing: `"right_before_left"`
    /// (default) or `"first_come"`.
    pub default: Fallback,
    /// Time gap a vehicle keeps to a foe at a conflict point \[s\] (SUMO's `jmTimegapMinor`, 1 s).
    /// More: fewer vehicles take a gap, longer waits.
    pub time_gap: f64,
    /// Largest lateral acceleration on a junction's links [m/s²] (2 m/s², comfortable driving).
    pub lateral_accel: f64,
    /// The same on the links of a SUMO network (lanelets tagged `sumo:lane`) [m/s²]; 0 (the
    /// default): none at control and dynamics rates of 10 Hz or more (5.5 m/s² below, where a
    /// step is too long to steer through a tight turn at speed), a link is driven at its lane's
    /// `speed` from the file, as SUMO drives it
    /// (SUMO's car following knows no curvature: netconvert bakes the turn speed into the
    /// internal lane's `speed` when it builds the net, `--junctions.limit-turn-speed` 5.5 m/s²).
    /// sumo-rl's older nets give their internal lanes the road's 13.9 m/s on 3 m turns, and SUMO
    /// drives them so; any limit of ours cost their junctions capacity: on
    /// `2way-single-intersection` travel times were 1.7x SUMO's at 2 m/s², 1.53x at 5.5 and
    /// 0.97x with none (issue 54).
    pub sumo_lateral_accel: f64,
    /// A vehicle stops for yellow if it can at this deceleration [m/s²] (the 3 m/s²;
    /// SUMO uses the vehicle's `decel`).
    pub yellow_decel: f64,
    /// A vehicle stops for red if it can at this deceleration [m/s²].
    pub red_decel: f64,
    /// How far before a junction a vehicle starts to look at it \[m\].
    pub look_ahead: f64,
    /// Waiting time \[s\] over which the accepted gap shrinks from `time_gap` to 0 (0: never).
    pub impatience: f64,
}

impl Default for JunctionParams {
    fn default() -> Self {
        JunctionParams {
            default: Fallback::RightBeforeLeft,
            time_gap: 1.0,
            lateral_accel: 2.0,
            sumo_lateral_accel: 0.0,
            yellow_decel: 3.0,
            red_decel: 7.5,
            look_ahead: 80.0,
            impatience: 60.0,
        }
    }
}

impl JunctionParams {
    /// Check the values (keys relative to `[junctions]`).
    pub fn check(&self) -> Result<(), ParamError> {
        check_all([
            ("time_gap", self.time_gap, Range::non_negative(60.0)),
            ("lateral_accel", self.lateral_accel, Range::positive(20.0)),
            ("sumo_lateral_accel", self.sumo_lateral_accel, Range::non_negative(20.0)),
            ("yellow_decel", self.yellow_decel, Range::positive(20.0)),
            ("red_decel", self.red_decel, Range::positive(20.0)),
            ("look_ahead", self.look_ahead, Range::positive(1000.0)),
            ("impatience", self.impatience, Range::non_negative(3600.0)),
        ])
    }
}

/// Time \[s\] to cover `d` \[m\] from speed `v` [m/s] accelerating at `a` [m/s²] up to `v_max`
/// [m/s] (0 for `d <= 0`; a vehicle that cannot move never arrives).
pub fn time_to_cover(d: f64, v: f64, a: f64, v_max: f64) -> f64 {
    if d <= 0.0 {
        return 0.0;
    }
    let v = v.max(0.0);
    let v_max = v_max.max(v);
    if v_max <= 1e-6 {
        return f64::INFINITY;
    }
    if a <= 1e-9 || v >= v_max {
        return if v > 1e-6 { d / v } else { f64::INFINITY };
    }
    let t1 = (v_max - v) / a;
    let d1 = 0.5 * (v + v_max) * t1;
    if d <= d1 { ((v * v + 2.0 * a * d).sqrt() - v) / a } else { t1 + (d - d1) / v_max }
}

/// Gap acceptance: a vehicle that clears the conflict point at `t_clear` \[s\] from now may go
/// before a foe with priority that reaches it at `t_foe` \[s\] when `t_foe > t_clear + gap`.
pub fn accepts_gap(t_clear: f64, t_foe: f64, gap: f64) -> bool {
    t_foe > t_clear + gap
}

/// The gap a vehicle that has stood `waiting` \[s\] before a junction accepts in front of a foe
/// with priority \[s\]: [`JunctionParams::time_gap`], shrinking linearly to nothing over
/// [`JunctionParams::impatience`] s of waiting (SUMO's `impatience`: drivers who have waited long
/// take smaller gaps). The arrival estimates stay conservative (the foe accelerating, this vehicle
/// clearing the conflict area with its whole length), so a gap of 0 is still one it clears.
pub fn impatient_gap(params: &JunctionParams, waiting: f64) -> f64 {
    if params.impatience <= 0.0 {
        return params.time_gap;
    }
    params.time_gap * (1.0 - waiting / params.impatience).clamp(0.0, 1.0)
}

/// SUMO's yellow rule: stop when the stop line `distance` \[m\] ahead can be reached from speed
/// `v` [m/s] decelerating at no more than `max_decel` [m/s²]; else drive on.
pub fn stops_at_yellow(v: f64, distance: f64, max_decel: f64) -> bool {
    if distance <= 0.0 {
        return v <= 0.0;
    }
    v * v / (2.0 * distance) <= max_decel
}

/// The phase of a cyclic `program` at time `t` \[s\] with the cycle shifted by `offset` \[s\]
/// (SUMO's `offset`: the program is at its start at t = offset).
pub fn phase_at(program: &[SignalPhase], offset: f64, t: f64) -> usize {
    let cycle: f64 = program.iter().map(|p| p.duration).sum();
    if program.is_empty() || cycle <= 0.0 {
        return 0;
    }
    let mut into = (t - offset).rem_euclid(cycle);
    for (k, p) in program.iter().enumerate() {
        if into < p.duration {
            return k;
        }
        into -= p.duration;
    }
    program.len() - 1
}

/// One conflict seen from a link.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FoeConflict {
    /// The other link (global link index).
    pub foe: u32,
    /// Arc length of the meeting point on this link \[m\].
    pub s_mine: f64,
    /// Arc length of the meeting point on the foe's link \[m\].
    pub s_foe: f64,
    /// Crossing or merging.
    pub kind: ConflictKind,
    /// Whether this link yields (None: first come).
    pub yields: Option<bool>,
}

/// One link as the right-of-way system uses it.
#[derive(Debug, Clone, PartialEq)]
pub struct LinkInfo {
    /// Junction index (in [`Junctions::list`]).
    pub junction: u32,
    /// Its conflicts.
    pub conflicts: Vec<FoeConflict>,
    /// Highest speed for the lateral acceleration limit on it [m/s].
    pub curve_speed: f64,
    /// Its turn.
    pub turn: Turn,
}

/// The map's junctions indexed for the per-tick decisions.
#[derive(Resource, Debug, Clone)]
pub struct JunctionNetwork {
    /// The junctions.
    pub junctions: Arc<Junctions>,
    /// Every link of every junction, junction by junction (global link index).
    pub links: Vec<LinkInfo>,
    /// Global index of each junction's first link.
    pub first_link: Vec<u32>,
    /// Lanelet index -> global link index (`u32::MAX`: not a link).
    pub link_of_lanelet: Vec<u32>,
    /// Lanelet index -> whether it is the lanelet after some link (an exit).
    pub is_exit: Vec<bool>,
    /// Lanelet lengths \[m\], by lanelet index.
    pub lengths: Vec<f64>,
    /// Per junction, the longest time \[s\] a vehicle starting from its stop line may take to
    /// clear one of its curved links (at the link's curve speed, below `CROSSING_SPEED`, 10 m/s): a
    /// vehicle is seen as a foe from as far as it drives in that time, so a slow link (a U-turn
    /// round a junction) is decided on seeing every foe that can come while it is on it.
    pub crossing_time: Vec<f64>,
    /// The map.
    pub map: Arc<LaneletMap>,
}

/// Largest curvature [1/m] of a polyline, over chords of at least 2 m on each side.
fn max_curvature(points: &[glam::DVec2]) -> f64 {
    let mut best: f64 = 0.0;
    for k in 0..points.len() {
        let p = points[k];
        let Some(a) = points[..k].iter().rev().find(|q| q.distance(p) >= 2.0) else { continue };
        let Some(b) = points[k + 1..].iter().find(|q| q.distance(p) >= 2.0) else { continue };
        // Circumscribed circle of (a, p, b): κ = 4·area / (|ab| |ap| |pb|).
        let area2 = (p - *a).perp_dot(*b - *a).abs();
        let denom = a.distance(p) * p.distance(*b) * a.distance(*b);
        if denom > 1e-9 {
            best = best.max(2.0 * area2 / denom);
        }
    }
    best
}

impl JunctionNetwork {
    /// Index the junctions of `map` (O(links + conflicts + lanelets)); curve speeds at
    /// `lateral_accel` [m/s²], at `sumo_lateral_accel` on the links of a SUMO network (0: none).
    pub fn new(
        map: Arc<LaneletMap>,
        junctions: Arc<Junctions>,
        lateral_accel: f64,
        sumo_lateral_accel: f64,
    ) -> JunctionNetwork {
        let n = map.lanelets.len();
        let mut links = Vec::new();
        let mut first_link = Vec::with_capacity(junctions.list.len());
        let mut link_of_lanelet = vec![u32::MAX; n];
        for (j, junction) in junctions.list.iter().enumerate() {
            first_link.push(links.len() as u32);
            for l in &junction.links {
                let i = map.lanelet_index(l.lanelet).unwrap_or(usize::MAX);
                let lanelet = map.lanelets.get(i);
                let kappa = lanelet.map_or(0.0, |x| max_curvature(&x.centre));
                let sumo = lanelet.is_some_and(|x| x.tags.contains_key("sumo:lane"));
                // A turnaround we drew (a 46 m loop for the file's 2 m half circle) is our shape:
                // the file's speed is not for it, netconvert's turn limit is.
                let ours = lanelet.is_some_and(|x| crate::map::junctions::redrawn_turnaround(&x.tags));
                let a_lat = match (sumo, ours) {
                    (false, _) => lateral_accel,
                    (true, true) if sumo_lateral_accel <= 0.0 => NETCONVERT_TURN_ACCEL,
                    (true, _) => sumo_lateral_accel,
                };
                let mut curve_speed = if kappa > 1e-6 && a_lat > 0.0 { (a_lat / kappa).sqrt() } else { f64::INFINITY };
                // A SUMO link is driven at most at its internal lane's `speed` (netconvert's turn
                // speed), reached before the link as SUMO brakes for a slower lane ahead: left to
                // the path follower, a left turner entered a 9.26 m/s lane at 13.9 m/s.
                if sumo
                    && !ours
                    && let Some(v) = lanelet.and_then(|x| x.speed_limit())
                {
                    curve_speed = curve_speed.min(v);
                }
                if i < n {
                    link_of_lanelet[i] = links.len() as u32;
                }
                links.push(LinkInfo { junction: j as u32, conflicts: Vec::new(), curve_speed, turn: l.turn });
            }
        }
        for (j, junction) in junctions.list.iter().enumerate() {
            let base = first_link[j];
            for c in &junction.conflicts {
                let (Some(ka), Some(kb)) = (junction.link_index(c.a), junction.link_index(c.b)) else { continue };
                let (ga, gb) = (base + ka as u32, base + kb as u32);
                links[ga as usize].conflicts.push(FoeConflict {
                    foe: gb,
                    s_mine: c.s_a,
                    s_foe: c.s_b,
                    kind: c.kind,
                    yields: c.yields_from(c.a),
                });
                links[gb as usize].conflicts.push(FoeConflict {
                    foe: ga,
                    s_mine: c.s_b,
                    s_foe: c.s_a,
                    kind: c.kind,
                    yields: c.yields_from(c.b),
                });
            }
        }
        let mut is_exit = vec![false; n];
        for (i, l) in map.lanelets.iter().enumerate() {
            if link_of_lanelet[i] == u32::MAX {
                continue;
            }
            for s in &l.successors {
                if let Some(k) = map.lanelet_index(*s).filter(|&k| link_of_lanelet[k] == u32::MAX) {
                    is_exit[k] = true;
                }
            }
        }
        let lengths: Vec<f64> = map.lanelets.iter().map(|l| l.length).collect();
        let mut crossing_time = vec![0.0f64; junctions.list.len()];
        for (j, junction) in junctions.list.iter().enumerate() {
            for (k, l) in junction.links.iter().enumerate() {
                // Links driven at road speed are covered by the look-ahead as before.
                let curve_speed = links[first_link[j] as usize + k].curve_speed;
                if curve_speed >= CROSSING_SPEED {
                    continue;
                }
                let length = map.lanelet_index(l.lanelet).map_or(0.0, |i| lengths[i]);
                let speed = curve_speed.max(1.0);
                // A car's length and a conflict margin each side, from a standing start.
                let t = time_to_cover(length + 2.0 * CLEAR + 5.0, 0.0, ACCEL_FAST, speed);
                crossing_time[j] = crossing_time[j].max(t);
            }
        }
        JunctionNetwork { junctions, links, first_link, link_of_lanelet, is_exit, lengths, crossing_time, map }
    }
}

/// A junction's light: its program and what it shows.
#[derive(Debug, Clone, PartialEq)]
pub struct LightController {
    /// Junction index (in [`Junctions::list`]).
    pub junction: u32,
    /// The phases, cycled.
    pub program: Vec<SignalPhase>,
    /// Cycle shift \[s\].
    pub offset: f64,
    /// A state set from outside ([`TrafficLights::set_state`]), held until set again.
    pub manual: Option<String>,
    /// Index of the phase shown (in `program`; meaningless while `manual` holds).
    pub phase: usize,
}

/// Every traffic light and the state of every link (one character each, [`NO_SIGNAL`] where
/// none).
#[derive(Resource, Debug, Clone, Default)]
pub struct TrafficLights {
    /// The lights, in junction order.
    pub controllers: Vec<LightController>,
    /// Signal of every global link.
    pub state: Vec<u8>,
    /// Global index of each junction's first link (a copy of [`JunctionNetwork::first_link`]).
    pub first_link: Vec<u32>,
    /// Phase changes so far.
    pub changes: u64,
}

impl TrafficLights {
    /// Lights for `programs` (junction index, program, offset) over `links` links.
    pub fn new(programs: Vec<(u32, Vec<SignalPhase>, f64)>, network: &JunctionNetwork) -> TrafficLights {
        let mut lights = TrafficLights {
            controllers: programs
                .into_iter()
                .map(|(junction, program, offset)| LightController {
                    junction,
                    program,
                    offset,
                    manual: None,
                    phase: 0,
                })
                .collect(),
            state: vec![NO_SIGNAL; network.links.len()],
            first_link: network.first_link.clone(),
            changes: 0,
        };
        lights.advance(0.0);
        lights.changes = 0;
        lights
    }

    /// Show what every program shows at `t` \[s\].
    pub fn advance(&mut self, t: f64) {
        for c in &mut self.controllers {
            let text = match &c.manual {
                Some(m) => m.as_bytes(),
                None => {
                    let k = phase_at(&c.program, c.offset, t);
                    if k != c.phase {
                        self.changes += 1;
                    }
                    c.phase = k;
                    match c.program.get(k) {
                        Some(p) => p.state.as_bytes(),
                        None => continue,
                    }
                }
            };
            let first = self.first_link[c.junction as usize] as usize;
            for (k, ch) in text.iter().enumerate() {
                if let Some(s) = self.state.get_mut(first + k) {
                    *s = *ch;
                }
            }
        }
    }

    /// The state a junction shows (one character per link), if it has a light.
    pub fn state_of(&self, junction: u32) -> Option<String> {
        let c = self.controllers.iter().find(|c| c.junction == junction)?;
        let first = self.first_link[c.junction as usize] as usize;
        let n = c.program.first().map_or(0, |p| p.state.len());
        Some(String::from_utf8_lossy(&self.state[first..first + n]).into_owned())
    }

    /// Hold `state` at the junction with index `junction` from now on (Python's
    /// `Sim.set_phase`); an error names what is wrong.
    pub fn set_state(&mut self, junction: u32, state: &str) -> Result<(), String> {
        let c = self
            .controllers
            .iter_mut()
            .find(|c| c.junction == junction)
            .ok_or_else(|| format!("junction {} has no traffic light", junction + 1))?;
        let n = c.program.first().map_or(0, |p| p.state.len());
        check_state(state, n)?;
        c.manual = Some(state.to_string());
        let first = self.first_link[junction as usize] as usize;
        for (k, ch) in state.bytes().enumerate() {
            self.state[first + k] = ch;
        }
        self.changes += 1;
        Ok(())
    }
}

/// Whether `state` is a valid signal state for `links` links; the error says why not. Signal
/// characters: `G` green with priority, `g` green yielding, `y` yellow, `r` red, and SUMO's `s`
/// (treated as red: stop), `o` (off, blinking: yield as `g`), `O` (off: as `G`).
pub fn check_state(state: &str, links: usize) -> Result<(), String> {
    if state.chars().count() != links {
        return Err(format!(
            "`{state}` has {} characters; the junction has {links} links (one character each)",
            state.chars().count()
        ));
    }
    if let Some(c) = state.chars().find(|c| !"GgyrsoO".contains(*c)) {
        return Err(format!("`{state}` has `{c}`; use G (green, priority), g (green, yield), y (yellow), r (red)"));
    }
    Ok(())
}

/// One passage of a route through a junction: consecutive links of one junction.
#[derive(Debug, Clone, PartialEq)]
pub struct Passage {
    /// Junction index.
    pub junction: u32,
    /// Route arc length of the stop line (the first link's start) \[m\].
    pub entry: f64,
    /// Route arc length of the last link's end \[m\].
    pub exit: f64,
    /// Global link indices with the route arc length of each link's start \[m\].
    pub links: Vec<(u32, f64)>,
    /// Lanelet index after the passage (`u32::MAX`: the route ends in the junction).
    pub exit_lanelet: u32,
    /// Lanelet index before it on the route (`u32::MAX`: the route starts in the junction).
    pub entry_lanelet: u32,
}

/// The junctions on `path`, in order (a closed loop: its first lap).
pub fn passages(path: &Path, map: &LaneletMap, network: &JunctionNetwork) -> Vec<Passage> {
    let Some(first) = path.lanelets.first().and_then(|id| map.lanelet_index(*id)) else { return Vec::new() };
    let start = path.points.first().copied().unwrap_or_default();
    let (along, _) = crate::map::polyline::project_polyline(&map.lanelets[first].centre, start);
    let mut s = -along;
    let mut out: Vec<Passage> = Vec::new();
    let mut before = u32::MAX;
    for (k, id) in path.lanelets.iter().enumerate() {
        let Some(i) = map.lanelet_index(*id) else { break };
        let len = network.lengths[i];
        let g = network.link_of_lanelet[i];
        if g != u32::MAX {
            let j = network.links[g as usize].junction;
            match out.last_mut() {
                // The same junction again within a few metres (Lanelet2 junctions drawn as
                // several groups with short lanelets between): one passage, decided once at its
                // first stop line.
                Some(p) if p.junction == j && s - p.exit < REJOIN => {
                    p.links.push((g, s));
                    p.exit = s + len;
                    p.exit_lanelet = u32::MAX;
                }
                _ => out.push(Passage {
                    junction: j,
                    entry: s,
                    exit: s + len,
                    links: vec![(g, s)],
                    exit_lanelet: u32::MAX,
                    entry_lanelet: before,
                }),
            }
        } else if let Some(p) = out.last_mut().filter(|p| p.exit_lanelet == u32::MAX && k > 0) {
            p.exit_lanelet = i as u32;
        }
        before = if g == u32::MAX { i as u32 } else { u32::MAX };
        s += len;
    }
    out
}

/// Per-vehicle state of the junction rules.
#[derive(Component, Debug, Clone, PartialEq, Default)]
pub struct JunctionDriver {
    /// The route the passages were found on (its address).
    route: usize,
    /// Its junctions.
    passages: Vec<Passage>,
    /// Index of the next (or current) passage.
    next: usize,
    /// Whether it has decided to drive through the next junction.
    pub going: bool,
    /// When it came near the next junction [s] (first come, first served).
    arrived_at: f64,
    /// Whether it has stopped at the stop line (all-way stops).
    stopped: bool,
    /// Waiting time at the next junction so far \[s\].
    pub waited: f64,
    /// Waiting time of the current stop so far \[s\].
    pub waiting_now: f64,
    /// Set while a V2V negotiation of the vehicle's own decides its passage (the GCDC 2016
    /// intersection's, `vehicles::gcdc_intersection`, writes it each control tick): the
    /// junction rules then treat it as a foe only.
    pub own_negotiation: bool,
    /// What the far-from-junctions test reads, kept beside the passages (on the heap, one cache
    /// miss a vehicle, for most vehicles of a town nothing else): the next passage's stop line
    /// \[m\] (infinite without one; `NaN` until first set, so the test fails), its junction, and
    /// the furthest exit of the passages it may still be inside \[m\].
    far: FarTest,
}

/// See [`JunctionDriver::far`].
#[derive(Debug, Clone, Copy, PartialEq)]
struct FarTest {
    next_entry: f64,
    next_junction: u32,
    inside_exit: f64,
}

impl Default for FarTest {
    fn default() -> FarTest {
        FarTest { next_entry: f64::NAN, next_junction: 0, inside_exit: f64::INFINITY }
    }
}

impl JunctionDriver {
    /// Set [`JunctionDriver::far`] from the passages.
    fn refresh_far(&mut self) {
        let inside_from = self.next.saturating_sub(2);
        let inside_exit = self.passages[inside_from..self.next].iter().fold(f64::NEG_INFINITY, |m, p| m.max(p.exit));
        self.far = match self.passages.get(self.next) {
            Some(p) => FarTest { next_entry: p.entry, next_junction: p.junction, inside_exit },
            None => FarTest { next_entry: f64::INFINITY, next_junction: 0, inside_exit },
        };
    }
}

/// What happened at each junction (`metrics.junctions`).
#[derive(Resource, Debug, Clone, Default)]
pub struct JunctionStats {
    /// Per junction (index): vehicles through, sum of their waits \[s\], longest wait \[s\], most
    /// vehicles waiting at once.
    pub per_junction: Vec<JunctionCounts>,
    /// Vehicles that passed a stop line while it showed red (should stay 0).
    pub red_crossings: u64,
}

/// One junction in `metrics.junctions` of `summary.json`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct JunctionMetric {
    /// Junction id (as `map info` lists it).
    pub id: u32,
    /// Vehicles that drove through it.
    pub vehicles_through: u64,
    /// Mean waiting time (speed under 0.1 m/s) before it of the vehicles through \[s\].
    pub mean_wait_s: f64,
    /// Longest waiting time of one vehicle before it \[s\].
    pub max_wait_s: f64,
    /// Most vehicles waiting before it at once.
    pub max_queue: u32,
}

/// A time rounded to the centisecond (the precision of the control ticks that measure it).
fn cs(t: f64) -> f64 {
    (t * 100.0).round() / 100.0
}

impl JunctionStats {
    /// `metrics.junctions`: every junction a vehicle came to, in id order.
    pub fn summary(&self) -> Vec<JunctionMetric> {
        self.per_junction
            .iter()
            .enumerate()
            .filter(|(_, c)| c.through > 0 || c.max_queue > 0)
            .map(|(j, c)| JunctionMetric {
                id: j as u32 + 1,
                vehicles_through: c.through,
                mean_wait_s: cs(if c.through > 0 { c.wait_sum / c.through as f64 } else { 0.0 }),
                max_wait_s: cs(c.wait_max),
                max_queue: c.max_queue,
            })
            .collect()
    }
}

/// Counts of one junction.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct JunctionCounts {
    /// Vehicles that drove through.
    pub through: u64,
    /// Sum of their waiting times \[s\].
    pub wait_sum: f64,
    /// Longest waiting time of one vehicle \[s\].
    pub wait_max: f64,
    /// Most vehicles waiting before it at once.
    pub max_queue: u32,
}

/// One vehicle near a junction this tick.
#[derive(Debug, Clone, Copy)]
struct Approach {
    entity: Entity,
    id: VehicleId,
    front: f64,
    length: f64,
    speed: f64,
    v_max: f64,
    inside: bool,
    going: bool,
    decides: bool,
    arrived_at: f64,
    stopped: bool,
    junction: u32,
    /// Range of its links in the shared buffer.
    links: (u32, u32),
    exit: u32,
    entry: f64,
    limit: f64,
    /// Lanelet it comes from (the one before the junction).
    entry_lanelet: u32,
    /// Behind another vehicle before the stop line of the same lanelet: it obeys signals and
    /// keeps clear but does not take gaps or hold the right to go (the one in front decides).
    queued: bool,
    /// A junction it has entered (one of up to two besides the one it decides on next).
    trailing: bool,
    /// How long it has stood before this junction without a break [s] (impatience).
    waiting_now: f64,
    /// The first vehicle before the stop line of its lanelet (itself when not queued).
    head: u32,
    /// Its leader stands before the stop line (a vehicle waiting there to change lanes, which
    /// approaches no junction link): it cannot come however it decides.
    blocked: bool,
}

/// Per-tick buffers of [`give_way_at_junctions`], kept between ticks.
#[derive(Default)]
pub struct Scratch {
    approaches: Vec<Approach>,
    links: Vec<(u32, f64)>,
    /// Approaches on each link: `link_list[link_first[g]..link_first[g + 1]]` for link `g`, in
    /// the order they were registered (one flat table, built after the gathering: a list per link
    /// was a cache miss a registration).
    link_first: Vec<u32>,
    link_list: Vec<u32>,
    exit_rear: Vec<(f64, f64)>,
    exit_touched: Vec<u32>,
    /// See [`Tables::reserved`].
    reserved: Vec<AtomicU64>,
    /// The approaches of junction `j` are `approaches[junction_first[j]..junction_first[j + 1]]`
    /// ([`Scratch::group_by_junction`]).
    junction_first: Vec<u32>,
    /// Buffer of [`Scratch::group_by_junction`].
    grouped: Vec<Approach>,
    /// Each chunk's finds (see [`Gathered`]).
    gathered: Vec<Gathered>,
    /// Each chunk's order of decisions (see [`decide_junction`]).
    orders: Vec<Vec<u32>>,
}

/// What the decisions at every junction read: the approaches' links, the approaches on each
/// link, the exits' last vehicles, and the room already promised on each exit.
struct Tables<'a> {
    links: &'a [(u32, f64)],
    link_first: &'a [u32],
    link_list: &'a [u32],
    exit_rear: &'a [(f64, f64)],
    /// Room [m] the vehicles that decided to go this tick hold on each exit lanelet (the bits
    /// of an `f64`). An exit follows one junction only, and one thread decides a junction, so
    /// every exit has one writer and the sums are the same at any thread count.
    reserved: &'a [AtomicU64],
}

impl Tables<'_> {
    /// Route arc length [m] where approach `a`'s link `g` starts, if `g` is one of its links.
    fn link_start(&self, a: &Approach, g: u32) -> Option<f64> {
        self.links[a.links.0 as usize..a.links.1 as usize].iter().find(|(x, _)| *x == g).map(|&(_, s)| s)
    }

    /// The approaches on link `g` (see [`Scratch::index_links`]).
    fn on_link(&self, g: u32) -> &[u32] {
        let g = g as usize;
        &self.link_list[self.link_first[g] as usize..self.link_first[g + 1] as usize]
    }

    /// Room already held on exit lanelet `exit` \[m\].
    fn reserved(&self, exit: u32) -> f64 {
        f64::from_bits(self.reserved[exit as usize].load(Ordering::Relaxed))
    }

    /// Hold `room` \[m\] more on exit lanelet `exit`.
    fn reserve(&self, exit: u32, room: f64) {
        let slot = &self.reserved[exit as usize];
        slot.store((f64::from_bits(slot.load(Ordering::Relaxed)) + room).to_bits(), Ordering::Relaxed);
    }
}

/// One junction's approaches while they are decided on: approach `q` (a global index, as the
/// tables name it) is `approaches[q - base]`.
struct Board<'a> {
    base: u32,
    approaches: &'a mut [Approach],
    t: &'a Tables<'a>,
}

impl Board<'_> {
    /// Approach `q`, if it is one of this junction's (every foe on a link of the junction is).
    fn at(&self, q: u32) -> Option<&Approach> {
        self.approaches.get(q.wrapping_sub(self.base) as usize)
    }
}

impl Scratch {
    /// Forget the last tick's exits (`n_exits` lanelets): the last vehicle on each and the
    /// room promised on each, then its approaches. Room is promised only by approaches, on
    /// their exits, so those are the exits to reset, a vehicle on them or not (when only exits
    /// with a vehicle were reset, an empty exit kept its sum tick after tick, and the first slow
    /// vehicle to come onto it met that stale promise: every approach to it held back a tick).
    fn begin_tick(&mut self, n_exits: usize) {
        if self.exit_rear.len() != n_exits {
            self.exit_rear = vec![(f64::INFINITY, 0.0); n_exits];
            self.reserved = (0..n_exits).map(|_| AtomicU64::new(0.0f64.to_bits())).collect();
            self.exit_touched.clear();
        }
        for i in self.exit_touched.drain(..) {
            self.exit_rear[i as usize] = (f64::INFINITY, 0.0);
        }
        for a in &self.approaches {
            if let Some(slot) = self.reserved.get_mut(a.exit as usize) {
                *slot.get_mut() = 0.0f64.to_bits();
            }
        }
        self.approaches.clear();
    }

    /// Order the approaches by junction (keeping their order within each), so each junction's
    /// are one slice ([`Scratch::junction_first`]); each is its own head again.
    fn group_by_junction(&mut self, n_junctions: usize) {
        bucket_starts(&mut self.junction_first, n_junctions, self.approaches.iter().map(|a| a.junction));
        self.grouped.clear();
        self.grouped.extend_from_slice(&self.approaches);
        for a in &self.approaches {
            let slot = &mut self.junction_first[a.junction as usize + 1];
            self.grouped[*slot as usize] = Approach { head: *slot, ..*a };
            *slot += 1;
        }
        self.junction_first.truncate(n_junctions + 1);
        std::mem::swap(&mut self.approaches, &mut self.grouped);
    }

    /// Build the table of approaches by link from their links (a counting sort: O(approaches +
    /// links)); `n_links` links in all.
    fn index_links(&mut self, n_links: usize) {
        bucket_starts(&mut self.link_first, n_links, self.links.iter().map(|&(g, _)| g));
        self.link_list.clear();
        self.link_list.resize(self.links.len(), 0);
        for (k, a) in self.approaches.iter().enumerate() {
            for &(g, _) in &self.links[a.links.0 as usize..a.links.1 as usize] {
                let slot = &mut self.link_first[g as usize + 1];
                self.link_list[*slot as usize] = k as u32;
                *slot += 1;
            }
        }
        self.link_first.truncate(n_links + 1);
    }

    /// Append every chunk's finds ([`Scratch::gathered`]) in order: approaches and links,
    /// waiting vehicles to `queue_at`, passages entered to `stats`.
    fn take_gathered(&mut self, stats: &mut JunctionStats, queue_at: &mut Vec<(u32, u32)>) {
        for g in &self.gathered {
            let l0 = self.links.len() as u32;
            self.links.extend_from_slice(&g.links);
            self.approaches
                .extend(g.approaches.iter().map(|a| Approach { links: (a.links.0 + l0, a.links.1 + l0), ..*a }));
            queue_at.extend(g.queued_at.iter().map(|&j| (j, 1)));
            for &(j, waited, red) in &g.entered {
                stats.red_crossings += u64::from(red);
                let c = &mut stats.per_junction[j as usize];
                c.through += 1;
                c.wait_sum += waited;
                c.wait_max = c.wait_max.max(waited);
            }
        }
    }
}

/// The first step of a counting sort of `keys` (each below `n`) into `first`: `first[key + 1]`
/// is where key's items start once sorted, so that filling each item at `first[key + 1]` (then
/// one on) leaves `first[key]..first[key + 1]` as key's range; the caller truncates `first` to
/// `n + 1` after filling.
fn bucket_starts(first: &mut Vec<u32>, n: usize, keys: impl Iterator<Item = u32>) {
    first.clear();
    first.resize(n + 2, 0);
    for key in keys {
        first[key as usize + 2] += 1;
    }
    for k in 2..first.len() {
        first[k] += first[k - 1];
    }
}

/// One chunk's finds of the gathering in [`give_way_at_junctions`], in the vehicles' order.
#[derive(Default)]
struct Gathered {
    approaches: Vec<Approach>,
    links: Vec<(u32, f64)>,
    /// The junction each waiting vehicle waits at.
    queued_at: Vec<u32>,
    /// Passages entered: junction, the vehicle's wait there \[s\], whether on red.
    entered: Vec<(u32, f64, bool)>,
}

impl Gathered {
    fn clear(&mut self) {
        self.approaches.clear();
        self.links.clear();
        self.queued_at.clear();
        self.entered.clear();
    }

    /// Add `a` near passage `p`: its links go to the shared buffer ([`Scratch::index_links`]
    /// lists it on each).
    fn register(&mut self, p: &Passage, a: Approach) {
        let start = self.links.len() as u32;
        self.links.extend_from_slice(&p.links);
        // Its head is set once the approaches are grouped ([`Scratch::group_by_junction`]).
        self.approaches.push(Approach {
            junction: p.junction,
            links: (start, self.links.len() as u32),
            exit: p.exit_lanelet,
            entry: p.entry,
            entry_lanelet: p.entry_lanelet,
            ..a
        });
    }
}

/// Give every vehicle without junction state one (the next tick uses it).
#[allow(clippy::type_complexity)]
pub fn attach_junction_drivers(
    mut commands: Commands,
    new: Query<Entity, (With<Longitudinal>, With<Route>, With<PathFollower>, Without<JunctionDriver>)>,
) {
    for e in &new {
        commands.entity(e).insert(JunctionDriver::default());
    }
}

/// Show what every light's program shows now.
pub fn advance_traffic_lights(clock: Res<SimClock>, mut lights: ResMut<TrafficLights>) {
    lights.advance(clock.now.as_secs());
}

/// Decide, for every vehicle near a junction, whether it may drive through, and limit its
/// acceleration to stop at the stop line when not (see the module documentation).
#[allow(clippy::type_complexity, clippy::too_many_arguments)]
pub fn give_way_at_junctions(
    clock: Res<SimClock>,
    params: Res<JunctionParams>,
    network: Res<JunctionNetwork>,
    lights: Option<Res<TrafficLights>>,
    mut stats: ResMut<JunctionStats>,
    mut vehicles: Query<(
        Entity,
        &VehicleId,
        &VehicleState,
        &VehicleSize,
        &Route,
        &PathFollower,
        &mut Longitudinal,
        &mut JunctionDriver,
        Option<&CrossingNegotiator>,
    )>,
    positions: Query<(&super::LanePosition, &VehicleSize, &VehicleState)>,
    parallelism: Option<Res<Parallelism>>,
    mut scratch: Local<Scratch>,
) {
    let now = clock.now.as_secs();
    let dt = clock.dt;
    let net = &*network;
    let sc = &mut *scratch;
    let n_links = net.links.len();
    sc.begin_tick(net.is_exit.len());
    if stats.per_junction.len() != net.junctions.list.len() {
        stats.per_junction = vec![JunctionCounts::default(); net.junctions.list.len()];
    }
    sc.links.clear();
    // Where the rear of the last vehicle on every exit lanelet is, and how fast it goes.
    for (pos, size, state) in &positions {
        let i = pos.index as usize;
        if net.is_exit.get(i).copied().unwrap_or(false) {
            let rear = pos.s - 0.5 * size.length;
            let slot = &mut sc.exit_rear[i];
            if slot.0 == f64::INFINITY {
                sc.exit_touched.push(i as u32);
            }
            if rear < slot.0 {
                *slot = (rear, state.speed());
            }
        }
    }
    // Who is near a junction: each vehicle on its own, split over the threads (the table's
    // order kept: chunk k's finds come k-th), then the finds in order.
    let cx = GatherContext { net, params: &params, lights: lights.as_deref(), now, dt };
    let parallelism = parallelism.as_deref().copied().unwrap_or_else(Parallelism::single);
    let mut queue_at: Vec<(u32, u32)> = Vec::new();
    if let Ok(tables) = vehicles.contiguous_iter_mut() {
        for (entities, ids, states, sizes, routes, followers, lons, mut drivers, negotiators) in tables {
            for g in &mut sc.gathered {
                g.clear();
            }
            let lons: &[Longitudinal] = &lons;
            parallelism.for_each_chunk_at(&mut drivers, &mut sc.gathered, |start, chunk, out| {
                for k in 0..chunk.len() {
                    // The next passage of a vehicle a few places on, on the heap (each
                    // vehicle's own), then its links, one step nearer.
                    if let Some(d) = chunk.get(k + 2 * PREFETCH_AHEAD)
                        && let Some(p) = d.passages.get(d.next)
                    {
                        crate::world::prefetch_value(p);
                    }
                    if let Some(d) = chunk.get(k + PREFETCH_AHEAD)
                        && let Some(p) = d.passages.get(d.next)
                    {
                        crate::world::prefetch_all(&p.links);
                    }
                    let i = start + k;
                    let vehicle = Vehicle {
                        entity: entities[i],
                        id: ids[i],
                        state: &states[i],
                        size: &sizes[i],
                        route: &routes[i],
                        follower: &followers[i],
                        lon: &lons[i],
                        negotiated: negotiators.is_some_and(|n| n.get(i).is_some()),
                    };
                    gather_one(&cx, out, vehicle, &mut chunk[k]);
                }
            });
            sc.take_gathered(&mut stats, &mut queue_at);
        }
    } else {
        // Only if a component were stored sparsely (none is): one at a time.
        for g in &mut sc.gathered {
            g.clear();
        }
        if sc.gathered.is_empty() {
            sc.gathered.push(Gathered::default());
        }
        for (entity, &id, state, size, route, follower, lon, mut driver, negotiator) in &mut vehicles {
            let vehicle =
                Vehicle { entity, id, state, size, route, follower, lon: &lon, negotiated: negotiator.is_some() };
            gather_one(&cx, &mut sc.gathered[0], vehicle, &mut driver);
        }
        sc.take_gathered(&mut stats, &mut queue_at);
    }
    sc.group_by_junction(net.junctions.list.len());
    sc.index_links(n_links);
    // Most vehicles waiting at once before each junction.
    queue_at.sort_unstable();
    let mut k = 0;
    while k < queue_at.len() {
        let j = queue_at[k].0;
        let n = queue_at[k..].iter().take_while(|q| q.0 == j).count();
        let c = &mut stats.per_junction[j as usize];
        c.max_queue = c.max_queue.max(n as u32);
        k += n;
    }
    // Each junction decides on its own (its approaches, its links, its exits), so the junctions
    // are shared out over the threads; within one, decisions follow a fixed order.
    let Scratch { approaches, links, link_first, link_list, exit_rear, reserved, junction_first, orders, .. } = sc;
    let tables = Tables { links, link_first, link_list, exit_rear, reserved };
    let mut boards: Vec<Board> = Vec::new();
    let mut rest: &mut [Approach] = approaches;
    for j in 0..junction_first.len().saturating_sub(1) {
        let (from, to) = (junction_first[j], junction_first[j + 1]);
        let (mine, others) = std::mem::take(&mut rest).split_at_mut((to - from) as usize);
        rest = others;
        if !mine.is_empty() {
            boards.push(Board { base: from, approaches: mine, t: &tables });
        }
    }
    let signal = |g: u32| cx.signal(g);
    // Split as the vehicles would be (a junction's decisions cost about its approaches').
    let split = parallelism.for_share_of(tables.link_list.len());
    split.for_each_chunk(&mut boards, orders, |chunk, order| {
        for board in chunk {
            decide_junction(board, order, net, &params, &signal, dt);
        }
    });
    // Write back.
    for a in &sc.approaches {
        let Ok((.., mut lon, mut driver, _)) = vehicles.get_mut(a.entity) else { continue };
        if !a.trailing {
            driver.going = a.going;
        }
        if a.limit.is_finite() {
            lon.limit(a.limit);
        }
    }
}

/// What [`gather_one`] reads of one vehicle.
struct Vehicle<'a> {
    entity: Entity,
    id: VehicleId,
    state: &'a VehicleState,
    size: &'a VehicleSize,
    route: &'a Route,
    follower: &'a PathFollower,
    lon: &'a Longitudinal,
    /// It carries a [`CrossingNegotiator`] (the V2V negotiation decides for it).
    negotiated: bool,
}

/// What every vehicle's gathering shares.
struct GatherContext<'a> {
    net: &'a JunctionNetwork,
    params: &'a JunctionParams,
    lights: Option<&'a TrafficLights>,
    now: f64,
    dt: f64,
}

impl GatherContext<'_> {
    /// What link `g`'s signal shows.
    fn signal(&self, g: u32) -> u8 {
        self.lights.map_or(NO_SIGNAL, |l| l.state[g as usize])
    }
}

/// Bring `driver`'s passages up to date with where `v` is, and add to `out` what
/// [`give_way_at_junctions`] must know of it: an approach for each passage it is inside or
/// near, the junction it waits at, the passages it entered this tick.
fn gather_one(cx: &GatherContext, out: &mut Gathered, v: Vehicle, driver: &mut JunctionDriver) {
    let GatherContext { net, params, now, dt, .. } = *cx;
    let Vehicle { entity, id, state, size, route, follower, lon, negotiated } = v;
    let key = Arc::as_ptr(&route.0) as usize;
    let front = follower.s + 0.5 * size.length;
    if driver.route != key {
        // A new route (a lane change begun or given up, a new trip) starts with the passages
        // whose stop lines the front has not reached: those it is past were crossed (and
        // counted) on the route before, or never stood before it. Walked from the first, they
        // were each "entered" again where the switch happened, and one the light now showed
        // red counted as a red light crossed (93 in 2,400 s of issue 54's 20x20 grid, all
        // false: a change given up puts the vehicle back on a route it had driven for km).
        let passages = passages(&route.0, &net.map, net);
        let next = passages.partition_point(|p| p.entry <= front);
        *driver = JunctionDriver { route: key, passages, next, ..JunctionDriver::default() };
    }
    let rear = follower.s - 0.5 * size.length;
    let speed = state.speed();
    // Far from its junctions (no stop line reached, inside none, the next one beyond its
    // look-ahead): the same as the walk below finding nothing, without reading the passages.
    let far = driver.far;
    if front < far.next_entry && rear >= far.inside_exit {
        let time = net.crossing_time.get(far.next_junction as usize).copied().unwrap_or(0.0) + params.time_gap;
        if far.next_entry - front > params.look_ahead.max(speed * time) {
            return;
        }
    }
    // Passages the front has entered: decided; the next one is decided on from before its
    // stop line even while the vehicle is still inside the one before (junctions back to back).
    while let Some(p) = driver.passages.get(driver.next) {
        if front < p.entry {
            break;
        }
        let red = !driver.going && cx.signal(p.links[0].0) == b'r';
        if red {
            // Told to stop and could not: passed the stop line on red.
            tracing::debug!(target: "junctions", "{id} passed a red stop line at {now:.2} s (junction {}, {speed:.1} m/s)", p.junction + 1);
        }
        out.entered.push((p.junction, driver.waited, red));
        let next = driver.next + 1;
        *driver = JunctionDriver {
            route: key,
            passages: std::mem::take(&mut driver.passages),
            next,
            ..JunctionDriver::default()
        };
    }
    driver.refresh_far();
    // The passages it is in: there as a foe that others must let clear (at most the last two).
    let inside_from = driver.next.saturating_sub(2);
    let seen = Approach {
        entity,
        id,
        front,
        length: size.length,
        speed,
        v_max: follower.params.speed.max(speed),
        inside: true,
        going: true,
        decides: !negotiated && !driver.own_negotiation,
        arrived_at: f64::INFINITY,
        stopped: false,
        junction: 0,
        links: (0, 0),
        exit: u32::MAX,
        entry: 0.0,
        limit: f64::INFINITY,
        entry_lanelet: u32::MAX,
        queued: false,
        trailing: true,
        waiting_now: 0.0,
        head: 0,
        blocked: false,
    };
    for p in driver.passages[inside_from..driver.next].iter().filter(|p| rear < p.exit) {
        out.register(p, seen);
    }
    let Some(p) = driver.passages.get(driver.next) else { return };
    let time = net.crossing_time.get(p.junction as usize).copied().unwrap_or(0.0) + params.time_gap;
    if p.entry - front > params.look_ahead.max(speed * time) {
        return;
    }
    if speed < WAITING_SPEED {
        driver.waited += dt;
        driver.waiting_now += dt;
        out.queued_at.push(p.junction);
        if p.entry - front < 3.0 {
            driver.stopped = true;
        }
    } else {
        driver.waiting_now = 0.0;
    }
    if driver.arrived_at == 0.0 && p.entry - front < 20.0 {
        driver.arrived_at = now.max(1e-9);
    }
    let arrived_at = if driver.arrived_at > 0.0 { driver.arrived_at } else { f64::INFINITY };
    let (going, stopped, waiting_now) = (driver.going, driver.stopped, driver.waiting_now);
    let blocked = lon.leader.is_some_and(|l| l.speed < STANDING && l.gap < p.entry - front);
    let approach =
        Approach { inside: false, going, arrived_at, stopped, trailing: false, waiting_now, blocked, ..seen };
    out.register(p, approach);
}

/// Decide for every approach of one junction: only the first vehicle before the stop line of
/// each lanelet decides on the conflicts (the others are queued behind it); then, in a fixed
/// order (inside first, then nearest to its stop line, then id), each approach ([`decide`]).
fn decide_junction(
    b: &mut Board,
    order: &mut Vec<u32>,
    net: &JunctionNetwork,
    params: &JunctionParams,
    signal: &(dyn Fn(u32) -> u8 + Sync),
    dt: f64,
) {
    order.clear();
    order.extend((0..b.approaches.len() as u32).filter(|&k| {
        let a = &b.approaches[k as usize];
        !a.inside && a.entry_lanelet != u32::MAX
    }));
    let approaches = &*b.approaches;
    order.sort_by(|&a, &b| {
        let (x, y) = (&approaches[a as usize], &approaches[b as usize]);
        x.entry_lanelet
            .cmp(&y.entry_lanelet)
            .then((x.entry - x.front).total_cmp(&(y.entry - y.front)))
            .then(x.id.cmp(&y.id))
    });
    for w in 1..order.len() {
        let (prev, k) = (order[w - 1] as usize, order[w] as usize);
        if b.approaches[prev].entry_lanelet == b.approaches[k].entry_lanelet {
            let head = b.approaches[prev].head;
            let a = &mut b.approaches[k];
            a.queued = true;
            a.going = false;
            a.head = head;
        }
    }
    order.clear();
    order.extend(0..b.approaches.len() as u32);
    let approaches = &*b.approaches;
    order.sort_by(|&a, &b| {
        let (x, y) = (&approaches[a as usize], &approaches[b as usize]);
        (!x.inside).cmp(&!y.inside).then((x.entry - x.front).total_cmp(&(y.entry - y.front))).then(x.id.cmp(&y.id))
    });
    for &me in order.iter() {
        decide(me as usize, b, net, params, signal, dt);
    }
}

/// Decide for approach `me` (see [`give_way_at_junctions`]); sets its `going` and `limit`, and
/// reserves room on its exit.
///
/// Whether it can still stop, and the braking that stops it, count in control steps of `dt`
/// \[s\] ([`can_stop_within`], [`stop_within_step`]: the speed asked for is held over the step):
/// at a coarse step (a signal env at SUMO's 1 s) the continuous laws alone carried vehicles past
/// the stop line on red, and one standing within the stop margin of it counted as unable to stop.
fn decide(
    me: usize,
    b: &mut Board,
    net: &JunctionNetwork,
    params: &JunctionParams,
    signal: &dyn Fn(u32) -> u8,
    dt: f64,
) {
    let a = b.approaches[me];
    let links = &b.t.links[a.links.0 as usize..a.links.1 as usize];
    let v = a.speed.max(0.0);
    let mut limit = f64::INFINITY;
    // Curves: reach each link at its curve speed, hold it on the link. A link this step's travel
    // reaches counts as reached, and on it the speed asked for never exceeds the curve speed nor
    // turns back more than a step's worth: at a coarse step (SUMO's 1 s) the continuous gain
    // (1 / 0.5 s) overshot both ways, 2.4 -> 5.2 -> 2.4 m/s through a 3.8 m/s left turn.
    let mut v_through = a.v_max;
    for &(g, start) in links {
        let vc = net.links[g as usize].curve_speed;
        v_through = v_through.min(vc);
        let d = start - a.front;
        if d <= 0.5f64.max(v.max(vc) * dt) {
            limit = limit.min(if v > vc { (vc - v) / 0.5f64.max(dt) } else { (vc - v) / dt.max(1e-6) });
        } else if v > vc {
            limit = limit.min((vc * vc - v * v) / (2.0 * d));
        }
    }
    let v_through = v_through.max(1.0);
    let stop_room = a.entry - a.front - STOP_MARGIN;
    let can_stop = |decel: f64| can_stop_within(v, stop_room, decel, dt);
    // The hardest braking asked for to stop at the line (beyond it, drive on).
    let hard = params.red_decel.max(STOP_DECEL * 2.0);
    let mut go = true;
    if !a.inside && a.decides {
        let first = links[0].0;
        match signal(first) {
            b'r' | b's' => go = !can_stop(params.red_decel),
            b'y' => go = !can_stop(params.yellow_decel),
            _ => {}
        }
        tracing::trace!(target: "junctions", "{} signal {} at {stop_room:.1} m, {v:.1} m/s, queued {}, go {go}", a.id, signal(first) as char, a.queued);
        let control = net.junctions.list[a.junction as usize].control;
        if go && control == JunctionControl::AllWayStop && !a.stopped && !a.queued {
            go = false;
        }
        // Keep clear: room on the lanelet after the junction.
        if go && a.exit != u32::MAX {
            let (rear, speed) = b.t.exit_rear[a.exit as usize];
            let reserved = b.t.reserved(a.exit);
            let room = if rear.is_finite() && speed < 3.0 { rear } else { f64::INFINITY };
            if room - reserved < a.length + 1.0 {
                tracing::trace!(target: "junctions", "{} keeps clear: room {room:.1} m, reserved {reserved:.1} m", a.id);
                go = false;
            }
        }
        // Behind the vehicle that decides for its lane, only signals and room count: car
        // following keeps it behind, and it decides on the conflicts once it is first.
        if go && !a.queued {
            go = conflicts_allow(me, b, net, params, signal, v_through);
        }
        // Too late to stop comfortably: drive on; so does one already at the stop line (within
        // 0.01 m of the margin), which right before left in a saturated junction lets go first.
        // (The step bound below stops a vehicle 0.05 m short of that, at any step.)
        if !go && (stop_room <= 0.01 || !can_stop(hard)) {
            go = true;
        }
        if !go {
            let bound = stop_within_step(v, stop_room - 0.05, hard, dt);
            limit = limit.min(stop_before(v, stop_room, STOP_DECEL)).min(bound);
        }
    } else if a.inside {
        // Inside: brake only for a foe standing in a conflict area ahead.
        if let Some(room) = occupied_ahead(me, b, net) {
            limit = limit.min(stop_before(v, room, STOP_DECEL)).min(stop_within_step(v, room, hard, dt));
        }
    }
    // A queued vehicle never holds the right to go: standing, it would block every foe.
    let go = go && !a.queued;
    let ap = &mut b.approaches[me];
    ap.going = go || a.inside;
    ap.limit = limit;
    if ap.going && a.exit != u32::MAX {
        b.t.reserve(a.exit, a.length + 2.0);
    }
}

/// Whether every conflict of approach `me` lets it drive through now.
fn conflicts_allow(
    me: usize,
    b: &Board,
    net: &JunctionNetwork,
    params: &JunctionParams,
    signal: &dyn Fn(u32) -> u8,
    v_through: f64,
) -> bool {
    let a = &b.approaches[me];
    let v = a.speed.max(0.0);
    let my_signal = signal(b.t.links[a.links.0 as usize].0);
    for &(g, start) in &b.t.links[a.links.0 as usize..a.links.1 as usize] {
        for fc in &net.links[g as usize].conflicts {
            let d_me = start + fc.s_mine - a.front;
            if d_me + a.length + CLEAR < 0.0 {
                continue;
            }
            let t_me_arrive = time_to_cover(d_me - CLEAR, v, ACCEL_FAST, v_through);
            let t_me_clear = time_to_cover(d_me + a.length + CLEAR, v, ACCEL_FAST, v_through);
            for &q in b.t.on_link(fc.foe) {
                let Some(f) = b.at(q) else { continue };
                if q == b.base + me as u32 {
                    continue;
                }
                let Some(f_start) = b.t.link_start(f, fc.foe) else { continue };
                let d_foe = f_start + fc.s_foe - f.front;
                if d_foe + f.length + CLEAR < 0.0 {
                    continue;
                }
                let f_signal = signal(b.t.links[f.links.0 as usize].0);
                let foe_priority = match (my_signal, f_signal) {
                    (b'g' | b'o', b'G' | b'O') => true,
                    (b'G' | b'O', b'g' | b'o') => false,
                    _ => fc
                        .yields
                        .unwrap_or(f.arrived_at < a.arrived_at || (f.arrived_at == a.arrived_at && f.id < a.id)),
                };
                let f_v = f.speed.max(0.0);
                let t_foe_arrive = time_to_cover(d_foe - CLEAR, f_v, ACCEL_FAST, f.v_max.max(f_v));
                // A foe held behind a vehicle standing before its stop line cannot come: a left
                // turner waited for ever on one that had decided to go but stood behind a vehicle
                // waiting to change lanes, itself waiting for the left turner's queue (issue 54).
                if (f.going && !f.blocked) || f.inside {
                    // A merge behind a foe that is already past the merge point is car following.
                    if fc.kind == ConflictKind::Merging && d_foe < 0.0 && d_me > 0.0 {
                        continue;
                    }
                    // A foe standing in the conflict area inside the junction waits for its own
                    // way to clear, which no time estimate knows: enter only once it moves.
                    if f.inside && f_v < STANDING && d_foe < CLEAR && fc.kind != ConflictKind::Merging {
                        tracing::trace!(target: "junctions", "{} waits for {} standing in its way", a.id, f.id);
                        return false;
                    }
                    // It clears no faster than its link's curve lets it (a turnaround: ~3 m/s).
                    let f_v_max = f.v_max.min(net.links[fc.foe as usize].curve_speed).max(f_v);
                    let t_foe_clear = time_to_cover(d_foe + f.length + CLEAR, f_v, ACCEL_SLOW, f_v_max);
                    let after = t_me_arrive > t_foe_clear + params.time_gap;
                    let gap = if foe_priority { impatient_gap(params, a.waiting_now) } else { params.time_gap };
                    let before = !f.inside && accepts_gap(t_me_clear, t_foe_arrive, gap);
                    if !(after || before) {
                        tracing::trace!(target: "junctions", "{} waits for {} driving through (arrive {t_me_arrive:.1} s, it clears {t_foe_clear:.1} s)", a.id, f.id);
                        return false;
                    }
                } else {
                    let red = matches!(f_signal, b'r' | b's' | b'y');
                    // Behind a first vehicle that does not go, a queued foe cannot come.
                    let held = f.queued && b.at(f.head).is_some_and(|h| !h.going);
                    if red || held || f.blocked || f.speed < STANDING || !f.decides && !f.going {
                        continue;
                    }
                    if foe_priority && !accepts_gap(t_me_clear, t_foe_arrive, impatient_gap(params, a.waiting_now)) {
                        tracing::trace!(target: "junctions", "{} gives way to {} (clears {t_me_clear:.1} s, it arrives {t_foe_arrive:.1} s)", a.id, f.id);
                        return false;
                    }
                }
            }
        }
    }
    true
}

/// Room [m] before the first conflict area ahead of approach `me` (inside the junction) that a
/// foe further through it stands in, if any.
fn occupied_ahead(me: usize, b: &Board, net: &JunctionNetwork) -> Option<f64> {
    let a = &b.approaches[me];
    let mut room: Option<f64> = None;
    for &(g, start) in &b.t.links[a.links.0 as usize..a.links.1 as usize] {
        for fc in &net.links[g as usize].conflicts {
            if fc.kind == ConflictKind::Merging {
                continue;
            }
            let d_me = start + fc.s_mine - a.front;
            if d_me <= 0.0 {
                continue;
            }
            for &q in b.t.on_link(fc.foe) {
                let Some(f) = b.at(q) else { continue };
                if q == b.base + me as u32 || !f.inside {
                    continue;
                }
                let Some(f_start) = b.t.link_start(f, fc.foe) else { continue };
                let d_foe = f_start + fc.s_foe - f.front;
                let in_area = d_foe < CLEAR && d_foe + f.length + CLEAR > 0.0;
                // Of two in each other's way, the one further from the point waits.
                if in_area && (d_foe < d_me || (d_foe == d_me && f.id < a.id)) {
                    let r = d_me - CLEAR - STOP_MARGIN;
                    room = Some(room.map_or(r, |x: f64| x.min(r)));
                }
            }
        }
    }
    room
}

/// Junction rules for a map: its junctions (under `params.default`), lights from `programs`
/// (junction id, program, offset) and from the map (a default program where a junction has
/// lights but no program), the decisions in [`LongitudinalSystems::Limit`].
#[derive(Debug, Clone)]
pub struct JunctionsPlugin {
    /// The map.
    pub map: Arc<LaneletMap>,
    /// Parameters.
    pub params: JunctionParams,
    /// Programs given by the scenario: junction id (from 1), phases, offset \[s\].
    pub programs: Vec<(u32, Vec<SignalPhase>, f64)>,
}

impl JunctionsPlugin {
    /// The junctions of the map under these rules (the map's own under the default ones).
    pub fn junctions(&self) -> Arc<Junctions> {
        match self.params.default {
            Fallback::RightBeforeLeft => self.map.junctions(),
            fallback => Arc::new(find_junctions(&self.map, &JunctionRules { fallback, left_hand: None })),
        }
    }
}

impl Plugin for JunctionsPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        let junctions = self.junctions();
        if junctions.is_empty() {
            return;
        }
        install_longitudinal(sim);
        let coarse = [sim.rate(Control), sim.rate(Dynamics)].into_iter().flatten().any(|hz| hz < COARSE_HZ);
        let network = JunctionNetwork::new(
            Arc::clone(&self.map),
            Arc::clone(&junctions),
            self.params.lateral_accel,
            sumo_turn_accel(self.params.sumo_lateral_accel, coarse),
        );
        let left_hand = self.map.left_hand_traffic();
        let mut programs: Vec<(u32, Vec<SignalPhase>, f64)> =
            self.programs.iter().map(|(id, p, o)| (id - 1, p.clone(), *o)).collect();
        for (j, junction) in junctions.list.iter().enumerate() {
            if junction.control == JunctionControl::TrafficLight && !programs.iter().any(|p| p.0 == j as u32) {
                let (program, offset) = crate::map::junctions::map_program(&self.map, junction)
                    .unwrap_or_else(|| (crate::map::junctions::default_program(junction, left_hand), 0.0));
                programs.push((j as u32, program, offset));
            }
        }
        programs.sort_by_key(|p| p.0);
        let lights = TrafficLights::new(programs, &network);
        sim.insert_resource(self.params);
        sim.insert_resource(network);
        sim.insert_resource(lights);
        sim.insert_resource(JunctionStats::default());
        sim.add_systems(
            Control,
            (
                attach_junction_drivers,
                advance_traffic_lights.before(LongitudinalSystems::Limit),
                give_way_at_junctions.in_set(LongitudinalSystems::Limit),
            ),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sumo_links_take_the_file_s_speeds_at_sumo_s_steps_and_netconvert_s_limit_at_coarse_ones() {
        assert_eq!(sumo_turn_accel(0.0, false), 0.0);
        assert_eq!(sumo_turn_accel(0.0, true), NETCONVERT_TURN_ACCEL);
        // A value the scenario sets holds at any step.
        assert_eq!(sumo_turn_accel(3.0, false), 3.0);
        assert_eq!(sumo_turn_accel(3.0, true), 3.0);
    }

    #[test]
    fn room_promised_on_an_exit_nobody_stands_on_is_forgotten_the_next_tick() {
        let approach_to = |exit: u32| Approach {
            entity: Entity::PLACEHOLDER,
            id: VehicleId(1),
            front: 0.0,
            length: 4.5,
            speed: 10.0,
            v_max: 10.0,
            inside: false,
            going: true,
            decides: true,
            arrived_at: 0.0,
            stopped: false,
            junction: 0,
            links: (0, 0),
            exit,
            entry: 0.0,
            limit: f64::INFINITY,
            entry_lanelet: 0,
            queued: false,
            trailing: false,
            waiting_now: 0.0,
            head: 0,
            blocked: false,
        };
        let mut sc = Scratch::default();
        sc.begin_tick(4);
        // A vehicle stands on exit 1; two approaches went, to exit 1 and to exit 2 (empty), one
        // ends in the junction; each promised 6.5 m.
        sc.exit_touched.push(1);
        sc.exit_rear[1] = (5.0, 0.0);
        for exit in [1, 2, u32::MAX] {
            sc.approaches.push(approach_to(exit));
            if let Some(slot) = sc.reserved.get_mut(exit as usize) {
                *slot.get_mut() = 6.5f64.to_bits();
            }
        }
        sc.begin_tick(4);
        for (i, slot) in sc.reserved.iter().enumerate() {
            assert_eq!(f64::from_bits(slot.load(Ordering::Relaxed)), 0.0, "room still promised on exit {i}");
        }
        assert_eq!(sc.exit_rear[1], (f64::INFINITY, 0.0), "the last vehicle on exit 1 is forgotten");
        assert!(sc.approaches.is_empty() && sc.exit_touched.is_empty());
    }

    #[test]
    fn time_to_cover_accelerates_then_cruises() {
        // 20 m/s for 2 s is 40 m.
        assert!((time_to_cover(40.0, 20.0, 1.0, 20.0) - 2.0).abs() < 1e-12);
        // From rest at 2 m/s²: 16 m in 4 s (below the top speed).
        assert!((time_to_cover(16.0, 0.0, 2.0, 100.0) - 4.0).abs() < 1e-12);
        // From rest at 2 m/s² to 4 m/s (2 s, 4 m), then 4 m/s for 10 m more: 4.5 s.
        assert!((time_to_cover(14.0, 0.0, 2.0, 4.0) - 4.5).abs() < 1e-12);
        assert_eq!(time_to_cover(-1.0, 0.0, 1.0, 10.0), 0.0);
        assert!(time_to_cover(5.0, 0.0, 1.0, 0.0).is_infinite());
    }

    #[test]
    fn a_gap_is_taken_only_when_the_foe_arrives_after_clearing_plus_the_gap() {
        assert!(accepts_gap(3.0, 4.5, 1.0));
        assert!(!accepts_gap(3.0, 4.0, 1.0));
        assert!(!accepts_gap(3.0, 3.5, 1.0));
    }

    #[test]
    fn yellow_stops_only_when_the_line_is_reachable_at_the_allowed_deceleration() {
        // 15 m/s needs 37.5 m at 3 m/s².
        assert!(stops_at_yellow(15.0, 40.0, 3.0));
        assert!(!stops_at_yellow(15.0, 30.0, 3.0));
        assert!(stops_at_yellow(0.0, 0.0, 3.0));
        assert!(!stops_at_yellow(5.0, 0.0, 3.0));
    }

    #[test]
    fn programs_cycle_with_their_offset() {
        let p = |s: &str, d| SignalPhase { state: s.into(), duration: d };
        let program = vec![p("Gr", 30.0), p("yr", 3.0), p("rG", 30.0), p("ry", 3.0)];
        assert_eq!(phase_at(&program, 0.0, 0.0), 0);
        assert_eq!(phase_at(&program, 0.0, 29.9), 0);
        assert_eq!(phase_at(&program, 0.0, 30.0), 1);
        assert_eq!(phase_at(&program, 0.0, 33.0), 2);
        assert_eq!(phase_at(&program, 0.0, 65.0), 3);
        assert_eq!(phase_at(&program, 0.0, 66.0), 0);
        assert_eq!(phase_at(&program, 10.0, 5.0), 2);
    }

    #[test]
    fn states_are_checked_for_length_and_characters() {
        assert!(check_state("GGrr", 4).is_ok());
        assert!(check_state("GGr", 4).unwrap_err().contains("3 characters"));
        assert!(check_state("GGxr", 4).unwrap_err().contains("`x`"));
    }
}
