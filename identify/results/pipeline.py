"""The identification as one pure function: measurements in, identified model with its evidence out.

Geometric step (the paper) and the nominal model (when given) start a maximum-likelihood fit of the joint
axes as lines (:mod:`identify.estimator.estimate`, every sample used, unread joints as nuisance parameters, gross
outliers rejected); its covariance is scaled to the noise and inflated for model error
(:mod:`identify.estimator.adequacy`); the lines are written as DH (:mod:`identify.results.dh_output`); held-out poses
validate it; and :mod:`identify.results.verdict` says whether it can be trusted.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np
from numpy.typing import NDArray

from common.errors import InputError
from identify.estimator.adequacy import Adequacy, assess
from identify.estimator.clock_split import ClockSplit, split_clock
from identify.estimator.cpa import DEFAULT_PARALLEL_TOL, GeometricResult, home_from_measurements
from identify.estimator.estimate import FitData, LinesFit, along_arc, best_start, fit, fit_kept, place_nominal, readmit
from identify.estimator.extend import select_terms
from identify.estimator.extensions import Decision, TermSet, candidates
from identify.estimator.identifiability import Identifiability, identifiability
from identify.estimator.measurements import Measurements, in_dh_joints, prepared_joints, validate
from identify.estimator.outliers import sweep_neighbours
from identify.estimator.poe import AxisLines, LineProblem, points_from_lines
from identify.estimator.refine import Refinement, full_jacobian, parameter_names
from identify.estimator.starts import starts
from identify.estimator.sync import Retiming, retiming
from identify.results import verdict as checks
from identify.results.predict import Predictor
from identify.results.validation import Validation
from identify.results.validation import validate as validate_model
from identify.results.written import UNDETERMINED, FixedParameter, WrittenModel, robot_size, written_model
from kinematics.dh import DHModel, points_from_joints
from kinematics.joint_errors import Coupling, LinkMasses, gravity_torques

Array = NDArray[np.float64]


@dataclass(frozen=True)
class SweepFit:
    """Residuals of one sweep (or of the free poses, ``joint`` 0): RMS 3D residual (m) of inliers."""

    sweep: int
    joint: int
    samples: int
    rejected: int
    rms: float


@dataclass(frozen=True)
class ClockFit:
    """The tracker-to-robot clock relation of streamed rows, fitted with the kinematics: robot time =
    tracker time + ``offset`` + ``drift`` · (tracker time − ``t_ref``). ``offset`` (s) is the recording's
    coarse offset plus the fitted correction; ``*_std`` their standard uncertainties (``drift`` None when not
    fitted: streams shorter than :data:`identify.estimator.sync.DRIFT_SPAN`); ``rows`` the streamed rows fitted.
    ``test``: whether the sweeps needed an offset each (:mod:`identify.estimator.clock_split`); when they did,
    ``sweeps`` lists (sweep id, offset s, std s) per streamed sweep, ``offset`` is their inverse-variance
    mean and ``offset_std`` the largest of their uncertainties."""

    offset: float
    offset_std: float
    drift: float | None
    drift_std: float | None
    t_ref: float
    rows: int
    test: ClockSplit | None = None
    sweeps: tuple[tuple[int, float, float], ...] = ()


@dataclass(frozen=True)
class Identification:
    """The identified models and the evidence behind them, ending in ``verdict``.

    ``models``: ``plain`` (standard DH, no joint errors: the result's top-level model) and, when the data support
    joint errors, ``extended`` (:class:`identify.results.written.WrittenModel`); ``use`` names the one the result
    recommends (the extended one when it was selected) and ``validations`` holds each one's held-out figure from
    its written numbers. ``model``, ``std``, ``fixed``, ``lines``, ``tools``, ``refinement`` are the plain
    model's (what a plain reader of the result gets); ``predictor``, ``adequacy`` and ``validation`` the
    recommended one's (what compensation and verification use)."""

    models: dict[str, WrittenModel]
    use: str
    validations: dict[str, Validation]
    geometric: GeometricResult | None
    sweeps: list[SweepFit]
    rejected_rows: list[int]
    convention: str
    verdict: checks.Verdict
    start: str
    coupling: Coupling | None
    decisions: list[Decision] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    clock: ClockFit | None = None

    @property
    def plain(self) -> WrittenModel:
        return self.models["plain"]

    @property
    def used(self) -> WrittenModel:
        """The model the result recommends."""
        return self.models[self.use]

    @property
    def extended(self) -> WrittenModel | None:
        return self.models.get("extended")

    @property
    def model(self) -> DHModel:
        return self.plain.model

    @property
    def std(self) -> Array:
        return self.plain.std

    @property
    def fixed(self) -> list[FixedParameter]:
        return self.plain.fixed

    @property
    def refinement(self) -> Refinement:
        return self.plain.refinement

    @property
    def lines(self) -> AxisLines:
        return self.plain.lines

    @property
    def lines_covariance(self) -> Array:
        return self.plain.lines_covariance

    @property
    def tools(self) -> Array:
        return self.plain.tools

    @property
    def parallel(self) -> list[int]:
        return sorted(self.plain.capped)

    @property
    def adequacy(self) -> Adequacy:
        return self.used.adequacy

    @property
    def predictor(self) -> Predictor:
        """What predicts with the recommended model (exact axis lines, its joint errors, the coupling)."""
        return replace(self.used.predictor, coupling=self.coupling)

    @property
    def validation(self) -> Validation | None:
        """The recommended model's held-out figure (None without check rows)."""
        return self.validations.get(self.use)

    @property
    def tp_ids(self) -> tuple[int, ...]:
        """Ids of the tracked points, ``tools`` rows in this order."""
        return self.plain.predictor.tp_ids

    @property
    def extensions(self) -> list[tuple[str, float, float]]:
        """Selected joint-error coefficients of the extended model: (name, value, standard uncertainty), units in
        :data:`identify.estimator.extensions.UNITS` (empty without one)."""
        ext = self.extended
        if ext is None:
            return []
        pred = ext.predictor
        k = pred.lines.n_parameters
        std = np.sqrt(np.clip(np.diag(pred.covariance)[k:], 0.0, None))
        return list(zip(pred.terms.names, pred.coefs.tolist(), std.tolist(), strict=True))

    @property
    def rms(self) -> float:
        """RMS 3D residual of the fitted inliers under the recommended model, m."""
        fit = self.used.fit
        return float(np.sqrt(np.mean(np.sum(fit.residuals[fit.inliers] ** 2, axis=1))))

    @property
    def geometric_rms(self) -> float:
        """RMS 3D residual of the same inliers under the geometric step's model (the paper's), m."""
        if self.geometric is None:
            return float("nan")
        ref = self.refinement
        err = ref.points - points_from_joints(self.geometric.model, ref.q)
        return float(np.sqrt(np.mean(np.sum(err[ref.inliers] ** 2, axis=1))))

    @property
    def exact_dh(self) -> bool:
        """True when the DH table is the identified model; False when a parallel-axis convention it keeps
        costs measurable accuracy (then predictions use the axis lines)."""
        return self.verdict_check("dh_table").status == "pass"

    def verdict_check(self, name: str) -> checks.Check:
        return next(c for c in self.verdict.checks if c.name == name)

    def predict(self, q: Array, tp: int | NDArray[np.int64] | None = None) -> Array:
        """Predicted TP (k, 3), tracker frame, at joint readings ``q`` (k, n) (as the controller reports them;
        positions-only data: relative to the home pose), for tracked point id(s) ``tp`` (default the first)."""
        return self.predictor.points(q, tp)

    def prediction_covariances(self, q: Array, tp: int | NDArray[np.int64] | None = None) -> Array:
        """Covariance (k, 3, 3) of the predicted TP at ``q`` from the parameters' uncertainty, m²."""
        return self.predictor.covariances(q, tp)

    def prediction_rms(self, q: Array, tp: int | NDArray[np.int64] | None = None) -> float:
        """RMS over ``q`` of the 3D standard uncertainty of predictions (m), model error included: what the
        error against the real arm should be near."""
        cov = self.prediction_covariances(q, tp)
        return float(np.sqrt(np.mean(np.trace(cov, axis1=1, axis2=2)) + 3 * self.adequacy.model_error**2))


def split_holdout(meas: Measurements, fraction: float, seed: int = 0) -> Measurements:
    """Mark a seeded ``fraction`` of the free poses as held out (``check``), unless a role column did."""
    if meas.has_role or fraction <= 0:
        return meas
    free = np.flatnonzero(meas.joint == 0)
    count = round(len(free) * fraction)
    if count == 0:
        return meas
    chosen = np.random.default_rng(seed).choice(free, size=count, replace=False)
    check = meas.check.copy()
    check[chosen] = True
    return replace(meas, check=check)


def identify(
    meas: Measurements,
    nominal: DHModel | None = None,
    parallel_tol: float = DEFAULT_PARALLEL_TOL,
    robust: bool = True,
    max_offset: float | None = None,
    noise: float | None = None,
    links: LinkMasses | None = None,
    extensions: bool = True,
) -> Identification:
    """Identify the DH model from ``meas`` (fit rows; ``check`` rows are only used for validation).

    ``nominal`` (optional) starts a second fit (and the only one for free poses without sweeps), supplies
    the conventional values of redundant parameters and the signs of the x axes, and is checked against
    the data. ``noise`` (m per axis): the tracker's declared noise (the ``sigma`` column overrides it).
    ``max_offset`` (m): how far exact DH may move a near-parallel pair's ``d`` before the convention is kept
    (None: the robot's size, :func:`identify.results.written.robot_size`). ``links`` (with ``nominal``): link masses,
    for compliance; ``extensions``: select joint errors the fit rows support (:mod:`identify.estimator.extensions`).
    Readings are the controller's (``meas.coupling``); several tracked points (``meas.tp``) share the model, each with
    its own tool.
    """
    coupling = meas.coupling
    meas, relabelled = in_dh_joints(meas)
    try:
        warnings = validate(meas, with_nominal=nominal is not None) + relabelled
    except InputError as exc:  # say what the coupling did to the sweeps when it matters
        raise InputError("; ".join([str(exc), *relabelled])) from None
    n = meas.n_joints
    if nominal is not None and nominal.joint_types != meas.joint_types:
        raise ValueError(f"nominal model has joints {nominal.joint_types}, data have {meas.joint_types}")
    conventional = np.zeros((n, 4)) if nominal is None else nominal.dh_table()
    tp_ids = meas.tp_ids
    fitm = meas.subset(~meas.check)
    home = home_from_measurements(fitm)
    q, unknown = prepared_joints(fitm, home)
    tp_index = np.searchsorted(tp_ids, fitm.tp)
    weights = np.ones(len(q)) if fitm.sigma is None else 1.0 / fitm.sigma
    numbers = {s: k + 1 for k, s in enumerate(np.unique(fitm.sweep[fitm.joint > 0]))}
    sweep_group = np.array([numbers.get(int(s), 0) if j > 0 else 0 for s, j in zip(fitm.sweep, fitm.joint,
                                                                                     strict=True)])
    group = np.where(sweep_group > 0, sweep_group * len(tp_ids) + tp_index, 0)  # neighbours: same sweep and point
    timing = None if fitm.t is None else retiming(fitm.t, fitm.streamed, fitm.sweep, q)
    data = FitData(q, fitm.points, weights, unknown, tp_index, group, fitm.joint, timing)
    geo, found_starts = starts(fitm, q, unknown, tp_index, home, nominal, conventional, parallel_tol, warnings)
    fits = [fit(start, data, robust, label) for label, start in found_starts]
    best: LinesFit = best_start(fits, data)
    unit = 1.0 if fitm.sigma is None else float(np.median(fitm.sigma))
    declared = unit if fitm.sigma is not None else noise
    adequacy = _adequacy(best, data, unit, declared)
    best, clock_test = split_clock(best, data, robust, max(adequacy.residual, declared or 0.0) ** 2 / unit**2)
    if clock_test is not None and clock_test.split:
        adequacy = _adequacy(best, data, unit, declared)
    torques = None if links is None or nominal is None else (lambda x: gravity_torques(nominal, links, x))
    # joint errors referenced to the readings' zero, not to this data set's home: the extended model's DH offsets
    # then mean the same on every data set of the arm (a home that moved with the split moved them by c·τ(home))
    empty = TermSet((), np.zeros(n), torques)
    cap = robot_size(best.lines, fitm.points) if max_offset is None else max_offset
    write = partial(written_model, tp_ids=tuple(tp_ids), conventional=conventional, nominal=nominal,
                    parallel_tol=parallel_tol, max_offset=cap, unit=unit, declared=declared, sigma=fitm.sigma)
    decisions: list[Decision] = []
    extended: tuple[LinesFit, TermSet] | None = None
    if extensions:
        pool = candidates(meas.joint_types, q[best.inliers], torques)
        variance = max(adequacy.noise, declared or 0.0) ** 2 / unit**2
        terms, _, decisions = select_terms(best, data.timed(best.timing), empty, pool, variance)
        if terms.candidates:  # refitted on the plain model's inliers: joint errors never make outliers
            joint_errors = readmit(fit_kept(best.lines, data.timed(best.timing), best.inliers, best.start,
                                            terms.terms(q, None, best.q)), data)
            if not np.array_equal(joint_errors.inliers, best.inliers):  # rows the joint errors explain are not gross
                best = fit_kept(best.lines, data.timed(best.timing), joint_errors.inliers, best.start, best.terms)
                adequacy = _adequacy(best, data, unit, declared)
            extended = joint_errors, terms
    models = {"plain": write("plain", best, data, adequacy, empty)}
    if extended is not None:
        fitted, terms = extended
        models["extended"] = write("extended", fitted, data, _adequacy(fitted, data, unit, declared), terms)
    use = "extended" if "extended" in models else "plain"
    used = models[use]
    inl = used.fit.inliers
    check_rows = meas.subset(meas.check & np.all(np.isfinite(meas.q), axis=1))
    validations = {} if not len(check_rows) else {
        name: validate_model(check_rows.q, check_rows.points, check_rows.tp, check_rows.sigma,
                             partial(_written_points, m, tp_ids), m.predictor, m.adequacy.noise, m.adequacy.model_error)
        for name, m in models.items()}
    ref = used.refinement
    sweeps = [_sweep_fit(int(sid), int(fitm.joint[sweep_group == g][0]), ref, sweep_group == g)
              for sid, g in numbers.items()]
    if np.any(fitm.joint == 0):
        sweeps.append(_sweep_fit(0, 0, ref, fitm.joint == 0))
    for sw in sweeps:
        if sw.rejected:
            warnings.append(f"sweep {sw.sweep}: {sw.rejected} sample(s) rejected as outliers")
    clock = None if used.fit.timing is None else _clock(
        used.fit.timing, used.covariance[used.problem.n_terms:, used.problem.n_terms:], meas.clock_offset, clock_test)
    found = [
        checks.model_fit(used.fit_rms, used.adequacy, _cause(models, decisions)),
        checks.conditioning(used.condition, _identifiability(used, robot_size(best.lines, fitm.points))),
        checks.outliers(int(np.sum(~inl)), len(inl), _lost(sweeps)),
        models["plain"].dh_check,
    ]
    if clock is not None:
        found.append(checks.timing(clock.offset_std, _tp_speed(used.jacobian_blocks, used.problem, weights[inl]),
                                   used.adequacy.noise, clock.test, [o for _, o, _ in clock.sweeps]))
    if validations:
        v = validations[use]
        others = {k: (w.rms, w.expected) for k, w in validations.items() if k != use}
        found.append(checks.holdout(v.samples, v.rms, v.expected, use, others, _moved(models, tp_ids, check_rows)))
    elif use == "extended" and not np.any(fitm.joint == 0):
        found.append(checks.sweeps_only_extension())
    if nominal is not None and np.sum(unknown < 0) >= 3:
        known = unknown < 0
        lines = models["plain"].lines
        placed, _ = place_nominal(nominal, best.q[known], points_from_lines(lines, best.q[known]),
                                  tool=models["plain"].tools[0])
        gap = points_from_joints(placed, best.q[known]) - points_from_lines(lines, best.q[known])
        found.append(checks.nominal("model", float(np.sqrt(np.mean(np.sum(gap**2, axis=1))))))
    if decisions:
        kept = [d.candidate.names for d in decisions if d.selected]
        warnings.append("joint errors selected: " + (", ".join(n for names in kept for n in names) if kept else "none"))
    notes = [f"fitted from the {best.start}" + (f" (of {len(fits)} starts)" if len(fits) > 1 else "")]
    a = used.adequacy
    if fitm.sigma is not None:
        notes.append(f"reduced chi-square {a.statistic:.3g} (1 when the given sigma is right)")
    if a.inflation > 1.0:
        notes.append(f"residuals correlated along the arcs (lag-1 {a.rho:.2f}): covariance inflated {a.inflation:.3g}x")
    ref.notes.extend(notes)
    return Identification(
        models=models,
        use=use,
        validations=validations,
        geometric=geo,
        sweeps=sweeps,
        rejected_rows=[int(r) for r in fitm.row[~inl]],
        convention="nominal" if nominal is not None else "zero",
        verdict=checks.Verdict(tuple(found)),
        start=best.start,
        coupling=coupling,
        decisions=decisions,
        warnings=warnings,
        clock=clock,
    )


def _written_points(model: WrittenModel, tp_ids: NDArray[np.int64], q: Array, tp: NDArray[np.int64]) -> Array:
    """What ``model``'s written numbers predict at DH joint values ``q`` for tracked point ids ``tp``."""
    return model.dh_points(q, np.searchsorted(tp_ids, tp))


def _moved(models: dict[str, WrittenModel], tp_ids: NDArray[np.int64], rows: Measurements) -> float | None:
    """RMS distance (m) between the extended and plain models' predictions at ``rows`` (None without joint errors)."""
    if "extended" not in models:
        return None
    gap = (_written_points(models["extended"], tp_ids, rows.q, rows.tp)
           - _written_points(models["plain"], tp_ids, rows.q, rows.tp))
    return float(np.sqrt(np.mean(np.sum(gap**2, axis=1))))


def _identifiability(model: WrittenModel, size: float) -> Identifiability:
    """What the data determine of ``model``'s free parameters, for the robot's ``size`` (m)."""
    ref, a = model.refinement, model.adequacy
    names = [name for name, free in zip(parameter_names(model.model.n_joints), ref.free, strict=False) if free]
    scale = max(a.residual, a.declared or 0.0) * np.sqrt(a.inflation)
    held = tuple(f.name for f in model.fixed if f.reason == UNDETERMINED)
    _, jac = full_jacobian(model.model, ref.q[ref.inliers])
    lever = np.sqrt(np.einsum("kij,kij->j", jac, jac)[ref.free] / len(jac))
    return identifiability(names, ref.covariance, lever, size, a.model_error, scale, int(ref.inliers.sum()), held)


def _cause(models: dict[str, WrittenModel], decisions: list[Decision]) -> str | None:
    """What the joint-error selection says about a large model error: the kinds of error selected and how much
    of the residual they explain, or that none explained it."""
    if not decisions:
        return None
    plain = models["plain"].fit_rms
    ext = models.get("extended")
    if ext is None:
        return "no joint error (gear ratio, eccentricity, compliance) explains it"
    kinds = sorted({d.candidate.family for d in decisions if d.selected})
    name = {"compliance": "elasticity (compliance under gravity)", "scale": "gear ratio (reading scale)",
            "eccentricity": "eccentricity"}
    return (f"{', '.join(name[k] for k in kinds)} selected: residual RMS {checks.mm(plain)} without joint errors, "
            f"{checks.mm(ext.fit_rms)} with them")


def _tp_speed(jac_blocks: Array, problem: LineProblem, weights: Array) -> float:
    """RMS speed (m/s) of the tracked point over the streamed rows: the Jacobian column of the clock offset."""
    rows = problem.timing.rows
    velocity = jac_blocks[rows, :, problem.n_terms] / weights[rows, None]
    return float(np.sqrt(np.mean(np.sum(velocity**2, axis=1))))


def _clock(timing: Retiming, covariance: Array, offset: float, test: ClockSplit | None) -> ClockFit:
    """The fitted clock relation (``covariance`` of ``timing.tau``; ``offset`` s the recording's coarse one;
    ``test`` whether the sweeps needed one offset each)."""
    std = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    k = timing.offsets
    drift, drift_std = (float(timing.tau[k]), float(std[k])) if timing.drift else (None, None)
    rows = int(np.sum(timing.rows))
    if k == 1:
        return ClockFit(offset + float(timing.tau[0]), float(std[0]), drift, drift_std, timing.t_ref, rows, test)
    offsets, stds = offset + timing.tau[:k], np.maximum(std[:k], 1e-300)
    mean = float(np.sum(offsets / stds**2) / np.sum(1 / stds**2))
    sweeps = tuple((int(s), float(o), float(e)) for s, o, e in zip(np.unique(timing.sweep), offsets, std[:k],
                                                                     strict=True))
    return ClockFit(mean, float(np.max(std[:k])), drift, drift_std, timing.t_ref, rows, test, sweeps)


def _lost(sweeps: list[SweepFit]) -> list[str]:
    """Sweeps that lost more than half their samples, or all but two, to the outlier test."""
    return [f"sweep {s.sweep} (joint {s.joint})" for s in sweeps
            if s.joint > 0 and (s.rejected * 2 > s.samples or s.samples - s.rejected < 3)]


def _adequacy(best: LinesFit, data: FitData, unit: float, declared: float | None) -> Adequacy:
    """Adequacy of ``best`` on its inliers (see :mod:`identify.estimator.adequacy`)."""
    inl = best.inliers
    rows = data.timed(best.timing).subset(inl)
    problem = rows.problem(best.lines, best.terms.subset(inl))
    zero = np.zeros(problem.size)
    runs = sweep_neighbours(rows.group, along_arc(best.q[inl], rows.joint))
    return assess(problem.residuals(zero).reshape(-1, 3), best.jacobian_blocks(problem), rows.unknown, runs, unit,
                  declared)


def _sweep_fit(sweep: int, joint: int, ref: Refinement, rows: NDArray[np.bool_]) -> SweepFit:
    good = rows & ref.inliers
    res = ref.residuals[good]
    rms = float(np.sqrt(np.mean(np.sum(res**2, axis=1)))) if len(res) else float("nan")
    return SweepFit(sweep, joint, int(rows.sum()), int((rows & ~ref.inliers).sum()), rms)


