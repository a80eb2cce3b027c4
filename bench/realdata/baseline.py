"""The DH-only maximum-likelihood baseline: every DH value, the base and every tracked point's tool vector fitted
to the fit rows by plain least squares (scipy ``least_squares``, equal weights, no outlier rejection, no joint
errors), started from a given model (the product's plain one, or a nominal). This is the textbook calibration
the product's plain model must match (target: within 2 % on the check rows).

Parameters, in order: the DH table (n x 4: theta, d, a, alpha), the base as a rotation vector (applied on the
left of the start's base, rad) and a translation (m), then the tools (3 per tracked point, m). Gauge freedoms
(e.g. theta_1 against the base's rotation) make the Jacobian rank deficient; the trust-region solver handles
that, and only the predictions (which do not depend on the gauge) are scored.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from bench.realdata.common import Array
from bench.realdata.score import Model


def _unpack(x: Array, start: Model, points: list[int]) -> Model:
    n = len(start.types)
    table = x[: 4 * n].reshape(n, 4)
    rotation = Rotation.from_rotvec(x[4 * n: 4 * n + 3]).as_matrix()
    base = start.base.copy()
    base[:3, :3] = rotation @ start.base[:3, :3]
    base[:3, 3] = start.base[:3, 3] + x[4 * n + 3: 4 * n + 6]
    tools = {tp: x[4 * n + 6 + 3 * k: 4 * n + 9 + 3 * k] for k, tp in enumerate(points)}
    return replace(start, table=table, base=base, tools=tools, terms={}, home=None)


def fit(start: Model, readings: Array, points: Array, tp: np.ndarray) -> tuple[Model, float]:
    """The DH-only least-squares model on these rows (readings as in the file, points in m), and the time (s)."""
    ids = sorted(int(k) for k in np.unique(tp))
    plain = replace(start, terms={}, home=None)
    x0 = np.concatenate([plain.table.ravel(), np.zeros(6), *(plain.tools[k] for k in ids)])

    def residuals(x: Array) -> Array:
        return (_unpack(x, plain, ids).predict(readings, tp) - points).ravel()

    began = time.perf_counter()
    solution = least_squares(residuals, x0, method="trf", x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12,
                             max_nfev=200)
    return _unpack(solution.x, plain, ids), time.perf_counter() - began
