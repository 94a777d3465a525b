"""Vector environments stepped in Rust: ``make_vec("smlworld/PlatoonFollow-v0", num_envs=64)``.

One Rust object holds all ``num_envs`` simulations and steps them in one call: numpy actions in,
numpy observations, rewards and flags out, the GIL released and the environments split over the
simulator's persistent thread pool (DESIGN.md, "Python environments at scale"; the same idea as
EnvPool). There is no Python per environment step.

Autoreset follows gymnasium 1.x's default for vector envs, ``AutoresetMode.NEXT_STEP`` (see
https://farama.org/Vector-Autoreset-Mode and ``gymnasium.vector.SyncVectorEnv``): the step that
ends an episode returns its last observation with ``terminated`` or ``truncated`` set; the next
step ignores that environment's action, resets it and returns the first observation of the new
episode with reward 0 and both flags false (its ``info`` entries are masked out).

Seeds follow ``SyncVectorEnv``: ``reset(seed=s)`` seeds environment ``i`` with ``s + i`` (a list
gives one seed per environment, ``None`` entries draw fresh entropy), and later episodes continue
each environment's generator. Each environment draws its episodes with the single env's own
function (``platoon.draw_episode``, ``merge.draw_episode``) and steps with a Rust port of the
single env's step, so a vector env gives the same observations, rewards and flags, bit for bit,
as ``gymnasium.make_vec(env_id, num_envs, vectorization_mode="sync")`` for the same seeds and
actions (python/tests/test_vec_env.py checks it).
"""

from __future__ import annotations

from typing import Any, Dict, List, Optional, Sequence, Union

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .. import _smlworld
from . import merge, platoon

#: The env ids ``make_vec`` knows.
VECTOR_ENVS = ("smlworld/PlatoonFollow-v0", "smlworld/HighwayMerge-v0", "smlworld/TrafficSignal-v0")

#: Info values that are flags (the others are floats).
_BOOL_INFO = ("merged", "collided")


