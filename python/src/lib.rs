//! The `smlworld._smlworld` extension: thin PyO3 wrappers over [`smlworld::app::Session`],
//! [`smlworld::app::run_scenario`] and [`smlworld::map::LaneletMap`]. Arrays go in and out as
//! numpy arrays, the GIL is released while Rust runs, and every Rust error becomes a Python
//! exception carrying its message (file, line, key or id).

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1};
use pyo3::exceptions::{PyFileNotFoundError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList};

use smlworld::app::running::session::load_scenario_with_overrides;
use smlworld::app::{RunError, RunOptions, ScenarioError, Session, SessionError, StateColumns, run_scenario};
use smlworld::map::{LaneletMap, MapError, Place, RouteOptions};

mod controllers;
mod kinematics;
mod vec;

fn scenario_err(e: ScenarioError) -> PyErr {
    match &e {
        ScenarioError::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
            PyFileNotFoundError::new_err(e.to_string())
        }
        ScenarioError::Map { source, .. } if matches!(**source, MapError::Io { .. }) => {
            PyFileNotFoundError::new_err(e.to_string())
        }
        _ => PyValueError::new_err(e.to_string()),
    }
}

fn session_err(e: SessionError) -> PyErr {
    match e {
        SessionError::Scenario(e) => scenario_err(e),
        SessionError::Argument(m) => PyValueError::new_err(m),
    }
}

fn run_err(e: RunError) -> PyErr {
    match e {
        RunError::Scenario(e) => scenario_err(e),
        RunError::Option(m) => PyValueError::new_err(m),
        e => PyRuntimeError::new_err(e.to_string()),
    }
}

/// Python value -> TOML value for an override (bool, int, float, str, list).
fn to_toml(key: &str, v: &Bound<'_, PyAny>) -> PyResult<toml::Value> {
    if let Ok(b) = v.extract::<bool>() {
        return Ok(toml::Value::Boolean(b));
    }
    if let Ok(i) = v.extract::<i64>() {
        return Ok(toml::Value::Integer(i));
    }
    if let Ok(f) = v.extract::<f64>() {
        return Ok(toml::Value::Float(f));
    }
    if let Ok(s) = v.extract::<String>() {
        return Ok(toml::Value::String(s));
    }
    if let Ok(l) = v.cast::<PyList>() {
        return l.iter().map(|x| to_toml(key, &x)).collect::<PyResult<Vec<_>>>().map(toml::Value::Array);
    }
    Err(PyValueError::new_err(format!(
        "override `{key}`: a value must be a bool, int, float, str or list, got {}",
        v.get_type().name()?
    )))
}

fn overrides(kwargs: Option<&Bound<'_, PyDict>>) -> PyResult<Vec<(String, toml::Value)>> {
    let mut out = Vec::new();
    if let Some(kw) = kwargs {
        for (k, v) in kw.iter() {
            let key: String = k.extract()?;
            let value = to_toml(&key, &v)?;
            out.push((key, value));
        }
    }
    Ok(out)
}

fn json_to_py<'py>(py: Python<'py>, text: &str) -> PyResult<Bound<'py, PyAny>> {
    py.import("json")?.call_method1("loads", (text,))
}

fn column<'py>(py: Python<'py>, v: &[f64]) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_slice(py, v)
}

/// A scenario's simulation, stepped from Python (see `smlworld.Sim`).
#[pyclass(module = "smlworld._smlworld")]
struct Core {
    session: Mutex<Session>,
    states: Mutex<StateColumns>,
    /// `stop_metrics` was called: a restarted session records none either.
    metrics_stopped: AtomicBool,
}

impl Core {
    fn lock(&self) -> std::sync::MutexGuard<'_, Session> {
        self.session.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn address(&self) -> usize {
        &self.session as *const Mutex<Session> as usize
    }

