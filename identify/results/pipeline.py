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

from identify.estimator.adequacy import Adequacy
from identify.estimator.cpa import DEFAULT_PARALLEL_TOL, GeometricResult
from identify.estimator.estimate import best_start
from identify.estimator.extensions import Decision, TermSet
from identify.estimator.measurements import Measurements
from identify.estimator.poe import AxisLines, points_from_lines
from identify.estimator.refine import Refinement
from identify.results import verdict as checks
from identify.results.hold import nominal_lines
from identify.results.predict import Predictor
from identify.results.stages import (
    ClockFit,
    SweepFit,
    add_notes,
    checked_measurements,
    clock_fit,
    clock_tested,
    fit_domain,
    fit_rows,
    fits_from_starts,
    held_out,
    joint_errors,
    orientation_fit,
    recommended,
    sweep_fits,
    verdict_of,
    written_models,
)
from identify.results.validation import Validation
from identify.results.written import FixedParameter, WrittenModel, robot_size, written_model
from kinematics.dh import DHModel, points_from_joints
from kinematics.joint_errors import Coupling, LinkMasses, gravity_torques

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Identification:
    """The identified models and the evidence behind them, ending in ``verdict``.

    ``models``: ``plain`` (standard DH, no joint errors: the result's top-level model) and, when the data support
    joint errors, ``extended`` (:class:`identify.results.written.WrittenModel`); ``use`` names the one the result
    recommends (the extended one only when the held-out rows validate it: :func:`identify.results.stages.recommended`)
    and ``validations`` holds each one's held-out figure from
    its written numbers. ``model``, ``std``, ``fixed``, ``lines``, ``tools``, ``refinement`` are the plain
    model's (what a plain reader of the result gets); ``predictor``, ``adequacy`` and ``validation`` the
    recommended one's (what compensation and verification use). ``domain`` (n, 2): each DH joint value's range over
    the recommended model's fit rows (rad or m), where its stated accuracies hold."""

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
    domain: Array | None = None
    orientation: tuple[int, int, float] | None = None  # orientation rows: count, rejected, RMS residual (rad)

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
        return float(np.sqrt(np.mean(np.sum(fit.residuals[fit.inliers & fit.positions] ** 2, axis=1))))

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
    noise_typed: str | None = None,
) -> Identification:
    """Identify the DH model from ``meas`` (fit rows; ``check`` rows are only used for validation).

    ``nominal`` (optional) starts a second fit (and the only one for free poses without sweeps), supplies
    the conventional values of redundant parameters and the signs of the x axes, and is checked against
    the data. ``noise`` (m per axis): the tracker's declared noise (the ``sigma`` column overrides it);
    ``noise_typed``: it as the operator typed it (``--noise 50um``), which a unit slip's hint repeats.
    ``max_offset`` (m): how far exact DH may move a near-parallel pair's ``d`` before the convention is kept
    (None: the robot's size, :func:`identify.results.written.robot_size`). ``links`` (with ``nominal``): link masses,
    for compliance; ``extensions``: select joint errors the fit rows support (:mod:`identify.estimator.extensions`).
    Readings are the controller's (``meas.coupling``); several tracked points (``meas.tp``) share the model, each with
    its own tool.

    The body reads as the data's way through the estimator: each call is one stage of :mod:`identify.results.stages`
    (its docstring gives inputs, outputs and units), and ``rows`` (:class:`identify.results.stages.FitRows`) carries the
    prepared fit rows through them.
    """
    coupling = meas.coupling
    meas, warnings = checked_measurements(meas, nominal)
    conventional = np.zeros((meas.n_joints, 4)) if nominal is None else nominal.dh_table()
    rows = fit_rows(meas, noise, warnings)
    geo, fits = fits_from_starts(rows, nominal, conventional, parallel_tol, robust, warnings)
    best, adequacy, clock_test = clock_tested(best_start(fits, rows.data), rows, robust)
    torques = None if links is None or nominal is None else (lambda x: gravity_torques(nominal, links, x))
    # joint errors referenced to the readings' zero, not to this data set's home: the extended model's DH offsets
    # then mean the same on every data set of the arm (a home that moved with the split moved them by c·τ(home))
    empty = TermSet((), np.zeros(meas.n_joints), torques)
    size = robot_size(best.lines, rows.meas.points)  # before joint errors
    cap = size if max_offset is None else max_offset
    # what the data do not determine is held at the nominal placed on them
    inl = best.inliers
    reference = None if nominal is None else nominal_lines(
        nominal, best.q[inl], rows.data.points[inl], rows.data.tp_index[inl], best.lines.home)
    if reference is not None:  # a nominal the data contradict is no measurement of the arm (the nominal check says so)
        missed = points_from_lines(reference, best.q[inl], rows.data.tp_index[inl]) - rows.data.points[inl]
        if np.sqrt(np.mean(np.sum(missed**2, axis=1))) > checks.NOMINAL_TOLERANCE * size:
            reference = None
    write = partial(written_model, tp_ids=tuple(meas.tp_ids), conventional=conventional, nominal=nominal,
                    parallel_tol=parallel_tol, max_offset=cap, unit=rows.unit, declared=rows.declared,
                    sigma=rows.meas.sigma, reference=reference, size=size)
    best, adequacy, extended, decisions = (joint_errors(best, adequacy, rows, empty) if extensions
                                           else (best, adequacy, None, []))
    models = written_models(write, rows, best, adequacy, empty, extended)
    check_rows = meas.subset(meas.check & np.all(np.isfinite(meas.q), axis=1))  # held out, every joint read
    validations = held_out(models, check_rows, meas.tp_ids)
    use, why_plain = recommended(models, validations, check_rows, meas.tp_ids)
    sweeps = sweep_fits(rows, models[use].refinement, warnings)
    clock = clock_fit(models[use], meas.clock_offset, clock_test)
    verdict = verdict_of(models, use, decisions, validations, sweeps, clock, rows, check_rows, nominal, meas.tp_ids,
                         why_plain, noise_typed)
    add_notes(models, use, decisions, len(fits), rows, warnings)
    return Identification(
        models=models,
        use=use,
        validations=validations,
        geometric=geo,
        sweeps=sweeps,
        rejected_rows=[int(r) for r in rows.meas.row[~models[use].fit.inliers & ~rows.meas.oriented]],
        orientation=orientation_fit(rows, models[use].refinement),
        convention="nominal" if nominal is not None else "zero",
        verdict=verdict,
        start=models["plain"].fit.start,
        coupling=coupling,
        decisions=decisions,
        warnings=warnings,
        clock=clock,
        domain=fit_domain(rows.meas.q[models[use].fit.inliers]),
    )


