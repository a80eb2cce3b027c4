"""A printed board that is not flat: what its shape does to one view's pose (``aruco:...&flatness=M``).

A sheet on a table curls and warps by tenths of a millimetre; the detection takes its corners as flat, so every view
sees a pose off by what the shape does to the corners at that angle, the same in every frame of the view. The shape is
taken as three quadratic modes over the board (x, y: its centre-to-edge half extents scaled to ±1): ``1/3 - x²``
(curled about its y axis), ``1/3 - y²`` (about x) and ``x·y`` (twisted), each out of the print's plane with a standard
uncertainty of ``flatness`` m (at its peak; ``1/3 - x²`` spans ``flatness`` from the centre to the edges). The modes
have no mean over the board: a shape's mean height moves the board along its normal, which a fit of the board's pose
absorbs. :func:`flatness_bias` gives the view's sensitivity to them (least-squares pose through the projections'
Jacobian), added to each reading's ``shared`` error like the corners' bias (drivers/camera/tracker.py).
Units: metres, radians, pixels.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
_STEP = 1e-6  # m: the finite difference of a mode's height


def modes(points: Array, half: tuple[float, float]) -> Array:
    """The three shape modes' heights (3, N) at board points ``points`` (N, 2 or 3, m, board frame), with ``half``
    the board's half extents (m)."""
    x, y = points[:, 0] / half[0], points[:, 1] / half[1]
    return np.stack([1.0 / 3.0 - x**2, 1.0 / 3.0 - y**2, x * y])


def _project(points: Array, rotation: Array, translation: Array, camera: Any) -> Array:
    rvec = cv2.Rodrigues(np.asarray(rotation, dtype=float))[0]
    tvec = np.asarray(translation, dtype=float).reshape(3, 1)
    return cv2.projectPoints(points, rvec, tvec, camera.matrix, camera.distortion)[0].reshape(-1)


def pose_jacobian(points: Array, rotation: Array, translation: Array, camera: Any) -> Array:
    """(2N, 6): the projections' (x0 y0 x1 y1 ...) derivatives by a small turn ω of the board (rad, camera frame:
    ``R -> exp(ω) R``) and by its translation (m), by central differences."""
    out = []
    for k in range(6):
        step = np.zeros(6)
        step[k] = _STEP
        ends = []
        for sign in (1.0, -1.0):
            turn = cv2.Rodrigues(sign * step[:3])[0] @ rotation
            ends.append(_project(points, turn, np.asarray(translation, dtype=float) + sign * step[3:], camera))
        out.append((ends[0] - ends[1]) / (2 * _STEP))
    return np.array(out).T


def mode_shifts(rotation: Array, translation: Array, object_points: Array, half: tuple[float, float],
                camera: Any) -> Array:
    """(3, 6): how the least-squares pose of a flat board (camera <- board ``rotation``, ``translation``) moves, as a
    turn ω (rad, camera frame) and a translation (m), per metre of each shape mode (rows) of the print: the modes'
    moves of the corners ``object_points`` (N, 3, board frame) in the image through :func:`pose_jacobian`."""
    points = np.asarray(object_points, dtype=float).reshape(-1, 3)
    base = _project(points, rotation, translation, camera)
    solve = np.linalg.pinv(pose_jacobian(points, rotation, translation, camera))
    out = []
    for heights in modes(points, half):
        lifted = points.copy()
        lifted[:, 2] += _STEP * heights
        out.append(solve @ (_project(lifted, rotation, translation, camera) - base) / _STEP)
    return np.array(out)


