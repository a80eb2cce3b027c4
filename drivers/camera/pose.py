"""Target pose from one frame's points, and the tracked point's position with its covariance.

:func:`estimate_pose` solves the perspective-n-point problem with OpenCV: ``SOLVEPNP_IPPE_SQUARE`` for one
square marker, ``SOLVEPNP_IPPE`` for several coplanar points (a board, markers on one plane), ``SQPNP``
otherwise; every candidate is refined by Levenberg-Marquardt (``solvePnPRefineLM``: the maximum-likelihood
pose under Gaussian corner noise). A planar target has two poses that explain the points (the IPPE
ambiguity: the target tilted one way or the mirror way). When the second explains them almost as well as
the first (reprojection RMS within ``AMBIGUITY_RATIO`` × and ``AMBIGUITY_FLOOR_PX``), the one closer in
rotation to ``reference`` (the previous pose) is kept, so a sequence of frames stays on one branch.

The TP's covariance propagates the pose covariance ``s² (JᵀJ)⁻¹`` (J: the Jacobian of the projections by
rotation vector and translation, from ``cv2.projectPoints``; s: the corner noise, pixels) through
``p = R·tp + t``. Frames: the camera frame is the tracker frame; metres; pixels in OpenCV's convention.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.typing import NDArray

from drivers.camera.targets import Observation

Array = NDArray[np.float64]

AMBIGUITY_RATIO = 1.5  # second-best RMS below this multiple of the best: the frame is ambiguous ...
AMBIGUITY_FLOOR_PX = 0.05  # ... or both RMS within this many pixels of each other
SIGMA_PX_FLOOR = 0.01  # pixels: corner noise assumed at least this (clean renders reach 0.005-0.01 px)
# the detection's error fixed for a view (bench/camera_honesty.py, docs/benchmarks.md section 23):
VIEW_BIAS_PX = 0.00088  # for the TP: px, a scale error of the corners' image at their RMS radius, times 1/cos² of the
# obliquity (the depth error of an oblique view)
VIEW_TURN_BIAS_PX = 0.015  # for the orientation: px per corner coordinate, independent from corner to corner
_LM = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-12)


@dataclass(frozen=True)
class Pose:
    """One frame's target pose: ``rotation`` (3, 3) and ``translation`` (3,) m, camera frame <- target frame;
    ``rms`` reprojection RMS (pixels, per coordinate) over ``points`` points; ``jacobian`` (2N, 6) of the
    projections by (rotation vector, translation); ``ambiguous`` True when the IPPE alternative was close
    and a reference chose; ``image_covariance`` (2N, 2N) pixels² of the points, when the detection gave
    one (else the points are taken as independent with a common noise); ``image_points`` (N, 2) pixels, the
    detected points the pose was solved from (for :meth:`view_bias`)."""

    rotation: Array
    translation: Array
    rms: float
    points: int
    jacobian: Array
    ambiguous: bool = False
    image_covariance: Array | None = None
    image_points: Array | None = None

    @property
    def expected_rss(self) -> float | None:
        """Expected sum of squared reprojection residuals (pixels²) under :attr:`image_covariance`:
        ``tr((I - J N⁻¹ Jᵀ) Σ)``; None without one. Compare with ``2 N rms²``, the observed sum."""
        if self.image_covariance is None:
            return None
        hat = self.jacobian @ np.linalg.pinv(self.jacobian.T @ self.jacobian) @ self.jacobian.T
        return float(np.trace(self.image_covariance) - np.trace(hat @ self.image_covariance))

    @property
    def dof(self) -> int:
        """Degrees of freedom of the residuals (2N - 6)."""
        return 2 * self.points - 6

    def point(self, tp: Array) -> Array:
        """``tp`` (3,) m in the target frame -> camera frame."""
        return self.rotation @ np.asarray(tp, dtype=float) + self.translation

    def pose_covariance(self, sigma_px: float) -> Array:
        """Covariance (6, 6) of (rotation vector, translation), rad² and m², of the least-squares pose: the sandwich
        ``N⁻¹ Jᵀ Σ J N⁻¹`` (N = JᵀJ) with :attr:`image_covariance`, else ``sigma_px² N⁻¹`` (independent corners)."""
        inverse = np.linalg.pinv(self.jacobian.T @ self.jacobian)
        if self.image_covariance is not None:
            gain = inverse @ self.jacobian.T
            return gain @ self.image_covariance @ gain.T
        return sigma_px**2 * inverse

    def orientation_covariance(self, sigma_px: float) -> Array:
        """Covariance (3, 3) rad² of the target frame's orientation as a small turn in the camera frame
        (``R -> exp(δφ) R``): the rotation vector's block of :meth:`pose_covariance` through the left Jacobian."""
        rvec = cv2.Rodrigues(self.rotation)[0].ravel()
        angle = float(np.linalg.norm(rvec))
        k = np.array([[0.0, -rvec[2], rvec[1]], [rvec[2], 0.0, -rvec[0]], [-rvec[1], rvec[0], 0.0]])
        if angle < 1e-8:
            left = np.eye(3) + 0.5 * k
        else:
            left = np.eye(3) + (1 - np.cos(angle)) / angle**2 * k + (angle - np.sin(angle)) / angle**3 * (k @ k)
        return left @ self.pose_covariance(sigma_px)[:3, :3] @ left.T

    def view_bias(self, tp: Array, bias_px: float, turn_px: float | None = None) -> tuple[float, float]:
        """Per-axis RMS (m, rad) of the TP's and the orientation's error that the detection makes for this view,
        the same in every frame of it.

        The TP's: the corners' image scaled about its centre by ``bias_px`` pixels at its RMS radius, times
        ``1 / cos²`` of the obliquity (the angle between the target's normal and the line of sight to it): a
        coherent error of the target's apparent size, which the pose turns into a depth error along the line of
        sight (measured on rendered views: the error is along the line of sight, and it grows with the obliquity
        faster than the pose's sensitivity to independent corner errors). Needs :attr:`image_points` (0 without a
        ``bias_px``). The orientation's: a corner error of ``turn_px`` (default ``bias_px``) pixels per coordinate,
        independent from corner to corner (the pose's sensitivity ``turn_px² N⁻¹``)."""
        plain = replace(self, image_covariance=None)
        turn = bias_px if turn_px is None else turn_px
        turning = math.sqrt(float(np.trace(plain.orientation_covariance(turn))) / 3)
        if bias_px == 0.0:
            return 0.0, turning
        if self.image_points is None:
            raise ValueError("the view's error of the TP needs the pose's image points")
        centred = self.image_points - self.image_points.mean(axis=0)
        radius = math.sqrt(float(np.mean(np.sum(centred**2, axis=1))))
        sight = self.translation / np.linalg.norm(self.translation)
        cos = max(abs(float(self.rotation[:, 2] @ sight)), 0.1)  # beyond 84 deg no target is detected anyway
        shift = np.linalg.pinv(self.jacobian.T @ self.jacobian) @ self.jacobian.T @ (centred.ravel() / radius)
        moved = self._point_jacobian(tp) @ shift * bias_px / cos**2
        return float(np.linalg.norm(moved)) / math.sqrt(3), turning

    def _point_jacobian(self, tp: Array) -> Array:
        """(3, 6): the TP's change (m, camera frame) by the pose's (rotation vector, translation)."""
        rvec = cv2.Rodrigues(self.rotation)[0]
        _, d_r = cv2.Rodrigues(rvec)  # (3, 9): d vec(R) (row-major) / d rvec
        tp = np.asarray(tp, dtype=float)
        d_rot = np.stack([d_r[k].reshape(3, 3) @ tp for k in range(3)], axis=1)  # (3, 3): dp / d rvec
        return np.hstack([d_rot, np.eye(3)])

    def point_covariance(self, tp: Array, sigma_px: float) -> Array:
        """Covariance (3, 3) m² of :meth:`point`: from :attr:`image_covariance` when there is one (the
        least-squares pose's sandwich ``N⁻¹ Jᵀ Σ J N⁻¹``, N = JᵀJ), else for independent corner noise
        ``sigma_px`` pixels per coordinate (``sigma_px² N⁻¹``)."""
        jp = self._point_jacobian(tp)
        return jp @ self.pose_covariance(sigma_px) @ jp.T


