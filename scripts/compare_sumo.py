#!/usr/bin/env python3
"""Run SUMO and SML World on the same SUMO net and routes, side by side (issue 54 §2).

    python3 scripts/compare_sumo.py NET ROUTES [ROUTES ...] [--end S] [--step S] [--begin S]

Both sides get the same files at the same step length (SUMO's `--step-length` equal to our
dynamics step, default 0.1 s) with every vType driving the IDM: a copy of each route file has
`carFollowModel="IDM"` set on every `<vType>`, and a `DEFAULT_VEHTYPE` with the IDM is added
where vehicles name no type (SUMO's defaults otherwise: accel 2.6 m/s², decel 4.5 m/s², tau 1 s,
minGap 2.5 m). SUMO (eclipse-sumo from PyPI, one thread, `--seed 42`) writes its tripinfo with
the unfinished trips; SML World runs the same configuration (`smlworld run x.sumocfg`, log at
1 Hz) and writes trips.csv. Prints one JSON line per side:

    {"side": "sumo", "inserted", "arrived", "peak_vehicles", "mean_travel_time_s",
     "mean_waiting_time_s", "wall_s", "step_s"}

(travel time over the vehicles that arrived; waiting time, time below 0.1 m/s, over every
vehicle inserted; peak = most vehicles in the network at once; wall = the process's wall
time, start-up and writing included), then `{"ratio_wall": SUMO's wall / ours,
"ratio_travel_time": our mean travel time / SUMO's}`.

The SUMO binary is `$SUMO_BINARY`, else `sumo` beside this Python (a venv with eclipse-sumo),
else `sumo` on the PATH; ours is target/release/smlworld (built when missing).
"""

import argparse
import csv
import json
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET

ROOT = pathlib.Path(__file__).resolve().parent.parent
BINARY = ROOT / "target" / "release" / "smlworld"


def fail(message):
    sys.exit(f"compare_sumo.py: {message}")


def sumo_binary():
    if os.environ.get("SUMO_BINARY"):
        return os.environ["SUMO_BINARY"]
    beside = pathlib.Path(sys.executable).parent / "sumo"
    if beside.exists():
        return str(beside)
    found = shutil.which("sumo")
    if found is None:
        fail("no SUMO: install it with `pip install eclipse-sumo` (or set SUMO_BINARY)")
    return found


def idm_routes(src, dst):
    """Copy the route file `src` to `dst` with every vType driving the IDM."""
    try:
        tree = ET.parse(src)
    except (OSError, ET.ParseError) as e:
        fail(f"{src}: {e}")
    root = tree.getroot()
    types = root.findall("vType")
    for t in types:
        t.set("carFollowModel", "IDM")
    typed = {"vehicle", "flow", "trip"}
    untyped = any(el.tag in typed and "type" not in el.attrib for el in root.iter())
    if untyped and not any(t.get("id") == "DEFAULT_VEHTYPE" for t in types):
        default = ET.Element("vType", {"id": "DEFAULT_VEHTYPE", "carFollowModel": "IDM"})
        default.tail = "\n    "
        root.insert(0, default)
    tree.write(dst, encoding="UTF-8", xml_declaration=True)


def peak(intervals, end):
    """Most intervals (depart, arrival or None) open at once; an open end lasts until `end`."""
    events = []
    for depart, arrival in intervals:
        events.append((depart, 1))
        events.append((arrival if arrival is not None else end, -1))
    events.sort(key=lambda e: (e[0], e[1]))  # a departure at the time of an arrival comes after it
    now = best = 0
    for _, step in events:
        now += step
        best = max(best, now)
    return best


def figures(side, trips, end, wall, step):
    """The JSON line of one side from its trips: (depart, arrival or None, travel or None, waiting)."""
    arrived = [t for t in trips if t[2] is not None]
    mean = lambda xs: round(sum(xs) / len(xs), 2) if xs else None  # noqa: E731
    return {
        "side": side,
        "inserted": len(trips),
        "arrived": len(arrived),
        "peak_vehicles": peak([(t[0], t[1]) for t in trips], end),
        "mean_travel_time_s": mean([t[2] for t in arrived]),
        "mean_waiting_time_s": mean([t[3] for t in trips]),
        "wall_s": round(wall, 3),
        "step_s": step,
    }


