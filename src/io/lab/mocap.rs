//! [`MocapPlugin`]: motion-capture bodies drive the states of the real vehicles.

use std::sync::Mutex;
use std::time::Instant;

use bevy_ecs::prelude::{Component, Query, Res, ResMut, Resource};

use crate::io::lock;
use crate::io::mock_mocap::MockMocapServer;
use crate::io::qualisys::{QtmClient, QtmStats, Tracker};
use crate::sim::{Plugin, SimBuilder};
use bevy_ecs::schedule::IntoScheduleConfigs;

use crate::sim::{Dynamics, SimClock, SimSystems};
use crate::world::{VehicleId, VehicleState, Vehicles};

/// The running motion-capture bridge: the QTM client, the body tracker and, in mock mode, the
/// in-process mock server (stopped when the simulation is dropped).
#[derive(Resource, Debug)]
pub struct MocapBridge {
    /// In a mutex only to make the resource `Sync` (the client's frame queue is not); the
    /// system takes it with `get_mut`, without locking.
    client: Mutex<QtmClient>,
    tracker: Tracker,
    mock: Option<MockMocapServer>,
}

impl MocapBridge {
    /// A bridge over a started client; `mock` is kept alive as long as the bridge.
    pub fn new(client: QtmClient, tracker: Tracker, mock: Option<MockMocapServer>) -> MocapBridge {
        MocapBridge { client: Mutex::new(client), tracker, mock }
    }

    /// The client's counters (connection, frames, bad packets).
    pub fn client_stats(&self) -> QtmStats {
        lock(&self.client).stats()
    }

    /// The tracker (every body seen so far, stale ones included).
    pub fn tracker(&self) -> &Tracker {
        &self.tracker
    }

    /// Address of the in-process mock server, in mock mode.
    pub fn mock_addr(&self) -> Option<std::net::SocketAddr> {
        self.mock.as_ref().map(MockMocapServer::local_addr)
    }
}

/// Motion-capture status of a real vehicle.
#[derive(Component, Debug, Clone, Copy, Default, PartialEq)]
pub struct MocapTrack {
    /// Frames in which its body was seen (each QTM frame counted once).
    pub frames: u64,
    /// Whether it has no fresh tracking now: never seen yet, or lost for longer than the
    /// timeout. A stale vehicle keeps its last position, with zero velocity.
    pub stale: bool,
    /// Sim time spent stale \[s\], counted per dynamics step.
    pub stale_seconds: f64,
    /// Motion-capture timestamp of the last frame that saw its body \[µs\] (QTM's clock; the
    /// truck line's `time`), also used to count each frame once.
    pub last_timestamp_us: Option<i64>,
}

/// Each [`Dynamics`] tick: feed the frames received since the last tick into the tracker, mark
/// lost bodies stale, and copy every tracked body's pose and velocity into its vehicle's
/// [`VehicleState`] (real vehicles have no dynamics model, so nothing else writes it).
pub fn apply_mocap(
    bridge: ResMut<MocapBridge>,
    clock: Res<SimClock>,
    vehicles: Res<Vehicles>,
    mut tracks: Query<(&VehicleId, &mut VehicleState, &mut MocapTrack)>,
) {
    let bridge = bridge.into_inner();
    let client = bridge.client.get_mut().unwrap_or_else(|p| p.into_inner());
    while let Some(f) = client.try_next() {
        bridge.tracker.update(&f.frame, f.received_at);
        for t in bridge.tracker.seen_in(&f.frame) {
            let Some(e) = vehicles.get(VehicleId(t.id)) else { continue };
            if let Ok((_, _, mut track)) = tracks.get_mut(e)
                && track.last_timestamp_us != Some(t.timestamp_us)
            {
                track.last_timestamp_us = Some(t.timestamp_us);
                track.frames += 1;
            }
        }
    }
    bridge.tracker.refresh(Instant::now());
    for (id, mut state, mut track) in &mut tracks {
        match bridge.tracker.get(id.0) {
            Some(t) if !t.stale => {
                state.position = t.position;
                state.yaw = t.yaw;
                state.velocity = t.velocity;
                track.stale = false;
            }
            _ => {
                if !track.stale {
                    state.velocity = glam::DVec2::ZERO;
                }
                track.stale = true;
                track.stale_seconds += clock.dt;
            }
        }
    }
}

/// Motion capture drives the real vehicles `ids` (each gets a [`MocapTrack`], stale until its
/// body is first seen) from the [`Dynamics`] schedule. Build it once: a second `build` finds
/// the bridge taken and adds nothing.
#[derive(Debug)]
pub struct MocapPlugin {
    bridge: Mutex<Option<MocapBridge>>,
    ids: Vec<VehicleId>,
}

impl MocapPlugin {
    /// The plugin for a started bridge and the real vehicles it drives.
    pub fn new(bridge: MocapBridge, ids: Vec<VehicleId>) -> MocapPlugin {
        MocapPlugin { bridge: Mutex::new(Some(bridge)), ids }
    }
}

impl Plugin for MocapPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        let Some(bridge) = lock(&self.bridge).take() else { return };
        let world = sim.world_mut();
        for id in &self.ids {
            let Some(e) = world.resource::<Vehicles>().get(*id) else { continue };
            world.entity_mut(e).insert((MocapTrack { stale: true, ..Default::default() }, crate::world::LabDriven));
        }
        sim.insert_resource(bridge);
        sim.add_systems(Dynamics, apply_mocap.in_set(SimSystems::Integrate));
    }
}
