"""The commands answer ``--help``, ``--version`` and one-line refusals before importing the heavy parts: measured
as what is imported (robust on a loaded machine), not as time. A fresh interpreter per case."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HEAVY = ("numpy", "scipy", "cv2", "matplotlib", "yaml", "identify.estimator.refine", "identify.results.pipeline",
         "acquire.commands.cli", "identify.commands.cli", "tqdm")

PROBE = """
import json, sys
from {module} import main
try:
    code = main({argv!r})
except SystemExit as exc:
    code = exc.code
print(json.dumps([code, sorted(sys.modules)]))
"""


@pytest.mark.parametrize(("module", "argv", "code"), [
    ("acquire.commands.launch", ["--help"], 0),
    ("acquire.commands.launch", ["--version"], 0),
    ("acquire.commands.launch", ["--robot", "moc:ur5e"], 2),
    ("acquire.commands.launch", ["--noise", "0.05xx"], 2),
    ("acquire.commands.launch", ["--tracker", "serial"], 2),
    ("acquire.commands.launch", ["export", "--help"], 0),  # before, these two imported everything (1 s of CPU)
    ("acquire.commands.launch", ["backup", "--help"], 0),
    ("acquire.commands.launch", ["verify", "--help"], 0),  # before: the estimator and the drivers (about 1 s of CPU)
    ("acquire.commands.launch", ["calibrate-camera", "--help"], 0),  # before: OpenCV (1.8 s of CPU; issue 39)
    ("acquire.commands.launch", ["print-board", "--views", "3"], 2),
    ("identify.commands.launch", ["compare", "--help"], 0),  # before: scipy, the estimator (1 s of CPU)
    ("identify.commands.launch", ["compensate", "--help"], 0),
    ("identify.commands.launch", ["check", "--help"], 0),
    ("identify.commands.launch", ["check", "r.yaml", "d.csv", "--noise", "0.05xx"], 2),
    ("acquire.commands.launch", ["export", "s.session"], 2),
    ("identify.commands.launch", ["--help"], 0),
    ("identify.commands.launch", ["--version"], 0),
    ("identify.commands.launch", ["missing.csv"], 2),
    ("identify.commands.launch", ["x.csv", "--noise", "-1mm"], 2),
])
def test_help_version_and_refusals_import_nothing_heavy(module, argv, code, tmp_path):
    out = subprocess.run([sys.executable, "-c", PROBE.format(module=module, argv=argv)], capture_output=True,
                         text=True, timeout=60, cwd=tmp_path)
    got, modules = json.loads(out.stdout.splitlines()[-1])
    assert got == code, out.stderr
    assert sorted(m for m in modules if m.split(".")[0] in HEAVY or m in HEAVY) == []
    if code == 2:
        assert len(out.stderr.splitlines()) == 1, out.stderr


def test_the_light_parsers_defaults_are_the_estimators():
    import inspect

    from identify.commands import options
    from identify.estimator.cpa import DEFAULT_PARALLEL_TOL
    from identify.io.csvio import UNITS
    from identify.results.pipeline import identify

    assert options.DEFAULT_PARALLEL_TOL == DEFAULT_PARALLEL_TOL
    # --max-offset's default is the estimator's: None (the robot's size)
    assert options.build_parser().parse_args(["x.csv"]).max_offset is None
    assert inspect.signature(identify).parameters["max_offset"].default is None
    assert sorted(options.UNITS) == sorted(UNITS)
    from identify.applications import compare
    from identify.commands import sub_options

    assert (sub_options.ALPHA, sub_options.POSES) == (compare.ALPHA, compare.POSES)
    assert sorted(sub_options.UNITS) == sorted(UNITS)


def test_a_pipe_closed_by_its_reader_stops_the_command_quietly():
    """``acquire --dry-run | head -1``: no traceback, the exit status a shell gives a command its pipe stopped (the
    dry run prints again after seconds of computing, when the reader is gone)."""
    from pathlib import Path

    argv = [str(Path(sys.executable).with_name("acquire")), "--robot", "ur5e", "--tracker", "mock", "--dry-run"]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, bufsize=0)
    proc.stdout.read(10)
    proc.stdout.close()  # the reader goes away after its first bytes
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 141 and "Traceback" not in err and "Error" not in err, err
