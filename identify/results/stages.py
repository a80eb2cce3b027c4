"""The stages of :func:`identify.results.pipeline.identify`, in the order it runs them, each a function of what the ones
before it made: the readings checked and prepared (:class:`FitRows`), the lines fitted from every start, the clock
split tested, joint errors selected, the models written as DH, the held-out rows validated, the residuals per sweep,
the clock relation, the verdict and the notes. Units: m and rad (or m for prismatic joints); points in the tracker
frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial

import numpy as np
from numpy.typing import NDArray

from common.errors import InputError
from identify.estimator.adequacy import Adequacy, assess
from identify.estimator.cpa import GeometricResult, home_from_measurements
from identify.estimator.dh_vector import full_jacobian, parameter_names
from identify.estimator.estimate import FitData, LinesFit, along_arc, fit, fit_kept, place_nominal, readmit
from identify.estimator.extend import select_terms
from identify.estimator.extensions import Decision, TermSet, candidates
from identify.estimator.identifiability import Identifiability, identifiability
from identify.estimator.measurements import Measurements, in_dh_joints, orientation_rows, prepared_joints, validate
from identify.estimator.orientation import matrices_from_rotvecs
from identify.estimator.outliers import sweep_neighbours
from identify.estimator.poe import LineProblem, points_from_lines
from identify.estimator.refine import Refinement, orientation_blocks
from identify.estimator.starts import starts
from identify.estimator.sync import retiming
from identify.results import verdict as checks
from identify.results.clock_split import ClockSplit, split_clock
from identify.results.validation import TurnValidation, Validation, validate_turns
from identify.results.validation import validate as validate_model
from identify.results.written import UNDETERMINED, WrittenModel, robot_size
from kinematics.dh import DHModel, points_from_joints

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
    ``test``: whether the sweeps needed an offset each (:mod:`identify.results.clock_split`); when they did,
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
class FitRows:
    """The fit rows (``check`` rows left out) as the estimator sees them. ``meas``: those rows, DH joints, each
    measured orientation a row of its own after the position rows (``meas.oriented`` marks them:
    :func:`identify.estimator.measurements.orientation_rows`);
    ``data``: their prepared readings (unread joints named), tracker-frame points (m), weights 1/sigma, tracked
    points and neighbour groups; ``home`` (n,) every joint's home reading (rad or m); ``numbers`` {sweep id:
    1-based sweep number}; ``sweep_group`` (m,) each row's sweep number (0: free pose); ``unit``: the weights'
    scale (median sigma m, or 1); ``declared``: the tracker noise declared (m per axis) or None."""

    meas: Measurements
    data: FitData
    home: Array
    numbers: dict[int, int]
    sweep_group: NDArray[np.int64]
    unit: float
    declared: float | None


def fit_domain(q: Array) -> Array | None:
    """The domain (n, 2) of DH joint values ``q`` (m, n): each joint's [min, max] over the rows that read it
    (NaN for a joint no row reads); None without rows."""
    q = np.asarray(q, dtype=float)
    if q.ndim != 2 or not len(q):
        return None
    read = np.isfinite(q)
    domain = np.stack([np.where(read, q, np.inf).min(axis=0), np.where(read, q, -np.inf).max(axis=0)], axis=1)
    domain[~read.any(axis=0)] = np.nan
    return domain


def checked_measurements(meas: Measurements, nominal: DHModel | None) -> tuple[Measurements, list[str]]:
    """``meas`` in DH joints (its coupling applied, sweeps relabelled by the joint they move), checked; and the
    warnings so far. Raises InputError (unusable data) or ValueError (``nominal``'s joints are not the data's)."""
    meas, relabelled = in_dh_joints(meas)
    try:
        warnings = validate(meas, with_nominal=nominal is not None) + relabelled
    except InputError as exc:  # say what the coupling did to the sweeps when it matters
        raise InputError("; ".join([str(exc), *relabelled])) from None
    if nominal is not None and nominal.joint_types != meas.joint_types:
        raise ValueError(f"nominal model has joints {nominal.joint_types}, data have {meas.joint_types}")
    return meas, warnings


def fit_rows(meas: Measurements, noise: float | None, warnings: list[str] | None = None) -> FitRows:
    """The rows of ``meas`` that are not held out, prepared for the fit; ``noise``: the declared noise (m per axis),
    which a ``sigma`` column overrides. Neighbours (for the outlier test) share a sweep, a tracked point and a kind
    (position or orientation). Appends to ``warnings`` the orientations left unused."""
    fitm, notes = orientation_rows(meas.subset(~meas.check))
    if warnings is not None:
        warnings.extend(notes)
    home = home_from_measurements(fitm)
    q, unknown = prepared_joints(fitm, home)
    tp_index = np.searchsorted(meas.tp_ids, fitm.tp)
    weights = np.ones(len(q)) if fitm.sigma is None else 1.0 / fitm.sigma
    numbers = {s: k + 1 for k, s in enumerate(np.unique(fitm.sweep[fitm.joint > 0]))}
    sweep_group = np.array([numbers.get(int(s), 0) if j > 0 else 0 for s, j in zip(fitm.sweep, fitm.joint,
                                                                                     strict=True)])
    oriented = fitm.oriented
    kinds = 2 if np.any(oriented) else 1
    group = np.where(sweep_group > 0, (sweep_group * len(meas.tp_ids) + tp_index) * kinds + oriented, 0)
    timing = None if fitm.t is None else retiming(fitm.t, fitm.streamed, fitm.sweep, q)
    rotations = matrices_from_rotvecs(fitm.rotvec) if np.any(oriented) else None
    data = FitData(q, fitm.points, weights, unknown, tp_index, group, fitm.joint, timing, rotations)
    unit = 1.0 if fitm.sigma is None else float(np.median(fitm.sigma[~oriented]))
    declared = unit if fitm.sigma is not None else noise
    return FitRows(fitm, data, home, numbers, sweep_group, unit, declared)


def fits_from_starts(rows: FitRows, nominal: DHModel | None, conventional: Array, parallel_tol: float,
                     robust: bool, warnings: list[str]) -> tuple[GeometricResult | None, list[LinesFit]]:
    """The geometric step (None without a sweep of every joint) and a maximum-likelihood lines fit from every start
    it and ``nominal`` give (:mod:`identify.estimator.starts`); appends to ``warnings`` what the starts lost."""
    geo, found = starts(rows.meas, rows.data.q, rows.data.unknown, rows.data.tp_index, rows.home, nominal,
                        conventional, parallel_tol, warnings)
    return geo, [fit(start, rows.data, robust, label) for label, start in found]


def clock_tested(best: LinesFit, rows: FitRows, robust: bool) -> tuple[LinesFit, Adequacy, ClockSplit | None]:
    """``best`` refitted with one clock offset per sweep when the streamed sweeps need it
    (:mod:`identify.results.clock_split`), its adequacy, and the test (None without streamed sweeps)."""
    adequacy = _adequacy(best, rows)
    best, test = split_clock(best, rows.data, robust, max(adequacy.residual, rows.declared or 0.0) ** 2 / rows.unit**2)
    if test is not None and test.split:
        adequacy = _adequacy(best, rows)
    return best, adequacy, test


def joint_errors(best: LinesFit, adequacy: Adequacy, rows: FitRows, empty: TermSet
                 ) -> tuple[LinesFit, Adequacy, tuple[LinesFit, TermSet] | None, list[Decision]]:
    """The joint errors the fit rows support (:mod:`identify.estimator.extend`): the plain fit ``best`` and its adequacy
    (refitted without the rows the joint errors explain), the extended fit with its terms (None when none was
    selected) and every selection decision."""
    data, q = rows.data.timed(best.timing), rows.data.q
    pool = candidates(rows.meas.joint_types, q[best.inliers], empty.torques)
    variance = max(adequacy.noise, rows.declared or 0.0) ** 2 / rows.unit**2
    terms, _, decisions = select_terms(best, data, empty, pool, variance)
    if not terms.candidates:
        return best, adequacy, None, decisions
    # refitted on the plain model's inliers: joint errors never make outliers
    extended_fit = readmit(fit_kept(best.lines, data, best.inliers, best.start, terms.terms(q, None, best.q)),
                           rows.data)
    if not np.array_equal(extended_fit.inliers, best.inliers):  # rows the joint errors explain are not gross
        best = fit_kept(best.lines, data, extended_fit.inliers, best.start, best.terms)
        adequacy = _adequacy(best, rows)
    return best, adequacy, (extended_fit, terms), decisions


def written_models(write: Callable[..., WrittenModel], rows: FitRows, best: LinesFit, adequacy: Adequacy,
                   empty: TermSet, extended: tuple[LinesFit, TermSet] | None) -> dict[str, WrittenModel]:
    """The plain fit ``best`` and the ``extended`` one (when selected) written as DH by ``write``."""
    models = {"plain": write("plain", best, rows.data, adequacy, empty)}
    if extended is not None:
        fitted, terms = extended
        models["extended"] = write("extended", fitted, rows.data, _adequacy(fitted, rows), terms)
    return models


def held_out(models: dict[str, WrittenModel], check_rows: Measurements, tp_ids: list[int]) -> dict[str, Validation]:
    """Each model's held-out figure from its written numbers on ``check_rows`` (empty without any); ``tp_ids``:
    the tracked points' ids in the models' order."""
    if not len(check_rows):
        return {}
    return {name: replace(validate_model(check_rows.q, check_rows.points, check_rows.tp, check_rows.sigma,
                                         partial(_written_points, m, tp_ids), m.predictor, m.adequacy.noise,
                                         m.adequacy.model_error), orientation=_held_out_turns(m, check_rows, tp_ids))
            for name, m in models.items()}


def _held_out_turns(model: WrittenModel, rows: Measurements, tp_ids: list[int]) -> TurnValidation | None:
    """The held-out orientations of the first tracked point (the one ``tool_frame`` describes) against the
    written model (None without any); the bound through the DH table's and the frame turn's covariance."""
    turned = rows.oriented & (rows.tp == tp_ids[0]) & np.all(np.isfinite(rows.q), axis=1)
    if model.frames is None or not np.any(turned) or not np.all(np.isfinite(model.frames[0])):
        return None
    check = rows.subset(turned)
    measured = matrices_from_rotvecs(check.rotvec)
    jacobian = None
    if model.turn_covariance is not None:
        q = model.dh_joints(check.q)
        jacobian = orientation_blocks(model.model, model.refinement.free, q, measured, model.frames[0],
                                      np.ones(len(q)))
    return validate_turns(model.dh_rotations(check.q, np.zeros(len(check), dtype=np.int64)), measured,
                          check.sigma_r, jacobian, model.turn_covariance)


def sweep_fits(rows: FitRows, ref: Refinement, warnings: list[str]) -> list[SweepFit]:
    """Residuals of every sweep, then of the free poses (when any), under the refinement ``ref``; appends a warning
    for each sweep with rejected rows, and one naming the rows whose orientation alone was rejected (metres: the
    position rows; orientations are summed up in :func:`orientation_fit`)."""
    joint, group, positions = rows.meas.joint, rows.sweep_group, ~rows.meas.oriented
    sweeps = [_sweep_fit(int(sid), int(joint[group == g][0]), ref, (group == g) & positions)
              for sid, g in rows.numbers.items()]
    if np.any(joint == 0):
        sweeps.append(_sweep_fit(0, 0, ref, (joint == 0) & positions))
    warnings.extend(f"sweep {sw.sweep}: {sw.rejected} sample(s) rejected as outliers" for sw in sweeps if sw.rejected)
    turned = rows.meas.oriented & ~ref.inliers
    if np.any(turned):
        lines = ", ".join(str(int(r)) for r in rows.meas.row[turned][:10])
        warnings.append(f"{int(turned.sum())} orientation(s) rejected as outliers, their positions kept: line(s) "
                        f"{lines}{' ...' if turned.sum() > 10 else ''}")
    return sweeps


def orientation_fit(rows: FitRows, ref: Refinement) -> tuple[int, int, float] | None:
    """The orientation rows' (count, rejected, RMS 3D residual of the kept ones, rad) under ``ref``; None without."""
    turning = rows.meas.oriented
    if not np.any(turning):
        return None
    kept = ref.residuals[turning & ref.inliers]
    rms = float(np.sqrt(np.mean(np.sum(kept**2, axis=1)))) if len(kept) else float("nan")
    return int(turning.sum()), int(np.sum(turning & ~ref.inliers)), rms


