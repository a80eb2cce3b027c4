"""The identification as one pure function: measurements in, identified model with its evidence out.

Geometric step (the paper) -> maximum-likelihood refinement -> uncertainties -> held-out validation.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from identify.cpa import DEFAULT_PARALLEL_TOL, GeometricResult, dh_from_axes, geometric_step
from identify.kinematics import DHModel, points_from_joints
from identify.measurements import Measurements, validate
from identify.poe import AxisLines, fit_lines
from identify.refine import (
    DEFAULT_MAX_OFFSET,
    Refinement,
    dh_index,
    full_jacobian,
    inlier_mask,
    parallel_links,
    parameter_names,
    refine,
    vector_from_model,
)

Array = NDArray[np.float64]

PARALLEL_SIGMAS = 3.0  # an alpha within this many standard uncertainties of 0 or pi counts as parallel
UNDETERMINED_D = 0.05  # m: a d less certain than this is left to the parallel-axis convention


@dataclass(frozen=True)
class FixedParameter:
    """A parameter the data cannot determine, held at ``value`` (rad or m) for ``reason``."""

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
    ``expected`` adds the tracker noise of the held-out measurements (what ``rms`` should be near).
    """

    samples: int
    rms: float
    max: float
    bound: float
    expected: float


@dataclass(frozen=True)
class Identification:
    """Identified model (``model``), standard uncertainties in the layout of
    :func:`identify.refine.parameter_names` (``std``), and the evidence behind them."""

    model: DHModel
    std: Array
    fixed: list[FixedParameter]
    geometric: GeometricResult
    refinement: Refinement
    sweeps: list[SweepFit]
    rejected_rows: list[int]
    validation: Validation | None
    parallel: list[int]
    convention: str
    warnings: list[str] = field(default_factory=list)

    @property
    def rms(self) -> float:
        """RMS 3D residual of the fitted inliers, m."""
        res = self.refinement.residuals[self.refinement.inliers]
        return float(np.sqrt(np.mean(np.sum(res**2, axis=1))))

    @property
    def geometric_rms(self) -> float:
        """RMS 3D residual of the same inliers under the geometric step's model (the paper's), m."""
        ref = self.refinement
        err = ref.points - points_from_joints(self.geometric.model, ref.q)
        return float(np.sqrt(np.mean(np.sum(err[ref.inliers] ** 2, axis=1))))


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


def _reason(name: str, n: int, types: str, parallel: list[int]) -> str:
    joint = int("".join(ch for ch in name if ch.isdigit()) or 0)
    if name.startswith("tool"):
        return "redundant with the base pose along a prismatic axis"
    if joint == 1 and name[:-1] in ("theta", "d"):
        return "redundant with the base pose (frame 0 is placed by convention)"
    if joint == n:
        return "redundant with the tool: frame n is placed by convention and the tool carries the TP"
    if types[joint - 1] == "P" and name[:-1] in ("a", "d"):
        return "a prismatic axis has no position; it is placed to meet the next axis"
    if joint in parallel or joint - 1 in parallel:
        return "axes parallel within tolerance: the common normal is placed by convention"
    return "not determined by these data"


