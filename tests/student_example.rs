//! The student example (`examples/student_controller.rs`) runs and does what it says: both
//! careful cars stop behind the parked one without touching, keeping their standstill distance,
//! and hear each other over wifi.

#[path = "../examples/student_controller.rs"]
mod student;

use smlworld::prelude::*;

#[test]
fn student_example_main_runs() {
    student::main();
}

#[test]
fn careful_cars_queue_behind_the_parked_car_and_hear_each_other() {
    let mut sim = student::demo();
    let careful =
        |sim: &Sim, id: i32| *sim.world().get::<student::Careful>(sim.entity(VehicleId(id)).unwrap()).unwrap();
    sim.run_for(5.0);
    // 100 m apart at the start, beyond the wifi range of 50 m.
    assert_eq!(careful(&sim, -2).heard, 0);
    sim.run_for(115.0);
    let x = |id: i32| sim.state(VehicleId(id)).unwrap().position.x;
    let v = |id: i32| sim.state(VehicleId(id)).unwrap().speed();
    assert!(v(-2).abs() < 1e-6 && v(-3).abs() < 1e-6, "both stopped: {} and {} m/s", v(-2), v(-3));
    // Stopped where the room ahead is zero: the standstill distance (8 m) centre to centre.
    assert!((x(-1) - x(-2) - 8.0).abs() < 0.5, "-2 stopped at {} m, 8 m behind the parked car at 300 m", x(-2));
    assert!((x(-2) - x(-3) - 8.0).abs() < 0.5, "-3 stopped at {} m, 8 m behind -2", x(-3));
    // 8 m apart now: each hears the other's report (the parked car sends nothing).
    assert!(careful(&sim, -2).heard >= 1 && careful(&sim, -3).heard >= 1);
}
