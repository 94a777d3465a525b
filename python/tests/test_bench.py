"""python/bench/bench_envs.py, the figures the README gives for the envs' speed, runs and reports
min / median / max over repeats."""

import re
import subprocess
import sys


def test_bench_envs_repeats_and_reports_min_median_max(root):
    done = subprocess.run(
        [sys.executable, str(root / "python/bench/bench_envs.py"), "--steps", "100", "--repeat", "3", "--no-highway-env"],
        capture_output=True,
        text=True,
        timeout=120,  # seconds; a parallel env with max_steps=10**9 once spent a minute per reset
    )
    assert done.returncode == 0, done.stderr[-2000:]
    lines = {line.split(":")[0]: line for line in done.stdout.splitlines()}
    for name in ("PlatoonFollow-v0", "HighwayMerge-v0"):
        m = re.search(r": ([\d,]+) / ([\d,]+) / ([\d,]+) \(min / median / max\) env-steps/s", lines[name])
        assert m, lines[name]
        lo, mid, hi = (float(g.replace(",", "")) for g in m.groups())
        assert 0 < lo <= mid <= hi


def test_bench_envs_vec_mode_reports_both_vector_envs(root):
    done = subprocess.run(
        [sys.executable, str(root / "python/bench/bench_envs.py"), "--vec", "4", "--steps", "20", "--repeat", "3"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    for name in ("PlatoonFollow-v0", "HighwayMerge-v0"):
        line = next(x for x in done.stdout.splitlines() if x.startswith(f"{name} make_vec(num_envs=4)"))
        m = re.search(r": ([\d,]+) / ([\d,]+) / ([\d,]+) \(min / median / max\) env-steps/s \(20 steps x 4 envs", line)
        assert m, line