    /// The session, for a call from Python: an error inside one of its own controller callbacks
    /// (the step holds the lock), and waiting for a step on another thread without the GIL
    /// (that step's callbacks need it).
    fn session(&self, py: Python<'_>) -> PyResult<std::sync::MutexGuard<'_, Session>> {
        if controllers::Stepping::active(self.address()) {
            return Err(PyRuntimeError::new_err(
                "this Sim is stepping: a controller callback cannot call its own Sim (it gets its observation \
                 and returns commands; read or send anything else between steps)",
            ));
        }
        loop {
            match self.session.try_lock() {
                Ok(s) => return Ok(s),
                Err(std::sync::TryLockError::Poisoned(p)) => return Ok(p.into_inner()),
                Err(std::sync::TryLockError::WouldBlock) => py.detach(|| drop(self.lock())),
            }
        }
    }

    /// Step with the Python controllers inside the Control phase (see `controllers`).
    fn step_session(&self, py: Python<'_>, session: &mut Session, dt: f64) -> PyResult<()> {
        let _stepping = controllers::Stepping::enter(self.address());
        py.detach(|| controllers::step(session, dt)).map_err(|e| match e {
            controllers::StepError::Session(e) => session_err(e),
            controllers::StepError::Python(e) => e,
        })
    }
}

/// A kinematics observation as Python gets it: the (1 + nearest, 5) rows, the speed [m/s] of the
/// observed vehicle and whether another vehicle's centre lies inside its footprint.
type Observation<'py> = (Bound<'py, PyArray2<f64>>, f64, bool);

fn observation<'py>(py: Python<'py>, k: kinematics::Kinematics) -> PyResult<Observation<'py>> {
    let n = k.rows.len();
    let flat: Vec<f64> = k.rows.into_iter().flatten().collect();
    Ok((PyArray1::from_vec(py, flat).reshape([n, 5])?, k.speed, k.collided))
}

/// A lane-change side as the session names it: checked before the GIL is released.
fn side_name(side: Option<&str>) -> PyResult<Option<&'static str>> {
    match side {
        None => Ok(None),
        Some("left") => Ok(Some("left")),
        Some("right") => Ok(Some("right")),
        Some(other) => Err(PyValueError::new_err(format!("side must be \"left\" or \"right\", got {other:?}"))),
    }
}

fn slice<'a>(a: &'a Option<PyReadonlyArray1<'_, f64>>, name: &str) -> PyResult<Option<&'a [f64]>> {
    match a {
        Some(a) => a
            .as_slice()
            .map(Some)
            .map_err(|_| PyValueError::new_err(format!("{name} must be a contiguous 1-d float array"))),
        None => Ok(None),
    }
}

