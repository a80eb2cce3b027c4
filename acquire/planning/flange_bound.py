"""The accuracy a flange camera's plan can reach: a Cramér-Rao bound of the flange's position (pure).

The fit (identify/sensors/flange.py) takes each view as the camera's view point and axes in the board frame, with a
position sigma and a turn sigma_r. The bound builds the same rows at the plan's fitted views on the nominal model:
the parameters are the DH table (4 n), the camera's mount (flange <- camera, 6) and the board's place (base <-
board, 6); each view's sigmas come from the board's corners projected into the image (the pose's sensitivity to
its corners, drivers/camera/pose.py ``Pose.pose_covariance``) for a corner noise ``sigma_px`` (pixels per coordinate,
each reading the mean of ``frames`` images), the lever to the view point added as the fit adds it. Predicted: the RMS
position error of the flange (the point fixed to the camera at the flange's origin, in the board frame) at the fit
views and at random poses over the joint ranges, from ``pinv(JᵀJ)`` (the gauge directions, e.g. the last link's
twist against the mount's, change no prediction). Only the camera's noise: the arm's departures from its DH model and
the board's own errors are not in it. Units: metres, radians, pixels.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from drivers.camera.pose import Pose
from identify.simulators.simulate import random_poses
from kinematics.dh import DHModel, frames_from_joints

Array = NDArray[np.float64]

DRY_SIGMA_PX = 0.1  # pixels: the corner noise a dry run assumes before the camera has been seen (rendered: 0.03-0.1)
EVAL_POSES = 300  # random poses over the joint ranges at which the flange is predicted
STEP = 1e-6  # finite-difference step (m, rad)


def view_sigmas(points: Array, matrix: Array, views: Array, sigma_px: float, frames: int) -> tuple[Array, Array]:
    """Per view (k,): the stated position sigma (m per axis, the board's origin in the camera frame) and turn sigma
    (rad per axis) of a reading of ``frames`` images with corner noise ``sigma_px``, the board's ``points`` (M, 3,
    board frame) seen at ``views`` (k, 4, 4; camera <- board) through the camera ``matrix`` (3x3)."""
    sigma, sigma_r = [], []
    for view in views:
        rvec = cv2.Rodrigues(view[:3, :3])[0]
        _, jac = cv2.projectPoints(points, rvec, view[:3, 3], matrix, np.zeros(5))
        pose = Pose(view[:3, :3], view[:3, 3], 0.0, len(points), jac[:, :6].astype(float))
        cov = pose.pose_covariance(sigma_px) / frames
        sigma.append(math.sqrt(float(np.trace(cov[3:, 3:])) / 3))
        sigma_r.append(math.sqrt(float(np.trace(pose.orientation_covariance(sigma_px))) / 3 / frames))
    return np.array(sigma), np.array(sigma_r)


def corner_noise(points: Array, matrix: Array, views: Array, stated_r: Array, frames: int) -> float:
    """The corner noise (pixels) that gives the camera's stated turn sigmas ``stated_r`` (k,) rad at ``views`` (the
    locate phase's readings): the median ratio to :func:`view_sigmas` at one pixel."""
    unit = view_sigmas(points, matrix, views, 1.0, frames)[1]
    return float(np.median(np.asarray(stated_r, dtype=float) / unit))


def _perturbed(model: DHModel, mount: Array, board: Array, p: Array) -> tuple[DHModel, Array, Array]:
    n = model.n_joints
    table = model.dh_table() + p[: 4 * n].reshape(n, 4)
    x, b = mount.copy(), board.copy()
    x[:3, :3] = Rotation.from_rotvec(p[4 * n: 4 * n + 3]).as_matrix() @ mount[:3, :3]
    x[:3, 3] += p[4 * n + 3: 4 * n + 6]
    b[:3, :3] = Rotation.from_rotvec(p[4 * n + 6: 4 * n + 9]).as_matrix() @ board[:3, :3]
    b[:3, 3] += p[4 * n + 9:]
    return model.with_dh_table(table), x, b


def _jacobian(function: Callable[[Array], Array], size: int) -> Array:
    zero = function(np.zeros(size))
    out = np.empty((zero.size, size))
    for k in range(size):
        step = np.zeros(size)
        step[k] = STEP
        out[:, k] = (function(step) - function(-step)) / (2 * STEP)
    return out


def flange_bound(model: DHModel, mount: Array, board: Array, q_fit: Array, points: Array, matrix: Array,
                 sigma_px: float, frames: int, limits: Array, rng_seed: int = 1) -> dict[str, float]:
    """The bound (module docstring) of the plan's fitted views ``q_fit`` (k, n) for ``model`` (base and tool not
    used), ``mount`` (flange <- camera), ``board`` (base <- board): keys ``fit_rms`` and ``random_rms`` (m),
    ``sigma_px``, ``sigma_median`` (m) and ``sigma_r_median`` (rad) of the views, ``eval_poses``."""
    q_fit = np.atleast_2d(np.asarray(q_fit, dtype=float))
    cameras = frames_from_joints(model, q_fit)[:, -1] @ mount
    views = np.einsum("kij,jl->kil", np.linalg.inv(cameras), board)  # camera <- board
    sigma, sigma_r = view_sigmas(points, matrix, views, sigma_px, frames)
    c = np.median(views[:, :3, 3], axis=0)  # the view point, camera frame (identify/sensors/flange.py)
    sigma_v = np.sqrt(sigma**2 + (2.0 / 3.0) * np.sum((views[:, :3, 3] - c) ** 2, axis=1) * sigma_r**2)
    size = 4 * model.n_joints + 12
    at_c = np.append(c, 1.0)
    flange_in_camera = np.linalg.inv(mount)[:, 3]

    def rows(p: Array) -> Array:
        m, x, b = _perturbed(model, mount, board, p)
        seen = np.einsum("ij,kjl->kil", np.linalg.inv(b), frames_from_joints(m, q_fit)[:, -1] @ x)  # board <- cam
        position = (seen @ at_c)[:, :3] / sigma_v[:, None]
        turn = Rotation.from_matrix(seen[:, :3, :3] @ np.swapaxes(np.einsum("ij,kjl->kil", np.linalg.inv(board),
                                    cameras)[:, :3, :3], 1, 2)).as_rotvec() / sigma_r[:, None]
        return np.concatenate([position.ravel(), turn.ravel()])

    def flange_at(q: Array) -> Callable[[Array], Array]:
        def point(p: Array) -> Array:
            m, x, b = _perturbed(model, mount, board, p)
            return np.einsum("ij,kjl,l->ki", np.linalg.inv(b), frames_from_joints(m, q)[:, -1] @ x,
                             flange_in_camera)[:, :3].ravel()
        return point

    jac = _jacobian(rows, size)
    cov = np.linalg.pinv(jac.T @ jac, rcond=1e-12)
    q_eval = random_poses(np.asarray(limits, dtype=float), EVAL_POSES, np.random.default_rng(rng_seed))

    def rms(q: Array) -> float:
        g = _jacobian(flange_at(q), size)
        return math.sqrt(float(np.einsum("ij,jk,ik->", g, cov, g)) / len(q))

    return {"fit_rms": rms(q_fit), "random_rms": rms(q_eval), "sigma_px": float(sigma_px),
            "sigma_median": float(np.median(sigma)), "sigma_r_median": float(np.median(sigma_r)),
            "eval_poses": float(EVAL_POSES)}
