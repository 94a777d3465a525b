#!/usr/bin/env bash
# SML World beside SUMO on the same traffic (issue 25, item 6): N vehicles (default 10,000)
# evenly spread over a 3-lane ring, 40 m apart per lane, at 20 m/s, stepped at 0.02 s.
#
#   scripts/bench_vs_sumo.sh [--vehicles N] [--rounds R] [--sumo-seconds S]
#
# SUMO (eclipse-sumo from PyPI, pinned) lives in its own virtual environment .venv-sumo (not the
# test .venv). Each round runs SUMO and `smlworld bench --vehicles N --duration 10`, so both
# figures of a round come from the same minute; odd rounds start with SUMO, even ones with
# smlworld, so neither always runs straight after the other (a bench straight after SUMO's
# 10 s at full load ran 0-10 % slower than one before it, 5 pairs). SUMO's figure is its own "UPS" (vehicle updates
# per second of wall time, from --duration-log.statistics); ours is `vehicle_steps_per_second`.
# Prints one line per round (with that round's own ratio, ours / SUMO's: the two figures of one
# minute) and a closing JSON object with the medians and their ratio ("ratio"), and each round's
# ratio with their median, least and greatest ("round_ratios", "round_ratio_median", ...): SUMO's
# figure swings by half from one minute to the next on this kind of machine, so the ratio of the
# medians can pair a fast minute of one program with a slow one of the other. Nothing is written into the repository but .venv-sumo; the SUMO network and routes go
# into a temporary folder that is removed at the end.
#
# Each program writes into a file while it is timed and is read only after it has exited: a
# reader started beside it (`bench | python3 -c ...`, as this script once did) takes one of the
# two cores for its own start-up (about 0.2 s here) while the bench runs, and cut our figure by
# a fifth.
#
# Environment: SMLWORLD_BIN times that smlworld binary instead of building this checkout's
# (e.g. another build beside SUMO); SUMO_VENV uses that virtual environment for SUMO instead of
# .venv-sumo (it must hold bin/sumo, bin/netconvert and bin/python with the `sumo` package).
set -euo pipefail
cd "$(dirname "$0")/.."

VEHICLES=10000
ROUNDS=3
SUMO_SECONDS=4
SUMO_VERSION=1.28.0
while [ $# -gt 0 ]; do
  case "$1" in
    --vehicles) VEHICLES="$2"; shift 2 ;;
    --rounds) ROUNDS="$2"; shift 2 ;;
    --sumo-seconds) SUMO_SECONDS="$2"; shift 2 ;;
    -h|--help) sed -n '2,27p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "bench_vs_sumo.sh: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done
case "$VEHICLES$ROUNDS" in
  *[!0-9]*) echo "bench_vs_sumo.sh: --vehicles and --rounds take whole numbers" >&2; exit 2 ;;
esac

VENV=${SUMO_VENV:-.venv-sumo}
if [ ! -x "$VENV/bin/sumo" ] || [ "$(cat "$VENV/.sumo.stamp" 2>/dev/null || true)" != "$SUMO_VERSION" ]; then
  echo "installing eclipse-sumo $SUMO_VERSION into $VENV ..." >&2
  python3 -m venv "$VENV"
  "$VENV/bin/pip" install -q --disable-pip-version-check "eclipse-sumo==$SUMO_VERSION"
  echo "$SUMO_VERSION" > "$VENV/.sumo.stamp"
fi
export SUMO_HOME
SUMO_HOME=$("$VENV/bin/python" -c 'import sumo; print(sumo.SUMO_HOME)')

if [ -n "${SMLWORLD_BIN:-}" ]; then
  SMLWORLD=$SMLWORLD_BIN
else
  cargo build --release --quiet
  SMLWORLD=target/release/smlworld
