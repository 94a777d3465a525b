"""SML World as a Python library: the Rust simulator stepped from notebooks, learning code and
parameter sweeps.

Units: metres, seconds, radians, m/s, newtons. Arrays are numpy arrays; nothing creates a Python
object per vehicle on the hot paths, and the GIL is released while Rust runs. Errors raise
``FileNotFoundError`` (missing scenario or map) or ``ValueError`` carrying the Rust message (file,
line, key or id).

    import smlworld
    sim = smlworld.Sim.from_scenario("scenarios/platoon_brake.toml", seed=3)
    sim.step(1.0)
    print(sim.time, sim.states()["vx"])
"""

from __future__ import annotations

import math
from typing import Callable, Dict, List, Optional, Tuple

import numpy as np

from . import _smlworld
from ._smlworld import Map

__all__ = ["Sim", "Map", "run", "load_map", "sweep"]


class Sim:
    """A scenario's simulation, advanced by the caller.

    Build it with :meth:`Sim.from_scenario`. Python controllers added with
    :meth:`add_controller` run inside the Control phase of the ticks they are due, as Rust
    controllers do.
    """

    def __init__(self, core: "_smlworld.Core"):
        self._core = core

    @classmethod
    def from_scenario(cls, path, seed: Optional[int] = None, **overrides) -> "Sim":
        """Load a scenario file (TOML). ``seed`` replaces the scenario's seed; each override is
        a dotted scenario key, e.g. ``duration=20.0`` or
        ``**{"vehicles.controller.platoon.time_gap": 0.8}`` (a key through ``vehicles`` applies
        to every vehicle that has the tables on the way), ``**{"vehicles.0.speed": 9.0}`` (one
        element) or ``**{"vehicles.*.lane_change.politeness": 0.5}`` (every element, tables
        created), the same keys as ``smlworld run --set``."""
        return cls(_smlworld.Core.from_scenario(str(path), seed, **overrides))

    def restart(self, seed: Optional[int] = None) -> None:
        """Start over at time 0 from the scenario as loaded, overrides included, with ``seed``
        (``None``: the seed of the run now): what ``Sim.from_scenario(path, seed,
        **overrides)`` gives, without reading the scenario file or the map again (a learning
        environment's reset). Commands, in-boxes, Python controllers and metrics start empty;
        metrics stay off after :meth:`stop_metrics`."""
        seed = self._core.seed if seed is None else int(seed)
        if seed < 0:
            raise ValueError(f"seed must be >= 0, got {seed}")
        self._core.restart(seed)

    def stop_metrics(self) -> None:
        """Stop recording the summary's ``metrics`` (collisions, gaps, speeds) from now on, for
        code that never reads them: about a third of each tick of a small scenario. The
        trajectories stay the same, bit for bit."""
        self._core.stop_metrics()

    def kinematics(self, id: int, nearest: int = 5, footprint: Tuple[float, float] = (0.0, 0.0)):
        """Vehicle ``id`` and its ``nearest`` nearest vehicles, highway-env's ``Kinematics``
        unscaled: a (1 + nearest, 5) float array, row 0 ``[1, x, y, vx, vy]`` of the vehicle
        [-, m, m, m/s, m/s], then ``[1, dx, dy, dvx, dvy]`` of each other vehicle relative to it
        (world axes), nearest first (equal distances in id order), rows of zeros when there are
        fewer. Returns ``(rows, speed [m/s], collided)``, ``collided`` when another vehicle's
        centre lies strictly inside the box ``footprint = (length along x, width along y)`` [m]
        around it."""
        return self._core.kinematics(int(id), int(nearest), (float(footprint[0]), float(footprint[1])))

    def drive(
        self,
        id: int,
        throttle: float,
        change: Optional[str],
        dt: float,
        nearest: int = 5,
        footprint: Tuple[float, float] = (0.0, 0.0),
    ):
        """One learning step in one call: ask vehicle ``id`` to change lanes to ``change``
        (``"left"``, ``"right"`` or ``None``; a refusal is silent, as :meth:`change_lane`'s
        False), set its ``throttle`` [N] as :meth:`set_commands` does, advance ``dt`` [s], and
        return :meth:`kinematics` of ``id``. Python controllers run on the way, as in :meth:`step`."""
        return self._core.drive(id, throttle, change, dt, nearest, footprint)

    @property
    def time(self) -> float:
        """Sim time [s]."""
        return self._core.time

    @property
    def control_rate(self) -> float:
        """The scenario's control rate [Hz]."""
        return self._core.control_rate

    def step(self, dt: float) -> None:
        """Advance sim time by ``dt`` [s] through the normal multi-rate schedule; Python
        controllers run inside the control ticks on the way (see :meth:`add_controller`)."""
        dt = float(dt)
        if not math.isfinite(dt) or dt < 0:
            raise ValueError(f"dt must be a finite number of seconds >= 0, got {dt}")
        self._core.step(dt)

    def observe(self, ids) -> Dict[str, np.ndarray]:
        """The observation a Python controller gets: ``id, x, y, yaw, vx, vy`` for ``ids``
        (in that order) and ``time`` [s]."""
        ids = np.asarray(ids, dtype=np.int32)
        st = self.states()
        pos = np.searchsorted(st["id"], ids)
        pos = np.clip(pos, 0, len(st["id"]) - 1)
        bad = st["id"][pos] != ids
        if bad.any():
            raise ValueError(f"unknown vehicle id {int(ids[bad][0])}; the scenario has ids {st['id'].tolist()}")
        out = {k: v[pos] for k, v in st.items()}
        out["time"] = np.full(len(ids), self.time)
        return out

    def run(self, duration: float) -> dict:
        """Advance by ``duration`` [s]; returns the summary of everything run so far (the
        content of ``summary.json``)."""
        self.step(duration)
        return self._core.summary()

    def summary(self) -> dict:
        """The content of ``summary.json`` for everything run so far."""
        return self._core.summary()

    def states(self) -> Dict[str, np.ndarray]:
        """All vehicles, sorted by id: ``id`` (int32), ``x, y`` [m], ``yaw`` [rad], ``vx, vy`` [m/s],
        ``lanelet`` (id of the lanelet under the vehicle, NaN off the road or without a map) and
        ``lane_offset`` [m] (signed offset from its centre line, left positive; NaN off the road)."""
        return self._core.states()

    def change_lane(self, id: int, side: str) -> bool:
        """Ask vehicle ``id`` (it needs a ``lane_change`` table) to change lanes, ``side`` =
        ``"left"`` or ``"right"``. False when the map (no lane there, a solid line) or the gap
        forbids it now; True when the lane-change plugin takes the request, which it carries out
        with the same safety check as its own changes (``kind = "requested"`` in
        ``metrics.lane_changes``)."""
        return bool(self._core.change_lane(int(id), str(side)))

    def readings(self, id: int) -> np.ndarray:
        """Vehicle ``id``'s sensor readings of the last sensor tick, nearest first: a (k, 5)
        array of ``id, x, y, vx, vy`` [-, m, m, m/s, m/s]."""
        return self._core.readings(int(id))

    def reading_sensors(self, id: int) -> list[str]:
        """The name of the sensor that saw each row of :meth:`readings` of vehicle ``id``, in
        the same order: ``"radar"``, ``"velodyne"``, ``"omniscient"`` or a plugin sensor's
        registered name."""
        return list(self._core.reading_sensors(int(id)))

    def set_commands(self, ids, throttle=None, steering=None, speed=None) -> None:
        """Set commands for vehicles ``ids``: ``throttle`` [N] (acceleration model),
        ``steering`` [rad], ``speed`` [m/s] (kinematic model), one finite value per id; a column
        left out keeps its value. They act at once and win over the vehicle's own Rust controller
        at every later control tick, until :meth:`clear_commands`."""
        ids = np.ascontiguousarray(ids, dtype=np.int32).reshape(-1)

        def col(a):
            return None if a is None else np.ascontiguousarray(a, dtype=np.float64).reshape(-1)

        self._core.set_commands(ids, col(throttle), col(steering), col(speed))

    def clear_commands(self, ids) -> None:
        """Give vehicles ``ids`` back to their own Rust controllers."""
        self._core.clear_commands(np.ascontiguousarray(ids, dtype=np.int32).reshape(-1))

    def add_controller(self, ids, fn: Callable[[dict], dict], rate: float = 20.0) -> None:
        """Call ``fn(obs) -> dict`` for the whole batch ``ids`` (one call per tick) at ``rate``
        [Hz], at most the scenario's control rate. Each call runs inside the Control phase of
        the control tick it is due, where a Rust controller runs: after that instant's sensor
        and V2V rounds, and the commands it returns drive the dynamics step that starts at that
        tick, so a Python controller at the control rate behaves like a Rust one, whatever
        chunks :meth:`step` is called with. (A rate that does not divide the control rate runs
        at the first control tick at or after each of its due times ``k / rate``.)

        ``obs`` is :meth:`observe` of ``ids`` at the tick; the result is a dict of arrays
        ``throttle`` [N], ``steering`` [rad] and/or ``speed`` [m/s], one finite value per id,
        which act like :meth:`set_commands` (they stay until replaced or cleared). An exception
        in ``fn``, or a bad result, stops :meth:`step` at that tick (``time`` is the tick's) and
        is raised from it. Inside ``fn`` this Sim cannot be called (it is stepping): read what
        the observation lacks, or send messages, between steps."""
        rate = float(rate)
        ids = np.ascontiguousarray(ids, dtype=np.int32).reshape(-1)
        name = getattr(fn, "__qualname__", None) or repr(fn)

        def call(obs):
            act = fn(obs)
            if not isinstance(act, dict):
                raise TypeError(f"controller {name} must return a dict of arrays, got {type(act).__name__}")
            unknown = set(act) - {"throttle", "steering", "speed"}
            if unknown:
                raise ValueError(
                    f"controller {name} returned unknown keys {sorted(unknown)}; allowed: throttle, steering, speed"
                )

            def col(key):
                a = act.get(key)
                return None if a is None else np.ascontiguousarray(a, dtype=np.float64).reshape(-1)

            return col("throttle"), col("steering"), col("speed")

        self._core.add_controller(ids.tolist(), call, rate, name)

    def frame(self, width: int = 640, height: int = 480) -> np.ndarray:
        """The bird's-eye view of the map with the vehicles now: an (height, width, 4) uint8 RGBA
        array from the off-screen renderer (Vulkan; Mesa's lavapipe works without a GPU)."""
        return self._core.frame(int(width), int(height))

    def send(self, id: int, channel: str, payload: bytes) -> None:
        """Queue ``payload`` from vehicle ``id`` on ``channel`` ("wifi" or "network"); it leaves
        at the channel's next V2V round, as a Rust controller's message does."""
        self._core.send(int(id), channel, bytes(payload))

    def inbox(self, id: int, channel: str) -> List[Tuple[int, bytes]]:
        """Byte messages vehicle ``id`` received on ``channel`` since the last call for it,
        oldest first: ``[(sender, bytes), ...]``. The first call returns what the in-box holds
        now; from then on every message is kept until read, at most 10,000 per vehicle and
        channel (the oldest dropped first, with a warning)."""
        return self._core.inbox(int(id), channel)

    def models(self) -> Dict[str, np.ndarray]:
        """Per vehicle (sorted by id): ``mass`` [kg] and ``drag`` [N s/m] (NaN for kinematic models)."""
        return self._core.models()

    def map(self) -> Optional[Map]:
        """The scenario's map, if it names one."""
        return self._core.map()

    def traffic_lights(self) -> Dict[int, dict]:
        """What every signalised junction shows now, keyed by junction id (from 1, as
        ``smlworld map info`` lists them; empty without traffic lights)::

            {3: {"state": "GGgrrr", "phase": 0, "lanelets": [101, 102, 103, 201, 202, 203]}}

        ``state`` has one character per link: ``G`` green with priority, ``g`` green yielding to
        a ``G``, ``y`` yellow, ``r`` red. ``lanelets`` gives each character's link (the lanelet
        that crosses the junction, its start is the stop line), so queues can be measured per
        signal. ``phase`` is the index of the program's phase shown (0-based), ``None`` while a
        state set by :meth:`set_phase` is held. A learning agent reads this as its observation
        of the signals and acts with :meth:`set_phase`."""
        return self._core.traffic_lights()

    def set_phase(self, junction: int, state: str) -> None:
        """Show ``state`` at ``junction`` (its id) from now on, instead of its program, until set
        again; vehicles see it at the next control tick (the yellow rule applies to ``y``, so
        put a ``y`` state before a ``r`` one as a program does). ``state`` needs one character
        per link (see :meth:`traffic_lights`). Raises ``ValueError`` naming the problem for a
        junction without a light, a state of the wrong length or an unknown character."""
        if isinstance(junction, bool) or not isinstance(junction, (int, np.integer)):
            raise ValueError(f"set_phase: junction must be an integer id, got {junction!r}")
        if not isinstance(state, str):
            raise ValueError(f"set_phase: state must be a str such as 'GGrr', got {state!r}")
        self._core.set_phase(int(junction), state)


