"""The full parameter vector of a DH model and its Jacobian.

Parameters, in this order: base rotation (3, a rotation vector applied on the left of the start base rotation),
base translation (3, m), tool (3, m, in DH frame n), then per joint theta, d, a, alpha (rad, m, m, rad). Used by the
refinement (:mod:`identify.estimator.refine`) and by everything that speaks of the DH values one by one.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from identify.estimator.geometry import cross, left_jacobian, skew
from kinematics.dh import DH_NAMES, DHModel, points_from_joints, running_frames

Array = NDArray[np.float64]

BASE_NAMES = ("base.rx", "base.ry", "base.rz", "base.x", "base.y", "base.z")
TOOL_NAMES = ("tool.x", "tool.y", "tool.z")


def parameter_names(n: int) -> list[str]:
    """Names of the full parameter vector for ``n`` joints, e.g. ``theta3``, ``base.rx``."""
    return [*BASE_NAMES, *TOOL_NAMES, *(f"{name}{i}" for i in range(1, n + 1) for name in DH_NAMES)]


def dh_index(joint: int, name: str) -> int:
    """Index in the full vector of DH value ``name`` of 1-based ``joint``."""
    return 9 + 4 * (joint - 1) + DH_NAMES.index(name)


def model_from_vector(start: DHModel, vector: Array) -> DHModel:
    """The model at full parameter ``vector`` (base rotation relative to ``start.base``)."""
    base = np.eye(4)
    base[:3, :3] = Rotation.from_rotvec(vector[:3]).as_matrix() @ start.base[:3, :3]
    base[:3, 3] = vector[3:6]
    table = vector[9:].reshape(-1, 4)
    return replace(start.with_dh_table(table), base=base, tool=vector[6:9].copy())


def vector_from_model(model: DHModel) -> Array:
    """Full parameter vector of ``model`` with zero base rotation increment."""
    return np.concatenate([np.zeros(3), model.base[:3, 3], model.tool, model.dh_table().ravel()])


JACOBIAN_ROWS = 4096  # rows whose Jacobian is formed at once (its temporaries stay in cache: twice as fast)


def full_jacobian(model: DHModel, q: Array, omega: Array | None = None) -> tuple[Array, Array]:
    """Predicted TP (m, 3) and its Jacobian (m, 3, 9 + 4n) with respect to the full vector."""
    q = np.asarray(q, dtype=float)
    if len(q) <= JACOBIAN_ROWS:
        return _full_jacobian_rows(model, q, omega)
    p, jac = np.empty((len(q), 3)), np.empty((len(q), 3, 9 + 4 * model.n_joints))
    for start in range(0, len(q), JACOBIAN_ROWS):
        rows = slice(start, start + JACOBIAN_ROWS)
        p[rows], jac[rows] = _full_jacobian_rows(model, q[rows], omega)
    return p, jac


def _full_jacobian_rows(model: DHModel, q: Array, omega: Array | None) -> tuple[Array, Array]:
    """:func:`full_jacobian` of a block of rows."""
    m, n = len(q), model.n_joints
    p = points_from_joints(model, q)
    jac = np.zeros((m, 3, 9 + 4 * n))
    rel_base = p - model.base[:3, 3]
    jl = np.eye(3) if omega is None else left_jacobian(omega)
    jac[:, :, 0:3] = -skew(rel_base) @ jl
    jac[:, :, 3:6] = np.eye(3)
    frames = running_frames(model, q)
    _, _, z_prev, o_prev = next(frames)
    for i, frame in enumerate(frames):
        x_cur, _, z_cur, o_cur = frame
        col = 9 + 4 * i
        jac[:, :, col] = cross(z_prev, p - o_prev)
        jac[:, :, col + 1] = z_prev
        jac[:, :, col + 2] = x_cur
        jac[:, :, col + 3] = cross(x_cur, p - o_cur)
        z_prev, o_prev = z_cur, o_cur
    jac[:, :, 6:9] = np.stack(frame[:3], axis=2)  # the last frame's rotation
    return p, jac


def orientation_jacobian(model: DHModel, q: Array, omega: Array | None = None) -> tuple[Array, Array]:
    """Rotation of DH frame n (m, 3, 3) and the turn of it (m, 3, 9 + 4n; rad per unit of each full-vector parameter,
    tracker frame) at joint values ``q`` (m, n): a joint's theta turns it about z_{i-1}, its alpha about x_i, the base
    rotation (its increment ``omega``) as itself; lengths and the tool do not turn it."""
    q = np.asarray(q, dtype=float)
    n = model.n_joints
    jac = np.zeros((len(q), 3, 9 + 4 * n))
    jac[:, :, 0:3] = np.eye(3) if omega is None else left_jacobian(omega)
    frames = running_frames(model, q)
    _, _, z_prev, _ = next(frames)
    frame = None
    for i, frame in enumerate(frames):
        x_cur, _, z_cur, _ = frame
        jac[:, :, 9 + 4 * i] = z_prev
        jac[:, :, 9 + 4 * i + 3] = x_cur
        z_prev = z_cur
    rotation = np.stack(frame[:3], axis=2) if frame is not None else np.broadcast_to(model.base[:3, :3], (len(q), 3, 3))
    return rotation, jac


def prior_rows(free: NDArray[np.bool_], sigma: Array) -> Array:
    """Rows (k, free count) that measure each ``free`` value of the full vector with a finite ``sigma`` to that
    sigma: a prior's Jacobian (and its information, stacked with the data's)."""
    own = sigma[free]
    keep = np.flatnonzero(np.isfinite(own))
    out = np.zeros((len(keep), int(free.sum())))
    out[np.arange(len(keep)), keep] = 1.0 / own[keep]
    return out
