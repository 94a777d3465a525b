"""Is the signal env's simulation still correct at a coarse step? One full episode of
``smlworld/TrafficSignal-v0`` (or of sumo-rl's ``SumoEnvironment``, the reference) on sumo-rl's
nets, with the file's fixed-time programs or with random actions, checked from outside the
simulator (issue 55 §2, docs/signals.md "Simulation step").

    python python/bench/check_signal_steps.py --net 2way --mode fixed --step 1.0 [--seconds 3600]
    python python/bench/check_signal_steps.py --net grid4x4 --mode random --step 0.02,0.05 --sumo

``--step`` is the env's ``sim_step`` (comma-separated for several runs; ``0.02`` = the 50 Hz
dynamics of the scenario defaults, with control and sensors at 20 Hz as before); ``--sumo`` adds
sumo-rl's own run (libsumo or TraCI) on the same files and actions. Random actions come from a
generator seeded with ``--seed`` independently of the observations, so every run gets the same
action sequence and, the lights' logic being sumo-rl's, the same signal timeline.

Checked, per run (one JSON line each):

- ``collisions``: the simulator's own count (footprints overlapping after a dynamics step), and
  ``swept_collisions``: footprints (5 m x 1.8 m, sumo-rl's nets use SUMO's default car) tested
  at ``--sub`` instants inside every dynamics step, each vehicle moved along the arc of constant
  curvature and speed that joins its poses at the step's ends (our kinematic model's exact
  motion), so a step long enough to jump over a crossing car cannot hide it;
- ``red_entries``: vehicles whose reference point moved onto a junction link in a step during
  which the light showed red (from the vehicles' lanelets and the lights, not the junction code's
  figures); ``red_crossings_simulator``: the junction code's own count (vehicles told to stop
  that could not);
- ``inserted``, ``arrived``, ``running`` at the end and ``stuck`` (vehicles standing for more
  than 600 s at the end: a gridlock);
- ``off_lane``: samples of a vehicle off every lanelet (NaN lanelet) and the largest
  ``|lane_offset|`` [m];
- ``mean_waiting_time``: the mean over the env steps of ``info["system_mean_waiting_time"]``
  (sumo-rl's metric), ``mean_stopped`` of ``system_total_stopped``, and the mean travel time and
  waiting of the arrived vehicles.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

NETS = {
    "2way": (
        "2way-single-intersection/single-intersection.net.xml",
        "2way-single-intersection/single-intersection-vhvh.rou.xml",
    ),
    "grid4x4": ("RESCO/grid4x4/grid4x4.net.xml", "RESCO/grid4x4/grid4x4_1.rou.xml"),
}
LENGTH, WIDTH = 5.0, 1.8  # SUMO's default passenger car (the nets' routes name no vType)


def nets_dir() -> Path:
    from smlworld.envs.traffic_signal import sumo_rl_nets

    try:
        return sumo_rl_nets()
    except FileNotFoundError as e:
        sys.exit(f"check_signal_steps: {e}")


def _arc(x0, y0, yaw0, x1, y1, yaw1, f):
    """Poses at fraction ``f`` of a step along the arc of constant curvature from pose 0 to
    pose 1 (uniform speed): turn ``f * dyaw``, chord from the arc length."""
    dyaw = (yaw1 - yaw0 + np.pi) % (2 * np.pi) - np.pi
    chord = np.hypot(x1 - x0, y1 - y0)
    half = 0.5 * dyaw
    sinc = np.where(np.abs(half) > 1e-9, np.sin(half) / np.where(half == 0, 1, half), 1.0)
    length = chord / sinc
    hf = half * f
    sincf = np.where(np.abs(hf) > 1e-9, np.sin(hf) / np.where(hf == 0, 1, hf), 1.0)
    d = length * f * sincf
    ang = yaw0 + hf
    return x0 + d * np.cos(ang), y0 + d * np.sin(ang), yaw0 + 2 * hf


def _overlaps(x, y, yaw, pairs):
    """Separating-axis test of the 5 x 1.8 m boxes of ``pairs`` (index arrays i, j)."""
    i, j = pairs
    if len(i) == 0:
        return np.zeros(0, dtype=bool)
    c = np.stack([x, y], axis=1)
    ax = np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
    ay = np.stack([-np.sin(yaw), np.cos(yaw)], axis=1)
    d = c[j] - c[i]
    sep = np.zeros(len(i), dtype=bool)
    half = (0.5 * LENGTH, 0.5 * WIDTH)
    for axis in (ax[i], ay[i], ax[j], ay[j]):
        dist = np.abs(np.sum(d * axis, axis=1))
        ra = half[0] * np.abs(np.sum(ax[i] * axis, axis=1)) + half[1] * np.abs(np.sum(ay[i] * axis, axis=1))
        rb = half[0] * np.abs(np.sum(ax[j] * axis, axis=1)) + half[1] * np.abs(np.sum(ay[j] * axis, axis=1))
        sep |= dist > ra + rb
    return ~sep


class Checker:
    """Records every dynamics step of ``sim`` (by stepping it one dynamics step at a time, which
    runs the same ticks) and checks it."""

    def __init__(self, sim, dt: float, sub: int):
        self.sim, self.dt, self.sub = sim, dt, sub
        self.swept = 0
        self.swept_pairs = set()
        self.red_entries = 0
        self.entries = 0
        self.off_lane = 0
        self.max_offset = 0.0
        self.samples = 0
        self.first = []
        self._prev = None
        self._link = {}  # lanelet id -> (junction, index)
        for j, light in sim.traffic_lights().items():
            for k, lanelet in enumerate(light["lanelets"]):
                self._link[int(lanelet)] = (j, k)
        self._links = np.array(sorted(self._link), dtype=float)
        self._step = sim.step
        sim.step = self.step

    def step(self, seconds: float):
        n = int(round(seconds / self.dt))
        if abs(n * self.dt - seconds) > 1e-9:
            raise ValueError(f"{seconds} s is not a whole number of {self.dt} s steps")
        for _ in range(n):
            self._step(self.dt)
            # What the lights showed during the step: its control tick (at its start, the only
            # one in a step no longer than the control step) advanced the programs already.
            shown = {j: light["state"] for j, light in self.sim.traffic_lights().items()}
            self._check(self.sim.states(), shown)

    def _check(self, st, shown):
        ids = st["id"]
        lanelet = st["lanelet"]
        self.samples += len(ids)
        self.off_lane += int(np.isnan(lanelet).sum())
        off = st["lane_offset"][~np.isnan(st["lane_offset"])]
        if len(off):
            self.max_offset = max(self.max_offset, float(np.abs(off).max()))
        if self._prev is not None:
            p = self._prev
            common, a, b = np.intersect1d(p["id"], ids, return_indices=True)
            # Entries onto a link while it showed red.
            before, now = p["lanelet"][a], lanelet[b]
            links = self._links
            entering = np.isin(now, links) & ~np.isnan(before) & ~np.isin(before, links)
            for k in np.flatnonzero(entering):
                self.entries += 1
                j, idx = self._link[int(now[k])]
                if shown[j][idx] == "r":
                    self.red_entries += 1
                    if len(self.first) < 5:
                        self.first.append(
                            f"t={self.sim.time:.2f} vehicle {int(common[k])} onto lanelet {int(now[k])} on red"
                        )
            # Footprints at sub-instants along each vehicle's arc.
            x0, y0, w0 = p["x"][a], p["y"][a], p["yaw"][a]
            x1, y1, w1 = st["x"][b], st["y"][b], st["yaw"][b]
            for s in range(1, self.sub + 1):
                x, y, w = _arc(x0, y0, w0, x1, y1, w1, s / self.sub)
                near = self._near(x, y)
                hit = _overlaps(x, y, w, near)
                for i, j in zip(near[0][hit], near[1][hit]):
                    pair = (int(common[i]), int(common[j]))
                    if pair not in self.swept_pairs:
                        self.swept_pairs.add(pair)
                        self.swept += 1
                        if len(self.first) < 5:
                            self.first.append(f"t={self.sim.time:.2f} swept overlap of vehicles {pair}")
        self._prev = {k: st[k] for k in ("id", "x", "y", "yaw", "lanelet")}

    @staticmethod
    def _near(x, y):
        """Pairs (i < j) whose centres are within a car's diagonal: sorted by x, a window."""
        reach = math.hypot(LENGTH, WIDTH)
        order = np.argsort(x, kind="stable")
        xs = x[order]
        out_i, out_j = [], []
        for shift in range(1, len(xs)):
            close = (xs[shift:] - xs[:-shift]) <= reach
            if not close.any():
                break
            i, j = order[:-shift][close], order[shift:][close]
            keep = np.abs(y[i] - y[j]) <= reach
            out_i.append(i[keep])
            out_j.append(j[keep])
        if not out_i:
            return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
        return np.concatenate(out_i), np.concatenate(out_j)


