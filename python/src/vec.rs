//! Vector environments: `num_envs` episodes of one learning task held in Rust and stepped in one
//! call (the `smlworld.envs.make_vec` environments).
//!
//! The design is EnvPool's and gymnasium's `SyncVectorEnv` in one object: actions come in as one
//! numpy array, every environment steps on the crate's persistent thread pool with the GIL
//! released (the threads of [`Parallelism::for_each_chunk`], each with its share of the
//! environments and helping the others when done, see [`run`]; each environment depends on
//! itself only, so the results do not depend on the thread count), and observations, rewards and flags are written into numpy arrays the Python side
//! allocated once. Episodes end and start again inside the call
//! with gymnasium 1.x's default next-step autoreset (`AutoresetMode.NEXT_STEP`): the step that
//! ends an episode returns its last observation; the next step ignores that environment's
//! action, resets it and returns the first observation of the new episode with reward 0 and
//! both flags false.
//!
//! Each task here is the step of its single Python environment (`smlworld/envs/platoon.py`,
//! `smlworld/envs/merge.py`) written again in Rust, operation for operation on the same `f64`
//! values, so a vector environment gives the same observations and rewards, bit for bit, as
//! single environments given the same actions and seeds (python/tests/test_vec_env.py). The
//! random draws of an episode (its simulation seed, the leader's speed targets) stay in Python,
//! from each environment's own `numpy` generator, and come in as an [`Episode`] ahead of the
//! reset that uses them.

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, PoisonError};

use numpy::{PyReadonlyArray1, PyReadonlyArray2, PyReadwriteArray1, PyReadwriteArray2};
use pyo3::exceptions::{PyKeyError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use smlworld::app::running::scenario::ModelConfig;
use smlworld::app::{Scenario, Session, SessionError};
use smlworld::sim::Parallelism;
use smlworld::world::VehicleId;

use crate::kinematics;

/// The random draws of one episode, made in Python by the environment's generator.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Episode {
    /// Seed of the episode's simulation [-].
    pub seed: u64,
    /// PlatoonFollow: the leader's speed targets, `(from time [s], speed [m/s])`, in time order.
    pub targets: Vec<(f64, f64)>,
}

/// Constants of `smlworld/PlatoonFollow-v0` (the module constants of `smlworld/envs/platoon.py`,
/// handed over by it so that they live in one place).
#[derive(Debug, Clone, PartialEq)]
pub struct PlatoonParams {
    /// Time per env step [s].
    pub dt: f64,
    /// Steps before truncation.
    pub max_steps: u64,
    /// Car length [m]: the gap is the centre distance minus it.
    pub car_length: f64,
    /// Action bounds [m/s²].
    pub a_min: f64,
    /// Action bounds [m/s²].
    pub a_max: f64,
    /// Observation bounds, `float32` as the observation space holds them.
    pub obs_low: [f32; 4],
    /// Observation bounds.
    pub obs_high: [f32; 4],
}

/// Constants of `smlworld/HighwayMerge-v0` (from `smlworld/envs/merge.py`).
#[derive(Debug, Clone, PartialEq)]
pub struct MergeParams {
    /// Time per env step [s].
    pub dt: f64,
    /// Steps before truncation.
    pub max_steps: u64,
    /// `action="continuous"`: `[acceleration, lane-change request]`; else DiscreteMetaAction.
    pub continuous: bool,
    /// Action bounds [m/s²].
    pub a_min: f64,
    /// Action bounds [m/s²].
    pub a_max: f64,
    /// Target speeds of FASTER / SLOWER [m/s].
    pub target_speeds: Vec<f64>,
    /// Index of the target speed at reset.
    pub initial_target: usize,
    /// Gain of the discrete actions' speed law [1/s].
    pub speed_gain: f64,
    /// Speed of full progress reward [m/s].
    pub v_max: f64,
    /// y below which the car has merged [m].
    pub right_lane_top: f64,
    /// x where the left lane ends [m].
    pub lane_end_x: f64,
    /// x where the episode ends [m].
    pub road_end_x: f64,
    /// Vehicles observed besides the car.
    pub nearest: usize,
    /// Collision box (length, width) [m].
    pub footprint: (f64, f64),
    /// Divisors of the kinematics rows, `(1 + nearest) x 5`, row-major.
    pub obs_scale: Vec<f64>,
}

