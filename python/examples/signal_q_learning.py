"""Tabular Q-learning of one traffic light (issue 55 §3), as sumo-rl's
``experiments/ql_2way-single-intersection.py`` does it (LucasAlegre/sumo-rl): its ``QLAgent``
(alpha 0.1, gamma 0.99) with epsilon-greedy exploration (0.05, min 0.005, no decay), states as
``env.encode`` gives them (the green phase, the min-green flag and every lane's density and queue in tenths),
``min_green=10``, ``max_green=30``, reward ``diff-waiting-time``, episodes of the script's 100,000 s,
on ``2way-single-intersection`` with ``single-intersection-vhvh.rou.xml``.

    python python/examples/signal_q_learning.py [--episodes 150] [--seconds 100000] [--sumo] [--out ql.png]

The Q-table carries over from episode to episode (sumo-rl's script starts a new table each run;
one 100,000 s run is far from enough for this table: its states are every lane's density and
queue, hundreds of thousands of them). Each episode's mean of ``info["system_mean_waiting_time"]``
is printed and plotted beside the fixed-time program's (``fixed_ts=True``), and the last line says
whether the mean of the last 10 episodes is lower than the fixed-time program's. With ``--sumo``
(needs sumo-rl and SUMO; with ``libsumo`` installed it is used, ``LIBSUMO_AS_TRACI=1``) the same
agent also learns on sumo-rl's own ``SumoEnvironment`` and its curve goes in the same figure.
At the defaults ours took 12 minutes on one core (3,918 env-steps/s while learning), sumo-rl's
with libsumo 45 (1,312; docs/signals.md). Not part of the tests.
"""

import argparse
import importlib.util
import os
import sys
import time
from pathlib import Path

import numpy as np


def nets_dir() -> Path:
    from smlworld.envs.traffic_signal import sumo_rl_nets

    try:
        return sumo_rl_nets()
    except FileNotFoundError as e:
        sys.exit(f"signal_q_learning: {e}")


class QLAgent:
    """sumo-rl's ``QLAgent`` with its ``EpsilonGreedy`` exploration (``sumo_rl/agents/ql_agent.py``,
    ``sumo_rl/exploration/epsilon_greedy.py``), drawing from its own generator."""

    def __init__(self, state, n_actions, rng, alpha=0.1, gamma=0.99, epsilon=0.05, min_epsilon=0.005, decay=1.0):
        self.state, self.n, self.rng = state, n_actions, rng
        self.alpha, self.gamma = alpha, gamma
        self.epsilon, self.min_epsilon, self.decay = epsilon, min_epsilon, decay
        self.q = {state: [0.0] * n_actions}
        self.action = None

    def act(self):
        if self.rng.random() < self.epsilon:
            self.action = int(self.rng.integers(self.n))
        else:
            self.action = int(np.argmax(self.q[self.state]))
        self.epsilon = max(self.epsilon * self.decay, self.min_epsilon)
        return self.action

    def learn(self, next_state, reward):
        self.q.setdefault(next_state, [0.0] * self.n)
        s, a = self.state, self.action
        self.q[s][a] += self.alpha * (reward + self.gamma * max(self.q[next_state]) - self.q[s][a])
        self.state = next_state


def encode(state, n_green: int):
    """sumo-rl's ``SumoEnvironment.encode``: (green phase, min-green flag, every density and queue
    in tenths, 9 at most). Written out here: sumo-rl's own fails on numpy 2 (``int()`` of a
    1-element array)."""
    phase = int(np.flatnonzero(state[:n_green] == 1)[0])
    return tuple([phase, state[n_green]] + [min(int(d * 10), 9) for d in state[n_green + 1 :]])


def episode(env, agent, fixed: bool, seed: int):
    """One episode (multi-agent API of both envs); returns (mean system waiting time [s], the
    agent, env steps)."""
    obs = env.reset(seed=seed)
    ts = env.ts_ids[0]
    n = env.traffic_signals[ts].num_green_phases
    if agent is None and not fixed:
        agent = QLAgent(encode(obs[ts], n), env.action_spaces(ts).n, np.random.default_rng(seed))
    elif agent is not None:
        agent.state = encode(obs[ts], n)
        agent.q.setdefault(agent.state, [0.0] * agent.n)
    waits, done, steps = [], False, 0
    while not done:
        if fixed:
            obs, rewards, dones, info = env.step({})
        else:
            obs, rewards, dones, info = env.step({ts: agent.act()})
            agent.learn(encode(obs[ts], n), rewards[ts])
        waits.append(info["system_mean_waiting_time"])
        done = dones["__all__"]
        steps += 1
    return float(np.mean(waits)), agent, steps


