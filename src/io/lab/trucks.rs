//! [`TruckPlugin`]: each real vehicle's TCP server is fed the 2015 status line: gap to the
//! leader on its lane, desired gap, lane (left/center/right) and offset from the lane centre.

use std::sync::Mutex;

use bevy_ecs::prelude::{Component, Query, Res, Resource};
use bevy_ecs::schedule::ScheduleLabel;
use glam::DVec2;

use super::mocap::MocapTrack;
use crate::io::lock;
use crate::io::trucks::{Lane, TruckServer, TruckState};
use crate::map::{LaneletMap, Path};
use crate::sim::{Phase, SimClock};
use crate::sim::{Plugin, SimBuilder};
use crate::world::{Detection, Route, SensorReadings, VehicleId, VehicleState, Vehicles};

/// Schedule of the truck status lines ([`Phase::Sense`], after the sensors at the same instant).
#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Trucks;

/// The truck servers and how gaps are measured.
#[derive(Resource, Debug)]
pub struct TruckBridge {
    /// One TCP server per real vehicle.
    pub server: TruckServer,
    /// Gap the trucks are asked to keep \[m\].
    pub desired_distance: f64,
    /// Vehicles whose centre is within this of the lane's centre line are on it \[m\].
    pub lane_half_width: f64,
    /// Longest gap looked for \[m\]; sent when no leader is closer.
    pub max_gap: f64,
}

/// The last status a real vehicle's truck was sent (a component of every served vehicle).
#[derive(Component, Debug, Clone, Copy, Default, PartialEq)]
pub struct TruckLine {
    /// The leader, if a vehicle is ahead on the lane within `max_gap`.
    pub leader: Option<VehicleId>,
    /// Gap to the leader, centre to centre along the lane \[m\] (`max_gap` without a leader).
    pub current_distance: f64,
    /// Lane the truck is on.
    pub lane: Lane,
    /// Signed offset from that lane's centre line \[m\], positive to the left.
    pub lane_offset: f64,
    /// Arc length of the truck along its route at the last tick [m] (projection hint).
    route_s: Option<f64>,
}

/// Lanes of a map for the status lines: each lanelet's centre line and whether it is the left,
/// centre or right lane of its road (from shared bounds: a lanelet whose left bound is another
/// lanelet's right bound has a lane to its left).
#[derive(Resource, Debug, Clone)]
pub struct LaneIndex {
    lanes: Vec<(Lane, Vec<DVec2>)>,
}

impl LaneIndex {
    /// Index the lanelets of `map`.
    pub fn new(map: &LaneletMap) -> LaneIndex {
        let rights: std::collections::BTreeSet<i64> = map.lanelets.iter().map(|l| l.right_way).collect();
        let lefts: std::collections::BTreeSet<i64> = map.lanelets.iter().map(|l| l.left_way).collect();
        let lanes = map
            .lanelets
            .iter()
            .map(|l| {
                let has_left = rights.contains(&l.left_way);
                let has_right = lefts.contains(&l.right_way);
                let lane = match (has_left, has_right) {
                    (false, true) => Lane::Left,
                    (true, false) => Lane::Right,
                    _ => Lane::Center,
                };
                (lane, l.centre.clone())
            })
            .collect();
        LaneIndex { lanes }
    }

    /// The lane whose centre line is nearest to `p`, and the signed offset of `p` from it \[m\]
    /// (positive to the left of the driving direction). O(centre-line points).
    pub fn locate(&self, p: DVec2) -> Option<(Lane, f64)> {
        let mut best: Option<(f64, Lane, f64)> = None;
        for (lane, centre) in &self.lanes {
            for w in centre.windows(2) {
                let (a, b) = (w[0], w[1]);
                let d = b - a;
                let len2 = d.length_squared();
                if len2 <= 0.0 {
                    continue;
                }
                let t = ((p - a).dot(d) / len2).clamp(0.0, 1.0);
                let q = a + d * t;
                let dist2 = p.distance_squared(q);
                if best.is_none_or(|(b2, _, _)| dist2 < b2) {
                    let side = d.perp_dot(p - a).signum();
                    best = Some((dist2, *lane, side * dist2.sqrt()));
                }
            }
        }
        best.map(|(_, lane, offset)| (lane, offset))
    }
}

/// Gap from a vehicle at `s` \[m\] along `route` to the nearest of `others` ahead of it on the
/// route: centre to centre along the route, counting only vehicles within `half_width` \[m\] of
/// the route and at most `max_gap` \[m\] ahead (wrapping around a closed route). Returns the
/// leader and the gap.
pub fn leader_gap(
    route: &Path,
    s: f64,
    others: &[Detection],
    half_width: f64,
    max_gap: f64,
) -> Option<(VehicleId, f64)> {
    let mut best: Option<(VehicleId, f64)> = None;
    for d in others {
        let p = route.project_near(d.position, s + 0.5 * max_gap, 0.5 * max_gap + half_width + route.spacing());
        if p.lateral.abs() > half_width {
            continue;
        }
        let mut ds = p.s - s;
        if route.closed {
            ds = ds.rem_euclid(route.length);
        }
        if ds > 0.0 && ds <= max_gap && best.is_none_or(|(id, g)| ds < g || (ds == g && d.id < id)) {
            best = Some((d.id, ds));
        }
    }
    best
}

