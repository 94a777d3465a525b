"""Parameter sweeps: one run per grid point and seed, locally (process pool) or on Ray.

    import smlworld
    df = smlworld.sweep("scenarios/platoon_brake.toml",
                        grid={"vehicles.controller.platoon.time_gap": [0.5, 1.0]},
                        seeds=[1, 2, 3], backend="local")

Grid keys are dotted scenario keys (see ``smlworld.Sim.from_scenario``). Each run is one task
that carries the scenario text and its map's bytes, so a Ray cluster needs no shared file
system. The result has one row per run: the parameters, ``seed``, and the summary's entries
flattened with dots (``metrics.min_gap.-2``, ...).

From a file (TOML: ``scenario`` relative to the file, ``seeds``, a ``[grid]`` table, optional
``duration`` [s]):

    python -m smlworld.sweep SWEEP.toml --backend ray --address auto --out results.parquet

Ctrl-C keeps what finished: ``sweep`` raises :class:`SweepInterrupted` whose ``results`` are the
finished rows, and ``python -m smlworld.sweep`` writes them to ``--out`` and exits with 130; on
SIGTERM (``kill PID``, a batch system ending the job) it does the same and exits with 143.
"""

from __future__ import annotations

import argparse
import itertools
import os
import re
import shutil
import signal
import sys
import tempfile
import types
from pathlib import Path
from typing import Dict, List, Optional, Sequence

_MAP_LINE = re.compile(r'^\s*map\s*=\s*"([^"]+)"', re.M)


def _bundle(scenario) -> dict:
    """The scenario text and its map's bytes: everything a task needs on any machine."""
    path = Path(scenario)
    text = path.read_text()
    head = re.split(r"^\s*\[", text, maxsplit=1, flags=re.M)[0]  # top-level keys only
    m = _MAP_LINE.search(head)
    bundle = {"name": path.name, "text": text, "map_name": None, "map": None}
    if m:
        map_path = path.parent / m.group(1)
        bundle["map_name"] = map_path.name
        bundle["map"] = map_path.read_bytes()
    return bundle


def flatten(d, prefix: str = "") -> dict:
    """Nested dicts to one level with dotted keys; lists become ``key.0``, ``key.1``, ..."""
    out = {}
    items = d.items() if isinstance(d, dict) else enumerate(d)
    for k, v in items:
        key = f"{prefix}{k}"
        if isinstance(v, (dict, list, tuple)):
            out.update(flatten(v, key + "."))
        else:
            out[key] = v
    return out


def run_one(bundle: dict, params: dict, seed: int, duration: Optional[float] = None) -> dict:
    """One sweep run in a fresh temporary folder; returns its table row."""
    import smlworld

    # In the sweep's own folder when it runs on this machine (`bundle["scratch"]`, removed by
    # the sweep even when this process is ended mid-run), else in the system's.
    scratch = bundle.get("scratch")
    with tempfile.TemporaryDirectory(prefix="run-" if scratch else "smlworld-sweep-", dir=scratch) as tmp:
        scenario = os.path.join(tmp, bundle["name"])
        with open(scenario, "w") as f:
            f.write(bundle["text"])
        overrides = dict(params)
        if bundle["map"] is not None:
            with open(os.path.join(tmp, bundle["map_name"]), "wb") as f:
                f.write(bundle["map"])
            overrides["map"] = bundle["map_name"]
        if duration is not None:
            overrides["duration"] = float(duration)
        summary = smlworld.run(scenario, out=os.path.join(tmp, "out"), seed=int(seed), **overrides)
    row = dict(params)
    row["seed"] = int(seed)
    summary.pop("seed", None)
    # What a replay needs (map path in this task's temporary folder, classes, sizes) is no result.
    summary.pop("replay", None)
    row.update(flatten(summary))
    return row


def mean_ci95(values) -> tuple:
    """Mean of ``values`` and the half width of the 95 % confidence interval of that mean (normal
    approximation: 1.96 standard errors; 0 for a single value): the band a sweep's figure draws
    over its seeds."""
    v = [float(x) for x in values]
    if not v:
        raise ValueError("mean_ci95 of no values")
    mean = sum(v) / len(v)
    if len(v) < 2:
        return mean, 0.0
    sd = (sum((x - mean) ** 2 for x in v) / (len(v) - 1)) ** 0.5
    return mean, 1.96 * sd / len(v) ** 0.5


