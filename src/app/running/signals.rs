//! What a traffic-signal learning environment reads (issue 55, sumo-rl's interface): for every
//! traffic light its program and its controlled incoming and outgoing lanes, and per lane at each
//! step the vehicle count, halting count, summed vehicle length, summed normalised speed and
//! accumulated waiting time, plus the system-wide numbers sumo-rl puts in `info`.
//!
//! Everything is O(N) per measurement in the vehicles: one pass over them fills every lane's
//! numbers for every light at once. The waiting time of each vehicle is integrated at every
//! dynamics tick by [`accumulate_waiting`], as SUMO counts it (a vehicle waits while its speed is
//! below 0.1 m/s, SUMO's `SUMO_const_haltingSpeed`).

use std::collections::VecDeque;

use bevy_ecs::prelude::{Commands, Component, Entity, Query, Res, Resource, World};
use bevy_ecs::query::QueryState;

use crate::map::LaneletMap;
use crate::map::junctions::SignalPhase;
use crate::sim::SimClock;
use crate::vehicles::{JunctionNetwork, LanePosition, TrafficLights};
use crate::world::{VehicleSize, VehicleState};

/// Below this speed a vehicle halts and waits [m/s] (SUMO's `SUMO_const_haltingSpeed`).
pub const HALTING_SPEED: f64 = 0.1;

/// Speed limit assumed on a lane without a `speed_limit` tag [m/s] (50 km/h).
pub const DEFAULT_ALLOWED_SPEED: f64 = 50.0 / 3.6;

/// How far back [`WaitingTime::accumulated`] remembers waiting \[s\] (SUMO's
/// `--waiting-time-memory`; sumo-rl's `waiting_time_memory` default, 1000 s, which it passes to
/// SUMO).
#[derive(Resource, Debug, Clone, Copy, PartialEq)]
pub struct WaitingMemory(pub f64);

impl Default for WaitingMemory {
    fn default() -> Self {
        WaitingMemory(1000.0)
    }
}

/// The waiting of one vehicle, as SUMO counts it (`MSVehicle::myWaitingTime` and its
/// `WaitingTimeCollector`).
#[derive(Component, Debug, Clone, Default, PartialEq)]
pub struct WaitingTime {
    /// Time since the vehicle last moved at [`HALTING_SPEED`] or more \[s\] (TraCI
    /// `vehicle.getWaitingTime`).
    pub current: f64,
    /// Waiting periods `(start, end)` [s] that end within the memory, oldest first.
    periods: VecDeque<(f64, f64)>,
    /// sumo-rl's per-lane share: the lanelet index where the vehicle was last measured on an
    /// incoming lane (`u32::MAX`: never), its waiting there, and its waiting stored for the
    /// lanes before.
    lane: u32,
    on_lane: f64,
    before: f64,
}

impl WaitingTime {
    fn new() -> WaitingTime {
        WaitingTime { lane: u32::MAX, ..Default::default() }
    }

    /// Waiting within the last `memory` seconds before `now` \[s\] (TraCI
    /// `vehicle.getAccumulatedWaitingTime`).
    pub fn accumulated(&self, now: f64, memory: f64) -> f64 {
        let from = now - memory;
        self.periods.iter().map(|&(a, b)| (b - a.max(from)).max(0.0)).sum()
    }

    /// Count `dt` [s] ending at `now` [s] at speed `speed` [m/s].
    fn pass(&mut self, now: f64, dt: f64, speed: f64, memory: f64) {
        if speed < HALTING_SPEED {
            self.current += dt;
            match self.periods.back_mut() {
                Some(last) if (last.1 - (now - dt)).abs() < 1e-9 => last.1 = now,
                _ => self.periods.push_back((now - dt, now)),
            }
        } else {
            self.current = 0.0;
        }
        while self.periods.front().is_some_and(|p| p.1 <= now - memory) {
            self.periods.pop_front();
        }
    }

    /// sumo-rl's `get_accumulated_waiting_time_per_lane` for one vehicle seen on lane `lane`
    /// with accumulated waiting `acc` [s]: the waiting counted on this lane is `acc` less what
    /// was counted on the lanes it was seen on before (sumo-rl `traffic_signal.py`).
    fn on_lane(&mut self, lane: u32, acc: f64) -> f64 {
        if self.lane != lane {
            if self.lane != u32::MAX {
                self.before += self.on_lane;
            }
            self.lane = lane;
        }
        self.on_lane = acc - self.before;
        self.on_lane
    }
}

