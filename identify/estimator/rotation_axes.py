"""The geometric step with full-pose readings: each joint's axis straight from one sweep's relative rotations.

While joint i alone turns, the target frame turns about joint i's axis: ``R_k R_refᵀ = exp(θ_k u)`` with
``θ_k = q_k - q_ref`` (tracker frame), whatever the joints before and after it do at home. So the measured relative
rotations give the axis direction ``u`` by linear least squares (``r_k ≈ θ_k u`` for ``r_k = log(R_k R_refᵀ)``), with
no circle to fit, on any arc, and the positions then give a point ``c`` of the axis linearly:
``(I - exp(θ_k u)) c = p_k - exp(θ_k u) p_ref``. A prismatic joint's direction comes from its positions,
``p_k - p_ref ≈ (q_k - q_ref) u``. Frames: tracker; units: metres and radians.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from identify.estimator.geometry import rotation_about_axis, unit
from identify.estimator.measurements import Measurements
from identify.estimator.orientation import matrices_from_rotvecs, rotation_residuals
from identify.estimator.poe import AxisLines, points_from_lines

Array = NDArray[np.float64]

MIN_SAMPLES = 3  # oriented samples a sweep needs (the reference and two turns)


def axis_from_rotations(rotations: Array, points: Array, angles: Array) -> tuple[Array, Array]:
    """A revolute joint's axis (point (3,), unit direction (3,)) from one sweep's measured target ``rotations``
    (k, 3, 3), positions ``points`` (k, 3) and joint readings ``angles`` (k,), rad: the direction turns positively
    with the readings; the point is the least-squares one nearest the sweep's centroid along the axis."""
    ref = int(np.argmin(np.abs(angles - np.median(angles))))
    theta = angles - angles[ref]
    turns = rotation_residuals(rotations, np.repeat(rotations[ref][None], len(rotations), axis=0))
    direction = unit(theta @ turns)
    spins = rotation_about_axis(direction, theta)
    a = (np.eye(3) - spins).reshape(-1, 3)
    b = (points - np.einsum("kij,j->ki", spins, points[ref])).reshape(-1)
    centre = points.mean(axis=0)
    # the axis' own direction is free in c: solve for the offset from the centroid, minimum norm (across the axis)
    point = centre + np.linalg.lstsq(a, b - a @ centre, rcond=None)[0]
    return point, direction


def axis_from_translations(points: Array, strokes: Array) -> tuple[Array, Array]:
    """A prismatic joint's axis (a point (3,) and unit direction (3,)) from positions ``points`` (k, 3) at joint
    readings ``strokes`` (k,), m: the least-squares direction of motion, positive with the readings."""
    dq = strokes - strokes.mean()
    return points.mean(axis=0), unit(dq @ (points - points.mean(axis=0)))


def lines_from_rotations(meas: Measurements, home: Array) -> AxisLines | None:
    """Axis lines at the ``home`` readings from the first tracked point's orientation rows of ``meas`` (fit rows,
    orientation rows marked by ``meas.oriented``, moved joint read), one sweep per joint (its most oriented one), and
    the tracked point at home by linear least squares over the rows with every joint read; None unless every
    joint has such a sweep of at least :data:`MIN_SAMPLES` samples."""
    oriented = meas.oriented & (meas.tp == meas.tp.min()) & ~meas.check & (meas.joint > 0)
    points, directions = [], []
    for j in range(1, meas.n_joints + 1):
        rows = oriented & (meas.joint == j) & np.isfinite(meas.q[:, j - 1])
        if not np.any(rows):
            return None
        ids, counts = np.unique(meas.sweep[rows], return_counts=True)
        if counts.max() < MIN_SAMPLES:
            return None
        rows &= meas.sweep == ids[np.argmax(counts)]
        values = meas.q[rows, j - 1]
        if meas.joint_types[j - 1] == "R":
            point, direction = axis_from_rotations(matrices_from_rotvecs(meas.rotvec[rows]), meas.points[rows], values)
        else:
            point, direction = axis_from_translations(meas.points[rows], values)
        points.append(point)
        directions.append(direction)
    lines = AxisLines(meas.joint_types, np.array(points), np.array(directions), np.asarray(home, dtype=float),
                      np.zeros(3))
    known = (meas.tp == meas.tp.min()) & ~meas.check & np.all(np.isfinite(meas.q), axis=1)
    return AxisLines(lines.joint_types, lines.points, lines.directions, lines.home,
                     _point_at_home(lines, meas.q[known], meas.points[known]))


def _point_at_home(lines: AxisLines, q: Array, points: Array) -> Array:
    """The tracked point at home (3,) that the chain of ``lines`` moves closest to ``points`` (m, 3) at readings
    ``q`` (m, n): linear least squares (the chain is a rigid motion of the point)."""
    def moved(x: Array) -> Array:
        return points_from_lines(AxisLines(lines.joint_types, lines.points, lines.directions, lines.home, x), q)

    at_zero = moved(np.zeros(3))
    a = np.stack([moved(e) - at_zero for e in np.eye(3)], axis=2).reshape(-1, 3)
    return np.linalg.lstsq(a, (points - at_zero).reshape(-1), rcond=None)[0]
