"""What a board not quite flat and a lens not quite calibrated do to every view, estimated from all the frames.

``aruco:...&flatness=M``, ``&lens_sigma=K``, ``&focal_sigma=F`` and ``&centre_sigma=C`` (drivers/camera/tracker.py).
These errors are the same in every view and move its corners in a pattern no pose can take up entirely, so the
residuals of the views' flat poses tell them:

- **the board's shape**: a sheet on a table curls and warps by tenths of a millimetre, out of its plane, in three
  quadratic modes over the board (x, y its centre-to-edge half extents scaled to ±1): ``1/3 - x²`` (curled about
  its y axis), ``1/3 - y²`` (about x) and ``x·y`` (twisted), each with a prior standard uncertainty of ``flatness``
  m (``1/3 - x²`` spans it from the centre to the edges). The modes have no mean over the board: a shape's mean
  height moves the board along its normal, and the board's frame is its mean plane;
- **the lens**: the radial distortion left after calibration, k1 and k2 off by ``dk1``, ``dk2`` (prior standard
  uncertainty ``lens_sigma`` each); the focal lengths fx, fy off by the factor 1 + ``dfocal`` (relative, prior
  ``focal_sigma``) and the principal point by ``dcx``, ``dcy`` px (prior ``centre_sigma`` each). What a view's pose
  can take up is projected out: for a board facing the camera a focal error is a change of its distance (the
  residuals see it in tilted views, whose near and far corners it scales differently), and most of a principal
  point's shift is a turn of the camera (the residuals see what is left of it, the perspective's change across
  the image; the turn is the same in every view, and a camera mount fitted with the arm takes up most of what the
  estimate misses, not all: docs/benchmarks.md section 24a).

Each frame's flat pose leaves the reprojection residuals ``r`` (2N px) that the parameters θ explain as ``G θ`` (``G``:
their image moves with the pose's span projected out). :class:`BoardAndLens` keeps the least-squares θ over every
frame so far with its covariance ``s² (Σ GᵀG + s² P⁻²)⁻¹`` (``P`` the priors, ``s²`` the residuals' variance left
after the fit, over their 2N - 6 degrees of freedom each minus θ's). A frame's pose is then corrected by its
least-squares response to θ (:func:`pose_shifts`), its reprojection RMS becomes that of ``r - G θ`` (the corner
noise the reading's sigma is scaled by: the flat pose's RMS holds the shape's and the lens's pattern, which made the
readings' sigmas 1.5x their errors with a board bowed 0.5 mm, docs/benchmarks.md section 24a), and what θ's
covariance leaves goes into the reading's ``shared`` error. A reading made early in a session carries more of it
(fewer frames behind θ). Units: metres, radians, pixels.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from drivers.base import Correction

Array = NDArray[np.float64]
_STEP = 1e-6  # finite differences: m of a mode's height, rad of a turn, m of a translation, of a lens coefficient
#: the lens's parameters in their order (module docstring): dk1, dk2 (``lens_sigma``), dfocal (``focal_sigma``),
#: dcx, dcy (``centre_sigma``)
LENS = ("dk1", "dk2", "dfocal", "dcx", "dcy")
MODES = ("bow_x", "bow_y", "twist")  #: the shape modes' names, in their order (:func:`modes`)


def modes(points: Array, half: tuple[float, float]) -> Array:
    """The three shape modes' heights (3, N) at board points ``points`` (N, 2 or 3, m, board frame), with ``half``
    the board's half extents (m)."""
    x, y = points[:, 0] / half[0], points[:, 1] / half[1]
    return np.stack([1.0 / 3.0 - x**2, 1.0 / 3.0 - y**2, x * y])


def _project(points: Array, rotation: Array, translation: Array, camera: Any, distortion: Array | None = None) -> Array:
    rvec = cv2.Rodrigues(np.asarray(rotation, dtype=float))[0]
    tvec = np.asarray(translation, dtype=float).reshape(3, 1)
    lens = camera.distortion if distortion is None else distortion
    return cv2.projectPoints(points, rvec, tvec, camera.matrix, lens)[0].reshape(-1)


