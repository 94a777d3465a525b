"""Every Python code block of README.md and docs/*.md runs (issue 60 §4: `sim.change_lane(-3,
"left")` on platoon_brake raised ValueError and `m.route(-590, "left_lane_node")` found no route,
while the README showed them as working). Each block is saved as a script and run with `python
FILE` from the repository root, as a reader would paste it; a block that fails fails here."""

import re
import subprocess
import sys

import pytest

from conftest import ROOT


def _blocks():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    for page in pages:
        text = page.read_text()
        for k, match in enumerate(re.finditer(r"^```python\n(.*?)^```", text, re.S | re.M)):
            line = text[: match.start()].count("\n") + 1
            yield pytest.param(match.group(1), id=f"{page.relative_to(ROOT)}:{line}")


BLOCKS = list(_blocks())


def test_the_docs_have_python_blocks():
    # The collection itself must find the blocks, or every test below would pass vacuously.
    assert len(BLOCKS) >= 5, [b.id for b in BLOCKS]


@pytest.mark.parametrize("code", BLOCKS)
def test_python_block_runs(code, tmp_path):
    script = tmp_path / "block.py"
    script.write_text(code)
    out = subprocess.run([sys.executable, str(script)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, f"{code}\n--- stderr:\n{out.stderr[-3000:]}"
