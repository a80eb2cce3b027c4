"""Joint errors on top of a fitted lines model: the selection of :mod:`identify.extensions` run on the
inliers of a fit (:mod:`identify.estimate`), with the held-out rows as the veto. Frames: tracker; metres."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from identify.estimate import FitData, LinesFit
from identify.extensions import Candidate, Decision, TermSet, score_statistics, select
from identify.poe import JointTerms, LeastSquares, points_from_lines

Array = NDArray[np.float64]


@dataclass(frozen=True)
class HeldOut:
    """Held-out rows for the veto: DH joint values ``q`` (k, n), ``points`` (k, 3), ``weights`` (k,),
    ``tp_index`` (k,)."""

    q: Array
    points: Array
    weights: Array
    tp_index: NDArray[np.int64]


def select_terms(best: LinesFit, data: FitData, empty: TermSet, pool: list[Candidate], variance: float,
                 heldout: HeldOut | None) -> tuple[TermSet, LeastSquares | None, list[Decision]]:
    """Forward selection of ``pool`` on the inliers of ``best`` (fitted without terms). ``data.q`` holds
    readings (NaN where unread); ``variance`` is the noise variance in weighted units. Returns the terms
    kept, their least-squares fit on the inliers (None when none is kept) and every decision."""
    rows = data.subset(best.inliers)
    filled = best.q[best.inliers]  # unread values as solved, for the gravity torques

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
        groups, start = [], 0
        for c in remaining:
            groups.append(np.arange(start, start + c.dof))
            start += c.dof
        return score_statistics(res, jac[:, :, :fitted], jac[:, :, fitted:], groups, variance)

    def chi_square(fit: LeastSquares) -> float:
        return float(np.sum(fit.residuals**2)) / variance

    def held(fit: LeastSquares, terms: TermSet) -> float:
        assert heldout is not None
        q = terms.terms(heldout.q, fit.terms.coefs).corrected(heldout.q)
        err = (points_from_lines(fit.lines, q, heldout.tp_index) - heldout.points) * heldout.weights[:, None]
        return float(np.sum(err**2))

    base = LeastSquares(best.lines, filled, -best.residuals[best.inliers] * data.weights[best.inliers, None],
                        JointTerms.none(len(filled)))
    return select(base, pool, empty, refit, score, chi_square, held if heldout is not None else None,
                  3 * len(filled))