def run_ours(net, mode, step, seconds, seed, sub):
    import smlworld
    from smlworld.envs import TrafficSignalEnv

    net_file, route_file = (str(nets_dir() / p) for p in NETS[net])
    # Keep the simulator's metrics (collisions, red crossings, trips) on: the env stops them.
    smlworld.Sim.stop_metrics = lambda self: None
    kwargs = dict(net_file=net_file, route_file=route_file, num_seconds=seconds, sumo_seed=seed)
    if step == 0.02:
        # The scenario defaults: dynamics 50 Hz, control and sensors 20 Hz (before sim_step).
        kwargs["sim_step"] = 0.02
        kwargs["overrides"] = {"rates.control": 20.0, "rates.sensors": 20.0}
    else:
        kwargs["sim_step"] = step
    env = TrafficSignalEnv(single_agent=False, fixed_ts=(mode == "fixed"), **kwargs)
    env.reset(seed=seed)
    checker = Checker(env._sim, step, sub if step > 0.05 else 1)
    rng = np.random.default_rng(seed)
    waits, stopped = [], []
    moved = {}  # vehicle id -> last env step time it moved
    t = time.perf_counter()
    done = False
    while not done:
        actions = {ts: int(rng.integers(env.traffic_signals[ts].action_space.n)) for ts in env.ts_ids}
        _, _, dones, info = env.step(None if mode == "fixed" else actions)
        waits.append(info["system_mean_waiting_time"])
        stopped.append(info["system_total_stopped"])
        done = dones["__all__"]
        now = env._sim.states()
        fast = np.hypot(now["vx"], now["vy"]) >= 0.1
        for i in now["id"][fast].tolist():
            moved[i] = env.sim_step
        for i in now["id"][~fast].tolist():
            moved.setdefault(i, env.sim_step)
        present = set(now["id"].tolist())
    wall = time.perf_counter() - t
    s = env._sim.summary()
    m = s["metrics"]
    st = env._sim.states()
    standing = env._sim._core.signal_measures()
    trips = m.get("trips") or {}
    return {
        "who": "smlworld",
        "net": net,
        "mode": mode,
        "step": step,
        "seconds": seconds,
        "wall_s": round(wall, 1),
        "collisions": m["collision_count"],
        "swept_collisions": checker.swept,
        "red_entries": checker.red_entries,
        "entries": checker.entries,
        "red_crossings_simulator": m.get("red_light_crossings"),
        "inserted": trips.get("inserted"),
        "arrived": trips.get("arrived"),
        "running": int(len(st["id"])),
        "stuck": sum(1 for i in present if env.sim_step - moved[i] > 600),
        "off_lane": checker.off_lane,
        "samples": checker.samples,
        "max_lane_offset_m": round(checker.max_offset, 2),
        "mean_waiting_time": round(float(np.mean(waits)), 2),
        "mean_stopped": round(float(np.mean(stopped)), 2),
        "mean_travel_time": trips.get("mean_travel_time_s"),
        "mean_trip_waiting": trips.get("mean_waiting_time_s"),
        "first_problems": checker.first,
        "halting_now": int(standing["stopped"]),
    }


