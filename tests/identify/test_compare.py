"""Change over time (``identify compare``): calibrations of one truth with independent noise show no significant
change, a 0.05° offset change on one joint at 0.02 mm tracker noise is found and named, the false-alarm control,
and the command's inputs (results and sessions), refusals and outputs."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from config.robots import load_robot
from identify.applications.calibrated import CalibratedModel
from identify.applications.compare import _holm, compare
from identify.commands.cli import main
from identify.io.result_io import result_to_dict
from identify.results.pipeline import identify
from identify.simulators.simulate import simulate
from kinematics.truth import random_truth

NOISE = 2e-5
DRAWS = 20
ROBOT = load_robot("ur5e")


def _calibrate(truth, seed) -> CalibratedModel:
    meas, _ = simulate(truth, ROBOT.home, ROBOT.limits, np.random.default_rng(seed), noise=NOISE, free_poses=20,
                       check_poses=10)
    return CalibratedModel.from_identification(identify(meas, ROBOT.nominal))


def draws(count: int) -> list[tuple[bool, list[str], float, float, float]]:
    """Per draw a new truth and three calibrations: A and B of the truth (independent noise), C after joint 3's
    offset moved by 0.05°. Returns per draw: A -> B significant, the names A -> C calls changed, A -> B's
    chi-square per degree of freedom, and the change found in theta3 with its standard uncertainty (deg)."""
    out = []
    for k in range(count):
        truth = random_truth(ROBOT.nominal, ROBOT.home, np.random.default_rng(500 + k))
        a, b = _calibrate(truth, [k, 1]), _calibrate(truth, [k, 2])
        moved = replace(truth, theta=truth.theta + np.radians([0, 0, 0.05, 0, 0, 0]))
        c = _calibrate(moved, [k, 3])
        same = compare([a, b], ["A", "B"], ROBOT.limits, poses=100).pairs[0]
        changed = compare([a, c], ["A", "C"], ROBOT.limits, poses=100).pairs[0]
        theta3 = next((ch for ch in changed.changes if ch.name == "theta3"), None)
        out.append((same.significant, [ch.name for ch in changed.changed], same.statistic / same.dof,
                    np.degrees(theta3.delta) if theta3 else np.nan, np.degrees(theta3.std) if theta3 else np.nan))
    return out


@pytest.mark.slow
def test_no_change_is_not_called_a_change_and_a_005_degree_offset_change_is_found() -> None:
    """A -> B: no significant change in >= 95 % of the draws (the test's false-alarm rate is 1 %); A -> C: a
    significant change naming theta3 (and nothing else) in >= 95 %, of the size simulated within its uncertainty."""
    results = draws(DRAWS)
    quiet = sum(not r[0] for r in results)
    found = [r for r in results if r[1] == ["theta3"]]
    assert quiet >= 0.95 * DRAWS and len(found) >= 0.95 * DRAWS
    for *_, delta, std in found:
        assert abs(delta - 0.05) < 4 * std
    assert 0.6 < np.mean([r[2] for r in results]) < 1.5  # chi-square per degree of freedom: the covariances hold


def test_holm_adjustment() -> None:
    p = np.array([0.01, 0.04, 0.03, 0.005])
    np.testing.assert_allclose(_holm(p), [0.03, 0.06, 0.06, 0.02])


def _result(tmp_path, name: str, truth, seed, robot=ROBOT) -> str:
    meas, _ = simulate(truth, robot.home, robot.limits, np.random.default_rng(seed), noise=NOISE, steps=18,
                       free_poses=12, check_poses=4)
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(result_to_dict(identify(meas, robot.nominal), robot.nominal, robot.name)))
    return str(path)


@pytest.mark.slow
def test_compare_command_results_html_json_and_refusals(tmp_path, capsys) -> None:
    pytest.importorskip("matplotlib")
    truth = random_truth(ROBOT.nominal, ROBOT.home, np.random.default_rng(3))
    moved = replace(truth, theta=truth.theta + np.radians([0, 0.1, 0, 0, 0, 0]))
    files = [_result(tmp_path, "jan", truth, 1), _result(tmp_path, "feb", truth, 2), _result(tmp_path, "mar", moved, 3)]
    html = tmp_path / "trend.html"
    assert main(["compare", *files, "--html", str(html)]) == 3
    out = capsys.readouterr().out
    first = out.splitlines()[0]
    assert first.startswith("verdict: SIGNIFICANT CHANGE feb -> mar (largest: joint 2 offset (theta2) changed by +0.")
    assert out.count("feb -> mar: SIGNIFICANT CHANGE") == 1  # the pair's full verdict, once
    assert "jan -> feb: no significant change" in out
    text = html.read_text()
    assert "SIGNIFICANT CHANGE" in text and "joint 2 offset (theta2)" in text and text.count("<img") == 2
    assert main(["compare", *files, "--json"]) == 3
    doc = json.loads(capsys.readouterr().out)
    assert doc["significant"] is True and not doc["pairs"][0]["significant"] and doc["pairs"][0]["dof"] > 10
    changed = [c for c in doc["pairs"][1]["changes"] if c["significant"]]
    assert [c["parameter"] for c in changed] == ["theta2"]
    assert abs(np.degrees(changed[0]["delta"]) - 0.1) < 4 * np.degrees(changed[0]["std"])
    # refusals: one line, exit 2, nothing written
    scara = load_robot("scara")
    other = _result(tmp_path, "scara", random_truth(scara.nominal, scara.home, np.random.default_rng(1)), 4, scara)
    ur10 = yaml.safe_load(Path(files[0]).read_text())
    ur10["nominal"]["name"] = "ur10e"
    (tmp_path / "ur10e.yaml").write_text(yaml.safe_dump(ur10))
    for args, message in (([files[0], other], "different robots"), ([files[0], str(tmp_path / "ur10e.yaml")],
                                                                      "a ur5e, ur10e a ur10e"),
                          ([files[0]], "at least two"), ([files[0], str(tmp_path / "none.yaml")], "no such"),
                          ([*files[:2], "--html", files[0], "--force"], "is the input")):
        assert main(["compare", *args]) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err


def two_sessions(folder: str) -> tuple[list[int], int, str]:
    """Two acquisitions of the same simulated robot (independent tracker noise), then compare them as sessions:
    the acquisitions' exit codes, compare's, and its output."""
    import contextlib
    import io

    from acquire.commands.cli import main as acquire

    sessions, codes = [], []
    with contextlib.redirect_stdout(io.StringIO()):
        for k in (1, 2):
            path = Path(folder) / f"s{k}.session"
            codes.append(acquire(["--robot", "mock:ur5e", "--tracker", f"mock?seed={k}", "--steps", "12",
                                  "--free-poses", "8", "--session", str(path), "--quiet"]))
            sessions.append(str(path))
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(["compare", *sessions])
    return codes, code, out.getvalue()


@pytest.mark.slow
def test_compare_sessions_of_the_mock_rig(tmp_path) -> None:
    codes, code, out = two_sessions(str(tmp_path))
    assert codes == [0, 0] and code == 0, out
    assert out.startswith("verdict: no significant change over 2 calibrations")