def run(path, out=None, seed: Optional[int] = None, **overrides) -> dict:
    """Do what ``smlworld run PATH --out OUT`` does (``out`` defaults to ``out``): write
    ``trajectories.csv`` and ``summary.json``; returns the summary. Overrides as in
    :meth:`Sim.from_scenario`."""
    return _smlworld.run(str(path), None if out is None else str(out), seed, **overrides)


def load_map(path) -> Map:
    """Load a lanelet map: ``.lanelets`` (ids), ``.successors`` ((n, 2) pairs),
    ``.centre(id)``, ``.route(from_node, to_node)`` and ``.loop(node)`` return numpy arrays
    of points [m]."""
    return _smlworld.load_map(str(path))


#: Every gymnasium environment of smlworld: id -> entry point (registered on import).
ENVS = {
    "smlworld/PlatoonFollow-v0": "smlworld.envs.platoon:PlatoonFollowEnv",
    "smlworld/HighwayMerge-v0": "smlworld.envs.merge:HighwayMergeEnv",
    "smlworld/TrafficSignal-v0": "smlworld.envs.traffic_signal:TrafficSignalEnv",
}

#: Constructor arguments an env id fixes by default (``gymnasium.make`` may override them).
ENV_KWARGS = {
    "smlworld/TrafficSignal-v0": {"single_agent": True},
}

