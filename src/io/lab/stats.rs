//! Real vehicles among virtual ones: V2V beacons of the real vehicles, and counters of how often
//! virtual vehicles detected and heard them; the `lab` part of `summary.json`.

use std::collections::BTreeMap;
use std::sync::Arc;

use bevy_ecs::prelude::{Component, Local, Query, Res, Without, World};
use bevy_ecs::schedule::IntoScheduleConfigs;
use glam::DVec2;

use crate::sim::{Control, Sensors, SimClock, SimSystems};
use crate::sim::{Plugin, SimBuilder};
use crate::world::{Channel, Mailbox, Payload, SensorReadings, VehicleId, VehicleState, Vehicles};

use super::{MocapTrack, TruckBridge, TruckLine, VizStream};

/// What a real vehicle broadcasts on wifi every wifi round: its measured state, so virtual
/// vehicles' controllers can cooperate with it (read it with `message.payload::<RealVehicleBeacon>()`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RealVehicleBeacon {
    /// The real vehicle.
    pub id: VehicleId,
    /// Its position \[m\].
    pub position: DVec2,
    /// Its heading \[rad\].
    pub yaw: f64,
    /// Its velocity [m/s].
    pub velocity: DVec2,
    /// Whether motion capture has lost it (the state is the last one measured).
    pub stale: bool,
}

/// How a real vehicle was seen by the virtual ones (a component of every real vehicle).
#[derive(Component, Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RealVehicleStats {
    /// Sensor detections of it by virtual vehicles, summed over sensor ticks.
    pub detections_by_virtual: u64,
    /// Its beacons received by virtual vehicles (one message to one receiver counts one).
    pub v2v_received_by_virtual: u64,
    /// Beacons it queued (one per wifi round it took part in).
    pub beacons_sent: u64,
}

/// Each [`Control`] tick: every real vehicle with a mailbox queues a [`RealVehicleBeacon`] for
/// the next wifi round, replacing a beacon still waiting there (so a round carries one beacon
/// per real vehicle, the freshest, whatever the rates).
pub fn beacon_real_vehicles(
    clock: Res<SimClock>,
    mut real: Query<(&VehicleId, &VehicleState, Option<&MocapTrack>, &mut Mailbox, &mut RealVehicleStats)>,
) {
    for (&id, s, track, mut mailbox, mut stats) in &mut real {
        let beacon = RealVehicleBeacon {
            id,
            position: s.position,
            yaw: s.yaw,
            velocity: s.velocity,
            stale: track.is_some_and(|t| t.stale),
        };
        let waiting = mailbox.wifi_out.iter_mut().find(|m| m.payload::<RealVehicleBeacon>().is_some());
        match waiting {
            Some(m) => {
                m.sent_at = clock.now;
                m.payload = Payload::new(beacon);
            }
            None => {
                mailbox.send(Channel::Wifi, clock.now, Arc::new(beacon));
                stats.beacons_sent += 1;
            }
        }
    }
}

/// Each [`Sensors`] tick, after sensing: count detections of real vehicles by virtual ones.
pub fn count_real_detections(
    vehicles: Res<Vehicles>,
    sensing: Query<(&VehicleId, &SensorReadings), Without<RealVehicleStats>>,
    mut real: Query<&mut RealVehicleStats>,
) {
    for (id, readings) in &sensing {
        if id.is_real() {
            continue;
        }
        for d in readings.0.iter().filter(|d| d.id.is_real()) {
            if let Some(mut stats) = vehicles.get(d.id).and_then(|e| real.get_mut(e).ok()) {
                stats.detections_by_virtual += 1;
            }
        }
    }
}

/// Each [`Control`] tick: count beacons of real vehicles in the wifi in-boxes of virtual
/// vehicles, each wifi round once (`last_round`: the newest round counted). O(wifi deliveries
/// since the last control tick): only lab scenarios add it.
pub fn count_real_messages(
    vehicles: Res<Vehicles>,
    mailboxes: Query<(&VehicleId, &Mailbox), Without<RealVehicleStats>>,
    mut real: Query<&mut RealVehicleStats>,
    mut last_round: Local<u64>,
) {
    let mut newest = *last_round;
    for (id, mailbox) in &mailboxes {
        if id.is_real() {
            continue;
        }
        let inbox = mailbox.inbox(Channel::Wifi);
        newest = newest.max(inbox.latest_round().unwrap_or(0));
        for m in
            inbox.iter_after(*last_round).filter(|m| m.sender.is_real() && m.payload::<RealVehicleBeacon>().is_some())
        {
            if let Some(mut stats) = vehicles.get(m.sender).and_then(|e| real.get_mut(e).ok()) {
                stats.v2v_received_by_virtual += 1;
            }
        }
    }
    *last_round = newest;
}

