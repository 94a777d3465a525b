"""Gymnasium environments on SML World. Importing this module registers:

- ``smlworld/PlatoonFollow-v0``: one learning car behind a leader that varies its speed.
  Action: longitudinal acceleration [m/s^2] in [-6, 3]. Observation: own speed [m/s], gap to the
  leader [m] (bumper to bumper), relative speed (leader - own) [m/s], the leader's acceleration
  [m/s^2] as received over wifi (0 until the first message). Reward per step in [-1, 1]
  (:func:`smlworld.envs.platoon.step_reward`): ``1 - 2 * penalty``, the penalty weighing gap
  tracking ``((gap - gap_ref) / gap_ref)^2`` (0.8), comfort ``(a / 6)^2`` (0.1) and smoothness
  (0.1), each capped at 1, with ``gap_ref = 5 + 1.0 * v``; -1 and termination on collision
  (gap <= 0). 0.1 s per step,
  truncated after 600 steps (60 s). Bit-reproducible from ``reset(seed=...)``.

- ``smlworld/HighwayMerge-v0``: the learning car starts on the lane that ends (the GCDC 2016 lane
  drop, 300 m) and must merge into IDM traffic on the other lane. Actions: highway-env's
  DiscreteMetaAction (``0 LANE_LEFT, 1 IDLE, 2 LANE_RIGHT, 3 FASTER, 4 SLOWER``) by default,
  ``action="continuous"`` for ``[acceleration, lane-change request]``. Observation: a (6, 5)
  array like highway-env's Kinematics, rows the car then its 5 nearest vehicles, columns
  ``presence, x, y, vx, vy`` (the others relative to the car), scaled into [-1, 1]. Reward per
  step in [-1, 1] (:func:`smlworld.envs.merge.step_reward`): progress ``0.6 * v / 30`` plus 0.4
  once merged, -1 on a collision or when the lane ends under the car (both terminate; so does
  reaching x = 480 m). 0.5 s per step, truncated after 80 steps (40 s). Bit-reproducible from
  ``reset(seed=...)``.

``platoon_parallel_env(n=5)`` is the PettingZoo parallel version: every member behind the
scripted leader is an agent (see :mod:`smlworld.envs.platoon_parallel`).

- ``smlworld/TrafficSignal-v0``: traffic-signal control with sumo-rl's interface and defaults
  (``net_file``, ``route_file``, ``delta_time=5``, ``yellow_time=2``, ``min_green=5``,
  ``reward_fn="diff-waiting-time"``, ...): one traffic light, action the next green phase,
  observation sumo-rl's default (see :mod:`smlworld.envs.traffic_signal`, docs/signals.md).
  ``traffic_signal_parallel_env(net_file=..., route_file=...)`` is its PettingZoo parallel form,
  one agent per light.

``make_vec(env_id, num_envs=64, seed=0)`` gives either env as a ``gymnasium.vector.VectorEnv``
whose ``num_envs`` copies step together in Rust, in one call per step (see
:mod:`smlworld.envs.vector`); ``gymnasium.make_vec(env_id, num_envs)`` builds the same.
"""

from __future__ import annotations

import gymnasium

from .merge import HighwayMergeEnv
from .platoon import PlatoonFollowEnv
from .platoon_parallel import PlatoonParallelEnv, platoon_parallel_env
from .traffic_signal import TrafficSignalEnv, TrafficSignalParallelEnv, traffic_signal_parallel_env
from .vector import SmlworldVectorEnv, make_vec

__all__ = [
    "HighwayMergeEnv",
    "PlatoonFollowEnv",
    "PlatoonParallelEnv",
    "SmlworldVectorEnv",
    "TrafficSignalEnv",
    "TrafficSignalParallelEnv",
    "make_vec",
    "platoon_parallel_env",
    "traffic_signal_parallel_env",
]

from .. import ENV_KWARGS, ENVS, VECTOR_ENVS

for _id, _entry in ENVS.items():
    if _id not in gymnasium.registry:
        gymnasium.register(
            id=_id, entry_point=_entry, vector_entry_point=VECTOR_ENVS.get(_id), kwargs=ENV_KWARGS.get(_id, {})
        )