def pose_jacobian(points: Array, rotation: Array, translation: Array, camera: Any) -> Array:
    """(2N, 6): the projections' (x0 y0 x1 y1 ...) derivatives by a small turn ω of the board (rad, camera frame:
    ``R -> exp(ω) R``) and by its translation (m), by central differences."""
    out = []
    for k in range(6):
        step = np.zeros(6)
        step[k] = _STEP
        ends = [_project(points, cv2.Rodrigues(sign * step[:3])[0] @ rotation,
                         np.asarray(translation, dtype=float) + sign * step[3:], camera) for sign in (1.0, -1.0)]
        out.append((ends[0] - ends[1]) / (2 * _STEP))
    return np.array(out).T


def effects(points: Array, rotation: Array, translation: Array, camera: Any, half: tuple[float, float],
            lens: tuple[str, ...] = ()) -> Array:
    """(2N, 3 + len(lens)): the projections' moves per metre of each shape mode, then per unit of each of the lens's
    parameters named in ``lens`` (of :data:`LENS`: dk1, dk2 by finite differences; dfocal, the pixel's offset from
    the principal point; dcx, dcy, one pixel along u or v)."""
    base = _project(points, rotation, translation, camera)
    out = []
    for heights in modes(points, half):
        lifted = points.copy()
        lifted[:, 2] += _STEP * heights
        out.append((_project(lifted, rotation, translation, camera) - base) / _STEP)
    for name in lens:
        if name in ("dk1", "dk2"):
            distortion = np.array(camera.distortion, dtype=float)
            distortion[LENS.index(name)] += _STEP
            out.append((_project(points, rotation, translation, camera, distortion) - base) / _STEP)
        elif name == "dfocal":  # u = fx (1 + dfocal) x_distorted + cx
            out.append((base.reshape(-1, 2) - camera.matrix[:2, 2]).reshape(-1))
        else:
            out.append(np.tile([1.0, 0.0] if name == "dcx" else [0.0, 1.0], len(points)))
    return np.array(out).T


def pose_shifts(rotation: Array, translation: Array, object_points: Array, half: tuple[float, float], camera: Any,
                lens: tuple[str, ...] = ()) -> Array:
    """(3 + len(lens), 6): how the least-squares pose of a flat board seen through the calibrated lens (camera <- board
    ``rotation``, ``translation``) moves, as a turn ω (rad, camera frame) and a translation (m), per unit of each
    parameter (rows: the shape modes, m, then the lens's parameters named in ``lens``, :func:`effects`) at the
    corners ``object_points`` (N, 3)."""
    points = np.asarray(object_points, dtype=float).reshape(-1, 3)
    solve = np.linalg.pinv(pose_jacobian(points, rotation, translation, camera))
    return (solve @ effects(points, rotation, translation, camera, half, lens)).T


