"""``make demo`` fits an 80-column terminal: the commands' own output is checked in tests/acquire/test_progress.py
(a real pseudo-terminal); here the recipe lines make echoes, and the reader of a ``script`` recording that
scripts/demo_width.py uses to check the whole demo (``python scripts/demo_width.py``: docs/benchmarks.md)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

from demo_width import shown_lines  # noqa: E402


@pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
def test_the_demo_recipe_lines_make_echoes_fit_80_columns():
    """Before, make echoed two recipe lines of 94 and 101 characters."""
    done = subprocess.run(["make", "-n", "-o", ".venv/.installed", "demo"], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    lines = [line.expandtabs() for line in done.stdout.splitlines()]
    assert any("acquire verify" in line for line in lines)
    assert max(map(len, lines)) <= 80, lines


def test_a_recording_is_read_as_the_terminal_shows_it():
    raw = "step 1/9 \x1b[32m10%\x1b[0m\rstep 2/9 20%\r\nresult written\r\n"
    assert shown_lines(raw) == ["step 2/9 20%", "result written", ""]
