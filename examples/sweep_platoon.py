"""Sweep platoon_brake: followers' time gap x the leader's braking deceleration x 3 seeds; writes
out/sweep_platoon.csv and a heat map of the platoon's minimum gap, out/sweep_platoon.png.

    pip install ./python pandas matplotlib          # + ray for --backend ray
    python examples/sweep_platoon.py [--backend local|ray] [--address auto]
"""

import argparse
from pathlib import Path

import numpy as np

import smlworld

ROOT = Path(__file__).resolve().parents[1]
TIME_GAP = "vehicles.controller.platoon.time_gap"  # [s], every follower
DECEL = "vehicles.controller.cruise.dip.deceleration"  # [m/s^2], the leader's stop



def main():  # under a main guard: the local backend's worker processes re-import this file
    ap = argparse.ArgumentParser()
    ap.add_argument("--backend", default="local", choices=["local", "ray"])
    ap.add_argument("--address", default=None)
    args = ap.parse_args()

    df = smlworld.sweep(
        ROOT / "scenarios/platoon_brake.toml",
        grid={TIME_GAP: [0.3, 0.5, 0.8, 1.2], DECEL: [2.0, 4.0, 6.0, 8.0]},
        seeds=[1, 2, 3],
        backend=args.backend,
        address=args.address,
        duration=50.0,
    )
    gap_cols = [c for c in df.columns if c.startswith("metrics.followers.") and c.endswith(".min_gap")]
    df["min_gap"] = df[gap_cols].min(axis=1)
    out = ROOT / "out"
    out.mkdir(exist_ok=True)
    df.to_csv(out / "sweep_platoon.csv", index=False)
    table = df.groupby([TIME_GAP, DECEL])["min_gap"].min().unstack()
    print(table.round(2))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    im = ax.imshow(table.values, origin="lower", cmap="viridis", aspect="auto")
    ax.set_xticks(range(len(table.columns)), [f"{v:g}" for v in table.columns])
    ax.set_yticks(range(len(table.index)), [f"{v:g}" for v in table.index])
    ax.set_xlabel("leader deceleration [m/s²]")
    ax.set_ylabel("follower time gap [s]")
    ax.set_title("platoon_brake: minimum gap over 3 seeds [m]")
    for i in range(table.shape[0]):
        for j in range(table.shape[1]):
            ax.text(j, i, f"{table.values[i, j]:.1f}", ha="center", va="center", color="w")
    fig.colorbar(im, ax=ax, label="minimum gap [m]")
    fig.savefig(out / "sweep_platoon.png", dpi=100, bbox_inches="tight")
    print("wrote", out / "sweep_platoon.csv", "and", out / "sweep_platoon.png")


if __name__ == "__main__":
    main()