def timed(who, cmd):
    """Run `cmd` and return its wall time [s]; stop with its error output when it fails."""
    start = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        fail(f"{who} failed ({' '.join(cmd)}):\n{done.stderr}")
    return wall


def run_sumo(cfg, out, end, step):
    tripinfo = out / "tripinfo.xml"
    cmd = [sumo_binary(), "-c", str(cfg), "--tripinfo-output", str(tripinfo),
           "--tripinfo-output.write-unfinished", "true", "--seed", "42", "--no-step-log", "true",
           "--no-warnings", "true", "--duration-log.disable", "true"]
    wall = timed("SUMO", cmd)
    trips = []
    for t in ET.parse(tripinfo).getroot().iter("tripinfo"):
        depart = float(t.get("depart"))
        if depart < 0:
            continue  # never inserted
        arrival = float(t.get("arrival"))
        finished = arrival >= 0 and t.get("vaporized", "") == ""
        duration = float(t.get("duration"))
        trips.append((depart, arrival if finished else None, duration if finished else None,
                      float(t.get("waitingTime"))))
    return figures("sumo", trips, end, wall, step)


def run_ours(cfg, out, end, step):
    if not BINARY.exists():
        subprocess.run(["cargo", "build", "--release", "--quiet"], cwd=ROOT, check=True)
    cmd = [str(BINARY), "run", str(cfg), "--out", str(out / "smlworld"), "--log-rate", "1"]
    wall = timed("smlworld", cmd)
    trips = []
    with open(out / "smlworld" / "trips.csv", newline="") as f:
        for row in csv.DictReader(f):
            arrival = float(row["arrival"]) if row["arrival"] else None
            travel = float(row["travel_time_s"]) if row["travel_time_s"] else None
            trips.append((float(row["depart"]), arrival, travel, float(row["waiting_time_s"])))
    return figures("smlworld", trips, end, wall, step)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("net", type=pathlib.Path, help="SUMO network (.net.xml)")
    ap.add_argument("routes", type=pathlib.Path, nargs="+", help="SUMO route files (.rou.xml)")
    ap.add_argument("--begin", type=float, default=0.0, help="first second simulated (default 0)")
    ap.add_argument("--end", type=float, default=3600.0, help="last second simulated (default 3600)")
    ap.add_argument("--step", type=float, default=0.1, help="step length of both [s] (default 0.1)")
    ap.add_argument("--keep", type=pathlib.Path, help="keep the files of both runs in this folder")
    a = ap.parse_args()
    if a.step <= 0 or a.end <= a.begin:
        fail("--step must be above 0 and --end after --begin")
    for f in [a.net, *a.routes]:
        if not f.is_file():
            fail(f"{f}: no such file")
    with tempfile.TemporaryDirectory() as tmp:
        out = a.keep or pathlib.Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        routes = []
        for k, r in enumerate(a.routes):
            dst = out / f"idm_{k}_{r.name}"
            idm_routes(r, dst)
            routes.append(dst)
        cfg = out / "compare.sumocfg"
        cfg.write_text(
            '<?xml version="1.0" encoding="UTF-8"?>\n<configuration>\n'
            f'    <input><net-file value="{a.net.resolve()}"/>'
            f'<route-files value="{",".join(str(r) for r in routes)}"/></input>\n'
            f'    <time><begin value="{a.begin:g}"/><end value="{a.end:g}"/><step-length value="{a.step:g}"/></time>\n'
            "</configuration>\n")
        print(f"step length {a.step:g} s, {a.begin:g} s to {a.end:g} s, every vType on the IDM", file=sys.stderr)
        sumo = run_sumo(cfg, out, a.end, a.step)
        print(json.dumps(sumo), flush=True)
        ours = run_ours(cfg, out, a.end, a.step)
        print(json.dumps(ours), flush=True)
        travel = (ours["mean_travel_time_s"] / sumo["mean_travel_time_s"]
                  if ours["mean_travel_time_s"] and sumo["mean_travel_time_s"] else None)
        print(json.dumps({"ratio_wall": round(sumo["wall_s"] / ours["wall_s"], 2),
                          "ratio_travel_time": round(travel, 3) if travel else None}))


if __name__ == "__main__":
    main()
