"""``smlworld/HighwayMerge-v0`` (see :mod:`smlworld.envs`): merge from an ending lane into traffic.

The road is the GCDC 2016 lane drop (``maps/lane_drop.osm``, along +x): two 3.5 m lanes for 300 m,
then the left one ends and the right one goes on to 500 m. The learning car (id -1) starts on the
left lane at x = 20 m; IDM traffic with cooperative lane changes drives the right lane. The car's
lane changes are the agent's alone (``lane_change = { manual = true }``): the simulator's own
lane-change plugin carries them out, with MOBIL's safety check, when asked.
"""

from __future__ import annotations

from importlib import resources
from typing import Optional

import gymnasium as gym
import numpy as np
from gymnasium import spaces

import smlworld

from ._frames import rgb_frame

EGO = -1
LANE_WIDTH = 3.5  # [m]
RIGHT_LANE_TOP = 3.5  # [m] y of the line between the lanes: the car has merged below it
LANE_END_X = 300.0  # [m] where the left lane ends
ROAD_END_X = 480.0  # [m] the episode ends here, merged (the road ends at 500 m)
CAR_LENGTH, CAR_WIDTH = 4.5, 1.8  # [m] for the collision check (a little above the car's size)
A_MIN, A_MAX = -6.0, 3.0  # [m/s^2]
V_MAX = 30.0  # [m/s]
TARGET_SPEEDS = (10.0, 15.0, 20.0, 25.0, 30.0)  # [m/s] of the discrete actions FASTER / SLOWER
SPEED_GAIN = 1.0  # [1/s] discrete actions: a = gain * (target - v), clipped to [A_MIN, A_MAX]
DT = 0.5  # [s] per step
MAX_STEPS = 80  # 40 s
NEAREST = 5  # vehicles in the observation besides the car
FEATURES = ("presence", "x", "y", "vx", "vy")
SCALE = np.array([1.0, 100.0, 2.0 * LANE_WIDTH, V_MAX, V_MAX])
#: Divides the kinematics rows: the car's own row by its absolute scales, the others by SCALE.
OBS_SCALE = np.vstack([[1.0, LANE_END_X, 2.0 * LANE_WIDTH, V_MAX, V_MAX], np.tile(SCALE, (NEAREST, 1))])
FOOTPRINT = (CAR_LENGTH, CAR_WIDTH)

ACTIONS = {0: "LANE_LEFT", 1: "IDLE", 2: "LANE_RIGHT", 3: "FASTER", 4: "SLOWER"}


def step_reward(speed: float, merged: bool, collided: bool, lane_ended: bool) -> float:
    """Reward of one step, always in [-1, 1]: -1 on a collision or when the lane ends under the
    car; else progress ``0.6 * min(1, speed / 30 m/s)`` plus 0.4 once merged."""
    if collided or lane_ended:
        return -1.0
    return float(0.6 * min(1.0, max(0.0, speed) / V_MAX) + (0.4 if merged else 0.0))


def draw_episode(np_random: np.random.Generator) -> int:
    """The random draw of one episode from the env's generator: the seed of its simulation (the
    vector env draws with this same function)."""
    return int(np_random.integers(0, 2**31 - 1))


def _scenario_path() -> str:
    return str(resources.files("smlworld") / "data" / "highway_merge.toml")


