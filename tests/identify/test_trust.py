"""Issue 11: right, or it says it isn't. One test per symptom measured on data the project never tuned on.

Every case is simulated here with what the project's own simulator did not vary (thin and short sweeps,
missing readings, systematic errors a DH table cannot hold, wrong joint types or robot models). The
accuracy tolerance of a single draw is ``ERROR_FACTOR`` times the prediction uncertainty the result itself
reports: an honest estimator lands within about 0.5-1.8 times it; a confident wrong answer lands far above.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from common.errors import InputError
from config.robots import load_robot
from identify.commands.cli import main
from identify.estimator.measurements import Measurements
from identify.io.csvio import format_measurements
from identify.results.pipeline import Identification, identify
from identify.simulators.simulate import observe, random_poses, simulate, sweep_readings
from kinematics.dh import points_from_joints
from kinematics.truth import random_truth

ERROR_FACTOR = 3.0


def _ur5e(seed: int):
    robot = load_robot("ur5e")
    rng = np.random.default_rng(seed)
    truth = random_truth(robot.nominal, robot.home, rng)
    return robot, rng, truth


def _error(ident: Identification, truth, q: np.ndarray) -> float:
    """RMS 3D error (m) of the identification's predictions against the truth at readings ``q``."""
    return float(np.sqrt(np.mean(np.sum((ident.predict(q) - points_from_joints(truth, q)) ** 2, axis=1))))


def _honest(ident: Identification, truth, q: np.ndarray) -> None:
    error, reported = _error(ident, truth, q), ident.prediction_rms(q)
    assert error < ERROR_FACTOR * reported, f"error {error * 1e3:.4f} mm vs reported {reported * 1e3:.4f} mm"


def test_short_arcs_without_free_poses_or_nominal_keep_every_identifiable_parameter():
    """Symptom 1: ±20° sweeps of 12 samples, no nominal. d4 (133 mm on a UR5e) was fixed at 0 and the fit bent
    the rest; now only exact redundancies are conventions, d4 is estimated and no clean sample is rejected."""
    robot, rng, truth = _ur5e(31)
    q_check = random_poses(robot.limits, 200, rng)
    for _ in range(3):
        meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=2e-5, steps=12, arc=np.radians(20))
        ident = identify(meas, noise=2e-5)
        assert "d4" not in {f.name for f in ident.fixed}
        # joints 2-4 are parallel: d2 and d3 are conventions, so d4 carries the sum of the three
        assert abs(ident.model.d[1:4].sum() - truth.d[1:4].sum()) < 4 * ident.std[9 + 4 * 3 + 1]
        assert ident.rejected_rows == []
        _honest(ident, truth, q_check)
        assert ident.verdict.status in ("pass", "warn")


def test_gross_outliers_on_thin_sweeps_are_the_only_rejections():
    """Symptom 2: 5 % of the rows of 12-sample sweeps off by 5-20 mm. About ten clean samples were rejected
    besides the real ones; now exactly the planted ones are."""
    robot, rng, truth = _ur5e(32)
    q_check = random_poses(robot.limits, 200, rng)
    meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=2e-5, steps=12)
    bad = rng.choice(len(meas), size=round(0.05 * len(meas)), replace=False)
    points = meas.points.copy()
    direction = rng.normal(size=(len(bad), 3))
    points[bad] += direction / np.linalg.norm(direction, axis=1)[:, None] * rng.uniform(5e-3, 2e-2, (len(bad), 1))
    ident = identify(replace(meas, points=points))
    assert sorted(ident.rejected_rows) == sorted(int(b) + 1 for b in bad)
    _honest(ident, truth, q_check)


def _positions_only(meas: Measurements) -> Measurements:
    return replace(meas, q=np.full_like(meas.q, np.nan))


def test_positions_only_sweeps_are_identified_as_in_the_paper():
    """Symptom 3: no joint readings anywhere (exit 2 before). The sweeps share the home point; each sample's
    angle is a nuisance parameter. Readings are then relative to home, and turn counter-clockwise in row order."""
    robot, rng, truth = _ur5e(33)
    meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=2e-5, steps=12)
    ident = identify(_positions_only(meas))
    assert np.allclose(ident.lines.home, 0.0)
    q_check = random_poses(robot.limits, 200, rng)
    error = float(np.sqrt(np.mean(np.sum((ident.predict(q_check - robot.home) - points_from_joints(truth, q_check))
                                         ** 2, axis=1))))
    assert error < ERROR_FACTOR * ident.prediction_rms(q_check - robot.home)
    _passes_but_nothing_held_out(ident)


def _passes_but_nothing_held_out(ident) -> None:
    """Every check passes but the holdout one, which warns: no pose was held out to validate the result."""
    assert [c.name for c in ident.verdict.checks if c.status != "pass"] == ["holdout"]
    assert ident.verdict.status == "warn" and "not validated" in ident.verdict_check("holdout").message


