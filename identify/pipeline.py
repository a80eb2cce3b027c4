"""The identification as one pure function: measurements in, identified model with its evidence out.

Geometric step (the paper) and the nominal model (when given) start a maximum-likelihood fit of the joint
axes as lines (:mod:`identify.estimate`, every sample used, unread joints as nuisance parameters, gross
outliers rejected); its covariance is scaled to the noise and inflated for model error
(:mod:`identify.adequacy`); the lines are written as DH (:mod:`identify.dh_output`); held-out poses
validate it; and :mod:`identify.verdict` says whether it can be trusted.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from common.errors import InputError
from identify import verdict as checks
from identify.adequacy import Adequacy, assess
from identify.clock_split import ClockSplit, split_clock
from identify.cpa import DEFAULT_PARALLEL_TOL, GeometricResult, home_from_measurements
from identify.dh_output import DHOutput, dh_output, near_parallel
from identify.estimate import FitData, LinesFit, along_arc, fit, place_nominal
from identify.extend import HeldOut, select_terms
from identify.extensions import Decision, TermSet, candidates
from identify.linalg import project_out, scaled_inverse
from identify.measurements import Measurements, in_dh_joints, prepared_joints, validate
from identify.outliers import sweep_neighbours
from identify.poe import AxisLines, LineProblem, points_from_lines
from identify.predict import Predictor
from identify.refine import DEFAULT_MAX_OFFSET, Refinement, full_jacobian, parameter_names, refine
from identify.starts import starts
from identify.sync import Retiming, retiming
from kinematics.dh import DHModel, frames_from_joints, points_from_joints
from kinematics.joint_errors import Coupling, LinkMasses, gravity_torques

Array = NDArray[np.float64]


@dataclass(frozen=True)
class FixedParameter:
    """A parameter held at ``value`` (rad or m) by a convention, for ``reason``."""

    name: str
    value: float
    reason: str


@dataclass(frozen=True)
class SweepFit:
    """Residuals of one sweep (or of the free poses, ``joint`` 0): RMS 3D residual (m) of inliers."""

    sweep: int
    joint: int
    samples: int
    rejected: int
    rms: float


@dataclass(frozen=True)
class Validation:
    """Errors at held-out poses: measured vs predicted TP, 3D, metres.

    ``bound`` is the RMS error of the model's own predictions the fit's covariance implies;
    ``expected`` adds the tracker noise and model error of the held-out measurements (what ``rms``
    should be near).
    """

    samples: int
    rms: float
    max: float
    bound: float
    expected: float


@dataclass(frozen=True)
class ClockFit:
    """The tracker-to-robot clock relation of streamed rows, fitted with the kinematics: robot time =
    tracker time + ``offset`` + ``drift`` · (tracker time − ``t_ref``). ``offset`` (s) is the recording's
    coarse offset plus the fitted correction; ``*_std`` their standard uncertainties (``drift`` None when not
    fitted: streams shorter than :data:`identify.sync.DRIFT_SPAN`); ``rows`` the streamed rows fitted.
    ``test``: whether the sweeps needed an offset each (:mod:`identify.clock_split`); when they did,
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
    """Identified model (``model``, standard DH), standard uncertainties in the layout of
    :func:`identify.refine.parameter_names` (``std``), the axis lines it was fitted as (``lines``, with
    their covariance ``lines_covariance``), and the evidence behind them, ending in ``verdict``."""

    model: DHModel
    std: Array
    fixed: list[FixedParameter]
    geometric: GeometricResult | None
    refinement: Refinement
    sweeps: list[SweepFit]
    rejected_rows: list[int]
    validation: Validation | None
    parallel: list[int]
    convention: str
    lines: AxisLines
    lines_covariance: Array
    adequacy: Adequacy
    verdict: checks.Verdict
    start: str
    predictor: Predictor
    tools: Array
    decisions: list[Decision] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    clock: ClockFit | None = None

    @property
    def coupling(self) -> Coupling | None:
        """How the readings give DH joint values (None: they are DH values)."""
        return self.predictor.coupling

    @property
    def tp_ids(self) -> tuple[int, ...]:
        """Ids of the tracked points, ``tools`` rows in this order."""
        return self.predictor.tp_ids

    @property
    def extensions(self) -> list[tuple[str, float, float]]:
        """Selected joint-error coefficients: (name, value, standard uncertainty), units in
        :data:`identify.extensions.UNITS`."""
        pred = self.predictor
        k = pred.lines.n_parameters
        std = np.sqrt(np.clip(np.diag(pred.covariance)[k:], 0.0, None))
        return list(zip(pred.terms.names, pred.coefs.tolist(), std.tolist(), strict=True))

    @property
    def rms(self) -> float:
        """RMS 3D residual of the fitted inliers, m."""
        res = self.refinement.residuals[self.refinement.inliers]
        return float(np.sqrt(np.mean(np.sum(res**2, axis=1))))

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