class BoardShape:
    """The print's shape modes (3,), m, estimated from every frame seen so far, with a prior of ``flatness`` m per mode
    (``extent``: the board's width and height, m). Each frame's flat pose leaves the residuals ``r`` (its
    reprojection residuals, 2N px) that the modes explain as ``G a`` (``G``: their image moves with the pose's span
    projected out); the estimate is the least-squares ``a`` over the frames, its covariance ``s² (Σ GᵀG + s²/flatness²
    I)⁻¹`` with ``s²`` the residuals' variance left after it (over their 2N - 6 degrees of freedom each, minus 3)."""

    def __init__(self, flatness: float, extent: tuple[float, float]) -> None:
        self.flatness, self.half = float(flatness), (extent[0] / 2, extent[1] / 2)
        self._normal, self._rhs = np.zeros((3, 3)), np.zeros(3)
        self._square_sum, self._dof = 0.0, 0

    def add(self, pose: Any, observation: Any, camera: Any) -> None:
        """Take one frame's flat ``pose`` (drivers/camera/pose.py ``Pose``) of the detected ``observation``."""
        points = np.asarray(observation.object_points, dtype=float).reshape(-1, 3)
        base = _project(points, pose.rotation, pose.translation, camera)
        jacobian = pose_jacobian(points, pose.rotation, pose.translation, camera)
        span = jacobian @ np.linalg.pinv(jacobian)
        moves = []
        for heights in modes(points, self.half):
            lifted = points.copy()
            lifted[:, 2] += _STEP * heights
            moves.append((_project(lifted, pose.rotation, pose.translation, camera) - base) / _STEP)
        seen = np.asarray(moves).T  # (2N, 3)
        g = seen - span @ seen
        residual = np.asarray(observation.image_points, dtype=float).reshape(-1) - base
        residual = residual - span @ residual
        self._normal += g.T @ g
        self._rhs += g.T @ residual
        self._square_sum += float(residual @ residual)
        self._dof += len(base) - 6

    def _variance(self) -> float:
        """The residuals' variance (px²) once the modes' fit is taken out."""
        if self._dof <= 3:
            return math.inf
        fitted = np.linalg.lstsq(self._normal, self._rhs, rcond=None)[0]
        return max(self._square_sum - float(fitted @ self._rhs), 0.0) / (self._dof - 3)

    def estimate(self) -> tuple[Array, Array]:
        """The modes' estimate (3,), m, and its covariance (3, 3), m²."""
        s2 = self._variance()
        if not math.isfinite(s2) or s2 <= 0:
            return np.zeros(3), np.eye(3) * self.flatness**2
        normal = self._normal + np.eye(3) * s2 / self.flatness**2
        return np.linalg.solve(normal, self._rhs), s2 * np.linalg.inv(normal)

    def take(self, pose: Any, observation: Any, camera: Any, tp: Array) -> tuple[Any, tuple[float, float]]:
        """:meth:`add` the frame, then :meth:`correct` it."""
        self.add(pose, observation, camera)
        return self.correct(pose, observation, camera, tp)

    def correct(self, pose: Any, observation: Any, camera: Any, tp: Array) -> tuple[Any, tuple[float, float]]:
        """``pose`` moved to where the estimated shape says the board is (the flat pose minus the modes' response),
        and the per-axis RMS (m, rad) of the TP's and the orientation's error the estimate's uncertainty leaves."""
        shape, covariance = self.estimate()
        shifts = mode_shifts(pose.rotation, pose.translation, observation.object_points, self.half, camera).T  # (6, 3)
        move = shifts @ shape
        rotation = cv2.Rodrigues(-move[:3])[0] @ np.asarray(pose.rotation, dtype=float)
        corrected = replace(pose, rotation=rotation, translation=np.asarray(pose.translation) - move[3:])
        arm = rotation @ np.asarray(tp, dtype=float)  # the TP's lever in the camera frame: a turn ω moves it ω × arm
        lever = np.array([[0.0, arm[2], -arm[1]], [-arm[2], 0.0, arm[0]], [arm[1], -arm[0], 0.0]])  # ω -> ω × arm
        position = (lever @ shifts[:3] + shifts[3:]) @ covariance @ (lever @ shifts[:3] + shifts[3:]).T
        turn = shifts[:3] @ covariance @ shifts[:3].T
        return corrected, (math.sqrt(float(np.trace(position)) / 3), math.sqrt(float(np.trace(turn)) / 3))
