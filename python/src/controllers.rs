//! Python controllers (`Sim.add_controller`) as a system of the [`Control`] schedule: each
//! callback runs inside the Control phase of the tick it is due, after the sensors and V2V
//! rounds of that instant and before the longitudinal pipeline, and the commands it returns
//! drive the dynamics step that starts at that tick, exactly where a Rust controller's do (the
//! controller contract of `smlworld::app`). A Python controller at the control rate therefore
//! behaves like a Rust one, whatever chunks of time the caller steps by.
//!
//! The system takes the GIL (`Python::attach`) only at ticks where a controller is due. A
//! callback's exception, or a command that is not finite, stops the step at that tick
//! ([`Session::step_until`]) and reaches the caller of `Sim.step` as a Python exception.

use std::cell::RefCell;

use bevy_ecs::prelude::{Resource, World};
use bevy_ecs::schedule::IntoScheduleConfigs;
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use smlworld::app::{CommandOverride, Session, SessionError};
use smlworld::sim::{Control, SimClock, SimSystems};
use smlworld::vehicles::{LongitudinalSystems, SteeringSystems};
use smlworld::world::{ControlCommand, SimTime, VehicleId, VehicleState, Vehicles};

/// What the Python side of a controller returns: throttle [N], steering [rad] and speed [m/s]
/// columns, each one value per vehicle or None.
type Commands<'py> =
    (Option<PyReadonlyArray1<'py, f64>>, Option<PyReadonlyArray1<'py, f64>>, Option<PyReadonlyArray1<'py, f64>>);

/// One Python controller: a callable for a batch of vehicles at a rate.
struct PyController {
    /// The vehicles it drives, in the order of its arrays.
    ids: Vec<i32>,
    /// `fn(obs) -> (throttle, steering, speed)`, each a float64 array or None (the Python side
    /// wraps the user's function so that it returns this).
    call: Py<PyAny>,
    /// Name for messages (the user's function).
    name: String,
    /// Rate [Hz].
    rate: f64,
    /// Its next tick: due at `tick / rate`.
    tick: u64,
}

impl PyController {
    /// Due time of tick `k`, rounded to the microsecond as the scheduler rounds its modules'.
    fn due_at(&self, k: u64) -> SimTime {
        SimTime((k as f64 * 1e6 / self.rate).round() as u64)
    }

    /// The observation of its vehicles now: `id, x, y, yaw, vx, vy, time` arrays.
    fn observation<'py>(&self, py: Python<'py>, world: &World, now: SimTime) -> PyResult<Bound<'py, PyDict>> {
        let vehicles = world.resource::<Vehicles>();
        let mut cols: [Vec<f64>; 5] = Default::default();
        for &id in &self.ids {
            let state = vehicles.get(VehicleId(id)).and_then(|e| world.get::<VehicleState>(e)).ok_or_else(|| {
                PyValueError::new_err(format!(
                    "controller {}: vehicle {id} is no longer in the simulation at t = {} s",
                    self.name,
                    now.as_secs()
                ))
            })?;
            for (col, v) in
                cols.iter_mut().zip([state.position.x, state.position.y, state.yaw, state.velocity.x, state.velocity.y])
            {
                col.push(v);
            }
        }
        let obs = PyDict::new(py);
        obs.set_item("id", PyArray1::from_slice(py, &self.ids))?;
        let [x, y, yaw, vx, vy] = cols;
        for (key, col) in [("x", x), ("y", y), ("yaw", yaw), ("vx", vx), ("vy", vy)] {
            obs.set_item(key, PyArray1::from_vec(py, col))?;
        }
        obs.set_item("time", PyArray1::from_vec(py, vec![now.as_secs(); self.ids.len()]))?;
        Ok(obs)
    }

    /// Call it and apply its commands to the world (as `Session::set_commands` does: they stay
    /// until cleared or replaced).
    fn run(&self, py: Python<'_>, world: &mut World, now: SimTime) -> PyResult<()> {
        let obs = self.observation(py, world, now)?;
        let out = self.call.bind(py).call1((obs,))?;
        let (throttle, steering, speed): Commands<'_> = out.extract()?;
        let mut columns: [Option<Vec<f64>>; 3] = [None, None, None];
        for ((name, col), slot) in
            [("throttle", &throttle), ("steering", &steering), ("speed", &speed)].into_iter().zip(&mut columns)
        {
            let Some(col) = col else { continue };
            let values = col.as_array().to_vec();
            if values.len() != self.ids.len() {
                return Err(PyValueError::new_err(format!(
                    "controller {} returned {} {name} values for {} vehicles at t = {} s; return one per id",
                    self.name,
                    values.len(),
                    self.ids.len(),
                    now.as_secs()
                )));
            }
            if let Some(i) = values.iter().position(|v| !v.is_finite()) {
                return Err(PyValueError::new_err(format!(
                    "controller {} returned {name}[{i}] = {} for vehicle {} at t = {} s; commands must be finite",
                    self.name,
                    values[i],
                    self.ids[i],
                    now.as_secs()
                )));
            }
            *slot = Some(values);
        }
        if columns.iter().all(Option::is_none) {
            // Nothing asked: the vehicles keep what they had (no empty override, which would
            // change what they report over V2V).
            return Ok(());
        }
        let [throttle, steering, speed] = columns;
        for (i, &id) in self.ids.iter().enumerate() {
            let entity = world.resource::<Vehicles>().get(VehicleId(id));
            let Some(mut entity) =
                entity.and_then(|e| world.get_entity_mut(e).ok()).filter(|e| e.contains::<ControlCommand>())
            else {
                return Err(PyValueError::new_err(format!("controller {}: vehicle {id} takes no commands", self.name)));
            };
            let mut o = entity.get::<CommandOverride>().copied().unwrap_or_default();
            if let Some(t) = &throttle {
                o.throttle = Some(t[i]);
            }
            if let Some(s) = &steering {
                o.steering = Some(s[i]);
            }
            if let Some(v) = &speed {
                o.speed = Some(v[i]);
            }
            if let Some(mut c) = entity.get_mut::<ControlCommand>() {
                o.apply(&mut c);
            }
            entity.insert(o);
        }
        Ok(())
    }
}

