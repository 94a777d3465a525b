"""``smlworld/PlatoonFollow-v0`` (see :mod:`smlworld.envs`)."""

from __future__ import annotations

import struct
from importlib import resources
from typing import Optional

import gymnasium as gym
import numpy as np
from gymnasium import spaces

import smlworld

from ._frames import rgb_frame

LEADER, EGO = -1, -2
CAR_LENGTH = 4.5  # [m], the default car length
A_MIN, A_MAX = -6.0, 3.0  # [m/s^2]


def step_reward(gap: float, gap_ref: float, accel: float, accel_change: float) -> float:
    """Reward of one step, always in [-1, 1]: 1 at the reference gap with no acceleration, -1 on a
    collision (gap <= 0) or when far off. Weighted penalties, each capped at 1: gap tracking
    ``((gap - gap_ref) / gap_ref)^2`` (0.8), comfort ``(accel / 6 m/s^2)^2`` (0.1) and
    smoothness ``(accel_change / 9 m/s^2)^2`` (0.1, the change of the acceleration in one step);
    the sum maps to ``1 - 2 * penalty``. Bounded, so a random policy's return stays comparable
    to a good one's (an unbounded quadratic gave -177,000 over 1,000 random steps)."""
    if gap <= 0.0:
        return -1.0
    # Squares as products (not ``** 2``, which is libm's pow): the vector env's Rust port
    # (python/src/vec.rs) computes the same bits.
    e, c, s = (gap - gap_ref) / gap_ref, accel / -A_MIN, accel_change / (A_MAX - A_MIN)
    tracking = min(1.0, e * e)
    comfort = min(1.0, c * c)
    smooth = min(1.0, s * s)
    return float(1.0 - 2.0 * (0.8 * tracking + 0.1 * comfort + 0.1 * smooth))
DT = 0.1  # [s] per step
MAX_STEPS = 600


def draw_episode(np_random: np.random.Generator, max_steps: int, dt: float):
    """The random draws of one episode from the env's generator, in this order: the seed of its
    simulation, then the leader's speed profile (a new target every 4-10 s, 8-22 m/s) as a list
    of ``(from time [s], speed [m/s])`` covering the episode and 10 s more. The vector env draws
    with this same function, so its episodes are the single env's."""
    sim_seed = int(np_random.integers(0, 2**31 - 1))
    targets = []
    t = 0.0
    while t < max_steps * dt + 10:
        t += float(np_random.uniform(4.0, 10.0))
        targets.append((t, float(np_random.uniform(8.0, 22.0))))
    return sim_seed, targets


def _scenario_path() -> str:
    return str(resources.files("smlworld") / "data" / "platoon_follow.toml")


class PlatoonFollowEnv(gym.Env):
    """Follow a leader that changes its speed every few seconds (see :mod:`smlworld.envs`)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": int(round(1.0 / DT))}

    def __init__(self, dt: float = DT, max_steps: int = MAX_STEPS, render_mode: Optional[str] = None):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.dt = float(dt)
        self.max_steps = int(max_steps)
        self.action_space = spaces.Box(A_MIN, A_MAX, shape=(1,), dtype=np.float32)
        high = np.array([40.0, 200.0, 40.0, 10.0], dtype=np.float32)
        self.observation_space = spaces.Box(np.array([0.0, -50.0, -40.0, -10.0], dtype=np.float32), high, dtype=np.float32)
        self._sim: Optional[smlworld.Sim] = None
        self._ids = np.array([LEADER, EGO], dtype=np.int32)

    def render(self):
        """With ``render_mode="rgb_array"``: the bird's-eye view now, an (H, W, 3) uint8 array
        (640 x 360) from the off-screen renderer; ``None`` without a render mode."""
        return rgb_frame(self)

    # -- helpers -----------------------------------------------------------------------------
    def _kinematics(self):
        """The leader's speed, the car's speed [m/s] and the gap [m] now: kept until the next
        step, which reads them before it moves anything."""
        st = self._sim.states()  # sorted by id: [-2, -1]
        v = np.hypot(st["vx"], st["vy"])
        centre = float(np.hypot(st["x"][1] - st["x"][0], st["y"][1] - st["y"][0]))
        self._now = float(v[1]), float(v[0]), centre - CAR_LENGTH
        return self._now

    def _obs(self):
        v_lead, v_ego, gap = self._kinematics()
        a_lead = 0.0
        msgs = self._sim.inbox(EGO, "wifi")
        for sender, payload in msgs:
            if sender == LEADER and len(payload) == 8:
                a_lead = struct.unpack("<d", payload)[0]
        if msgs:
            self._last_a_lead = a_lead
        obs = np.array([v_ego, gap, v_lead - v_ego, self._last_a_lead], dtype=np.float32)
        return np.clip(obs, self.observation_space.low, self.observation_space.high), gap, v_ego

    # -- gymnasium API -----------------------------------------------------------------------
    def reset(self, *, seed: Optional[int] = None, options=None):
        super().reset(seed=seed)
        sim_seed, self._targets = draw_episode(self.np_random, self.max_steps, self.dt)
        if self._sim is None:
            # Loaded once: later resets start the same scenario over with a new seed, without
            # reading the scenario file or the map again. The summary's metrics are never read.
            self._sim = smlworld.Sim.from_scenario(_scenario_path(), seed=sim_seed)
            self._sim.stop_metrics()
            m = self._sim.models()
            self._mass, self._drag = m["mass"][::-1].copy(), m["drag"][::-1].copy()  # leader, ego
        else:
            self._sim.restart(sim_seed)
        self._target = 15.0
        self._steps = 0
        self._last_a = 0.0
        self._last_a_lead = 0.0
        self._a_lead = 0.0
        obs, _, _ = self._obs()
        return obs, {}

    def step(self, action):
        if self._sim is None:
            raise RuntimeError("call reset() before step()")
        a = min(max(float(np.asarray(action, dtype=np.float64).reshape(-1)[0]), A_MIN), A_MAX)  # NaN stays NaN
        if not np.isfinite(a):
            raise ValueError(f"action must be finite, got {action!r}")
        t = self._sim.time
        while self._targets and self._targets[0][0] <= t:
            self._target = self._targets.pop(0)[1]
        v_lead, v_ego, _ = self._now  # as the last reset() or step() left them
        self._a_lead = min(max(0.5 * (self._target - v_lead), -3.0), 1.5)
        accel = np.array([self._a_lead, a])
        v = np.array([v_lead, v_ego])
        self._sim.set_commands(self._ids, throttle=self._mass * accel + self._drag * v)
        self._sim.send(LEADER, "wifi", struct.pack("<d", self._a_lead))
        self._sim.step(self.dt)
        self._steps += 1
        obs, gap, v_ego = self._obs()
        collided = gap <= 0.0
        gap_ref = 5.0 + 1.0 * v_ego
        reward = step_reward(gap, gap_ref, a, a - self._last_a)
        self._last_a = a
        truncated = self._steps >= self.max_steps
        return obs, float(reward), bool(collided), bool(truncated), {"gap": gap, "time": self._sim.time}
