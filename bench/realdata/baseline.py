"""The DH-only maximum-likelihood baseline and the placed nominal, fitted to the fit rows by plain least squares
(scipy ``least_squares``, equal weights, no outlier rejection, no joint errors).

- :func:`fit`: every DH value, the base and every tracked point's tool vector, started from a given model (the
  product's plain one). This is the textbook calibration the product's plain model must match (target: within
  2 % on the check rows).
- :func:`place`: the nominal's DH table kept as it is, only the base and the tools fitted: what the arm does
  before any calibration, in the tracker's frame.

Parameters, in order: the DH table (n x 4: theta, d, a, alpha; :func:`fit` only), the base as a rotation vector
(applied on the left of the start's base, rad) and a translation (m), then the tools (3 per tracked point, m).
Gauge freedoms (e.g. theta_1 against the base's rotation) make the Jacobian rank deficient; the trust-region
solver handles that, and only the predictions (which do not depend on the gauge) are scored.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from bench.realdata.common import Array
from bench.realdata.score import Model

PLACE_STARTS = 12  # random base rotations tried by place() besides the given start


def _unpack(x: Array, start: Model, points: list[int], fit_dh: bool, keep_terms: bool = False) -> Model:
    n = 4 * len(start.types) if fit_dh else 0
    table = x[:n].reshape(-1, 4) if fit_dh else start.table
    rotation = Rotation.from_rotvec(x[n: n + 3]).as_matrix()
    base = start.base.copy()
    base[:3, :3] = rotation @ start.base[:3, :3]
    base[:3, 3] = start.base[:3, 3] + x[n + 3: n + 6]
    tools = {tp: x[n + 6 + 3 * k: n + 9 + 3 * k] for k, tp in enumerate(points)}
    if keep_terms:
        return replace(start, table=table, base=base, tools=tools)
    return replace(start, table=table, base=base, tools=tools, terms={}, home=None)


def _solve(start: Model, readings: Array, points: Array, tp: np.ndarray, fit_dh: bool,
           keep_terms: bool = False) -> tuple[Model, float]:
    ids = sorted(int(k) for k in np.unique(tp))
    x0 = np.concatenate([start.table.ravel() if fit_dh else [], np.zeros(6), *(start.tools[k] for k in ids)])

    def residuals(x: Array) -> Array:
        return (_unpack(x, start, ids, fit_dh, keep_terms).predict(readings, tp) - points).ravel()

    solution = least_squares(residuals, x0, method="trf", x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12,
                             max_nfev=200)
    return _unpack(solution.x, start, ids, fit_dh, keep_terms), float(solution.cost)


def fit(start: Model, readings: Array, points: Array, tp: np.ndarray) -> tuple[Model, float]:
    """The DH-only least-squares model on these rows (readings as in the file, points in m), and the time (s)."""
    began = time.perf_counter()
    model, _ = _solve(replace(start, terms={}, home=None), readings, points, tp, fit_dh=True)
    return model, time.perf_counter() - began


def place(nominal: Model, readings: Array, points: Array, tp: np.ndarray, seed: int = 0,
          keep_terms: bool = False, random_starts: int = PLACE_STARTS) -> Model:
    """The model with only its base and tools fitted to these rows (its joint errors kept when ``keep_terms``,
    else dropped). Started from ``nominal.base`` and ``nominal.tools`` and from ``random_starts`` random base
    rotations (each moved onto the points' centroid); the start with the least squared error wins."""
    starts = [nominal]
    shape = nominal.predict(readings, tp)
    for rotation in Rotation.random(random_starts, random_state=seed).as_matrix() if random_starts else []:
        base = nominal.base.copy()
        base[:3, :3] = rotation @ nominal.base[:3, :3]
        moved = shape @ rotation.T
        base[:3, 3] = rotation @ nominal.base[:3, 3] + points.mean(axis=0) - moved.mean(axis=0)
        starts.append(replace(nominal, base=base))
    fits = [_solve(start, readings, points, tp, fit_dh=False, keep_terms=keep_terms) for start in starts]
    return min(fits, key=lambda f: f[1])[0]

