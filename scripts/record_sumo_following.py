#!/usr/bin/env python3
"""Record SUMO's IDM follower behind an imposed leader (issue 54 §2, car following).

    .venv/bin/python scripts/record_sumo_following.py [--out tests/data/sumo_following.csv]
                                                      [--ballistic]

One straight lane (netconvert, 5 km, 30 m/s limit). The leader (id `leader`) starts 40 m ahead
of the follower (id `follower`), both at 15 m/s; the leader's speed is imposed every step with
traci's `setSpeed` under `setSpeedMode(leader, 0)` (no checks): 15 m/s for 20 s, braking at
2 m/s² to 5 m/s, 5 m/s for 20 s, accelerating at 1 m/s² to 15 m/s, 15 m/s to 120 s. The follower
drives SUMO's IDM (`carFollowModel="IDM"`, stepping 0.1 s, one iteration per step) with the
parameters in `PARAMS` (the test uses the same). Step 0.1 s. SUMO integrates positions with its
default Euler update (x += v(t+dt) dt) unless `--ballistic` (`--step-method.ballistic`:
x += (v(t) + v(t+dt)) / 2 dt).

Writes a CSV: t [s], leader_speed, follower_speed [m/s], gap [m] (the follower's bumper-to-bumper
gap: leader's back minus follower's front, SUMO's `getLeader` distance plus `minGap`).
"""

import argparse
import pathlib
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent
PARAMS = dict(accel=1.5, decel=3.0, tau=1.2, minGap=2.0, delta=4.0, length=5.0, maxSpeed=20.0)
LEADER_START = 40.0  # leader's back ahead of the follower's front at t = 0 [m]
SPEED = 15.0
DT = 0.1
DURATION = 120.0


def leader_speed(t):
    """The imposed leader speed [m/s] at time t [s]."""
    if t < 20.0:
        return SPEED
    v = SPEED - 2.0 * (t - 20.0)
    if v > 5.0:
        return v
    t_low = 20.0 + (SPEED - 5.0) / 2.0
    if t < t_low + 20.0:
        return 5.0
    return min(SPEED, 5.0 + 1.0 * (t - t_low - 20.0))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=pathlib.Path, default=ROOT / "tests" / "data" / "sumo_following.csv")
    ap.add_argument("--ballistic", action="store_true", help="SUMO's --step-method.ballistic")
    a = ap.parse_args()
    bin_dir = pathlib.Path(sys.executable).parent
    try:
        import traci  # noqa: PLC0415
    except ImportError:
        sys.exit("record_sumo_following.py: no traci: `.venv/bin/pip install eclipse-sumo traci`")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        (tmp / "n.nod.xml").write_text('<nodes><node id="a" x="0" y="0"/><node id="b" x="5000" y="0"/></nodes>\n')
        (tmp / "e.edg.xml").write_text('<edges><edge id="ab" from="a" to="b" numLanes="1" speed="30"/></edges>\n')
        subprocess.run([str(bin_dir / "netconvert"), "-n", str(tmp / "n.nod.xml"), "-e", str(tmp / "e.edg.xml"),
                        "-o", str(tmp / "line.net.xml"), "--no-warnings"], check=True)
        p = " ".join(f'{k}="{v}"' for k, v in PARAMS.items())
        # The follower's front at 100 m; the leader's front LEADER_START + its length ahead.
        (tmp / "r.rou.xml").write_text(
            "<routes>\n"
            f'  <vType id="idm" carFollowModel="IDM" stepping="{DT}" sigma="0" {p}/>\n'
            '  <route id="r" edges="ab"/>\n'
            f'  <vehicle id="leader" type="idm" route="r" depart="0" departPos="{100 + LEADER_START + PARAMS["length"]}" departSpeed="{SPEED}"/>\n'
            f'  <vehicle id="follower" type="idm" route="r" depart="0" departPos="100" departSpeed="{SPEED}"/>\n'
            "</routes>\n")
        cmd = [str(bin_dir / "sumo"), "-n", str(tmp / "line.net.xml"), "-r", str(tmp / "r.rou.xml"),
               "--step-length", str(DT), "--no-step-log", "true", "--no-warnings", "true"]
        if a.ballistic:
            cmd += ["--step-method.ballistic", "true"]
        traci.start(cmd)
        rows = []
        traci.simulationStep()  # both inserted at t = 0
        traci.vehicle.setSpeedMode("leader", 0)
        steps = int(round(DURATION / DT))
        for k in range(steps + 1):
            t = k * DT
            lead = traci.vehicle.getLanePosition("leader")
            foll = traci.vehicle.getLanePosition("follower")
            gap = lead - PARAMS["length"] - foll
            rows.append((t, traci.vehicle.getSpeed("leader"), traci.vehicle.getSpeed("follower"), gap))
            traci.vehicle.setSpeed("leader", leader_speed(t + DT))
            traci.simulationStep()
        traci.close()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    with open(a.out, "w") as f:
        f.write("t,leader_speed,follower_speed,gap\n")
        for r in rows:
            f.write(f"{r[0]:.1f},{r[1]:.4f},{r[2]:.4f},{r[3]:.4f}\n")
    print(f"{a.out}: {len(rows)} rows", file=sys.stderr)


if __name__ == "__main__":
    main()