def dh_covariance(model: DHModel, free: NDArray[np.bool_], q: Array, weights: Array,
                  unknown: NDArray[np.int64]) -> Array:
    """Unit-variance covariance of the ``free`` DH values (weighted units), rows of unread joints (``unknown``,
    0-based, -1 for none) projected on the complement of their nuisance joint value."""
    p, jac = full_jacobian(model, q)
    jac = jac[:, :, free] * weights[:, None, None]
    rows = np.flatnonzero(unknown >= 0)
    if len(rows):
        frames = frames_from_joints(model, q[rows])
        j = unknown[rows]
        axis = frames[np.arange(len(rows)), j, :3, 2]
        origin = frames[np.arange(len(rows)), j, :3, 3]
        revolute = model.revolute[j]
        g = np.where(revolute[:, None], np.cross(axis, p[rows] - origin), axis) * weights[rows, None]
        project_out(jac, rows, g)
    return scaled_inverse(jac.reshape(-1, jac.shape[2]))[0]


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


def _reason(name: str, n: int, types: str, capped: dict[int, float]) -> str:
    joint = int("".join(ch for ch in name if ch.isdigit()) or 0)
    if joint in capped and name.startswith("d"):
        return (f"axes {joint} and {joint + 1} are parallel within tolerance or their uncertainty: the common "
                f"normal is placed by convention (exact DH would move d{joint} by {capped[joint]:.3g} m)")
    if joint == 1 and name[:-1] in ("theta", "d"):
        return "redundant with the base pose (frame 0 is placed by convention)"
    if joint == n:
        return "redundant with the tool: frame n is placed by convention and the tool carries the TP"
    if types[joint - 1] == "P" and name[:-1] in ("a", "d"):
        return "a prismatic axis has no position; it is placed to meet the next axis"
    return "placed by convention"