def test_a_jogged_sweep_keeps_its_axis_in_the_model():
    """Symptom 4: one sweep jogged by hand (its moved joint unread). Its rows were dropped, its DH row fixed at
    zero and the model off by hundreds of mm; now its rows stay in the fit with their angles estimated."""
    robot, rng, truth = _ur5e(34)
    meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=2e-5, steps=12)
    q = meas.q.copy()
    jogged = meas.joint == 3
    q[jogged, 2] = np.nan
    ident = identify(replace(meas, q=q), robot.nominal)
    assert not {"theta3", "a3", "alpha3"} & {f.name for f in ident.fixed}
    assert ident.refinement.inliers.sum() == len(meas)
    _honest(ident, truth, random_poses(robot.limits, 200, rng))


def _sweeps_that_disagree(truth, robot, rng, noise: float, sizes: tuple[float, float]) -> Measurements:
    """Sweeps each seen by a slightly different robot (base moved by ``sizes`` m between sweeps)."""
    q, sweep, joint = sweep_readings(truth.joint_types, robot.home, robot.limits, 36)
    points = np.empty((len(q), 3))
    for s in np.unique(sweep):
        rows = sweep == s
        base = truth.base.copy()
        shift = rng.normal(size=3)
        base[:3, 3] += shift / np.linalg.norm(shift) * rng.uniform(*sizes)
        points[rows], _ = observe(replace(truth, base=base), q[rows], rng, noise)
    return Measurements(truth.joint_types, q, points, sweep, joint)


def test_near_noise_free_sweeps_that_disagree_are_model_error_not_outliers():
    """Symptom 5: 0.001 mm noise, sweeps inconsistent by 0.01-0.03 mm, TP 5 mm off the last axis. A whole sweep
    was rejected and the condition number was 2e16 with exit 0; now nothing is rejected and the model error
    is named, in numbers, with the uncertainties inflated to cover it."""
    robot, rng, truth = _ur5e(35)
    frames_tool = np.array([0.005, 0.0, 0.03])  # 5 mm off joint 6's axis
    truth = replace(truth, tool=frames_tool)
    meas = _sweeps_that_disagree(truth, robot, rng, 1e-6, (1e-5, 3e-5))
    ident = identify(meas, noise=1e-6)
    assert ident.rejected_rows == []
    check = next(c for c in ident.verdict.checks if c.name == "model_fit")
    assert check.status == "warn" and "model error" in check.message
    assert 5e-6 < ident.adequacy.model_error < 3e-5
    assert ident.refinement.condition < 1e6
    assert ident.adequacy.inflation > 1.0


def test_sparse_wrist_sweeps_unwrap_against_their_readings():
    """Symptom 6: 6 samples over ±360° in 144° steps with 2 held out leaves a gap over 180°; the unwrap in row
    order made it 72° and exit 2 blamed the units. A full turn with 20 of 36 steps missing too."""
    robot, rng, truth = _ur5e(36)
    q, sweep, joint = sweep_readings(truth.joint_types, robot.home, robot.limits, 6)
    wrist = joint == 6
    q[wrist, 5] = robot.home[5] + np.radians(np.array([-360.0, -216.0, -72.0, 72.0, 216.0, 360.0]))
    points, _ = observe(truth, q, rng, 2e-5)
    check = np.zeros(len(q), dtype=bool)
    check[np.flatnonzero(wrist)[[1, 2]]] = True  # hold out -216° and -72°
    meas = Measurements(truth.joint_types, q, points, sweep, joint, check=check, has_role=True)
    ident = identify(meas)
    _honest(ident, truth, random_poses(robot.limits, 200, rng))
    full, _ = simulate(truth, robot.home, robot.limits, rng, noise=2e-5, steps=36)
    lost = np.flatnonzero(full.joint == 2)[5:25]
    ident = identify(full.subset(~np.isin(np.arange(len(full)), lost)))
    _passes_but_nothing_held_out(ident)


def _reading_errors(truth, q: np.ndarray, scale: float, wobble: float) -> np.ndarray:
    """Positions where the arm really is when the controller reports ``q``: a gear-ratio error ``scale`` and a
    once-per-turn error of amplitude ``wobble`` rad on every revolute joint."""
    true_q = q * (1 + scale) + wobble * np.sin(q + 0.7)
    return points_from_joints(truth, true_q)


