"""Starting values for the maximum-likelihood fit: the paper's circles, the axes from full-pose readings' relative
rotations (:mod:`identify.estimator.rotation_axes`, no circle needed: any arc) and the nominal model on the data.

Frames: tracker; units: metres and radians. With several tracked points the geometric step runs on the
first one's rows and every other point's position at home follows by linear least squares (the chain is a
rigid motion of the point at home).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from common.errors import InputError
from identify.estimator.cpa import GeometricResult, ReadingScaleError, geometric_step
from identify.estimator.estimate import nominal_start
from identify.estimator.measurements import Measurements
from identify.estimator.poe import AxisLines, points_from_lines
from identify.estimator.rotation_axes import lines_from_rotations
from kinematics.dh import DHModel

Array = NDArray[np.float64]


def starts(meas: Measurements, q: Array, unknown: NDArray[np.int64], tp_index: NDArray[np.int64], home: Array,
           nominal: DHModel | None, conventional: Array, parallel_tol: float, warnings: list[str]
           ) -> tuple[GeometricResult | None, list[tuple[str, AxisLines]]]:
    """Every start the data allow, each with a label: the geometric step (every joint swept) and the
    nominal model placed on the rows with known readings (at least 3). ``q``, ``unknown``, ``tp_index``:
    the fit rows' prepared readings, unread joints and tracked points (see :mod:`identify.estimator.poe`)."""
    found: list[tuple[str, AxisLines]] = []
    geo = None
    positions = ~meas.oriented  # (orientation rows repeat their position rows' readings)
    first = meas.subset((tp_index == 0) & positions)
    rotated = lines_from_rotations(meas, home) if np.any(meas.oriented) else None
    if rotated is not None:
        found.append(("axes from the relative rotations", other_points(rotated, q[positions], meas.points[positions],
                                                                       unknown[positions], tp_index[positions],
                                                                       warnings)))
    if all(first.sweeps_of(j) for j in range(1, meas.n_joints + 1)):
        try:
            geo = geometric_step(first, conventional, parallel_tol, nominal)
            lines = AxisLines(meas.joint_types, np.array([ax.point for ax in geo.axes]),
                              np.array([ax.direction for ax in geo.axes]), home, geo.tp_home)
            found.append(("geometric step", other_points(lines, q, meas.points, unknown, tp_index, warnings)))
        except InputError as exc:
            if (nominal is None and rotated is None) or isinstance(exc, ReadingScaleError):  # degrees: no start helps
                raise
            other = "the nominal model" if rotated is None else "the axes of the relative rotations"
            warnings.append(f"geometric step skipped ({exc}); started from {other}")
    if nominal is not None and np.sum(unknown < 0) >= 3:
        found.append(("nominal", nominal_start(nominal, q[positions], meas.points[positions], unknown[positions], home,
                                               tp_index[positions])))
    if not found:
        raise InputError("no start for the fit: sweep every joint, or give a nominal model and free poses")
    return geo, found


def other_points(lines: AxisLines, q: Array, points: Array, unknown: NDArray[np.int64], tp_index: NDArray[np.int64],
                 warnings: list[str]) -> AxisLines:
    """``lines`` with the positions at home of tracked points 1.. (0-based ``tp_index``): least squares over
    their rows with known readings, ``p = A(q) x + b(q)``; a point without such rows starts at the first
    point's position shifted by the mean offset between the two points' measurements."""
    count = int(tp_index.max()) + 1 if len(tp_index) else 1
    if count == 1:
        return lines
    extra = np.empty((count - 1, 3))
    for p in range(1, count):
        rows = (tp_index == p) & (unknown < 0)
        if np.any(rows):
            at_first = _moved(lines, q[rows], lines.tp_home)
            a = np.stack([_moved(lines, q[rows], lines.tp_home + e) - at_first for e in np.eye(3)], axis=2)
            rhs = (points[rows] - at_first).reshape(-1)
            extra[p - 1] = lines.tp_home + np.linalg.lstsq(a.reshape(-1, 3), rhs, rcond=None)[0]
        else:
            offset = points[tp_index == p].mean(axis=0) - points[tp_index == 0].mean(axis=0)
            extra[p - 1] = lines.tp_home + offset
            warnings.append(f"tracked point {p + 1} has no rows with joint readings: its start is a mean offset")
    return AxisLines(lines.joint_types, lines.points, lines.directions, lines.home, lines.tp_home, extra)


def _moved(lines: AxisLines, q: Array, x: Array) -> Array:
    """The point ``x`` (3,), taken at home, moved by the chain to readings ``q`` (m, n): (m, 3)."""
    moved = AxisLines(lines.joint_types, lines.points, lines.directions, lines.home, x)
    return points_from_lines(moved, q)