/// The Python controllers of one session, and the first error one of them raised.
#[derive(Resource, Default)]
pub struct PyControllers {
    list: Vec<PyController>,
    error: Option<PyErr>,
}

/// Control-phase system: run every Python controller due now, in the order they were added.
/// After an error no controller runs again (the step stops at this tick).
fn run_python_controllers(world: &mut World) {
    let now = world.resource::<SimClock>().now;
    let Some(mut controllers) = world.remove_resource::<PyControllers>() else { return };
    let due = |c: &PyController| c.due_at(c.tick) <= now;
    if controllers.error.is_none() && controllers.list.iter().any(due) {
        Python::attach(|py| {
            for c in &mut controllers.list {
                if !due(c) {
                    continue;
                }
                if let Err(e) = c.run(py, world, now) {
                    controllers.error = Some(e);
                    return;
                }
                while c.due_at(c.tick) <= now {
                    c.tick += 1;
                }
            }
        });
    }
    world.insert_resource(controllers);
}

/// Add a Python controller to `session`: `call(obs)` for `ids` at `rate` [Hz] from the first
/// tick due at or after the current time. The system joins the Control schedule with the first
/// controller. The rate may not exceed the control rate (a controller runs inside control ticks).
pub fn add(session: &mut Session, ids: Vec<i32>, call: Py<PyAny>, name: String, rate: f64) -> PyResult<()> {
    let control = session.scenario().file.rates.control;
    if !(rate.is_finite() && rate > 0.0) {
        return Err(PyValueError::new_err(format!("rate must be a positive number of Hz, got {rate}")));
    }
    if rate > control * (1.0 + 1e-12) {
        return Err(PyValueError::new_err(format!(
            "rate {rate} Hz is above the scenario's control rate {control} Hz: a Python controller runs inside \
             control ticks, at most once per tick; lower the rate or raise `rates.control` in the scenario"
        )));
    }
    for &id in &ids {
        if session.sim().entity(VehicleId(id)).is_none() {
            let known: Vec<i32> = session.sim().states().iter().map(|(v, _)| v.0).collect();
            return Err(PyValueError::new_err(format!("unknown vehicle id {id}; the scenario has ids {known:?}")));
        }
    }
    let now = session.sim().now();
    let mut c = PyController { ids, call, name, rate, tick: 0 };
    c.tick = (now.0 as f64 * rate / 1e6).floor() as u64;
    while c.due_at(c.tick) < now {
        c.tick += 1;
    }
    while c.tick > 0 && c.due_at(c.tick - 1) >= now {
        c.tick -= 1;
    }
    let sim = session.sim_mut();
    if !sim.world().contains_resource::<PyControllers>() {
        sim.world_mut().insert_resource(PyControllers::default());
        let Some(schedule) = sim.scheduler_mut().schedule_mut(Control) else {
            return Err(PyRuntimeError::new_err("the simulation has no control module"));
        };
        // First in the Control phase: it sees what a Rust controller sees, and its commands are
        // in place before the longitudinal pipeline reports the vehicle's acceleration.
        schedule.add_systems(
            run_python_controllers
                .in_set(SimSystems::Control)
                .before(SteeringSystems)
                .before(LongitudinalSystems::FindLeader),
        );
    }
    sim.world_mut().resource_mut::<PyControllers>().list.push(c);
    Ok(())
}

