"""Gross outliers among fitted samples: far from the model *and* from their neighbours along the arc.

A beam break or a wrong reflector gives one sample far from every model. Errors a DH table cannot hold
(gear ratio, eccentricity, compliance) give residuals that are systematic along each arc: large, but
shared by neighbouring samples. Only the first are outliers. So a sample is rejected when

1. its studentised residual (divided by sqrt(1 - leverage), so thin sweeps' well-fitted samples are not
   judged by the scale of the others) fails the Bonferroni-corrected Hotelling test of
   :func:`inlier_mask` (sweep rows and free poses on scales of their own: model error
   grows away from home, where the free poses are), and
2. within its sweep (ordered by the moved joint's value), it also departs from the straight line through
   its two neighbours by more than the noise of such second differences allows, at the same per-sample
   false-alarm rate: a smooth systematic residual follows its neighbours, a gross error does not. Free
   poses and sweeps of fewer than four samples have no such neighbours; for them the first test decides,
3. unless the pose was seen at three or more tracked points (reflectors) and their residuals together are a
   rigid motion of the end effector within the noise (the residual after a small-motion fit, chi-square
   with 3k - 6 dof at the same false-alarm rate, its scale estimated robustly from every such pose): an
   error of the joints moves every reflector together, a beam break moves one;
4. and, in any case, only when it stands out from the errors the data set already accepts: its studentised
   residual beyond GROSS_FACTOR times the largest kept in its scale group. Systematic errors of thin sweeps
   (four to six samples over a turn, too far apart for the neighbour test) and of free poses far from home
   reach a size of their own; a sample within it is not gross, whatever the bulk's scale;
5. and never as half or more of one sweep: a beam break or a wrong reflector spoils a sample or a few, while an
   error that follows the joints (an elastic joint under the gravity torque, a gear) moves a whole sweep. Such a
   sweep keeps them all, and its error is the model's to show (the ``model_fit`` check), not a loss of that
   joint's data (a real FANUC arm's 4-sample sweeps lost 2 clean samples each, and its verdict failed).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2
from scipy.stats import f as f_dist

from identify.estimator.linalg import column_basis

Array = NDArray[np.float64]

OUTLIER_PROBABILITY = 0.01  # chance that a clean data set has any sample flagged as an outlier
ROBUST_CORE = 0.975  # share of clean samples the robust noise covariance is estimated from
NOISE_FLOOR = 1e-8  # m: below this, residuals are rounding, not noise (no outlier is called on them)


def leverages(jac_blocks: Array, unknown: NDArray[np.int64]) -> Array:
    """Mean leverage of the parameters per sample (m,): trace of its 3x3 block of the hat matrix / 3 (a row's
    own nuisance angle, where its joint was not read, takes one more dimension: see :func:`outlier_free`).
    ``jac_blocks`` (m, 3, p) are weighted and already projected on the nuisance complement."""
    u = column_basis(jac_blocks)
    return np.einsum("kir,kir->k", u, u) / 3.0


MIN_GROUP = 10  # samples a group needs for a scale of its own
GROSS_FACTOR = 1.5  # a gross error stands out by this factor from the largest residual kept beside it
CORE = 0.975  # share of clean rows the noise is estimated from


def _scale_groups(group: NDArray[np.int64]) -> list[NDArray[np.int64]]:
    """Sweep rows and free poses, each judged on its own scale when both are large enough: errors a DH
    table cannot hold grow away from home, where the free poses are."""
    sweeps, free = np.flatnonzero(group > 0), np.flatnonzero(group == 0)
    if len(sweeps) >= MIN_GROUP and len(free) >= MIN_GROUP:
        return [sweeps, free]
    return [np.arange(len(group))]


def sweep_neighbours(group: NDArray[np.int64], key: Array) -> list[NDArray[np.int64]]:
    """Rows of each sweep (``group`` >= 1), ordered by ``key`` (the moved joint's value)."""
    out = []
    for g in np.unique(group[group > 0]):
        rows = np.flatnonzero(group == g)
        out.append(rows[np.argsort(key[rows], kind="stable")])
    return out


def second_differences(res: Array, run: NDArray[np.int64]) -> tuple[Array, Array]:
    """Each sample's residual minus the straight line through its neighbours along the arc (m, 3): the
    mean of both neighbours inside the run, the extrapolation of the next two at its ends; and the variance
    of that difference in units of the noise variance (1.5 inside, 6 at the ends)."""
    r = res[run]
    e = np.empty_like(r)
    spread = np.full(len(r), 1.5)
    e[1:-1] = r[1:-1] - 0.5 * (r[:-2] + r[2:])
    e[0] = r[0] - (2 * r[1] - r[2])
    e[-1] = r[-1] - (2 * r[-2] - r[-3])
    spread[[0, -1]] = 6.0
    return e, spread


def _isotropic_inliers(res: Array, leverage: Array, unknown: NDArray[np.int64], probability: float
                       ) -> NDArray[np.bool_]:
    """The outlier test for rows of which some carry a nuisance angle: each row's squared residual over its
    own degrees of freedom (3, or 2 with a nuisance; less the parameters' share) against an F limit, the noise
    (isotropic) estimated from the rows within the 97.5 % core (corrected for that truncation)."""
    dof = np.where(unknown >= 0, 2.0, 3.0)
    variance = np.maximum(dof - 3.0 * leverage, 0.05 * dof)  # E|r|² / sigma², per row
    t = np.sum(res**2, axis=1) * dof / variance  # ~ sigma² chi²(dof)
    s2 = float(np.median(t / chi2.median(dof))) + NOISE_FLOOR**2
    core = np.ones(len(res), dtype=bool)
    for _ in range(2):
        cut = chi2.ppf(CORE, dof)
        core = t / s2 <= cut
        if core.sum() <= 3:
            break
        kept_mean = dof * chi2.cdf(cut, dof + 2) / CORE  # E[chi²(k) | below its CORE quantile]
        s2 = float(np.sum(t[core]) / np.sum(kept_mean[core])) + NOISE_FLOOR**2
    nu = max(float(np.sum(dof[core])) - 1.0, 5.0)
    return f_dist.sf(t / (dof * s2), dof, nu) >= probability / len(res)


def rigid_motion_residuals(res: Array, points: Array) -> Array:
    """What is left of residuals ``res`` (k, 3) of one pose's tracked points at ``points`` (k, 3, m) after the
    best small rigid motion (translation t, rotation w: r ≈ t + w × (p - centre)), by linear least squares."""
    arm = points - points.mean(axis=0)
    a = np.zeros((len(res), 3, 6))
    a[:, :, :3] = np.eye(3)
    a[:, 0, 4], a[:, 0, 5] = arm[:, 2], -arm[:, 1]  # w × arm = (w_y z - w_z y, w_z x - w_x z, w_x y - w_y x)
    a[:, 1, 3], a[:, 1, 5] = -arm[:, 2], arm[:, 0]
    a[:, 2, 3], a[:, 2, 4] = arm[:, 1], -arm[:, 0]
    flat = a.reshape(-1, 6)
    x, *_ = np.linalg.lstsq(flat, res.reshape(-1), rcond=None)
    return (res.reshape(-1) - flat @ x).reshape(-1, 3)


def _rigid_poses(res: Array, points: Array, pose: NDArray[np.int64], keep: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Rows of poses (``pose`` ids, -1: none) seen at three or more points whose residuals are a rigid motion
    within the noise (test 3 of the module docstring)."""
    ids, counts = np.unique(pose[pose >= 0], return_counts=True)
    multi = ids[counts >= 3]
    if not len(multi):
        return np.zeros(len(res), dtype=bool)
    stats = {}
    for p in multi:
        rows = np.flatnonzero(pose == p)
        e = rigid_motion_residuals(res[rows], points[rows])
        stats[p] = (rows, float(np.sum(e**2)), 3 * len(rows) - 6)
    scale2 = float(np.median([t / dof for _, t, dof in stats.values()])) / (chi2.median(3) / 3)
    scale2 = max(scale2, NOISE_FLOOR**2)
    out = np.zeros(len(res), dtype=bool)
    for rows, t, dof in stats.values():
        if not np.all(keep[rows]) and t / scale2 <= chi2.isf(OUTLIER_PROBABILITY / len(res), dof):
            out[rows] = True
    return out


def outlier_free(res: Array, leverage: Array, group: NDArray[np.int64], key: Array,
                 unknown: NDArray[np.int64] | None = None, pose: NDArray[np.int64] | None = None,
                 points: Array | None = None) -> NDArray[np.bool_]:
    """Mask of the samples kept: see the module docstring. ``res`` (m, 3) weighted residuals; ``leverage``
    (m,) the parameters' mean leverage per row; ``unknown`` (m,) rows' unread joints (-1: none); ``pose`` (m,)
    the pose of each row (rows of one pose seen at several tracked points share it; -1: not comparable) with
    the measured ``points`` (m, 3), for test 3."""
    unknown = np.full(len(res), -1) if unknown is None else unknown
    lev = np.clip(leverage, 0.0, 0.99)
    keep = np.ones(len(res), dtype=bool)
    for rows in _scale_groups(group):
        share = OUTLIER_PROBABILITY * len(rows) / len(res)
        if np.any(unknown[rows] >= 0):  # a nuisance angle leaves 2 of the row's 3 dimensions to the noise
            keep[rows] = _isotropic_inliers(res[rows], lev[rows], unknown[rows], share)
        else:
            keep[rows] = inlier_mask(res[rows] / np.sqrt(1.0 - lev[rows])[:, None], 0, share)
    if np.all(keep):
        return keep
    if pose is not None and points is not None:
        keep |= _rigid_poses(res, points, pose, keep)
    runs = [r for r in sweep_neighbours(group, key) if len(r) >= 4]
    if runs:
        _smooth(res, runs, keep)
    size = np.linalg.norm(res, axis=1) / np.sqrt(1.0 - lev)
    for rows in _scale_groups(group):
        kept = rows[keep[rows]]
        if len(kept):
            keep[rows[size[rows] <= GROSS_FACTOR * size[kept].max()]] = True
    for g in np.unique(group[group > 0]):  # test 5
        rows = group == g
        rejected, samples = np.count_nonzero(~keep[rows]), np.count_nonzero(rows)
        if 2 * rejected >= samples:
            keep[rows] = True
    return keep


def _smooth(res: Array, runs: list[NDArray[np.int64]], keep: NDArray[np.bool_]) -> None:
    """Test 2 of the module docstring: re-admit (in ``keep``) the samples that move with their neighbours."""
    parts = [second_differences(res, r) for r in runs]
    inner = np.vstack([e[1:-1] / np.sqrt(s[1:-1])[:, None] for e, s in parts])
    scale = np.maximum(1.4826 * np.median(np.abs(inner), axis=0), NOISE_FLOOR)  # noise per axis, robust
    limit = chi2.isf(OUTLIER_PROBABILITY / len(res), 3)
    for run, (e, spread) in zip(runs, parts, strict=True):
        d2 = np.sum((e / scale) ** 2, axis=1) / spread
        smooth = d2 <= limit
        keep[run[smooth & ~keep[run]]] = True  # it moves with its neighbours: systematic, not gross


def inlier_mask(weighted_residuals: Array, n_free: int, probability: float = OUTLIER_PROBABILITY) -> NDArray[np.bool_]:
    """Samples whose residual is within the chi-square(3) limit of a robust estimate of the noise.

    The noise may be anisotropic even after weighting: one sigma per sample cannot say that a camera's
    error is mostly along its line of sight (5-10x a lateral one). So the residuals' 3x3 covariance is
    estimated robustly (per-axis median absolute deviation, then two passes over the samples within the
    97.5 % chi-square(3) quantile, corrected for that truncation and for the fitted parameters) and each
    sample's Mahalanobis distance is tested; for isotropic noise this is the usual test on the norm. The
    limit makes OUTLIER_PROBABILITY the chance that a clean data set loses any sample, whatever its size
    (Bonferroni), so a large session does not shed clean samples. Since the covariance is itself estimated
    from the samples, the limit is Hotelling's (a scaled F) rather than chi-square(3): with a few hundred
    samples the difference is a few per cent, but it halves the false alarms of small sessions.
    ``probability``: the chance for these samples (a share of OUTLIER_PROBABILITY when they are a group of a
    larger data set)."""
    res = np.asarray(weighted_residuals, dtype=float).reshape(-1, 3)
    count = res.size
    inflate = count / max(count - n_free, 1)  # residuals of a fit are smaller than the noise
    floor = NOISE_FLOOR**2 * np.eye(3)
    cov = np.diag((1.4826 * np.median(np.abs(res), axis=0)) ** 2) * inflate + floor
    core = chi2.ppf(ROBUST_CORE, 3)
    truncation = ROBUST_CORE / chi2.cdf(core, 5)  # E[r rᵀ | d² < core] = cov · cdf5(core) / cdf3(core)
    used = len(res)  # samples behind the covariance estimate
    for _ in range(2):
        distance2 = np.einsum("ij,jk,ik->i", res, np.linalg.inv(cov), res)
        core_rows = res[distance2 <= core]
        if len(core_rows) <= 3:
            break
        cov = core_rows.T @ core_rows / len(core_rows) * truncation * inflate + floor
        used = len(core_rows)
    distance2 = np.einsum("ij,jk,ik->i", res, np.linalg.inv(cov), res)
    per_sample = probability / len(res)
    dof = max(used - n_free / 3.0, 5.0)  # of the covariance estimate, per axis
    limit = 3.0 * dof / (dof - 2.0) * f_dist.isf(per_sample, 3, dof - 2.0)  # Hotelling's T² for 3 dimensions
    return distance2 <= limit