/// Dynamics-phase system (after integration): every vehicle's waiting over the step just taken.
pub fn accumulate_waiting(
    clock: Res<SimClock>,
    memory: Option<Res<WaitingMemory>>,
    mut commands: Commands,
    mut q: Query<(Entity, &VehicleState, Option<&mut WaitingTime>)>,
) {
    let memory = memory.map_or(WaitingMemory::default().0, |m| m.0);
    let dt = clock.dt;
    let now = clock.now.as_secs() + dt;
    for (e, state, waiting) in &mut q {
        match waiting {
            Some(mut w) => w.pass(now, dt, state.speed(), memory),
            None => {
                let mut w = WaitingTime::new();
                w.pass(now, dt, state.speed(), memory);
                commands.entity(e).insert(w);
            }
        }
    }
}

/// One traffic light as a learning environment sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct LightLayout {
    /// Junction id (from 1).
    pub junction: u32,
    /// The SUMO `tlLogic` id its links name (tag `signal_program`), else the junction id.
    pub name: String,
    /// The program's phases: state (one character per link, in link order) and duration \[s\].
    pub phases: Vec<(String, f64)>,
    /// The same phases as the map file states them, in link order: SUMO's own characters (`s`,
    /// `u`, `o`, `O` ... kept, which `phases` shows as ours), so an environment derives green and
    /// yellow phases from them as sumo-rl does. Equal to `phases`' states for other maps.
    pub file_states: Vec<String>,
    /// Incoming lanes (lanelet ids) in the order of the links they feed (SUMO's `linkIndex`
    /// where the map gives it, as `trafficlight.getControlledLanes`), each once.
    pub lanes: Vec<i64>,
    /// Outgoing lanes (lanelet ids), ascending, each once.
    pub out_lanes: Vec<i64>,
}

/// Every light's layout and the lane slots measured for it.
#[derive(Debug, Clone, Default)]
pub struct SignalLayout {
    /// The lights, in junction order.
    pub lights: Vec<LightLayout>,
    /// Lane slots: every light's incoming lanes in order, then every light's outgoing lanes; a
    /// lanelet index per slot.
    pub slots: Vec<u32>,
    /// Whether each slot is an incoming lane (waiting is counted on those only).
    pub incoming: Vec<bool>,
    /// Length of each slot's lane \[m\].
    pub length: Vec<f64>,
    /// Speed limit of each slot's lane [m/s] (the `speed_limit` tag; [`DEFAULT_ALLOWED_SPEED`]
    /// where none).
    pub allowed: Vec<f64>,
    /// Lanelet index -> the slots measuring it.
    slots_of_lanelet: Vec<Vec<u32>>,
}

