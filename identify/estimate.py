"""The maximum-likelihood estimate in the axis-line parameterisation, robust to gross outliers.

Every sample is used: rows with all readings, rows of sweeps jogged by hand and positions-only rows (their
unread joint a nuisance parameter, see :mod:`identify.poe`). The fit starts from each start it is given
(the paper's circles, the nominal model placed on the data) and keeps the one with the best robust cost.
Frames: tracker; units: metres and radians.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from identify.kinematics import DHModel, frames_from_joints
from identify.outliers import leverages, outlier_free
from identify.poe import AxisLines, LineProblem, fit_lines, lines_from_model
from identify.refine import NOISE_FLOOR

Array = NDArray[np.float64]

ROBUST_WIDTH = 3.0  # soft-L1 scale, in robust noise standard deviations
PLACE_ITERATIONS = 3  # alternations before the joint least-squares finish
ROBUST_PASSES = 2


@dataclass(frozen=True)
class LinesFit:
    """A fitted lines model. ``q`` (m, n): readings with the unread values solved; ``inliers`` (m,);
    ``residuals`` (m, 3) measured minus predicted, metres; ``robust_cost`` compares starts."""

    lines: AxisLines
    q: Array
    inliers: NDArray[np.bool_]
    residuals: Array
    robust_cost: float
    start: str


def place_nominal(nominal: DHModel, q: Array, points: Array) -> DHModel:
    """``nominal`` with the base (tracker <- frame 0) and tool (TP in frame n) that best fit ``points``
    (m, 3) at readings ``q`` (m, n): alternately a point-set fit of the base (Kabsch) and a linear fit of
    the TP, from the flange."""
    frames = frames_from_joints(replace(nominal, base=np.eye(4)), q)[:, -1]
    tool = np.zeros(3)
    base = np.eye(4)
    for _ in range(PLACE_ITERATIONS):
        local = np.einsum("kij,j->ki", frames[:, :3, :3], tool) + frames[:, :3, 3]  # TP in frame 0
        centre_l, centre_p = local.mean(axis=0), points.mean(axis=0)
        rot, _ = Rotation.align_vectors(points - centre_p, local - centre_l)
        base[:3, :3] = rot.as_matrix()
        base[:3, 3] = centre_p - base[:3, :3] @ centre_l
        # TP: points = R_b (R_k t + o_k) + t_b  ->  linear least squares in t
        a = np.einsum("ij,kjl->kil", base[:3, :3], frames[:, :3, :3]).reshape(-1, 3)
        rhs = (points - (frames[:, :3, 3] @ base[:3, :3].T + base[:3, 3])).reshape(-1)
        new_tool = np.linalg.lstsq(a, rhs, rcond=None)[0]
        if np.linalg.norm(new_tool - tool) < 1e-12:
            tool = new_tool
            break
        tool = new_tool

    def residuals(x: Array) -> Array:  # the alternation can stall on short arcs: finish jointly
        rot = Rotation.from_rotvec(x[:3]).as_matrix() @ base[:3, :3]
        local = np.einsum("kij,j->ki", frames[:, :3, :3], x[6:]) + frames[:, :3, 3]
        return (local @ rot.T + x[3:6] - points).ravel()

    x = least_squares(residuals, np.concatenate([np.zeros(3), base[:3, 3], tool]), method="lm", xtol=1e-12,
                      ftol=1e-12).x
    base[:3, :3] = Rotation.from_rotvec(x[:3]).as_matrix() @ base[:3, :3]
    base[:3, 3] = x[3:6]
    return replace(nominal, base=base.copy(), tool=x[6:].copy())


def nominal_start(nominal: DHModel, q: Array, points: Array, unknown: NDArray[np.int64], home: Array) -> AxisLines:
    """Axis lines of the nominal model placed on the rows whose readings are all known."""
    known = unknown < 0
    placed = place_nominal(nominal, q[known], points[known])
    return lines_from_model(placed, home)


def robust_scale(res: Array, leverage: Array) -> float:
    """Robust per-axis noise (weighted units) of studentised residuals: median of the squared norm over
    the median of chi-square(3)."""
    r2 = np.sum(res**2, axis=1) / np.maximum(1.0 - leverage, 0.01)  # (a nuisance row's third dimension aside)
    return float(np.sqrt(np.median(r2) / 2.365974))


def fit(start: AxisLines, q: Array, points: Array, weights: Array, unknown: NDArray[np.int64],
        group: NDArray[np.int64], joint: NDArray[np.int64], robust: bool, label: str) -> LinesFit:
    """Least squares from ``start``; if any sample fails the outlier test, a soft-L1 fit, the test again
    on its residuals, and a final least-squares fit on the samples kept. ``group``: sweep number of each
    row (>= 1; 0 for free poses) and ``joint`` the joint it moves, for the neighbour test."""
    lines, q_s, res = fit_lines(start, q, points, weights, unknown)
    inliers = np.ones(len(q), dtype=bool)
    if robust:
        lev = leverages(LineProblem(lines, q, points, weights, unknown).jacobian_blocks(np.zeros(lines.n_parameters)),
                        unknown)
        key = along_arc(q_s, joint)
        inliers = outlier_free(res, lev, group, key, unknown)
        if not np.all(inliers):
            for _ in range(ROBUST_PASSES):  # the scale of a fit pulled by outliers is too wide: shrink it
                scale = max(robust_scale(res, lev), NOISE_FLOOR * float(np.median(weights)))
                lines, q_s, res = fit_lines(lines, q, points, weights, unknown, "soft_l1", ROBUST_WIDTH * scale)
            inliers = outlier_free(res, lev, group, along_arc(q_s, joint), unknown)
            for _ in range(2):  # least squares on the samples kept; re-admit those it then explains
                lines, _, _ = fit_lines(lines, q[inliers], points[inliers], weights[inliers], unknown[inliers])
                problem = LineProblem(lines, q, points, weights, unknown)
                q_s = problem.joints(lines)
                res = problem.residuals(np.zeros(lines.n_parameters)).reshape(-1, 3)
                kept = inliers
                lev = leverages(problem.jacobian_blocks(np.zeros(lines.n_parameters)), unknown)
                inliers = outlier_free(res, lev, group, along_arc(q_s, joint), unknown)
                if np.array_equal(inliers, kept):
                    break
    scale = max(robust_scale(res[inliers], np.zeros(int(inliers.sum()))), NOISE_FLOOR)
    r2 = np.sum(res**2, axis=1) / (ROBUST_WIDTH * scale) ** 2
    cost = float(np.sum(2.0 * (np.sqrt(1.0 + r2) - 1.0)))
    return LinesFit(lines, q_s, inliers, -res / weights[:, None], cost, label)


def along_arc(q: Array, joint: NDArray[np.int64]) -> Array:
    """Each sweep row's position along its arc: the value of the joint it moves (free poses: 0)."""
    swept = joint > 0
    key = np.zeros(len(q))
    key[swept] = q[np.flatnonzero(swept), joint[swept] - 1]
    return key