def identify(
    meas: Measurements,
    nominal: DHModel | None = None,
    parallel_tol: float = DEFAULT_PARALLEL_TOL,
    robust: bool = True,
    max_offset: float = DEFAULT_MAX_OFFSET,
    noise: float | None = None,
    links: LinkMasses | None = None,
    extensions: bool = True,
) -> Identification:
    """Identify the DH model from ``meas`` (fit rows; ``check`` rows are only used for validation).

    ``nominal`` (optional) starts a second fit (and the only one for free poses without sweeps), supplies
    the conventional values of redundant parameters and the signs of the x axes, and is checked against
    the data. ``noise`` (m per axis): the tracker's declared noise (the ``sigma`` column overrides it).
    ``max_offset`` (m): how far exact DH may move a near-parallel pair's ``d`` before the convention is kept.
    ``links`` (with ``nominal``): link masses, for compliance; ``extensions``: select joint errors the data
    support (:mod:`identify.extensions`). Readings are the controller's (``meas.coupling``); several tracked
    points (``meas.tp``) share the model, each with its own tool.
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
    best: LinesFit = min(fits, key=lambda f: f.robust_cost)
    unit = 1.0 if fitm.sigma is None else float(np.median(fitm.sigma))
    declared = unit if fitm.sigma is not None else noise
    adequacy = _adequacy(best, data, unit, declared)
    torques = None if links is None or nominal is None else (lambda x: gravity_torques(nominal, links, x))
    empty = TermSet((), home, torques)
    terms, decisions = empty, []
    base_rms = float(np.sqrt(np.mean(np.sum(best.residuals[best.inliers] ** 2, axis=1))))
    if extensions and base_rms < checks.GROSS_MISFIT:  # joint errors are corrections, not a wrong model
        pool = candidates(meas.joint_types, q[best.inliers], torques)
        check_all = meas.subset(meas.check & np.all(np.isfinite(meas.q), axis=1))
        held = None if not len(check_all) else HeldOut(
            check_all.q, check_all.points, np.ones(len(check_all)) if check_all.sigma is None else 1 / check_all.sigma,
            np.searchsorted(tp_ids, check_all.tp))
        variance = max(adequacy.noise, declared or 0.0) ** 2 / unit**2
        held_clock = data.timed(None if best.timing is None else best.timing.held())
        terms, _, decisions = select_terms(best, held_clock, empty, pool, variance, held)
        if terms.candidates:
            best = fit(best.lines, data.timed(best.timing), robust, best.start, terms.terms(q, None, best.q))
            adequacy = _adequacy(best, data, unit, declared)
    best, clock_test = split_clock(best, data, robust, max(adequacy.residual, declared or 0.0) ** 2 / unit**2)
    if clock_test is not None and clock_test.split:
        adequacy = _adequacy(best, data, unit, declared)
    data = data.timed(best.timing)
    lines, inl = best.lines, best.inliers
    problem = data.subset(inl).problem(lines, best.terms.subset(inl))
    x0 = np.zeros(problem.size)
    jac_blocks = problem.jacobian_blocks(x0)
    res_w = problem.residuals(x0).reshape(-1, 3)
    inv, condition = scaled_inverse(jac_blocks.reshape(-1, problem.size))
    # noise variance in weighted units (1 for a right sigma column), never below the declared noise
    variance = max(adequacy.residual, declared or 0.0) ** 2 / unit**2 * adequacy.inflation
    covariance = inv * variance
    n_lines = lines.n_parameters
    lines_cov = covariance[:n_lines, :n_lines]
    near, beyond = near_parallel(lines, lines_cov, conventional, nominal, parallel_tol, max_offset)
    first = tp_index[inl] == 0
    fitted = (best.q[inl][first], fitm.points[inl][first], None if fitm.sigma is None else fitm.sigma[inl][first],
              weights[inl][first], res_w[first], variance)
    out, dh_fit, gap = _written_dh(lines, conventional, nominal, near, fitted, adequacy.noise)
    if near and gap[1] > checks.dh_limit(len(near)) and len(beyond) < len(near):
        # the data resolve the misalignment: exact DH wherever it stays within --max-offset
        out, dh_fit, gap = _written_dh(lines, conventional, nominal, beyond, fitted, adequacy.noise)
    if dh_fit is None:  # exact DH: the lines' covariance carried over
        model = out.model
        free = np.any(out.jacobian != 0.0, axis=1)
        cov_free = (out.jacobian @ lines_cov @ out.jacobian.T)[np.ix_(free, free)]
    else:  # DH refitted under the convention: its own covariance, on the noise scale of the lines' fit
        model, free = dh_fit.model, dh_fit.free
        cov_free = dh_covariance(model, free, best.q[inl][first], weights[inl][first], unknown[inl][first]) * variance
    std = np.zeros(len(free))
    std[free] = np.sqrt(np.clip(np.diag(cov_free), 0.0, None))
    residuals = best.residuals
    notes = [f"fitted from the {best.start}" + (f" (of {len(fits)} starts)" if len(fits) > 1 else "")]
    if fitm.sigma is not None:
        notes.append(f"reduced chi-square {adequacy.statistic:.3g} (1 when the given sigma is right)")
    if adequacy.inflation > 1.0:
        notes.append(f"residuals correlated along the arcs (lag-1 {adequacy.rho:.2f}): covariance inflated "
                     f"{adequacy.inflation:.3g}x")
    ref = Refinement(model, free, cov_free, adequacy.noise, inl, residuals, condition,
                     float(np.sum(res_w**2)), best.q, fitm.points, notes)
    names = parameter_names(n)
    vector = np.concatenate([np.zeros(3), model.base[:3, 3], model.tool, model.dh_table().ravel()])
    fixed = [FixedParameter(names[k], float(vector[k]), _reason(names[k], n, meas.joint_types, out.capped))
             for k in np.flatnonzero(~free)]
    sweeps = [_sweep_fit(int(sid), int(fitm.joint[sweep_group == g][0]), ref, sweep_group == g)
              for sid, g in numbers.items()]
    if np.any(fitm.joint == 0):
        sweeps.append(_sweep_fit(0, 0, ref, fitm.joint == 0))
    for sw in sweeps:
        if sw.rejected:
            warnings.append(f"sweep {sw.sweep}: {sw.rejected} sample(s) rejected as outliers")
    ident_rms = float(np.sqrt(np.mean(np.sum(residuals[inl] ** 2, axis=1))))
    check_rows = meas.subset(meas.check & np.all(np.isfinite(meas.q), axis=1))
    kinematic = slice(0, problem.n_terms)  # the clock correction's parameters come last
    predictor = Predictor(lines, covariance[kinematic, kinematic], terms, best.terms.coefs, None, tuple(tp_ids))
    clock = None if best.timing is None else _clock(best.timing, covariance[problem.n_terms:, problem.n_terms:],
                                                     meas.clock_offset, clock_test)
    fitted_tp = np.asarray(tp_ids)[tp_index[inl]]
    expected = _expected_accuracy(predictor, best.q[inl], fitted_tp, adequacy)
    gap_rms, gap_statistic = gap
    dh_check = checks.dh_table(gap_rms, gap_statistic, expected, [f"d{i}" for i in out.capped])
    validation = _validate(check_rows, predictor, adequacy) if len(check_rows) else None
    found = [
        checks.model_fit(ident_rms, adequacy),
        checks.conditioning(condition),
        checks.outliers(int(np.sum(~inl)), len(inl), _lost(sweeps)),
        dh_check,
    ]
    if clock is not None:
        found.append(checks.timing(clock.offset_std, _tp_speed(jac_blocks, problem, weights[inl]), adequacy.noise,
                                   clock.test, [o for _, o, _ in clock.sweeps]))
    if validation is not None:
        found.append(checks.holdout(validation.samples, validation.rms, validation.expected))
    if nominal is not None and np.sum(unknown < 0) >= 3:
        known = unknown < 0
        placed, _ = place_nominal(nominal, best.q[known], points_from_lines(lines, best.q[known]))
        gap = points_from_joints(placed, best.q[known]) - points_from_lines(lines, best.q[known])
        found.append(checks.nominal("model", float(np.sqrt(np.mean(np.sum(gap**2, axis=1))))))
    if decisions:
        kept = [d.candidate.names for d in decisions if d.selected]
        warnings.append("joint errors selected: " + (", ".join(n for names in kept for n in names) if kept else "none"))
    return Identification(
        model=model,
        std=std,
        fixed=fixed,
        geometric=geo,
        refinement=ref,
        sweeps=sweeps,
        rejected_rows=[int(r) for r in fitm.row[~inl]],
        validation=validation,
        parallel=sorted(out.capped),
        convention="nominal" if nominal is not None else "zero",
        lines=lines,
        lines_covariance=lines_cov,
        adequacy=adequacy,
        verdict=checks.Verdict(tuple(found)),
        start=best.start,
        predictor=replace(predictor, coupling=coupling),
        tools=_tools(model, lines),
        decisions=decisions,
        warnings=warnings,
        clock=clock,
    )


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


def _written_dh(lines: AxisLines, conventional: Array, nominal: DHModel | None, capped: dict[int, float],
                fitted: tuple[Array, Array, Array | None, Array, Array, float], noise: float
                ) -> tuple[DHOutput, Refinement | None, tuple[float, float]]:
    """The DH conversion with ``capped`` links at the parallel-axis convention; with any capped, the DH
    table refitted under that convention (so the cost it adds is a likelihood ratio, chi-square when the
    axes are parallel); and that cost with the RMS gap to the lines (see :func:`_dh_gap`)."""
    q, points, sigma, weights, res_w, variance = fitted
    out = dh_output(lines, conventional, nominal, capped, with_jacobian=not capped)
    if not capped:
        return out, None, _dh_gap(out.model, lines, q, points, weights, res_w, variance)
    dh_fit = refine(out.model, q, points, sigma, conventional, sorted(capped), noise, False, 0.0)
    return out, dh_fit, _dh_gap(dh_fit.model, lines, q, points, weights, res_w, variance)


def _dh_gap(model: DHModel, lines: AxisLines, q: Array, points: Array, weights: Array, res_w: Array,
            variance: float) -> tuple[float, float]:
    """RMS difference (m) of the DH model's and the lines' predictions at ``q``, and the cost the DH model
    adds over the lines', in noise variances."""
    gap = points_from_joints(model, q) - points_from_lines(lines, q)
    res_dh = (points - points_from_joints(model, q)) * weights[:, None]
    added = float(np.sum(res_dh**2) - np.sum(res_w**2)) / max(variance, 1e-300)
    return float(np.sqrt(np.mean(np.sum(gap**2, axis=1)))), added


