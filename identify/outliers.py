"""Gross outliers among fitted samples: far from the model *and* from their neighbours along the arc.

A beam break or a wrong reflector gives one sample far from every model. Errors a DH table cannot hold
(gear ratio, eccentricity, compliance) give residuals that are systematic along each arc: large, but
shared by neighbouring samples. Only the first are outliers. So a sample is rejected when

1. its studentised residual (divided by sqrt(1 - leverage), so thin sweeps' well-fitted samples are not
   judged by the scale of the others) fails the Bonferroni-corrected Hotelling test of
   :func:`identify.refine.inlier_mask`, and
2. within its sweep, it also differs from the mean of its nearest accepted neighbours (ordered by the
   moved joint's value) by more than the noise of successive differences allows, at the same per-sample
   false-alarm rate. Free poses have no neighbours; for them the first test decides.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from identify.refine import NOISE_FLOOR, OUTLIER_PROBABILITY, inlier_mask

Array = NDArray[np.float64]


def leverages(jac_blocks: Array, unknown: NDArray[np.int64]) -> Array:
    """Mean leverage per sample (m,): trace of its 3x3 block of the hat matrix / 3, including the row's
    own nuisance parameter where its joint was not read. ``jac_blocks`` (m, 3, p) are weighted and
    already projected on the nuisance complement."""
    m, _, p = jac_blocks.shape
    j = jac_blocks.reshape(-1, p)
    scale = np.maximum(np.linalg.norm(j, axis=0), 1e-300)
    u, s, _ = np.linalg.svd(j / scale, full_matrices=False)
    u = u[:, s > 1e-12 * s[0]].reshape(m, 3, -1)
    return (np.einsum("kir,kir->k", u, u) + (unknown >= 0)) / 3.0


def sweep_neighbours(group: NDArray[np.int64], key: Array) -> list[NDArray[np.int64]]:
    """Rows of each sweep (``group`` >= 1), ordered by ``key`` (the moved joint's value)."""
    out = []
    for g in np.unique(group[group > 0]):
        rows = np.flatnonzero(group == g)
        out.append(rows[np.argsort(key[rows], kind="stable")])
    return out


def difference_scale(res: Array, runs: list[NDArray[np.int64]]) -> Array:
    """Robust per-axis noise (3,) from successive differences along each sweep (weighted units): smooth
    systematic residuals cancel in them, gross errors do not move a median."""
    diffs = [res[r[1:]] - res[r[:-1]] for r in runs if len(r) > 1]
    if not diffs:
        return np.full(3, np.nan)
    d = np.vstack(diffs)
    return 1.4826 * np.median(np.abs(d), axis=0) / np.sqrt(2.0)


def outlier_free(res: Array, leverage: Array, group: NDArray[np.int64], key: Array) -> NDArray[np.bool_]:
    """Mask of the samples kept: see the module docstring. ``res`` (m, 3) weighted residuals."""
    lev = np.clip(leverage, 0.0, 0.99)
    keep = inlier_mask(res / np.sqrt(1.0 - lev)[:, None], 0)
    if np.all(keep):
        return keep
    runs = sweep_neighbours(group, key)
    scale = np.maximum(difference_scale(res, runs), NOISE_FLOOR)
    limit = chi2.isf(OUTLIER_PROBABILITY / len(res), 3)
    for run in runs:
        bad = ~keep[run]
        if not np.any(bad) or np.all(bad):
            continue
        good = np.flatnonzero(~bad)
        for pos in np.flatnonzero(bad):
            left, right = good[good < pos], good[good > pos]
            nbrs = [run[v[i]] for v, i in ((left, -1), (right, 0)) if len(v)]
            expected = np.mean(res[nbrs], axis=0)
            spread = 1.0 + 1.0 / len(nbrs)  # variance of the difference, in units of the noise
            e = (res[run[pos]] - expected) / scale
            if float(e @ e) / spread <= limit:
                keep[run[pos]] = True  # it moves with its neighbours: systematic, not gross
    return keep
