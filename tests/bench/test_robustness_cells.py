"""The robustness cases the real-data sets taught (``bench.robustness`` cases ``grid2`` and ``elastic``), drawn as
the benchmark draws them and identified as it identifies them."""

from __future__ import annotations

import numpy as np
import pytest

from bench import robustness
from bench.robustness_cells import GRID_ROBOT, gravity_sag
from identify.results import pipeline
from kinematics.dh import points_from_joints


def identified(robot: str, case: str, k: int) -> tuple[pipeline.Identification, float, float, float]:
    """Draw ``k`` of ``case``: the identification, its held-out 3D RMS against the truth, the RMS it states for
    those poses and the bound (m)."""
    scen, q_check = robustness.draw(robot, case, k)
    spec = next(c for c in robustness.CASES if c.key == case)
    nominal = robustness.case_nominal(spec, robustness.load_robot(robustness.case_robot(spec, robot)))
    ident = pipeline.identify(scen.meas, nominal=nominal, noise=scen.noise)
    readings = scen.predictor_readings(q_check)
    err = robustness._rms(ident.predict(readings) - scen.truth_points(q_check))
    fit = ~scen.meas.check
    bound = robustness.lines_bound(scen.truth, scen.true_q[fit], scen.unknown[fit], scen.meas.joint[fit],
                                   scen.true_values(q_check), scen.noise)
    return ident, err, float(ident.prediction_rms(readings)), bound


@pytest.mark.parametrize("k", [2, 3])  # draws whose nominal check failed (~320 mm) before the fix
def test_the_grid_with_a_toolless_nominal_passes_its_nominal_check_and_predicts_to_the_bound(k: int) -> None:
    ident, err, _, bound = identified("iiwa7", "grid2", k)
    nominal = next(c for c in ident.verdict.checks if c.name == "nominal")
    # the true arm is the nominal perturbed by about 0.5 mm and 0.03 deg: the placed nominal misses by < 1 mm
    assert nominal.status == "pass" and nominal.value < 1e-3
    assert ident.verdict.status != "fail"
    assert err < 2.0 * bound  # the benchmark's ratio target is 1.10 on average; 2x for a single draw


def test_the_elastic_arm_sags_as_the_boby2021_j2_sweep_does() -> None:
    """The simulated sag is of the real set's size: from ~0.1 to ~1 mm at the TP along the J2 sweep."""
    robot = robustness.load_robot("ur5e")
    spec = next(c for c in robustness.CASES if c.key == "elastic")
    sag = gravity_sag(robot, robot.nominal, spec.compliance)
    scen, _ = robustness.draw("ur5e", "elastic", 0)
    q = scen.meas.q[scen.meas.joint == 2]
    moved = np.linalg.norm(points_from_joints(robot.nominal, sag.true_from_reading("RRRRRR", q))
                           - points_from_joints(robot.nominal, q), axis=1)
    assert 0.2e-3 < moved.min() < 0.5e-3 and 0.7e-3 < moved.max() < 1.2e-3
    turned = sag.true_from_reading("RRRRRR", q) - q
    assert np.all(turned[:, [0, 3, 4, 5]] == 0) and np.all(np.abs(turned[:, 1:3]) > 0)


def test_joint_errors_from_sweeps_alone_are_not_vouched_for_away_from_the_sweeps() -> None:
    """Draw 4 passed while predicting 0.84 mm where it stated 0.19 mm: its eccentricity terms, fitted on single-joint
    sweeps, stood in for the gravity sag that depends on the other joints. Without free or held-out poses nothing
    tests that: the holdout check says so, and the joint errors are not recommended."""
    ident, *_ = identified("ur5e", "elastic", 4)
    assert ident.extended is not None  # the defect's situation is still drawn: joint errors selected on the sweeps
    check = ident.verdict_check("holdout")
    assert check.status == "warn" and "not validated" in check.message and "joint errors" in check.message
    assert ident.use == "plain" and ident.verdict.status == "warn"  # nothing held out: neither recommended nor a pass


def test_an_elastic_arm_keeps_its_sweeps_and_does_not_pass_beyond_its_stated_accuracy() -> None:
    """Draw 6 rejected 10 of the 12 J2/J3 sweep samples as gross outliers and failed at 827 mm: a sweep the model
    misses as a whole is now kept (identify/estimator/outliers.py, test 5), and the joint errors fitted on sweeps alone
    are not vouched for (the holdout check warns)."""
    for k in (4, 6):
        ident, err, stated, _ = identified("ur5e", "elastic", k)
        assert len(ident.rejected_rows) == 0, k
        assert ident.verdict.status != "pass" or err < 1.5 * stated, (k, err, stated)
        assert err < 2e-3, (k, err)  # the sag is 0.3-0.9 mm at the TP: the fit keeps the arm, it does not lose it


def test_a_wrong_nominal_zero_does_not_win_over_a_good_geometric_start() -> None:
    _, err, _, bound = identified("ur5e", "zero90", 3)
    assert err < 10 * bound  # the geometric step's fit predicts to ~0.2 mm; the nominal's stalled one to 225 mm


def test_the_grid_case_runs_on_its_own_robot_once() -> None:
    grid = next(c for c in robustness.CASES if c.key == "grid2")
    assert [r for r in robustness.ROBOTS if robustness.applicable(grid, r)] == ["iiwa7"]
    assert robustness.case_robot(grid, "iiwa7") == GRID_ROBOT
    zero = next(c for c in robustness.CASES if c.key == "zero90")
    assert [r for r in robustness.ROBOTS if robustness.applicable(zero, r)] == ["ur5e"]
    robot = robustness.load_robot(robustness.case_robot(zero, "ur5e"))
    assert robustness.case_nominal(zero, robot).theta[1] == pytest.approx(robot.nominal.theta[1] - np.pi / 2)
