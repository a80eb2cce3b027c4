"""Geometric fits on 3D points: plane, circle, line, and the common normal of two lines.

All points are in one Cartesian frame (the tracker's), metres. Pure numpy/scipy, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares

Array = NDArray[np.float64]


def unit(v: ArrayLike) -> Array:
    """``v`` scaled to unit length (last axis)."""
    v = np.asarray(v, dtype=float)
    return v / np.sqrt(np.add.reduce(v * v, axis=-1, keepdims=True))  # np.linalg.norm's sum, without its checks


def perpendicular_basis(normal: ArrayLike) -> tuple[Array, Array]:
    """Two unit vectors ``(e1, e2)`` with ``(e1, e2, normal)`` right-handed and orthonormal."""
    n = unit(normal)
    helper = np.zeros(3)
    helper[int(np.argmin(np.abs(n)))] = 1.0
    e1 = unit(cross(helper, n))
    return e1, cross(n, e1)


def skew(v: ArrayLike) -> Array:
    """Cross-product matrix ``[v]x`` so that ``skew(v) @ w == cross(v, w)``; broadcasts over (..., 3)."""
    v = np.asarray(v, dtype=float)
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def rotation_about_axis(axis: ArrayLike, angle: ArrayLike) -> Array:
    """Rotation matrices (Rodrigues) about unit ``axis`` by ``angle`` radians; shape (..., 3, 3)."""
    axis = np.asarray(axis, dtype=float)
    angle = np.asarray(angle, dtype=float)
    if axis.ndim > 1:
        k = skew(unit(axis))
        return np.eye(3) + np.sin(angle)[..., None, None] * k + (1.0 - np.cos(angle))[..., None, None] * (k @ k)
    # one axis: I + sin K + (1 - cos) K², entry by entry (K² = k kᵀ - I)
    kx, ky, kz = unit(axis)
    s, c = np.sin(angle), np.cos(angle)
    v = 1.0 - c
    out = np.empty((*angle.shape, 3, 3))
    out[..., 0, 0], out[..., 1, 1], out[..., 2, 2] = c + kx * kx * v, c + ky * ky * v, c + kz * kz * v
    out[..., 0, 1], out[..., 1, 0] = kx * ky * v - kz * s, kx * ky * v + kz * s
    out[..., 0, 2], out[..., 2, 0] = kx * kz * v + ky * s, kx * kz * v - ky * s
    out[..., 1, 2], out[..., 2, 1] = ky * kz * v - kx * s, ky * kz * v + kx * s
    return out


def turned(points: Array, centre: Array, axis: Array, angle: Array) -> Array:
    """``points`` (m, 3) turned by ``angle`` (m,) rad about the line through ``centre`` along unit ``axis`` (3,)
    (Rodrigues' formula on the vectors, without forming the rotations)."""
    v = points - centre
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    return centre + v * c + cross(axis, v) * s + np.outer((v @ axis) * (1.0 - c[:, 0]), axis)


@dataclass(frozen=True)
class Plane:
    """Plane through ``centroid`` with unit ``normal``; ``rms`` = RMS point distance, metres."""

    centroid: Array
    normal: Array
    rms: float


def plane_from_points(points: ArrayLike) -> Plane:
    """Total-least-squares plane of (m, 3) points (m >= 3)."""
    p = np.asarray(points, dtype=float)
    centroid = p.mean(axis=0)
    _, s, vt = np.linalg.svd(p - centroid, full_matrices=False)
    return Plane(centroid, vt[2], float(s[2] / np.sqrt(len(p))) if len(s) > 2 else 0.0)


@dataclass(frozen=True)
class Line:
    """Line through ``point`` along unit ``direction``; ``rms`` = RMS point distance, metres."""

    point: Array
    direction: Array
    rms: float


def line_from_points(points: ArrayLike) -> Line:
    """Total-least-squares line of (m, 3) points (m >= 2)."""
    p = np.asarray(points, dtype=float)
    centroid = p.mean(axis=0)
    _, s, vt = np.linalg.svd(p - centroid, full_matrices=False)
    rms = float(np.sqrt(np.sum(s[1:] ** 2) / len(p)))
    return Line(centroid, vt[0], rms)


@dataclass(frozen=True)
class Circle:
    """Circle in 3D: ``center``, unit ``normal`` (axis direction), ``radius`` (m), ``rms`` (m).

    ``rms`` is the RMS 3D distance of the fitted points from the circle.
    """

    center: Array
    normal: Array
    radius: float
    rms: float


def circle_2d_algebraic(xy: ArrayLike) -> tuple[Array, float]:
    """Taubin's algebraic circle fit of (m, 2) points; returns (centre, radius). Seed for a geometric fit."""
    xy = np.asarray(xy, dtype=float)
    mean = xy.mean(axis=0)
    u, v = (xy - mean).T
    z = u * u + v * v
    zmean = z.mean()
    z0 = (z - zmean) / (2.0 * np.sqrt(zmean))
    design = np.column_stack([z0, u, v])
    _, _, vt = np.linalg.svd(design, full_matrices=False)
    coef = vt[2]
    a0 = coef[0] / (2.0 * np.sqrt(zmean))
    coef = np.array([a0, coef[1], coef[2], -zmean * a0])
    centre = -coef[1:3] / (2.0 * coef[0])
    radius = np.sqrt(coef[1] ** 2 + coef[2] ** 2 - 4 * coef[0] * coef[3]) / (2.0 * abs(coef[0]))
    return centre + mean, float(radius)


def cross(u: Array, v: Array, out: Array | None = None) -> Array:
    """Row-wise cross product of (..., 3) arrays, into ``out`` when given (it may be a strided view); faster than
    ``np.cross`` on small arrays."""
    out = np.empty(np.broadcast_shapes(np.shape(u), np.shape(v))) if out is None else out
    out[..., 0] = u[..., 1] * v[..., 2] - u[..., 2] * v[..., 1]
    out[..., 1] = u[..., 2] * v[..., 0] - u[..., 0] * v[..., 2]
    out[..., 2] = u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]
    return out