def _lost(sweeps: list[SweepFit]) -> list[str]:
    """Sweeps that lost more than half their samples, or all but two, to the outlier test."""
    return [f"sweep {s.sweep} (joint {s.joint})" for s in sweeps
            if s.joint > 0 and (s.rejected * 2 > s.samples or s.samples - s.rejected < 3)]


def _expected_accuracy(predictor: Predictor, q: Array, tp: NDArray[np.int64], adequacy: Adequacy) -> float:
    """RMS 3D prediction uncertainty at the fitted configurations (DH values with joint errors: the
    predictor without coupling), model error included (m)."""
    plain = replace(predictor, coefs=np.zeros_like(predictor.coefs))  # q already carries the joint errors
    cov = plain.covariances(q, tp)
    return float(np.sqrt(np.mean(np.trace(cov, axis1=1, axis2=2)) + 3 * adequacy.model_error**2))


def _adequacy(best: LinesFit, data: FitData, unit: float, declared: float | None) -> Adequacy:
    """Adequacy of ``best`` on its inliers (see :mod:`identify.adequacy`)."""
    inl = best.inliers
    rows = data.timed(best.timing).subset(inl)
    problem = rows.problem(best.lines, best.terms.subset(inl))
    zero = np.zeros(problem.size)
    runs = sweep_neighbours(rows.group, along_arc(best.q[inl], rows.joint))
    return assess(problem.residuals(zero).reshape(-1, 3), problem.jacobian_blocks(zero), rows.unknown, runs, unit,
                  declared)


