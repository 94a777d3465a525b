"""SML World from Python in one page: load a scenario, drive one truck with a Python controller,
plot everyone's speed.

    pip install ./python matplotlib
    python examples/python_quickstart.py        # writes out/python_quickstart.png
"""

from pathlib import Path

import numpy as np

import smlworld

ROOT = Path(__file__).resolve().parents[1]

# The platoon of five trucks on the ring; the leader (id -1) brakes to a stop at 30 s.
sim = smlworld.Sim.from_scenario(ROOT / "scenarios/platoon_brake.toml", seed=1, duration=60.0)
print("vehicles:", sim.states()["id"], "control rate:", sim.control_rate, "Hz")

# A Python controller for the leader, called once per control tick for the whole batch: it
# replaces the leader's scripted stop by a gentle speed wave (throttle in newtons; the trucks use
# the acceleration model: acceleration = (throttle - drag * v) / mass).
model = sim.models()
leader = np.array([-1])
mass = model["mass"][model["id"] == -1]
drag = model["drag"][model["id"] == -1]


def wave(obs):
    v = np.hypot(obs["vx"], obs["vy"])
    target = 15.0 + 3.0 * np.sin(2 * np.pi * obs["time"] / 20.0)  # [m/s]
    accel = np.clip(0.8 * (target - v), -3.0, 1.5)  # [m/s^2]
    return {"throttle": mass * accel + drag * v}


sim.add_controller(leader, wave, rate=20.0)
# The leader's scripted stop at 30 s is gone with its command: a vehicle driven from Python tells
# the others (its wifi beacons) the acceleration OUR command gives it, so the CACC followers
# track the wave (each a little less than the truck ahead: string stable) and nobody brakes.

times, speeds = [], []
for _ in range(600):  # 60 s in steps of 0.1 s
    sim.step(0.1)
    st = sim.states()
    times.append(sim.time)
    speeds.append(np.hypot(st["vx"], st["vy"]))
ids = sim.states()["id"]
speeds = np.array(speeds)
metrics = sim.summary()["metrics"]
print("summary metrics:")
for key, value in metrics.items():  # one line each, long lists cut short
    text = repr(value)
    print(f"  {key}: {text if len(text) <= 100 else text[:97] + '...'}")
min_gap = min(f["min_gap"] for f in metrics["followers"])  # [m], bumper to bumper

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

fig, ax = plt.subplots(figsize=(8, 4))
for k, vid in enumerate(ids):
    ax.plot(times, speeds[:, k], label=f"truck {vid}" + (" (leader, Python)" if vid == -1 else ""))
ax.set_xlabel("time [s]")
ax.set_ylabel("speed [m/s]")
ax.set_title(
    f"platoon_brake with a Python leader: {metrics['collision_count']} collisions, "
    f"smallest gap {min_gap:.1f} m"
)
ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0))
out = ROOT / "out" / "python_quickstart.png"
out.parent.mkdir(exist_ok=True)
fig.savefig(out, dpi=100, bbox_inches="tight")
print("wrote", out)
