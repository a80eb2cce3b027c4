"""The forward model: standard DH chain, base transform and tracked point (TP).

``T(q) = base · A_1(q_1) · … · A_n(q_n)`` with
``A_i = Rz(theta_i + q_i if R) · Tz(d_i + q_i if P) · Tx(a_i) · Rx(alpha_i)``
and the predicted TP ``p(q) = T(q) · [tool, 1]``, in the tracker's frame, metres.

Everything here is vectorised over samples: ``q`` has shape (m, n).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

DH_NAMES = ("theta", "d", "a", "alpha")


def check_joint_types(joint_types: str) -> str:
    """Return ``joint_types`` upper-cased, or raise ValueError unless it is a non-empty string of R/P."""
    types = joint_types.strip().upper()
    if not types or set(types) - {"R", "P"}:
        raise ValueError(f"joint types must be a string of R and P, e.g. RRRRRR; got {joint_types!r}")
    return types


@dataclass(frozen=True)
class DHModel:
    """A serial chain in standard DH with base transform and tracked point.

    ``theta``, ``alpha`` in radians; ``d``, ``a`` in metres (all shape (n,)).
    ``base``: 4x4, tracker frame <- DH frame 0. ``tool``: TP in the last joint's DH frame n, metres.
    """

    joint_types: str
    theta: Array
    d: Array
    a: Array
    alpha: Array
    base: Array = field(default_factory=lambda: np.eye(4))
    tool: Array = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        types = check_joint_types(self.joint_types)
        n = len(types)
        object.__setattr__(self, "joint_types", types)
        for name in DH_NAMES:
            value = np.array(getattr(self, name), dtype=float).reshape(-1)
            if value.shape != (n,):
                raise ValueError(f"DH '{name}' has {value.size} values for {n} joints")
            object.__setattr__(self, name, value)
        base = np.array(self.base, dtype=float)
        if base.shape != (4, 4):
            raise ValueError("base must be a 4x4 matrix")
        object.__setattr__(self, "base", base)
        tool = np.array(self.tool, dtype=float).reshape(-1)
        if tool.shape != (3,):
            raise ValueError("tool must have 3 values")
        object.__setattr__(self, "tool", tool)

    @property
    def n_joints(self) -> int:
        return len(self.joint_types)

    @property
    def revolute(self) -> NDArray[np.bool_]:
        return np.array([t == "R" for t in self.joint_types])

    def dh_table(self) -> Array:
        """(n, 4) array with columns theta, d, a, alpha."""
        return np.column_stack([self.theta, self.d, self.a, self.alpha])

    def with_dh_table(self, table: ArrayLike) -> DHModel:
        table = np.asarray(table, dtype=float)
        return replace(self, theta=table[:, 0], d=table[:, 1], a=table[:, 2], alpha=table[:, 3])


def transform_from_dh(theta: ArrayLike, d: ArrayLike, a: ArrayLike, alpha: ArrayLike) -> Array:
    """Standard DH link transforms ``Rz(theta) Tz(d) Tx(a) Rx(alpha)``; broadcast shape (..., 4, 4)."""
    theta, d, a, alpha = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (theta, d, a, alpha)))
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
    out = np.zeros((*theta.shape, 4, 4))
    out[..., 0, 0] = ct
    out[..., 0, 1] = -st * ca
    out[..., 0, 2] = st * sa
    out[..., 0, 3] = a * ct
    out[..., 1, 0] = st
    out[..., 1, 1] = ct * ca
    out[..., 1, 2] = -ct * sa
    out[..., 1, 3] = a * st
    out[..., 2, 1] = sa
    out[..., 2, 2] = ca
    out[..., 2, 3] = d
    out[..., 3, 3] = 1.0
    return out


def _as_joints(model: DHModel, q: ArrayLike) -> Array:
    q = np.asarray(q, dtype=float)
    if q.ndim == 1:
        q = q[None, :]
    if q.ndim != 2 or q.shape[1] != model.n_joints:
        raise ValueError(f"joint readings must have shape (m, {model.n_joints}); got {q.shape}")
    return q


def link_transforms(model: DHModel, q: ArrayLike) -> Array:
    """A_i(q_i) for every sample and joint, shape (m, n, 4, 4)."""
    q = _as_joints(model, q)
    rev = model.revolute
    theta = model.theta + np.where(rev, q, 0.0)
    d = model.d + np.where(rev, 0.0, q)
    return transform_from_dh(theta, d, model.a, model.alpha)


def frames_from_joints(model: DHModel, q: ArrayLike) -> Array:
    """DH frames 0..n in the tracker frame for each sample, shape (m, n+1, 4, 4)."""
    links = link_transforms(model, q)
    m, n = links.shape[:2]
    frames = np.empty((m, n + 1, 4, 4))
    frames[:, 0] = model.base
    for i in range(n):
        frames[:, i + 1] = frames[:, i] @ links[:, i]
    return frames


def running_frames(model: DHModel, q: ArrayLike) -> Iterator[tuple[Array, Array, Array, Array]]:
    """DH frames 0..n in the tracker frame, one at a time, as their axes and origin (x, y, z, o), each
    (m, 3): what :func:`frames_from_joints` holds, without storing (m, n+1, 4, 4) (a few vector operations
    per joint, from A_i's sparsity)."""
    q = _as_joints(model, q)
    rev = model.revolute
    theta = model.theta + np.where(rev, q, 0.0)
    d = model.d + np.where(rev, 0.0, q)
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(model.alpha), np.sin(model.alpha)
    x, y, z, o = (np.broadcast_to(model.base[:3, k], (len(q), 3)) for k in range(4))
    yield x, y, z, o
    for i in range(model.n_joints):
        c, s = ct[:, i, None], st[:, i, None]
        x, y_turned = x * c + y * s, y * c - x * s  # rotated about z by theta
        o = o + x * model.a[i] + z * d[:, i, None]
        y, z = y_turned * ca[i] + z * sa[i], z * ca[i] - y_turned * sa[i]  # twisted about the new x by alpha
        yield x, y, z, o


def flange_frames(model: DHModel, q: ArrayLike) -> tuple[Array, Array]:
    """Frame n in the tracker frame for each sample: rotation (m, 3, 3) and origin (m, 3), metres."""
    *_, (x, y, z, o) = running_frames(model, q)
    return np.stack([x, y, z], axis=2), o


def points_from_joints(model: DHModel, q: ArrayLike) -> Array:
    """Predicted TP in the tracker frame, metres, shape (m, 3)."""
    *_, (x, y, z, o) = running_frames(model, q)
    return o + x * model.tool[0] + y * model.tool[1] + z * model.tool[2]


def model_to_dict(model: DHModel) -> dict[str, Any]:
    """The result contract's three keys (README.md, File contracts: ``joints``, ``base``, ``tool``) for ``model``,
    as plain data."""
    joints = [
        {"type": t, "a": float(a), "alpha": float(al), "d": float(d), "theta": float(th)}
        for t, th, d, a, al in zip(model.joint_types, model.theta, model.d, model.a, model.alpha, strict=True)
    ]
    return {"joints": joints, "base": np.asarray(model.base, dtype=float).tolist(),
            "tool": np.asarray(model.tool, dtype=float).tolist()}


def model_from_dict(doc: dict[str, Any]) -> DHModel:
    """Inverse of :func:`model_to_dict`; raises ValueError (one line) on a malformed document."""
    try:
        joints = doc["joints"]
        types = "".join(str(j["type"]) for j in joints)
        table = np.array([[float(j[name]) for name in DH_NAMES] for j in joints])
        return DHModel(types, table[:, 0], table[:, 1], table[:, 2], table[:, 3], doc["base"], doc["tool"])
    except (KeyError, TypeError, IndexError) as exc:
        raise ValueError(f"result document lacks or misshapes {exc}") from None