/// Which task, with its constants.
#[derive(Debug, Clone, PartialEq)]
pub enum Task {
    /// `smlworld/PlatoonFollow-v0`.
    Platoon(PlatoonParams),
    /// `smlworld/HighwayMerge-v0`.
    Merge(MergeParams),
}

const LEADER: i32 = -1;
const FOLLOWER: i32 = -2;
/// The learning car of HighwayMerge-v0.
const MERGER: i32 = -1;
/// The DiscreteMetaAction numbers (highway-env's order).
const LANE_LEFT: i64 = 0;
const LANE_RIGHT: i64 = 2;
const FASTER: i64 = 3;
const SLOWER: i64 = 4;
const DISCRETE_ACTIONS: i64 = 5;

impl Task {
    /// Length of one observation (its values, row-major).
    pub fn obs_len(&self) -> usize {
        match self {
            Task::Platoon(_) => 4,
            Task::Merge(p) => (p.nearest + 1) * 5,
        }
    }

    /// Names of the info values of one step, in the order [`Slot::info`] holds them.
    pub fn info_keys(&self) -> &'static [&'static str] {
        match self {
            Task::Platoon(_) => &["gap", "time"],
            Task::Merge(_) => &["merged", "collided", "speed", "x", "time"],
        }
    }

    /// Values per action: 1 for a discrete action.
    pub fn action_len(&self) -> usize {
        match self {
            Task::Platoon(_) => 1,
            Task::Merge(p) if p.continuous => 2,
            Task::Merge(_) => 1,
        }
    }

    /// The error the single environment raises for this action, if any (checked for every
    /// environment that steps before any of them moves).
    pub fn check_action(&self, env: usize, action: &[f64]) -> Result<(), String> {
        match self {
            Task::Platoon(_) if !action[0].is_finite() => {
                Err(format!("environment {env}: action must be finite, got {}", action[0]))
            }
            Task::Merge(p) if p.continuous && !action.iter().all(|a| a.is_finite()) => {
                Err(format!("environment {env}: action must be 2 finite numbers [accel, lane change], got {action:?}"))
            }
            Task::Merge(p) if !p.continuous && !(0.0..DISCRETE_ACTIONS as f64).contains(&action[0]) => Err(format!(
                "environment {env}: action must be one of [0, 1, 2, 3, 4] (LANE_LEFT, IDLE, LANE_RIGHT, FASTER, SLOWER), got {}",
                action[0]
            )),
            _ => Ok(()),
        }
    }
}

/// One environment's own state between steps.
enum EnvState {
    /// Not reset yet.
    Fresh,
    Platoon(PlatoonEnv),
    Merge(MergeEnv),
}

/// One PlatoonFollow-v0 episode (the attributes of `PlatoonFollowEnv`).
struct PlatoonEnv {
    session: Session,
    /// Mass [kg] and drag [N s/m] of the leader and the follower.
    mass: [f64; 2],
    drag: [f64; 2],
    targets: Vec<(f64, f64)>,
    next_target: usize,
    target: f64,
    steps: u64,
    last_a: f64,
    last_a_lead: f64,
    /// The leader's speed, the follower's speed [m/s] and the gap [m] after the last step.
    now: (f64, f64, f64),
}

/// One HighwayMerge-v0 episode (the attributes of `HighwayMergeEnv`).
struct MergeEnv {
    session: Session,
    mass: f64,
    drag: f64,
    target: usize,
    steps: u64,
    speed: f64,
}

/// One environment of the vector: its episode, the draws of its next one, and what its last
/// step or reset gave.
pub struct Slot {
    state: EnvState,
    /// The draws the next reset of this environment uses (Python sets them after each reset).
    pub pending: Option<Episode>,
    /// Whether its episode ended at the last step: the next step resets it.
    pub done: bool,
    /// This call's action.
    pub action: [f64; 2],
    /// Observation after the call (`Task::obs_len` values).
    pub obs: Vec<f32>,
    /// Reward of the call.
    pub reward: f64,
    /// Flags of the call.
    pub terminated: bool,
    /// Flags of the call.
    pub truncated: bool,
    /// Whether the call reset this environment (its info values are then NaN).
    pub reset: bool,
    /// The single environment's `info` values of the step, in [`Task::info_keys`] order.
    pub info: [f64; 5],
    /// A simulation error of the call.
    pub error: Option<SessionError>,
}

