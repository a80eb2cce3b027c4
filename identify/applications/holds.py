"""Does a calibration hold on new data? Re-register the tracker, then predict with each model (pure, no I/O).

A calibration predicts the tracked point (TP) in the tracker frame of the day it was made. On another day the
tracker stands elsewhere (and the reflector may have been re-mounted), so new measurements are first brought into
that frame by a rigid 6-DoF fit (closed-form Kabsch start, then a robust least-squares refinement), optionally with
each TP's position on the flange refitted too (``refit_tool``: 3 more parameters per point, which absorb a moved
reflector and anything else that looks like one, e.g. a changed last link). Gross errors (beam breaks) are found
on that fit and left out: rows beyond :data:`GROSS` times the residuals' robust scale, as long as they are a few
(at most :data:`GROSS_SHARE` of the rows; more are not beam breaks, and none is left out).

The registration's own parameters bend towards the data, so an in-sample RMS flatters the model. The figure that
decides is cross-validated: the poses are split into ``folds`` interleaved blocks, each block is predicted from a
registration fitted on the others, and the held-out errors are pooled. A dof-corrected in-sample RMS
(``sqrt(SS / (m - p / 3))``, p registration parameters, m rows) is reported beside it for information.

The verdict compares that cross-validated 3D RMS with what the result says a prediction should miss by
(``expected``: tracker noise, model uncertainty and model error): within :data:`WARN_RATIO` (or the chi-square
allowance of a small sample, whichever is larger) it holds; beyond :data:`FAIL_RATIO` it does not (another arm,
another tool, or the arm changed); in between it warns.

Frames: ``points`` are in the new tracker frame; models predict in the calibration's tracker frame. Units: m, rad.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

Array = NDArray[np.float64]

WARN_RATIO = 1.5  # cross-validated RMS / expected RMS above which the check warns
FAIL_RATIO = 3.0  # ... and above which it fails
GROSS = 6.0  # a row is gross beyond GROSS x the per-axis scale (robust, floored at expected / sqrt(3))
GROSS_SHARE = 0.1  # more rows beyond the cutoff than this share: not beam breaks; none left out, and a warning
FOLDS = 5
MIN_POSES = 6
CHI3_MEDIAN = float(np.sqrt(chi2.ppf(0.5, 3)))  # median 3D error norm / per-axis sigma (Gaussian, isotropic)


@dataclass(frozen=True)
class Model:
    """A model to check. ``points(q, tp)``: predicted TP (m, 3), calibration's tracker frame, at readings ``q``
    (m, n) for tracked point ids ``tp`` (m,). ``flange_rotations(q)``: (m, 3, 3) rotation of the flange frame
    in that tracker frame (needed only with ``refit_tool``). ``expected``: 3D RMS (m) a prediction should miss a
    measurement by on the new data (noise included)."""

    name: str
    points: Callable[[Array, NDArray[np.int64]], Array]
    expected: float
    flange_rotations: Callable[[Array], Array] | None = None


@dataclass(frozen=True)
class Registration:
    """New tracker <- calibration tracker frame: ``x_new = rotation @ x_old + translation``. ``moved``: how far
    the new tracker frame's origin (the tracker) stands from the old one, m; ``turned``: its rotation, rad;
    ``tools``: TP id -> change of its position on the flange (3,), m (zeros without ``refit_tool``)."""

    rotation: Array
    translation: Array
    tools: dict[int, Array]

    @property
    def moved(self) -> float:
        return float(np.linalg.norm(self.translation))

    @property
    def turned(self) -> float:
        return float(Rotation.from_matrix(self.rotation).magnitude())

    def to_calibration(self, points: Array) -> Array:
        """``points`` (..., 3) of the new tracker frame in the calibration's tracker frame, m."""
        return (np.asarray(points, dtype=float) - self.translation) @ self.rotation


@dataclass(frozen=True)
class Errors:
    """3D prediction errors of some rows: ``samples``, ``rms`` and ``max`` (m)."""

    samples: int
    rms: float
    max: float

    @classmethod
    def of(cls, norms: Array) -> Errors:
        if not len(norms):
            return cls(0, float("nan"), float("nan"))
        return cls(len(norms), float(np.sqrt(np.mean(norms**2))), float(norms.max()))


