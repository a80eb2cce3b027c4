"""Maximum-likelihood fit of the joint axes as lines (product of exponentials at the home pose).

Model, tracker frame, metres: ``p(q) = T_1(q_1 - h_1) ∘ … ∘ T_n(q_n - h_n) (p_home)`` where ``T_i`` turns
about joint i's axis line (revolute) or slides along its direction (prismatic), both as they are at the
home pose ``h``. Lines have no singular configuration (parallel or intersecting axes are ordinary), so
this fit is well conditioned where DH is not; its lines are then turned into DH frames.
Parameters: per revolute joint, 2 tilts of the direction and 2 shifts of the point; per prismatic, 2
tilts; then the TP at home (3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from identify.geometry import perpendicular_basis, rotation_about_axis, skew, unit

Array = NDArray[np.float64]


@dataclass(frozen=True)
class AxisLines:
    """Joint axes at the home pose: ``points`` (n, 3) on each line, unit ``directions`` (n, 3), the
    ``home`` readings (n,) and the TP there, ``tp_home`` (3,). Prismatic points are meaningless."""

    joint_types: str
    points: Array
    directions: Array
    home: Array
    tp_home: Array


def points_from_lines(lines: AxisLines, q: Array) -> Array:
    """Predicted TP (m, 3) at joint readings ``q`` (m, n)."""
    p, _ = _chain(lines, q)
    return p


def _chain(lines: AxisLines, q: Array) -> tuple[Array, list[tuple[Array, Array, Array, Array]]]:
    """TP and, per joint from the tip, (input point u, output point w, rotation R, angle or stroke)."""
    m = len(q)
    x = np.tile(lines.tp_home, (m, 1))
    steps = []
    for i in reversed(range(len(lines.joint_types))):
        delta = q[:, i] - lines.home[i]
        if lines.joint_types[i] == "R":
            rot = rotation_about_axis(lines.directions[i], delta)
            y = lines.points[i] + np.einsum("kij,kj->ki", rot, x - lines.points[i])
        else:
            rot = np.broadcast_to(np.eye(3), (m, 3, 3))
            y = x + delta[:, None] * lines.directions[i]
        steps.append((x, y, rot, delta))
        x = y
    return x, steps[::-1]


class _LineProblem:
    def __init__(self, start: AxisLines, q: Array, points: Array, weights: Array):
        self.start, self.q, self.points, self.weights = start, q, points, weights
        self.types = start.joint_types
        self.bases = [np.array(perpendicular_basis(d)) for d in start.directions]
        self.size = sum(4 if t == "R" else 2 for t in self.types) + 3

    def lines(self, x: Array) -> tuple[AxisLines, list[Array]]:
        pts, dirs, tangents, k = [], [], [], 0
        for i, t in enumerate(self.types):
            e = self.bases[i]
            v = self.start.directions[i] + x[k] * e[0] + x[k + 1] * e[1]
            length = np.linalg.norm(v)
            u = v / length
            tangents.append((e - np.outer(e @ u, u)) / length)  # d(direction)/d(tilt), (2, 3)
            dirs.append(u)
            if t == "R":
                pts.append(self.start.points[i] + x[k + 2] * e[0] + x[k + 3] * e[1])
                k += 4
            else:
                pts.append(self.start.points[i])
                k += 2
        lines = AxisLines(self.types, np.array(pts), np.array(dirs), self.start.home, x[k:k + 3] + self.start.tp_home)
        return lines, tangents

    def residuals(self, x: Array) -> Array:
        lines, _ = self.lines(x)
        return ((points_from_lines(lines, self.q) - self.points) * self.weights[:, None]).ravel()

    def jacobian(self, x: Array) -> Array:
        lines, tangents = self.lines(x)
        _, steps = _chain(lines, self.q)
        m = len(self.q)
        jac = np.zeros((m, 3, self.size))
        left = np.broadcast_to(np.eye(3), (m, 3, 3)).copy()  # rotation of T_1 … T_{i-1}
        k = 0
        for i, t in enumerate(self.types):
            u, w, rot, delta = steps[i]
            if t == "R":
                # moving joint i's line rigidly by (eps_w, eps_v) moves the TP by
                # L [(-[w]x + R [u]x) eps_w + (I - R) eps_v]   (L = rotation of the joints before i)
                turn = left @ (rot @ skew(u) - skew(w))
                shift = left - left @ rot
                c = lines.points[i]
                for j in range(2):  # tilting the direction turns the line about its point c
                    eps_w = np.cross(lines.directions[i], tangents[i][j])
                    jac[:, :, k + j] = turn @ eps_w - shift @ np.cross(eps_w, c)
                    jac[:, :, k + 2 + j] = shift @ self.bases[i][j]
                k += 4
            else:
                jac[:, :, k:k + 2] = (left @ tangents[i].T) * delta[:, None, None]
                k += 2
            left = left @ rot
        jac[:, :, k:k + 3] = left
        jac *= self.weights[:, None, None]
        return jac.reshape(-1, self.size)


def fit_lines(start: AxisLines, q: Array, points: Array, weights: Array | None = None) -> tuple[AxisLines, Array]:
    """Least-squares axis lines and TP for readings ``q`` (m, n) and TP ``points`` (m, 3).

    ``weights`` (m,) = 1/sigma per sample. Returns the lines and the weighted residuals (m, 3).
    """
    weights = np.ones(len(q)) if weights is None else weights
    problem = _LineProblem(start, q, points, weights)
    method = "lm" if 3 * len(q) >= problem.size else "trf"
    fit = least_squares(problem.residuals, np.zeros(problem.size), jac=problem.jacobian, method=method,
                        x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200)
    lines, _ = problem.lines(fit.x)
    return _canonical(lines), fit.fun.reshape(-1, 3)


def _canonical(lines: AxisLines) -> AxisLines:
    """Each revolute line's point moved to the foot of the perpendicular from the TP at home."""
    pts = lines.points.copy()
    for i, t in enumerate(lines.joint_types):
        if t == "R":
            d = lines.directions[i]
            pts[i] = pts[i] + ((lines.tp_home - pts[i]) @ d) * d
    return AxisLines(lines.joint_types, pts, np.array([unit(d) for d in lines.directions]), lines.home,
                     lines.tp_home)
