"""``smlworld/TrafficSignal-v0`` and ``traffic_signal_parallel_env``: traffic-signal control with
sumo-rl's interface (issue 55; see docs/signals.md).

The constructor takes sumo-rl's ``SumoEnvironment`` names, defaults and meanings
(LucasAlegre/sumo-rl ``sumo_rl/environment/env.py``, version 1.4.5); a traffic signal, its green
phases, its yellow transitions, its observation and its rewards follow sumo-rl's
``TrafficSignal`` (``traffic_signal.py``) and ``DefaultObservationFunction``
(``observations.py``) line by line, on numbers the simulator measures in one Rust call per step
(``Core.signal_measures``: per incoming and outgoing lane its vehicle count, halting count
(speed < 0.1 m/s), summed vehicle length, summed speed / allowed speed and the vehicles'
accumulated waiting time, counted per lane as sumo-rl counts it).

What differs from sumo-rl: the vehicles are ours (IDM drivers on lanelets, at SUMO's 1 s step by
default: ``sim_step``), so numbers are close to SUMO's, not equal; a lane's allowed speed is its speed limit (SUMO takes the
lower of it and the vehicle's maximum speed); lanes are lanelet ids (ints), not SUMO lane ids.
Arguments sumo-rl has and this env does not support (``use_gui``, ``additional_sumo_cmd``,
``out_csv_name``, ...) raise a ValueError naming them when given a value other than sumo-rl's
default.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from collections import namedtuple
from pathlib import Path
from typing import Callable, Dict, Optional, Union

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from pettingzoo import ParallelEnv

import smlworld

from .. import _smlworld

from ._frames import rgb_frame

#: A program phase as sumo-rl builds them (``traci.trafficlight.Phase(duration, state)``).
Phase = namedtuple("Phase", ["duration", "state"])

#: sumo-rl's arguments this env does not support, with the value that means "not used" (the
#: value sumo-rl defaults to); any other value raises a ValueError naming the argument.
UNSUPPORTED = {
    "out_csv_name": None,
    "use_gui": False,
    "virtual_display": (3200, 1800),
    "max_depart_delay": -1,
    "time_to_teleport": -1,
    "sumo_warnings": True,
    "additional_sumo_cmd": None,
}


#: SUMO signal characters -> the ones the simulator shows for them, as it runs a SUMO program
#: (src/map/junctions.rs ``map_program``): ``u`` red, ``s`` and ``o`` yielding green, ``O``
#: green, ``Y`` yellow.
_AS_SHOWN = str.maketrans({"O": "G", "s": "g", "o": "g", "Y": "y", "u": "r"})

#: States in the file's characters -> as shown (``_AS_SHOWN``), translated once each.
_SHOWN: Dict[str, str] = {}


class TrafficSignal:
    """One traffic light as sumo-rl's ``TrafficSignal`` presents it to observation and reward
    functions: the same attributes (``id``, ``green_phase``, ``is_yellow``,
    ``time_since_last_phase_change``, ``lanes``, ``out_lanes``, ``lanes_length``,
    ``num_green_phases``, ``green_phases``, ``yellow_dict``, ``all_phases``, ``min_green``,
    ``max_green``, ``yellow_time``, ``delta_time``, ``last_measure``, ``last_reward``) and
    methods (``get_lanes_density``, ``get_lanes_queue``, ``get_out_lanes_density``,
    ``get_total_queued``, ``get_accumulated_waiting_time_per_lane``, ``get_average_speed``,
    ``get_pressure``). The numbers are those of the env's last measurement."""

    # SUMO's default minimum gap [m] (sumo-rl ``TrafficSignal.MIN_GAP``).
    MIN_GAP = 2.5

    def __init__(self, env, ts_id: str, light: dict, in_slots: np.ndarray, out_slots: np.ndarray, reward_fn):
        self.id = ts_id
        self.env = env
        self.junction = int(light["junction"])
        self.delta_time = env.delta_time
        self.yellow_time = env.yellow_time
        self.min_green = env.min_green
        self.max_green = env.max_green
        self.green_phase = 0
        self.is_yellow = False
        self.time_since_last_phase_change = 0
        self.next_action_time = env.begin_time
        self._green_start = env.begin_time  # when the green shown now came on [s]
        self._shown = None
        self.last_measure = 0.0
        self.last_reward = None
        if isinstance(reward_fn, str):
            if reward_fn not in TrafficSignal.reward_fns:
                raise NotImplementedError(f"Reward function {reward_fn} not implemented")
            reward_fn = TrafficSignal.reward_fns[reward_fn]
        elif not callable(reward_fn):
            raise ValueError(
                f"reward_fn must be a name of {sorted(TrafficSignal.reward_fns)} or a callable, got {reward_fn!r}"
            )
        self.reward_fn = reward_fn
        # The light's lanes in the measurement's arrays: consecutive slots, read as views
        # (a slice, not an index array: no copy per read).
        self._in = slice(int(in_slots[0]), int(in_slots[-1]) + 1) if len(in_slots) else slice(0, 0)
        self._out = slice(int(out_slots[0]), int(out_slots[-1]) + 1) if len(out_slots) else slice(0, 0)
        self.lanes = list(light["lanes"])
        self.out_lanes = list(light["out_lanes"])
        lengths = env._layout["slot_length"]
        self.lanes_length = {
            lane: float(lengths[k])
            for lane, k in zip(self.lanes + self.out_lanes, np.concatenate([in_slots, out_slots]))
        }
        self._build_phases([Phase(d, s) for s, (_, d) in zip(light["file_states"], light["phases"])])
        self.observation_fn = env.observation_class(self)
        self.observation_space = self.observation_fn.observation_space()
        self.action_space = spaces.Discrete(self.num_green_phases)

    def _build_phases(self, phases):
        """sumo-rl ``TrafficSignal._build_phases``: green phases are the program's phases without
        ``y`` that are not all red; a yellow phase for every ordered pair of green phases turns
        ``G``/``g`` that go red to ``y``."""
        if self.env.fixed_ts:
            self.num_green_phases = len(phases) // 2
            return
        self.green_phases = []
        self.yellow_dict = {}
        for phase in phases:
            state = phase.state
            if "y" not in state and (state.count("r") + state.count("s") != len(state)):
                self.green_phases.append(Phase(60, state))
        if not self.green_phases:
            raise ValueError(f"traffic light {self.id}: its program has no green phase (sumo-rl needs one)")
        self.num_green_phases = len(self.green_phases)
        self.all_phases = self.green_phases.copy()
        for i, p1 in enumerate(self.green_phases):
            for j, p2 in enumerate(self.green_phases):
                if i == j:
                    continue
                yellow_state = ""
                for s in range(len(p1.state)):
                    if (p1.state[s] == "G" or p1.state[s] == "g") and (p2.state[s] == "r" or p2.state[s] == "s"):
                        yellow_state += "y"
                    else:
                        yellow_state += p1.state[s]
                self.yellow_dict[(i, j)] = len(self.all_phases)
                self.all_phases.append(Phase(self.yellow_time, yellow_state))
        self._show(self.all_phases[0].state)

    def _show(self, state: str):
        """Hold ``state`` (in the file's characters) at the light (sumo-rl
        ``setRedYellowGreenState``; a state already held is not sent again), shown as the
        simulator shows the file's program (``map_program`` in src/map/junctions.rs)."""
        if state != self._shown:
            shown = _SHOWN.get(state)
            if shown is None:
                shown = _SHOWN[state] = state.translate(_AS_SHOWN)
            # The junction id was checked when the env was made: straight to the core.
            self.env._sim._core.set_phase(self.junction, shown)
            self._shown = state

    @property
    def time_to_act(self) -> bool:
        """Whether the light acts at this step (sumo-rl ``TrafficSignal.time_to_act``)."""
        return self.next_action_time == self.env._t

    def update(self, seconds: int = 1):
        """``seconds`` of sumo-rl's per-second ``update``: the yellow ends after ``yellow_time``."""
        self.time_since_last_phase_change += seconds
        if self.is_yellow and self.time_since_last_phase_change >= self.yellow_time:
            self._show(self.all_phases[self.green_phase].state)
            self.is_yellow = False
            self._green_start = self.env.sim_step

    def set_next_phase(self, new_phase: int):
        """sumo-rl ``set_next_phase``: keep the green, or show the yellow towards ``new_phase``
        (only after ``yellow_time + min_green`` in the current phase). With the env's
        ``enforce_max_green``, a green held ``max_green`` seconds or more moves on to the next
        green phase whatever the action and ``min_green`` (sumo-rl 1.4.5 ignores ``max_green``)."""
        new_phase = int(new_phase)
        if not 0 <= new_phase < self.num_green_phases:
            raise ValueError(
                f"traffic light {self.id}: action {new_phase} is not a green phase index "
                f"in [0, {self.num_green_phases})"
            )
        forced = (
            self.env.enforce_max_green
            and not self.is_yellow
            and self.num_green_phases > 1
            and self.env.sim_step + self.delta_time - self._green_start > self.max_green
        )
        if forced and new_phase == self.green_phase:
            new_phase = (self.green_phase + 1) % self.num_green_phases
        if self.green_phase == new_phase or (
            not forced and self.time_since_last_phase_change < self.yellow_time + self.min_green
        ):
            self._show(self.all_phases[self.green_phase].state)
            self.next_action_time = self.env.sim_step + self.delta_time
        else:
            self._show(self.all_phases[self.yellow_dict[(self.green_phase, new_phase)]].state)
            self.green_phase = new_phase
            self.next_action_time = self.env.sim_step + self.delta_time
            self.is_yellow = True
            self.time_since_last_phase_change = 0

    def compute_observation(self):
        return self.observation_fn()

    def compute_reward(self):
        self.last_reward = self.reward_fn(self)
        return self.last_reward

    # -- sumo-rl's rewards ----------------------------------------------------------------
    def _pressure_reward(self):
        return self.get_pressure()

    def _average_speed_reward(self):
        return self.get_average_speed()

    def _queue_reward(self):
        return -self.get_total_queued()

    def _diff_waiting_time_reward(self):
        ts_wait = sum(self.get_accumulated_waiting_time_per_lane()) / 100.0
        reward = self.last_measure - ts_wait
        self.last_measure = ts_wait
        return reward

    # -- sumo-rl's measurements -----------------------------------------------------------
    def get_accumulated_waiting_time_per_lane(self):
        """Accumulated waiting time [s] of the vehicles on each incoming lane, a vehicle's
        waiting split over the lanes it waited on as sumo-rl splits it."""
        return self.env._measures["waiting"][self._in].tolist()

    def get_average_speed(self) -> float:
        """Mean of speed / allowed speed over the vehicles on the incoming lanes; 1.0 with none."""
        m = self.env._measures
        n = m["count"][self._in].sum()
        if n == 0:
            return 1.0
        return float(m["speed_ratio_sum"][self._in].sum() / n)

    def get_pressure(self):
        """Vehicles on the outgoing lanes minus vehicles on the incoming lanes."""
        m = self.env._measures["count"]
        return int(m[self._out].sum() - m[self._in].sum())

    def get_out_lanes_density(self):
        return self.env._measures["density"][self._out].tolist()

    def get_lanes_density(self):
        """Vehicles on each incoming lane over the vehicles that fit, capped at 1."""
        return self.env._measures["density"][self._in].tolist()

    def get_lanes_queue(self):
        """Halting vehicles (speed < 0.1 m/s) on each incoming lane over the vehicles that fit,
        capped at 1."""
        return self.env._measures["queue"][self._in].tolist()

    def get_total_queued(self) -> int:
        """Halting vehicles on the incoming lanes."""
        return int(self.env._measures["halting"][self._in].sum())

    @classmethod
    def register_reward_fn(cls, fn: Callable):
        if fn.__name__ in cls.reward_fns:
            raise KeyError(f"Reward function {fn.__name__} already exists")
        cls.reward_fns[fn.__name__] = fn

    reward_fns = {
        "diff-waiting-time": _diff_waiting_time_reward,
        "average-speed": _average_speed_reward,
        "queue": _queue_reward,
        "pressure": _pressure_reward,
    }


