"""Which joint errors beyond the DH table the data support, and their regressors (README: "Real robots").

Candidates, per joint the data move (:mod:`kinematics.joint_errors` for the equations): reading scale,
once-per-turn error (revolute joints; sin and cos together) and, when the robot model gives link masses,
compliance under gravity (joints whose gravity torque varies). Each acts on the joint value as
``Δq_i = Σ coefficient · (f(q) - f(home))``; the constant ``f(home)`` is a zero offset the lines absorb. The
identification takes the readings' zero as ``home`` for every data set, so the offsets mean the same across them.

Forward selection: at each step every remaining candidate is scored by the Lagrange-multiplier (score)
test at the current fit, ``s = rᵀ G⊥ (G⊥ᵀ G⊥)⁻¹ G⊥ᵀ r / σ²`` with ``G⊥`` the candidate's columns projected
off the fitted parameters' (chi-square with the candidate's dof when it is absent); the best is refitted
and kept when its likelihood ratio passes both the information criterion (BIC: ``dof · ln N``) and a
family-wise 5 % false-selection limit over all candidates (Bonferroni), and when its size is physically
plausible (:data:`PLAUSIBLE`; beyond it the term stands in for another error). Each term enters on its own
evidence only: a kind of error found on one joint does not bring the same kind on the others, and a term
that the terms entering after it explain is dropped (its likelihood ratio beside them tested again against its
limit). The terms stay within what the rows can carry (:data:`ROWS_PER_TERM`). The set selected is then tested
by grouped cross-validation on the fit rows (:mod:`identify.estimator.extend`): it is kept only if it predicts left-out
blocks of the fit rows better than the model without it; the rows held out for validation never take part.
Every decision is recorded.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from identify.estimator.linalg import residual_maker
from identify.estimator.poe import JointTerms, LeastSquares

Array = NDArray[np.float64]

FAMILY_WISE = 0.05  # chance of selecting any term when the data hold none
MIN_INDEPENDENT = 1e-6  # a candidate whose columns the lines absorb to this fraction is not identifiable
ROWS_PER_TERM = 10  # residual degrees of freedom (3 per row, less the lines') per joint-error coefficient
# The largest size a real drive shows, beyond which a term stands in for another error (or for a pair of terms that
# only cancel inside the fitted range: a -6,400 ppm scale against a +1,300 arcsec once-per-turn error on a UR5 joint
# that turned 80 degrees, which extrapolated to -0.9 degrees at the far side of the joint):
# - scale (gear ratio, 1): a reading scale of 1,000 ppm. Identified gear-ratio errors of industrial arms and cobots
#   are a few hundred ppm at most (the encoder sits on the motor; the ratio is exact up to the output stage's
#   wind-up and the belt or wave generator's slip), so 1e-3 leaves a factor of three;
# - eccentricity (rad, amplitude of each of sin and cos): 1e-3 rad (206 arcsec). Harmonic and cycloid reducers are
#   sold with a transmission error of 1-1.5 arcmin peak to peak (0.3-0.44 mrad), and once-per-turn errors of
#   output encoders are tens of arcsec; 1 mrad is twice the worst of these;
# - compliance (rad/(N m)): 1e-3, a joint stiffness of 1,000 N m/rad, ten times softer than the softest cobot joint.
PLAUSIBLE = {"scale": 1e-3, "eccentricity": 1e-3, "compliance": 1e-3}
UNITS = {"scale": "1", "ecc_sin": "rad", "ecc_cos": "rad", "compliance": "rad/(N m)"}
EQUATIONS = {
    "scale": "dq_i = scale_i * (q_i - home_i)",
    "eccentricity": "dq_i = ecc_sin_i * (sin q_i - sin home_i) + ecc_cos_i * (cos q_i - cos home_i)",
    "compliance": "dq_i = compliance_i * (tau_i(q) - tau_i(home)); tau_i: gravity torque about joint i (N m)",
}


@dataclass(frozen=True)
class Candidate:
    """One joint-error term: ``family`` (scale, eccentricity, compliance) on 0-based ``joint``."""

    family: str
    joint: int

    @property
    def names(self) -> list[str]:
        """Its coefficients' names, e.g. ``ecc_sin_3``, ``ecc_cos_3`` (1-based joints)."""
        if self.family == "eccentricity":
            return [f"ecc_sin_{self.joint + 1}", f"ecc_cos_{self.joint + 1}"]
        return [f"{self.family}_{self.joint + 1}"]

    @property
    def dof(self) -> int:
        return 2 if self.family == "eccentricity" else 1

    def columns(self, q: Array, home: Array, torques: Callable[[Array], Array] | None,
                filled: Array | None = None) -> Array:
        """Regressors (m, dof) at joint values ``q`` (m, n); NaN (unread) values give 0 (their value is a
        nuisance parameter). ``filled`` (m, n): ``q`` with the unread values estimated, for the torques."""
        j = self.joint
        x, h = q[:, j], home[j]
        if self.family == "scale":
            cols = (x - h)[:, None]
        elif self.family == "eccentricity":
            cols = np.stack([np.sin(x) - np.sin(h), np.cos(x) - np.cos(h)], axis=1)
        else:
            if torques is None:
                raise ValueError("compliance needs the robot model's link masses")
            filled = np.where(np.isnan(q), home, q) if filled is None else filled
            cols = (torques(filled)[:, j] - torques(home[None, :])[0, j])[:, None]
            cols[np.isnan(x)] = 0.0
        return np.nan_to_num(cols)


