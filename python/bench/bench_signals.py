"""Env-steps per second of sumo-rl's ``SumoEnvironment`` (libsumo, ``LIBSUMO_AS_TRACI=1``) and of
``smlworld/TrafficSignal-v0`` on the same SUMO net and routes with random actions (issue 55 §2).

    python python/bench/bench_signals.py [--steps 200] [--repeat 3] [--only ours|sumo] [--net 2way|grid4x4] [--hz 10]
                                         [--vec 8] [--old]

Needs ``sumo-rl``, ``eclipse-sumo`` and ``libsumo`` (the same version as eclipse-sumo; without
it sumo-rl falls back to TraCI over a socket and the worker stops with a message).
Each measurement runs in a fresh process (libsumo holds one simulation per process), sumo-rl's and
ours taking turns, ``--repeat`` times; a line gives min / median / max. The clock runs over the
``--steps`` env steps after ``reset()`` (start-up excluded), each 5 s of sim time (sumo-rl's
default ``delta_time``). ``2way``: sumo-rl's
``2way-single-intersection`` with ``single-intersection-vhvh.rou.xml``, one agent; ``grid4x4``:
RESCO's grid with ``grid4x4_1.rou.xml``, all 16 lights acting at every step, counted as 16
env-steps per step (one per agent-step, as sumo-rl's own figures count them). Ours runs at the
env's default ``sim_step`` (SUMO's 1 s, as sumo-rl runs SUMO); ``--old`` also measures it at
``sim_step=0.02`` (the scenario defaults: dynamics 50 Hz, control and sensors 20 Hz), taking
turns with the others.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

NETS = {
    "2way": (
        "2way-single-intersection/single-intersection.net.xml",
        "2way-single-intersection/single-intersection-vhvh.rou.xml",
    ),
    "grid4x4": ("RESCO/grid4x4/grid4x4.net.xml", "RESCO/grid4x4/grid4x4_1.rou.xml"),
}


def nets_dir() -> Path:
    from smlworld.envs.traffic_signal import sumo_rl_nets

    try:
        return sumo_rl_nets()
    except FileNotFoundError as e:
        sys.exit(f"bench_signals: {e}")


def worker(kind: str, net: str, steps: int, seed: int, hz: float, vec: int = 0) -> dict:
    """One measurement in this process: env-steps per second of `kind` ("ours", "old": ours at
    the 50/20 Hz rates, or "sumo"); with ``vec`` (ours, 2way) of ``make_vec`` with that many
    copies (steps x copies per second)."""
    import numpy as np

    net_file, route_file = (str(nets_dir() / p) for p in NETS[net])
    rng = np.random.default_rng(seed)
    kwargs = dict(net_file=net_file, route_file=route_file, num_seconds=steps * 5 + 100, sumo_seed=seed)
    if vec:
        import smlworld.envs

        overrides = {f"rates.{m}": hz for m in ("dynamics", "control", "sensors")} if hz else {}
        envs = smlworld.envs.make_vec("smlworld/TrafficSignal-v0", num_envs=vec, overrides=overrides, **kwargs)
        envs.reset(seed=seed)
        t = time.perf_counter()
        for _ in range(steps):
            envs.step(rng.integers(envs.single_action_space.n, size=vec))
        return {"env_steps_per_s": steps * vec / (time.perf_counter() - t), "agents": 1}
    if kind == "sumo":
        import traci

        if not traci.isLibsumo():
            sys.exit(
                "bench_signals: libsumo is not installed (`pip install libsumo`, the version of eclipse-sumo): "
                "sumo-rl would fall back to TraCI over a socket, which is slower than the libsumo it is compared with"
            )
        from sumo_rl import SumoEnvironment

        env = SumoEnvironment(single_agent=(net == "2way"), sumo_warnings=False, **kwargs)
    else:
        from smlworld.envs import TrafficSignalEnv

        overrides = {f"rates.{m}": hz for m in ("dynamics", "control", "sensors")} if hz else {}
        if kind == "old":
            kwargs["sim_step"] = 0.02
        env = TrafficSignalEnv(single_agent=(net == "2way"), overrides=overrides, **kwargs)
    out = env.reset(seed=seed)
    agents = list(env.ts_ids)
    t = time.perf_counter()
    for _ in range(steps):
        if net == "2way":
            env.step(int(rng.integers(env.action_space.n)))
        else:
            env.step({a: int(rng.integers(env.traffic_signals[a].action_space.n)) for a in agents})
    wall = time.perf_counter() - t
    del out
    return {"env_steps_per_s": steps * len(agents if net != "2way" else [0]) / wall, "agents": len(agents)}


def measure(kind, net, steps, seed, hz, vec=0):
    env = dict(os.environ)
    if kind == "sumo":
        env["LIBSUMO_AS_TRACI"] = "1"
        if "SUMO_HOME" not in env:
            import sumo

            env["SUMO_HOME"] = sumo.SUMO_HOME
    done = subprocess.run(
        [
            sys.executable,
            __file__,
            "--worker",
            kind,
            "--net",
            net,
            "--steps",
            str(steps),
            "--seed",
            str(seed),
            "--hz",
            str(hz),
            "--vec",
            str(vec),
        ],
        capture_output=True,
        text=True,
        env=env,
    )
    if done.returncode != 0:
        sys.exit(f"bench_signals: the {kind} worker failed:\n{done.stderr[-3000:]}")
    return json.loads(next(line for line in done.stdout.splitlines()[::-1] if line.startswith("{")))


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=200, help="env steps per measurement")
    p.add_argument("--repeat", type=int, default=3, help="measurements of each, taking turns")
    p.add_argument("--net", choices=sorted(NETS), action="append", help="which nets (default: both)")
    p.add_argument("--only", choices=["ours", "sumo"], help="measure one side only")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--hz",
        type=float,
        default=0.0,
        help="our dynamics, control and sensors rate [Hz] (scenario overrides; 0: the defaults, 50/20/20 Hz)",
    )
    p.add_argument("--vec", type=int, default=0, help="also measure make_vec with this many copies (2way)")
    p.add_argument(
        "--old", action="store_true", help="also measure ours at sim_step=0.02 (dynamics 50 Hz, control 20 Hz)"
    )
    p.add_argument("--worker", choices=["ours", "old", "sumo"], help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.steps < 1 or a.repeat < 1:
        sys.exit("bench_signals: --steps and --repeat must be at least 1")
    if a.worker:
        print(json.dumps(worker(a.worker, a.net[0], a.steps, a.seed, a.hz, a.vec)))
        return
    kinds = [a.only] if a.only else ["sumo", "ours"]
    if a.old and "ours" in kinds:
        kinds.append("old")
    for net in a.net or ["2way", "grid4x4"]:
        results = {k: [] for k in kinds}
        agents = None
        for r in range(a.repeat):
            for k in kinds if r % 2 == 0 else kinds[::-1]:
                m = measure(k, net, a.steps, a.seed + r, a.hz)
                results[k].append(m["env_steps_per_s"])
                agents = m["agents"]
        if a.vec and net == "2way" and "ours" in kinds:
            results["vec"] = [
                measure("ours", net, a.steps, a.seed + r, a.hz, a.vec)["env_steps_per_s"] for r in range(a.repeat)
            ]
        for k in results:
            v = results[k]
            name = "sumo-rl (libsumo)" if k == "sumo" else ("smlworld" + (f" at {a.hz:g} Hz" if a.hz else ""))
            if k == "old":
                name = "smlworld sim_step=0.02 (50/20 Hz)"
            if k == "vec":
                name += f" make_vec(num_envs={a.vec})"
            print(
                f"{net} {name}: {min(v):,.0f} / {statistics.median(v):,.0f} / {max(v):,.0f} (min / median / max) "
                f"env-steps/s ({a.steps} steps, {agents} agent{'s' if agents != 1 else ''}, {a.repeat} runs)"
            )
        if "sumo" in results and "ours" in results:
            ratio = statistics.median(results["ours"]) / statistics.median(results["sumo"])
            print(f"{net} speed-up (median): {ratio:.1f}x")


if __name__ == "__main__":
    main()