impl Slot {
    /// A slot before its first reset.
    pub fn new(task: &Task) -> Slot {
        Slot {
            state: EnvState::Fresh,
            pending: None,
            done: false,
            action: [0.0; 2],
            obs: vec![0.0; task.obs_len()],
            reward: 0.0,
            terminated: false,
            truncated: false,
            reset: false,
            info: [f64::NAN; 5],
            error: None,
        }
    }

    /// The session of the episode under way, if any.
    pub fn session(&self) -> Option<&Session> {
        match &self.state {
            EnvState::Fresh => None,
            EnvState::Platoon(e) => Some(&e.session),
            EnvState::Merge(e) => Some(&e.session),
        }
    }

    /// Start the pending episode: what the single environment's `reset()` does.
    pub fn reset(&mut self, task: &Task, scenario: &Scenario) {
        self.reset = true;
        self.done = false;
        self.reward = 0.0;
        self.terminated = false;
        self.truncated = false;
        self.info = [f64::NAN; 5];
        let Some(episode) = self.pending.take() else {
            self.error = Some(SessionError::Argument("no episode drawn for this reset (set_episode)".into()));
            return;
        };
        let result = match task {
            Task::Platoon(p) => PlatoonEnv::reset(p, scenario, episode, &mut self.obs).map(EnvState::Platoon),
            Task::Merge(p) => MergeEnv::reset(p, scenario, episode.seed, &mut self.obs).map(EnvState::Merge),
        };
        match result {
            Ok(state) => self.state = state,
            Err(e) => self.error = Some(e),
        }
    }

    /// One call of the vector's step for this environment: reset it if its episode ended at the
    /// last step (next-step autoreset), else step it with [`Slot::action`].
    pub fn advance(&mut self, task: &Task, scenario: &Scenario) {
        if self.done || matches!(self.state, EnvState::Fresh) {
            self.reset(task, scenario);
            return;
        }
        self.reset = false;
        let result = match (&mut self.state, task) {
            (EnvState::Platoon(env), Task::Platoon(p)) => env.step(p, self.action[0], &mut self.obs, &mut self.info),
            (EnvState::Merge(env), Task::Merge(p)) => env.step(p, self.action, &mut self.obs, &mut self.info),
            _ => unreachable!("a slot holds the state of its vector's task"),
        };
        match result {
            Ok((reward, terminated, truncated)) => {
                self.reward = reward;
                self.terminated = terminated;
                self.truncated = truncated;
                self.done = terminated || truncated;
            }
            Err(e) => self.error = Some(e),
        }
    }
}

/// Call `f` on every slot on the shared pool, `threads` threads at most (the calling thread is
/// one of them). Thread `w` owns the `w`-th contiguous share of the environments and takes them
/// in order, so an environment's world stays in the cache of the core that stepped it last;
/// a thread done with its share takes the next untaken environments of the others', so a thread
/// that the machine slows down (another process on its core, an environment resetting) does not
/// hold the step up. Every environment's result depends on itself only, so any assignment gives
/// the same bits.
pub fn run(slots: &mut [Slot], threads: usize, f: impl Fn(&mut Slot) + Sync) {
    let n = slots.len();
    let threads = threads.clamp(1, n.max(1));
    if threads == 1 {
        slots.iter_mut().for_each(f);
        return;
    }
    let share = n.div_ceil(threads);
    // One lock per slot, never contended: each index is handed out once.
    let cells: Vec<Mutex<&mut Slot>> = slots.iter_mut().map(Mutex::new).collect();
    // The next untaken environment of each share (past its end: none left).
    let next: Vec<AtomicUsize> = (0..threads).map(|w| AtomicUsize::new(w * share)).collect();
    let mut workers: Vec<usize> = (0..threads).collect();
    let parallelism = Parallelism { threads, min_vehicles: 2 };
    parallelism.for_each_chunk(&mut workers, &mut Vec::<()>::new(), |chunk, _| {
        for &mut w in chunk {
            for k in 0..threads {
                let v = (w + k) % threads;
                let end = ((v + 1) * share).min(n);
                loop {
                    let i = next[v].fetch_add(1, Ordering::Relaxed);
                    if i >= end {
                        break;
                    }
                    f(&mut cells[i].lock().unwrap_or_else(PoisonError::into_inner));
                }
            }
        }
    });
}

