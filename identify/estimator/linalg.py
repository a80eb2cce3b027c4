"""Linear algebra on weighted Jacobians of many samples and few parameters (pure numpy)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import solve_triangular

Array = NDArray[np.float64]

RANK_RCOND = 1e-12  # relative singular value below which a column direction counts as absent


def _column_scale(a: Array) -> Array:
    """Euclidean norm of each column of ``a`` (N, p), at least 1e-300 (summed without an (N, p) temporary)."""
    return np.maximum(np.sqrt(np.einsum("ij,ij->j", a, a)), 1e-300)


GRAM_CONDITION = 1e10  # below this condition number of JᵀJ (1e5 of J) the Gram matrix loses < 1e-6 relative


def _r_factor(a: Array, scale: Array | None = None) -> Array:
    """An upper triangle R (p, p) with RᵀR = bᵀb for b = ``a`` (N, p) with its columns divided by ``scale`` (p,)
    (None: b = a), N >= p: the Cholesky factor of the Gram matrix when it is well conditioned (one BLAS product,
    tens of times faster than a QR of a tall matrix), else the R of a Householder QR (exact to rounding at any
    condition). b itself is never formed."""
    scale = np.ones(a.shape[1]) if scale is None else scale
    gram = (a.T @ a) / np.outer(scale, scale)
    eig = np.linalg.eigvalsh(gram)
    if eig[0] > eig[-1] / GRAM_CONDITION:
        return np.linalg.cholesky(gram).T
    return _stacked_r(a) / scale


QR_ROWS = 8192  # rows per block of :func:`_stacked_r` (a block's QR stays in cache)


def _stacked_r(a: Array) -> Array:
    """The R of a Householder QR of ``a`` (N, p) (up to the signs of its rows), block by block: the R factors of
    blocks of rows stacked and factored again (a tall-skinny QR; each block's QR in cache, where one QR of the whole
    runs at memory speed)."""
    if a.shape[0] <= 2 * QR_ROWS:
        return np.linalg.qr(a, mode="r")
    blocks = [np.linalg.qr(a[start:start + QR_ROWS], mode="r") for start in range(0, a.shape[0], QR_ROWS)]
    return np.linalg.qr(np.vstack(blocks), mode="r")



def residual_maker(a: Array) -> Callable[[Array], Array]:
    """The map ``v -> v - P v`` (``v`` (N,) or (N, k)), ``P`` the orthogonal projector on the columns of ``a``
    (N, p), N >= p: through the Cholesky factor of the scaled columns' Gram matrix when it is well conditioned (two
    BLAS products), else through an explicit orthonormal basis (Householder QR)."""
    scale = _column_scale(a)
    gram = (a.T @ a) / np.outer(scale, scale)  # of the columns scaled to unit norm, never formed
    eig = np.linalg.eigvalsh(gram)
    if eig[0] > eig[-1] / GRAM_CONDITION:
        lower = np.linalg.cholesky(gram)

        def through_gram(v: Array) -> Array:
            column = scale if v.ndim == 1 else scale[:, None]
            inner = solve_triangular(lower, (a.T @ v) / column, lower=True, check_finite=False)
            step = solve_triangular(lower, inner, lower=True, trans="T", check_finite=False)
            return v - a @ (step / column)
        return through_gram
    basis, _ = np.linalg.qr(a / scale)
    return lambda v: v - basis @ (basis.T @ v)

def _svd(a: Array, scale: Array) -> tuple[Array, Array]:
    """Singular values and right singular vectors (rows) of ``a`` (N, p) with its columns divided by ``scale``
    (p,), without its left vectors."""
    if a.shape[0] < a.shape[1]:
        _, s, vt = np.linalg.svd(a / scale, full_matrices=False)
        return s, vt
    _, s, vt = np.linalg.svd(_r_factor(a, scale))
    return s, vt


def column_basis(jac_blocks: Array) -> Array:
    """Orthonormal basis of the column space of ``jac_blocks`` (m, 3, p) (columns scaled to unit norm first),
    as (m, 3, rank): the hat matrix is ``U Uᵀ``."""
    m, _, p = jac_blocks.shape
    flat = jac_blocks.reshape(-1, p)
    scale = _column_scale(flat)
    s, vt = _svd(flat, scale)
    kept = s > RANK_RCOND * s[0]
    return (flat @ (vt[kept].T / s[kept] / scale[:, None])).reshape(m, 3, -1)


def scaled_inverse(flat: Array) -> tuple[Array, float]:
    """``(JᵀJ)⁻¹`` of ``flat`` (N, p) through the SVD of its unit-norm columns, and their condition number."""
    scale = _column_scale(flat)
    s, vt = _svd(flat, scale)
    inverse = (vt.T / np.maximum(s, 1e-300) ** 2) @ vt / np.outer(scale, scale)
    return inverse, float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


def project_out(jac_blocks: Array, rows: NDArray[np.int64], g: Array) -> None:
    """In place: each of ``rows`` of ``jac_blocks`` (m, 3, p) made orthogonal to its own direction ``g``
    (len(rows), 3), e.g. a nuisance parameter's column (the Schur complement / Kaufman projection)."""
    coef = np.einsum("ki,kip->kp", g, jac_blocks[rows]) / np.maximum(np.einsum("ki,ki->k", g, g), 1e-300)[:, None]
    jac_blocks[rows] -= g[:, :, None] * coef[:, None, :]


def triangle(a: Array, unit_columns: bool = False) -> Array:
    """A (p, p) matrix with the same column norms and inner products as ``a`` (N, p), N >= p (an R factor), or as
    ``a`` with its columns scaled to unit norm. Greedy column selections on it cost p² per column instead of N p."""
    return _r_factor(a, _column_scale(a) if unit_columns else None)