def run_sumo(net, mode, seconds, seed):
    os.environ.setdefault("LIBSUMO_AS_TRACI", "1")
    if "SUMO_HOME" not in os.environ:
        import sumo

        os.environ["SUMO_HOME"] = sumo.SUMO_HOME
    import traci
    from sumo_rl import SumoEnvironment

    net_file, route_file = (str(nets_dir() / p) for p in NETS[net])
    out = tempfile.mkdtemp(prefix="check-signal-sumo-")
    tripinfo = os.path.join(out, "tripinfo.xml")
    env = SumoEnvironment(
        net_file=net_file,
        route_file=route_file,
        num_seconds=seconds,
        sumo_seed=seed,
        fixed_ts=(mode == "fixed"),
        sumo_warnings=False,
        additional_sumo_cmd=f"--tripinfo-output {tripinfo} --collision.action warn",
    )
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    waits, stopped = [], []
    collisions = 0
    t = time.perf_counter()
    done = False
    while not done:
        actions = {ts: int(rng.integers(env.traffic_signals[ts].action_space.n)) for ts in env.ts_ids}
        _, _, dones, info = env.step({} if mode == "fixed" else actions)
        waits.append(info["system_mean_waiting_time"])
        stopped.append(info["system_total_stopped"])
        collisions += env.sumo.simulation.getCollidingVehiclesNumber()
        done = dones["__all__"]
    wall = time.perf_counter() - t
    running = env.sumo.vehicle.getIDCount()
    inserted = running + 0
    env.close()
    trips = ET.parse(tripinfo).getroot().findall("tripinfo")
    arrived = len(trips)
    del traci
    return {
        "who": "sumo-rl" + (" (libsumo)" if os.environ.get("LIBSUMO_AS_TRACI") else ""),
        "net": net,
        "mode": mode,
        "step": 1.0,
        "seconds": seconds,
        "wall_s": round(wall, 1),
        "collisions_seen_at_env_steps": collisions,
        "inserted": arrived + inserted,
        "arrived": arrived,
        "running": running,
        "mean_waiting_time": round(float(np.mean(waits)), 2),
        "mean_stopped": round(float(np.mean(stopped)), 2),
        "mean_travel_time": round(float(np.mean([float(x.get("duration")) for x in trips])), 2) if trips else None,
        "mean_trip_waiting": round(float(np.mean([float(x.get("waitingTime")) for x in trips])), 2) if trips else None,
    }


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--net", choices=sorted(NETS), default="2way")
    p.add_argument("--mode", choices=["fixed", "random"], default="fixed")
    p.add_argument("--step", default="1.0", help="sim_step values [s], comma-separated (0.02: the old 50/20/20 Hz)")
    p.add_argument("--seconds", type=int, default=3600)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sub", type=int, default=10, help="instants tested inside each coarse step")
    p.add_argument("--sumo", action="store_true", help="also run sumo-rl's env (the reference)")
    a = p.parse_args()
    for step in [float(s) for s in a.step.split(",") if s]:
        print(json.dumps(run_ours(a.net, a.mode, step, a.seconds, a.seed, a.sub)), flush=True)
    if a.sumo:
        print(json.dumps(run_sumo(a.net, a.mode, a.seconds, a.seed)), flush=True)


if __name__ == "__main__":
    main()
