"""PettingZoo parallel platoon: ``platoon_parallel_env(n=5)``.

A scripted lead car (id -1) varies its speed as in ``PlatoonFollow-v0``; behind it ``n`` cars
(ids -2, -3, ...) are the agents ``member_0`` (right behind the leader) ... ``member_{n-1}``.
Action per agent: longitudinal acceleration [m/s^2] in [-6, 3]. Observation per agent: own speed
[m/s], gap to its predecessor [m], relative speed (predecessor - own) [m/s], the predecessor's
acceleration received over wifi [m/s^2] (every car broadcasts its acceleration each step).
Reward per agent as in ``PlatoonFollow-v0``; an agent that collides terminates, and so does the
whole episode (all agents). 0.1 s per step, truncated after ``max_steps``.
"""

from __future__ import annotations

import functools
import os
import shutil
import struct
import tempfile
import weakref
from importlib import resources
from typing import Optional

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

import smlworld

from .platoon import A_MAX, A_MIN, CAR_LENGTH, DT, step_reward

_VEHICLE = """
[[vehicles]]
id = {id}
class = "car"
model = {{ type = "acceleration", mass = 1500.0, drag = 50.0 }}
route = {{ loop = "right_lane_node" }}
start = {{ at = "right_lane_node", offset = {offset} }}
speed = 15.0
controller = {{ type = "path_following", speed = 15.0 }}
"""


def _scenario(n: int, spacing: float) -> str:
    ring = str(resources.files("smlworld") / "data" / "highway_ring.osm")
    head = f'seed = 0\nduration = 3600.0\nmap = "{ring}"\n[v2v]\nwifi_range = 100.0\n'
    return head + "".join(_VEHICLE.format(id=-(k + 1), offset=30.0 + spacing * (n - k)) for k in range(n + 1))


def platoon_parallel_env(n: int = 5, max_steps: int = 600, spacing: float = 20.0) -> "PlatoonParallelEnv":
    """The platoon as a PettingZoo ``ParallelEnv`` with ``n`` learning members."""
    return PlatoonParallelEnv(n=n, max_steps=max_steps, spacing=spacing)


class PlatoonParallelEnv(ParallelEnv):
    metadata = {"render_modes": [], "name": "smlworld_platoon_v0"}

    def __init__(self, n: int = 5, max_steps: int = 600, spacing: float = 20.0):
        if n < 1:
            raise ValueError(f"n must be >= 1, got {n}")
        self.n = int(n)
        self.max_steps = int(max_steps)
        self.possible_agents = [f"member_{k}" for k in range(self.n)]
        self.agents = []
        self._dir = tempfile.mkdtemp(prefix="smlworld-platoon-")
        # The scenario file lives as long as the env (every reset reads it); the folder goes
        # with `close()` or when the env is collected, so a sweep of many envs leaves nothing.
        self._cleanup = weakref.finalize(self, shutil.rmtree, self._dir, True)
        self._path = os.path.join(self._dir, "platoon.toml")
        with open(self._path, "w") as f:
            f.write(_scenario(self.n, float(spacing)))
        self._ids = np.array([-(k + 1) for k in range(self.n + 1)], dtype=np.int32)  # leader first
        self._rng = np.random.default_rng()

    @functools.lru_cache(maxsize=None)
    def observation_space(self, agent):
        return spaces.Box(
            np.array([0.0, -50.0, -40.0, -10.0], dtype=np.float32),
            np.array([40.0, 200.0, 40.0, 10.0], dtype=np.float32),
            dtype=np.float32,
        )

    @functools.lru_cache(maxsize=None)
    def action_space(self, agent):
        return spaces.Box(A_MIN, A_MAX, shape=(1,), dtype=np.float32)

    def _kin(self):
        st = self._sim.states()  # ascending ids: -(n+1) ... -1; reverse to leader first
        x, y = st["x"][::-1], st["y"][::-1]
        v = np.hypot(st["vx"], st["vy"])[::-1]
        gaps = np.hypot(np.diff(x), np.diff(y)) - CAR_LENGTH  # member k behind car k
        return v, gaps

    def _observe(self):
        v, gaps = self._kin()
        obs = {}
        for k, agent in enumerate(self.possible_agents):
            me = int(self._ids[k + 1])
            pred = int(self._ids[k])
            for sender, payload in self._sim.inbox(me, "wifi"):
                if sender == pred and len(payload) == 8:
                    self._heard[k] = struct.unpack("<d", payload)[0]
            o = np.array([v[k + 1], gaps[k], v[k] - v[k + 1], self._heard[k]], dtype=np.float32)
            sp = self.observation_space(agent)
            obs[agent] = np.clip(o, sp.low, sp.high)
        return obs, v, gaps

    def close(self):
        """Remove the env's scenario folder (also done when the env is collected)."""
        self._cleanup()

    def reset(self, seed: Optional[int] = None, options=None):
        if not self._cleanup.alive:
            raise RuntimeError("this PlatoonParallelEnv is closed; make a new one with platoon_parallel_env()")
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        self._sim = smlworld.Sim.from_scenario(self._path, seed=int(self._rng.integers(0, 2**31 - 1)))
        self._targets = []
        t = 0.0
        while t < self.max_steps * DT + 10:
            t += float(self._rng.uniform(4.0, 10.0))
            self._targets.append((t, float(self._rng.uniform(8.0, 22.0))))
        self._target = 15.0
        self._heard = np.zeros(self.n)
        self._last = np.zeros(self.n)
        self._steps = 0
        self.agents = list(self.possible_agents)
        obs, _, _ = self._observe()
        return obs, {a: {} for a in self.agents}

    def step(self, actions):
        t = self._sim.time
        while self._targets and self._targets[0][0] <= t:
            self._target = self._targets.pop(0)[1]
        v, _ = self._kin()
        a = np.zeros(self.n + 1)
        a[0] = np.clip(0.5 * (self._target - v[0]), -3.0, 1.5)
        for k, agent in enumerate(self.possible_agents):
            if agent in actions:
                a[k + 1] = float(np.clip(np.asarray(actions[agent], dtype=np.float64).reshape(-1)[0], A_MIN, A_MAX))
        self._sim.set_commands(self._ids, throttle=1500.0 * a + 50.0 * v)
        for k in range(self.n + 1):
            self._sim.send(int(self._ids[k]), "wifi", struct.pack("<d", a[k]))
        self._sim.step(DT)
        self._steps += 1
        obs, v, gaps = self._observe()
        rewards, terms, truncs, infos = {}, {}, {}, {}
        collided = bool((gaps <= 0.0).any())
        trunc = self._steps >= self.max_steps
        for k, agent in enumerate(self.possible_agents):
            ref = 5.0 + v[k + 1]
            rewards[agent] = step_reward(float(gaps[k]), ref, float(a[k + 1]), float(a[k + 1] - self._last[k]))
            terms[agent] = collided
            truncs[agent] = trunc
            infos[agent] = {"gap": float(gaps[k])}
        self._last = a[1:].copy()
        if collided or trunc:
            self.agents = []
        return obs, rewards, terms, truncs, infos
