"""The hold's pieces (identify/estimator/hold.py): the reference as increments, and the nominal as a prior."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from config.robots import load_robot
from identify.estimator.hold import NominalPrior, increments
from identify.estimator.poe import LineProblem, lines_from_model
from kinematics.truth import perturbed_model, random_truth


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


def test_the_prior_vanishes_on_the_reference_and_its_jacobian_is_its_derivative():
    """The nominal as a measurement of the end effector's points over the joint space: zero residual where the
    lines are the reference's, one tolerance per RMS metre of their offset, and an exact Jacobian."""
    robot = load_robot("ur5e")
    rng = np.random.default_rng(2)
    arm = random_truth(robot.nominal, robot.home, rng)
    start = lines_from_model(arm, robot.home)
    other = replace(perturbed_model(robot.nominal, rng), base=arm.base, tool=arm.tool)  # the same arm's nominal
    reference = lines_from_model(other, robot.home)
    problem = LineProblem(start, np.zeros((0, 6)), np.zeros((0, 3)), np.zeros(0))
    prior = NominalPrior(problem, reference, 2e-3)
    at_reference = increments(problem, reference)
    assert np.linalg.norm(prior.residuals(at_reference)) < 1e-9
    offset = np.linalg.norm(prior.residuals(np.zeros(problem.size)))  # RMS over points and poses, in tolerances
    assert 0.1 < offset < 10.0  # two perturbed arms are a few mm apart, and a tolerance is 2 mm
    step = 1e-7
    x = 0.5 * at_reference
    numeric = np.stack([(prior.residuals(x + step * e) - prior.residuals(x - step * e)) / (2 * step)
                        for e in np.eye(problem.size)], axis=1)
    np.testing.assert_allclose(prior.jacobian(x), numeric, atol=1e-6 * np.abs(numeric).max())
