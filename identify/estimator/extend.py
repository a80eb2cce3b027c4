"""Joint errors on top of a fitted lines model: the selection of :mod:`identify.estimator.extensions` run on the
inliers of a fit (:mod:`identify.estimator.estimate`), its result tested by grouped cross-validation on those same fit
rows (never on the rows held out for validation). Frames: tracker; metres.

Streamed rows (continuous motion) carry a timing error: a row's joint values are read at its stamp plus the fitted
latency, and what the latency misses moves the readings by the joint's speed times the time error. A latency that
wanders within a sweep of joint j at constant speed moves joint j's readings linearly with the joint value, which
is a reading scale error of j; a slower curve looks like an eccentricity. So the selection runs with a latency free
to differ and drift in every streamed sweep (:meth:`identify.estimator.sync.Retiming.local`): the score test projects
each candidate and the residuals off those timing columns at the fit with the session's clock (Neyman's C(alpha) form of
the test, so a session where no candidate passes costs no refit), and every refit and cross-validation fits them,
so a term earns its place only on what a sweep's own timing cannot explain (its ends, the still poses, the other
sweeps). The written models keep the session's clock model."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from identify.estimator.estimate import FitData, LinesFit, along_arc
from identify.estimator.extensions import ROWS_PER_TERM, Candidate, Decision, TermSet, score_statistics, select
from identify.estimator.poe import JointTerms, LeastSquares

Array = NDArray[np.float64]

FOLDS = 5  # cross-validation blocks: each sweep cut into this many arcs, the free poses into as many regions
MIN_FOLD_ROWS = 3  # rows a block must have for the cross-validation to use it


def cv_folds(rows: FitData, filled: Array, folds: int = FOLDS) -> NDArray[np.int64]:
    """The block (0 .. folds-1) of each row: every sweep (and tracked point) cut into ``folds`` contiguous arcs
    along the joint it moves, so a block leaves a stretch of arc out rather than single samples between
    neighbours that would still pin it; free poses cut into as many regions of the joint space
    (:func:`_regions`), every tracked point of a pose in the same block. ``filled`` (m, n): joint values with the
    unread ones solved."""
    out = np.zeros(len(rows.q), dtype=np.int64)
    key = along_arc(filled, rows.joint)
    for g in np.unique(rows.group[rows.group > 0]):
        idx = np.flatnonzero(rows.group == g)
        rank = np.empty(len(idx), dtype=np.int64)
        rank[np.argsort(key[idx], kind="stable")] = np.arange(len(idx))
        out[idx] = rank * folds // max(len(idx), 1)
    free = np.flatnonzero(rows.group == 0)
    if len(free):
        poses, pose = np.unique(np.round(filled[free], 12), axis=0, return_inverse=True)
        out[free] = _regions(poses, folds)[pose.ravel()]
    return out


def _regions(poses: Array, folds: int) -> NDArray[np.int64]:
    """The block of each free pose (k, n joint values): ``folds`` contiguous regions along the direction in which
    the poses spread most (their first principal component, each joint scaled by its spread), so a block at
    either end is predicted from poses that all lie on one side of it: a term must extrapolate to win there."""
    if len(poses) < 2:
        return np.zeros(len(poses), dtype=np.int64)
    centred = poses - poses.mean(axis=0)
    spread = centred.std(axis=0)
    scaled = centred / np.where(spread > 0, spread, 1.0)
    direction = np.linalg.svd(scaled, full_matrices=False)[2][0]
    rank = np.empty(len(poses), dtype=np.int64)
    rank[np.argsort(scaled @ direction, kind="stable")] = np.arange(len(poses))
    return rank * folds // len(poses)


def select_terms(best: LinesFit, data: FitData, empty: TermSet, pool: list[Candidate], variance: float
                 ) -> tuple[TermSet, LeastSquares | None, list[Decision]]:
    """Forward selection of ``pool`` on the inliers of ``best`` (fitted without terms), then the grouped
    cross-validation veto (:func:`cv_folds`) on the same rows. ``data.q`` holds readings (NaN where unread);
    ``variance`` is the noise variance in weighted units. Returns the terms kept, their least-squares fit on the
    inliers (None when none is kept) and every decision."""
    rows = data.subset(best.inliers)
    filled = best.q[best.inliers]  # unread values as solved, for the gravity torques
    if rows.timing is not None:  # streamed rows: every term competes with a latency free to wander
        rows = rows.timed(rows.timing.local())  # the same shift at every row as the fit's clock
    base = LeastSquares(best.lines, filled, -best.residuals[best.inliers] * data.weights[best.inliers, None],
                        JointTerms.none(len(filled)))
    settled: list[LeastSquares] = []  # the fit without terms with the local latency, fitted when first needed

    def terms_of(terms: TermSet, coefs: Array | None = None) -> JointTerms:
        return JointTerms(terms.regressors(rows.q, filled), terms.joints,
                          np.zeros(len(terms.joints)) if coefs is None else coefs)

    def refit(terms: TermSet, start: LeastSquares) -> LeastSquares:
        coefs = np.concatenate([start.terms.coefs, np.zeros(len(terms.joints) - len(start.terms.coefs))])
        return rows.fit(start.lines, terms_of(terms, coefs))

    def score(current: LeastSquares, terms: TermSet, remaining: list[Candidate]) -> list[float]:
        every = TermSet((*terms.candidates, *remaining), terms.home, terms.torques)
        coefs = np.concatenate([current.terms.coefs, np.zeros(len(every.joints) - len(current.terms.coefs))])
        problem = rows.problem(current.lines, terms_of(every, coefs))
        zero = np.zeros(problem.size)
        jac = problem.jacobian_blocks(zero)
        res = problem.residuals(zero).reshape(-1, 3)
        fitted = problem.n_lines + len(terms.joints)
        nuisance = np.concatenate([jac[:, :, :fitted], jac[:, :, problem.n_terms:]], axis=2)  # with the timing's
        groups, start = [], 0
        for c in remaining:
            groups.append(np.arange(start, start + c.dof))
            start += c.dof
        return score_statistics(res, nuisance, jac[:, :, fitted:problem.n_terms], groups, variance)

    def chi_square(fit: LeastSquares) -> float:
        """Sum of squared weighted residuals over the variance; for ``base`` with streamed rows, at the best local
        latency (the score test projected it already; only a candidate that passes it needs the refit)."""
        if fit is base and rows.timing is not None:
            if not settled:
                settled.append(rows.fit(base.lines, JointTerms.none(len(filled))))
            fit = settled[0]
        return float(np.sum(fit.residuals**2)) / variance

    fold = cv_folds(rows, filled)
    blocks = [k for k in range(FOLDS) if np.sum(fold == k) >= MIN_FOLD_ROWS and np.sum(fold != k) > 0]

    def left_out_squares(terms: TermSet, fit: LeastSquares) -> float:
        """Sum of squared weighted residuals of every block, each predicted by a fit of the other blocks."""
        total = 0.0
        for k in blocks:
            train = fold != k
            part = rows.subset(train)
            coefs = fit.terms.coefs
            trained = part.fit(fit.lines, JointTerms(terms.regressors(rows.q[train], filled[train]), terms.joints,
                                                     coefs.copy()))
            everyone = rows if rows.timing is None else rows.timed(replace(rows.timing, tau=trained.timing.tau))
            problem = everyone.problem(trained.lines, terms_of(terms, trained.terms.coefs))
            res = problem.residuals(np.zeros(problem.size)).reshape(-1, 3)
            total += float(np.sum(res[fold == k] ** 2))
        return total

    plain_cv: list[float] = []

    def cross_validate(terms: TermSet, fit: LeastSquares) -> tuple[float, float] | None:
        if len(blocks) < 2:
            return None
        if not plain_cv:
            plain_cv.append(left_out_squares(empty, base))
        with_terms = left_out_squares(terms, fit)
        return with_terms / max(plain_cv[0], 1e-300), (plain_cv[0] - with_terms) / variance

    room = 3 * len(filled) - best.lines.n_parameters
    return select(base, pool, empty, refit, score, chi_square, cross_validate, 3 * len(filled),
                  max(room // ROWS_PER_TERM, 0))