#[pymethods]
impl Core {
    #[staticmethod]
    #[pyo3(signature = (path, seed=None, **kwargs))]
    fn from_scenario(
        py: Python<'_>,
        path: PathBuf,
        seed: Option<u64>,
        kwargs: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Core> {
        let ov = overrides(kwargs)?;
        let session = py.detach(|| Session::from_scenario(&path, seed, &ov)).map_err(session_err)?;
        Ok(Core {
            session: Mutex::new(session),
            states: Mutex::new(StateColumns::default()),
            metrics_stopped: AtomicBool::new(false),
        })
    }

    #[getter]
    fn time(&self, py: Python<'_>) -> PyResult<f64> {
        Ok(self.session(py)?.time())
    }

    /// The seed of the run [-].
    #[getter]
    fn seed(&self, py: Python<'_>) -> PyResult<u64> {
        Ok(self.session(py)?.scenario().file.seed)
    }

    /// Start over at time 0 from the scenario as loaded (its overrides included) with `seed`:
    /// the session `from_scenario(path, seed, **overrides)` gives, without reading the scenario
    /// file or the map again. Commands, in-boxes and recorded metrics start empty; metrics stay
    /// off after `stop_metrics`.
    fn restart(&self, py: Python<'_>, seed: u64) -> PyResult<()> {
        if i64::try_from(seed).is_err() {
            return Err(PyValueError::new_err(format!("seed must be < 2^63, got {seed}")));
        }
        let mut scenario = self.session(py)?.scenario().clone();
        scenario.file.seed = seed;
        let stop = self.metrics_stopped.load(Ordering::Relaxed);
        // Built without the GIL and without holding the lock (a thread waiting for the lock with
        // the GIL would otherwise keep this one from taking the GIL back).
        let fresh = py
            .detach(|| {
                let mut fresh = Session::new(scenario)?;
                if stop {
                    fresh.stop_metrics();
                }
                Ok(fresh)
            })
            .map_err(session_err)?;
        *self.session(py)? = fresh;
        Ok(())
    }

    /// Stop recording the summary's metrics (see `Session::stop_metrics`).
    fn stop_metrics(&self, py: Python<'_>) -> PyResult<()> {
        self.session(py)?.stop_metrics();
        self.metrics_stopped.store(true, Ordering::Relaxed);
        Ok(())
    }

    /// Kinematics of vehicle `id` and of its `nearest` nearest vehicles (see
    /// `kinematics::Kinematics`), with the collision check of a `footprint` = (length, width) [m]
    /// box around it.
    fn kinematics<'py>(
        &self,
        py: Python<'py>,
        id: i32,
        nearest: usize,
        footprint: (f64, f64),
    ) -> PyResult<Observation<'py>> {
        let k = kinematics::observe(&*self.session(py)?, id, nearest, footprint).map_err(session_err)?;
        observation(py, k)
    }

    /// One environment step in one call: ask vehicle `id` for a lane change to `change`
    /// ("left", "right" or None; refused quietly as `change_lane` is), set its throttle [N]
    /// (as `set_commands` does), advance `dt` [s], then return `kinematics(id, nearest,
    /// footprint)`.
    #[pyo3(signature = (id, throttle, change, dt, nearest, footprint))]
    #[allow(clippy::too_many_arguments)] // the Python signature's six, plus self and the GIL token
    fn drive<'py>(
        &self,
        py: Python<'py>,
        id: i32,
        throttle: f64,
        change: Option<&str>,
        dt: f64,
        nearest: usize,
        footprint: (f64, f64),
    ) -> PyResult<Observation<'py>> {
        let change = side_name(change)?;
        // Checked before anything changes (set_commands and step would check them after the
        // lane-change request).
        if !throttle.is_finite() {
            return Err(PyValueError::new_err(format!("throttle is {throttle}; commands must be finite")));
        }
        if !(dt.is_finite() && dt >= 0.0) {
            return Err(PyValueError::new_err(format!("dt must be a finite number of seconds >= 0, got {dt}")));
        }
        let mut s = self.session(py)?;
        kinematics::command(&mut s, id, throttle, change).map_err(session_err)?;
        self.step_session(py, &mut s, dt)?;
        let k = kinematics::observe(&s, id, nearest, footprint).map_err(session_err)?;
        observation(py, k)
    }

    /// Advance `dt` [s]; Python controllers run inside the control ticks on the way.
    fn step(&self, py: Python<'_>, dt: f64) -> PyResult<()> {
        let mut s = self.session(py)?;
        self.step_session(py, &mut s, dt)
    }

    fn run<'py>(&self, py: Python<'py>, duration: f64) -> PyResult<Bound<'py, PyAny>> {
        let mut s = self.session(py)?;
        self.step_session(py, &mut s, duration)?;
        let summary = s.summary();
        let text = serde_json_string(&summary)?;
        json_to_py(py, &text)
    }

    fn summary<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let summary = self.session(py)?.summary();
        json_to_py(py, &serde_json_string(&summary)?)
    }

    fn states<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let mut cols = self.states.lock().unwrap_or_else(|p| p.into_inner());
        self.session(py)?.states_into(&mut cols);
        let d = PyDict::new(py);
        d.set_item("id", PyArray1::from_slice(py, &cols.id))?;
        d.set_item("x", column(py, &cols.x))?;
        d.set_item("y", column(py, &cols.y))?;
        d.set_item("yaw", column(py, &cols.yaw))?;
        d.set_item("vx", column(py, &cols.vx))?;
        d.set_item("vy", column(py, &cols.vy))?;
        d.set_item("lanelet", column(py, &cols.lanelet))?;
        d.set_item("lane_offset", column(py, &cols.lane_offset))?;
        Ok(d)
    }

    /// Ask vehicle `id` to change lanes, `side` = "left" or "right": False when the map or the
    /// gap forbids it now (see `Session::change_lane`).
    fn change_lane(&self, py: Python<'_>, id: i32, side: &str) -> PyResult<bool> {
        self.session(py)?.change_lane(id, side).map_err(session_err)
    }

    fn readings<'py>(&self, py: Python<'py>, id: i32) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let rows = self.session(py)?.readings(id).map_err(session_err)?;
        let flat: Vec<f64> = rows.iter().flatten().copied().collect();
        let a = PyArray1::from_vec(py, flat);
        a.reshape([rows.len(), 5])
    }

    fn reading_sensors(&self, py: Python<'_>, id: i32) -> PyResult<Vec<&'static str>> {
        self.session(py)?.reading_sensors(id).map_err(session_err)
    }

    #[pyo3(signature = (ids, throttle=None, steering=None, speed=None))]
    fn set_commands(
        &self,
        py: Python<'_>,
        ids: PyReadonlyArray1<'_, i32>,
        throttle: Option<PyReadonlyArray1<'_, f64>>,
        steering: Option<PyReadonlyArray1<'_, f64>>,
        speed: Option<PyReadonlyArray1<'_, f64>>,
    ) -> PyResult<()> {
        let ids = ids.as_slice().map_err(|_| PyValueError::new_err("ids must be a contiguous 1-d int array"))?;
        let (t, s, v) = (slice(&throttle, "throttle")?, slice(&steering, "steering")?, slice(&speed, "speed")?);
        self.session(py)?.set_commands(ids, t, s, v).map_err(session_err)
    }

    #[pyo3(signature = (width=640, height=480))]
    fn frame<'py>(&self, py: Python<'py>, width: u32, height: u32) -> PyResult<Bound<'py, numpy::PyArray3<u8>>> {
        let mut guard = self.session(py)?;
        let s: &mut Session = &mut guard;
        let pixels = py.detach(|| s.frame(width, height)).map_err(session_err)?;
        PyArray1::from_vec(py, pixels).reshape([height as usize, width as usize, 4])
    }

    fn clear_commands(&self, py: Python<'_>, ids: PyReadonlyArray1<'_, i32>) -> PyResult<()> {
        let ids = ids.as_slice().map_err(|_| PyValueError::new_err("ids must be a contiguous 1-d int array"))?;
        self.session(py)?.clear_commands(ids).map_err(session_err)
    }

    fn send(&self, py: Python<'_>, id: i32, channel: &str, payload: &[u8]) -> PyResult<()> {
        self.session(py)?.send(id, channel, payload.to_vec()).map_err(session_err)
    }

    fn inbox<'py>(&self, py: Python<'py>, id: i32, channel: &str) -> PyResult<Vec<(i32, Bound<'py, PyBytes>)>> {
        let msgs = self.session(py)?.inbox(id, channel).map_err(session_err)?;
        Ok(msgs.into_iter().map(|(s, b)| (s, PyBytes::new(py, &b))).collect())
    }

    /// Per vehicle (sorted by id): mass [kg] and drag [N s/m] of acceleration models, NaN for
    /// kinematic ones.
    fn models<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = self.session(py)?;
        let mut ids = Vec::new();
        let mut mass = Vec::new();
        let mut drag = Vec::new();
        for v in &s.scenario().file.vehicles {
            ids.push(v.id);
            match v.model {
                smlworld::app::running::scenario::ModelConfig::Acceleration { mass: m, drag: d, .. } => {
                    mass.push(m);
                    drag.push(d);
                }
                _ => {
                    mass.push(f64::NAN);
                    drag.push(f64::NAN);
                }
            }
        }
        let mut order: Vec<usize> = (0..ids.len()).collect();
        order.sort_by_key(|&i| ids[i]);
        let d = PyDict::new(py);
        d.set_item("id", PyArray1::from_vec(py, order.iter().map(|&i| ids[i]).collect()))?;
        d.set_item("mass", PyArray1::from_vec(py, order.iter().map(|&i| mass[i]).collect()))?;
        d.set_item("drag", PyArray1::from_vec(py, order.iter().map(|&i| drag[i]).collect()))?;
        Ok(d)
    }

    /// The control rate of the scenario [Hz].
    #[getter]
    fn control_rate(&self, py: Python<'_>) -> PyResult<f64> {
        Ok(self.session(py)?.scenario().file.rates.control)
    }

    /// The scenario's map, if any.
    fn map(&self, py: Python<'_>) -> PyResult<Option<Map>> {
        Ok(self.session(py)?.map().cloned().map(|m| Map { map: m }))
    }

    /// Call `call(obs)` for vehicles `ids` at `rate` [Hz] inside the Control phase of each tick
    /// it is due (see `controllers`); `call` returns `(throttle, steering, speed)`, each a
    /// float64 array with one value per id or None. `name` names it in error messages.
    fn add_controller(&self, py: Python<'_>, ids: Vec<i32>, call: Py<PyAny>, rate: f64, name: String) -> PyResult<()> {
        controllers::add(&mut *self.session(py)?, ids, call, name, rate)
    }

    /// Every signalised junction: `{id: {"state": str, "phase": int | None, "lanelets": [int]}}`
    /// (see `smlworld.Sim.traffic_lights`).
    fn traffic_lights<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let lights = self.session(py)?.traffic_lights();
        let out = PyDict::new(py);
        for l in lights {
            let d = PyDict::new(py);
            d.set_item("state", l.state)?;
            d.set_item("phase", l.phase)?;
            d.set_item("lanelets", l.lanelets)?;
            out.set_item(l.junction, d)?;
        }
        Ok(out)
    }

    /// Hold `state` at junction `junction` (id from 1) until set again (see
    /// `smlworld.Sim.set_phase`).
    fn set_phase(&self, py: Python<'_>, junction: i64, state: &str) -> PyResult<()> {
        let id = u32::try_from(junction).ok().filter(|&j| j >= 1).ok_or_else(|| {
            PyValueError::new_err(format!(
                "set_phase: junction {junction} is not a junction id (ids count from 1, as `smlworld map info` \
                 lists them)"
            ))
        })?;
        self.session(py)?.set_phase(id, state).map_err(session_err)
    }

    /// Every traffic light for a signal-control environment (issue 55): a list of dicts
    /// `{"junction", "name", "phases": [(state, duration)], "file_states", "lanes", "out_lanes"}` plus the lane
    /// slots the measurements use: `{"lights": [...], "slot_lanelet", "slot_incoming",
    /// "slot_length", "slot_allowed"}` (see `smlworld::app::running::signals::SignalLayout`).
    fn signal_layout<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let mut s = self.session(py)?;
        let map = s.map().cloned();
        let layout = s.signal_layout();
        let lights = PyList::empty(py);
        for l in &layout.lights {
            let d = PyDict::new(py);
            d.set_item("junction", l.junction)?;
            d.set_item("name", &l.name)?;
            d.set_item("phases", l.phases.clone())?;
            d.set_item("file_states", l.file_states.clone())?;
            d.set_item("lanes", l.lanes.clone())?;
            d.set_item("out_lanes", l.out_lanes.clone())?;
            lights.append(d)?;
        }
        let out = PyDict::new(py);
        out.set_item("lights", lights)?;
        let ids: Vec<i64> =
            layout.slots.iter().map(|&i| map.as_ref().map_or(-1, |m| m.lanelets[i as usize].id.0)).collect();
        out.set_item("slot_lanelet", PyArray1::from_vec(py, ids))?;
        out.set_item("slot_incoming", PyArray1::from_vec(py, layout.incoming.clone()))?;
        out.set_item("slot_length", column(py, &layout.length))?;
        out.set_item("slot_allowed", column(py, &layout.allowed))?;
        Ok(out)
    }

    /// One measurement of every light's lanes and of the system, in one pass over the vehicles
    /// (see `smlworld::app::running::signals::SignalMeasures`): per lane slot the float arrays "count",
    /// "halting", "length_sum", "speed_ratio_sum", "waiting"; and "running", "stopped",
    /// "total_waiting", "total_speed".
    fn signal_measures<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let mut m = smlworld::app::running::signals::SignalMeasures::default();
        self.session(py)?.signal_measures(&mut m);
        let d = PyDict::new(py);
        d.set_item("count", PyArray1::from_vec(py, m.count))?;
        d.set_item("halting", PyArray1::from_vec(py, m.halting))?;
        d.set_item("length_sum", PyArray1::from_vec(py, m.length_sum))?;
        d.set_item("speed_ratio_sum", PyArray1::from_vec(py, m.speed_ratio_sum))?;
        d.set_item("waiting", PyArray1::from_vec(py, m.waiting))?;
        d.set_item("running", m.running)?;
        d.set_item("stopped", m.stopped)?;
        d.set_item("total_waiting", m.total_waiting)?;
        d.set_item("total_speed", m.total_speed)?;
        Ok(d)
    }

    /// Remember waiting for `seconds` [s] (SUMO's `--waiting-time-memory`).
    fn set_waiting_memory(&self, py: Python<'_>, seconds: f64) -> PyResult<()> {
        self.session(py)?.set_waiting_memory(seconds).map_err(session_err)
    }

    /// Whether Python controllers are added.
    #[getter]
    fn has_controllers(&self, py: Python<'_>) -> PyResult<bool> {
        Ok(controllers::any(&*self.session(py)?))
    }
}