/// Each [`Trucks`] tick: for every served real vehicle, find its leader among what its sensors
/// see (its [`SensorReadings`]; every vehicle if it has no sensors) along its [`Route`] (without
/// a route: along its heading), find its lane on the map, and publish the status line.
#[allow(clippy::type_complexity)]
pub fn publish_trucks(
    bridge: Res<TruckBridge>,
    clock: Res<SimClock>,
    lanes: Option<Res<LaneIndex>>,
    everyone: Query<(&VehicleId, &VehicleState)>,
    mut served: Query<(
        &VehicleId,
        &VehicleState,
        Option<&Route>,
        Option<&SensorReadings>,
        Option<&MocapTrack>,
        &mut TruckLine,
    )>,
    mut all: bevy_ecs::prelude::Local<Vec<Detection>>,
) {
    for (&id, state, route, readings, track, mut line) in &mut served {
        let others: &[Detection] = match readings {
            Some(r) => &r.0,
            None => {
                all.clear();
                all.extend(everyone.iter().filter(|(other, _)| **other != id).map(|(&other, s)| Detection {
                    id: other,
                    position: s.position,
                    velocity: s.velocity,
                    sensor: crate::sim::sensors::OMNISCIENT,
                }));
                &all
            }
        };
        let leader = match route {
            Some(r) => {
                // A truck moves far less than 10 m per tick; the first tick searches the whole route.
                let s = match line.route_s {
                    Some(hint) => r.0.project_near(state.position, hint, 10.0 + r.0.spacing()).s,
                    None => r.0.project(state.position).s,
                };
                line.route_s = Some(s);
                leader_gap(&r.0, s, others, bridge.lane_half_width, bridge.max_gap)
            }
            None => {
                let heading = state.heading();
                others
                    .iter()
                    .filter_map(|d| {
                        let rel = d.position - state.position;
                        let ahead = rel.dot(heading);
                        (ahead > 0.0
                            && ahead <= bridge.max_gap
                            && heading.perp_dot(rel).abs() <= bridge.lane_half_width)
                            .then_some((d.id, ahead))
                    })
                    .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)))
            }
        };
        line.leader = leader.map(|(l, _)| l);
        line.current_distance = leader.map_or(bridge.max_gap, |(_, g)| g);
        let (lane, offset) = match (&lanes, route) {
            (Some(index), _) => index.locate(state.position).unwrap_or((Lane::Center, 0.0)),
            (None, Some(r)) => {
                (Lane::Center, r.0.project_near(state.position, line.route_s.unwrap_or(0.0), 10.0).lateral)
            }
            (None, None) => (Lane::Center, 0.0),
        };
        line.lane = lane;
        line.lane_offset = offset;
        let status = TruckState {
            // The 2015 sender sent the body's motion-capture time (QTM µs / 1e6, see
            // `MotionCaptureModule.py` and `vehiclecontrolmodule.py` `get_tcp_string`); a
            // vehicle motion capture has not seen yet, or one without it, sends sim time.
            time: track.and_then(|t| t.last_timestamp_us).map_or(clock.now.as_secs(), |us| us as f64 * 1e-6),
            lane,
            current_distance: line.current_distance,
            desired_distance: bridge.desired_distance,
            velocity: state.speed(),
            x: state.position.x,
            y: state.position.y,
            yaw: state.yaw,
            lane_offset: offset,
        };
        if let Err(e) = bridge.server.publish(id.0, status) {
            tracing::warn!("truck {id}: {e}");
        }
    }
}

/// Feeds the truck servers of the real vehicles at `rate` \[Hz\] (a module of its own). Build it
/// once: a second `build` finds the bridge taken and adds nothing.
#[derive(Debug)]
pub struct TruckPlugin {
    bridge: Mutex<Option<TruckBridge>>,
    rate: f64,
    lanes: Option<LaneIndex>,
}

impl TruckPlugin {
    /// The plugin for started servers, sending at `rate` \[Hz\]; `lanes` names the lanes (without
    /// a map every truck is told `center`).
    pub fn new(bridge: TruckBridge, rate: f64, lanes: Option<LaneIndex>) -> TruckPlugin {
        TruckPlugin { bridge: Mutex::new(Some(bridge)), rate, lanes }
    }
}

impl Plugin for TruckPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        let Some(bridge) = lock(&self.bridge).take() else { return };
        let world = sim.world_mut();
        let ids: Vec<i32> = bridge.server.ids().collect();
        for id in ids {
            let Some(e) = world.resource::<Vehicles>().get(VehicleId(id)) else { continue };
            world.entity_mut(e).insert((TruckLine::default(), crate::world::LabDriven));
        }
        if let Some(lanes) = &self.lanes {
            sim.insert_resource(lanes.clone());
        }
        sim.insert_resource(bridge);
        sim.add_module("trucks", Trucks, Phase::Sense, self.rate);
        sim.add_systems(Trucks, publish_trucks);
    }
}
