//! Scenarios, runners and run outputs: everything that wires the layers below into a run.
//! Two rooms: [`running`] (scenario files, runners, sessions, metrics, traffic, benchmarks and
//! the run's summary) and [`results`] (the trajectory log, replay and plots, which read what a
//! run left); [`run_scenario`] sits above both and wires them for `smlworld run`.
//! [`crate::sim::Plugin`], [`crate::sim::SimBuilder`] and [`crate::sim::Sim`] live in [`crate::sim`];
//! each item has one path.
//!
//! # Running a scenario from your own program
//! [`run_scenario`] does what `smlworld run` does (trajectories, summary with metrics, optional
//! frames, GIF and stream); your plugins go into [`RunOptions::plugins`], and controllers they
//! register ([`crate::sim::SimBuilder::register_controller`]) can be named in the scenario like built-in
//! ones. `examples/student_controller.rs` is a complete program to copy.
//!
//! # The controller contract
//! A controller is a plugin that adds systems to the [`crate::sim::Control`] schedule in the
//! [`crate::sim::SimSystems::Control`] set. Each control tick (20 Hz by default) such a system
//! reads, per vehicle, [`crate::world::VehicleState`], [`crate::world::SensorReadings`] (filled
//! by the last sensor tick), the in-boxes of its [`crate::world::Mailbox`] (every V2V round
//! since the previous control tick) and its [`crate::world::Route`], plus
//! [`crate::sim::SimClock`] for the time and step; it writes the vehicle's
//! [`crate::world::ControlCommand`] (read by the dynamics until the next control tick) and
//! queues messages with [`crate::world::Mailbox::send`] (they leave at the channel's next round).
//! Per-vehicle controller state lives in a component of the controller's own (see
//! [`crate::vehicles::PathFollower`]). Controllers must not write `VehicleState`: the dynamics
//! (or, for real vehicles, a bridge) own it.
//!
//! A speed controller does not write the command itself: it writes the acceleration it wants
//! into [`crate::vehicles::Longitudinal::accel`] from a system in
//! [`crate::vehicles::LongitudinalSystems::Demand`]; the pipeline then applies limiters
//! (intersections, emergency braking) and turns the demand into a throttle (acceleration model)
//! or a speed (kinematic model), so the same controller brakes on both models (see
//! [`crate::vehicles::longitudinal`]). Writing `ControlCommand::speed` directly does nothing on
//! the acceleration model, whose dynamics read the throttle.
//!
//! At one instant modules run in the order sense -> communicate -> control -> dynamics, so a
//! controller at time t sees sensor readings and messages of time t, and its command drives the
//! dynamics step that starts at t.

pub mod progress;
pub mod results;
mod run;
pub mod running;

pub use results::output::{Log, TrajectoryLog, TrajectoryLogPlugin, log_trajectories};
pub use results::plot::{FIGURE_SIZE, MAX_LEGEND, PALETTE, Pen, pen, plot_compare, plot_run};
pub use results::replay::{
    ReplayError, ReplayMarks, ReplayOptions, ReplayReport, read_replay_info, read_replay_marks, replay_run,
};
pub use run::{RunError, RunOptions, ScenarioSource, run_scenario};
pub use running::runner::{RealtimeRunner, RunReport, run_headless};
pub use running::scenario::{Scenario, ScenarioError};
pub use running::session::{CommandOverride, LightState, Session, SessionError, StateColumns};
pub use running::summary::{MessagesDelivered, ReplayInfo, ReplayVehicle, RunSummary};