def _grid_points(grid: Dict[str, Sequence]) -> List[dict]:
    keys = list(grid)
    for k in keys:
        if isinstance(grid[k], (str, bytes)) or not hasattr(grid[k], "__iter__"):
            raise ValueError(f"grid[{k!r}] must be a list of values, got {grid[k]!r}")
    return [dict(zip(keys, values)) for values in itertools.product(*(list(grid[k]) for k in keys))]


def sweep(
    scenario,
    grid: Dict[str, Sequence],
    seeds: Sequence[int] = (0,),
    backend: str = "local",
    address: Optional[str] = None,
    duration: Optional[float] = None,
    max_workers: Optional[int] = None,
):
    """Run ``scenario`` for every combination of ``grid`` values and every seed; returns a
    ``pandas.DataFrame`` with one row per run (grid order, seeds innermost).

    backend: ``"local"`` (a process pool on this machine) or ``"ray"`` (one Ray task per run;
    ``address`` is passed to ``ray.init``, e.g. ``"auto"``; Ray is started locally when it is
    None and not yet running). ``duration`` [s] overrides the scenario's duration."""
    import pandas as pd

    if backend not in ("local", "ray"):
        raise ValueError(f"backend must be 'local' or 'ray', got {backend!r}")
    bundle = _bundle(scenario)
    jobs = [(p, int(s)) for p in _grid_points(grid) for s in seeds]
    rows: Dict[int, dict] = {}  # job index -> row, filled as runs finish
    try:
        if backend == "local":
            # The runs' folders go into one folder of the sweep's, removed below: a run whose
            # process is ended (Ctrl-C, SIGTERM) cannot remove its own.
            bundle["scratch"] = tempfile.mkdtemp(prefix="smlworld-sweep-")
            try:
                _sweep_local(bundle, jobs, duration, max_workers, rows)
            finally:
                shutil.rmtree(bundle["scratch"], ignore_errors=True)
        else:
            _sweep_ray(bundle, jobs, duration, address, rows)
    except KeyboardInterrupt:
        done = pd.DataFrame([rows[i] for i in sorted(rows)])
        done.attrs["interrupted"] = True
        print(f"smlworld.sweep: interrupted; {len(rows)} of {len(jobs)} runs finished", file=sys.stderr)
        raise SweepInterrupted(done, len(jobs)) from None
    return pd.DataFrame([rows[i] for i in range(len(jobs))])


class SweepInterrupted(KeyboardInterrupt):
    """Ctrl-C (or SIGINT) stopped a sweep: ``results`` holds the rows of the runs that finished
    (a ``pandas.DataFrame``, in grid order, ``results.attrs["interrupted"] = True``); runs still
    going were stopped and left no row."""

    def __init__(self, results, total: int):
        super().__init__(f"sweep interrupted: {len(results)} of {total} runs finished")
        self.results = results
        self.total = total


def _progress(done: int, total: int) -> None:
    print(f"smlworld.sweep: {done}/{total} runs done", file=sys.stderr, flush=True)


def _sweep_local(bundle, jobs, duration, max_workers, rows: Dict[int, dict]) -> None:
    """A process pool; on Ctrl-C the runs not finished are cancelled and their processes ended."""
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    import multiprocessing as mp

    pool = ProcessPoolExecutor(max_workers=max_workers, mp_context=mp.get_context("spawn"))
    try:
        index = {pool.submit(run_one, bundle, p, s, duration): i for i, (p, s) in enumerate(jobs)}
        pending = set(index)
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in finished:
                rows[index[f]] = f.result()
            _progress(len(rows), len(jobs))
    except BaseException:
        processes = list((getattr(pool, "_processes", None) or {}).values())
        for process in processes:
            process.terminate()
        pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:  # ended before their folders are removed
            process.join(timeout=10)
        raise
    pool.shutdown()


