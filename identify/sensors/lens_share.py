"""A flange camera's final shape-and-lens estimate's error through the fit: one draw shared by every reading.

Readings corrected again with the session's final estimate (identify/sensors/recorrection.py) all carry that
estimate's error δθ (covariance C, the rows' ``lens``): reading i is off by its response ``R_i δθ``, the same δθ in
every one. Kept in each row's sigma it weighs the rows as if it were noise of their own (there the sigmas came out
about 2x the rows' scatter, a reduced chi-square of 0.27, and the flange's statement 1.9x its error: docs/benchmarks.md
section 24c), although most of it is a change of the camera's mount that the fit takes up. So the fit is given the
rows without it (:func:`identify.sensors.recorrection.unfolded`) and it goes through the fit as what it is: for each
principal direction of C (one standard deviation), the rows are moved by their responses, turned round as the fit's
were (the same view point), and the fit's linear answer to that move (the weighted least-squares step of its
Jacobian at the solution, over its inlier rows) is one direction of the lines' error; identify/sensors/evidence.py
adds these to the flange's statement beside the fit's own covariance, and what they leave the held-out rows
(:func:`held_out_share`) to the held-out check's expectation. Units: metres, radians.
"""

from __future__ import annotations

import copy

import numpy as np
from numpy.typing import NDArray

from identify.estimator.measurements import Measurements, orientation_rows
from identify.estimator.orientation import matrices_from_rotvecs
from identify.results.pipeline import Identification
from identify.sensors.flange import frame_point_jacobian, turned_round
from identify.sensors.recorrection import moved

Array = NDArray[np.float64]


def shared_lines(ident: Identification, device: Measurements, view_point: Array) -> Array | None:
    """(k, d): the plain model's k line parameters' answer to each of the d principal directions (one standard
    deviation each) of the final estimate's error in ``device``'s rows (the camera's, before turning round about
    ``view_point``); (k, 0) without a ``lens``; None when the fit's rows cannot be told among them (the caller says
    so: the error is then left out)."""
    problem = ident.plain.problem
    k = problem.n_lines
    lens = device.lens
    if lens is None:
        return np.zeros((k, 0))
    steps = _principal(lens.covariance)
    if not len(steps):
        return np.zeros((k, 0))
    rows = _fit_order(problem, _fit_rows(device, view_point))
    if rows is None:
        return None
    x0 = np.zeros(problem.size)
    jacobian, base = problem.jacobian(x0), problem.residuals(x0)
    out = []
    for step in steps:
        moves = lens.response @ step  # (m, 6)
        fit = _fit_rows(moved(device, moves), view_point)
        shifted = copy.copy(problem)
        shifted.points = fit.points[rows]
        if problem.rotations is not None:
            shifted.rotations = _rotations(fit)[rows]  # NaN on position rows, as the fit's
        answer = np.linalg.lstsq(jacobian, base - shifted.residuals(x0), rcond=None)[0]
        out.append(answer[:k])
    return np.array(out).T


def _principal(covariance: Array) -> Array:
    """(d, p): one standard deviation along each principal direction of ``covariance`` (p, p) with a variance."""
    values, vectors = np.linalg.eigh((covariance + covariance.T) / 2)
    keep = values > 1e-12 * max(float(values.max()), 0.0)
    return (vectors[:, keep] * np.sqrt(values[keep])).T


def _fit_rows(device: Measurements, view_point: Array) -> Measurements:
    """The fit's rows of ``device`` turned round about ``view_point``: the held-out rows left out, each orientation a
    row of its own after the positions (identify/estimator/measurements.orientation_rows)."""
    turned, _ = turned_round(device, view_point)
    return orientation_rows(turned.subset(~turned.check))[0]


def _rotations(rows: Measurements) -> Array:
    out = np.full((len(rows), 3, 3), np.nan)
    oriented = rows.oriented
    out[oriented] = matrices_from_rotvecs(rows.rotvec[oriented])
    return out


def _fit_order(problem, rows: Measurements) -> NDArray[np.int64] | None:
    """Which of ``rows`` each of the fit problem's rows is (the fit keeps its inliers in their order): matched in
    order by position (the same numbers) and kind (position or orientation); None when one cannot be found."""
    oriented = rows.oriented
    out, j = [], 0
    for point, turning in zip(problem.points, problem.oriented, strict=True):
        while j < len(rows) and not (oriented[j] == turning and np.allclose(rows.points[j], point, rtol=0,
                                                                            atol=1e-12)):
            j += 1
        if j == len(rows):
            return None
        out.append(j)
        j += 1
    return np.array(out, dtype=np.int64)


def held_out_share(ident: Identification, device: Measurements, view_point: Array, lines: Array | None) -> float:
    """Mean square (m², 3D) that the shared error leaves the held-out rows' positions (``device``'s check rows,
    turned round about ``view_point``) beyond what the fit's answer to it (``lines``: :func:`shared_lines`) predicts
    there: what the held-out check adds to its expectation (the rows' sigmas no longer hold it). 0 without held-out
    rows or directions."""
    check = device.check
    if lines is None or lines.shape[1] == 0 or device.lens is None or not np.any(check):
        return 0.0
    q = device.q[check]
    if device.coupling is not None:
        q = q @ device.coupling.matrix.T + device.coupling.offset
    predicted = frame_point_jacobian(ident.plain, q, np.zeros(3))  # (c, 3, k): the view point, board frame
    before = turned_round(device, view_point)[0].points[check]
    total = 0.0
    for step, answer in zip(_principal(device.lens.covariance), lines.T, strict=True):
        after = turned_round(moved(device, device.lens.response @ step), view_point)[0]
        left = after.points[check] - before - predicted @ answer
        total += float(np.mean(np.sum(left**2, axis=1)))
    return total