/// Whether `session` has Python controllers.
pub fn any(session: &Session) -> bool {
    session.sim().world().get_resource::<PyControllers>().is_some_and(|c| !c.list.is_empty())
}

/// Why a step with Python controllers failed.
pub enum StepError {
    /// The session refused the step.
    Session(SessionError),
    /// A controller raised, or returned a bad command.
    Python(PyErr),
}

/// Advance `session` by `dt` [s]; with Python controllers, stop at the tick where one fails
/// and return its error.
pub fn step(session: &mut Session, dt: f64) -> Result<(), StepError> {
    if !any(session) {
        return session.step(dt).map_err(StepError::Session);
    }
    let failed = |w: &World| w.get_resource::<PyControllers>().is_some_and(|c| c.error.is_some());
    let stopped = session.step_until(dt, failed).map_err(StepError::Session)?;
    if stopped && let Some(mut c) = session.sim_mut().world_mut().get_resource_mut::<PyControllers>() {
        // The controller stays: stepping on calls it again at the next control tick.
        if let Some(e) = c.error.take() {
            return Err(StepError::Python(e));
        }
    }
    Ok(())
}

thread_local! {
    /// Addresses of the sessions this thread is stepping now (their locks are held): a call
    /// into one of them from a controller callback would wait for itself.
    static STEPPING: RefCell<Vec<usize>> = const { RefCell::new(Vec::new()) };
}

/// Marks a session as being stepped by this thread until dropped.
pub struct Stepping(usize);

impl Stepping {
    /// Mark the session at `address`.
    pub fn enter(address: usize) -> Stepping {
        STEPPING.with(|s| s.borrow_mut().push(address));
        Stepping(address)
    }

    /// Whether this thread is stepping the session at `address` (so it is inside one of its
    /// controller callbacks).
    pub fn active(address: usize) -> bool {
        STEPPING.with(|s| s.borrow().contains(&address))
    }
}

impl Drop for Stepping {
    fn drop(&mut self) {
        STEPPING.with(|s| {
            let mut s = s.borrow_mut();
            if let Some(i) = s.iter().rposition(|&a| a == self.0) {
                s.remove(i);
            }
        });
    }
}
