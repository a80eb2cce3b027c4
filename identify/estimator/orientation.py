"""Orientations of a measured target frame (6-DoF probes, camera targets): the rotation algebra the fit needs.

A full-pose reading gives the target frame's rotation ``R`` (3, 3) in the tracker frame besides its origin. Its
residual against a predicted rotation ``P`` is the rotation vector ``log(P Rᵀ)`` (rad, tracker frame: the small turn
that takes the measured frame onto the predicted one). A left perturbation ``exp(δφ) P`` moves it by
``J_l⁻¹(r) δφ`` (:func:`inverse_left_jacobians`). Pure numpy/scipy: arrays in, arrays out.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from identify.estimator.geometry import skew

Array = NDArray[np.float64]

SMALL_ANGLE = 1e-6  # rad: below it the series of the Jacobians' coefficients are used


def matrices_from_rotvecs(rotvec: Array) -> Array:
    """Rotation matrices (m, 3, 3) of rotation vectors (m, 3) (axis times angle, rad); NaN rows give NaN."""
    rotvec = np.asarray(rotvec, dtype=float).reshape(-1, 3)
    out = np.full((len(rotvec), 3, 3), np.nan)
    given = np.all(np.isfinite(rotvec), axis=1)
    if np.any(given):
        out[given] = Rotation.from_rotvec(rotvec[given]).as_matrix()
    return out


def rotvecs_from_matrices(rotations: Array) -> Array:
    """Rotation vectors (m, 3), rad, of rotation matrices (m, 3, 3)."""
    return Rotation.from_matrix(np.asarray(rotations, dtype=float).reshape(-1, 3, 3)).as_rotvec()


def rotation_residuals(predicted: Array, measured: Array) -> Array:
    """``log(predicted · measuredᵀ)`` (m, 3), rad, tracker frame, for rotations (m, 3, 3) each."""
    return rotvecs_from_matrices(predicted @ np.swapaxes(measured, 1, 2))


def left_jacobians(phi: Array) -> Array:
    """Left Jacobians (m, 3, 3) of SO(3) at rotation vectors ``phi`` (m, 3): d exp(phi) = (J_l(phi) dphi)^ exp(phi)."""
    phi = np.asarray(phi, dtype=float).reshape(-1, 3)
    angle = np.linalg.norm(phi, axis=1)
    small = angle < SMALL_ANGLE
    safe = np.where(small, 1.0, angle)
    a = np.where(small, 0.5 - angle**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    b = np.where(small, 1.0 / 6.0 - angle**2 / 120.0, (safe - np.sin(safe)) / safe**3)
    k = skew(phi)
    return np.eye(3) + a[:, None, None] * k + b[:, None, None] * (k @ k)


def inverse_left_jacobians(phi: Array) -> Array:
    """Inverses (m, 3, 3) of :func:`left_jacobians`: ``I - [phi]/2 + c [phi]²``, valid below a half turn."""
    phi = np.asarray(phi, dtype=float).reshape(-1, 3)
    angle = np.linalg.norm(phi, axis=1)
    small = angle < SMALL_ANGLE
    safe = np.where(small, 1.0, angle)
    c = np.where(small, 1.0 / 12.0 + angle**2 / 720.0,
                 1.0 / safe**2 - (1.0 + np.cos(safe)) / (2.0 * safe * np.sin(np.minimum(safe, np.pi - 1e-9))))
    k = skew(phi)
    return np.eye(3) - 0.5 * k + c[:, None, None] * (k @ k)


def mean_rotation(rotations: Array) -> Array:
    """The chordal mean (3, 3) of rotations (m, 3, 3): the rotation nearest their arithmetic mean (SVD)."""
    u, _, vt = np.linalg.svd(np.mean(np.asarray(rotations, dtype=float), axis=0))
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt
