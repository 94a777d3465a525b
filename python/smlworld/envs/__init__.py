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

``platoon_parallel_env(n=5)`` is the PettingZoo parallel version: every member behind the
scripted leader is an agent (see :mod:`smlworld.envs.platoon_parallel`).
"""

from __future__ import annotations

import gymnasium

from .platoon import PlatoonFollowEnv
from .platoon_parallel import PlatoonParallelEnv, platoon_parallel_env

__all__ = ["PlatoonFollowEnv", "PlatoonParallelEnv", "platoon_parallel_env"]

if "smlworld/PlatoonFollow-v0" not in gymnasium.registry:
    gymnasium.register(id="smlworld/PlatoonFollow-v0", entry_point="smlworld.envs.platoon:PlatoonFollowEnv")