def identify(
    meas: Measurements,
    nominal: DHModel | None = None,
    parallel_tol: float = DEFAULT_PARALLEL_TOL,
    robust: bool = True,
    max_offset: float = DEFAULT_MAX_OFFSET,
) -> Identification:
    """Identify the DH model from ``meas`` (fit rows; ``check`` rows are only used for validation).

    ``nominal`` (optional) supplies the conventional values of undetermined parameters and the signs
    of the x axes, so the result reads as deltas against it; identification never depends on it.
    ``max_offset`` (m): how far a near-parallel pair's ``d`` may move when the data resolve its misalignment.
    """
    warnings = validate(meas)
    if nominal is not None and nominal.joint_types != meas.joint_types:
        raise ValueError(f"nominal model has joints {nominal.joint_types}, data have {meas.joint_types}")
    conventional = None if nominal is None else nominal.dh_table()
    geo = geometric_step(meas, conventional, parallel_tol, nominal)
    usable = ~meas.check & np.all(np.isfinite(meas.q), axis=1)
    fit = meas.subset(usable)
    lines = _fitted_lines(geo, fit, robust)

    def start_model(parallel: list[int]) -> DHModel:
        return dh_from_axes(meas.joint_types, list(lines.points), list(lines.directions), lines.home,
                            lines.tp_home, _conventional(conventional, meas.n_joints), parallel_tol, nominal,
                            parallel)

    start = start_model([])
    parallel = parallel_links(start, parallel_tol)
    noise = max(geo.noise, 1e-9)
    ref = refine(start, fit.q, fit.points, fit.sigma, conventional, parallel, noise, robust, max_offset)
    unresolved = _parallel_within_uncertainty(ref, parallel)
    if unresolved:  # short or noisy sweeps: axes look skew only by noise; redo under the convention
        parallel = sorted({*parallel, *unresolved})
        ref = refine(start_model(parallel), fit.q, fit.points, fit.sigma, conventional, parallel, noise, robust,
                     max_offset)
    names = parameter_names(meas.n_joints)
    fixed = [
        FixedParameter(name, float(value), _reason(name, meas.n_joints, meas.joint_types, parallel))
        for name, value, is_free in zip(names, vector_from_model(ref.model), ref.free, strict=True)
        if not is_free
    ]
    sweeps = []
    for s in np.unique(fit.sweep[fit.joint > 0]):
        rows = fit.sweep == s
        sweeps.append(_sweep_fit(int(s), int(fit.joint[rows][0]), ref, rows))
    if np.any(fit.joint == 0):
        sweeps.append(_sweep_fit(0, 0, ref, fit.joint == 0))
    for s in sweeps:
        if s.rejected:
            warnings.append(f"sweep {s.sweep}: {s.rejected} sample(s) rejected as outliers")
    validation = _validate(meas.subset(meas.check), ref) if np.any(meas.check) else None
    return Identification(
        model=ref.model,
        std=ref.std(),
        fixed=fixed,
        geometric=geo,
        refinement=ref,
        sweeps=sweeps,
        rejected_rows=[int(r) for r in fit.row[~ref.inliers]],
        validation=validation,
        parallel=parallel,
        convention="nominal" if nominal is not None else "zero",
        warnings=warnings,
    )


def _conventional(conventional: Array | None, n: int) -> Array:
    return np.zeros((n, 4)) if conventional is None else conventional


def _fitted_lines(geo: GeometricResult, fit: Measurements, robust: bool) -> AxisLines:
    """Axis lines fitted to every sample with its joint readings, started from the paper's circles."""
    start = AxisLines(fit.joint_types, np.array([ax.point for ax in geo.axes]),
                      np.array([ax.direction for ax in geo.axes]), geo.home, geo.tp_home)
    weights = None if fit.sigma is None else 1.0 / fit.sigma
    lines, res = fit_lines(start, fit.q, fit.points, weights)
    keep = inlier_mask(res, 4 * fit.n_joints + 3)
    if robust and not np.all(keep):
        lines, _ = fit_lines(lines, fit.q[keep], fit.points[keep], None if weights is None else weights[keep])
    return lines


def _parallel_within_uncertainty(ref: Refinement, parallel: list[int]) -> list[int]:
    """Links not yet treated as parallel whose axes the data cannot tell from parallel: alpha within
    PARALLEL_SIGMAS standard uncertainties of 0 or pi, or a ``d`` more uncertain than UNDETERMINED_D."""
    std = ref.std()
    out = []
    for i in range(1, ref.model.n_joints):
        alpha, d = dh_index(i, "alpha"), dh_index(i, "d")
        if i in parallel:
            continue
        near_zero = ref.free[alpha] and abs(np.sin(ref.model.alpha[i - 1])) < PARALLEL_SIGMAS * std[alpha]
        if near_zero or (ref.model.joint_types[i - 1] == "R" and std[d] > UNDETERMINED_D):
            out.append(i)
    return out


def _sweep_fit(sweep: int, joint: int, ref: Refinement, rows: NDArray[np.bool_]) -> SweepFit:
    good = rows & ref.inliers
    res = ref.residuals[good]
    rms = float(np.sqrt(np.mean(np.sum(res**2, axis=1)))) if len(res) else float("nan")
    return SweepFit(sweep, joint, int(rows.sum()), int((rows & ~ref.inliers).sum()), rms)


def _validate(check: Measurements, ref: Refinement) -> Validation:
    predicted, jac = full_jacobian(ref.model, check.q)
    err = np.linalg.norm(check.points - predicted, axis=1)
    g = jac[:, :, ref.free]
    cov = g @ ref.covariance @ np.swapaxes(g, 1, 2)
    bound = float(np.sqrt(np.mean(np.trace(cov, axis1=1, axis2=2))))
    noise_var = 3 * ref.noise**2 if check.sigma is None else 3 * float(np.mean(check.sigma**2))
    return Validation(len(check), float(np.sqrt(np.mean(err**2))), float(err.max()), bound,
                      float(np.sqrt(bound**2 + noise_var)))
