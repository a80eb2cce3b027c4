"""Cramér-Rao bounds for predicted TP positions: the accuracy no calibration of the same data can beat, which
plans, verdicts and benchmarks are measured against (docs/method.md, "How far to trust it").

For isotropic tracker noise ``sigma`` (m per axis) and fitted joint readings ``q_fit``, the covariance
of any unbiased estimate of the model's prediction at ``q_check`` is at least
``sigma² · Jc · pinv(JᵀJ) · Jcᵀ``, with J the Jacobian of all predicted TPs with respect to all model
parameters. Redundant parameters (pinv's null space) do not change the predictions, so the bound
does not depend on which are fixed.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from identify.estimator.refine import full_jacobian
from kinematics.dh import DHModel

Array = NDArray[np.float64]

RCOND = 1e-9  # relative singular value below which a direction counts as undetermined


def prediction_covariances(
    model: DHModel, q_fit: Array, q_check: Array, sigma: float, weights: Array | None = None
) -> Array:
    """Lower bound on the covariance (k, 3, 3) of predicted TPs at ``q_check``, m².

    ``weights`` (m,) = 1/sigma_k relative to ``sigma`` for samples of unequal uncertainty.
    """
    _, jac = full_jacobian(model, q_fit)
    if weights is not None:
        jac = jac * np.asarray(weights, dtype=float)[:, None, None]
    j = jac.reshape(-1, jac.shape[2])
    scale = np.maximum(np.linalg.norm(j, axis=0), 1e-300)
    _, s, vt = np.linalg.svd(j / scale, full_matrices=False)
    keep = s > RCOND * s[0]
    _, jac_check = full_jacobian(model, q_check)
    # Jc D^-1 V S^-1: rows are the check predictions' sensitivities to the whitened parameters
    g = (jac_check / scale) @ (vt[keep].T / s[keep])
    return sigma**2 * (g @ np.swapaxes(g, 1, 2))


def prediction_rms_bound(model: DHModel, q_fit: Array, q_check: Array, sigma: float) -> float:
    """Cramér-Rao bound on the RMS 3D error (m) of predicted TPs at ``q_check`` (vs the truth)."""
    cov = prediction_covariances(model, q_fit, q_check, sigma)
    return float(np.sqrt(np.mean(np.trace(cov, axis1=1, axis2=2))))
