"""The tall-problem solver (identify/estimator/tall_lsq.py) and the blocked linear algebra of large sessions: the same
optimum as MINPACK to far below the estimate's uncertainty, on a toy problem and through the whole pipeline."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import least_squares

import identify.estimator.linalg as linalg
import identify.estimator.tall_lsq as tall_lsq
from config.robots import load_robot
from identify.estimator.dh_vector import vector_from_model
from identify.estimator.extensions import score_statistics
from identify.estimator.measurements import Measurements
from identify.estimator.tall_lsq import solve_tall
from identify.results.pipeline import identify
from identify.simulators.simulate import random_poses
from identify.simulators.simulate_stream import StreamSettings, joined, streamed_sweeps
from kinematics.dh import points_from_joints
from kinematics.truth import perturbed_model, random_base

NOISE = 2e-5  # m per axis


def _sphere_problem(seed: int, noise: float = 1e-3):
    """Distances of noisy points on a sphere cap (centre (1, 2, 3) m, radius 2 m) to a sphere (centre, radius)."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(400, 3))
    u[:, 2] = np.abs(u[:, 2])  # a cap: the centre and radius are correlated, as a real fit's parameters are
    points = np.array([1.0, 2.0, 3.0]) + 2.0 * u / np.linalg.norm(u, axis=1)[:, None]
    points += rng.normal(0, noise, points.shape)

    def fun(x):
        return np.linalg.norm(points - x[:3], axis=1) - x[3]

    def jac(x):
        d = points - x[:3]
        return np.column_stack([-d / np.linalg.norm(d, axis=1)[:, None], -np.ones(len(d))])
    return fun, jac


