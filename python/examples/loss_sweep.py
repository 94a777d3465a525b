"""Platoon braking under packet loss (issue 21): scenarios/platoon_brake.toml with wifi loss 0, 0.1,
..., 0.5 x 10 seeds, with the followers' fallback to ACC (the default) and without it (a beacon
timeout longer than the run, so a follower keeps trusting the last beacon it heard). Writes
out/loss_sweep.csv and out/loss_sweep.png: the platoon's smallest gap and the string-stability
amplification against loss, mean and 95 % band over the seeds, and prints collisions per cell.

    pip install "./python[sweep,plot]"
    python python/examples/loss_sweep.py [--seeds 10] [--backend local|ray] [--address auto]
"""

import argparse
from pathlib import Path

import numpy as np

import smlworld
from smlworld.sweep import mean_ci95  # mean and 95 % band over the seeds

ROOT = Path(__file__).resolve().parents[2]
LOSS = "v2v.wifi.loss"
FOLLOWERS = range(1, 5)  # vehicles[1..4] of platoon_brake are the followers
NO_FALLBACK = {f"vehicles.{i}.controller.fallback.beacon_timeout": [1000.0] for i in FOLLOWERS}  # [s]


def run(seeds, backend, address, fallback):
    grid = {LOSS: [0.0, 0.1, 0.2, 0.3, 0.4, 0.5]}
    if not fallback:
        grid.update(NO_FALLBACK)
    df = smlworld.sweep(
        ROOT / "scenarios/platoon_brake.toml",
        grid=grid,
        seeds=list(seeds),
        backend=backend,
        address=address,
        duration=50.0,
    )
    gaps = [c for c in df.columns if c.startswith("metrics.followers.") and c.endswith(".min_gap")]
    df["min_gap"] = df[gaps].min(axis=1)
    df["amplification"] = df["metrics.platoons.0.amplification"]
    df["collisions"] = df["metrics.collision_count"]
    df["fallback"] = fallback
    return df[[LOSS, "seed", "fallback", "min_gap", "amplification", "collisions"]]


def main():  # under a main guard: the local backend's worker processes re-import this file
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--backend", default="local", choices=["local", "ray"])
    ap.add_argument("--address", default=None)
    ap.add_argument("--out", default=str(ROOT / "out"))
    args = ap.parse_args()

    import pandas as pd

    seeds = range(1, args.seeds + 1)
    df = pd.concat([run(seeds, args.backend, args.address, fb) for fb in (True, False)], ignore_index=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    df.to_csv(out / "loss_sweep.csv", index=False)
    print(df.groupby(["fallback", LOSS])[["min_gap", "amplification", "collisions"]].agg(["mean", "max"]).round(3))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for fb, colour, label in ((True, "#1f77b4", "with fallback to ACC"), (False, "#d62728", "without fallback")):
        part = df[df["fallback"] == fb]
        losses = sorted(part[LOSS].unique())
        for ax, col in zip(axes, ("min_gap", "amplification")):
            stats = [mean_ci95(part[part[LOSS] == p][col]) for p in losses]
            mean = np.array([s[0] for s in stats])
            half = np.array([s[1] for s in stats])
            ax.plot(losses, mean, "o-", color=colour, label=label)
            ax.fill_between(losses, mean - half, mean + half, color=colour, alpha=0.2)
    axes[0].set_ylabel("smallest gap in the platoon [m]")
    axes[1].set_ylabel("speed amplification, last / first follower [-]")
    for ax in axes:
        ax.set_xlabel("wifi packet loss [-]")
        ax.grid(alpha=0.3)
    axes[0].legend()
    fig.suptitle(f"platoon_brake: leader brakes at 6 m/s² at 30 s; mean and 95 % band over {args.seeds} seeds")
    fig.tight_layout()
    fig.savefig(out / "loss_sweep.png", dpi=120)
    print(f"wrote {out / 'loss_sweep.csv'} and {out / 'loss_sweep.png'}")


if __name__ == "__main__":
    main()
