"""The identified axis lines written as standard DH, with the covariance carried over.

DH is exact for any chain of lines, but near-parallel consecutive axes put their common normal far away
(``d`` ~ link length / misalignment). Exact DH is used unless it would move such a ``d`` more than
``max_offset`` from its conventional value; those links keep the parallel-axis convention, and the caller
measures what that costs. The covariance of the DH values (full vector of :mod:`identify.estimator.dh_vector`) is the
lines' covariance mapped through the conversion's Jacobian (forward differences); values held by a
convention have zero rows.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from identify.estimator.cpa import dh_from_axes
from identify.estimator.poe import AxisLines, LineProblem
from kinematics.dh import DHModel

Array = NDArray[np.float64]

EXACT_TOL = 1e-12  # rad: below this, axes are parallel to float precision and only a convention places them
STEP = 1e-7  # rad / m: forward-difference step on the line parameters


@dataclass(frozen=True)
class DHOutput:
    """The DH model, the links kept at the parallel-axis convention (1-based) with the ``d`` shift exact DH
    would need (m), and the full-vector Jacobian of the conversion (9 + 4n, p)."""

    model: DHModel
    capped: dict[int, float]
    jacobian: Array


def _convert(lines: AxisLines, conventional: Array, reference: DHModel | None, capped: Collection[int]) -> DHModel:
    return dh_from_axes(lines.joint_types, list(lines.points), list(lines.directions), lines.home, lines.tp_home,
                        conventional, EXACT_TOL, reference, capped)


def _vector(model: DHModel, base_rotation: Array) -> Array:
    increment = Rotation.from_matrix(model.base[:3, :3] @ base_rotation.T).as_rotvec()
    return np.concatenate([increment, model.base[:3, 3], model.tool, model.dh_table().ravel()])


PARALLEL_SIGMAS = 3.0  # axes whose angle is within this many standard uncertainties of 0 may be parallel


def axis_angle(lines: AxisLines, i: int) -> float:
    """Angle (rad) between the axes of joints i and i+1 (0-based), as lines (sign-free)."""
    return float(np.arccos(np.clip(abs(lines.directions[i] @ lines.directions[i + 1]), 0.0, 1.0)))


def near_parallel(lines: AxisLines, covariance: Array, conventional: Array, reference: DHModel | None,
                  parallel_tol: float, max_offset: float) -> tuple[dict[int, float], dict[int, float]]:
    """Links (1-based) whose axes the data cannot tell from parallel (angle within ``parallel_tol`` rad or
    within PARALLEL_SIGMAS standard uncertainties, from the lines' ``covariance``) or, for two revolute axes, whose
    exact ``d`` would move beyond ``max_offset`` whatever their angle (no table beyond the robot's reach), each with
    the shift of ``d`` from its conventional value that exact DH needs (m); and those of them beyond
    ``max_offset``."""
    exact = _convert(lines, conventional, reference, ())
    problem = LineProblem(lines, np.zeros((0, len(lines.home))), np.zeros((0, 3)), np.zeros(0))
    starts = np.cumsum([0] + [4 if t == "R" else 2 for t in lines.joint_types])  # first parameter of each joint
    near: dict[int, float] = {}
    for i in range(1, exact.n_joints):
        angle = axis_angle(lines, i - 1)
        grad = np.zeros(problem.size)
        for k in (*range(starts[i - 1], starts[i - 1] + 2), *range(starts[i], starts[i] + 2)):  # their tilts
            x = np.zeros(problem.size)
            x[k] = STEP
            grad[k] = (axis_angle(problem.lines(x)[0], i - 1) - angle) / STEP
        sigma = float(np.sqrt(max(grad @ covariance @ grad, 0.0)))
        if angle < max(parallel_tol, PARALLEL_SIGMAS * sigma):
            near[i] = _shift(exact, conventional, i)
    # a pair of revolute axes beyond the tolerance whose exact d would still leave the robot's reach (a prismatic
    # joint's d is its travel's zero, not a common normal): with the pairs above at the convention (a far common
    # normal of one pair moves the next frame's origin too), one pair at a time
    revolute = [i for i in range(1, exact.n_joints) if lines.joint_types[i - 1] == lines.joint_types[i] == "R"]
    for _ in range(exact.n_joints):
        placed = _convert(lines, conventional, reference, near)
        far = {i: _shift(placed, conventional, i) for i in revolute if i not in near}
        far = {i: v for i, v in far.items() if v > max_offset}
        if not far:
            break
        i = max(far, key=far.__getitem__)
        near[i] = far[i]
    return near, {i: v for i, v in near.items() if v > max_offset}


def _shift(model: DHModel, conventional: Array, i: int) -> float:
    """How far (m) ``model`` moves the ``d`` of link ``i`` (1-based; joint i+1's d) from its conventional value."""
    shift = abs(model.d[i] - conventional[i, 1])
    return float(shift) if np.isfinite(shift) else float("inf")


def dh_output(lines: AxisLines, conventional: Array, reference: DHModel | None, capped: dict[int, float],
              with_jacobian: bool = True) -> DHOutput:
    """Convert ``lines`` to DH (conventions from ``conventional`` (n, 4), x-axis signs from ``reference``),
    the ``capped`` links at the parallel-axis convention; the Jacobian (zeros unless ``with_jacobian``)."""
    model = _convert(lines, conventional, reference, capped)
    if not with_jacobian:
        return DHOutput(model, dict(capped), np.zeros((9 + 4 * model.n_joints, lines.n_parameters)))
    problem = LineProblem(lines, np.zeros((0, len(lines.home))), np.zeros((0, 3)), np.zeros(0))
    centre = _vector(model, model.base[:3, :3])
    jac = np.zeros((len(centre), problem.size))
    for k in range(problem.size):
        x = np.zeros(problem.size)
        x[k] = STEP
        moved, _ = problem.lines(x)
        diff = _vector(_convert(moved, conventional, reference, capped), model.base[:3, :3]) - centre
        for angles in (slice(9, None, 4), slice(12, None, 4)):  # theta, alpha
            diff[angles] = np.angle(np.exp(1j * diff[angles]))
        jac[:, k] = diff / STEP
    jac[np.abs(jac) < 1e-7] = 0.0  # conventions: values that do not move with the lines at all
    return DHOutput(model, dict(capped), jac)