def clock_fit(model: WrittenModel, offset: float, test: ClockSplit | None) -> ClockFit | None:
    """The clock relation fitted with ``model`` (None without streamed rows); ``offset`` (s): the recording's coarse
    one; ``test``: whether the sweeps needed one offset each."""
    timing = model.fit.timing
    if timing is None:
        return None
    n = model.problem.n_terms
    std = np.sqrt(np.clip(np.diag(model.covariance[n:, n:]), 0.0, None))
    k = timing.offsets
    drift, drift_std = (float(timing.tau[k]), float(std[k])) if timing.drift else (None, None)
    oriented = model.fit.oriented if model.fit.oriented is not None else np.zeros(len(timing.t), dtype=bool)
    rows = int(np.sum(timing.rows & ~oriented))  # the streamed samples (not their orientation rows)
    if k == 1:
        return ClockFit(offset + float(timing.tau[0]), float(std[0]), drift, drift_std, timing.t_ref, rows, test)
    offsets, stds = offset + timing.tau[:k], np.maximum(std[:k], 1e-300)
    mean = float(np.sum(offsets / stds**2) / np.sum(1 / stds**2))
    sweeps = tuple((int(s), float(o), float(e)) for s, o, e in zip(np.unique(timing.sweep), offsets, std[:k],
                                                                     strict=True))
    return ClockFit(mean, float(np.max(std[:k])), drift, drift_std, timing.t_ref, rows, test, sweeps)


