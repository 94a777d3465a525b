#!/usr/bin/env python3
"""Measure the performance table of docs/performance.md and write it there (issue 25: the table is generated,
not typed).

    python3 scripts/perf_table.py [--runs 3] [--vehicles 10000] [--no-write]
    python3 scripts/perf_table.py --readme [--check]

Builds the release binary, then runs each `smlworld bench` configuration RUNS times, the
simulation configurations taking turns (plain, --lane-change, --degraded, the student camera on a
tenth of the vehicles, on the default threads
and on one) so every ratio compares figures of the same minutes. Each ratio is given three ways:
of the medians, paired (the median of each turn's ratio) and of the best runs. Prints the table (min / median /
max of the runs, the command of each row, N, the commit, the machine's load) and, unless
--no-write, replaces the block between docs/performance.md's `<!-- perf-table:start -->` and
`<!-- perf-table:end -->` markers with it. The generated grid map for the routing and loading rows
goes into a temporary folder that is removed at the end.

The README's short table (between `<!-- perf-summary:start -->` and `<!-- perf-summary:end -->`)
is derived from docs/performance.md's table, never typed: a measuring run rewrites both, and
`--readme` rewrites only the README's from the table as it stands (`--check`: exit 1, naming
the difference, when the README's is not what the table gives; a test runs it).
"""

import argparse
import json
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent
BINARY = ROOT / "target" / "release" / "smlworld"
START, END = "<!-- perf-table:start -->", "<!-- perf-table:end -->"
SUMMARY_START, SUMMARY_END = "<!-- perf-summary:start -->", "<!-- perf-summary:end -->"
# The rows of docs/performance.md's table the README shows: (command, threads column, README label).
SUMMARY_ROWS = [
    ("smlworld bench --vehicles 10000 --duration 10", "threads", "10,000 vehicles on a ring"),
    ("smlworld bench --vehicles 10000 --duration 10 --lane-change", "threads", "the same with MOBIL lane changes"),
    ("smlworld bench --vehicles 100000 --duration 2", "threads", "100,000 vehicles"),
    ("smlworld bench --city --duration 60", "threads", "a 20x20 town with lights, 10,000 vehicles on random trips"),
    ("smlworld bench --map-load Town04.xodr", "MB", "loading CARLA's Town04 (OpenDRIVE)"),
]


def bench(args):
    """Run `smlworld bench ARGS` and return its JSON."""
    out = subprocess.run([str(BINARY), "bench", *args], capture_output=True, text=True)
    if out.returncode != 0:
        sys.exit(f"perf_table.py: smlworld bench {' '.join(args)} failed:\n{out.stderr}")
    return json.loads(out.stdout)


def processor():
    """The processor's model name (the figures depend on it: machines of one kind differ)."""
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "an unknown processor"


def spread(xs, digits=2):
    return " / ".join(f"{x:,.{digits}f}" for x in (min(xs), statistics.median(xs), max(xs)))


def table_rows(text):
    """The rows of the generated table in `text` (docs/performance.md): a list of its cells."""
    if START not in text or END not in text:
        sys.exit(f"perf_table.py: docs/performance.md has no {START} ... {END} block")
    block = text.split(START, 1)[1].split(END, 1)[0]
    rows = []
    for line in block.splitlines():
        if line.startswith("| `"):
            rows.append([c.strip() for c in line.strip().strip("|").split("|")])
    return rows


def median_of(figure):
    """`a / b / c UNIT, more` -> `b UNIT, more`: the median of a min / median / max figure."""
    parts = figure.split(" / ")
    if len(parts) < 3:
        return figure
    unit = parts[2].split(" ", 1)[1] if " " in parts[2] else ""
    return f"{parts[1]} {unit}".strip()


def summary(table_text):
    """The README's short table, from docs/performance.md's generated one."""
    rows = table_rows(table_text)
    lines = [SUMMARY_START, "| what (2 cores, no GPU) | command | figure |", "|---|---|---|"]
    for command, on, label in SUMMARY_ROWS:
        row = next((r for r in rows if r[0] == f"`{command}`" and on in r[1]), None)
        if row is None:
            continue  # not measured on this machine (e.g. Town04 absent): the README leaves it out
        figure = median_of(row[2])
        if len(row) > 3 and row[3]:
            figure += f", {row[3]} real time"
        lines.append(f"| {label} | `{command}` | {figure} |")
    lines.append(SUMMARY_END)
    return "\n".join(lines)