@dataclass(frozen=True)
class TermSet:
    """Selected terms with what computes their regressors: ``home`` (n,) the reference joint values (where every
    term is zero; also the value of unread joints without ``filled``), ``torques`` the
    gravity torques (m, n) at joint values (m, n), or None without link masses."""

    candidates: tuple[Candidate, ...]
    home: Array
    torques: Callable[[Array], Array] | None

    @property
    def names(self) -> list[str]:
        return [name for c in self.candidates for name in c.names]

    @property
    def joints(self) -> NDArray[np.int64]:
        return np.array([c.joint for c in self.candidates for _ in range(c.dof)], dtype=np.int64)

    def regressors(self, q: Array, filled: Array | None = None) -> Array:
        """Regressors (m, T) at joint values ``q`` (m, n) (``filled``: see :meth:`Candidate.columns`)."""
        if not self.candidates:
            return np.zeros((len(q), 0))
        return np.hstack([c.columns(q, self.home, self.torques, filled) for c in self.candidates])

    def terms(self, q: Array, coefs: Array | None = None, filled: Array | None = None) -> JointTerms:
        """The joint terms at joint values ``q`` (m, n) with ``coefs`` (default zero)."""
        joints = self.joints
        return JointTerms(self.regressors(q, filled), joints, np.zeros(len(joints)) if coefs is None else coefs)

    def with_candidate(self, candidate: Candidate) -> TermSet:
        return TermSet((*self.candidates, candidate), self.home, self.torques)


def candidates(joint_types: str, q: Array, torques: Callable[[Array], Array] | None) -> list[Candidate]:
    """Every term the data could show: joints the data move (their values span more than 1e-6 rad or m)."""
    out: list[Candidate] = []
    span = np.nanmax(q, axis=0) - np.nanmin(q, axis=0)
    tau = None
    if torques is not None:
        tau = torques(np.where(np.isnan(q), np.nanmedian(q, axis=0), q))
    for j, kind in enumerate(joint_types):
        if not span[j] > 1e-6:
            continue
        out.append(Candidate("scale", j))
        if kind == "R":
            out.append(Candidate("eccentricity", j))
    if tau is not None:
        out += [Candidate("compliance", j) for j in range(len(joint_types)) if np.ptp(tau[:, j]) > 1e-3]
    return out


@dataclass(frozen=True)
class Decision:
    """One candidate's fate: the score and likelihood-ratio statistics, the limit it had to pass, the
    cross-validated change of the selected set (ratio of the left-out blocks' sums of squares, with / without
    the terms; None when not tested)."""

    candidate: Candidate
    score: float
    ratio: float | None
    limit: float
    cv: float | None
    selected: bool
    reason: str