#: Their vector envs stepped in Rust (``smlworld.envs.make_vec``): what ``gymnasium.make_vec``
#: builds for them unless told ``vectorization_mode="sync"`` or ``"async"``.
VECTOR_ENVS = {
    "smlworld/PlatoonFollow-v0": "smlworld.envs.vector:platoon_follow_vec",
    "smlworld/HighwayMerge-v0": "smlworld.envs.vector:highway_merge_vec",
    "smlworld/TrafficSignal-v0": "smlworld.envs.traffic_signal:traffic_signal_vec",
}


def _register_envs() -> None:
    """Register the Gymnasium environments on a plain ``import smlworld`` (by name: their
    modules load only when ``gymnasium.make`` asks for them). Without gymnasium (the ``envs``
    extra) there is nothing to register and smlworld works as before."""
    try:
        import gymnasium
    except ImportError:
        return
    for env_id, entry_point in ENVS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id,
                entry_point=entry_point,
                vector_entry_point=VECTOR_ENVS.get(env_id),
                kwargs=ENV_KWARGS.get(env_id, {}),
            )


_register_envs()

# `smlworld.sweep(...)` runs a sweep and `python -m smlworld.sweep` reads a sweep file: the
# module is callable (see smlworld/sweep.py), so both names stay one object.
from . import sweep  # noqa: E402