class ObservationFunction:
    """sumo-rl's ``ObservationFunction``: built with the traffic signal, ``__call__`` gives the
    observation and ``observation_space()`` its space."""

    def __init__(self, ts: TrafficSignal):
        self.ts = ts

    def __call__(self):
        raise NotImplementedError

    def observation_space(self):
        raise NotImplementedError


class DefaultObservationFunction(ObservationFunction):
    """sumo-rl's ``DefaultObservationFunction``: one-hot green phase, the min-green flag, then
    every incoming lane's density and every incoming lane's queue, all in [0, 1] (float32)."""

    def __call__(self) -> np.ndarray:
        ts = self.ts
        n = ts.num_green_phases
        m = ts.env._measures
        density = m["density"][ts._in]
        k = n + 1 + len(density)
        # Filled in place: the same float32 numbers as sumo-rl's list of one-hot phase, flag,
        # densities and queues.
        out = np.zeros(k + len(density), dtype=np.float32)
        if 0 <= ts.green_phase < n:
            out[ts.green_phase] = 1.0
        out[n] = 0.0 if ts.time_since_last_phase_change < ts.min_green + ts.yellow_time else 1.0
        out[n + 1 : k] = density
        out[k:] = m["queue"][ts._in]
        return out

    def observation_space(self) -> spaces.Box:
        n = self.ts.num_green_phases + 1 + 2 * len(self.ts.lanes)
        return spaces.Box(low=np.zeros(n, dtype=np.float32), high=np.ones(n, dtype=np.float32))