def recommended(models: dict[str, WrittenModel], validations: dict[str, Validation], check_rows: Measurements,
                tp_ids: list[int]) -> tuple[str, str]:
    """The model the held-out rows support (``plain`` or ``extended``) and, when the joint errors are not it, why
    (:func:`identify.results.verdict.recommended`)."""
    plain, ext = validations.get("plain"), validations.get("extended")
    if "extended" not in models:
        return "plain", ""
    if plain is None or ext is None:
        return checks.recommended((0.0, 0.0), (0.0, 0.0), 0, None)
    return checks.recommended((plain.rms, plain.expected), (ext.rms, ext.expected), ext.samples,
                              _moved(models, tp_ids, check_rows))


def verdict_of(models: dict[str, WrittenModel], use: str, decisions: list[Decision], validations: dict[str, Validation],
               sweeps: list[SweepFit], clock: ClockFit | None, rows: FitRows, check_rows: Measurements,
               nominal: DHModel | None, tp_ids: list[int], why_plain: str = "",
               noise_typed: str | None = None) -> checks.Verdict:
    """The checks of the recommended model ``models[use]`` (:mod:`identify.results.verdict`): fit, conditioning,
    outliers, the DH table; then, when they apply, the clock and the nominal model; and the held-out rows, or
    that nothing was held out. ``why_plain``: why joint errors in ``models`` are not recommended; ``noise_typed``:
    the declared noise as typed (``--noise``), for the hint of a unit slip."""
    used, plain = models[use], models["plain"]
    inl = used.fit.inliers
    size = robot_size(plain.lines, rows.meas.points)
    found = [
        checks.model_fit(used.fit_rms, used.adequacy, _cause(models, decisions), noise_typed,
                         rows.meas.sigma is not None),
        checks.conditioning(used.condition, _identifiability(used, size), () if used.held is None else used.held.names,
                            used.held is not None and used.held.model_error),
        checks.outliers(int(np.sum(~inl)), len(inl), _lost(sweeps)),
        plain.dh_check,
    ]
    if clock is not None:
        speed = _tp_speed(used.jacobian_blocks, used.problem, rows.data.weights[inl])
        found.append(checks.timing(clock.offset_std, speed, used.adequacy.noise, clock.test,
                                   [o for _, o, _ in clock.sweeps]))
    if validations:
        v = validations[use]
        others = {k: (w.rms, w.expected) for k, w in validations.items() if k != use}
        found.append(checks.holdout(v.samples, v.rms, v.expected, use, others, _moved(models, tp_ids, check_rows),
                                    why_plain))
        if v.orientation is not None and v.orientation.samples:
            t = v.orientation
            found.append(checks.holdout_orientation(t.samples, t.rms, t.expected, use))
    else:
        found.append(checks.not_validated("extended" in models))
    known = rows.data.unknown < 0
    if nominal is not None and np.sum(known) >= 3:
        found.append(checks.nominal("model", _nominal_gap(nominal, plain, known), size, plain.expected))
    return checks.Verdict(tuple(found))