def score_statistics(res_w: Array, jac: Array, columns: Array, groups: list[NDArray[np.int64]], variance: float
                     ) -> list[float]:
    """Score statistic of each column group (indices into ``columns``' last axis) at a fit with weighted
    residuals ``res_w`` (m, 3), Jacobian ``jac`` (m, 3, p) and candidate columns (m, 3, c), both weighted
    and projected; ``variance`` the noise variance in weighted units. NaN when the lines absorb a group."""
    perpendicular = residual_maker(jac.reshape(-1, jac.shape[2]))
    flat = columns.reshape(-1, columns.shape[2])
    squares = np.einsum("ij,ij->j", flat, flat)  # each candidate column's squared norm
    c_perp = perpendicular(flat)  # every candidate column at once, what the fitted columns leave of it
    inner = c_perp.T @ c_perp
    towards = c_perp.T @ perpendicular(res_w.reshape(-1))
    del c_perp
    rounding = (np.finfo(float).eps * len(flat)) ** 2  # a least-squares solver's relative cut, squared
    out = []
    for idx in groups:
        block = inner[np.ix_(idx, idx)]
        if np.trace(block) <= MIN_INDEPENDENT**2 * max(float(np.sum(squares[idx])), 1e-300):
            out.append(float("nan"))
            continue
        # the residual's squared projection on the group's columns, ‖P r‖² = bᵀ M⁺ b (M, b: their products)
        values, vectors = np.linalg.eigh(block)
        kept = values > rounding * values[-1]
        along = vectors[:, kept].T @ towards[idx]
        out.append(float(np.sum(along**2 / values[kept]) / variance))
    return out


def limit_for(dof: int, n_candidates: int, n_observations: int) -> float:
    """The statistic a term of ``dof`` coefficients must exceed: BIC and the family-wise limit."""
    return max(dof * np.log(max(n_observations, 2)), float(chi2.isf(FAMILY_WISE / max(n_candidates, 1), dof)))


Refit = Callable[[TermSet, LeastSquares], LeastSquares]
Score = Callable[[LeastSquares, TermSet, list[Candidate]], list[float]]
CrossValidate = Callable[[TermSet, LeastSquares], tuple[float, float] | None]


def select(base: LeastSquares, pool: list[Candidate], empty: TermSet, refit: Refit, score: Score,
           chi_square: Callable[[LeastSquares], float], cross_validate: CrossValidate | None,
           n_observations: int, max_coefficients: int) -> tuple[TermSet, LeastSquares, list[Decision]]:
    """Forward selection from ``base`` (the fit without terms) over ``pool``. ``refit(terms, start)`` fits
    with ``terms``; ``score(fit, terms, remaining)`` the score statistics of the remaining candidates;
    ``chi_square(fit)`` its sum of squared weighted residuals over the noise variance; ``cross_validate(terms,
    fit)`` the ratio of cross-validated sums of squares with and without ``terms`` and the gain (their
    difference, in noise variances; None: not testable): the set is kept only when the left-out blocks gain what
    the selection demanded of the fit rows (:func:`limit_for` the set's coefficients), else its last term is
    dropped and the smaller set tested. At most
    ``max_coefficients`` coefficients enter. Returns the terms kept, their fit and every decision."""
    chosen, current = empty, base
    fits = [base]  # the fit after each term kept
    remaining = list(pool)
    decisions: list[Decision] = []
    while remaining:
        scores = score(current, chosen, remaining)
        top = int(np.argmax([s if np.isfinite(s) else -np.inf for s in scores]))
        best, best_score = remaining[top], scores[top]
        limit = limit_for(best.dof, len(pool), n_observations)
        if not np.isfinite(best_score) or best_score <= limit:
            decisions += [Decision(c, s, None, limit_for(c.dof, len(pool), n_observations), None, False,
                                   "score below the limit" if np.isfinite(s) else "not identifiable beside the lines")
                          for c, s in zip(remaining, scores, strict=True)]
            break
        if len(chosen.joints) + best.dof > max_coefficients:
            why = (f"not tried: the fit rows carry at most {max_coefficients} joint-error coefficient(s) "
                   f"({ROWS_PER_TERM} residual degrees of freedom each)")
            decisions += [Decision(c, s, None, limit_for(c.dof, len(pool), n_observations), None, False,
                                   why if np.isfinite(s) else "not identifiable beside the lines")
                          for c, s in zip(remaining, scores, strict=True)]
            break
        trial_terms = chosen.with_candidate(best)
        trial = refit(trial_terms, current)
        ratio = chi_square(current) - chi_square(trial)
        remaining.remove(best)
        if ratio <= limit:
            decisions.append(Decision(best, best_score, ratio, limit, None, False, "likelihood ratio below the limit"))
            continue
        beyond = _implausible(trial_terms, trial.terms.coefs)
        if beyond:
            decisions.append(Decision(best, best_score, ratio, limit, None, False, f"implausible size: {beyond}"))
            continue
        decisions.append(Decision(best, best_score, ratio, limit, None, True, "selected"))
        chosen, current = trial_terms, trial
        fits.append(trial)
    chosen, current, fits, decisions = _backward(chosen, current, fits, decisions, refit, chi_square, len(pool),
                                                 n_observations)
    if cross_validate is None or not chosen.candidates:
        return chosen, current, decisions
    kept = list(chosen.candidates)
    while kept:
        terms = TermSet(tuple(kept), chosen.home, chosen.torques)
        tested = cross_validate(terms, fits[len(kept)])
        if tested is None:
            return terms, fits[len(kept)], decisions
        ratio, gain = tested
        decisions = [replace(d, cv=ratio) if d.selected and d.candidate in kept else d for d in decisions]
        demanded = limit_for(len(terms.joints), len(pool), n_observations)
        if gain > demanded:
            return terms, fits[len(kept)], decisions
        dropped = kept.pop()
        why = (f"cross-validation on the fit rows: left-out blocks gained {gain:.3g} noise variances with the terms "
               f"up to this one (sum of squares {ratio:.3g}x), less than the {demanded:.3g} demanded")
        decisions = [replace(d, selected=False, reason=why) if d.candidate == dropped and d.selected else d
                     for d in decisions]
    return empty, base, decisions


