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
