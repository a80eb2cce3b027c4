"""The hold's pieces (identify/estimator/hold.py): the reference as increments, and the update's covariance."""

from __future__ import annotations

import numpy as np

from config.robots import load_robot
from identify.estimator.hold import Hold, increments
from identify.estimator.poe import LineProblem, lines_from_model
from kinematics.truth import random_truth


def test_the_reference_as_increments_moves_the_lines_onto_it():
    robot = load_robot("ur5e")
    rng = np.random.default_rng(1)
    start = lines_from_model(random_truth(robot.nominal, robot.home, rng), robot.home)
    reference = lines_from_model(random_truth(robot.nominal, robot.home, rng), robot.home)
    problem = LineProblem(start, np.zeros((0, 6)), np.zeros((0, 3)), np.zeros(0))
    moved, _ = problem.lines(increments(problem, reference))
    cos = np.abs(np.sum(moved.directions * reference.directions, axis=1))
    np.testing.assert_allclose(cos, 1.0, atol=1e-12)
    gap = np.cross(moved.points - reference.points, reference.directions)  # each moved point on its reference line
    np.testing.assert_allclose(gap, 0.0, atol=1e-12)
    np.testing.assert_allclose(moved.tp_home, reference.tp_home, atol=1e-15)


def test_a_held_direction_ends_at_the_tolerance_and_the_others_keep_their_variance():
    covariance = np.diag([1e-2, 1e-8])  # the first direction undetermined, the second determined
    hold = Hold(np.array([[1.0, 0.0]]), np.array([0.1]), 2e-3, ("axis 6",))
    after = hold.update(covariance)
    assert after[0, 0] < (2e-3) ** 2 and after[0, 0] > 0.99 * (2e-3) ** 2 * 1e-2 / (1e-2 + 4e-6)
    assert after[1, 1] == covariance[1, 1]
    shift = hold.shift(covariance, np.array([0.05, 1.0]))
    assert abs(shift[0] - 0.05) < 1e-3 and shift[1] == 0.0
