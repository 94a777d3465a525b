//! Modules and phases: a module label cannot be taken twice, and a control-phase module of a
//! student's own sees every V2V round since its last tick, like the built-in `Control`.

use std::collections::BTreeSet;

use bevy_ecs::prelude::Resource;
use bevy_ecs::schedule::ScheduleLabel;
use smlworld::prelude::*;

#[derive(ScheduleLabel, Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct SlowControl;

#[test]
fn a_module_label_cannot_be_added_twice() {
    let mut b = SimBuilder::new();
    b.try_add_module("mine", SlowControl, Phase::Control, 2.0).expect("first time");
    let e = b.try_add_module("again", SlowControl, Phase::Sense, 5.0).err().expect("second time is an error");
    assert!(e.to_string().contains("mine"), "names the module that has the label: {e}");
    assert_eq!(b.rate(SlowControl), Some(2.0), "the first module is unchanged");
    let built_in = b.try_add_module("control again", Control, Phase::Control, 20.0);
    assert!(built_in.is_err(), "a built-in label is taken too");
}

/// Wifi rounds (numbers) the slow module saw.
#[derive(Resource, Default)]
struct Seen(BTreeSet<u64>);

fn beacon(clock: Res<SimClock>, mut q: Query<(&VehicleId, &mut Mailbox)>) {
    for (id, mut m) in &mut q {
        if id.0 == -1 {
            m.send_typed(Channel::Wifi, clock.now, clock.now.0);
        }
    }
}

fn read_slowly(mut seen: ResMut<Seen>, q: Query<&Mailbox>) {
    for m in &q {
        for (_, _, &sent) in m.received::<u64>(Channel::Wifi) {
            seen.0.insert(sent);
        }
    }
}

#[test]
fn a_slow_control_module_of_ones_own_misses_no_round() {
    // Built-in control at 20 Hz beacons every tick; wifi at 10 Hz; our own control-phase module
    // reads at 2 Hz. Every beacon a wifi round carried must reach the 2 Hz reader.
    let mut b = SimBuilder::new();
    b.add_plugin(default_plugins);
    b.add_module("slow control", SlowControl, Phase::Control, 2.0);
    b.add_systems(Control, beacon.in_set(SimSystems::Control));
    b.add_systems(SlowControl, read_slowly.in_set(SimSystems::Control));
    b.insert_resource(Seen::default());
    for (id, x) in [(-1, 0.0), (-2, 10.0)] {
        let mut spec = VehicleSpec::new(VehicleId(id), VehicleState::new(DVec2::new(x, 0.0), 0.0, 0.0));
        spec.model = VehicleModel::None;
        b.spawn_vehicle(spec).expect("fresh id");
    }
    let mut sim = b.build();
    sim.run_for(10.0);
    let seen = &sim.world().resource::<Seen>().0;
    // Beacons of 0..9.45 s were carried by rounds up to 9.5 s, read by the tick at 9.5 s: 190.
    let expected: BTreeSet<u64> = (0..190).map(|k| k * 50_000).collect();
    assert_eq!(seen, &expected, "{} of 190 beacons seen", seen.len());
}
