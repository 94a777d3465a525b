//! Dynamics: pure step functions of the two unicycle models and the thin systems that call them.
//!
//! Both models move the vehicle along an arc of constant curvature κ = tan φ / L during a step
//! (φ held by the controller for the whole step), integrated exactly: a constant command gives
//! an exact circle of radius L / tan φ whatever the step. The acceleration model's speed follows
//! the exact solution of v̇ = (u − c v) / m over the step and stops at zero when braking.

use bevy_ecs::prelude::{Component, Local, Query, Res};
use glam::DVec2;

use super::{Plugin, SimBuilder};
use crate::world::{AccelerationUnicycle, ControlCommand, KinematicUnicycle, VehicleState};

use bevy_ecs::schedule::IntoScheduleConfigs;

use super::grid::{Pass, vectorised};
use super::trig::{is_small, sin_cos_polynomial, small_sin_cos, small_tan, tan_polynomial};
use super::{Dynamics, Parallelism, SimClock, SimSystems};
use crate::map::path::{LANES, groups_of_four, per_lane};

/// Wrap an angle to (−π, π] [rad].
fn wrap_angle(a: f64) -> f64 {
    use std::f64::consts::{PI, TAU};
    let x = a + PI;
    // `rem_euclid` is a library `fmod` call (a few percent of a benchmark's dynamics); on
    // [0, 2π) it returns x itself, so the common case skips it with the same bits.
    let w = if (0.0..TAU).contains(&x) { x - PI } else { x.rem_euclid(TAU) - PI };
    if w == -PI { PI } else { w }
}

/// Move `state` a distance `distance` [m] along an arc of curvature `curvature` [1/m] starting
/// at its heading, whose unit vector is `facing` (cos, sin), and set its velocity to `end_speed`
/// [m/s] along the new heading. The new heading's sine and cosine come from the old ones by the
/// angle-sum formulas and are remembered with the new yaw ([`VehicleState::turn_to`]), so a
/// step takes no `sin_cos` of the yaw. (sin(yaw + 2π k) and sin(yaw) agree to rounding, so
/// wrapping the yaw first is harmless.)
fn advance_arc(state: &mut VehicleState, distance: f64, curvature: f64, end_speed: f64, facing: DVec2) {
    let (s0, c0) = (facing.y, facing.x);
    let turn = curvature * distance;
    if turn.abs() > 1e-12 {
        let yaw1 = wrap_angle(state.yaw + turn);
        let (st, ct) = small_sin_cos(turn);
        let (s1, c1) = (s0 * ct + c0 * st, c0 * ct - s0 * st);
        state.position.x += (s1 - s0) / curvature;
        state.position.y += (c0 - c1) / curvature;
        state.turn_to(yaw1, DVec2::new(c1, s1));
        state.velocity = DVec2::new(c1, s1) * end_speed;
    } else {
        state.position += DVec2::new(c0, s0) * distance;
        state.velocity = DVec2::new(c0, s0) * end_speed;
    }
}

/// One step of the kinematic unicycle over `dt` \[s\]: drive at the commanded speed with the
/// commanded steering (clamped to ±`max_steering`).
pub fn step_kinematic_unicycle(
    state: &mut VehicleState,
    command: &ControlCommand,
    params: &KinematicUnicycle,
    dt: f64,
) {
    let steering = command.steering.max(-params.max_steering).min(params.max_steering); // total: clamp panics on NaN bounds
    let curvature = small_tan(steering) / params.wheelbase;
    advance_arc(state, command.speed * dt, curvature, command.speed, state.heading());
}