@pytest.mark.parametrize("start", [[1.1, 1.9, 3.2, 1.5], [0.0, 0.0, 0.0, 0.5]])
def test_the_same_optimum_as_minpack(start):
    fun, jac = _sphere_problem(1)
    reference = least_squares(fun, start, jac=jac, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    found = solve_tall(fun, jac, np.array(start), stop_sigmas=1e-3)
    j, r = jac(reference), fun(reference)
    sigma = np.sqrt(np.diag(np.linalg.inv(j.T @ j)) * (r @ r) / (len(r) - 4))
    # the rule stops within 0.001 sigma of the optimum (and far closer: the last step is taken, not just measured)
    assert np.all(np.abs(found - reference) < 1e-3 * sigma), (found - reference) / sigma


def test_a_redundant_parameter_gets_a_minimum_norm_step():
    fun, jac = _sphere_problem(2)

    def fun5(x):  # the radius split into two parameters that only their sum determines
        return fun(np.r_[x[:3], x[3] + x[4]])

    def jac5(x):
        j = jac(np.r_[x[:3], x[3] + x[4]])
        return np.column_stack([j, j[:, 3]])
    found = solve_tall(fun5, jac5, np.array([1.1, 1.9, 3.2, 1.0, 0.5]), stop_sigmas=1e-3)
    reference = least_squares(fun, [1.1, 1.9, 3.2, 1.5], jac=jac, method="lm", xtol=1e-15, ftol=1e-15).x
    assert np.all(np.isfinite(found))
    assert found[3] + found[4] == pytest.approx(reference[3], abs=1e-9)
    assert found[3] - found[4] == pytest.approx(0.5, abs=1e-9)  # the undetermined direction is not moved


def test_blocked_r_factor_has_the_geometry_of_the_columns(monkeypatch):
    monkeypatch.setattr(linalg, "QR_ROWS", 64)
    rng = np.random.default_rng(3)
    a = rng.normal(size=(1000, 8)) * np.array([1, 10, 100, 1e3, 1, 1, 1, 1])
    a[:, 7] = a[:, 0] + 1e-9 * a[:, 1]  # nearly dependent: the Gram matrix is too ill-conditioned for Cholesky
    r = linalg.triangle(a)
    gram = a.T @ a
    assert np.allclose(r.T @ r, gram, rtol=0, atol=1e-12 * np.abs(gram).max())
    assert np.allclose(np.tril(r, -1), 0.0)


def test_score_statistic_is_the_projection_of_the_residual():
    rng = np.random.default_rng(4)
    m = 300
    jac, columns = rng.normal(size=(m, 3, 5)), rng.normal(size=(m, 3, 4))
    columns[:, :, 3] = jac[:, :, 0]  # absorbed by the fitted columns: not identifiable
    res = rng.normal(size=(m, 3))
    groups = [np.array([0]), np.array([1, 2]), np.array([3])]
    got = score_statistics(res, jac, columns, groups, 2.0)
    j = jac.reshape(-1, 5)
    r_perp = res.ravel() - j @ np.linalg.lstsq(j, res.ravel(), rcond=None)[0]
    for idx, value in zip(groups[:2], got[:2], strict=True):
        g = columns[:, :, idx].reshape(-1, len(idx))
        g_perp = g - j @ np.linalg.lstsq(j, g, rcond=None)[0]
        projected = g_perp @ np.linalg.lstsq(g_perp, r_perp, rcond=None)[0]
        assert value == pytest.approx(float(projected @ projected) / 2.0, rel=1e-9)
    assert np.isnan(got[2])


def _stream_session(seed: int) -> tuple[Measurements, object]:
    """Six streamed sweeps (±0.6 rad, 100 Hz) of a perturbed UR5e and 24 stop-and-go poses, 10 of them held out."""
    rng = np.random.default_rng(seed)
    home = np.array([0.0, -1.2, 1.2, -1.5, -1.5, 0.3])
    nominal = replace(load_robot("ur5e").nominal, base=random_base(rng), tool=np.array([0.02, 0.03, 0.08]))
    truth = perturbed_model(nominal, rng)
    settings = StreamSettings(robot_rate=250.0, tracker_rate=100.0, speed=0.25, offset=-0.02,
                              recorded_offset=-0.012, jitter=2e-5, noise=NOISE)
    stream = streamed_sweeps(truth, home, [(j, home[j - 1] - 0.6, home[j - 1] + 0.6) for j in range(1, 7)],
                             settings, rng)
    limits = np.array([[-2, 2], [-2, -0.5], [0.5, 2], [-2, -1], [-2, -1], [-2, 2]])
    q = random_poses(limits, 24, rng)
    points = points_from_joints(truth, q) + rng.normal(0, NOISE / np.sqrt(5), (24, 3))
    poses = Measurements("RRRRRR", q, points, np.full(24, 100), np.zeros(24, dtype=np.int64),
                         check=np.arange(24) >= 14)
    return joined(stream, poses), nominal


@pytest.mark.slow
@pytest.mark.parametrize("outliers", [0, 12])
def test_a_session_solved_as_tall_identifies_what_minpack_does(monkeypatch, outliers):
    meas, nominal = _stream_session(5)
    if outliers:  # beam breaks: 5 mm off in x on streamed rows (the robust fits go through LSMR when tall)
        rows = np.random.default_rng(6).choice(np.flatnonzero(meas.streamed), outliers, replace=False)
        points = meas.points.copy()
        points[rows, 0] += 5e-3
        meas = replace(meas, points=points)
    reference = identify(meas, nominal, noise=NOISE)
    monkeypatch.setattr(tall_lsq, "TALL_ENTRIES", 0)  # every linear fit through the normal equations
    tall = identify(meas, nominal, noise=NOISE)
    assert tall.use == reference.use and tall.verdict.status == reference.verdict.status
    assert tall.rejected_rows == reference.rejected_rows and len(tall.rejected_rows) >= outliers
    for name, model in reference.models.items():
        ref = model.refinement
        changed = np.abs(vector_from_model(tall.models[name].refinement.model) - vector_from_model(ref.model))
        # within 0.01 of each free value's own uncertainty (base rotation: its increments are not in the vector)
        assert np.all(changed[3:][ref.free[3:]] < 0.01 * ref.std()[3:][ref.free[3:]]), name
    assert tall.clock.offset == pytest.approx(reference.clock.offset, abs=0.01 * reference.clock.offset_std)