#: The rates of the scenario defaults that ``sim_step`` caps (src/sim/schedule.rs ``Rates``):
#: control and sensors run at most this fast [Hz], as ``smlworld run x.sumocfg`` maps SUMO's
#: ``step-length`` (src/app/running/scenario/sumocfg.rs).
_CAPPED_RATES = {"control": 20.0, "sensors": 20.0, "wifi": 10.0, "network": 1.0}


def sumo_rl_nets() -> Path:
    """sumo-rl's ``nets`` folder (its ``2way-single-intersection``, ``4x4-Lucas``, ``RESCO`` ...):
    ``$SUMO_RL_NETS`` if set, else the installed ``sumo_rl`` package's, found without importing it
    (importing sumo_rl needs SUMO_HOME). Raises ``FileNotFoundError`` naming both ways when neither
    gives one."""
    if "SUMO_RL_NETS" in os.environ:
        return Path(os.environ["SUMO_RL_NETS"])
    import importlib.util

    spec = importlib.util.find_spec("sumo_rl")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError(
            "sumo-rl's nets not found: `pip install sumo-rl`, or set SUMO_RL_NETS to a folder with its nets"
        )
    return Path(spec.submodule_search_locations[0]) / "nets"


def _step_rates(sim_step, sumo_files: bool) -> dict:
    """Scenario overrides for the simulation step ``sim_step`` [s] (SUMO's ``--step-length``):
    dynamics at ``1 / sim_step``, the other modules at most that fast. ``None`` gives SUMO's
    default step, 1 s, for SUMO files (what sumo-rl runs: it passes no ``--step-length``) and
    no override with ``scenario=`` (its own ``[rates]``). The step must divide a second into
    whole steps: sumo-rl advances the simulation in whole seconds."""
    if sim_step is None:
        if not sumo_files:
            return {}
        sim_step = 1.0
    if isinstance(sim_step, bool) or not isinstance(sim_step, (int, float, np.integer, np.floating)):
        raise ValueError(f"sim_step must be a number of seconds such as 1.0 or 0.1, got {sim_step!r}")
    sim_step = float(sim_step)
    steps = 1.0 / sim_step if math.isfinite(sim_step) and 0.0 < sim_step <= 1.0 else float("nan")
    if not (math.isfinite(steps) and abs(steps - round(steps)) < 1e-9 * max(1.0, steps)):
        raise ValueError(
            f"sim_step must divide one second into whole steps (1.0, 0.5, 0.25, 0.2, 0.1, ..., as sumo-rl "
            f"steps the simulation in whole seconds), got {sim_step!r}"
        )
    hz = float(round(steps))
    out = {"rates.dynamics": hz}
    out.update({f"rates.{k}": min(v, hz) for k, v in _CAPPED_RATES.items()})
    return out


