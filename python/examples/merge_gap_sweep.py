"""The merge's gap rule against what it costs (issue 59): scenarios/gcdc_merge.toml with the 2015
rule (front max(10, 0.27 v^1.5) m, rear max(10, 0.23 v^1.5) m) and with time-gap rules of 0.5 to
1.5 s (standstill 5 m), each with wifi loss 0 and 0.2, over 10 seeds. Writes
out/merge_gap_sweep.csv and out/merge_gap_sweep.png: the smallest time gap of the merge, the
lowest speed of any participant over its speed at the announcement, and the gap makers' extra
travel time against the same run without platoon B (metrics.merge.delay_s), mean and 95 % band
over the seeds, and prints merges and collisions per cell.

    pip install "./python[sweep,plot]"
    python python/examples/merge_gap_sweep.py [--seeds 10] [--backend local|ray] [--address auto]
"""

import argparse
from pathlib import Path

import numpy as np

import smlworld
from smlworld.sweep import mean_ci95  # mean and 95 % band over the seeds

ROOT = Path(__file__).resolve().parents[2]
LOSS = "v2v.wifi.loss"
RULE = "vehicles.*.controller.merge.gap_rule"
TIME_GAP = RULE + ".time_gap"  # [s]; the table gap_rule = { time_gap, standstill } is made by the two keys
STANDSTILL = RULE + ".standstill"  # [m]
TIME_GAPS = [0.5, 0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.2, 1.3, 1.4, 1.5]
METRICS = ("min_time_gap_s", "min_speed_ratio", "delay_s")


def run(seeds, backend, address, grid, rule):
    df = smlworld.sweep(
        ROOT / "scenarios/gcdc_merge.toml", grid=grid, seeds=list(seeds), backend=backend, address=address
    )
    for m in METRICS + ("vehicles_merged", "vehicles_to_merge"):
        df[m] = df[f"metrics.merge.{m}"]
    df["collisions"] = df["metrics.collision_count"]
    df["rule"] = rule
    df["time_gap"] = df[TIME_GAP] if TIME_GAP in df else np.nan
    return df[["rule", "time_gap", LOSS, "seed", *METRICS, "vehicles_merged", "vehicles_to_merge", "collisions"]]


def main():  # under a main guard: the local backend's worker processes re-import this file
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--backend", default="local", choices=["local", "ray"])
    ap.add_argument("--address", default=None)
    ap.add_argument("--out", default=str(ROOT / "out"))
    args = ap.parse_args()

    import pandas as pd

    seeds = range(1, args.seeds + 1)
    losses = [0.0, 0.2]
    sml = run(seeds, args.backend, args.address, {LOSS: losses}, "sml2015")
    tg = run(seeds, args.backend, args.address, {LOSS: losses, TIME_GAP: TIME_GAPS, STANDSTILL: [5.0]}, "time_gap")
    df = pd.concat([sml, tg], ignore_index=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    df.to_csv(out / "merge_gap_sweep.csv", index=False)
    table = df.groupby(["rule", "time_gap", LOSS], dropna=False)
    print(table[[*METRICS, "vehicles_merged", "collisions"]].agg(["mean", "min", "max"]).round(3).to_string())

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    labels = {
        "min_time_gap_s": "smallest time gap in the merge [s]",
        "min_speed_ratio": "lowest speed / speed at announcement [-]",
        "delay_s": "gap makers' delay vs. no platoon B [s]",
    }
    for loss, colour in zip(losses, ("#1f77b4", "#d62728")):
        part = tg[tg[LOSS] == loss]
        for ax, col in zip(axes, METRICS):
            stats = [mean_ci95(part[part["time_gap"] == g][col]) for g in TIME_GAPS]
            mean = np.array([s[0] for s in stats])
            half = np.array([s[1] for s in stats])
            ax.plot(TIME_GAPS, mean, "o-", color=colour, label=f"time-gap rule, wifi loss {loss:g}")
            ax.fill_between(TIME_GAPS, mean - half, mean + half, color=colour, alpha=0.2)
            m, h = mean_ci95(sml[sml[LOSS] == loss][col])
            ax.axhline(m, color=colour, ls="--", lw=1, label=f"2015 rule (sml2015), wifi loss {loss:g}")
    for ax, col in zip(axes, METRICS):
        ax.set_xlabel("time gap of the rule (standstill 5 m) [s]")
        ax.set_ylabel(labels[col])
        ax.grid(alpha=0.3)
    axes[1].axhline(0.75, color="grey", lw=0.8, ls=":")
    axes[0].legend(fontsize=8)
    fig.suptitle(
        f"gcdc_merge: 5 mergers into platoon A at 80 km/h; gap rule against safety and cost; mean and 95 % band over {args.seeds} seeds"
    )
    fig.tight_layout()
    fig.savefig(out / "merge_gap_sweep.png", dpi=120)
    print(f"wrote {out / 'merge_gap_sweep.csv'} and {out / 'merge_gap_sweep.png'}")


if __name__ == "__main__":
    main()
