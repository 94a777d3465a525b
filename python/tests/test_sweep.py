"""Sweeps: local process pool and a local Ray cluster give the same table; the CLI form."""

import subprocess
import sys

import pytest

import smlworld

GRID = {"vehicles.controller.platoon.time_gap": [0.5, 1.0]}


def _check(df):
    assert len(df) == 4
    assert list(df["seed"]) == [1, 2, 1, 2]
    assert list(df["vehicles.controller.platoon.time_gap"]) == [0.5, 0.5, 1.0, 1.0]
    assert (df["metrics.collision_count"] == 0).all()
    # a larger time gap keeps a larger minimum gap behind the braking leader
    gap = "metrics.followers.3.min_gap"  # the truck right behind the leader
    small = df[df["vehicles.controller.platoon.time_gap"] == 0.5][gap]
    large = df[df["vehicles.controller.platoon.time_gap"] == 1.0][gap]
    assert large.min() > small.max()


@pytest.fixture(scope="module")
def local(root):
    return smlworld.sweep(root / "scenarios/platoon_brake.toml", GRID, seeds=[1, 2], backend="local",
                          duration=40.0, max_workers=2)


def test_sweep_local(local):
    _check(local)


def test_sweep_ray_matches_local(root, local):
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        df = smlworld.sweep(root / "scenarios/platoon_brake.toml", GRID, seeds=[1, 2], backend="ray", duration=40.0)
    finally:
        ray.shutdown()
    _check(df)
    cols = [c for c in local.columns if "wall" not in c and "real_time" not in c]
    assert df[cols].equals(local[cols])


def test_sweep_module_cli(root, tmp_path):
    spec = tmp_path / "sweep.toml"
    spec.write_text(
        f'scenario = "{root / "scenarios/platoon_brake.toml"}"\nseeds = [1]\nduration = 40.0\n'
        '[grid]\n"vehicles.controller.platoon.time_gap" = [0.5, 1.0]\n'
    )
    out = tmp_path / "results.csv"
    subprocess.run([sys.executable, "-m", "smlworld.sweep", str(spec), "--backend", "local", "--out", str(out)],
                   check=True)
    import pandas as pd

    df = pd.read_csv(out)
    assert len(df) == 2 and (df["metrics.collision_count"] == 0).all()


def test_sweep_bad_key(root):
    with pytest.raises(ValueError, match="nosuch"):
        smlworld.sweep(root / "scenarios/platoon_brake.toml", {"nosuch.key": [1]}, seeds=[1], backend="local")