def test_systematic_residuals_are_model_error_with_numbers_not_outliers():
    """Symptom 7: residuals systematic along each arc, 50x the tracker noise: 8-17 % of the rows were rejected
    and the noise printed was model error. Now nothing is rejected, the model error is named against the
    declared tracker noise, and the reported accuracy covers the achieved one."""
    robot, rng, truth = _ur5e(37)
    q, sweep, joint = sweep_readings(truth.joint_types, robot.home, robot.limits, 36)
    q_free = random_poses(robot.limits, 40, rng)
    q_all = np.vstack([q, q_free])
    points = _reading_errors(truth, q_all, 1e-4, np.radians(0.01)) + rng.normal(0, 2e-5, (len(q_all), 3))
    sweep_all = np.concatenate([sweep, np.arange(100, 140)])
    joint_all = np.concatenate([joint, np.zeros(40, dtype=int)])
    check = np.zeros(len(q_all), dtype=bool)
    check[-20:] = True
    meas = Measurements(truth.joint_types, q_all, points, sweep_all, joint_all, check=check, has_role=True)
    q_check = random_poses(robot.limits, 200, rng)
    real = _reading_errors(truth, q_check, 1e-4, np.radians(0.01))
    ident = identify(meas, robot.nominal, noise=2e-5, extensions=False)  # a DH table alone cannot hold them
    assert ident.rejected_rows == []
    fit = next(c for c in ident.verdict.checks if c.name == "model_fit")
    assert fit.status == "warn" and "tracker noise 0.02 mm" in fit.message
    assert ident.adequacy.noise == pytest.approx(2e-5)
    achieved = float(np.sqrt(np.mean(np.sum((ident.predict(q_check) - real) ** 2, 1))))
    assert achieved < ERROR_FACTOR * ident.prediction_rms(q_check)
    # issue 14: the scale and once-per-turn terms are selected, and the residuals are the tracker's again
    extended = identify(meas, robot.nominal, noise=2e-5)
    names = [name for name, _, _ in extended.extensions]
    assert {f"scale_{j}" for j in range(1, 7)} <= set(names)
    assert extended.verdict_check("model_fit").status == "pass"
    scales = np.array([value for name, value, _ in extended.extensions if name.startswith("scale")])
    np.testing.assert_allclose(scales, 1e-4, atol=5 * max(std for name, _, std in extended.extensions
                                                           if name.startswith("scale")))
    improved = float(np.sqrt(np.mean(np.sum((extended.predict(q_check) - real) ** 2, 1))))
    assert improved < achieved / 5 and improved < ERROR_FACTOR * extended.prediction_rms(q_check)


def test_free_poses_only_calibrate_with_a_nominal_and_say_what_is_missing_without():
    """Symptom 8: free poses only (how most public data sets and commercial tools record) were refused."""
    robot, rng, truth = _ur5e(38)
    q = random_poses(robot.limits, 80, rng)
    points, _ = observe(truth, q, rng, 2e-5)
    check = np.zeros(80, dtype=bool)
    check[-15:] = True
    meas = Measurements(truth.joint_types, q, points, np.arange(80), np.zeros(80, dtype=int), check=check,
                        has_role=True)
    ident = identify(meas, robot.nominal)
    assert ident.start == "nominal"
    _honest(ident, truth, random_poses(robot.limits, 200, rng))
    assert ident.verdict.status == "pass"
    with pytest.raises(InputError, match="nominal model"):
        identify(meas)


def _write_csv(tmp_path: Path, meas: Measurements, name: str = "data.csv") -> Path:
    path = tmp_path / name
    path.write_text(format_measurements(meas, {"joints": meas.joint_types}), encoding="utf-8")
    return path


def _strict_json(text: str) -> dict:
    def refuse(name: str) -> None:
        raise ValueError(f"invalid JSON constant {name}")

    return json.loads(text, parse_constant=refuse)


@pytest.mark.slow
def test_nonsense_fails_its_verdict_with_exit_3_and_valid_json(tmp_path, capsys):
    """Symptom 9: --joints RRRRRP on 6R data gave exit 0 with a 106 mm residual; --robot ur10e on UR5e data
    reported Δa2 = +188 mm without a word; --json printed NaN."""
    robot, rng, truth = _ur5e(39)
    meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=2e-5, steps=12, free_poses=10)
    path = _write_csv(tmp_path, meas)
    assert main([str(path), "--json"]) == 0
    good = _strict_json(capsys.readouterr().out)
    assert good["verdict"]["status"] in ("pass", "warn")

    code = main([str(path), "--joints", "RRRRRP", "--json", "--out", str(tmp_path / "wrong.yaml")])
    out, err = capsys.readouterr()
    assert code == 3 and "FAILS its verdict" in err
    doc = _strict_json(out)
    failed = {c["name"] for c in doc["verdict"]["checks"] if c["status"] == "fail"}
    assert "model_fit" in failed
    assert (tmp_path / "wrong.yaml").exists()  # a failed result is still written, for diagnosis

    code = main([str(path), "--robot", "ur10e", "--json"])
    doc = _strict_json(capsys.readouterr().out)
    assert code == 3
    nominal = next(c for c in doc["verdict"]["checks"] if c["name"] == "nominal")
    assert nominal["status"] == "fail" and nominal["value"] > 0.05