def add_notes(models: dict[str, WrittenModel], use: str, decisions: list[Decision], starts: int, rows: FitRows,
              warnings: list[str]) -> None:
    """Appends the joint errors selected to ``warnings``, and to the recommended model's refinement notes the start
    it was fitted from (of ``starts``), the reduced chi-square (with a sigma column) and any covariance inflation."""
    if decisions:
        kept = [d.candidate.names for d in decisions if d.selected]
        warnings.append("joint errors selected: " + (", ".join(n for names in kept for n in names) if kept else "none"))
    notes = [f"fitted from the {models['plain'].fit.start}" + (f" (of {starts} starts)" if starts > 1 else "")]
    a = models[use].adequacy
    if rows.meas.sigma is not None:
        notes.append(f"reduced chi-square {a.statistic:.3g} (1 when the given sigma is right)")
    if a.inflation > 1.0:
        notes.append(f"residuals correlated along the arcs (lag-1 {a.rho:.2f}): covariance inflated {a.inflation:.3g}x")
    models[use].refinement.notes.extend(notes)


def _nominal_gap(nominal: DHModel, plain: WrittenModel, known: NDArray[np.bool_]) -> float:
    """RMS distance (m) between the plain model's predictions at the ``known`` fit rows (every joint read) and the
    nominal model placed on them (with the plain model's first tool)."""
    q = plain.fit.q[known]
    at = points_from_lines(plain.lines, q)
    placed, _ = place_nominal(nominal, q, at, tool=plain.tools[0])
    gap = points_from_joints(placed, q) - at
    return float(np.sqrt(np.mean(np.sum(gap**2, axis=1))))


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
    """RMS speed (m/s) of the tracked point over the streamed position rows: the Jacobian column of the clock
    offset (an orientation row's is the frame's turning rate, rad/s: not counted)."""
    rows = problem.timing.rows & ~problem.oriented
    velocity = jac_blocks[rows, :, problem.n_terms] / weights[rows, None]
    return float(np.sqrt(np.mean(np.sum(velocity**2, axis=1))))