class _CircleProblem:
    """Orthogonal distances of points to a 3D circle: per point (height over the plane, radial error).

    Parameters: centre (3), tilt of the normal along e1, e2 (2), radius (1).
    """

    def __init__(self, points: Array, n0: Array, e1: Array, e2: Array):
        self.points, self.n0, self.basis = points, n0, np.array([e1, e2])

    def _parts(self, x: Array) -> tuple[Array, Array, float, Array, Array, Array]:
        v = self.n0 + x[3] * self.basis[0] + x[4] * self.basis[1]
        length = np.linalg.norm(v)
        n = v / length
        rel = self.points - x[:3]
        h = rel @ n
        w = rel - h[:, None] * n
        return n, rel, length, h, w, np.linalg.norm(w, axis=1)

    def residuals(self, x: Array) -> Array:
        _, _, _, h, _, rho = self._parts(x)
        return np.concatenate([h, rho - x[5]])

    def jacobian(self, x: Array) -> Array:
        n, rel, length, h, w, rho = self._parts(x)
        w_hat = w / np.maximum(rho, 1e-300)[:, None]
        dn = (self.basis - np.outer(self.basis @ n, n)) / length  # (2, 3): dn/dtilt
        m = len(h)
        jac = np.zeros((2 * m, 6))
        jac[:m, :3] = -n
        jac[:m, 3:5] = rel @ dn.T
        jac[m:, :3] = -w_hat
        jac[m:, 3:5] = -h[:, None] * (w_hat @ dn.T)
        jac[m:, 5] = -1.0
        return jac


def circle_from_points(points: ArrayLike, robust_scale: float | None = None) -> Circle:
    """Geometric (orthogonal-distance) circle fit in 3D, seeded by a plane + Taubin algebraic fit.

    Minimises the distances of the (m, 3) points to the circle, so it stays unbiased on short arcs
    where algebraic fits shrink the radius. ``robust_scale`` (metres), when given, switches to a
    soft-L1 loss with that scale so a few gross outliers do not pull the fit.
    """
    p = np.asarray(points, dtype=float)
    plane = plane_from_points(p)
    e1, e2 = perpendicular_basis(plane.normal)
    rel = p - plane.centroid
    centre_2d, radius = circle_2d_algebraic(np.column_stack([rel @ e1, rel @ e2]))
    centre = plane.centroid + centre_2d[0] * e1 + centre_2d[1] * e2
    x0 = np.concatenate([centre, [0.0, 0.0, radius]])
    problem = _CircleProblem(p, plane.normal, e1, e2)
    scale = max(radius, 1e-6)
    fit = least_squares(
        problem.residuals,
        x0,
        jac=problem.jacobian,
        method="lm" if robust_scale is None and len(p) >= 3 else "trf",
        loss="linear" if robust_scale is None else "soft_l1",
        f_scale=robust_scale or 1.0,
        x_scale=np.array([scale, scale, scale, 1.0, 1.0, scale]),
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
    )
    n, _, _, _, _, _ = problem._parts(fit.x)
    res = problem.residuals(fit.x).reshape(2, -1)
    rms = float(np.sqrt(np.mean(np.sum(res**2, axis=0))))
    return Circle(fit.x[:3], n, float(abs(fit.x[5])), rms)


