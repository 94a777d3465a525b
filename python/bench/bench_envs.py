"""Env-steps per second of smlworld/PlatoonFollow-v0 and smlworld/HighwayMerge-v0, agent-steps
per second of the PettingZoo platoon (n agents), and, side by side, highway-env's highway-fast-v0
and merge-v0 (installed on demand), each with random actions.

    python python/bench/bench_envs.py [--steps 2000] [--agents 10] [--no-highway-env] [--repeat 1]
    python python/bench/bench_envs.py --vec 64 [--steps 2000] [--threads 2] [--repeat 3]

With ``--repeat N`` every measurement runs N times, ours and highway-env's taking turns (so the
pairs share the machine's load of the moment), and each line gives min / median / max.

``--vec N`` measures the vector envs instead (``smlworld.envs.make_vec(env_id, num_envs=N)``,
stepped in Rust in one call per step): env-steps per second = ``--steps`` vector steps x N envs
over the wall time of the steps, autoresets included (PlatoonFollow-v0 under the vectorised
follower policy, HighwayMerge-v0 under random discrete actions).
"""

import argparse
import statistics
import subprocess
import sys
import time

import numpy as np


def bench_platoon_follow(steps):
    import gymnasium as gym

    import smlworld.envs  # noqa: F401

    env = gym.make("smlworld/PlatoonFollow-v0")
    obs, _ = env.reset(seed=0)
    t = time.perf_counter()
    for _ in range(steps):
        v, gap, dv, _ = obs
        obs, r, term, trunc, _ = env.step(np.array([0.5 * (gap - (5 + v)) + dv], dtype=np.float32))
        if term or trunc:
            obs, _ = env.reset()
    return steps / (time.perf_counter() - t)


def bench_parallel(steps, agents):
    from smlworld.envs import platoon_parallel_env

    # no truncation inside the measured steps (the leader's speed targets are drawn up front for
    # the whole episode: max_steps=10**9 cost a minute per reset)
    env = platoon_parallel_env(n=agents, max_steps=steps + 1)
    obs, _ = env.reset(seed=0)
    t = time.perf_counter()
    for _ in range(steps):
        actions = {a: np.array([0.5 * (o[1] - (5 + o[0])) + o[2]], dtype=np.float32) for a, o in obs.items()}
        obs, *_ = env.step(actions)
    return steps * agents / (time.perf_counter() - t)


def bench_random(name, steps):
    """Env-steps per second of gymnasium env `name` under random actions (seeded)."""
    import gymnasium as gym

    env = gym.make(name)
    env.reset(seed=0)
    env.action_space.seed(0)
    t = time.perf_counter()
    for _ in range(steps):
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        if term or trunc:
            env.reset()
    return steps / (time.perf_counter() - t)


def bench_merge(steps):
    import smlworld  # noqa: F401  (registers the environments)

    return bench_random("smlworld/HighwayMerge-v0", steps)


def bench_highway_env(steps, name="highway-fast-v0"):
    try:
        import highway_env  # noqa: F401
    except ImportError:
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "highway-env"], check=True)
        import highway_env  # noqa: F401
    return bench_random(name, steps)


def bench_vec(name, num_envs, steps, threads):
    """Env-steps per second of ``make_vec(name, num_envs)`` (see the module documentation)."""
    from smlworld.envs import make_vec

    envs = make_vec(name, num_envs=num_envs, seed=0, threads=threads)
    obs, _ = envs.reset(seed=0)
    rng = np.random.default_rng(0)
    if name.endswith("PlatoonFollow-v0"):

        def policy(obs):
            v, gap, dv = obs[:, 0], obs[:, 1], obs[:, 2]
            return (0.5 * (gap - (5 + v)) + dv).reshape(-1, 1)

    else:

        def policy(obs):
            return rng.integers(0, 5, size=num_envs)

    for _ in range(10):  # warm up: every episode started, the pool's threads running
        obs, *_ = envs.step(policy(obs))
    t = time.perf_counter()
    for _ in range(steps):
        obs, *_ = envs.step(policy(obs))
    return steps * num_envs / (time.perf_counter() - t), envs.threads


def main_vec(args):
    """``--vec N``: the vector envs' figures."""
    for name in ("smlworld/PlatoonFollow-v0", "smlworld/HighwayMerge-v0"):
        runs = []
        for _ in range(max(1, args.repeat)):
            rate, threads = bench_vec(name, args.vec, args.steps, args.threads)
            runs.append(rate)
        print(
            f"{name.split('/')[1]} make_vec(num_envs={args.vec}): {spread(runs, '{:,.0f}')} env-steps/s "
            f"({args.steps} steps x {args.vec} envs, {threads} threads)"
        )


def spread(values, fmt):
    """``fmt`` of one value, or "min / median / max" of several."""
    if len(values) == 1:
        return fmt.format(values[0])
    return " / ".join(fmt.format(v) for v in (min(values), statistics.median(values), max(values))) + " (min / median / max)"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--agents", type=int, default=10)
    ap.add_argument("--no-highway-env", action="store_true")
    ap.add_argument("--repeat", type=int, default=1, help="runs of each measurement (min / median / max)")
    ap.add_argument("--vec", type=int, default=0, metavar="N", help="measure the vector envs with N envs instead")
    ap.add_argument("--threads", type=int, default=None, help="--vec: threads per step (default: the machine's, at most 4)")
    args = ap.parse_args()
    if args.vec:
        main_vec(args)
        return
    n = max(50, args.steps // 20)
    runs = {k: [] for k in ("pf", "pp", "he", "hm", "mv")}
    for _ in range(max(1, args.repeat)):
        runs["pf"].append(bench_platoon_follow(args.steps))
        runs["pp"].append(bench_parallel(args.steps // 4, args.agents))
        if not args.no_highway_env:
            runs["he"].append(bench_highway_env(n))
        runs["hm"].append(bench_merge(args.steps))
        if not args.no_highway_env:
            runs["mv"].append(bench_highway_env(n, "merge-v0"))

    def ratio(ours, theirs):
        """Ours over theirs, run by run (each pair measured one after the other)."""
        return [x / y for x, y in zip(runs[ours], runs[theirs])]

    print(f"PlatoonFollow-v0: {spread(runs['pf'], '{:,.0f}')} env-steps/s ({args.steps} steps)")
    print(f"platoon_parallel_env(n={args.agents}): {spread(runs['pp'], '{:,.0f}')} agent-steps/s ({args.steps // 4} steps)")
    if not args.no_highway_env:
        print(f"highway-env highway-fast-v0: {spread(runs['he'], '{:,.1f}')} env-steps/s ({n} steps)")
        print(f"ratio PlatoonFollow-v0 / highway-fast-v0: {spread(ratio('pf', 'he'), '{:,.1f}x')}")
    print(f"HighwayMerge-v0: {spread(runs['hm'], '{:,.0f}')} env-steps/s ({args.steps} steps)")
    if not args.no_highway_env:
        print(f"highway-env merge-v0: {spread(runs['mv'], '{:,.1f}')} env-steps/s ({n} steps)")
        print(f"ratio HighwayMerge-v0 / merge-v0: {spread(ratio('hm', 'mv'), '{:,.1f}x')}")


if __name__ == "__main__":
    main()
