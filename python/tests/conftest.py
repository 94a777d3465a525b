import os
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def root() -> Path:
    return ROOT


@pytest.fixture(scope="session")
def cli(root) -> Path:
    """The `smlworld` binary of this checkout (built if `cargo test --release` did not)."""
    exe = root / "target" / "release" / "smlworld"
    if not exe.exists():
        subprocess.run(["cargo", "build", "--release", "--bin", "smlworld"], cwd=root, check=True)
    return exe


def smlworld_bin() -> Path:
    """The `smlworld` binary: `$SMLWORLD_BIN` (relative to the checkout), else this checkout's
    release build, built when missing (never skipped: a test that needs it must run)."""
    path = Path(os.environ.get("SMLWORLD_BIN", ROOT / "target" / "release" / "smlworld"))
    if not path.is_absolute():
        path = ROOT / path
    if not path.exists() and "SMLWORLD_BIN" not in os.environ:
        subprocess.run(["cargo", "build", "--release", "--bin", "smlworld"], cwd=ROOT, check=True)
    assert path.exists(), f"{path} does not exist (SMLWORLD_BIN)"
    return path