class HighwayMergeEnv(gym.Env):
    """Merge from the ending lane into traffic (see :mod:`smlworld.envs`).

    ``action="discrete"`` (default): highway-env's DiscreteMetaAction, ``0 LANE_LEFT, 1 IDLE,
    2 LANE_RIGHT, 3 FASTER, 4 SLOWER`` (FASTER / SLOWER step the target speed through
    10-30 m/s). ``action="continuous"``: ``[acceleration in [-6, 3] m/s^2, lane-change request in
    [-1, 1]]`` (below -0.5 asks for the right lane, above 0.5 for the left).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": int(round(1.0 / DT))}

    def __init__(
        self,
        action: str = "discrete",
        dt: float = DT,
        max_steps: int = MAX_STEPS,
        render_mode: Optional[str] = None,
    ):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if action not in ("discrete", "continuous"):
            raise ValueError(f"action must be 'discrete' or 'continuous', got {action!r}")
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive number of seconds, got {dt!r}")
        self.render_mode = render_mode
        self.action_type = action
        self.dt = float(dt)
        self.max_steps = int(max_steps)
        if action == "discrete":
            self.action_space = spaces.Discrete(len(ACTIONS))
        else:
            self.action_space = spaces.Box(
                np.array([A_MIN, -1.0], dtype=np.float32), np.array([A_MAX, 1.0], dtype=np.float32), dtype=np.float32
            )
        self.observation_space = spaces.Box(-1.0, 1.0, shape=(NEAREST + 1, len(FEATURES)), dtype=np.float32)
        self._sim: Optional[smlworld.Sim] = None
        self._ego = np.array([EGO], dtype=np.int32)

    def render(self):
        """With ``render_mode="rgb_array"``: the bird's-eye view now, an (H, W, 3) uint8 array
        (640 x 360) from the off-screen renderer; ``None`` without a render mode."""
        return rgb_frame(self)

    # -- helpers -----------------------------------------------------------------------------
    def _look(self, rows, speed, collided):
        """Observation, the car's speed, whether it collided, whether it has merged and its x,
        from :meth:`smlworld.Sim.kinematics` rows (the car, then its 5 nearest vehicles; the
        road runs along +x, so the car's frame is the world's, shifted: no rotation needed)."""
        obs = np.clip(rows / OBS_SCALE, -1.0, 1.0).astype(np.float32)
        x, y = rows[0, 1], rows[0, 2]
        return obs, speed, collided, bool(y < RIGHT_LANE_TOP), float(x)

    # -- gymnasium API -----------------------------------------------------------------------
    def reset(self, *, seed: Optional[int] = None, options=None):
        super().reset(seed=seed)
        sim_seed = draw_episode(self.np_random)
        if self._sim is None:
            # Loaded once: later resets start the same scenario over with a new seed, without
            # reading the scenario file or the map again. The summary's metrics are never read.
            self._sim = smlworld.Sim.from_scenario(_scenario_path(), seed=sim_seed)
            self._sim.stop_metrics()
            m = self._sim.models()
            k = int(np.searchsorted(m["id"], EGO))
            self._mass, self._drag = float(m["mass"][k]), float(m["drag"][k])
        else:
            self._sim.restart(sim_seed)
        self._target = 2  # index into TARGET_SPEEDS: 20 m/s
        self._steps = 0
        obs, self._speed, _, _, _ = self._look(*self._sim.kinematics(EGO, NEAREST, FOOTPRINT))
        return obs, {}

    def step(self, action):
        if self._sim is None:
            raise RuntimeError("call reset() before step()")
        v = self._speed
        change = None
        if self.action_type == "discrete":
            a_idx = int(action) if isinstance(action, (int, np.integer)) else int(np.asarray(action).reshape(-1)[0])
            if not 0 <= a_idx < len(ACTIONS):
                raise ValueError(f"action must be one of {sorted(ACTIONS)}, got {action!r}")
            name = ACTIONS[a_idx]
            if name == "FASTER":
                self._target = min(self._target + 1, len(TARGET_SPEEDS) - 1)
            elif name == "SLOWER":
                self._target = max(self._target - 1, 0)
            elif name == "LANE_LEFT":
                change = "left"
            elif name == "LANE_RIGHT":
                change = "right"
            accel = min(max(SPEED_GAIN * (TARGET_SPEEDS[self._target] - v), A_MIN), A_MAX)
        else:
            a = np.asarray(action, dtype=np.float64).reshape(-1)
            if a.shape != (2,) or not np.all(np.isfinite(a)):
                raise ValueError(f"action must be 2 finite numbers [accel, lane change], got {action!r}")
            accel = min(max(float(a[0]), A_MIN), A_MAX)
            change = "right" if a[1] < -0.5 else "left" if a[1] > 0.5 else None
        # One call: the lane change (refused quietly when there is no lane, a solid line or no
        # gap), the throttle, the step, and the kinematics after it.
        kin = self._sim.drive(EGO, self._mass * accel + self._drag * v, change, self.dt, NEAREST, FOOTPRINT)
        self._steps += 1
        obs, speed, collided, merged, x = self._look(*kin)
        self._speed = speed
        lane_ended = (not merged) and x >= LANE_END_X - 1.0
        terminated = collided or lane_ended or x >= ROAD_END_X
        reward = step_reward(speed, merged, collided, lane_ended)
        truncated = (not terminated) and self._steps >= self.max_steps
        info = {"merged": merged, "collided": collided, "speed": speed, "x": x, "time": self._sim.time}
        return obs, reward, bool(terminated), bool(truncated), info