impl SignalLayout {
    /// The layout of every light of `lights` on `network`'s map.
    pub fn new(lights: &TrafficLights, network: &JunctionNetwork) -> SignalLayout {
        let map: &LaneletMap = &network.map;
        let n = map.lanelets.len();
        let mut predecessors: Vec<Vec<u32>> = vec![Vec::new(); n];
        for (i, l) in map.lanelets.iter().enumerate() {
            for s in &l.successors {
                if let Some(k) = map.lanelet_index(*s) {
                    predecessors[k].push(i as u32);
                }
            }
        }
        let mut out = SignalLayout { slots_of_lanelet: vec![Vec::new(); n], ..Default::default() };
        let mut outgoing_all: Vec<Vec<u32>> = Vec::new();
        for c in &lights.controllers {
            let Some(junction) = network.junctions.list.get(c.junction as usize) else { continue };
            let mut links: Vec<(usize, usize)> = junction
                .links
                .iter()
                .enumerate()
                .filter_map(|(k, link)| Some((k, map.lanelet_index(link.lanelet)?)))
                .collect();
            let signal_index = |i: usize| {
                map.lanelets[i].tags.get("signal_index").and_then(|v| v.parse::<usize>().ok()).unwrap_or(usize::MAX)
            };
            links.sort_by_key(|&(k, i)| (signal_index(i), k));
            let is_link = |i: u32| network.link_of_lanelet.get(i as usize).is_some_and(|&g| g != u32::MAX);
            let mut lanes: Vec<u32> = Vec::new();
            let mut outgoing: Vec<u32> = Vec::new();
            for &(_, i) in &links {
                for &p in &predecessors[i] {
                    if !is_link(p) && !lanes.contains(&p) {
                        lanes.push(p);
                    }
                }
                for s in &map.lanelets[i].successors {
                    if let Some(k) = map.lanelet_index(*s).map(|k| k as u32).filter(|&k| !is_link(k))
                        && !outgoing.contains(&k)
                    {
                        outgoing.push(k);
                    }
                }
            }
            outgoing.sort_unstable();
            let name = junction
                .links
                .first()
                .and_then(|l| map.lanelet(l.lanelet))
                .and_then(|l| l.tags.get("signal_program").cloned())
                .unwrap_or_else(|| junction.id.to_string());
            out.lights.push(LightLayout {
                junction: junction.id,
                name,
                phases: c.program.iter().map(|p| (p.state.clone(), p.duration)).collect(),
                file_states: file_states(map, junction, &c.program),
                lanes: lanes.iter().map(|&i| map.lanelets[i as usize].id.0).collect(),
                out_lanes: outgoing.iter().map(|&i| map.lanelets[i as usize].id.0).collect(),
            });
            for &i in &lanes {
                out.push_slot(map, i, true);
            }
            outgoing_all.push(outgoing);
        }
        for outgoing in outgoing_all {
            for i in outgoing {
                out.push_slot(map, i, false);
            }
        }
        out
    }

    fn push_slot(&mut self, map: &LaneletMap, i: u32, incoming: bool) {
        let l = &map.lanelets[i as usize];
        self.slots_of_lanelet[i as usize].push(self.slots.len() as u32);
        self.slots.push(i);
        self.incoming.push(incoming);
        self.length.push(l.length);
        let limit = l.tags.get("speed_limit").and_then(|v| v.parse::<f64>().ok()).filter(|v| *v > 0.0);
        self.allowed.push(limit.map_or(DEFAULT_ALLOWED_SPEED, |kmh| kmh / 3.6));
    }
}

/// The states of `program` as the map file gives them (see [`LightLayout::file_states`]): from
/// the SUMO `tlLogic` every link names (tags `signal_program`, `signal_index`), re-ordered into
/// link order like [`crate::map::junctions::map_program`] but with the file's characters; else
/// `program`'s states. A program of another length than the file's (a scenario's
/// `[[traffic_lights]]`) keeps its own states.
fn file_states(map: &LaneletMap, junction: &crate::map::junctions::Junction, program: &[SignalPhase]) -> Vec<String> {
    let own = || program.iter().map(|p| p.state.clone()).collect();
    let mut name: Option<&str> = None;
    let mut indices = Vec::with_capacity(junction.links.len());
    for link in &junction.links {
        let Some(tags) = map.lanelet(link.lanelet).map(|l| &l.tags) else { return own() };
        let (Some(id), Some(k)) =
            (tags.get("signal_program"), tags.get("signal_index").and_then(|k| k.parse::<usize>().ok()))
        else {
            return own();
        };
        if name.is_some_and(|n| n != id) {
            return own();
        }
        name = Some(id);
        indices.push(k);
    }
    let Some(file) = name.and_then(|n| map.signal_programs.get(n)) else { return own() };
    if file.phases.len() != program.len() {
        return own();
    }
    file.phases
        .iter()
        .map(|ph| indices.iter().map(|&k| ph.state.as_bytes().get(k).map_or('r', |&c| c as char)).collect())
        .collect()
}

/// One measurement: per lane slot of a [`SignalLayout`] and for the whole system.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SignalMeasures {
    /// Vehicles on the lane (`lane.getLastStepVehicleNumber`).
    pub count: Vec<f64>,
    /// Of them, halting: speed below [`HALTING_SPEED`] (`lane.getLastStepHaltingNumber`).
    pub halting: Vec<f64>,
    /// Sum of their lengths \[m\] (`lane.getLastStepLength` is this over `count`).
    pub length_sum: Vec<f64>,
    /// Sum of speed / allowed speed (the lane's limit) [-] (sumo-rl `get_average_speed`).
    pub speed_ratio_sum: Vec<f64>,
    /// Accumulated waiting counted on the lane, sumo-rl's way \[s\] (0 on outgoing slots).
    pub waiting: Vec<f64>,
    /// Vehicles in the simulation.
    pub running: usize,
    /// Of them, halting.
    pub stopped: usize,
    /// Sum of every vehicle's current waiting time \[s\] (`vehicle.getWaitingTime`).
    pub total_waiting: f64,
    /// Sum of every vehicle's speed [m/s].
    pub total_speed: f64,
}