class SmlworldVectorEnv(VectorEnv):
    """``num_envs`` copies of one smlworld environment stepped together in Rust (see the module
    documentation). Build it with :func:`make_vec`.

    ``copy=True`` (gymnasium's default) returns fresh arrays from :meth:`reset` and :meth:`step`;
    ``copy=False`` returns the env's own buffers, overwritten by the next call. ``threads`` caps
    the threads one step uses (``None``: the machine's cores, at most 4); results do not depend
    on it.
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, single_env, kind: str, scenario: str, params: dict, num_envs: int, threads=None, copy=True):
        num_envs = int(num_envs)
        if num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, got {num_envs}")
        self._single = single_env
        self.num_envs = num_envs
        self.copy = bool(copy)
        self.single_observation_space = single_env.observation_space
        self.single_action_space = single_env.action_space
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._core = _smlworld.VecCore(kind, scenario, num_envs, 0 if threads is None else int(threads), params)
        self._discrete = not hasattr(self.single_action_space, "shape") or self.single_action_space.shape == ()
        self._action_width = 1 if self._discrete else int(np.prod(self.single_action_space.shape))
        shape = (num_envs,) + tuple(self.single_observation_space.shape)
        self._obs = np.zeros(shape, dtype=np.float32)
        self._obs_rows = self._obs.reshape(num_envs, -1)  # a view: Rust writes rows of values
        self._rewards = np.zeros(num_envs, dtype=np.float64)
        self._terminated = np.zeros(num_envs, dtype=np.bool_)
        self._truncated = np.zeros(num_envs, dtype=np.bool_)
        self._reset = np.zeros(num_envs, dtype=np.bool_)
        self._info_keys = list(self._core.info_keys)
        self._info = np.zeros((num_envs, len(self._info_keys)), dtype=np.float64)
        self._rngs: List[Optional[np.random.Generator]] = [None] * num_envs
        self._started = False

    @property
    def threads(self) -> int:
        """Most threads one step uses."""
        return self._core.threads

    @property
    def np_random(self):
        """Each environment's generator (``SyncVectorEnv.np_random``)."""
        return tuple(self._rngs)

    # -- episodes ----------------------------------------------------------------------------
    def _draw(self, i: int) -> None:
        """Draw environment ``i``'s next episode from its generator and hand it to Rust."""
        rng = self._rngs[i]
        if isinstance(self._single, platoon.PlatoonFollowEnv):
            seed, targets = platoon.draw_episode(rng, self._single.max_steps, self._single.dt)
            self._core.set_episode(i, seed, np.asarray(targets, dtype=np.float64).reshape(-1, 2))
        else:
            self._core.set_episode(i, merge.draw_episode(rng))

    # -- gymnasium API -----------------------------------------------------------------------
    def reset(
        self,
        *,
        seed: Union[int, Sequence[Optional[int]], None] = None,
        options: Optional[Dict[str, Any]] = None,
    ):
        """Reset every environment (or those ``options["reset_mask"]`` selects), seeded as
        ``SyncVectorEnv.reset`` seeds them; returns ``(observations, {})``."""
        n = self.num_envs
        if seed is None:
            seeds = [None] * n
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(n)]
        else:
            seeds = list(seed)
            if len(seeds) != n:
                raise ValueError(f"seed is a list of {len(seeds)} seeds for num_envs={n}; give one per environment")
        mask = None
        if options is not None and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"])
            if mask.shape != (n,) or mask.dtype != np.bool_:
                raise ValueError(f"options['reset_mask'] must be a bool array of shape ({n},), got {mask.dtype} {mask.shape}")
            if not mask.any():
                raise ValueError("options['reset_mask'] selects no environment")
            if not self._started and not mask.all():
                raise ValueError("the first reset must reset every environment")
        selected = range(n) if mask is None else np.flatnonzero(mask)
        for i in selected:
            # A seed (or a first reset) makes a new generator; without one the episode drawn
            # after the last reset is the next one of the generator's stream.
            if seeds[i] is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(seeds[i])
                self._draw(i)
        self._core.reset(self._obs_rows, None if mask is None else np.ascontiguousarray(mask))
        for i in selected:
            self._draw(i)
            self._terminated[i] = self._truncated[i] = False
        self._started = True
        return (self._obs.copy() if self.copy else self._obs), {}

    def step(self, actions):
        """Step every environment with its row of ``actions`` (next-step autoreset: an
        environment whose episode ended at the last step is reset instead)."""
        if not self._started:
            raise RuntimeError("call reset() before step()")
        n = self.num_envs
        if self._discrete:
            a = np.asarray(actions)
            if a.size != n:
                raise ValueError(f"actions must hold one action per environment ({n}), got shape {a.shape}")
            a = a.reshape(n, 1).astype(np.int64).astype(np.float64)
        else:
            a = np.asarray(actions, dtype=np.float64)
            if a.size != n * self._action_width:
                raise ValueError(
                    f"actions must have shape {self.action_space.shape}, got {a.shape}"
                )
            a = np.ascontiguousarray(a.reshape(n, self._action_width))
        self._core.step(a, self._obs_rows, self._rewards, self._terminated, self._truncated, self._reset, self._info)
        reset = np.flatnonzero(self._reset)
        for i in reset:
            self._draw(int(i))
        infos = {}
        if self._info_keys:
            stepped = ~self._reset
            for k, key in enumerate(self._info_keys):
                # as SyncVectorEnv batches infos: a reset environment's entry is 0 / False
                col = np.where(stepped, self._info[:, k], 0.0)
                infos[key] = col.astype(np.bool_) if key in _BOOL_INFO else col
                infos["_" + key] = stepped.copy()
        if len(reset) == n:
            infos = {}
        return (
            self._obs.copy() if self.copy else self._obs,
            self._rewards.copy(),
            self._terminated.copy(),
            self._truncated.copy(),
            infos,
        )

    def times(self) -> np.ndarray:
        """Sim time of each environment's episode [s]."""
        return np.asarray(self._core.times())

    def close_extras(self, **kwargs):
        self._core = None


def _platoon(num_envs, threads, copy, dt=platoon.DT, max_steps=platoon.MAX_STEPS, render_mode=None):
    if render_mode is not None:
        raise ValueError("vector envs do not render; make a single env with gymnasium.make for frames")
    single = platoon.PlatoonFollowEnv(dt=dt, max_steps=max_steps)
    space = single.observation_space
    params = {
        "dt": single.dt,
        "max_steps": single.max_steps,
        "car_length": platoon.CAR_LENGTH,
        "a_min": platoon.A_MIN,
        "a_max": platoon.A_MAX,
        "obs_low": [float(x) for x in space.low],
        "obs_high": [float(x) for x in space.high],
    }
    return SmlworldVectorEnv(single, "platoon", platoon._scenario_path(), params, num_envs, threads, copy)