fn serde_json_string(summary: &smlworld::app::RunSummary) -> PyResult<String> {
    serde_json::to_string(&summary.to_json()).map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

/// `smlworld run`: run a scenario file (with overrides) and write trajectories.csv and
/// summary.json into `out`; returns the summary.
#[pyfunction]
#[pyo3(signature = (path, out=None, seed=None, **kwargs))]
fn run<'py>(
    py: Python<'py>,
    path: PathBuf,
    out: Option<PathBuf>,
    seed: Option<u64>,
    kwargs: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyAny>> {
    let ov = overrides(kwargs)?;
    let summary = py.detach(|| -> Result<_, PyErr> {
        let scenario = load_scenario_with_overrides(&path, seed, &ov).map_err(session_err)?;
        let mut options = RunOptions { progress: false, ..RunOptions::default() };
        if let Some(out) = out {
            options.out = out;
        }
        run_scenario(scenario, options).map_err(run_err)
    })?;
    json_to_py(py, &serde_json_string(&summary)?)
}

/// Advance `cores[i]` by `dts[i]` [s] for every `i` in one call, the simulations side by side on
/// the crate's persistent thread pool (at most `threads`, 0: the default) with the GIL released:
/// the traffic-signal vector env's step (issue 55). Each simulation gives the bits it gives
/// stepped alone; sims with Python controllers, a sim listed twice, or a bad `dt` are refused
/// before anything moves.
#[pyfunction]
#[pyo3(signature = (cores, dts, threads=0))]
fn step_many(py: Python<'_>, cores: Vec<PyRef<'_, Core>>, dts: Vec<f64>, threads: usize) -> PyResult<()> {
    if cores.len() != dts.len() {
        return Err(PyValueError::new_err(format!(
            "step_many: {} sims and {} dts; give one dt per sim",
            cores.len(),
            dts.len()
        )));
    }
    if let Some((i, dt)) = dts.iter().enumerate().find(|(_, dt)| !(dt.is_finite() && **dt >= 0.0)) {
        return Err(PyValueError::new_err(format!(
            "step_many: dts[{i}] must be a finite number of seconds >= 0, got {dt}"
        )));
    }
    let mut seen = std::collections::BTreeSet::new();
    if let Some(i) = cores.iter().position(|c| !seen.insert(c.address())) {
        return Err(PyValueError::new_err(format!("step_many: sim {i} is listed twice")));
    }
    let mut guards = Vec::with_capacity(cores.len());
    for (i, c) in cores.iter().enumerate() {
        let s = c.session(py)?;
        if controllers::any(&s) {
            return Err(PyValueError::new_err(format!(
                "step_many: sim {i} has Python controllers; step it with Sim.step"
            )));
        }
        guards.push(s);
    }
    let mut work: Vec<(&mut Session, f64)> = guards.iter_mut().map(|g| &mut **g).zip(dts).collect();
    let parallelism = if threads == 0 {
        smlworld::sim::Parallelism { min_vehicles: 1, ..Default::default() }
    } else {
        smlworld::sim::Parallelism { threads, min_vehicles: 1 }
    };
    py.detach(|| {
        parallelism.for_each_chunk(&mut work, &mut Vec::<()>::new(), |chunk, _| {
            for (s, dt) in chunk {
                // Checked above: a finite dt >= 0 cannot fail.
                let _ = s.step(*dt);
            }
        })
    });
    Ok(())
}

/// A lanelet map (see `smlworld.load_map`).
#[pyclass(module = "smlworld._smlworld", frozen)]
struct Map {
    map: Arc<LaneletMap>,
}

fn points<'py>(py: Python<'py>, pts: &[smlworld::prelude::DVec2]) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let flat: Vec<f64> = pts.iter().flat_map(|p| [p.x, p.y]).collect();
    PyArray1::from_vec(py, flat).reshape([pts.len(), 2])
}