@dataclass(frozen=True)
class ModelCheck:
    """One model on the new data. ``heldout``: cross-validated errors (pooled) and ``per_tp`` (id -> errors);
    ``fitted``: in-sample errors after registering on every kept row, with ``fitted_dof_rms`` their dof-corrected
    RMS; ``gross``: 0-based rows left out; ``limit``: the ratio below which it holds; ``status``: pass, warn or
    fail, with ``reasons``."""

    name: str
    registration: Registration
    parameters: int
    heldout: Errors
    per_tp: dict[int, Errors]
    fitted: Errors
    fitted_dof_rms: float
    expected: float
    ratio: float
    limit: float
    gross: NDArray[np.int64]
    gross_cutoff: float
    status: str
    reasons: list[str]


@dataclass(frozen=True)
class Check:
    """Every model's check; ``status`` is that of the model ``use`` names."""

    models: list[ModelCheck]
    use: str
    folds: int
    refit_tool: bool

    @property
    def chosen(self) -> ModelCheck:
        return next(m for m in self.models if m.name == self.use)

    @property
    def status(self) -> str:
        return self.chosen.status


def tabulated(name: str, predicted: Array, expected: float) -> Model:
    """A :class:`Model` whose predictions were made beforehand: ``predicted`` (m, 3), calibration's tracker frame,
    one per row of the data it will be checked on (in that order); ``expected`` its 3D RMS error, m."""
    table = np.asarray(predicted, dtype=float)

    def points(q: Array, tp: NDArray[np.int64]) -> Array:
        if len(q) != len(table):
            raise ValueError(f"{len(table)} tabulated predictions for {len(q)} rows")
        return table

    return Model(name, points, float(expected))