/// Mass [kg] and drag [N s/m] of vehicle `id` (an acceleration model; NaN otherwise), as
/// `Sim.models()` gives them.
fn model(scenario: &Scenario, id: i32) -> (f64, f64) {
    scenario.file.vehicles.iter().find(|v| v.id == id).map_or((f64::NAN, f64::NAN), |v| match v.model {
        ModelConfig::Acceleration { mass, drag, .. } => (mass, drag),
        _ => (f64::NAN, f64::NAN),
    })
}

/// `Sim.restart(seed)` of an environment whose metrics are stopped.
fn fresh_session(scenario: &Scenario, seed: u64) -> Result<Session, SessionError> {
    let mut scenario = scenario.clone();
    scenario.file.seed = seed;
    let mut session = Session::new(scenario)?;
    session.stop_metrics();
    Ok(session)
}

/// Python's `min(max(x, lo), hi)` for a finite `x` (the bounds are not zeros, so signed zeros
/// cannot tell the forms apart).
fn clip(x: f64, lo: f64, hi: f64) -> f64 {
    let x = if lo > x { lo } else { x };
    if hi < x { hi } else { x }
}

/// Python's `min(1.0, x)`.
fn cap(x: f64) -> f64 {
    if x < 1.0 { x } else { 1.0 }
}

/// `smlworld.envs.platoon.step_reward`, operation for operation.
pub fn platoon_reward(gap: f64, gap_ref: f64, accel: f64, accel_change: f64, a_min: f64, a_max: f64) -> f64 {
    if gap <= 0.0 {
        return -1.0;
    }
    let e = (gap - gap_ref) / gap_ref;
    let tracking = cap(e * e);
    let c = accel / -a_min;
    let comfort = cap(c * c);
    let s = accel_change / (a_max - a_min);
    let smooth = cap(s * s);
    1.0 - 2.0 * (0.8 * tracking + 0.1 * comfort + 0.1 * smooth)
}

/// `smlworld.envs.merge.step_reward`, operation for operation.
pub fn merge_reward(speed: f64, merged: bool, collided: bool, lane_ended: bool, v_max: f64) -> f64 {
    if collided || lane_ended {
        return -1.0;
    }
    let v = if speed > 0.0 { speed } else { 0.0 };
    0.6 * cap(v / v_max) + if merged { 0.4 } else { 0.0 }
}

impl PlatoonEnv {
    fn reset(p: &PlatoonParams, scenario: &Scenario, episode: Episode, obs: &mut [f32]) -> Result<Self, SessionError> {
        let session = fresh_session(scenario, episode.seed)?;
        let (ml, dl) = model(scenario, LEADER);
        let (mf, df) = model(scenario, FOLLOWER);
        let mut env = PlatoonEnv {
            session,
            mass: [ml, mf],
            drag: [dl, df],
            targets: episode.targets,
            next_target: 0,
            target: 15.0,
            steps: 0,
            last_a: 0.0,
            last_a_lead: 0.0,
            now: (0.0, 0.0, 0.0),
        };
        env.observe(p, obs)?;
        Ok(env)
    }

    /// `PlatoonFollowEnv._obs`: the observation now; returns the gap [m] and the follower's
    /// speed [m/s].
    fn observe(&mut self, p: &PlatoonParams, obs: &mut [f32]) -> Result<(f64, f64), SessionError> {
        let sim = self.session.sim();
        let (Some(lead), Some(ego)) = (sim.state(VehicleId(LEADER)), sim.state(VehicleId(FOLLOWER))) else {
            return Err(SessionError::Argument("PlatoonFollow-v0 needs vehicles -1 and -2".into()));
        };
        let v_lead = lead.velocity.x.hypot(lead.velocity.y);
        let v_ego = ego.velocity.x.hypot(ego.velocity.y);
        let centre = (lead.position.x - ego.position.x).hypot(lead.position.y - ego.position.y);
        let gap = centre - p.car_length;
        self.now = (v_lead, v_ego, gap);
        let msgs = self.session.inbox(FOLLOWER, "wifi")?;
        let mut a_lead = 0.0;
        for (sender, payload) in &msgs {
            if *sender == LEADER
                && let Ok(bytes) = <[u8; 8]>::try_from(payload.as_slice())
            {
                a_lead = f64::from_le_bytes(bytes);
            }
        }
        if !msgs.is_empty() {
            self.last_a_lead = a_lead;
        }
        let raw = [v_ego as f32, gap as f32, (v_lead - v_ego) as f32, self.last_a_lead as f32];
        for (k, o) in obs.iter_mut().enumerate() {
            // np.clip: maximum with the low bound, then minimum with the high one.
            let x = if raw[k] < p.obs_low[k] { p.obs_low[k] } else { raw[k] };
            *o = if x > p.obs_high[k] { p.obs_high[k] } else { x };
        }
        Ok((gap, v_ego))
    }