def _sweep_ray(bundle, jobs, duration, address, rows: Dict[int, dict]) -> None:
    """One Ray task per run; on Ctrl-C the finished ones are kept and the others cancelled."""
    import ray

    if not ray.is_initialized():
        if address is None:
            print(
                "smlworld.sweep: no address given, starting a local Ray on this machine; to use a "
                "cluster, start it (`ray start --head` on one machine, `ray start --address HEAD:6379` "
                "on the others) and pass address=\"auto\" (on a cluster machine) or "
                "address=\"ray://HEAD:10001\"",
                file=sys.stderr,
            )
        ray.init(address=address)
    task = ray.remote(run_one)
    ref = ray.put(bundle)
    index = {task.remote(ref, p, s, duration): i for i, (p, s) in enumerate(jobs)}
    pending = list(index)
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for r in ready:
                rows[index[r]] = ray.get(r)
            _progress(len(rows), len(jobs))
    except KeyboardInterrupt:
        ready, pending = ray.wait(pending, num_returns=len(pending), timeout=0)
        for r in ready:
            rows[index[r]] = ray.get(r)
        for r in pending:
            ray.cancel(r, force=True)
        raise


def _load_toml(path: Path) -> dict:
    try:
        import tomllib
    except ModuleNotFoundError:  # Python < 3.11
        import tomli as tomllib
    with open(path, "rb") as f:
        return tomllib.load(f)


_terminated = 0  # SIGTERM once received by `python -m smlworld.sweep`, else 0


def _sigterm_as_interrupt(signum, frame):
    """SIGTERM ends a command-line sweep the way Ctrl-C does (the finished rows are written),
    with exit status 128 + 15."""
    global _terminated
    _terminated = signum
    raise KeyboardInterrupt


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m smlworld.sweep", description="Run a parameter sweep from a TOML file.")
    ap.add_argument("file", help="sweep file: scenario = PATH, seeds = [...], [grid] KEY = [values], duration = S")
    ap.add_argument("--backend", choices=["local", "ray"], default="local")
    ap.add_argument("--address", default=None, help="Ray cluster address (e.g. auto)")
    ap.add_argument("--out", default="results.parquet", help="output table (.parquet or .csv)")
    ap.add_argument("--workers", type=int, default=None, help="local processes (default: one per core)")
    args = ap.parse_args(argv)
    path = Path(args.file)
    spec = _load_toml(path)
    allowed = {"scenario", "seeds", "grid", "duration"}
    unknown = set(spec) - allowed
    if unknown:
        raise SystemExit(f"{path}: unknown keys {sorted(unknown)}; allowed: {sorted(allowed)}")
    if "scenario" not in spec or "grid" not in spec:
        raise SystemExit(f"{path}: needs `scenario` and a `[grid]` table")
    code = 0
    previous = signal.signal(signal.SIGTERM, _sigterm_as_interrupt)
    try:
        df = sweep(
            path.parent / spec["scenario"],
            spec["grid"],
            spec.get("seeds", [0]),
            backend=args.backend,
            address=args.address,
            duration=spec.get("duration"),
            max_workers=args.workers,
        )
    except SweepInterrupted as e:
        df, code = e.results, 128 + (_terminated or signal.SIGINT)
    finally:
        signal.signal(signal.SIGTERM, previous)
    if code and len(df) == 0:
        print(f"no run finished; {args.out} left as it was", file=sys.stderr)
        return code
    _write_table(df, args.out)
    print(f"{len(df)} runs -> {args.out}" + (" (interrupted: the finished runs only)" if code else ""))
    return code


def _write_table(df, out: str) -> None:
    """Write ``df`` to ``out`` (.csv or .parquet) beside it first, then rename it into place: an
    earlier table there is replaced only by a complete one."""
    target = Path(out)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        if out.endswith(".csv"):
            df.to_csv(tmp, index=False)
        else:
            df.to_parquet(tmp, index=False)
        os.replace(tmp, target)
    finally:
        if tmp.exists():
            tmp.unlink()


class _CallableModule(types.ModuleType):
    """``smlworld.sweep`` is both this module and the function: calling it runs :func:`sweep`."""

    def __call__(self, *args, **kwargs):
        return sweep(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule

if __name__ == "__main__":
    sys.exit(main())