/// [`step_kinematic_unicycle`] for four vehicles at once, when all four take its common paths: a
/// steering small enough for the polynomials ([`is_small`]), and either a turn at or under the
/// straight-line threshold (a straight step) or one small enough for the polynomials with a new
/// yaw inside (−π, π] after one addition and subtraction of π (no `fmod`). Then it writes what
/// the one-at-a-time step writes, bit for bit (the same operations in the same order, lane by
/// lane), and returns true; else it writes nothing.
///
/// Straight steps are most steps on a road drawn as straight lines between nodes (the
/// benchmark's ring: pure pursuit on a chord steers by about 1e-13 rad): while they took the
/// one-at-a-time path, every group of four fell back to it.
///
/// A step is a chain of about ten divisions (the polynomials divide by their constants, the
/// arc by the curvature): one at a time it waits on the divider (about 16 ns a step on the
/// benchmark machine, a step at 50 Hz for every vehicle); in vector code four vehicles share
/// each division.
#[inline(always)]
fn step_kinematic_four(
    states: &mut [VehicleState],
    commands: &[ControlCommand],
    models: &[KinematicUnicycle],
    dt: f64,
) -> bool {
    use std::f64::consts::{PI, TAU};
    let (states, commands, models): (
        &mut [VehicleState; LANES],
        &[ControlCommand; LANES],
        &[KinematicUnicycle; LANES],
    ) = match (states.try_into(), commands.try_into(), models.try_into()) {
        (Ok(s), Ok(c), Ok(m)) => (s, c, m),
        _ => return false,
    };
    let facing: [DVec2; LANES] = per_lane(|l| states[l].heading());
    let mut common = [true; LANES];
    let (mut x, mut y, mut yaw, mut c1s, mut s1s, mut speeds) =
        ([0.0; LANES], [0.0; LANES], [0.0; LANES], [0.0; LANES], [0.0; LANES], [0.0; LANES]);
    let (mut arc, mut straight_x, mut straight_y) = ([true; LANES], [0.0; LANES], [0.0; LANES]);
    for l in 0..LANES {
        let (command, params, state) = (&commands[l], &models[l], &states[l]);
        // `step_kinematic_unicycle`, then `advance_arc` and `wrap_angle` on their common path.
        let steering = command.steering.max(-params.max_steering).min(params.max_steering);
        let curvature = tan_polynomial(steering) / params.wheelbase;
        let distance = command.speed * dt;
        let (s0, c0) = (facing[l].y, facing[l].x);
        let turn = curvature * distance;
        let wrapped = state.yaw + turn + PI;
        let w = wrapped - PI;
        let (st, ct) = sin_cos_polynomial(turn);
        let (s1, c1) = (s0 * ct + c0 * st, c0 * ct - s0 * st);
        x[l] = state.position.x + (s1 - s0) / curvature;
        y[l] = state.position.y + (c0 - c1) / curvature;
        yaw[l] = if w == -PI { PI } else { w };
        (c1s[l], s1s[l], speeds[l]) = (c1, s1, command.speed);
        // `advance_arc`'s straight line: along the old heading, which stays.
        arc[l] = turn.abs() > 1e-12;
        (straight_x[l], straight_y[l]) = (state.position.x + c0 * distance, state.position.y + s0 * distance);
        common[l] = is_small(steering) & (!arc[l] | (is_small(turn) & (0.0..TAU).contains(&wrapped)));
    }
    if common != [true; LANES] {
        return false;
    }
    for l in 0..LANES {
        let state = &mut states[l];
        if arc[l] {
            state.position = DVec2::new(x[l], y[l]);
            let facing = DVec2::new(c1s[l], s1s[l]);
            state.turn_to(yaw[l], facing);
            state.velocity = facing * speeds[l];
        } else {
            state.position = DVec2::new(straight_x[l], straight_y[l]);
            state.velocity = facing[l] * speeds[l];
        }
    }
    true
}

/// Kinematic unicycle steps of a chunk of vehicles as a [`Pass`] (vector code where the
/// processor has it): four at a time where [`step_kinematic_four`] can, else one at a time.
struct KinematicChunk<'a> {
    states: &'a mut [VehicleState],
    commands: &'a [ControlCommand],
    models: &'a [KinematicUnicycle],
    dt: f64,
}

impl Pass for KinematicChunk<'_> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        let KinematicChunk { states, commands, models, dt } = self;
        let n = states.len().min(commands.len()).min(models.len());
        for r in groups_of_four(n) {
            let (states, commands, models) = (&mut states[r.clone()], &commands[r.clone()], &models[r]);
            if !step_kinematic_four(states, commands, models, dt) {
                for ((state, command), model) in states.iter_mut().zip(commands).zip(models) {
                    step_kinematic_unicycle(state, command, model, dt);
                }
            }
        }
    }
}

/// One step of the acceleration unicycle over `dt` \[s\]: v̇ = (throttle − c v) / m, solved
/// exactly over the step; a negative throttle brakes to zero speed and stays there (the model
/// never reverses, and a negative starting speed counts as zero).
pub fn step_acceleration_unicycle(
    state: &mut VehicleState,
    command: &ControlCommand,
    params: &AccelerationUnicycle,
    dt: f64,
) {
    let steering = command.steering.max(-params.max_steering).min(params.max_steering); // total: clamp panics on NaN bounds
    let curvature = small_tan(steering) / params.wheelbase;
    let (u, m, c) = (command.throttle, params.mass, params.drag);
    // The heading serves the starting speed (`state.speed()`) and the arc.
    let facing = state.heading();
    let v0 = state.velocity.dot(facing).max(0.0);
    // Time until the speed reaches zero if it does within the step, else the whole step.
    let (v1, moving_time) = if c > 0.0 {
        let tau = m / c;
        let v_inf = u / c;
        let v1 = v_inf + (v0 - v_inf) * (-dt / tau).exp();
        if v1 < 0.0 {
            // v(t) = 0 at t0 = τ ln((v0 − v∞) / (−v∞)), v∞ < 0 here.
            (0.0, tau * ((v0 - v_inf) / -v_inf).ln())
        } else {
            (v1, dt)
        }
    } else {
        let a = u / m;
        let v1 = v0 + a * dt;
        if v1 < 0.0 { (0.0, v0 / -a) } else { (v1, dt) }
    };
    let distance = if c > 0.0 {
        let tau = m / c;
        let v_inf = u / c;
        v_inf * moving_time + (v0 - v_inf) * tau * (1.0 - (-moving_time / tau).exp())
    } else {
        v0 * moving_time + 0.5 * (u / m) * moving_time * moving_time
    };
    advance_arc(state, distance.max(0.0), curvature, v1, facing);
}

