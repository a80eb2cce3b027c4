"""The lines model's Jacobian blocks (identify.estimator.poe.LineProblem.jacobian_blocks): equal to central differences
of the residuals, and the same whether the rows are formed in one block or in many (the chunks that bound the memory
of large sessions), with every kind of column present: streamed rows with their clock, joint-error terms, unread
joints, two tracked points, and orientation rows (a 6-DoF target's rotation residuals,
:mod:`identify.estimator.orientation`)."""

from __future__ import annotations

import numpy as np
import pytest

from config.robots import load_robot
from identify.estimator import poe
from identify.estimator.orientation import matrices_from_rotvecs
from identify.estimator.poe import JointTerms, LineProblem, lines_from_model, points_from_lines, target_rotations
from identify.estimator.sync import retiming

ROBOT = load_robot("ur5e")


def _problem(unknown: bool, oriented: bool = False) -> LineProblem:
    """A 60-row problem: the first 40 rows streamed along joint 2 (two sweeps), the rest free poses; joint-error
    terms on joints 2 and 5; every other row at a second tracked point; with ``unknown`` joint 3 unread on 5 rows;
    with ``oriented`` every third row (of those with every joint read) an orientation row of its tracked point."""
    rng = np.random.default_rng(5)
    home = np.asarray(ROBOT.home, dtype=float)
    lines = lines_from_model(ROBOT.nominal, home)
    lines = poe.AxisLines(lines.joint_types, lines.points, lines.directions, lines.home, lines.tp_home,
                          lines.tp_home[None, :] + [[0.05, -0.02, 0.03]])
    m = 60
    q = home + rng.uniform(-0.8, 0.8, (m, 6))
    t = np.full(m, np.nan)
    t[:40] = np.arange(40) * 0.05
    q[:40, 1] = home[1] + 0.3 * np.sin(t[:40])
    streamed = np.arange(m) < 40
    sweep = np.where(np.arange(m) < 20, 1, np.where(streamed, 2, 0))
    timing = retiming(t, streamed, sweep, q)
    tp_index = np.arange(m) % 2
    terms = JointTerms(rng.normal(size=(m, 2)), np.array([1, 4]), np.array([1e-3, -2e-3]))
    points = points_from_lines(lines, terms.corrected(q), tp_index) + rng.normal(0, 1e-4, (m, 3))
    unread = np.full(m, -1)
    if unknown:
        unread[45:50] = 2
        q[45:50, 2] = np.nan
    weights = rng.uniform(0.5, 2.0, m)
    rotations = None
    if oriented:
        frames = matrices_from_rotvecs(rng.normal(0, 1.0, (2, 3)))
        lines = poe.AxisLines(lines.joint_types, lines.points, lines.directions, lines.home, lines.tp_home,
                              lines.extra_tps, frames)
        rotations = np.full((m, 3, 3), np.nan)
        turn = (np.arange(m) % 3 == 0) & (unread < 0)
        noise = matrices_from_rotvecs(rng.normal(0, 1e-3, (int(turn.sum()), 3)))  # residuals off zero
        rotations[turn] = noise @ target_rotations(lines, terms.corrected(q)[turn], tp_index[turn])
    return LineProblem(lines, q, points, weights, unread, tp_index, terms, timing, rotations)


@pytest.mark.parametrize(("unknown", "oriented"), [(False, False), (True, False), (True, True)])
def test_one_block_or_many_give_the_same_jacobian(monkeypatch, unknown, oriented):
    problem = _problem(unknown, oriented)
    x = np.random.default_rng(1).normal(0, 1e-4, problem.size)
    whole = problem.jacobian_blocks(x)
    monkeypatch.setattr(poe, "ROWS_PER_CHUNK", 7)
    np.testing.assert_allclose(problem.jacobian_blocks(x), whole, rtol=0, atol=1e-14)


@pytest.mark.parametrize("oriented", [False, True])
def test_jacobian_is_the_derivative_of_the_residuals(oriented):
    problem = _problem(False, oriented)
    assert problem.oriented.sum() == (20 if oriented else 0) and problem.size == 33 + (6 if oriented else 0)
    x = np.random.default_rng(2).normal(0, 1e-4, problem.size)
    jac = problem.jacobian(x)
    step = 1e-7
    numeric = np.empty_like(jac)
    for k in range(problem.size):
        e = np.zeros(problem.size)
        e[k] = step
        numeric[:, k] = (problem.residuals(x + e) - problem.residuals(x - e)) / (2 * step)
    # central differences err by O(step²) plus rounding (1e-16 · |r| / step): far below 1e-6 of the column
    scale = np.maximum(np.abs(jac).max(axis=0), 1e-12)
    assert np.max(np.abs(jac - numeric) / scale) < 1e-6