    /// `PlatoonFollowEnv.step`: returns (reward, terminated, truncated).
    fn step(
        &mut self,
        p: &PlatoonParams,
        action: f64,
        obs: &mut [f32],
        info: &mut [f64; 5],
    ) -> Result<(f64, bool, bool), SessionError> {
        let a = clip(action, p.a_min, p.a_max);
        let t = self.session.time();
        while self.next_target < self.targets.len() && self.targets[self.next_target].0 <= t {
            self.target = self.targets[self.next_target].1;
            self.next_target += 1;
        }
        let (v_lead, v_ego, _) = self.now;
        let a_lead = clip(0.5 * (self.target - v_lead), -3.0, 1.5);
        let throttle = [self.mass[0] * a_lead + self.drag[0] * v_lead, self.mass[1] * a + self.drag[1] * v_ego];
        self.session.set_commands(&[LEADER, FOLLOWER], Some(&throttle), None, None)?;
        self.session.send(LEADER, "wifi", a_lead.to_le_bytes().to_vec())?;
        self.session.step(p.dt)?;
        self.steps += 1;
        let (gap, v_ego) = self.observe(p, obs)?;
        let collided = gap <= 0.0;
        let gap_ref = 5.0 + 1.0 * v_ego;
        let reward = platoon_reward(gap, gap_ref, a, a - self.last_a, p.a_min, p.a_max);
        self.last_a = a;
        let truncated = self.steps >= p.max_steps;
        info[0] = gap;
        info[1] = self.session.time();
        Ok((reward, collided, truncated))
    }
}

impl MergeEnv {
    fn reset(p: &MergeParams, scenario: &Scenario, seed: u64, obs: &mut [f32]) -> Result<Self, SessionError> {
        let session = fresh_session(scenario, seed)?;
        let (mass, drag) = model(scenario, MERGER);
        let mut env = MergeEnv { session, mass, drag, target: p.initial_target, steps: 0, speed: 0.0 };
        let k = kinematics::observe(&env.session, MERGER, p.nearest, p.footprint)?;
        env.speed = k.speed;
        look(p, &k, obs);
        Ok(env)
    }

    /// `HighwayMergeEnv.step`: returns (reward, terminated, truncated).
    fn step(
        &mut self,
        p: &MergeParams,
        action: [f64; 2],
        obs: &mut [f32],
        info: &mut [f64; 5],
    ) -> Result<(f64, bool, bool), SessionError> {
        let v = self.speed;
        let (accel, change) = if p.continuous {
            let change = if action[1] < -0.5 {
                Some("right")
            } else if action[1] > 0.5 {
                Some("left")
            } else {
                None
            };
            (clip(action[0], p.a_min, p.a_max), change)
        } else {
            let mut change = None;
            match action[0] as i64 {
                FASTER => self.target = (self.target + 1).min(p.target_speeds.len() - 1),
                SLOWER => self.target = self.target.saturating_sub(1),
                LANE_LEFT => change = Some("left"),
                LANE_RIGHT => change = Some("right"),
                _ => {}
            }
            (clip(p.speed_gain * (p.target_speeds[self.target] - v), p.a_min, p.a_max), change)
        };
        let k = kinematics::drive(
            &mut self.session,
            MERGER,
            self.mass * accel + self.drag * v,
            change,
            p.dt,
            p.nearest,
            p.footprint,
        )?;
        self.steps += 1;
        let (merged, x) = look(p, &k, obs);
        self.speed = k.speed;
        let lane_ended = !merged && x >= p.lane_end_x - 1.0;
        let terminated = k.collided || lane_ended || x >= p.road_end_x;
        let reward = merge_reward(k.speed, merged, k.collided, lane_ended, p.v_max);
        let truncated = !terminated && self.steps >= p.max_steps;
        *info = [f64::from(u8::from(merged)), f64::from(u8::from(k.collided)), k.speed, x, self.session.time()];
        Ok((reward, terminated, truncated))
    }
}