/// Step every vehicle of `vehicles` (a query of state, command and model) with `step`, which
/// steps the vehicles of equally long slices of states, commands and models: table by table,
/// each table's slices cut into contiguous chunks over [`Parallelism::threads`] threads (each
/// vehicle's step reads only itself). The slices come straight from the ECS tables (bevy's
/// contiguous access): no list of the query's items is gathered first, which on one thread
/// took about as long as the steps themselves.
fn integrate<M: Component + Sync>(
    vehicles: &mut Query<(&mut VehicleState, &ControlCommand, &M)>,
    parallelism: &Parallelism,
    scratch: &mut Vec<()>,
    step: impl Fn(&mut [VehicleState], &[ControlCommand], &[M]) + Sync,
) {
    if let Ok(tables) = vehicles.contiguous_iter_mut() {
        for (mut states, commands, models) in tables {
            parallelism.for_each_chunk_at(&mut states, scratch, |start, chunk, _| {
                let end = start + chunk.len();
                step(chunk, &commands[start..end], &models[start..end]);
            });
        }
        return;
    }
    // Only if a component were stored sparsely (none is): one by one.
    for (mut state, command, model) in vehicles.iter_mut() {
        step(std::slice::from_mut(&mut *state), std::slice::from_ref(command), std::slice::from_ref(model));
    }
}

/// Integrate every vehicle with a [`KinematicUnicycle`] over the dynamics step (`integrate`),
/// four at a time where they can (`KinematicChunk`).
pub fn integrate_kinematic_unicycles(
    clock: Res<SimClock>,
    parallelism: Res<Parallelism>,
    mut vehicles: Query<(&mut VehicleState, &ControlCommand, &KinematicUnicycle)>,
    mut scratch: Local<Vec<()>>,
) {
    let dt = clock.dt;
    integrate(&mut vehicles, &parallelism, &mut scratch, |states, commands, models| {
        vectorised(KinematicChunk { states, commands, models, dt })
    });
}

/// Integrate every vehicle with an [`AccelerationUnicycle`] over the dynamics step
/// (`integrate`).
pub fn integrate_acceleration_unicycles(
    clock: Res<SimClock>,
    parallelism: Res<Parallelism>,
    mut vehicles: Query<(&mut VehicleState, &ControlCommand, &AccelerationUnicycle)>,
    mut scratch: Local<Vec<()>>,
) {
    let dt = clock.dt;
    integrate(&mut vehicles, &parallelism, &mut scratch, |states, commands, models| {
        for ((state, command), model) in states.iter_mut().zip(commands).zip(models) {
            step_acceleration_unicycle(state, command, model, dt);
        }
    });
}

/// Both unicycle models in the [`Dynamics`] schedule. Vehicles without a model component (real
/// vehicles, whose state a bridge writes) are left alone.
#[derive(Debug, Clone, Copy, Default)]
pub struct DynamicsPlugin;