def _merge(num_envs, threads, copy, action="discrete", dt=merge.DT, max_steps=merge.MAX_STEPS, render_mode=None):
    if render_mode is not None:
        raise ValueError("vector envs do not render; make a single env with gymnasium.make for frames")
    single = merge.HighwayMergeEnv(action=action, dt=dt, max_steps=max_steps)
    params = {
        "dt": single.dt,
        "max_steps": single.max_steps,
        "continuous": single.action_type == "continuous",
        "a_min": merge.A_MIN,
        "a_max": merge.A_MAX,
        "target_speeds": list(merge.TARGET_SPEEDS),
        "initial_target": 2,
        "speed_gain": merge.SPEED_GAIN,
        "v_max": merge.V_MAX,
        "right_lane_top": merge.RIGHT_LANE_TOP,
        "lane_end_x": merge.LANE_END_X,
        "road_end_x": merge.ROAD_END_X,
        "nearest": merge.NEAREST,
        "footprint": tuple(merge.FOOTPRINT),
        "obs_scale": [float(x) for x in merge.OBS_SCALE.reshape(-1)],
    }
    return SmlworldVectorEnv(single, "merge", merge._scenario_path(), params, num_envs, threads, copy)


_MAKERS = {"smlworld/PlatoonFollow-v0": _platoon, "smlworld/HighwayMerge-v0": _merge}


def make_vec(
    env_id: str,
    num_envs: int = 1,
    seed: Optional[int] = None,
    threads: Optional[int] = None,
    copy: bool = True,
    **kwargs,
) -> SmlworldVectorEnv:
    """A vector env of ``num_envs`` copies of ``env_id`` ("smlworld/PlatoonFollow-v0" or
    "smlworld/HighwayMerge-v0"), stepped together in Rust; "smlworld/TrafficSignal-v0" gives
    :class:`smlworld.envs.traffic_signal.TrafficSignalVectorEnv` (its ``kwargs`` are the single
    env's: ``net_file``, ``route_file``, ...). For the other two ``kwargs`` are the single env's
    (``dt``, ``max_steps``; HighwayMerge-v0 also ``action="discrete"|"continuous"``). With a
    ``seed`` the envs are reset with it now (env ``i`` gets ``seed + i``); call ``reset()``
    yourself otherwise. ``threads`` and ``copy``: see :class:`SmlworldVectorEnv`.

        envs = smlworld.envs.make_vec("smlworld/PlatoonFollow-v0", num_envs=64, seed=0)
        obs, rewards, terminated, truncated, infos = envs.step(envs.action_space.sample())
    """
    if env_id == "smlworld/TrafficSignal-v0":
        from .traffic_signal import traffic_signal_vec

        env = traffic_signal_vec(num_envs, threads, **kwargs)
        if seed is not None:
            env.reset(seed=seed)
        return env
    maker = _MAKERS.get(env_id)
    if maker is None:
        raise ValueError(f"make_vec knows no env {env_id!r}; known: {', '.join(VECTOR_ENVS)}")
    # gymnasium.make_vec passes the spec's episode limit under its own name
    steps = kwargs.pop("max_episode_steps", None)
    if steps is not None:
        kwargs["max_steps"] = steps
    env = maker(num_envs, threads, copy, **kwargs)
    if seed is not None:
        env.reset(seed=seed)
    return env


def platoon_follow_vec(num_envs: int = 1, **kwargs) -> SmlworldVectorEnv:
    """Gymnasium's ``vector_entry_point`` of smlworld/PlatoonFollow-v0: ``gymnasium.make_vec``
    builds this vector env by default."""
    return make_vec("smlworld/PlatoonFollow-v0", num_envs=num_envs, **kwargs)


def highway_merge_vec(num_envs: int = 1, **kwargs) -> SmlworldVectorEnv:
    """Gymnasium's ``vector_entry_point`` of smlworld/HighwayMerge-v0."""
    return make_vec("smlworld/HighwayMerge-v0", num_envs=num_envs, **kwargs)
