"""Bad input raises Python exceptions carrying the Rust message; nothing panics."""

import numpy as np
import pytest

import smlworld

PLATOON = "scenarios/platoon_brake.toml"


def test_missing_scenario(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.toml"):
        smlworld.Sim.from_scenario(tmp_path / "nope.toml")


def test_missing_map(tmp_path):
    sc = tmp_path / "s.toml"
    sc.write_text('seed = 1\nduration = 1.0\nmap = "missing_map.osm"\n')
    with pytest.raises(FileNotFoundError, match="missing_map.osm"):
        smlworld.Sim.from_scenario(sc)
    with pytest.raises(FileNotFoundError, match="missing_map.osm"):
        smlworld.load_map(tmp_path / "missing_map.osm")


def test_bad_scenario_names_line_and_key(tmp_path):
    sc = tmp_path / "s.toml"
    sc.write_text("seed = 1\nduration = 1.0\nbogus = 3\n")
    with pytest.raises(ValueError, match="bogus"):
        smlworld.Sim.from_scenario(sc)


def test_bad_override(root):
    with pytest.raises(ValueError, match="nosuch"):
        smlworld.Sim.from_scenario(root / PLATOON, **{"nosuch.table.key": 1.0})


def test_unknown_vehicle_id(root):
    sim = smlworld.Sim.from_scenario(root / PLATOON)
    with pytest.raises(ValueError, match="unknown vehicle id 42"):
        sim.readings(42)
    with pytest.raises(ValueError, match="unknown vehicle id 42"):
        sim.set_commands([42], throttle=[0.0])
    with pytest.raises(ValueError, match="unknown vehicle id 42"):
        sim.send(42, "wifi", b"x")
    with pytest.raises(ValueError, match="unknown vehicle id 42"):
        sim.add_controller([42], lambda o: {})


def test_wrong_array_length(root):
    sim = smlworld.Sim.from_scenario(root / PLATOON)
    with pytest.raises(ValueError, match="throttle has 1 values for 2 ids"):
        sim.set_commands([-1, -2], throttle=[0.0])


def test_nan_commands_change_nothing(root):
    sim = smlworld.Sim.from_scenario(root / PLATOON)
    with pytest.raises(ValueError, match=r"steering\[1\] \(vehicle -2\) is NaN"):
        sim.set_commands([-1, -2], throttle=[1.0, 2.0], steering=[0.0, float("nan")])
    with pytest.raises(ValueError, match="dt must be"):
        sim.step(float("nan"))


def test_unknown_channel(root):
    sim = smlworld.Sim.from_scenario(root / PLATOON)
    with pytest.raises(ValueError, match="unknown channel `radio`"):
        sim.inbox(-1, "radio")