/// The query one measurement runs over the vehicles.
pub type MeasureQuery = QueryState<(
    &'static VehicleState,
    Option<&'static LanePosition>,
    Option<&'static VehicleSize>,
    Option<&'static mut WaitingTime>,
)>;

/// Measure every slot of `layout` and the system in `world` at sim time `now` \[s\] into `out`
/// (its vectors are reused): one pass over the vehicles. Lane positions must be current
/// ([`crate::vehicles::refresh_lane_positions`]).
pub fn measure(world: &mut World, query: &mut MeasureQuery, layout: &SignalLayout, now: f64, out: &mut SignalMeasures) {
    let n = layout.slots.len();
    for v in [&mut out.count, &mut out.halting, &mut out.length_sum, &mut out.speed_ratio_sum, &mut out.waiting] {
        v.clear();
        v.resize(n, 0.0);
    }
    out.running = 0;
    out.stopped = 0;
    out.total_waiting = 0.0;
    out.total_speed = 0.0;
    let memory = world.get_resource::<WaitingMemory>().map_or(WaitingMemory::default().0, |m| m.0);
    for (state, pos, size, mut waiting) in query.iter_mut(world) {
        let speed = state.speed();
        out.running += 1;
        out.total_speed += speed;
        if speed < HALTING_SPEED {
            out.stopped += 1;
        }
        let acc = waiting.as_ref().map_or(0.0, |w| w.accumulated(now, memory));
        out.total_waiting += waiting.as_ref().map_or(0.0, |w| w.current);
        let Some(pos) = pos.filter(|p| p.index != u32::MAX) else { continue };
        let Some(slots) = layout.slots_of_lanelet.get(pos.index as usize) else { continue };
        let length = size.map_or(VehicleSize::default().length, |s| s.length);
        let mut share = None;
        for &k in slots {
            let k = k as usize;
            out.count[k] += 1.0;
            out.length_sum[k] += length;
            out.speed_ratio_sum[k] += speed / layout.allowed[k];
            if speed < HALTING_SPEED {
                out.halting[k] += 1.0;
            }
            if layout.incoming[k] {
                let w = *share.get_or_insert_with(|| waiting.as_mut().map_or(0.0, |w| w.on_lane(pos.index, acc)));
                out.waiting[k] += w;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn waiting_counts_time_below_the_halting_speed_within_the_memory() {
        let mut w = WaitingTime::new();
        // 3 s at 0.05 m/s, 2 s moving, 4 s stopped, in 1 s steps.
        let speeds = [0.05, 0.05, 0.05, 5.0, 5.0, 0.0, 0.0, 0.0, 0.0];
        for (k, v) in speeds.iter().enumerate() {
            w.pass(k as f64 + 1.0, 1.0, *v, 1000.0);
        }
        assert_eq!(w.current, 4.0, "the current stop only");
        assert_eq!(w.accumulated(9.0, 1000.0), 7.0, "both stops");
        assert_eq!(w.accumulated(9.0, 5.0), 4.0, "the first stop ended 6 s ago, beyond a 5 s memory");
        assert_eq!(w.accumulated(9.0, 7.0), 5.0, "one second of the first stop is within 7 s");
    }

    #[test]
    fn a_vehicle_s_waiting_is_shared_between_lanes_as_sumo_rl_does() {
        let mut w = WaitingTime::new();
        assert_eq!(w.on_lane(3, 10.0), 10.0);
        assert_eq!(w.on_lane(3, 12.0), 12.0);
        // On the next lane only what it waited after leaving the first one counts.
        assert_eq!(w.on_lane(7, 15.0), 3.0);
        assert_eq!(w.on_lane(7, 20.0), 8.0);
    }
}