def _tools(model: DHModel, lines: AxisLines) -> Array:
    """Every tracked point (k, 3) in the last DH frame of ``model``: the first is ``model.tool``, the others
    keep their offsets from it at home (the DH table may be refitted under a convention)."""
    flange = frames_from_joints(model, lines.home[None, :])[0, -1]
    return model.tool + (lines.tps - lines.tp_home) @ flange[:3, :3]


def _sweep_fit(sweep: int, joint: int, ref: Refinement, rows: NDArray[np.bool_]) -> SweepFit:
    good = rows & ref.inliers
    res = ref.residuals[good]
    rms = float(np.sqrt(np.mean(np.sum(res**2, axis=1)))) if len(res) else float("nan")
    return SweepFit(sweep, joint, int(rows.sum()), int((rows & ~ref.inliers).sum()), rms)


def _validate(check: Measurements, predictor: Predictor, adequacy: Adequacy) -> Validation:
    """Held-out rows (DH joint values: ``predictor`` is used without coupling)."""
    err = np.linalg.norm(check.points - predictor.points(check.q, check.tp), axis=1)
    cov = predictor.covariances(check.q, check.tp)
    bound = float(np.sqrt(np.mean(np.trace(cov, axis1=1, axis2=2))))
    noise2 = adequacy.noise**2 if check.sigma is None else float(np.mean(check.sigma**2))
    return Validation(len(check), float(np.sqrt(np.mean(err**2))), float(err.max()), bound,
                      float(np.sqrt(bound**2 + 3 * noise2 + 3 * adequacy.model_error**2)))