impl Plugin for DynamicsPlugin {
    fn build(&self, sim: &mut SimBuilder) {
        sim.world_mut().init_resource::<Parallelism>();
        sim.add_systems(
            Dynamics,
            (integrate_kinematic_unicycles, integrate_acceleration_unicycles).in_set(SimSystems::Integrate),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::{PI, TAU};

    #[test]
    fn four_kinematic_steps_at_once_give_the_bits_of_four_one_at_a_time() {
        // Common cases (gentle steering, headings all round, some near ±π so that the turn
        // wraps) and the ones the four-wide step must leave to the one-at-a-time step (large
        // steering, a straight line, NaN, a stale heading), mixed into groups of four.
        let mut next = crate::world::random::draws(0x9e37_79b9_7f4a_7c15);
        let (mut states, mut commands, mut models) = (Vec::new(), Vec::new(), Vec::new());
        for k in 0..4003 {
            let yaw = match k % 9 {
                0 => PI - 1e-7 * next(),
                1 => -PI + 1e-7 * next(),
                _ => (next() - 0.5) * TAU,
            };
            // Far out and near the origin (where each step's displacement keeps all its bits).
            let scale = if k % 2 == 0 { 1e4 } else { 1e-3 };
            let mut state = VehicleState::new(DVec2::new(next() * scale, -next() * scale), yaw, 20.0 * next());
            if k % 31 == 0 {
                state.yaw += 1e-3; // the remembered heading no longer belongs to the yaw
            }
            let steering = match k % 23 {
                0 => 0.3 * next(),
                1 => 0.0,
                2 => f64::NAN,
                _ => (next() - 0.5) * 2e-3,
            };
            states.push(state);
            commands.push(ControlCommand { steering, speed: 30.0 * next(), ..Default::default() });
            models.push(KinematicUnicycle { wheelbase: 2.5 + next(), max_steering: 0.5 });
        }
        let dt = 0.02;
        let mut one_at_a_time = states.clone();
        for ((state, command), model) in one_at_a_time.iter_mut().zip(&commands).zip(&models) {
            step_kinematic_unicycle(state, command, model, dt);
        }
        let bits = |states: &[VehicleState]| -> Vec<[u64; 6]> {
            states
                .iter()
                .map(|s| {
                    let h = s.heading();
                    [s.position.x, s.position.y, s.yaw, s.velocity.x, s.velocity.y, h.x + h.y].map(f64::to_bits)
                })
                .collect()
        };
        let mut plain = states.clone();
        KinematicChunk { states: &mut plain, commands: &commands, models: &models, dt }.run();
        assert_eq!(bits(&plain), bits(&one_at_a_time));
        let mut four = states.clone();
        vectorised(KinematicChunk { states: &mut four, commands: &commands, models: &models, dt });
        assert_eq!(bits(&four), bits(&one_at_a_time));
        // The groups of four did take the four-wide path (else this compared nothing new).
        let taken = (0..states.len() / LANES)
            .filter(|g| {
                let r = g * LANES..(g + 1) * LANES;
                step_kinematic_four(&mut states[r.clone()].to_vec(), &commands[r.clone()], &models[r], dt)
            })
            .count();
        assert!(taken > states.len() / LANES / 4, "{taken} groups of four stepped at once");

        // Straight steps (a steering of 1e-13 rad turns by less than the threshold; pure
        // pursuit along a straight line steers so), also with a stale heading and mixed with
        // turning ones: four at once, with the one-at-a-time step's bits.
        let steerings: Vec<f64> = vec![1e-13, -3e-13, 0.0, 2e-13, 1e-13, 1e-3, -2e-13, 5e-4];
        let mut states: Vec<VehicleState> = (0..8)
            .map(|k| VehicleState::new(DVec2::new(1e4 + f64::from(k), -5e3), 0.3 * f64::from(k) - 1.0, 20.0))
            .collect();
        states[2].yaw += 1e-3;
        let commands: Vec<ControlCommand> =
            steerings.iter().map(|&steering| ControlCommand { steering, speed: 25.0, ..Default::default() }).collect();
        let models = vec![KinematicUnicycle { wheelbase: 2.8, max_steering: 0.5 }; 8];
        let mut one_at_a_time = states.clone();
        for ((state, command), model) in one_at_a_time.iter_mut().zip(&commands).zip(&models) {
            step_kinematic_unicycle(state, command, model, dt);
        }
        let mut four = states.clone();
        for r in [0..4, 4..8] {
            assert!(step_kinematic_four(&mut four[r.clone()], &commands[r.clone()], &models[r], dt));
        }
        assert_eq!(bits(&four), bits(&one_at_a_time));
    }

    /// The wrap as it was: `rem_euclid` whatever the angle.
    fn wrap_by_rem_euclid(a: f64) -> f64 {
        let w = (a + PI).rem_euclid(TAU) - PI;
        if w == -PI { PI } else { w }
    }

    #[test]
    fn the_wrap_gives_the_bits_rem_euclid_gave_in_range_at_the_edges_and_beyond() {
        let mut angles = vec![0.0, -0.0, PI, -PI, TAU, -TAU, 3.0 * PI, -3.0 * PI, 1e-300, -1e-300, f64::NAN];
        angles.extend([PI, -PI, TAU - PI].iter().flat_map(|&a| [a.next_up(), a.next_down()]));
        angles.extend((-2000..=2000).map(|k| f64::from(k) * 0.00731));
        for a in angles {
            let (got, was) = (wrap_angle(a), wrap_by_rem_euclid(a));
            assert!(got.to_bits() == was.to_bits() || (got.is_nan() && was.is_nan()), "{a}: {got} against {was}");
            assert!(got.is_nan() || (-PI < got && got <= PI), "{a} wraps to {got}");
        }
    }
}