@dataclass
class CornerNoise:
    """The corner noise pooled over frames, for the TP covariance of each (the polled reading's frames, or every
    frame of a stream so far): ``rss`` the observed sum of squared reprojection residuals (pixels²), ``expected``
    its expectation under the detection's corner covariances (pixels²; None once a pose came without them),
    ``dof`` the residual degrees of freedom."""

    rss: float = 0.0
    expected: float | None = 0.0
    dof: int = 0

    def add(self, pose: Pose) -> None:
        """Pool one frame's pose."""
        self.rss += pose.rms**2 * 2 * pose.points
        self.dof += max(pose.dof, 0)
        extra = pose.expected_rss
        self.expected = None if self.expected is None or extra is None else self.expected + extra

    def covariance(self, pose: Pose, tp: Array) -> Array:
        """Covariance (3, 3) m² of ``pose.point(tp)``: the edge fits' corner covariances, scaled up when the pooled
        residuals are larger than they predict; without them, independent corners with the pooled residuals' noise
        (never below :data:`SIGMA_PX_FLOOR`)."""
        if self.expected is not None and pose.image_covariance is not None:
            scale = max(self.rss / max(self.expected, 1e-30), 1.0)  # corners scatter more than their edges say
            return pose.point_covariance(tp, 0.0) * scale
        sigma_px = max(math.sqrt(self.rss / self.dof) if self.dof else 0.0, SIGMA_PX_FLOOR)
        return pose.point_covariance(tp, sigma_px)

    def orientation_covariance(self, pose: Pose) -> Array:
        """Covariance (3, 3) rad² of ``pose``'s orientation (:meth:`Pose.orientation_covariance`), with the corner
        noise of :meth:`covariance`."""
        if self.expected is not None and pose.image_covariance is not None:
            return pose.orientation_covariance(0.0) * max(self.rss / max(self.expected, 1e-30), 1.0)
        sigma_px = max(math.sqrt(self.rss / self.dof) if self.dof else 0.0, SIGMA_PX_FLOOR)
        return pose.orientation_covariance(sigma_px)


