"""One clock offset for every streamed sweep, or one per sweep: a score test decides.

A session's streams share one tracker-to-robot clock relation only while neither clock restarts and no
timestamp jumps. A resume after a restart, or a jump, leaves sweeps whose offsets differ; one offset for all
of them bends the kinematics instead (0.8 mm of error for a few milliseconds at 1 rad/s). At the fit with
one offset, the score statistic of splitting it per sweep (``S - 1`` extra parameters for ``S`` streamed
sweeps) is compared with the limit the joint-error selection uses (:func:`identify.estimator.extensions.limit_for`:
BIC and a family-wise chi-square); above it, the fit is redone with one offset per sweep.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from identify.estimator.estimate import FitData, LinesFit, fit
from identify.estimator.extensions import limit_for, score_statistics


@dataclass(frozen=True)
class ClockSplit:
    """The test: ``statistic`` (score, in noise variances) against ``limit`` for ``sweeps`` streamed sweeps;
    ``split`` whether the fit now has one offset per sweep."""

    statistic: float
    limit: float
    sweeps: int
    split: bool


def split_clock(best: LinesFit, data: FitData, robust: bool, variance: float) -> tuple[LinesFit, ClockSplit | None]:
    """``best`` (fitted with one clock offset) or its refit with one offset per streamed sweep, and the test
    (None with fewer than two streamed sweeps or an offset already per sweep). ``variance``: the residual
    variance in weighted units, model error included (the test must not take a misfit for a clock jump)."""
    timing = best.timing
    if timing is None or timing.offsets > 1 or not timing.free:
        return best, None
    per_sweep = timing.per_sweep()
    sweeps = per_sweep.offsets
    if sweeps < 2:
        return best, None
    inl = best.inliers
    problem = data.timed(timing).subset(inl).problem(best.lines, best.terms.subset(inl))
    x0 = np.zeros(problem.size)
    jac = best.jacobian_blocks(problem)
    res = problem.residuals(x0).reshape(-1, 3)
    offset = jac[:, :, problem.n_terms]  # the offset's column: the TP's velocity on streamed rows
    rows = per_sweep.offset_index()[inl]
    columns = np.zeros((len(rows), 3, sweeps))
    for k in range(sweeps):
        columns[rows == k, :, k] = offset[rows == k]
    statistic = score_statistics(res, jac, columns, [np.arange(sweeps)], variance)[0]
    limit = limit_for(sweeps - 1, 1, res.size)
    split = bool(np.isfinite(statistic) and statistic > limit)
    if split:
        best = fit(best.lines, data.timed(per_sweep), robust, best.start, best.terms)
    return best, ClockSplit(float(statistic), float(limit), sweeps, split)
