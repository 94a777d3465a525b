"""Sweeps: local process pool and a local Ray cluster give the same table; the CLI form."""

import os
import signal
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


def test_sweep_ray_without_address_starts_a_local_ray_and_says_how_to_join(root, monkeypatch, capsys):
    # Issue 22 item 12, with a stand-in for Ray (the real one is exercised above).
    import types

    class Ref:  # an object ref: hashable, holding the finished task's value
        def __init__(self, value):
            self.value = value

    calls = []
    fake = types.SimpleNamespace(
        is_initialized=lambda: False,
        init=lambda address=None: calls.append(address),
        remote=lambda f: types.SimpleNamespace(remote=lambda *a: Ref(f(*a))),
        put=lambda x: x,
        get=lambda ref: ref.value,
        wait=lambda refs, num_returns=1, timeout=None: (refs[:num_returns], refs[num_returns:]),
        cancel=lambda ref, force=False: None,
    )
    monkeypatch.setitem(sys.modules, "ray", fake)
    df = smlworld.sweep(root / "scenarios/platoon_brake.toml", {"duration": [1.0]}, seeds=[1], backend="ray")
    assert len(df) == 1 and calls == [None]
    err = capsys.readouterr().err
    assert "local Ray" in err and 'address="auto"' in err and "ray start --head" in err


def test_readme_sweep_example_runs_as_a_script(root, tmp_path):
    # Issue 22 item 12: the sweep block of docs/python.md (once the README's), saved as a file and run with `python FILE`,
    # works (a process pool needs the `if __name__ == "__main__":` guard).
    text = (root / "docs" / "python.md").read_text()
    blocks = [b.split("```", 1)[0] for b in text.split("```python\n")[1:]]
    block = next(b for b in blocks if "smlworld.sweep(" in b)
    script = tmp_path / "sweep_example.py"
    script.write_text(block)
    out = subprocess.run([sys.executable, str(script)], cwd=root, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert "time_gap" in out.stdout


def _interrupted_sweep(root, tmp_path, send, code):
    """Start `python -m smlworld.sweep` on two short runs and one that would take minutes (one
    worker runs them in order), call ``send(proc)`` once two runs are done, and check that it
    exits with ``code`` having written the two finished rows."""
    import pandas as pd

    text = (root / "scenarios/platoon_brake.toml").read_text()
    text = text.replace('"../maps/highway_ring.osm"', f'"{root / "maps/highway_ring.osm"}"')
    text = text.replace("log = 10.0", "log = 0.01")  # the long run must not fill the disk
    assert "log = 0.01" in text
    (tmp_path / "platoon.toml").write_text(text)
    spec = tmp_path / "sweep.toml"
    spec.write_text('scenario = "platoon.toml"\nseeds = [1]\n[grid]\nduration = [1.0, 2.0, 1000000.0]\n')
    out = tmp_path / "results.csv"
    # Its own temporary folder, to see what the sweep leaves there.
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    proc = subprocess.Popen(
        [sys.executable, "-m", "smlworld.sweep", str(spec), "--workers", "1", "--out", str(out)],
        env={**os.environ, "TMPDIR": str(tmp)},
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
        # As from a terminal: a shell's background job starts with SIGINT ignored, and Python keeps
        # an ignored SIGINT ignored (so the suite behaves the same however it was launched).
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        seen = []
        for line in proc.stderr:
            seen.append(line)
            if "2/3 runs done" in line:
                break
        assert any("2/3 runs done" in l for l in seen), "".join(seen)
        send(proc)
        status = proc.wait(timeout=60)
    finally:
        try:  # whatever is left of its group (workers of a sweep that died), so pipes close
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    assert status == code, proc.stderr.read()
    assert "interrupted" in proc.stdout.read()
    df = pd.read_csv(out)
    assert list(df["duration"]) == [1.0, 2.0]
    assert (df["metrics.collision_count"] == 0).all()
    # The stopped run's folder went with the sweep's (CI's /tmp outlives its runs).
    assert not list(tmp.glob("smlworld-sweep-*")), list(tmp.rglob("*"))


def test_ctrl_c_keeps_the_finished_rows(root, tmp_path):
    """Issue 24 item 1: Ctrl-C during `python -m smlworld.sweep` writes the runs that finished
    and exits 130; the run still going is stopped (its process ended), not waited for."""
    # What Ctrl-C in a terminal does: SIGINT to the whole process group.
    _interrupted_sweep(root, tmp_path, lambda p: os.killpg(p.pid, signal.SIGINT), 130)


def test_sigterm_keeps_the_finished_rows(root, tmp_path):
    """Issue 24 item 1: SIGTERM (`kill PID`, a batch system ending the job) to
    `python -m smlworld.sweep` writes the runs that finished and exits 143 (128 + 15)."""
    _interrupted_sweep(root, tmp_path, lambda p: os.kill(p.pid, signal.SIGTERM), 143)


def test_loss_sweep_example_compares_fallback_and_writes_its_figure(root, tmp_path):
    """python/examples/loss_sweep.py (issue 21 item 6), two seeds: every cell is run with and
    without fallback, the fallback runs have no collision up to 50 % loss, and the figure is written."""
    import subprocess
    import sys

    import pandas as pd

    done = subprocess.run(
        [sys.executable, str(root / "python/examples/loss_sweep.py"), "--seeds", "2", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=300, cwd=root,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    df = pd.read_csv(tmp_path / "loss_sweep.csv")
    assert len(df) == 2 * 6 * 2, df  # with/without fallback x 6 losses x 2 seeds
    assert sorted(df["v2v.wifi.loss"].unique()) == [0.0, 0.1, 0.2, 0.3, 0.4, 0.5]
    assert (df[df["fallback"]]["collisions"] == 0).all(), df
    assert (tmp_path / "loss_sweep.png").stat().st_size > 10_000


def test_mean_ci95_is_the_normal_band_of_the_mean():
    # The band the sweep examples draw: mean ± 1.96 standard errors (sample sd, n - 1).
    from smlworld.sweep import mean_ci95

    mean, half = mean_ci95([1.0, 2.0, 3.0])
    assert mean == 2.0
    assert abs(half - 1.96 / 3**0.5) < 1e-12
    assert mean_ci95([4.0]) == (4.0, 0.0)
    with pytest.raises(ValueError):
        mean_ci95([])