#[pymethods]
impl Map {
    /// Lanelet ids, ascending.
    #[getter]
    fn lanelets<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i64>> {
        PyArray1::from_vec(py, self.map.lanelets.iter().map(|l| l.id.0).collect())
    }

    /// Successor pairs `(from, to)` as an (n, 2) int array.
    #[getter]
    fn successors<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<i64>>> {
        let pairs: Vec<i64> =
            self.map.lanelets.iter().flat_map(|l| l.successors.iter().flat_map(move |s| [l.id.0, s.0])).collect();
        let n = pairs.len() / 2;
        PyArray1::from_vec(py, pairs).reshape([n, 2])
    }

    /// Centre line of lanelet `id` as an (n, 2) array [m].
    fn centre<'py>(&self, py: Python<'py>, id: i64) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let l = self
            .map
            .lanelet(smlworld::map::LaneletId(id))
            .ok_or_else(|| PyValueError::new_err(format!("unknown lanelet id {id}")))?;
        points(py, &l.centre)
    }

    /// Shortest route from `from_node` to `to_node`, each a node id or a node tag value (such as
    /// "right_lane_node"; a tag on several nodes: the best of them), like `smlworld map route
    /// --from/--from-tag`, as an (n, 2) array of points [m].
    fn route<'py>(
        &self,
        py: Python<'py>,
        from_node: &Bound<'py, PyAny>,
        to_node: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let place = |n: &Bound<'py, PyAny>| -> PyResult<Place> {
            if let Ok(id) = n.extract::<i64>() {
                return Ok(Place::Node(id));
            }
            n.extract::<String>().map(Place::Tag).map_err(|_| {
                PyValueError::new_err(format!("a route end is a node id (int) or a node tag value (str), got {n}"))
            })
        };
        let p = self
            .map
            .route_places(&place(from_node)?, &place(to_node)?, &RouteOptions::default())
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        points(py, &p.points)
    }

    /// The closed loop through node `node` (an id, or a node tag value such as
    /// "right_lane_node") as an (n, 2) array of points [m].
    #[pyo3(name = "loop")]
    fn closed_loop<'py>(&self, py: Python<'py>, node: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let opts = RouteOptions::default();
        let p = if let Ok(id) = node.extract::<i64>() {
            self.map.closed_loop(id, &opts)
        } else {
            self.map.closed_loop_tag(&node.extract::<String>()?, &opts)
        }
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
        points(py, &p.points)
    }
}

/// Load a lanelet map (JOSM/OSM XML).
#[pyfunction]
fn load_map(py: Python<'_>, path: PathBuf) -> PyResult<Map> {
    let map = py.detach(|| LaneletMap::load(&path)).map_err(|e| match e {
        MapError::Io { .. } => PyFileNotFoundError::new_err(e.to_string()),
        e => PyValueError::new_err(e.to_string()),
    })?;
    Ok(Map { map: Arc::new(map) })
}

#[pymodule]
fn _smlworld(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Core>()?;
    m.add_class::<Map>()?;
    m.add_class::<vec::VecCore>()?;
    m.add_function(wrap_pyfunction!(run, m)?)?;
    m.add_function(wrap_pyfunction!(load_map, m)?)?;
    m.add_function(wrap_pyfunction!(step_many, m)?)?;
    Ok(())
}
