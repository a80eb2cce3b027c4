"""Cramér-Rao bounds for predicted TP positions: the accuracy no calibration of the same data can beat, which
plans, verdicts and benchmarks are measured against (docs/method.md, "How far to trust it").

For isotropic tracker noise ``sigma`` (m per axis) and fitted joint readings ``q_fit``, the covariance
of any unbiased estimate of the model's prediction at ``q_check`` is at least
``sigma² · Jc · pinv(JᵀJ) · Jcᵀ``, with J the Jacobian of all predicted TPs with respect to all model
parameters. Redundant parameters (pinv's null space) do not change the predictions, so the bound
does not depend on which are fixed.

Full-pose data (:func:`full_pose_jacobian`): each sample also measures the target frame's orientation with
isotropic noise ``sigma_r`` (rad per axis); its rows join the positions', each kind whitened by its own noise, and the
target frame's turn in frame n (3 parameters) joins the model's.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from identify.estimator.dh_vector import full_jacobian, orientation_jacobian
from kinematics.dh import DHModel

Array = NDArray[np.float64]

RCOND = 1e-9  # relative singular value below which a direction counts as undetermined


def prediction_covariances(
    model: DHModel, q_fit: Array, q_check: Array, sigma: float, weights: Array | None = None
) -> Array:
    """Lower bound on the covariance (k, 3, 3) of predicted TPs at ``q_check``, m².

    ``weights`` (m,) = 1/sigma_k relative to ``sigma`` for samples of unequal uncertainty.
    """
    _, jac = full_jacobian(model, q_fit)
    if weights is not None:
        jac = jac * np.asarray(weights, dtype=float)[:, None, None]
    j = jac.reshape(-1, jac.shape[2])
    scale = np.maximum(np.linalg.norm(j, axis=0), 1e-300)
    _, s, vt = np.linalg.svd(j / scale, full_matrices=False)
    keep = s > RCOND * s[0]
    _, jac_check = full_jacobian(model, q_check)
    # Jc D^-1 V S^-1: rows are the check predictions' sensitivities to the whitened parameters
    g = (jac_check / scale) @ (vt[keep].T / s[keep])
    return sigma**2 * (g @ np.swapaxes(g, 1, 2))


def prediction_rms_bound(model: DHModel, q_fit: Array, q_check: Array, sigma: float) -> float:
    """Cramér-Rao bound on the RMS 3D error (m) of predicted TPs at ``q_check`` (vs the truth)."""
    cov = prediction_covariances(model, q_fit, q_check, sigma)
    return float(np.sqrt(np.mean(np.trace(cov, axis1=1, axis2=2))))


def full_pose_jacobian(model: DHModel, q: Array, sigma: float, sigma_r: float | None = None,
                       weights: tuple[Array, Array] | None = None) -> Array:
    """Whitened Jacobian (m·3 or m·6, 9 + 4n + 3) of the samples at ``q`` (m, n) over the full DH vector and the turn
    of the target frame in frame n: positions divided by ``sigma`` (m), then, with ``sigma_r`` (rad), the target
    frame's orientations by ``sigma_r`` (the frame's turn moves the orientation alone). ``weights``: per sample (m,)
    each, the position's and the orientation's ``sigma / sigma_k`` and ``sigma_r / sigma_r_k`` for samples of unequal
    uncertainty (0: that sample has no such measurement)."""
    _, jac = full_jacobian(model, q)
    out = np.zeros((len(q), 3, jac.shape[2] + 3))
    out[:, :, : jac.shape[2]] = jac / sigma
    if weights is not None:
        out *= np.asarray(weights[0], dtype=float)[:, None, None]
    if sigma_r is None:
        return out.reshape(-1, out.shape[2])
    rotation, turns = orientation_jacobian(model, q)
    rows = np.zeros_like(out)
    rows[:, :, : jac.shape[2]] = turns / sigma_r
    rows[:, :, jac.shape[2]:] = rotation / sigma_r  # a turn of the target frame, expressed in frame n
    if weights is not None:
        rows *= np.asarray(weights[1], dtype=float)[:, None, None]
    return np.vstack([out, rows]).reshape(-1, out.shape[2])


def full_pose_covariance(model: DHModel, q_fit: Array, sigma: float, sigma_r: float | None,
                         free: NDArray[np.bool_]) -> Array:
    """Cramér-Rao bound on the covariance of the ``free`` full-vector values (the rest held at their conventions,
    as the estimator holds them), for samples at ``q_fit`` with position noise ``sigma`` (m) and, with ``sigma_r``
    (rad), orientations of the target frame: (free, free), m² / rad²."""
    jac = full_pose_jacobian(model, q_fit, sigma, sigma_r)
    keep = np.concatenate([free, [sigma_r is not None] * 3])
    j = jac[:, keep]
    scale = np.maximum(np.linalg.norm(j, axis=0), 1e-300)
    inverse = np.linalg.pinv((j / scale).T @ (j / scale), rcond=RCOND) / np.outer(scale, scale)
    n = int(np.sum(free))
    return inverse[:n, :n]


def full_pose_rms_bound(model: DHModel, q_fit: Array, q_check: Array, sigma: float, sigma_r: float | None,
                        offset: Array | None = None, weights: tuple[Array, Array] | None = None) -> float:
    """Cramér-Rao bound on the RMS 3D error (m) of a predicted point at ``q_check``: the tracked point, or with
    ``offset`` (3,) the point fixed to the target at that offset from the tracked point (m, axes of the last DH
    frame: the target frame's rotation times the offset in its own axes), whose prediction needs the target frame's
    orientation: the bound counts the uncertainty of its turn. Samples at ``q_fit`` (positions, and orientations
    with ``sigma_r``; without them the turn is undetermined and an ``offset`` bound means nothing); ``weights`` as in
    :func:`full_pose_jacobian`."""
    jac = full_pose_jacobian(model, q_fit, sigma, sigma_r, weights)
    scale = np.maximum(np.linalg.norm(jac, axis=0), 1e-300)
    _, s, vt = np.linalg.svd(jac / scale, full_matrices=False)
    keep = s > RCOND * s[0]
    _, jac_check = full_jacobian(model, q_check)
    g = np.zeros((len(q_check), 3, jac.shape[1]))
    g[:, :, : jac_check.shape[2]] = jac_check
    if offset is not None:
        rotation, turns = orientation_jacobian(model, q_check)
        lever = rotation @ np.asarray(offset, dtype=float)  # the offset in the tracker frame (target frame = frame n)
        arm = -np.einsum("kij,kjp->kip", _skew(lever), turns)  # a turn w moves the point by w x lever
        g[:, :, : jac_check.shape[2]] += arm
        g[:, :, jac_check.shape[2]:] = -_skew(lever) @ rotation
    g = (g / scale) @ (vt[keep].T / s[keep])
    return float(np.sqrt(np.mean(np.sum(g**2, axis=(1, 2)))))


def _skew(v: Array) -> Array:
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out