/// `HighwayMergeEnv._look`: the scaled observation into `obs`; returns (merged, x [m]).
fn look(p: &MergeParams, k: &kinematics::Kinematics, obs: &mut [f32]) -> (bool, f64) {
    for (r, row) in k.rows.iter().enumerate() {
        for (c, value) in row.iter().enumerate() {
            let i = r * 5 + c;
            // np.clip(rows / OBS_SCALE, -1, 1).astype(np.float32)
            let x = value / p.obs_scale[i];
            let x = if x < -1.0 { -1.0 } else { x };
            obs[i] = (if x > 1.0 { 1.0 } else { x }) as f32;
        }
    }
    let (x, y) = (k.rows[0][1], k.rows[0][2]);
    (y < p.right_lane_top, x)
}

// -- the Python class ----------------------------------------------------------------------------

/// The environments of a vector and what they share.
struct Envs {
    task: Task,
    scenario: Scenario,
    slots: Vec<Slot>,
    threads: usize,
}

/// `num_envs` environments of one task, stepped in one call (see the module documentation and
/// `smlworld.envs.vector`).
#[pyclass(module = "smlworld._smlworld")]
pub struct VecCore {
    envs: Mutex<Envs>,
}

fn param<'py, T: pyo3::conversion::FromPyObjectOwned<'py>>(params: &Bound<'py, PyDict>, key: &str) -> PyResult<T> {
    let value =
        params.get_item(key)?.ok_or_else(|| PyKeyError::new_err(format!("vector env parameters lack `{key}`")))?;
    value.extract::<T>().map_err(|e| {
        let e: PyErr = e.into();
        PyValueError::new_err(format!("vector env parameter `{key}`: {e}"))
    })
}

fn task(kind: &str, p: &Bound<'_, PyDict>) -> PyResult<Task> {
    match kind {
        "platoon" => Ok(Task::Platoon(PlatoonParams {
            dt: param(p, "dt")?,
            max_steps: param(p, "max_steps")?,
            car_length: param(p, "car_length")?,
            a_min: param(p, "a_min")?,
            a_max: param(p, "a_max")?,
            obs_low: param(p, "obs_low")?,
            obs_high: param(p, "obs_high")?,
        })),
        "merge" => {
            let t = MergeParams {
                dt: param(p, "dt")?,
                max_steps: param(p, "max_steps")?,
                continuous: param(p, "continuous")?,
                a_min: param(p, "a_min")?,
                a_max: param(p, "a_max")?,
                target_speeds: param(p, "target_speeds")?,
                initial_target: param(p, "initial_target")?,
                speed_gain: param(p, "speed_gain")?,
                v_max: param(p, "v_max")?,
                right_lane_top: param(p, "right_lane_top")?,
                lane_end_x: param(p, "lane_end_x")?,
                road_end_x: param(p, "road_end_x")?,
                nearest: param(p, "nearest")?,
                footprint: param(p, "footprint")?,
                obs_scale: param(p, "obs_scale")?,
            };
            if t.obs_scale.len() != (t.nearest + 1) * 5 || t.initial_target >= t.target_speeds.len() {
                return Err(PyValueError::new_err("HighwayMerge-v0: obs_scale or target speeds do not fit"));
            }
            Ok(Task::Merge(t))
        }
        other => Err(PyValueError::new_err(format!("unknown vector task {other:?}; known: \"platoon\", \"merge\""))),
    }
}