/// Gives every real vehicle (id >= 0, spawned before the plugin is added) a
/// [`RealVehicleStats`], beacons them on wifi and counts how virtual vehicles see them.
#[derive(Debug, Clone, Copy, Default)]
pub struct RealVehicleStatsPlugin;

impl Plugin for RealVehicleStatsPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        let world = sim.world_mut();
        let real: Vec<_> = world.resource::<Vehicles>().iter().filter(|(id, _)| id.is_real()).map(|(_, e)| e).collect();
        for e in real {
            world.entity_mut(e).insert(RealVehicleStats::default());
        }
        sim.add_systems(Control, (beacon_real_vehicles, count_real_messages).in_set(SimSystems::Control));
        sim.add_systems(Sensors, count_real_detections.after(SimSystems::Sense));
    }
}

/// One real vehicle in `summary.json`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RealVehicleSummary {
    /// Whether motion capture drives it.
    pub mocap: bool,
    /// Motion-capture frames in which it was seen.
    pub frames_received: u64,
    /// Whether it was stale (untracked) at the end.
    pub stale: bool,
    /// Sim time it spent stale \[s\] (including before its first frame).
    pub stale_seconds: f64,
    /// Sensor detections of it by virtual vehicles.
    pub detections_by_virtual: u64,
    /// Its V2V beacons received by virtual vehicles.
    pub v2v_received_by_virtual: u64,
    /// Status lines: the last gap to its leader sent [m, world units], if a truck server runs.
    pub truck_current_distance: Option<f64>,
    /// Status lines: its leader's id at the end (none: no vehicle ahead within `max_gap`).
    pub truck_leader: Option<i32>,
    /// Status lines: connections accepted from the truck.
    pub truck_connections: Option<u64>,
}

/// The `lab` part of `summary.json`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LabSummary {
    /// Per real vehicle id.
    pub real_vehicles: BTreeMap<i32, RealVehicleSummary>,
    /// Visualisation frames sent, if streaming.
    pub stream_frames_sent: Option<u64>,
    /// Motion-capture packets dropped as malformed, if motion capture is on.
    pub mocap_bad_packets: Option<u64>,
}

impl LabSummary {
    /// The summary of `world`, or `None` when no lab bridge ran.
    pub fn of(world: &World) -> Option<LabSummary> {
        let stream = world.get_resource::<VizStream>();
        let mocap = world.get_resource::<super::MocapBridge>();
        let trucks = world.get_resource::<TruckBridge>();
        let vehicles = world.get_resource::<Vehicles>()?;
        let mut real_vehicles = BTreeMap::new();
        for (id, e) in vehicles.iter().filter(|(id, _)| id.is_real()) {
            let Some(stats) = world.get::<RealVehicleStats>(e) else { continue };
            let track = world.get::<MocapTrack>(e);
            let line = world.get::<TruckLine>(e);
            real_vehicles.insert(
                id.0,
                RealVehicleSummary {
                    mocap: track.is_some(),
                    frames_received: track.map_or(0, |t| t.frames),
                    stale: track.is_some_and(|t| t.stale),
                    stale_seconds: track.map_or(0.0, |t| t.stale_seconds),
                    detections_by_virtual: stats.detections_by_virtual,
                    v2v_received_by_virtual: stats.v2v_received_by_virtual,
                    truck_current_distance: line.map(|l| l.current_distance),
                    truck_leader: line.and_then(|l| l.leader.map(|v| v.0)),
                    truck_connections: trucks.map(|t| t.server.connections(id.0)),
                },
            );
        }
        if real_vehicles.is_empty() && stream.is_none() {
            return None;
        }
        Some(LabSummary {
            real_vehicles,
            stream_frames_sent: stream.map(|s| s.frames_sent),
            mocap_bad_packets: mocap.map(|m| m.client_stats().bad_packets),
        })
    }
}
