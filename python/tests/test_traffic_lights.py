"""Traffic lights from Python: `Sim.traffic_lights()` reads every signalised junction's state and
`Sim.set_phase(junction, state)` holds one (issue 53, item 4), with errors as ValueError."""

import subprocess

import numpy as np
import pytest

import smlworld


@pytest.fixture(scope="module")
def lights_scenario(cli, tmp_path_factory):
    """A generated four-arm junction with traffic lights and random traffic for 60 s."""
    d = tmp_path_factory.mktemp("lights")
    subprocess.run(
        [str(cli), "map", "generate", "intersection4", "--traffic-lights", "--out", str(d / "x.osm")],
        check=True,
        capture_output=True,
    )
    (d / "lights.toml").write_text(
        'seed = 7\nduration = 60.0\nmap = "x.osm"\n\n'
        "[[traffic]]\n"
        'route = "random"\nrate = 900.0\nspeed = [10.0, 12.0]\nclasses = { car = 1.0 }\nlane_change = false\n'
    )
    return d / "lights.toml"


def test_states_are_read_set_held_and_read_back(lights_scenario):
    sim = smlworld.Sim.from_scenario(lights_scenario)
    lights = sim.traffic_lights()
    assert list(lights) == [1], lights
    first = lights[1]
    n = len(first["lanelets"])
    assert n == 12 and len(first["state"]) == n
    assert set(first["state"]) <= set("Ggyr") and "G" in first["state"] and "r" in first["state"]
    assert first["phase"] == 0
    # The default program: 27 s green, 3 s yellow, 2 s all red per axis.
    sim.step(28.0)
    assert sim.traffic_lights()[1]["phase"] == 1
    assert "y" in sim.traffic_lights()[1]["state"]

    # Flip the axes: what was red goes green and the rest red, held past the program's end.
    flipped = "".join("G" if c == "r" else "r" for c in first["state"])
    sim.set_phase(1, flipped)
    assert sim.traffic_lights()[1] == {"state": flipped, "phase": None, "lanelets": first["lanelets"]}
    sim.step(40.0)
    assert sim.traffic_lights()[1]["state"] == flipped, "held until set again"
    sim.set_phase(np.int64(1), "r" * n)
    sim.step(0.5)
    assert sim.traffic_lights()[1]["state"] == "r" * n
    # Vehicles keep driving: nobody collides under manual signals.
    assert sim.summary()["metrics"]["collision_count"] == 0


def test_bad_junctions_and_states_raise_value_errors(lights_scenario):
    sim = smlworld.Sim.from_scenario(lights_scenario)
    n = len(sim.traffic_lights()[1]["lanelets"])
    with pytest.raises(ValueError, match=r"junction 9 has no traffic light; the signalised junctions are 1"):
        sim.set_phase(9, "r" * n)
    with pytest.raises(ValueError, match=r"junction 0 is not a junction id"):
        sim.set_phase(0, "r" * n)
    with pytest.raises(ValueError, match=r"junction -3 is not a junction id"):
        sim.set_phase(-3, "r" * n)
    with pytest.raises(ValueError, match=rf"junction 1: `GGr` has 3 characters; the junction has {n} links"):
        sim.set_phase(1, "GGr")
    with pytest.raises(ValueError, match=r"has `x`; use G"):
        sim.set_phase(1, "x" * n)
    with pytest.raises(ValueError, match=r"state must be a str"):
        sim.set_phase(1, None)
    with pytest.raises(ValueError, match=r"junction must be an integer"):
        sim.set_phase("1", "r" * n)
    # Nothing changed by the refused calls.
    assert sim.traffic_lights()[1]["phase"] == 0


def test_a_scenario_without_lights_has_none(root):
    sim = smlworld.Sim.from_scenario(root / "scenarios/platoon_brake.toml", seed=3)
    assert sim.traffic_lights() == {}
    with pytest.raises(ValueError, match=r"has no traffic lights"):
        sim.set_phase(1, "G")


def test_frames_draw_stop_lines_in_the_signal_colours(lights_scenario):
    sim = smlworld.Sim.from_scenario(lights_scenario)
    n = len(sim.traffic_lights()[1]["lanelets"])

    def count(frame, rgb):
        return int(np.all(frame[:, :, :3] == np.array(rgb, dtype=np.uint8), axis=2).sum())

    red, green = (230, 30, 30), (40, 210, 60)  # smlworld::render::SIGNAL_RED, SIGNAL_GREEN
    sim.set_phase(1, "r" * n)
    f = sim.frame(640, 640)
    assert count(f, red) > 20 and count(f, green) == 0
    sim.set_phase(1, "G" * n)
    f = sim.frame(640, 640)
    assert count(f, green) > 20 and count(f, red) == 0