def _scenario_text(net_file, route_file, begin_time, num_seconds) -> str:
    net = Path(net_file).resolve()
    routes = [Path(r).resolve() for r in str(route_file).split(",")]
    for p in [net] + routes:
        if not p.exists():
            raise FileNotFoundError(f"{p} does not exist")
    demand = ", ".join(f'"{p.as_posix()}"' for p in routes)
    return (
        f'seed = 0\nduration = {float(num_seconds) + 1.0}\nmap = "{net.as_posix()}"\n'
        f"demand = [{demand}]\ndemand_begin = {float(begin_time)}\n"
    )


class TrafficSignalEnv(gym.Env):
    """sumo-rl's ``SumoEnvironment`` on SML World (see the module documentation).

    ``net_file`` a SUMO ``.net.xml`` (or any map of ours with traffic lights), ``route_file`` a
    SUMO ``.rou.xml`` (several comma-separated); or ``scenario`` a scenario file whose map has
    traffic lights and whose ``[[traffic]]`` or ``demand`` is the demand (``net_file``, if given
    too, replaces its map). ``single_agent=True`` (what ``gymnasium.make("smlworld/TrafficSignal-v0")``
    gives): a plain gymnasium env controlling light ``ts_id`` (default: the first); else sumo-rl's
    multi-agent dict API (``step`` returns observations, rewards, dones, info dicts). Extra:
    ``enforce_max_green`` (a green is never held longer than ``max_green``), ``sim_step`` (the
    simulation step [s], SUMO's ``--step-length``: default 1 s for SUMO files as sumo-rl runs
    SUMO, the scenario's rates with ``scenario=``; it must divide a second, e.g. 0.5 or 0.02 for
    the 50/20 Hz scenario defaults; docs/signals.md "Simulation step"), ``overrides`` (scenario
    overrides such as ``{"rates.dynamics": 10.0}``, winning over ``sim_step``).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 1}

    def __init__(
        self,
        net_file: Optional[str] = None,
        route_file: Optional[str] = None,
        *,
        scenario: Optional[str] = None,
        begin_time: int = 0,
        num_seconds: int = 20000,
        waiting_time_memory: int = 1000,
        delta_time: int = 5,
        yellow_time: int = 2,
        min_green: int = 5,
        max_green: int = 50,
        single_agent: bool = False,
        reward_fn: Union[str, Callable, dict] = "diff-waiting-time",
        observation_class=DefaultObservationFunction,
        add_system_info: bool = True,
        add_per_agent_info: bool = True,
        sumo_seed: Union[str, int] = "random",
        fixed_ts: bool = False,
        render_mode: Optional[str] = None,
        enforce_max_green: bool = False,
        ts_id: Optional[str] = None,
        sim_step: Optional[float] = None,
        overrides: Optional[dict] = None,
        **sumo_rl_only,
    ):
        for name, value in sumo_rl_only.items():
            if name not in UNSUPPORTED:
                raise TypeError(f"TrafficSignalEnv got an unexpected keyword argument {name!r}")
            if value != UNSUPPORTED[name]:
                raise ValueError(
                    f"{name}={value!r} is a sumo-rl argument this env does not support; leave it at "
                    f"{UNSUPPORTED[name]!r} (see docs/signals.md)"
                )
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        for name, v in [
            ("delta_time", delta_time),
            ("yellow_time", yellow_time),
            ("min_green", min_green),
            ("max_green", max_green),
            ("num_seconds", num_seconds),
            ("begin_time", begin_time),
        ]:
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
                raise ValueError(
                    f"{name} must be a whole number of seconds >= 0 (sumo-rl steps SUMO in 1 s), got {v!r}"
                )
        step_rates = _step_rates(sim_step, scenario is None)
        if not delta_time > yellow_time:
            raise ValueError(
                f"delta_time ({delta_time}) must be greater than yellow_time ({yellow_time}), as sumo-rl asserts"
            )
        if scenario is None and (net_file is None or route_file is None):
            raise ValueError(
                "give net_file and route_file (SUMO files), or scenario=... (a scenario with traffic lights)"
            )
        if not (
            sumo_seed == "random"
            or (isinstance(sumo_seed, (int, np.integer)) and not isinstance(sumo_seed, bool) and sumo_seed >= 0)
        ):
            raise ValueError(f"sumo_seed must be 'random' or an int >= 0, got {sumo_seed!r}")
        self.render_mode = render_mode
        self._net = net_file
        self._route = route_file
        self.begin_time = int(begin_time)
        self.sim_max_time = self.begin_time + int(num_seconds)
        self.delta_time = int(delta_time)
        self.yellow_time = int(yellow_time)
        self.min_green = int(min_green)
        self.max_green = int(max_green)
        self.waiting_time_memory = waiting_time_memory
        self.single_agent = bool(single_agent)
        self.reward_fn = reward_fn
        self.observation_class = observation_class
        self.add_system_info = add_system_info
        self.add_per_agent_info = add_per_agent_info
        self.sumo_seed = sumo_seed
        self.fixed_ts = bool(fixed_ts)
        self.enforce_max_green = bool(enforce_max_green)
        self.sim_step_length = 1.0 / step_rates["rates.dynamics"] if step_rates else None
        # Explicit ``overrides`` win over ``sim_step``'s rates.
        self._overrides = {**step_rates, **dict(overrides or {})}

        if scenario is not None:
            if route_file is not None:
                raise ValueError("give either route_file or scenario, not both")
            if net_file is not None:
                self._overrides.setdefault("map", str(Path(net_file).resolve()))
            self._sim = smlworld.Sim.from_scenario(scenario, seed=0, **self._overrides)
        else:
            d = tempfile.mkdtemp(prefix="smlworld-signals-")
            try:
                path = os.path.join(d, "signals.toml")
                with open(path, "w") as f:
                    f.write(_scenario_text(net_file, route_file, begin_time, num_seconds))
                self._sim = smlworld.Sim.from_scenario(path, seed=0, **self._overrides)
            finally:
                shutil.rmtree(d, ignore_errors=True)
        self._sim.stop_metrics()
        self._layout = self._sim._core.signal_layout()
        lights = self._layout["lights"]
        if not lights:
            raise ValueError(f"{scenario or net_file} has no traffic light to control")
        names = [str(light["name"]) for light in lights]
        if len(set(names)) != len(names):
            # A SUMO light split into several junctions here (docs/sumo.md): one agent each.
            names = [f"{light['name']}#{light['junction']}" for light in lights]
        self._lights = dict(zip(names, lights))
        # In SUMO's order (``trafficlight.getIDList``: sorted by id; junction ids by number).
        self.ts_ids = sorted(names, key=lambda n: (0, int(n), "") if n.isdigit() else (1, 0, n))
        if isinstance(reward_fn, dict):
            unknown = set(reward_fn) - set(self.ts_ids)
            if unknown:
                raise ValueError(
                    f"reward_fn names unknown traffic lights {sorted(unknown)}; the lights are {self.ts_ids}"
                )
            self.ts_ids = [t for t in self.ts_ids if t in reward_fn]
        if ts_id is not None:
            if ts_id not in self.ts_ids:
                raise ValueError(
                    f"ts_id {ts_id!r} is not a traffic light of {scenario or net_file}; the lights are {self.ts_ids}"
                )
            self.ts_ids = [ts_id] + [t for t in self.ts_ids if t != ts_id]
        # Lane slots of each light: its incoming lanes come first in the layout, light by light,
        # then the outgoing ones.
        self._slots = {}
        k_in = 0
        k_out = sum(len(light["lanes"]) for light in lights)
        for name, light in self._lights.items():
            n_in, n_out = len(light["lanes"]), len(light["out_lanes"])
            self._slots[name] = (np.arange(k_in, k_in + n_in), np.arange(k_out, k_out + n_out))
            k_in += n_in
            k_out += n_out
        self.vehicles = {}
        self.episode = 0
        self.metrics = []
        self.reward_range = (-float("inf"), float("inf"))
        self._started = False
        self._make_signals()
        self.observations = {ts: None for ts in self.ts_ids}
        self.rewards = {ts: None for ts in self.ts_ids}

    def _make_signals(self):
        self._t = self.begin_time
        self._sim._core.set_waiting_memory(float(self.waiting_time_memory))
        self._measure()
        self.traffic_signals = {
            ts: TrafficSignal(
                self,
                ts,
                self._lights[ts],
                *self._slots[ts],
                self.reward_fn[ts] if isinstance(self.reward_fn, dict) else self.reward_fn,
            )
            for ts in self.ts_ids
        }

    def _measure(self):
        """One measurement of every light's lanes (one Rust call), with every lane's density
        and queue as sumo-rl computes them: vehicles (halting vehicles) over the vehicles that
        fit, ``length / (MIN_GAP + mean vehicle length)``, capped at 1."""
        m = self._sim._core.signal_measures()
        count = m["count"]
        mean_length = np.divide(m["length_sum"], count, out=np.zeros_like(count), where=count > 0)
        capacity = self._layout["slot_length"] / (TrafficSignal.MIN_GAP + mean_length)
        m["density"] = np.minimum(1.0, count / capacity)
        m["queue"] = np.minimum(1.0, m["halting"] / capacity)
        self._measures = m

    @property
    def sim_step(self) -> int:
        """Sim time [s] (whole seconds, as sumo-rl's steps of 1 s give)."""
        return self._t

    @property
    def observation_space(self):
        return self.traffic_signals[self.ts_ids[0]].observation_space

    @property
    def action_space(self):
        return self.traffic_signals[self.ts_ids[0]].action_space

    def observation_spaces(self, ts_id: str):
        return self.traffic_signals[ts_id].observation_space

    def action_spaces(self, ts_id: str):
        return self.traffic_signals[ts_id].action_space

    def reset(self, seed: Optional[int] = None, options=None, **kwargs):
        """Start a new episode at ``begin_time``. ``seed`` (or else an int ``sumo_seed``) seeds
        the simulation; with neither, a seed is drawn from the env's generator."""
        super().reset(seed=seed, **kwargs)
        self.episode += 1
        self.metrics = []
        if seed is not None:
            self.sumo_seed = int(seed)
        sim_seed = int(self.np_random.integers(0, 2**31 - 1)) if self.sumo_seed == "random" else int(self.sumo_seed)
        self._sim.restart(sim_seed)
        self._started = True
        self._make_signals()
        self.vehicles = {}
        if self.single_agent:
            return self._compute_observations()[self.ts_ids[0]], self._compute_info()
        return self._compute_observations()

    def _advance(self, seconds: int):
        if seconds > 0:
            self._sim.step(float(seconds))
            self._t += seconds

    def step(self, action):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        if self._start_step(action):
            self._advance(self.delta_time)
        else:
            self._run_steps()
        return self._finish_step()

    def _start_step(self, action) -> bool:
        """Apply ``action``; True when the step just lets the program run (``fixed_ts`` or no
        action, as sumo-rl's ``step``)."""
        if self.fixed_ts or action is None or (isinstance(action, dict) and action == {}):
            return True
        self._apply_actions(action)
        return False

    def _finish_step(self):
        self._measure()
        acting = self._acting()
        observations = self._compute_observations(acting)
        rewards = self._compute_rewards(acting)
        dones = self._compute_dones()
        truncated = dones["__all__"]
        info = self._compute_info()
        if self.single_agent:
            ts = self.ts_ids[0]
            return observations[ts], rewards[ts], False, truncated, info
        return observations, rewards, dones, info

    def _run_steps(self):
        """sumo-rl ``_run_steps`` (1 s steps until a light acts), stepping straight to the next
        event (a yellow's end, a light's action time) instead of second by second."""
        while True:
            seconds = self._next_event()
            self._advance(seconds)
            if self._arrive(seconds):
                return

    def _next_event(self) -> int:
        """Seconds to the next event: a light's yellow ends or a light acts."""
        t = self.sim_step
        events = [ts.next_action_time for ts in self.traffic_signals.values() if ts.next_action_time > t]
        events += [
            t + ts.yellow_time - ts.time_since_last_phase_change
            for ts in self.traffic_signals.values()
            if ts.is_yellow and ts.time_since_last_phase_change < ts.yellow_time
        ]
        return (min(events) if events else t + 1) - t

    def _arrive(self, seconds: int) -> bool:
        """After the sim advanced ``seconds``: sumo-rl's per-second ``update`` of every light;
        True when a light acts now."""
        for ts in self.traffic_signals.values():
            ts.update(seconds)
        return any(ts.time_to_act for ts in self.traffic_signals.values())

    def _apply_actions(self, actions):
        if self.single_agent:
            ts = self.traffic_signals[self.ts_ids[0]]
            if ts.time_to_act:
                ts.set_next_phase(int(np.asarray(actions).reshape(-1)[0]))
        else:
            if not isinstance(actions, dict):
                raise ValueError(
                    f"actions must be a dict {{ts_id: green phase}} with single_agent=False, got {actions!r}"
                )
            for ts, action in actions.items():
                if ts not in self.traffic_signals:
                    raise ValueError(f"unknown traffic light {ts!r}; the lights are {self.ts_ids}")
                if self.traffic_signals[ts].time_to_act:
                    self.traffic_signals[ts].set_next_phase(action)

    def _compute_dones(self):
        dones = {ts_id: False for ts_id in self.ts_ids}
        dones["__all__"] = self.sim_step >= self.sim_max_time
        return dones

    def _acting(self):
        """The lights that act now (all with ``fixed_ts``), in ``ts_ids`` order."""
        if self.fixed_ts:
            return self.ts_ids
        t = self._t
        return [ts for ts in self.ts_ids if self.traffic_signals[ts].next_action_time == t]

    def _compute_observations(self, acting=None):
        acting = self._acting() if acting is None else acting
        for ts in acting:
            self.observations[ts] = self.traffic_signals[ts].compute_observation()
        return {ts: self.observations[ts].copy() for ts in acting}

    def _compute_rewards(self, acting=None):
        acting = self._acting() if acting is None else acting
        for ts in acting:
            self.rewards[ts] = self.traffic_signals[ts].compute_reward()
        return {ts: self.rewards[ts] for ts in acting}

    def _get_system_info(self):
        """sumo-rl ``_get_system_info``: halting vehicles, their summed and mean waiting time [s]
        (the current stop's, SUMO's ``getWaitingTime``) and mean speed [m/s]."""
        m = self._measures
        n = m["running"]
        return {
            "system_total_stopped": int(m["stopped"]),
            "system_total_waiting_time": float(m["total_waiting"]),
            "system_mean_waiting_time": 0.0 if n == 0 else float(m["total_waiting"]) / n,
            "system_mean_speed": 0.0 if n == 0 else float(m["total_speed"]) / n,
        }

    def _get_per_agent_info(self):
        info = {}
        total_stopped = 0
        total_waiting = 0
        for ts in self.ts_ids:
            signal = self.traffic_signals[ts]
            stopped = signal.get_total_queued()
            waiting = sum(signal.get_accumulated_waiting_time_per_lane())
            info[f"{ts}_stopped"] = stopped
            info[f"{ts}_accumulated_waiting_time"] = waiting
            info[f"{ts}_average_speed"] = signal.get_average_speed()
            total_stopped += stopped
            total_waiting += waiting
        info["agents_total_stopped"] = total_stopped
        info["agents_total_accumulated_waiting_time"] = total_waiting
        return info

    def _compute_info(self):
        info = {"step": self.sim_step}
        if self.add_system_info:
            info.update(self._get_system_info())
        if self.add_per_agent_info:
            info.update(self._get_per_agent_info())
        self.metrics.append(info.copy())
        return info

    def render(self):
        """With ``render_mode="rgb_array"``: the bird's-eye view now (640 x 360 RGB)."""
        return rgb_frame(self)

    def close(self):
        pass

    # sumo-rl's helpers for tabular agents (``SumoEnvironment.encode``).
    def encode(self, state, ts_id):
        n = self.traffic_signals[ts_id].num_green_phases
        phase = int(np.where(state[:n] == 1)[0][0])
        min_green = state[n]
        density_queue = [self._discretize_density(d) for d in state[n + 1 :]]
        return tuple([phase, min_green] + density_queue)

    def _discretize_density(self, density):
        return min(int(density * 10), 9)


class TrafficSignalParallelEnv(ParallelEnv):
    """One agent per traffic light, all acting every ``delta_time`` seconds (PettingZoo
    ``ParallelEnv``); the arguments are :class:`TrafficSignalEnv`'s. ``infos[agent]`` holds the
    system metrics and that light's own (``{ts}_stopped`` ...), as sumo-rl's PettingZoo env."""

    metadata = {"render_modes": ["rgb_array"], "name": "smlworld_traffic_signal_v0", "is_parallelizable": True}

    def __init__(self, **kwargs):
        if kwargs.pop("single_agent", False):
            raise ValueError(
                "traffic_signal_parallel_env has one agent per light; for one agent use "
                "gymnasium.make('smlworld/TrafficSignal-v0')"
            )
        self.env = TrafficSignalEnv(single_agent=False, **kwargs)
        self.render_mode = self.env.render_mode
        self.possible_agents = list(self.env.ts_ids)
        self.agents = []
        self.observation_spaces = {a: self.env.observation_spaces(a) for a in self.possible_agents}
        self.action_spaces = {a: self.env.action_spaces(a) for a in self.possible_agents}

    def observation_space(self, agent):
        return self.observation_spaces[agent]

    def action_space(self, agent):
        return self.action_spaces[agent]

    def _infos(self, info):
        out = {a: {} for a in self.agents}
        for a in self.agents:
            for k, v in info.items():
                if k.startswith(a) or k.startswith("system"):
                    out[a][k] = v
        return out

    def reset(self, seed: Optional[int] = None, options=None):
        self.agents = list(self.possible_agents)
        obs = self.env.reset(seed=seed, options=options)
        return obs, self._infos(self.env._compute_info())

    def step(self, actions: Dict[str, int]):
        if not self.agents:
            raise RuntimeError("the episode is over: call reset()")
        obs, rewards, dones, info = self.env.step(dict(actions))
        infos = self._infos(info)
        done = bool(dones["__all__"])
        terminations = {a: False for a in self.agents}
        truncations = {a: done for a in self.agents}
        if done:
            self.agents = []
        return obs, rewards, terminations, truncations, infos

    def render(self):
        return self.env.render()

    def close(self):
        self.env.close()

    @property
    def _sim(self):
        return self.env._sim


def traffic_signal_parallel_env(**kwargs) -> TrafficSignalParallelEnv:
    """sumo-rl's ``parallel_env`` on SML World: a PettingZoo ``ParallelEnv`` with one agent per
    traffic light (arguments as :class:`TrafficSignalEnv`)."""
    return TrafficSignalParallelEnv(**kwargs)


class TrafficSignalVectorEnv(VectorEnv):
    """``num_envs`` copies of ``smlworld/TrafficSignal-v0`` whose simulations advance together:
    every stretch of sim time between two signal events (a yellow's end, the next action) is one
    Rust call for all copies (``_smlworld.step_many``: side by side on the thread pool, the GIL
    released). The lights' logic stays the single env's Python, so each copy gives the single
    env's observations, rewards and flags for the same seed and actions.

    Autoreset as gymnasium's default ``NEXT_STEP`` (as :mod:`smlworld.envs.vector`): the step
    after an episode's end resets that copy, ignores its action and returns its first
    observation with reward 0. ``reset(seed=s)`` seeds copy ``i`` with ``s + i``. ``threads``
    caps the threads of one step (``None``: the default pool, at most 4).
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, threads: Optional[int] = None, **kwargs):
        num_envs = int(num_envs)
        if num_envs < 1:
            raise ValueError(f"num_envs must be at least 1, got {num_envs}")
        if not kwargs.pop("single_agent", True):
            raise ValueError("the vector env has one agent per copy (single_agent=True)")
        self.envs = [TrafficSignalEnv(single_agent=True, **kwargs) for _ in range(num_envs)]
        self.num_envs = num_envs
        self.threads = 0 if threads is None else int(threads)
        self.single_observation_space = self.envs[0].observation_space
        self.single_action_space = self.envs[0].action_space
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._autoreset = np.zeros(num_envs, dtype=bool)

    def reset(self, *, seed=None, options=None):
        if seed is None or isinstance(seed, (int, np.integer)):
            seeds = [None if seed is None else int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"reset: {len(seeds)} seeds for {self.num_envs} envs")
        obs, infos = [], {}
        for i, (env, s) in enumerate(zip(self.envs, seeds)):
            o, info = env.reset(seed=s, options=options)
            obs.append(o)
            infos = self._add_info(infos, info, i)
        self._autoreset[:] = False
        return np.stack(obs), infos

    def _advance_all(self, envs, seconds):
        _smlworld.step_many([e._sim._core for e in envs], [float(s) for s in seconds], self.threads)
        for e, s in zip(envs, seconds):
            e._t += int(s)

    def step(self, actions):
        actions = np.asarray(actions).reshape(self.num_envs, -1)
        if not all(e._started for e in self.envs):
            raise RuntimeError("call reset() before step()")
        moving = [i for i in range(self.num_envs) if not self._autoreset[i]]
        running, fixed = [], []
        for i in moving:
            (fixed if self.envs[i]._start_step(int(actions[i, 0])) else running).append(self.envs[i])
        if fixed:
            self._advance_all(fixed, [e.delta_time for e in fixed])
        # Every copy to its next signal event in one call, until each copy's lights act.
        while running:
            seconds = [e._next_event() for e in running]
            self._advance_all(running, seconds)
            running = [e for e, s in zip(running, seconds) if not e._arrive(s)]
        obs = np.zeros((self.num_envs,) + self.single_observation_space.shape, dtype=np.float32)
        rewards = np.zeros(self.num_envs)
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = np.zeros(self.num_envs, dtype=bool)
        infos = {}
        for i, env in enumerate(self.envs):
            if self._autoreset[i]:
                obs[i], info = env.reset()
            else:
                obs[i], rewards[i], terminated[i], truncated[i], info = env._finish_step()
            infos = self._add_info(infos, info, i)
        self._autoreset = terminated | truncated
        return obs, rewards, terminated, truncated, infos

    def close_extras(self, **kwargs):
        for env in self.envs:
            env.close()


def traffic_signal_vec(num_envs: int = 1, threads: Optional[int] = None, **kwargs) -> TrafficSignalVectorEnv:
    """``make_vec("smlworld/TrafficSignal-v0", num_envs=N, net_file=..., route_file=...)``: see
    :class:`TrafficSignalVectorEnv` (``kwargs`` are the single env's)."""
    kwargs.pop("max_episode_steps", None)
    return TrafficSignalVectorEnv(num_envs=num_envs, threads=threads, **kwargs)