def write_readme(check):
    """Rewrite (or with `check`, compare) the README's short table from docs/performance.md's."""
    readme = ROOT / "README.md"
    text = readme.read_text()
    if SUMMARY_START not in text or SUMMARY_END not in text:
        sys.exit(f"perf_table.py: README.md has no {SUMMARY_START} ... {SUMMARY_END} block")
    head, rest = text.split(SUMMARY_START, 1)
    old, tail = rest.split(SUMMARY_END, 1)
    new = summary((ROOT / "docs" / "performance.md").read_text())
    if check:
        if SUMMARY_START + old + SUMMARY_END != new:
            sys.exit("perf_table.py: README.md's performance table is not the one docs/performance.md's gives;"
                     " run `python3 scripts/perf_table.py --readme`. It should read:\n" + new)
        print("README.md's performance table matches docs/performance.md's")
        return
    readme.write_text(head + new + tail)
    print("README.md: performance summary written", file=sys.stderr)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="runs of each configuration (default 3)")
    ap.add_argument("--vehicles", type=int, default=10000, help="vehicles of the simulation rows (default 10000)")
    ap.add_argument("--no-write", action="store_true", help="print the table, leave docs/performance.md as it is")
    ap.add_argument("--readme", action="store_true",
                    help="measure nothing: rewrite README.md's short table from docs/performance.md's")
    ap.add_argument("--check", action="store_true",
                    help="with --readme: change nothing, exit 1 when README.md's short table is not the one docs/performance.md's gives")
    a = ap.parse_args()
    if a.check and not a.readme:
        sys.exit("perf_table.py: --check goes with --readme")
    if a.readme:
        write_readme(a.check)
        return
    if a.runs < 1 or a.vehicles < 1:
        sys.exit("perf_table.py: --runs and --vehicles must be at least 1")

    subprocess.run(["cargo", "build", "--release", "--quiet"], cwd=ROOT, check=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    load_before = os.getloadavg()[0]

    n = str(a.vehicles)
    sims = {
        "plain": ["--vehicles", n, "--duration", "10"],
        "lane-change": ["--vehicles", n, "--duration", "10", "--lane-change"],
        "degraded": ["--vehicles", n, "--duration", "10", "--degraded"],
        # The student camera of examples/student_sensor.rs on a tenth of the vehicles (issue 58).
        "plugin-camera": ["--vehicles", n, "--duration", "10", "--plugin-sensor-share", "0.1"],
    }
    results = {(name, threads): [] for name in sims for threads in ("default", "1")}
    used = {}
    for run in range(a.runs):
        for threads in ("default", "1"):
            for name, args in sims.items():
                extra = [] if threads == "default" else ["--threads", "1"]
                r = bench(args + extra)
                results[(name, threads)].append(r["vehicle_steps_per_second"] / 1e6)
                used[threads] = r["threads_used"]
                print(f"run {run + 1}: {name:11} threads {threads:7} {r['vehicle_steps_per_second'] / 1e6:6.2f} M vehicle-steps/s", file=sys.stderr)

    big = [bench(["--vehicles", "100000", "--duration", "2"]) for _ in range(a.runs)]
    render = [bench(["--vehicles", n, "--duration", "2", "--render", "1920x1080"]) for _ in range(a.runs)]
    render_ms = [ms for r in render for ms in r["render"]["frame_ms"]]
    adapter = render[0]["render"]["adapter"]

    with tempfile.TemporaryDirectory() as tmp:
        grid = pathlib.Path(tmp) / "grid32.osm"
        subprocess.run([str(BINARY), "map", "generate", "grid", "--rows", "32", "--cols", "32", "--out", str(grid)],
                       check=True, capture_output=True)
        routing = [bench(["--routing", str(grid), "--routes", "1000"]) for _ in range(a.runs)]
        loading = [bench(["--map-load", str(grid)]) for _ in range(a.runs)]
    lanelets = routing[0]["lanelets"]
    mb = loading[0]["bytes"] / 1e6
    # The town (issue 53) and an OpenDRIVE map (issue 56, Town04 from ../shared/data when present).
    city = [bench(["--city", "--duration", "60"]) for _ in range(a.runs)]
    town04 = ROOT.parent / "shared" / "data" / "opendrive" / "Town04.xodr"
    xodr = [bench(["--map-load", str(town04)]) for _ in range(a.runs)] if town04.exists() else []
    load_after = os.getloadavg()[0]

    def ratio(name, threads):
        """The configuration's figure as a share of plain's: of the medians, of each run with the
        plain run of the same turn (paired: both ran within seconds, under the same load), and
        of the best runs (the least disturbed by other work on a noisy machine)."""
        xs, plain = results[(name, threads)], results[("plain", threads)]
        paired = statistics.median(x / p for x, p in zip(xs, plain))
        return statistics.median(xs) / statistics.median(plain), paired, max(xs) / max(plain)

    rows = []
    for threads in ("default", "1"):
        flag = "" if threads == "default" else " --threads 1"
        label = f"{used[threads]} threads" if threads == "default" else "1 thread"
        for name in sims:
            cmd = "smlworld bench " + " ".join(sims[name]) + flag
            xs = results[(name, threads)]
            rtf = f"{statistics.median(xs) * 1e6 / a.vehicles * 0.02:,.1f}x"
            of_plain = "" if name == "plain" else "{:.0%} of plain (paired {:.0%}, best runs {:.0%})".format(*ratio(name, threads))
            rows.append(f"| `{cmd}` | {label} | {spread(xs)} M vehicle-steps/s | {rtf} | {of_plain} |")
    big_rtf = [r["real_time_factor"] for r in big]
    big_mb = max(r["peak_rss_mb"] or 0.0 for r in big)
    rows.append(f"| `smlworld bench --vehicles 100000 --duration 2` | {big[0]['threads_used']} threads | "
                f"{spread([r['vehicle_steps_per_second'] / 1e6 for r in big])} M vehicle-steps/s, peak {big_mb:,.0f} MB | "
                f"{statistics.median(big_rtf):,.2f}x | |")
    rows.append(f"| `smlworld bench --vehicles {n} --duration 2 --render 1920x1080` | {adapter.split(' (')[0]} | "
                f"{spread(render_ms, 1)} ms per frame ({len(render_ms)} frames) | | |")
    rows.append(f"| `smlworld bench --routing GRID --routes 1000` | {lanelets} lanelets | "
                f"{spread([r['routes_per_second'] for r in routing], 0)} routes/s | | |")
    rows.append(f"| `smlworld bench --map-load GRID` | {mb:.1f} MB | "
                f"{spread([r['mb_per_second'] for r in loading], 1)} MB/s | | |")
    rows.append(f"| `smlworld bench --city --duration 60` | {city[0]['threads']} threads, {city[0]['vehicles']:,} vehicles | "
                f"{spread([r['vehicle_updates_per_s'] / 1e6 for r in city])} M vehicle-steps/s, set-up "
                f"{statistics.median([r['setup_seconds'] for r in city]):.1f} s | "
                f"{statistics.median([r['real_time_factor'] for r in city]):.2f}x | |")
    if xodr:
        rows.append(f"| `smlworld bench --map-load Town04.xodr` | {xodr[0]['bytes'] / 1e6:.1f} MB | "
                    f"{spread([r['mb_per_second'] for r in xodr], 1)} MB/s | | |")
    table = "\n".join([
        START,
        f"Generated by `python3 scripts/perf_table.py --runs {a.runs}` at commit {commit}"
        + (" (with uncommitted changes)" if dirty else "")
        + f"; {a.runs} runs of each row (min / median / max), the simulation rows taking turns;"
        f" on {processor()}, {os.cpu_count()} cores; load average {load_before:.1f} before, {load_after:.1f} after."
        " GRID: `smlworld map generate grid --rows 32 --cols 32`.",
        "",
        "| command | on | figure | real time | ratio |",
        "|---|---|---|---|---|",
        *rows,
        END,
    ])
    print(table)
    if a.no_write:
        return
    readme = ROOT / "docs" / "performance.md"
    text = readme.read_text()
    if START in text and END in text:
        head, rest = text.split(START, 1)
        _, tail = rest.split(END, 1)
        text = head + table + tail
    else:
        sys.exit(f"perf_table.py: docs/performance.md has no {START} ... {END} block; add one where the table belongs")
    readme.write_text(text)
    print("docs/performance.md: performance table written", file=sys.stderr)
    write_readme(check=False)


if __name__ == "__main__":
    main()
