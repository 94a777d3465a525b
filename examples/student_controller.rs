//! A complete controller plugin in one short file: copy it to start your own.
//!
//! `Careful` drives a vehicle along its route and keeps a time gap to whatever its radar sees
//! ahead; it also tells its neighbours its speed over wifi and counts what it hears. Steering
//! comes from the path follower ([`PathFollowingPlugin`]); this controller only sets the speed.
//!
//! The contract (see `smlworld::app`): a system in the `Control` schedule reads, per vehicle,
//! `VehicleState`, `SensorReadings`, the `Mailbox` in-boxes and the `Route`, and writes the
//! `ControlCommand` and out-going messages. Its own parameters and memory live in a component.
//!
//! Run it: `cargo run --example student_controller`.

use std::sync::Arc;

use bevy_ecs::prelude::*;
use smlworld::map::routing::resample;
use smlworld::prelude::*;
use smlworld::vehicles::follow_paths;

/// The controller's parameters and memory: one on every vehicle it drives.
#[derive(Component, Debug, Clone, Copy, PartialEq)]
pub struct Careful {
    /// Time it keeps to the vehicle ahead [s].
    pub time_gap: f64,
    /// Distance kept to the vehicle ahead when stopped, centre to centre [m].
    pub standstill: f64,
    /// Speed reports heard from other vehicles at the last tick.
    pub heard: usize,
}

/// What it broadcasts: its own speed [m/s]. Any `Send + Sync` type can be a message.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SpeedReport(pub f64);

/// The plugin: one system in the `Control` schedule, after the path follower has steered.
pub struct CarefulPlugin;

impl Plugin for CarefulPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.add_systems(Control, drive_carefully.after(follow_paths));
    }
}

/// Runs every control tick (20 Hz) for every vehicle with a `Careful` component.
pub fn drive_carefully(
    clock: Res<SimClock>,
    mut vehicles: Query<(&VehicleState, &SensorReadings, &mut Mailbox, &mut Careful, &mut ControlCommand)>,
) {
    for (state, readings, mut mailbox, mut me, mut command) in &mut vehicles {
        // 1. Sensors: the nearest vehicle in front of us (readings are sorted nearest first).
        let ahead = readings.0.iter().find(|d| (d.position - state.position).dot(state.heading()) > 0.0);
        // 2. Speed: the path follower already asked for its cruise speed (lowered at the end of
        //    the route); we only ever lower it, so that the room ahead lasts `time_gap` seconds.
        if let Some(d) = ahead {
            let room = d.position.distance(state.position) - me.standstill;
            command.speed = command.speed.min((room / me.time_gap).max(0.0));
        }
        // 3. Mail: the in-box holds what arrived since our last tick.
        me.heard = mailbox.wifi_in.iter().filter(|m| m.payload::<SpeedReport>().is_some()).count();
        // 4. Send: our speed, to everyone within wifi range at the next wifi round.
        mailbox.send(Channel::Wifi, clock.now, Arc::new(SpeedReport(state.speed())));
    }
}

/// A demo: on a straight 400 m road a parked car at 300 m, a careful car at 100 m cruising at
/// 5 m/s and another at 0 m cruising at 10 m/s. Ids: -1 parked, -2 slow, -3 fast.
pub fn demo() -> Sim {
    let road = Arc::new(Path::from_points(Vec::new(), resample(&[DVec2::ZERO, DVec2::new(400.0, 0.0)], 2.0), false));
    let mut builder = SimBuilder::new();
    builder.add_plugin(default_plugins).add_plugin(PathFollowingPlugin).add_plugin(CarefulPlugin);
    let mut parked = VehicleSpec::new(VehicleId(-1), VehicleState::new(DVec2::new(300.0, 0.0), 0.0, 0.0));
    parked.model = VehicleModel::None;
    builder.spawn_vehicle(parked).expect("fresh id");
    for (id, x, cruise) in [(-2, 100.0, 5.0), (-3, 0.0, 10.0)] {
        let mut spec = VehicleSpec::new(VehicleId(id), VehicleState::new(DVec2::new(x, 0.0), 0.0, 0.0));
        spec.sensors.radar = Some(Radar::default());
        spec.route = Some(Arc::clone(&road));
        let entity = builder.spawn_vehicle(spec).expect("fresh id");
        let follow = PathFollower::new(PathFollowing { speed: cruise, ..Default::default() });
        let careful = Careful { time_gap: 2.0, standstill: 8.0, heard: 0 };
        builder.world_mut().entity_mut(entity).insert((follow, careful));
    }
    builder.build()
}

/// Run the demo for 80 s and print where everyone is every 10 s.
pub fn main() {
    let mut sim = demo();
    for _ in 0..8 {
        sim.run_for(10.0);
        let line: Vec<String> = sim
            .states()
            .iter()
            .map(|(id, s)| format!("{id}: x {:6.1} m, v {:4.1} m/s", s.position.x, s.speed()))
            .collect();
        println!("t {:5.1} s | {}", sim.now().as_secs(), line.join(" | "));
    }
}