#: Episodes whose mean is compared with the fixed-time program's at the end.
LAST = 10


def run(make_env, episodes, label):
    env = make_env(fixed=True)
    fixed, _, _ = episode(env, None, True, 0)
    env.close()
    env = make_env(fixed=False)
    curve, agent = [], None
    t = time.perf_counter()
    steps = 0
    for k in range(episodes):
        w, agent, n = episode(env, agent, False, k)
        curve.append(w)
        steps += n
        print(f"{label} episode {k + 1}: mean waiting time {w:.1f} s (fixed-time program: {fixed:.1f} s)", flush=True)
    env.close()
    print(f"{label}: {steps / (time.perf_counter() - t):,.0f} env-steps/s while learning")
    last = curve[-LAST:]
    mean_last = float(np.mean(last))
    verdict = "lower than" if mean_last < fixed else "not lower than"
    print(
        f"{label}: mean waiting time of the last {len(last)} episodes {mean_last:.1f} s, "
        f"{verdict} the fixed-time program's {fixed:.1f} s",
        flush=True,
    )
    return fixed, curve


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--episodes", type=int, default=150, help="episodes, the Q-table carried over")
    p.add_argument("--seconds", type=int, default=100000, help="sim time per episode [s] (sumo-rl's script: 100000)")
    p.add_argument("--sumo", action="store_true", help="also learn on sumo-rl's SumoEnvironment")
    p.add_argument("--out", default="signal_q_learning.png", help="the figure (PNG)")
    a = p.parse_args()
    if a.episodes < 1 or a.seconds < 10:
        sys.exit("signal_q_learning: --episodes >= 1 and --seconds >= 10")
    d = nets_dir() / "2way-single-intersection"
    common = dict(
        net_file=str(d / "single-intersection.net.xml"),
        route_file=str(d / "single-intersection-vhvh.rou.xml"),
        num_seconds=a.seconds,
        min_green=10,
        max_green=30,
    )

    def ours(fixed):
        from smlworld.envs import TrafficSignalEnv

        return TrafficSignalEnv(fixed_ts=fixed, **common)

    results = {"smlworld": run(ours, a.episodes, "smlworld")}
    if a.sumo:
        if "SUMO_HOME" not in os.environ:
            import sumo

            os.environ["SUMO_HOME"] = sumo.SUMO_HOME
        # sumo-rl reads this when it is first imported: libsumo in the process, not TraCI over a
        # socket (several times faster), where it is installed.
        if importlib.util.find_spec("libsumo") is not None:
            os.environ.setdefault("LIBSUMO_AS_TRACI", "1")

        def theirs(fixed):
            from sumo_rl import SumoEnvironment

            return SumoEnvironment(fixed_ts=fixed, sumo_warnings=False, **common)

        results["sumo-rl"] = run(theirs, a.episodes, "sumo-rl")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for (name, (fixed, curve)), colour in zip(results.items(), ["tab:blue", "tab:orange"]):
        x = np.arange(1, len(curve) + 1)
        ax.plot(x, curve, ".", color=colour, alpha=0.35)
        # The mean of the last (up to) LAST episodes: the trend through the exploration's noise.
        trend = [np.mean(curve[max(0, k + 1 - LAST) : k + 1]) for k in range(len(curve))]
        ax.plot(x, trend, "-", color=colour, label=f"{name}: Q-learning (mean of last {LAST})")
        ax.axhline(fixed, color=colour, linestyle="--", label=f"{name}: fixed-time program")
    ax.set_xlabel("episode")
    ax.set_ylabel("mean system waiting time [s]")
    ax.set_yscale("log")  # the first episodes wait minutes, the fixed-time program seconds
    ax.set_title(f"2way-single-intersection, vhvh, {a.seconds} s episodes")
    ax.legend()
    fig.tight_layout()
    fig.savefig(a.out, dpi=120)
    print(f"figure: {a.out}")


if __name__ == "__main__":
    main()