def estimate_pose(obs: Observation, matrix: Array, distortion: Array, square: bool = False,
                  reference: Array | None = None) -> Pose | None:
    """The target pose from ``obs`` (None with fewer than 4 points or no solution). ``square``: the points
    are one marker's corners in IPPE_SQUARE order; ``reference`` (3, 3): rotation that picks between two
    nearly equal IPPE solutions."""
    obj = np.ascontiguousarray(obs.object_points, dtype=np.float64).reshape(-1, 1, 3)
    img = np.ascontiguousarray(obs.image_points, dtype=np.float64).reshape(-1, 1, 2)
    n = len(obj)
    if n < 4:
        return None
    planar = np.ptp(obs.object_points[:, 2]) < 1e-9
    flag = cv2.SOLVEPNP_IPPE_SQUARE if square and n == 4 else cv2.SOLVEPNP_IPPE if planar else cv2.SOLVEPNP_SQPNP
    try:
        count, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, img, matrix, distortion, flags=flag)
    except cv2.error:
        return None
    candidates = []
    for rvec, tvec in zip(rvecs[:count], tvecs[:count], strict=True):
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, matrix, distortion, rvec.copy(), tvec.copy(), _LM)
        if tvec[2, 0] <= 0:
            continue  # behind the camera
        projected, jac = cv2.projectPoints(obj, rvec, tvec, matrix, distortion)
        residual = (projected - img).reshape(-1)
        rms = float(np.sqrt(np.mean(residual**2)))
        candidates.append((rms, rvec, tvec, jac[:, :6]))
    if not candidates:
        return None
    candidates.sort(key=lambda c: c[0])
    best, ambiguous = candidates[0], False
    if len(candidates) > 1:
        second = candidates[1]
        close = second[0] < AMBIGUITY_RATIO * best[0] or second[0] - best[0] < AMBIGUITY_FLOOR_PX
        distinct = _angle(cv2.Rodrigues(best[1])[0], cv2.Rodrigues(second[1])[0]) > 1e-3
        if close and distinct:
            ambiguous = True
            if reference is not None:
                best = min(candidates[:2], key=lambda c: _angle(cv2.Rodrigues(c[1])[0], reference))
    rms, rvec, tvec, jac = best
    return Pose(cv2.Rodrigues(rvec)[0], tvec.reshape(3), rms, n, np.asarray(jac, dtype=float), ambiguous,
                obs.covariance, np.asarray(obs.image_points, dtype=float).reshape(-1, 2))


def _angle(a: Array, b: Array) -> float:
    """Rotation angle (rad) between two rotation matrices."""
    c = (np.trace(a.T @ b) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))
