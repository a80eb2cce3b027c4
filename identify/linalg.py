"""Linear algebra on weighted Jacobians of many samples and few parameters (pure numpy)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

RANK_RCOND = 1e-12  # relative singular value below which a column direction counts as absent


def _column_scale(a: Array) -> Array:
    return np.maximum(np.linalg.norm(a, axis=0), 1e-300)


def column_basis(jac_blocks: Array) -> Array:
    """Orthonormal basis of the column space of ``jac_blocks`` (m, 3, p) (columns scaled to unit norm first),
    as (m, 3, rank): the hat matrix is ``U Uᵀ``."""
    m, _, p = jac_blocks.shape
    flat = jac_blocks.reshape(-1, p)
    u, s, _ = np.linalg.svd(flat / _column_scale(flat), full_matrices=False)
    return u[:, s > RANK_RCOND * s[0]].reshape(m, 3, -1)


def scaled_inverse(flat: Array) -> tuple[Array, float]:
    """``(JᵀJ)⁻¹`` of ``flat`` (N, p) through the SVD of its unit-norm columns, and their condition number."""
    scale = _column_scale(flat)
    _, s, vt = np.linalg.svd(flat / scale, full_matrices=False)
    inverse = (vt.T / np.maximum(s, 1e-300) ** 2) @ vt / np.outer(scale, scale)
    return inverse, float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


def project_out(jac_blocks: Array, rows: NDArray[np.int64], g: Array) -> None:
    """In place: each of ``rows`` of ``jac_blocks`` (m, 3, p) made orthogonal to its own direction ``g``
    (len(rows), 3), e.g. a nuisance parameter's column (the Schur complement / Kaufman projection)."""
    coef = np.einsum("ki,kip->kp", g, jac_blocks[rows]) / np.maximum(np.einsum("ki,ki->k", g, g), 1e-300)[:, None]
    jac_blocks[rows] -= g[:, :, None] * coef[:, None, :]


def triangle(a: Array) -> Array:
    """A (p, p) matrix with the same column norms and inner products as ``a`` (N, p): ``S Vᵀ`` of its SVD.
    Greedy column selections on it cost p² per column instead of N p."""
    _, s, vt = np.linalg.svd(a, full_matrices=False)
    return s[:, None] * vt
