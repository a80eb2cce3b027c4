"""Linear algebra on tall matrices (many samples, few parameters)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def thin_svd(a: Array, left: bool = True) -> tuple[Array | None, Array, Array]:
    """``(u, s, vt)`` of ``a`` (N, p), as ``np.linalg.svd(a, full_matrices=False)``; ``u`` is None unless
    ``left`` (LAPACK's divide and conquer reduces a tall matrix by QR first: cheaper than a QR of our own)."""
    if not left:
        _, s, vt = np.linalg.svd(a, full_matrices=False)
        return None, s, vt
    return np.linalg.svd(a, full_matrices=False)


def triangle(a: Array) -> Array:
    """A (p, p) matrix with the same column norms and inner products as ``a`` (N, p): ``S Vᵀ`` of its SVD.
    Greedy column selections on it cost p² per column instead of N p."""
    _, s, vt = np.linalg.svd(a, full_matrices=False)
    return s[:, None] * vt