class BoardAndLens:
    """The board's shape modes (m) and the lens's parameters whose prior is above 0 (``lens_sigma``: dk1, dk2;
    ``focal_sigma``: dfocal, relative; ``centre_sigma``: dcx, dcy, px), estimated from every frame so far (module
    docstring); ``flatness`` m the modes' prior (0: the board is flat, only the lens), ``extent`` the board's width
    and height, m. ``lens``: the names of the lens's parameters estimated (of :data:`LENS`), in order.
    ``frames_per_view``: the frames a reading takes of one still view; they share most of their detection's error
    (the same pixels, blur and texture: with 2 frames a view the estimate's sd came out 1.4x too small counting
    each frame as independent), so each frame counts for ``1 / frames_per_view`` of a view: the same estimate, its
    covariance that of the views."""

    def __init__(self, flatness: float, lens_sigma: float, extent: tuple[float, float], focal_sigma: float = 0.0,
                 centre_sigma: float = 0.0, frames_per_view: int = 1) -> None:
        self.weight = 1.0 / max(int(frames_per_view), 1)
        sigmas = dict(zip(LENS, (lens_sigma, lens_sigma, focal_sigma, centre_sigma, centre_sigma), strict=True))
        self.half = (extent[0] / 2, extent[1] / 2)
        self.lens = tuple(name for name in LENS if sigmas[name] > 0)
        self.names = (*MODES, *self.lens)
        prior = [flatness] * 3 + [sigmas[name] for name in self.lens]
        self.prior = np.array(prior, dtype=float)
        self.used = self.prior > 0  # a zero prior: that parameter is known (0)
        size = len(prior)
        self._normal, self._rhs = np.zeros((size, size)), np.zeros(size)
        self._square_sum, self._dof = 0.0, 0.0

    @classmethod
    def of(cls, flatness: float, lens_sigma: float, extent: tuple[float, float], focal_sigma: float = 0.0,
           centre_sigma: float = 0.0, frames_per_view: int = 1) -> BoardAndLens | None:
        """The estimator for a tracker's options, None when all are 0 (a flat board, a calibrated lens)."""
        if max(flatness, lens_sigma, focal_sigma, centre_sigma) <= 0:
            return None
        return cls(flatness, lens_sigma, extent, focal_sigma, centre_sigma, frames_per_view)

    def add(self, pose: Any, observation: Any, camera: Any) -> tuple[Array, Array]:
        """Take one frame's flat ``pose`` (drivers/camera/pose.py ``Pose``) of the detected ``observation``; return
        its residuals ``r`` (2N, px) and their moves per unit of each parameter ``G`` (2N, p), the pose's span
        projected out of both."""
        points = np.asarray(observation.object_points, dtype=float).reshape(-1, 3)
        jacobian = pose_jacobian(points, pose.rotation, pose.translation, camera)
        span = jacobian @ np.linalg.pinv(jacobian)
        moves = effects(points, pose.rotation, pose.translation, camera, self.half, self.lens)
        g = moves - span @ moves
        residual = np.asarray(observation.image_points, dtype=float).reshape(-1) - _project(
            points, pose.rotation, pose.translation, camera)
        residual = residual - span @ residual
        self._normal += self.weight * g.T @ g
        self._rhs += self.weight * g.T @ residual
        self._square_sum += self.weight * float(residual @ residual)
        self._dof += self.weight * (len(residual) - 6)
        return residual, g

    def estimate(self) -> tuple[Array, Array]:
        """The parameters' estimate and covariance (module docstring; the known ones 0 with no variance)."""
        used = self.used
        value, covariance = np.zeros(len(used)), np.zeros((len(used), len(used)))
        k = int(used.sum())
        if self._dof <= k:
            covariance[np.ix_(used, used)] = np.diag(self.prior[used] ** 2)
            return value, covariance
        normal, rhs = self._normal[np.ix_(used, used)], self._rhs[used]
        fitted = np.linalg.lstsq(normal, rhs, rcond=None)[0]
        s2 = max(self._square_sum - float(fitted @ rhs), 1e-12) / (self._dof - k)
        weighted = normal + np.diag(s2 / self.prior[used] ** 2)
        value[used] = np.linalg.solve(weighted, rhs)
        covariance[np.ix_(used, used)] = s2 * np.linalg.inv(weighted)
        return value, covariance

    def take(self, pose: Any, observation: Any, camera: Any, tp: Array) -> tuple[Any, Correction]:
        """:meth:`add` the frame, then return its pose corrected by the estimate (the flat pose minus its response
        to it, its reprojection RMS the residuals the estimate leaves: the corner noise, no longer the pattern of
        the shape and the lens) and how the TP (``tp``: m, board frame) and the orientation move with the
        parameters (drivers/base.py ``Correction``: its ``bias`` and ``bias_r`` the per-axis RMS, m and rad, of
        the error the estimate's uncertainty leaves them)."""
        residual, g = self.add(pose, observation, camera)
        value, covariance = self.estimate()
        shifts = pose_shifts(pose.rotation, pose.translation, observation.object_points, self.half, camera,
                             self.lens).T  # (6, p): turn, then the board's translation
        move = shifts @ value
        rotation = cv2.Rodrigues(-move[:3])[0] @ np.asarray(pose.rotation, dtype=float)
        left = residual - g @ value
        corrected = replace(pose, rotation=rotation, translation=np.asarray(pose.translation) - move[3:],
                            rms=float(np.sqrt(np.mean(left**2))))
        arm = rotation @ np.asarray(tp, dtype=float)  # the TP's lever in the camera frame: a turn ω moves it ω × arm
        cross = np.array([[0.0, arm[2], -arm[1]], [-arm[2], 0.0, arm[0]], [arm[1], -arm[0], 0.0]])  # ω -> ω × arm
        response = np.vstack([cross @ shifts[:3] + shifts[3:], shifts[:3]])  # (6, p): the TP (m), the turn (rad)
        correction = Correction(self.names, response, response @ value, value, covariance, 0.0, 0.0)
        bias, bias_r = correction.shares(covariance)
        return corrected, replace(correction, bias=bias, bias_r=bias_r)
