"""The optimal design of free poses: the information a set of poses gives about the parameters the data determine,
and the greedy choice of the poses that most reduce the predicted held-out error (the Cramér-Rao bound of
identify/estimator/bounds.py).

Pure numpy on the nominal model; joint values rad / m. Used by the planners (acquire/planning/plan.py,
acquire/planning/plan_continuous.py) and the dry run's accuracy prediction (acquire/planning/plan_report.py).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from identify.estimator.dh_vector import full_jacobian
from kinematics.dh import DHModel

Array = NDArray[np.float64]

SUBSPACE_TOL = 1e-7  # relative singular value below which a parameter combination counts as redundant


def gram(g: Array, block: int = 48) -> Array:
    """``sum_k g_kᵀ g_k`` over the poses of ``g`` (m, 3, r): the (r, r) information of those TPs.

    Summed over stacked small blocks: a multithreaded BLAS on one tall product is many times slower
    on a busy machine (here: 10-20 ms against 1-2 ms)."""
    flat = g.reshape(-1, g.shape[2])
    pad = (-len(flat)) % block
    if pad:
        flat = np.vstack([flat, np.zeros((pad, flat.shape[1]))])
    blocks = flat.reshape(-1, block, flat.shape[1])
    return (np.swapaxes(blocks, 1, 2) @ blocks).sum(axis=0)


def whitened(model: DHModel, *qs: Array) -> list[Array]:
    """Jacobians (m_i, 3, r) of the TP at each pose set w.r.t. the parameter combinations they determine.

    The columns of the full Jacobian (:func:`identify.estimator.dh_vector.full_jacobian`) are scaled to unit norm over
    all sets, then projected on the eigenvectors of the information of all sets whose singular value is
    above ``SUBSPACE_TOL`` of the largest: redundant combinations (which change no prediction; on the
    nominal models they sit below 1e-15, the others above 1e-3) drop out. A small Gram matrix and its
    eigendecomposition rather than an SVD of the tall Jacobian: fast on a busy machine too.
    """
    jacs = [full_jacobian(model, q)[1] if len(q) else np.zeros((0, 3, 9 + 4 * model.n_joints)) for q in qs]
    information = sum(gram(j) for j in jacs)
    scale = np.sqrt(np.maximum(np.diag(information), 1e-300))
    values, vectors = np.linalg.eigh(information / np.outer(scale, scale))
    keep = values > SUBSPACE_TOL**2 * values[-1]
    basis = vectors[:, keep] / scale[:, None]
    return [j @ basis for j in jacs]


def greedy_design(model: DHModel, q_fit: Array, candidates: Array, q_eval: Array, count: int,
                  accept: Callable[[int], bool] | None = None) -> NDArray[np.int64]:
    """Indices of ``count`` rows of ``candidates`` chosen one at a time, each the pose that most reduces the
    predicted held-out error given ``q_fit`` and those chosen before: the trace of the Cramér-Rao prediction
    covariance summed over ``q_eval``, ``sum_k tr(Jc_k Σ Jc_kᵀ)`` with ``Σ = (JᵀJ)⁻¹``.

    Rank-one (rank-three: one TP) updates of Σ keep it O(count · candidates · r²) for r parameters.
    Directions the fit leaves undetermined get a tiny ridge, so poses that determine them win first. With
    ``accept``, a best candidate it rejects is set aside and the next best taken (fewer than ``count`` when
    the candidates run out).
    """
    if count <= 0:
        return np.zeros(0, dtype=np.int64)
    g_fit, g_pool, g_eval = whitened(model, q_fit, candidates, q_eval)
    r = g_pool.shape[2]
    info = gram(g_fit)
    ridge = 1e-9 * max(float(np.trace(info)) / r, 1.0)
    cov = np.linalg.inv(info + ridge * np.eye(r))
    target = gram(g_eval)
    chosen: list[int] = []
    available = np.ones(len(candidates), dtype=bool)
    eye = np.eye(3)
    g_pool_t = np.swapaxes(g_pool, 1, 2)
    while len(chosen) < count and available.any():
        u = g_pool @ cov  # (K, 3, r): candidate rows weighted by the current covariance
        s = eye + u @ g_pool_t  # (K, 3, 3)
        w = (u @ target) @ np.swapaxes(u, 1, 2)  # (K, 3, 3)
        gain = np.trace(np.linalg.solve(s, w), axis1=1, axis2=2)
        gain[~available] = -np.inf
        k = int(np.argmax(gain))
        while accept is not None and not accept(k):
            available[k] = False
            gain[k] = -np.inf
            if not available.any():
                return np.array(chosen, dtype=np.int64)
            k = int(np.argmax(gain))
        cov = cov - u[k].T @ np.linalg.solve(s[k], u[k])
        cov = 0.5 * (cov + cov.T)
        chosen.append(k)
        available[k] = False
    return np.array(chosen, dtype=np.int64)
