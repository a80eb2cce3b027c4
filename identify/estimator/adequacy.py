"""Does the model explain the data? Residual noise against the tracker's and against its own differences.

Three estimates of the per-axis noise (weighted units: metres when no sigma is given):

- ``residual``: sum of squared residuals over the degrees of freedom (fitted parameters and the nuisance
  angles of unread joints subtracted): the noise *plus* whatever the model cannot hold;
- ``difference``: the same from successive differences along each sweep, made unbiased under the model
  (``E|D r|² = σ² tr(D (I - H) Dᵀ)``): smooth systematic residuals cancel in it, so it sees the noise;
- ``declared``: the tracker's (the ``sigma`` column, ``--noise``, or the session's tracker).

Excess residual is called when the residual noise exceeds the declared one (chi-square test), or, without a
declaration, its own difference estimate (F test), at a false-alarm rate of ``ALARM``. The excess,
``residual² - noise²`` per axis, has two parts: one white, uncorrelated from sample to sample (the tracker
noisier than declared, or a streamed sample's timestamp jitter times the TP's speed), and the model error,
correlated along each arc. White parts add variance but no autocovariance, so the residuals' lag-1 and lag-2
autocovariances (``g1``, ``g2``) see only the correlated part: under AR(1) its correlation is ``rho_c = g2 / g1``
and its variance ``g1 / rho_c`` (``rho_c`` kept in [:data:`MIN_RHO`, :data:`MAX_RHO`], the variance at most the
excess), counted only when the lag-1 correlation exceeds what white residuals give at the false-alarm rate
(``z / sqrt(3 pairs)``). ``model_error`` is that correlated part, the one that reaches every prediction; the
white rest is noise. Under AR(1) a sweep of n samples holds only ``n_eff = n (1 - rho_c) / (1 + rho_c)``
independent values of the model error, never fewer than one. The parameters' covariance is scaled to
``residual² - model_error² + model_error² · n / n_eff`` (the ``inflation`` factor relative to the residual
variance): the model error is inflated at most by the samples per sweep, when each sweep's error is one shared
offset; the noise, white excess included, not at all. ``detected`` says the excess is significant,
``model_error`` how much of it is correlated (0 when none).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2, norm
from scipy.stats import f as f_dist

from identify.estimator.linalg import column_basis

Array = NDArray[np.float64]

ALARM = 1e-3  # false-alarm rate of the model-error tests
MAX_RHO = 0.999  # lag-1 correlation used for inflation stays below 1
MIN_RHO = 0.5  # the correlated part's lag-1 correlation is taken as at least this (bounds g1 / rho_c by 2 g1)


@dataclass(frozen=True)
class Adequacy:
    """Noise estimates per axis (m), the model error they imply (m per axis: the correlated part of the excess, 0
    when none is detected), ``white`` the uncorrelated rest of the excess (m per axis), the variance inflation
    applied to the parameters' covariance, and the test that decided."""

    residual: float
    difference: float | None
    declared: float | None
    model_error: float
    detected: bool
    rho: float
    inflation: float
    statistic: float
    limit: float
    test: str
    white: float = 0.0

    @property
    def noise(self) -> float:
        """The best estimate of the tracker noise alone (m per axis)."""
        if self.declared is not None:
            return self.declared
        if self.detected and self.difference is not None:
            return self.difference
        return self.residual


def assess(res_w: Array, jac_red: Array, unknown: NDArray[np.int64], runs: list[NDArray[np.int64]],
           unit_scale: float, declared: float | None) -> Adequacy:
    """Adequacy of a fit. ``res_w`` (m, 3) weighted residuals of the fitted inliers, ``jac_red`` (m, 3, p)
    their projected weighted Jacobian, ``runs`` the rows of each sweep in order along the arc;
    ``unit_scale`` (m) turns weighted units into metres (1 without sigma, else the median sigma);
    ``declared`` the tracker's noise per axis (m) or None."""
    m, _, p = jac_red.shape
    n_unknown = int(np.sum(unknown >= 0))
    dof = max(3 * m - p - n_unknown, 1)
    s2_res = float(np.sum(res_w**2)) / dof
    u = column_basis(jac_red)
    pairs = [(r[:-1], r[1:]) for r in runs if len(r) > 1]
    s2_diff = None
    rho = rho2 = 0.0
    n_pairs = 0
    mean_square = max(s2_res * dof / m, 1e-300)
    if pairs:
        a = np.concatenate([x for x, _ in pairs])
        b = np.concatenate([y for _, y in pairs])
        n_pairs = len(a)
        d2 = float(np.sum((res_w[b] - res_w[a]) ** 2))
        hat = float(np.sum((u[b] - u[a]) ** 2))
        counts = np.bincount(np.concatenate([a, b]), minlength=m)
        expected = 6.0 * n_pairs - hat - float(np.sum(counts[unknown >= 0]))
        if expected > 0.5:
            s2_diff = d2 / expected
        rho = float(np.sum(res_w[a] * res_w[b]) / n_pairs / mean_square)
        lag2 = [(r[:-2], r[2:]) for r in runs if len(r) > 2]
        if lag2:
            a2, b2 = np.concatenate([x for x, _ in lag2]), np.concatenate([y for _, y in lag2])
            rho2 = float(np.sum(res_w[a2] * res_w[b2]) / len(a2) / mean_square)
    residual = float(np.sqrt(s2_res)) * unit_scale
    difference = None if s2_diff is None else float(np.sqrt(s2_diff)) * unit_scale
    if declared is not None:
        statistic = (residual / declared) ** 2
        limit = float(chi2.isf(ALARM, dof) / dof)
        test = f"residual noise vs the declared tracker noise (chi-square, {dof} dof)"
        reference = declared
    elif difference is not None and difference > 0:
        statistic = (residual / difference) ** 2
        limit = float(f_dist.isf(ALARM, dof, max(2 * n_pairs, 1)))
        test = "residual noise vs the noise of successive differences along the sweeps (F test)"
        reference = difference
    else:
        statistic, limit, test, reference = 1.0, float("inf"), "no reference noise (no sweep to difference)", residual
    detected = statistic > limit
    excess = max(residual**2 - reference**2, 0.0) if detected else 0.0
    rho_model = min(max(rho2 / rho, MIN_RHO), MAX_RHO) if rho > 0 else MAX_RHO  # the correlated part's lag-1
    correlated = rho > float(norm.isf(ALARM)) / np.sqrt(3.0 * max(n_pairs, 1))  # beyond white residuals' spread
    model_error = float(np.sqrt(min(rho * residual**2 / rho_model, excess))) if correlated else 0.0
    inflation = 1.0
    if model_error > 0.0:
        per_sweep = float(np.mean([len(r) for r in runs])) if runs else 1.0
        model_inflation = min((1.0 + rho_model) / (1.0 - rho_model), max(per_sweep, 1.0))
        inflation = (residual**2 - model_error**2 + model_error**2 * model_inflation) / residual**2
    white = float(np.sqrt(max(excess - model_error**2, 0.0)))
    return Adequacy(residual, difference, declared, model_error, bool(detected), rho, inflation, statistic, limit,
                    test, white)
