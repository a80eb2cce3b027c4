"""The Python API (identify/api.py): the README's worked example runs and prints what the README shows, and the
API's objects are the commands' (a saved result reloads to the same predictions; comparisons refuse other robots).
"""

from __future__ import annotations

import ast
import contextlib
import io
import os
import re
from pathlib import Path

import numpy as np
import pytest

from common.errors import InputError
from identify import api
from identify.applications.compensate import parse_ur_pose

ROOT = Path(__file__).resolve().parents[2]


def _readme_example() -> tuple[str, list[str]]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    start = text.index("<!-- api-example")
    code = re.search(r"```python\n(.*?)```", text[start:], re.S).group(1)
    shown = re.search(r"```python\n.*?```\n```\n(.*?)```", text[start:], re.S).group(1).splitlines()
    return code, shown


@pytest.mark.slow
def test_the_readme_example_runs_and_prints_what_the_readme_shows() -> None:
    code, shown = _readme_example()
    out = io.StringIO()
    cwd = os.getcwd()
    try:
        os.chdir(ROOT)
        with contextlib.redirect_stdout(out):
            exec(compile(code, "README.md", "exec"), {})
    finally:
        os.chdir(cwd)
    got = out.getvalue().splitlines()
    assert got[:2] == shown[:2] == ["pass", "['ok' 'ok']"]
    errors = np.array(got[2].strip("[]").split(), dtype=float)
    assert np.all(errors < 1e-9)
    expected = np.array(got[3].strip("[]").split(), dtype=float)
    np.testing.assert_allclose(expected, np.array(shown[3].strip("[]").split(), dtype=float), rtol=0.2)
    poses = [parse_ur_pose(p) for p in ast.literal_eval(got[4])]
    np.testing.assert_allclose(poses, [parse_ur_pose(p) for p in ast.literal_eval(shown[4])], atol=1e-6)


def test_results_round_trip_and_compare(tmp_path) -> None:
    meas = api.load_measurements(ROOT / "identify/data/sample_ur5e.csv")
    result = api.calibrate(meas, robot="ur5e")
    path = tmp_path / "r.yaml"
    result.save(path)
    loaded = api.load_result(path)
    q = np.radians([[10, -80, 70, -90, -90, 0]])
    np.testing.assert_allclose(loaded.predict(q), result.predict(q), atol=1e-12)
    np.testing.assert_allclose(loaded.expected_errors(q), result.expected_errors(q), rtol=1e-9)
    assert loaded.verdict == result.verdict == "pass" and loaded.robot.name == "ur5e"
    with pytest.raises(InputError, match="already exists"):
        result.save(path)
    same = api.compare([result, loaded], ["a", "b"], poses=50)
    assert not same.significant and same.pairs[0].statistic < 1e-6  # one calibration against itself
    scara = api.calibrate(api.load_measurements(ROOT / "identify/data/sample_ur5e.csv"), robot=None)
    other = api.Result({**scara.document, "nominal": {"name": "ur10e"}}, scara.model)
    with pytest.raises(InputError, match="different robots"):
        api.compare([result, other])
    with pytest.raises(InputError, match="frame must be"):
        api.compensate(result, [[0.1, 0.2, 0.3]], frame="world")
