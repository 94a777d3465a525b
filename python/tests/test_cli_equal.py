"""`smlworld.run` writes the same trajectories as the CLI, byte for byte."""

import subprocess

import smlworld


def test_python_run_equals_cli_csv(root, cli, tmp_path):
    scenario = root / "scenarios/platoon_brake.toml"
    subprocess.run(
        [str(cli), "run", str(scenario), "--out", str(tmp_path / "cli"), "--duration", "35"],
        check=True,
        cwd=root,
    )
    summary = smlworld.run(scenario, out=tmp_path / "py", duration=35.0)
    cli_csv = (tmp_path / "cli" / "trajectories.csv").read_bytes()
    py_csv = (tmp_path / "py" / "trajectories.csv").read_bytes()
    assert len(cli_csv) > 10000
    assert cli_csv == py_csv
    assert summary["seed"] == 5  # the scenario's
    assert summary["sim_seconds"] == 35.0

