"""Joint values beyond the DH table: coupled readings and non-geometric joint errors (pure math).

**Coupling.** Controllers of many industrial arms report readings that are not the DH joint values (on
FANUC arms J3 is measured against the horizontal, so the DH value is q3 = J3 + J2). Linear coupling:
``q_dh = C · readings + offset`` (C (n, n), offset (n,), rad or m).

**Joint errors**: the joint really stands at ``q + Δq(q)``, with, per joint i,

- reading scale (gear-ratio error): ``Δq_i = s_i · q_i``
- once-per-turn error (encoder or gear eccentricity): ``Δq_i = e_i · sin(q_i) + f_i · cos(q_i)``
- compliance under gravity: ``Δq_i = c_i · τ_i(q)``, with ``τ_i`` the torque (N·m; N for a prismatic joint)
  gravity exerts about joint i's axis through the links beyond it (:func:`gravity_torques`).

``q`` here is the DH joint value (after coupling). Radians for revolute joints, metres for prismatic ones.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from kinematics.dh import DHModel, frames_from_joints

Array = NDArray[np.float64]

STANDARD_GRAVITY = 9.80665  # m/s²


@dataclass(frozen=True)
class Coupling:
    """``q_dh = matrix · readings + offset``; ``matrix`` (n, n) invertible, ``offset`` (n,)."""

    matrix: Array
    offset: Array

    def __post_init__(self) -> None:
        matrix = np.array(self.matrix, dtype=float)
        n = len(matrix)
        if matrix.ndim != 2 or matrix.shape != (n, n) or n == 0:
            raise ValueError(f"coupling must be a square n x n matrix; got shape {matrix.shape}")
        offset = np.zeros(n) if self.offset is None else np.array(self.offset, dtype=float).reshape(-1)
        if offset.shape != (n,):
            raise ValueError(f"coupling offset has {offset.size} values for {n} joints")
        if not (np.all(np.isfinite(matrix)) and np.all(np.isfinite(offset))):
            raise ValueError("coupling values must be finite numbers")
        if abs(np.linalg.det(matrix)) < 1e-9:
            raise ValueError("coupling matrix is singular: readings could not be recovered from joint values")
        object.__setattr__(self, "matrix", matrix)
        object.__setattr__(self, "offset", offset)

    @classmethod
    def identity(cls, n: int) -> Coupling:
        return cls(np.eye(n), np.zeros(n))

    @property
    def n_joints(self) -> int:
        return len(self.matrix)

    @property
    def is_identity(self) -> bool:
        return bool(np.array_equal(self.matrix, np.eye(self.n_joints)) and not np.any(self.offset))

    def dh_from_readings(self, readings: Array) -> Array:
        """DH joint values (m, n) from controller ``readings`` (m, n); NaN readings spread to every joint
        that uses them."""
        r = np.asarray(readings, dtype=float)
        finite = np.where(np.isnan(r), 0.0, r)
        q = finite @ self.matrix.T + self.offset
        uses_missing = (np.isnan(r).astype(float) @ (self.matrix != 0).T.astype(float)) > 0
        return np.where(uses_missing, np.nan, q)

    def readings_from_dh(self, q: Array) -> Array:
        """Controller readings (m, n) that give the DH joint values ``q`` (m, n)."""
        return np.linalg.solve(self.matrix, (np.asarray(q, dtype=float) - self.offset).T).T

    def coupled_groups(self) -> list[list[int]]:
        """0-based joints whose DH value depends on more than one reading: [[joint, readings...], ...]."""
        return [[i, *np.flatnonzero(self.matrix[i]).tolist()] for i in range(self.n_joints)
                if np.count_nonzero(self.matrix[i]) > 1]

    def as_dict(self) -> dict[str, object]:
        return {"matrix": self.matrix.tolist(), "offset": self.offset.tolist(),
                "equation": "q_dh = matrix · readings + offset"}


@dataclass(frozen=True)
class LinkMasses:
    """Link masses (n,) in kg and centres of mass (n, 3) in metres, link i's in DH frame i (the frame that
    moves with joint i). ``gravity`` (3,): the gravity vector in DH frame 0, m/s² (robot upright: -z)."""

    masses: Array
    centres: Array
    gravity: Array = field(default_factory=lambda: np.array([0.0, 0.0, -STANDARD_GRAVITY]))

    def __post_init__(self) -> None:
        masses = np.array(self.masses, dtype=float).reshape(-1)
        centres = np.array(self.centres, dtype=float).reshape(len(masses), 3)
        object.__setattr__(self, "masses", masses)
        object.__setattr__(self, "centres", centres)
        object.__setattr__(self, "gravity", np.array(self.gravity, dtype=float).reshape(3))


def gravity_torques(model: DHModel, links: LinkMasses, q: Array) -> Array:
    """Torque (N·m; force in N for a prismatic joint) that gravity exerts about (along) each joint's axis
    at DH joint values ``q`` (m, n), from the links beyond that joint: (m, n). Base transform ignored."""
    frames = frames_from_joints(replace(model, base=np.eye(4)), np.atleast_2d(q))  # (m, n+1, 4, 4)
    centres = np.einsum("mkij,kj->mki", frames[:, 1:, :3, :3], links.centres) + frames[:, 1:, :3, 3]
    weights = links.masses[:, None] * links.gravity  # (n, 3) force on each link
    n = model.n_joints
    torques = np.empty((len(frames), n))
    for i in range(n):  # joint i+1 turns about z of frame i
        axis, origin = frames[:, i, :3, 2], frames[:, i, :3, 3]
        force = weights[i:].sum(axis=0)
        if model.joint_types[i] == "P":
            torques[:, i] = axis @ force
        else:
            moment = np.cross(centres[:, i:] - origin[:, None, :], weights[i:]).sum(axis=1)
            torques[:, i] = np.einsum("mi,mi->m", moment, axis)
    return torques


TERMS = ("scale", "eccentricity", "compliance")


@dataclass(frozen=True)
class JointErrors:
    """Per-joint error coefficients (n,) each: ``scale`` (1), ``ecc_sin`` and ``ecc_cos`` (rad or m),
    ``compliance`` (rad/(N·m) or m/N). Zero means absent."""

    scale: Array
    ecc_sin: Array
    ecc_cos: Array
    compliance: Array

    @classmethod
    def none(cls, n: int) -> JointErrors:
        return cls(np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n))

    def corrections(self, q: Array, torques: Array | None = None) -> Array:
        """Δq (m, n) at DH joint values ``q`` (m, n); ``torques`` (m, n) from :func:`gravity_torques`,
        needed when any compliance is non-zero."""
        q = np.atleast_2d(q)
        dq = self.scale * q + self.ecc_sin * np.sin(q) + self.ecc_cos * np.cos(q)
        if np.any(self.compliance):
            if torques is None:
                raise ValueError("compliance needs the gravity torques at q")
            dq = dq + self.compliance * torques
        return dq


def regressors(term: str, q: Array, torques: Array | None = None) -> list[Array]:
    """Per-joint derivative of Δq with respect to each coefficient of ``term``: a list of (m, n) arrays
    (one per coefficient; two for eccentricity, sin then cos), to be multiplied by dp/dq_i."""
    if term == "scale":
        return [q]
    if term == "eccentricity":
        return [np.sin(q), np.cos(q)]
    if term == "compliance":
        if torques is None:
            raise ValueError("compliance needs the gravity torques at q")
        return [torques]
    raise ValueError(f"unknown joint-error term {term!r}; expected one of {', '.join(TERMS)}")