def _lost(sweeps: list[SweepFit]) -> list[str]:
    """Sweeps that lost more than half their samples, or all but two, to the outlier test."""
    return [f"sweep {s.sweep} (joint {s.joint})" for s in sweeps
            if s.joint > 0 and (s.rejected * 2 > s.samples or s.samples - s.rejected < 3)]


def _adequacy(best: LinesFit, rows: FitRows) -> Adequacy:
    """Adequacy of ``best`` on its inliers of ``rows`` (see :mod:`identify.estimator.adequacy`)."""
    inl = best.inliers
    kept = rows.data.timed(best.timing).subset(inl)
    problem = kept.problem(best.lines, best.terms.subset(inl))
    zero = np.zeros(problem.size)
    runs = sweep_neighbours(kept.group, along_arc(best.q[inl], kept.joint))
    return assess(problem.residuals(zero).reshape(-1, 3), best.jacobian_blocks(problem), kept.unknown, runs,
                  rows.unit, rows.declared)


def _sweep_fit(sweep: int, joint: int, ref: Refinement, rows: NDArray[np.bool_]) -> SweepFit:
    """The residuals of the fit ``rows`` of one sweep (id ``sweep``, moving ``joint``; 0, 0: the free poses)."""
    good = rows & ref.inliers
    res = ref.residuals[good]
    rms = float(np.sqrt(np.mean(np.sum(res**2, axis=1)))) if len(res) else float("nan")
    return SweepFit(sweep, joint, int(rows.sum()), int((rows & ~ref.inliers).sum()), rms)