impl VecCore {
    fn lock(&self) -> std::sync::MutexGuard<'_, Envs> {
        self.envs.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// The first simulation error of a call, naming its environment.
fn first_error(slots: &mut [Slot]) -> PyResult<()> {
    for (i, slot) in slots.iter_mut().enumerate() {
        if let Some(e) = slot.error.take() {
            return Err(PyRuntimeError::new_err(format!("environment {i}: {e}")));
        }
    }
    Ok(())
}

fn rows<'a>(a: &'a mut PyReadwriteArray2<'_, f32>, n: usize, len: usize, name: &str) -> PyResult<&'a mut [f32]> {
    let s = a.as_slice_mut().map_err(|_| PyValueError::new_err(format!("{name} must be a contiguous array")))?;
    if s.len() != n * len {
        return Err(PyValueError::new_err(format!("{name} must hold {n} x {len} values, got {}", s.len())));
    }
    Ok(s)
}

fn column<'a, T: numpy::Element>(a: &'a mut PyReadwriteArray1<'_, T>, n: usize, name: &str) -> PyResult<&'a mut [T]> {
    let s = a.as_slice_mut().map_err(|_| PyValueError::new_err(format!("{name} must be a contiguous array")))?;
    if s.len() != n {
        return Err(PyValueError::new_err(format!("{name} must hold {n} values, got {}", s.len())));
    }
    Ok(s)
}

#[pymethods]
impl VecCore {
    /// `num_envs` environments of `kind` ("platoon": PlatoonFollow-v0, "merge":
    /// HighwayMerge-v0) on the scenario at `path`, with the task's constants in `params`,
    /// stepped on at most `threads` threads (0: the machine's, at most 4).
    #[new]
    fn new(
        py: Python<'_>,
        kind: &str,
        path: PathBuf,
        num_envs: usize,
        threads: usize,
        params: &Bound<'_, PyDict>,
    ) -> PyResult<VecCore> {
        if num_envs == 0 {
            return Err(PyValueError::new_err("num_envs must be at least 1"));
        }
        let task = task(kind, params)?;
        let scenario = py
            .detach(|| smlworld::app::running::session::load_scenario_with_overrides(&path, None, &[]))
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
        let threads = if threads == 0 { Parallelism::default().threads } else { threads };
        let slots = (0..num_envs).map(|_| Slot::new(&task)).collect();
        Ok(VecCore { envs: Mutex::new(Envs { task, scenario, slots, threads }) })
    }

    /// Number of environments.
    #[getter]
    fn num_envs(&self) -> usize {
        self.lock().slots.len()
    }

    /// Threads the steps use at most.
    #[getter]
    fn threads(&self) -> usize {
        self.lock().threads
    }

    /// Names of the info columns `step` writes.
    #[getter]
    fn info_keys(&self) -> Vec<&'static str> {
        self.lock().task.info_keys().to_vec()
    }

    /// The draws of environment `i`'s next episode: its simulation seed and (PlatoonFollow) the
    /// leader's speed targets as a (k, 2) array of (time [s], speed [m/s]).
    #[pyo3(signature = (i, seed, targets=None))]
    fn set_episode(&self, i: usize, seed: u64, targets: Option<PyReadonlyArray2<'_, f64>>) -> PyResult<()> {
        if i64::try_from(seed).is_err() {
            return Err(PyValueError::new_err(format!("seed must be < 2^63, got {seed}")));
        }
        let targets = match targets {
            Some(t) => {
                let a = t.as_array();
                if a.ncols() != 2 {
                    return Err(PyValueError::new_err("targets must be a (k, 2) array of (time, speed)"));
                }
                a.rows().into_iter().map(|r| (r[0], r[1])).collect()
            }
            None => Vec::new(),
        };
        let mut envs = self.lock();
        let n = envs.slots.len();
        let slot = envs.slots.get_mut(i).ok_or_else(|| PyValueError::new_err(format!("env {i} of {n}")))?;
        slot.pending = Some(Episode { seed, targets });
        Ok(())
    }