def _implausible(terms: TermSet, coefs: Array) -> str:
    """The coefficients of ``terms`` beyond what a real drive shows (:data:`PLAUSIBLE`), said in words ('' when
    none is): the term just added may push one that entered before it (two terms that cancel inside the fitted
    range grow together), so every coefficient is tested, not only the new one's."""
    out = []
    k = 0
    for c in terms.candidates:
        size = float(np.max(np.abs(coefs[k:k + c.dof])))
        if size > PLAUSIBLE[c.family]:
            out.append(f"{'/'.join(c.names)} {size:.3g} (> {PLAUSIBLE[c.family]:g}): another error")
        k += c.dof
    return "; ".join(out)


def _backward(chosen: TermSet, current: LeastSquares, fits: list[LeastSquares], decisions: list[Decision],
              refit: Refit, chi_square: Callable[[LeastSquares], float], n_candidates: int, n_observations: int
              ) -> tuple[TermSet, LeastSquares, list[LeastSquares], list[Decision]]:
    """The forward selection's terms, each tested again beside the ones that entered after it: while the term
    whose removal costs least no longer passes its limit (the likelihood ratio of the fit with and without it),
    it is dropped. ``fits``: the fits after each term kept, rebuilt for the terms left."""
    dropped = False
    while len(chosen.candidates) > 1:
        trials = []
        for c in chosen.candidates:
            others = TermSet(tuple(x for x in chosen.candidates if x != c), chosen.home, chosen.torques)
            without = refit(others, fits[0])
            trials.append((chi_square(without) - chi_square(current), c, others, without))
        ratio, c, others, without = min(trials, key=lambda x: x[0] / limit_for(x[1].dof, n_candidates, n_observations))
        limit = limit_for(c.dof, n_candidates, n_observations)
        if ratio > limit:
            break
        why = (f"dropped: beside the terms selected after it its likelihood ratio is {ratio:.3g}, below the limit "
               f"{limit:.3g}")
        decisions = [replace(d, selected=False, reason=why) if d.candidate == c and d.selected else d
                     for d in decisions]
        chosen, current, dropped = others, without, True
    if dropped:
        fits = [fits[0]]
        for k in range(1, len(chosen.candidates) + 1):
            fits.append(refit(TermSet(chosen.candidates[:k], chosen.home, chosen.torques), fits[-1]))
        current = fits[-1]
    return chosen, current, fits, decisions
