//! Vehicles driven by a recorded trajectory (CommonRoad obstacles): their state comes from the
//! recording, as motion capture gives real vehicles theirs; no dynamics model moves them.
//!
//! Each dynamics tick at time t sets the state to the recording at t + dt (the instant the
//! integrated vehicles reach in the same tick), so at every tick time sensors, controllers and
//! logs see the recorded state of that time: exactly a sample at a sample's time, linear
//! interpolation (position; heading along the shorter arc; speed) between samples. Before the
//! first sample the vehicle holds the first one; after the last it stands at the last position.

use std::sync::Arc;

use bevy_ecs::prelude::{Component, Query, Res};
use bevy_ecs::schedule::IntoScheduleConfigs;
use glam::DVec2;

use super::{Dynamics, SimBuilder, SimClock, SimSystems};
use crate::world::VehicleState;

/// One recorded state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RecordedSample {
    /// Time \[s\].
    pub t: f64,
    /// Position \[m\].
    pub position: DVec2,
    /// Heading, counter-clockwise from x \[rad\].
    pub yaw: f64,
    /// Speed along the heading [m/s].
    pub speed: f64,
}

/// A vehicle's recorded trajectory (samples in time order) and a cursor into it.
#[derive(Component, Debug, Clone)]
pub struct RecordedTrajectory {
    samples: Arc<[RecordedSample]>,
    cursor: usize,
}

impl RecordedTrajectory {
    /// A trajectory of `samples` (sorted by time here; at least one).
    pub fn new(mut samples: Vec<RecordedSample>) -> Option<RecordedTrajectory> {
        if samples.is_empty() {
            return None;
        }
        samples.sort_by(|a, b| a.t.total_cmp(&b.t));
        Some(RecordedTrajectory { samples: samples.into(), cursor: 0 })
    }

    /// The recorded state at time `t` \[s\]; moves the cursor (O(1) amortised as time goes on).
    pub fn state_at(&mut self, t: f64) -> VehicleState {
        let s = &self.samples;
        if self.cursor >= s.len() || s[self.cursor].t > t {
            self.cursor = 0;
        }
        while self.cursor + 1 < s.len() && s[self.cursor + 1].t <= t {
            self.cursor += 1;
        }
        let a = s[self.cursor];
        let last = self.cursor + 1 == s.len();
        if t <= a.t && self.cursor == 0 {
            return VehicleState::new(a.position, a.yaw, a.speed);
        }
        if last {
            return VehicleState::new(a.position, a.yaw, if t == a.t { a.speed } else { 0.0 });
        }
        let b = s[self.cursor + 1];
        let f = (t - a.t) / (b.t - a.t);
        let d = (b.yaw - a.yaw + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
        VehicleState::new(a.position.lerp(b.position, f), a.yaw + d * f, a.speed + (b.speed - a.speed) * f)
    }
}

/// Each dynamics tick: every recorded vehicle to its recording at the end of the step.
pub fn play_recorded_trajectories(clock: Res<SimClock>, mut q: Query<(&mut RecordedTrajectory, &mut VehicleState)>) {
    let t = clock.now.as_secs() + clock.dt;
    for (mut rec, mut state) in &mut q {
        *state = rec.state_at(t);
    }
}

/// Plays [`RecordedTrajectory`]s in the dynamics module ([`SimSystems::Integrate`]).
pub fn recorded_trajectories(sim: &mut SimBuilder) {
    sim.add_systems(Dynamics, play_recorded_trajectories.in_set(SimSystems::Integrate));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn samples_are_exact_and_between_them_interpolated() {
        let sample = |t: f64, x: f64| RecordedSample { t, position: DVec2::new(x, 0.0), yaw: 0.0, speed: 10.0 };
        let mut rec = RecordedTrajectory::new(vec![sample(0.0, 0.0), sample(0.1, 1.0), sample(0.2, 2.5)])
            .expect("three increasing samples make a trajectory");
        assert_eq!(rec.state_at(0.1).position, DVec2::new(1.0, 0.0));
        assert!((rec.state_at(0.15).position.x - 1.75).abs() < 1e-12);
        assert_eq!(rec.state_at(0.2).speed(), 10.0);
        // After the end it stands still at the last position; before the start it waits at the first.
        let end = rec.state_at(5.0);
        assert_eq!((end.position.x, end.speed()), (2.5, 0.0));
        assert_eq!(rec.state_at(-1.0).position.x, 0.0);
    }
}