    /// Start the pending episode of every environment `mask` selects (all without a mask) and
    /// write their first observations into the rows of `obs` (`num_envs` x observation length).
    #[pyo3(signature = (obs, mask=None))]
    fn reset(
        &self,
        py: Python<'_>,
        mut obs: PyReadwriteArray2<'_, f32>,
        mask: Option<PyReadonlyArray1<'_, bool>>,
    ) -> PyResult<()> {
        let mut guard = self.lock();
        let envs = &mut *guard;
        let n = envs.slots.len();
        let len = envs.task.obs_len();
        let obs = rows(&mut obs, n, len, "obs")?;
        let mask = match &mask {
            Some(m) => {
                let m = m.as_slice().map_err(|_| PyValueError::new_err("mask must be a contiguous bool array"))?;
                if m.len() != n {
                    return Err(PyValueError::new_err(format!("mask must hold {n} values, got {}", m.len())));
                }
                m.to_vec()
            }
            None => vec![true; n],
        };
        let (task, scenario) = (&envs.task, &envs.scenario);
        let slots = &mut envs.slots;
        // `reset` marks the selected slots until the call resets them.
        for (slot, &m) in slots.iter_mut().zip(&mask) {
            slot.reset = m;
        }
        let threads = envs.threads;
        py.detach(|| {
            run(slots, threads, |slot| {
                if slot.reset {
                    slot.reset(task, scenario);
                }
            });
            for (i, slot) in slots.iter().enumerate() {
                if mask[i] {
                    obs[i * len..(i + 1) * len].copy_from_slice(&slot.obs);
                }
            }
        });
        first_error(slots)
    }

    /// One step of every environment (next-step autoreset, see the module documentation):
    /// `actions` (`num_envs` x action length, float64; a discrete action as its number) in;
    /// observations, rewards, the flags, which environments this call reset, and the info values
    /// (`num_envs` x `len(info_keys)`, NaN for a reset environment) out, into the arrays given.
    #[allow(clippy::too_many_arguments)] // the arrays of one step, plus self and the GIL token
    fn step(
        &self,
        py: Python<'_>,
        actions: PyReadonlyArray2<'_, f64>,
        mut obs: PyReadwriteArray2<'_, f32>,
        mut rewards: PyReadwriteArray1<'_, f64>,
        mut terminated: PyReadwriteArray1<'_, bool>,
        mut truncated: PyReadwriteArray1<'_, bool>,
        mut reset: PyReadwriteArray1<'_, bool>,
        mut info: PyReadwriteArray2<'_, f64>,
    ) -> PyResult<()> {
        let mut guard = self.lock();
        let envs = &mut *guard;
        let n = envs.slots.len();
        let (len, width, keys) = (envs.task.obs_len(), envs.task.action_len(), envs.task.info_keys().len());
        let actions = actions.as_array();
        if actions.shape() != [n, width] {
            return Err(PyValueError::new_err(format!(
                "actions must be a ({n}, {width}) array, got shape {:?}",
                actions.shape()
            )));
        }
        let obs = rows(&mut obs, n, len, "obs")?;
        let rewards = column(&mut rewards, n, "rewards")?;
        let terminated = column(&mut terminated, n, "terminated")?;
        let truncated = column(&mut truncated, n, "truncated")?;
        let reset = column(&mut reset, n, "reset")?;
        let info = info.as_slice_mut().map_err(|_| PyValueError::new_err("info must be a contiguous array"))?;
        if info.len() != n * keys {
            return Err(PyValueError::new_err(format!("info must hold {n} x {keys} values")));
        }
        // Every action is checked before any environment moves, as the single environments
        // check theirs before they move.
        for (i, slot) in envs.slots.iter_mut().enumerate() {
            if slot.session().is_none() {
                return Err(PyRuntimeError::new_err("call reset() before step()"));
            }
            let row = actions.row(i);
            let mut a = [0.0; 2];
            for (k, v) in row.iter().enumerate() {
                a[k] = *v;
            }
            if !slot.done {
                envs.task.check_action(i, &a[..width]).map_err(PyValueError::new_err)?;
            }
            slot.action = a;
        }
        let (task, scenario, threads) = (&envs.task, &envs.scenario, envs.threads);
        let slots = &mut envs.slots;
        py.detach(|| {
            run(slots, threads, |slot| slot.advance(task, scenario));
            for (i, slot) in slots.iter().enumerate() {
                obs[i * len..(i + 1) * len].copy_from_slice(&slot.obs);
                rewards[i] = slot.reward;
                terminated[i] = slot.terminated;
                truncated[i] = slot.truncated;
                reset[i] = slot.reset;
                info[i * keys..(i + 1) * keys].copy_from_slice(&slot.info[..keys]);
            }
        });
        first_error(slots)
    }

    /// Sim time of every environment's episode [s] (NaN before its first reset).
    fn times(&self) -> Vec<f64> {
        self.lock().slots.iter().map(|s| s.session().map_or(f64::NAN, Session::time)).collect()
    }
}