fi

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# The ring as SUMO's plain XML: a 256-gon of 3-lane edges, one route starting on each edge (a
# vehicle departs on its route's first edge), every vehicle placed at t = 0 like the bench.
python3 - "$work" "$VEHICLES" <<'EOF'
import math, sys
work, n = sys.argv[1], int(sys.argv[2])
lanes, spacing, speed, sides = 3, 40.0, 20.0, 256
per_lane = -(-n // lanes)
radius = max(per_lane * spacing / (2 * math.pi), 500.0)
with open(f"{work}/ring.nod.xml", "w") as f:
    f.write("<nodes>\n")
    for k in range(sides):
        a = 2 * math.pi * k / sides
        f.write(f'  <node id="n{k}" x="{radius * math.cos(a):.3f}" y="{radius * math.sin(a):.3f}" type="priority"/>\n')
    f.write("</nodes>\n")
with open(f"{work}/ring.edg.xml", "w") as f:
    f.write("<edges>\n")
    for k in range(sides):
        f.write(f'  <edge id="e{k}" from="n{k}" to="n{(k + 1) % sides}" numLanes="{lanes}" speed="33.0"/>\n')
    f.write("</edges>\n")
edge = 2 * radius * math.sin(math.pi / sides)  # chord length of one side
length = sides * edge
with open(f"{work}/ring.rou.xml", "w") as f:
    f.write('<routes>\n  <vType id="car" length="4.5" minGap="2.5" maxSpeed="20.0" sigma="0" accel="2.6" decel="4.5"/>\n')
    for k in range(sides):
        edges = " ".join(f"e{(k + j) % sides}" for j in range(sides))
        f.write(f'  <route id="r{k}" edges="{edges}"/>\n')
    placed = []
    for lane in range(lanes):
        count = n // lanes + (1 if lane < n % lanes else 0)
        for j in range(count):
            s = length * j / count
            k = min(int(s / edge), sides - 1)
            placed.append((lane, k, min(s - k * edge, edge - 0.1)))
    for i, (lane, k, pos) in enumerate(placed):
        f.write(f'  <vehicle id="v{i}" type="car" route="r{k}" depart="0" departLane="{lane}" '
                f'departPos="{pos:.2f}" departSpeed="{speed}"/>\n')
    f.write("</routes>\n")
EOF
"$VENV/bin/netconvert" --node-files "$work/ring.nod.xml" --edge-files "$work/ring.edg.xml" \
  --output-file "$work/ring.net.xml" --no-turnarounds --no-warnings >/dev/null

median() { sort -g | awk '{a[NR]=$1} END {print (NR % 2) ? a[(NR+1)/2] : (a[NR/2] + a[NR/2+1]) / 2}'; }
: > "$work/sumo.txt"
: > "$work/ours.txt"
: > "$work/ratios.txt"
run_sumo() {
  "$VENV/bin/sumo" -n "$work/ring.net.xml" -r "$work/ring.rou.xml" --step-length 0.02 --end "$SUMO_SECONDS" \
    --no-step-log --no-warnings --duration-log.statistics --time-to-teleport -1 > "$work/sumo.log" 2>&1
  ups=$(awk '/UPS:/ {print $2}' "$work/sumo.log" | tail -1)
  if [ -z "$ups" ]; then
    echo "bench_vs_sumo.sh: SUMO printed no UPS figure; its log:" >&2
    cat "$work/sumo.log" >&2
    exit 1
  fi
}
run_ours() {
  # Into a file, read once the bench has exited (see the top: no reader beside it).
  if ! "$SMLWORLD" bench --vehicles "$VEHICLES" --duration 10 > "$work/ours.json" 2> "$work/ours.log"; then
    echo "bench_vs_sumo.sh: $SMLWORLD bench failed; its log:" >&2
    cat "$work/ours.log" >&2
    exit 1
  fi
  ours=$(python3 -c 'import json, sys; print(json.load(open(sys.argv[1]))["vehicle_steps_per_second"])' "$work/ours.json")
}
for round in $(seq 1 "$ROUNDS"); do
  # Odd rounds start with SUMO, even ones with smlworld (see the top).
  if [ $((round % 2)) -eq 1 ]; then
    run_sumo
    run_ours
    first=SUMO
  else
    run_ours
    run_sumo
    first=smlworld
  fi
  echo "$ups" >> "$work/sumo.txt"
  echo "$ours" >> "$work/ours.txt"
  ratio=$(awk -v a="$ours" -v b="$ups" 'BEGIN { printf "%.2f", a / b }')
  echo "$ratio" >> "$work/ratios.txt"
  echo "round $round ($first first): SUMO $ups vehicle updates/s, smlworld $ours vehicle-steps/s, ratio $ratio" >&2
done
sumo_median=$(median < "$work/sumo.txt")
ours_median=$(median < "$work/ours.txt")
python3 - "$VEHICLES" "$ROUNDS" "$SUMO_SECONDS" "$sumo_median" "$ours_median" "$work/ratios.txt" <<'EOF'
import json, statistics, sys
n, rounds, seconds, sumo, ours = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]), float(sys.argv[5])
round_ratios = [float(line) for line in open(sys.argv[6]) if line.strip()]
print(json.dumps({
    "vehicles": n, "rounds": rounds, "step_s": 0.02, "sumo_version": "eclipse-sumo " + "1.28.0",
    "sumo_sim_seconds": seconds, "sumo_updates_per_second": sumo,
    "smlworld_vehicle_steps_per_second": ours, "ratio": ours / sumo,
    "sumo_real_time_factor": sumo / n * 0.02, "smlworld_real_time_factor": ours / n * 0.02,
    "round_ratios": round_ratios, "round_ratio_median": statistics.median(round_ratios),
    "round_ratio_min": min(round_ratios), "round_ratio_max": max(round_ratios),
}))
EOF