def circle_residuals(points: ArrayLike, circle: Circle) -> Array:
    """3D distance (m) of each point from ``circle``, shape (m,)."""
    rel = np.asarray(points, dtype=float) - circle.center
    h = rel @ circle.normal
    rho = np.linalg.norm(rel - h[:, None] * circle.normal, axis=1)
    return np.hypot(h, rho - circle.radius)


UNWRAP_CONSISTENT = 0.5  # rad: most a reading-unwrapped angle may stray from the readings' line


def angles_on_circle(points: ArrayLike, circle: Circle, readings: ArrayLike | None = None) -> Array:
    """Angle of each point about ``circle.normal`` (counter-clockwise), radians, unwrapped.

    With the joint ``readings`` (rad, one per point) each angle is unwrapped to the turn the readings
    predict (turning either way about the normal), so samples more than half a turn apart, or a sweep
    with gaps, keep their true angles. Without readings, or when the angles do not follow the readings
    at one radian per radian either way (readings in another unit), they are unwrapped in row order.
    """
    e1, e2 = perpendicular_basis(circle.normal)
    rel = np.asarray(points, dtype=float) - circle.center
    raw = np.arctan2(rel @ e2, rel @ e1)
    if readings is not None and len(raw) > 1:
        ref = np.asarray(readings, dtype=float) - float(np.asarray(readings)[0])
        best = None
        for sign in (1.0, -1.0):
            turns = np.round((sign * ref - (raw - raw[0])) / (2 * np.pi))
            angles = raw + 2 * np.pi * turns
            stray = angles - sign * ref
            stray -= np.median(stray)
            worst = float(np.max(np.abs(stray)))
            if worst < UNWRAP_CONSISTENT and (best is None or worst < best[0]):
                best = (worst, angles)
        if best is not None:
            return best[1]
    return np.unwrap(raw)


@dataclass(frozen=True)
class CommonNormal:
    """Feet of the common normal of two lines: ``foot_1`` on line 1, ``foot_2`` on line 2.

    ``parallel`` is set when the lines are parallel within the tolerance given, in which case the feet
    are the anchor point given and its projection onto line 2 (the normal is not unique).
    """

    foot_1: Array
    foot_2: Array
    parallel: bool

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.foot_2 - self.foot_1))


def common_normal(
    p1: ArrayLike,
    u1: ArrayLike,
    p2: ArrayLike,
    u2: ArrayLike,
    parallel_tol: float = 1e-9,
    anchor: ArrayLike | None = None,
) -> CommonNormal:
    """Common normal of line 1 (``p1``, unit ``u1``) and line 2 (``p2``, unit ``u2``).

    Lines at an angle below ``parallel_tol`` radians count as parallel: the normal then passes through
    ``anchor`` (a point on line 1; ``p1`` by default), which is how a convention picks one of the
    infinitely many normals.
    """
    p1, u1, p2, u2 = (np.asarray(v, dtype=float) for v in (p1, u1, p2, u2))
    sin_angle = np.linalg.norm(cross(u1, u2))
    if sin_angle <= np.sin(parallel_tol):
        foot_1 = p1 if anchor is None else np.asarray(anchor, dtype=float)
        foot_2 = p2 + ((foot_1 - p2) @ u2) * u2
        return CommonNormal(foot_1, foot_2, True)
    w = p2 - p1
    b = u1 @ u2
    denom = 1.0 - b * b
    s = ((w @ u1) - b * (w @ u2)) / denom
    t = (b * (w @ u1) - (w @ u2)) / denom
    return CommonNormal(p1 + s * u1, p2 + t * u2, False)


def left_jacobian(omega: Array) -> Array:
    """The left Jacobian (3, 3) of SO(3) at rotation vector ``omega`` (rad): d(exp(omega) v) / d omega =
    -[exp(omega) v]x · left_jacobian(omega)."""
    angle = float(np.linalg.norm(omega))
    k = skew(omega)
    if angle < 1e-8:
        return np.eye(3) + 0.5 * k
    return np.eye(3) + (1 - np.cos(angle)) / angle**2 * k + (angle - np.sin(angle)) / angle**3 * (k @ k)