def pose_groups(q: Array) -> NDArray[np.int64]:
    """Per row (m,), the 0-based pose it was measured at (rows of equal readings share one; in order of
    first appearance)."""
    _, first, inverse = np.unique(q, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(np.argsort(first))  # renumber poses by first appearance
    return order[inverse.ravel()]


def check_models(points: Array, q: Array, tp: NDArray[np.int64], models: list[Model], use: str | None = None,
                 refit_tool: bool = False, folds: int = FOLDS) -> Check:
    """Check each of ``models`` against TP ``points`` (m, 3, new tracker frame) measured at readings ``q`` (m, n)
    of tracked points ``tp`` (m,). ``use``: the model whose verdict is the check's (default the first).

    Raises ValueError (one line) when the data cannot register: non-finite values, or fewer than
    :data:`MIN_POSES` distinct poses.
    """
    points, q = np.asarray(points, dtype=float), np.asarray(q, dtype=float)
    tp = np.asarray(tp, dtype=np.int64)
    if not (np.all(np.isfinite(points)) and np.all(np.isfinite(q))):
        raise ValueError("the data hold non-finite positions or readings")
    poses = pose_groups(q)
    if poses.max(initial=-1) + 1 < MIN_POSES:
        raise ValueError(f"{poses.max(initial=-1) + 1} distinct poses: at least {MIN_POSES} are needed to register "
                         "the tracker and check the model")
    if refit_tool and any(m.flange_rotations is None for m in models):
        raise ValueError("refitting the tool needs each model's flange orientation")
    ids = sorted({int(t) for t in tp})
    tp_index = np.searchsorted(ids, tp)
    folds = int(min(folds, poses.max() + 1))
    out = [_check_one(m, points, q, tp, tp_index, ids, poses, refit_tool, folds) for m in models]
    return Check(out, use or models[0].name, folds, refit_tool)


def _check_one(model: Model, y: Array, q: Array, tp: NDArray[np.int64], tp_index: NDArray[np.int64], ids: list[int],
               poses: NDArray[np.int64], refit_tool: bool, folds: int) -> ModelCheck:
    p = np.asarray(model.points(q, tp), dtype=float)
    flange = model.flange_rotations(q) if refit_tool and model.flange_rotations is not None else None
    fit = _Fit(p, y, flange, tp_index, len(ids))
    every = np.ones(len(y), dtype=bool)
    x0 = fit.kabsch(every)
    floor = model.expected / np.sqrt(3.0)
    scale = max(_robust_scale(fit.norms(x0)), floor, 1e-9)
    x = fit.refine(x0, every, loss="soft_l1", scale=scale)
    cutoff = GROSS * max(_robust_scale(fit.norms(x)), floor)
    beyond = fit.norms(x) > cutoff
    too_many = beyond.sum() > GROSS_SHARE * len(y)  # not a few beam breaks: a systematic error is not hidden
    kept = np.ones(len(y), dtype=bool) if too_many else ~beyond
    x = fit.refine(x, kept)
    fitted = fit.norms(x)[kept]
    held = np.full(len(y), np.nan)
    block = poses % folds
    for k in range(folds):
        train, test = kept & (block != k), kept & (block == k)
        if test.any():
            held[test] = fit.norms(fit.refine(x, train))[test]
    held_kept = held[kept]
    heldout = Errors.of(held_kept)
    per_tp = {i: Errors.of(held[kept & (tp == i)]) for i in ids}
    m_rows, n_par = int(kept.sum()), fit.size
    dof_rms = float(np.sqrt(np.sum(fitted**2) / max(m_rows - n_par / 3, 1.0)))
    ratio = heldout.rms / model.expected if model.expected > 0 else float("inf")
    limit = max(WARN_RATIO, float(np.sqrt(chi2.ppf(0.999, 3 * m_rows) / (3 * m_rows))))
    status, reasons = _status(ratio, limit, int(beyond.sum()) if too_many else 0, len(y), cutoff)
    return ModelCheck(model.name, fit.registration(x, ids), n_par, heldout, per_tp, Errors.of(fitted), dof_rms,
                      model.expected, ratio, limit, np.flatnonzero(~kept), cutoff, status, reasons)


def _status(ratio: float, limit: float, beyond: int, rows: int, cutoff: float) -> tuple[str, list[str]]:
    """pass, warn or fail, and why; ``beyond`` rows past the gross ``cutoff`` (m) that were too many to leave
    out (0 when they were left out)."""
    reasons = []
    if beyond:
        reasons.append(f"{beyond} of {rows} rows miss by more than {cutoff * 1e3:.2f} mm: too many for beam breaks, "
                       "none left out")
    if ratio > max(FAIL_RATIO, 2 * limit):
        return "fail", [f"held-out RMS {ratio:.1f}x the expected: another arm, another tool, or the arm changed",
                        *reasons]
    if ratio > limit:
        reasons.append(f"held-out RMS {ratio:.2f}x the expected (limit {limit:.2f}x)")
    return ("warn" if reasons else "pass"), reasons


def _robust_scale(norms: Array) -> float:
    """Per-axis sigma from 3D error norms, by their median (isotropic Gaussian errors)."""
    return float(np.median(norms)) / CHI3_MEDIAN if len(norms) else 0.0


class _Fit:
    """Registration of predictions ``p`` (m, 3) onto measurements ``y`` (m, 3): parameters are a rotation
    vector (applied on the left of the start rotation), a translation and, with ``flange`` (m, 3, 3), a change
    of each tracked point's position on the flange (3 per point, flange frame)."""

    def __init__(self, p: Array, y: Array, flange: Array | None, tp_index: NDArray[np.int64], n_tp: int):
        self.p, self.y, self.flange, self.tp_index = p, y, flange, tp_index
        self.n_tp = n_tp if flange is not None else 0
        self.size = 6 + 3 * self.n_tp
        self.start = np.eye(3)

    def kabsch(self, rows: NDArray[np.bool_]) -> Array:
        """Closed-form rigid fit on ``rows``; sets the start rotation and returns the parameters (zero rotation
        increment)."""
        p, y = self.p[rows], self.y[rows]
        rot, _ = Rotation.align_vectors(y - y.mean(axis=0), p - p.mean(axis=0))
        self.start = rot.as_matrix()
        x = np.zeros(self.size)
        x[3:6] = y.mean(axis=0) - self.start @ p.mean(axis=0)
        return x

    def predict(self, x: Array) -> Array:
        p = self.p
        if self.flange is not None:
            tools = x[6:].reshape(self.n_tp, 3)
            p = p + np.einsum("kij,kj->ki", self.flange, tools[self.tp_index])
        rot = Rotation.from_rotvec(x[:3]).as_matrix() @ self.start
        return p @ rot.T + x[3:6]

    def norms(self, x: Array) -> Array:
        return np.linalg.norm(self.predict(x) - self.y, axis=1)

    def refine(self, x: Array, rows: NDArray[np.bool_], loss: str = "linear", scale: float = 1.0) -> Array:
        """Least squares on ``rows`` from ``x`` (a robust ``loss`` with ``scale`` m per axis)."""
        def residuals(v: Array) -> Array:
            return (self.predict(v)[rows] - self.y[rows]).ravel()

        return least_squares(residuals, x, loss=loss, f_scale=scale, x_scale="jac", method="trf" if loss != "linear"
                             else "lm", xtol=1e-12, ftol=1e-12, gtol=1e-12).x

    def registration(self, x: Array, ids: list[int]) -> Registration:
        rot = Rotation.from_rotvec(x[:3]).as_matrix() @ self.start
        tools = x[6:].reshape(-1, 3) if self.n_tp else np.zeros((len(ids), 3))
        return Registration(rot, x[3:6].copy(), {i: tools[k].copy() for k, i in enumerate(ids)})
