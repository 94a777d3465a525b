"""scripts/compare_sumo.py (issue 54 §2): SUMO and SML World on the same net and routes. Its
pieces (the IDM copy of a route file, the peak count) on small inputs, and a real comparison on
sumo-rl's 4x4-Lucas grid, whose mean travel times must agree within 15 %."""

import importlib.util
import json
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "scripts" / "compare_sumo.py"


@pytest.fixture(scope="module")
def compare():
    spec = importlib.util.spec_from_file_location("compare_sumo", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def nets() -> Path:
    if "SUMO_RL_NETS" in os.environ:
        return Path(os.environ["SUMO_RL_NETS"])
    spec = importlib.util.find_spec("sumo_rl")
    assert spec is not None, "sumo-rl is not installed (python/requirements-test.txt) and SUMO_RL_NETS is unset"
    return Path(spec.submodule_search_locations[0]) / "nets"


def test_peak_counts_vehicles_in_the_network_at_once(compare):
    # 0-10 and 10-20 never overlap (an arrival at 10 comes before a departure at 10); the one
    # still driving at the end (None) counts until then.
    assert compare.peak([(0.0, 10.0), (10.0, 20.0)], end=30.0) == 1
    assert compare.peak([(0.0, 10.0), (5.0, None), (8.0, 9.0)], end=30.0) == 3
    assert compare.peak([], end=30.0) == 0


def test_every_vtype_of_the_copy_drives_the_idm(compare, tmp_path):
    src = tmp_path / "r.rou.xml"
    src.write_text(
        '<routes><vType id="car" accel="1.0" carFollowModel="Krauss"/>'
        '<vehicle id="a" type="car" depart="0"><route edges="e1"/></vehicle>'
        '<flow id="f" begin="0" end="10" number="2"><route edges="e1"/></flow></routes>'
    )
    dst = tmp_path / "idm.rou.xml"
    compare.idm_routes(src, dst)
    types = {t.get("id"): t.attrib for t in ET.parse(dst).getroot().iter("vType")}
    assert types["car"]["carFollowModel"] == "IDM" and types["car"]["accel"] == "1.0"
    # The flow names no type: SUMO's default type is redefined on the IDM.
    assert types["DEFAULT_VEHTYPE"]["carFollowModel"] == "IDM"


def test_bad_input_is_refused_with_the_file_named(tmp_path):
    missing = tmp_path / "none.net.xml"
    done = subprocess.run([sys.executable, str(SCRIPT), str(missing), str(missing)], capture_output=True, text=True)
    assert done.returncode != 0 and "none.net.xml: no such file" in done.stderr


def test_4x4_lucas_travel_times_agree_within_15_percent(nets):
    d = nets / "4x4-Lucas"
    done = subprocess.run(
        [sys.executable, str(SCRIPT), str(d / "4x4.net.xml"), str(d / "4x4c1c2c1c2.rou.xml"), "--end", "600"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    sumo, ours, ratio = (json.loads(line) for line in done.stdout.splitlines())
    assert (sumo["side"], ours["side"]) == ("sumo", "smlworld")
    for side in (sumo, ours):
        assert side["step_s"] == 0.1
        assert 0 < side["arrived"] <= side["inserted"], side
        assert side["peak_vehicles"] > 0 and side["wall_s"] > 0
    # The same demand goes in on both sides (within 5 %), and takes as long to cross the grid.
    assert abs(ours["inserted"] - sumo["inserted"]) <= 0.05 * sumo["inserted"], (sumo, ours)
    assert 0.85 <= ratio["ratio_travel_time"] <= 1.15, (sumo, ours, ratio)
    assert ratio["ratio_travel_time"] == pytest.approx(ours["mean_travel_time_s"] / sumo["mean_travel_time_s"], abs=1e-3)
