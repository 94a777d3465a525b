"""Env-steps per second of smlworld/PlatoonFollow-v0 and smlworld/HighwayMerge-v0, agent-steps
per second of the PettingZoo platoon (n agents), and, side by side, highway-env's highway-fast-v0
and merge-v0 (installed on demand), each with random actions.

    python python/bench/bench_envs.py [--steps 2000] [--agents 10] [--no-highway-env]
"""

import argparse
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

    env = platoon_parallel_env(n=agents, max_steps=10**9)
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


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--agents", type=int, default=10)
    ap.add_argument("--no-highway-env", action="store_true")
    args = ap.parse_args()
    pf = bench_platoon_follow(args.steps)
    print(f"PlatoonFollow-v0: {pf:,.0f} env-steps/s ({args.steps} steps)")
    pp = bench_parallel(args.steps // 4, args.agents)
    print(f"platoon_parallel_env(n={args.agents}): {pp:,.0f} agent-steps/s ({args.steps // 4} steps)")
    if not args.no_highway_env:
        he = bench_highway_env(max(50, args.steps // 20))
        print(f"highway-env highway-fast-v0: {he:,.1f} env-steps/s ({max(50, args.steps // 20)} steps)")
        print(f"ratio PlatoonFollow-v0 / highway-fast-v0: {pf / he:,.1f}x")
    hm = bench_merge(args.steps)
    print(f"HighwayMerge-v0: {hm:,.0f} env-steps/s ({args.steps} steps)")
    if not args.no_highway_env:
        n = max(50, args.steps // 20)
        mv = bench_highway_env(n, "merge-v0")
        print(f"highway-env merge-v0: {mv:,.1f} env-steps/s ({n} steps)")
        print(f"ratio HighwayMerge-v0 / merge-v0: {hm / mv:,.1f}x")


if __name__ == "__main__":
    main()
