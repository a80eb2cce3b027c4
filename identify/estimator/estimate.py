"""The maximum-likelihood estimate in the axis-line parameterisation, robust to gross outliers.

Every sample is used: rows with all readings, rows of sweeps jogged by hand and positions-only rows (their
unread joint a nuisance parameter, see :mod:`identify.estimator.poe`). The fit starts from each start it is given
(the paper's circles, the nominal model placed on the data) and keeps the one with the best robust cost.
Frames: tracker; units: metres and radians.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from identify.estimator.geometry import left_jacobian, skew, unit
from identify.estimator.outliers import NOISE_FLOOR, leverages, outlier_free
from identify.estimator.poe import (
    STOP_SIGMAS,
    AxisLines,
    JointTerms,
    LeastSquares,
    LineProblem,
    converged_tolerance,
    lines_from_model,
)
from identify.estimator.sync import Retiming
from identify.estimator.tall_lsq import is_tall, solve_tall
from kinematics.dh import DHModel, flange_frames, frames_from_joints

Array = NDArray[np.float64]

ROBUST_WIDTH = 3.0  # soft-L1 scale, in robust noise standard deviations
PLACE_ITERATIONS = 3  # alternations before the joint least-squares finish
ROBUST_PASSES = 2


@dataclass(frozen=True)
class LinesFit:
    """A fitted lines model. ``q`` (m, n): joint values with joint errors applied and the unread values
    solved; ``inliers`` (m,); ``residuals`` (m, 3) measured minus predicted, metres; ``robust_cost`` its
    soft-L1 cost on its own noise scale (starts are compared on a common one: :func:`best_start`); ``terms``
    the joint errors fitted with the lines; ``timing`` the streamed rows' clock correction (None without
    streamed rows); ``jacobian`` (m, 3, p): the weighted, projected Jacobian blocks of every row at the fit
    (:meth:`identify.estimator.poe.LineProblem.jacobian_blocks` at zero), when the fit computed them (else None);
    ``oriented`` (m,) the orientation rows, whose ``residuals`` are rad (None: no orientation row)."""

    lines: AxisLines
    q: Array
    inliers: NDArray[np.bool_]
    residuals: Array
    robust_cost: float
    start: str
    terms: JointTerms
    timing: Retiming | None = None
    jacobian: Array | None = field(default=None, repr=False)
    oriented: NDArray[np.bool_] | None = None

    @property
    def positions(self) -> NDArray[np.bool_]:
        """The position rows (m,): residuals in metres."""
        return np.ones(len(self.q), dtype=bool) if self.oriented is None else ~self.oriented

    def jacobian_blocks(self, problem: LineProblem) -> Array:
        """The Jacobian blocks of ``problem`` at zero, where ``problem`` is this fit's on its inliers."""
        if self.jacobian is None:
            return problem.jacobian_blocks(np.zeros(problem.size))
        return self.jacobian if np.all(self.inliers) else self.jacobian[self.inliers]


ALIGNED = 0.05  # of the points' spread: a placement missing by less has aligned the data (a stalled one misses by it)


def place_nominal(nominal: DHModel, q: Array, points: Array, tp_index: NDArray[np.int64] | None = None,
                  tool: Array | None = None) -> tuple[DHModel, Array]:
    """``nominal`` with the base (tracker <- frame 0) and tool (TP in frame n) that best fit ``points``
    (m, 3) at readings ``q`` (m, n): alternately a point-set fit of the base (Kabsch) and a linear fit of
    the TP, from the flange, on the first tracked point's rows; then every tracked point's tool (k, 3)
    with the base jointly (``tp_index`` (m,), 0-based; default all the first).

    A robot file carries no tool, and where the flange origin barely moves (an arm of two intersecting
    axes) a zero tool gives the base fit nothing to align; the fit therefore also starts from a tool of
    the points' spread along each flange axis, and keeps the start that fits best, unless the first start (the
    given ``tool`` (3,), m in frame n, or zero) already misses by less than :data:`ALIGNED` of the spread."""
    tp_index = np.zeros(len(q), dtype=np.int64) if tp_index is None else tp_index
    count = int(tp_index.max()) + 1 if len(tp_index) else 1
    flange_rot, flange_origin = flange_frames(replace(nominal, base=np.eye(4)), q)  # frame n in frame 0
    spread = float(np.sqrt(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=1))))
    first = np.zeros(3) if tool is None else np.asarray(tool, dtype=float)
    best: tuple[float, Array, Array] | None = None
    for start in (first, *(sign * spread * axis for axis in np.eye(3) for sign in (1.0, -1.0))):
        cost, base, tools = _placed(flange_rot, flange_origin, points, tp_index, count, start)
        if best is None or cost < best[0] * (1.0 - 1e-9):
            best = (cost, base, tools)
        if np.sqrt(best[0] / len(points)) < ALIGNED * spread:
            break
    assert best is not None
    _, base, tools = best
    return replace(nominal, base=base.copy(), tool=tools[0].copy()), tools.copy()


def _placed(flange_rot: Array, flange_origin: Array, points: Array, tp_index: NDArray[np.int64], count: int,
            tool: Array) -> tuple[float, Array, Array]:
    """One placement of :func:`place_nominal` from the first point's ``tool`` (m, frame n): its sum of squared
    residuals (m^2), base (4, 4) and tools (count, 3)."""
    first = tp_index == 0
    rots, origins, points_first = flange_rot[first], flange_origin[first], points[first]
    base = np.eye(4)
    with warnings.catch_warnings():  # a start whose TP does not move leaves the rotation undefined: tried anyway
        warnings.simplefilter("ignore", UserWarning)
        for _ in range(PLACE_ITERATIONS):
            local = np.einsum("kij,j->ki", rots, tool) + origins  # TP in frame 0
            centre_l, centre_p = local.mean(axis=0), points_first.mean(axis=0)
            rot, _ = Rotation.align_vectors(points_first - centre_p, local - centre_l)
            base[:3, :3] = rot.as_matrix()
            base[:3, 3] = centre_p - base[:3, :3] @ centre_l
            # TP: points = R_b (R_k t + o_k) + t_b  ->  linear least squares in t
            a = np.einsum("ij,kjl->kil", base[:3, :3], rots).reshape(-1, 3)
            rhs = (points_first - (origins @ base[:3, :3].T + base[:3, 3])).reshape(-1)
            new_tool = np.linalg.lstsq(a, rhs, rcond=None)[0]
            if np.linalg.norm(new_tool - tool) < 1e-12:
                tool = new_tool
                break
            tool = new_tool

    # the other tracked points: linear least squares with the base found
    tools = np.tile(tool, (count, 1))
    for p in range(1, count):
        rows = tp_index == p
        a = np.einsum("ij,kjl->kil", base[:3, :3], flange_rot[rows]).reshape(-1, 3)
        rhs = (points[rows] - (flange_origin[rows] @ base[:3, :3].T + base[:3, 3])).reshape(-1)
        tools[p] = np.linalg.lstsq(a, rhs, rcond=None)[0]

    def placed(x: Array) -> tuple[Array, Array]:  # TP in frame 0 and the base rotation at x
        local = np.einsum("kij,kj->ki", flange_rot, x[6:].reshape(-1, 3)[tp_index]) + flange_origin
        return local, Rotation.from_rotvec(x[:3]).as_matrix() @ base[:3, :3]

    def residuals(x: Array) -> Array:  # the alternation can stall on short arcs: finish jointly
        local, rot = placed(x)
        return (local @ rot.T + x[3:6] - points).ravel()

    def jacobian(x: Array) -> Array:
        local, rot = placed(x)
        jac = np.zeros((len(points), 3, 6 + 3 * count))
        jac[:, :, 0:3] = -skew(local @ rot.T) @ left_jacobian(x[:3])
        jac[:, :, 3:6] = np.eye(3)
        turned = np.einsum("ij,kjl->kil", rot, flange_rot)
        for p in range(count):
            rows = tp_index == p
            jac[rows, :, 6 + 3 * p:9 + 3 * p] = turned[rows]
        return jac.reshape(-1, jac.shape[2])

    tol = converged_tolerance(points.size)
    solved = least_squares(residuals, np.concatenate([np.zeros(3), base[:3, 3], tools.ravel()]), jac=jacobian,
                           method="lm", xtol=tol, ftol=tol)
    x = solved.x
    base[:3, :3] = Rotation.from_rotvec(x[:3]).as_matrix() @ base[:3, :3]
    base[:3, 3] = x[3:6]
    return float(np.sum(solved.fun**2)), base, x[6:].reshape(-1, 3)


def nominal_start(nominal: DHModel, q: Array, points: Array, unknown: NDArray[np.int64], home: Array,
                  tp_index: NDArray[np.int64] | None = None) -> AxisLines:
    """Axis lines of the nominal model placed on the rows whose readings are all known."""
    known = unknown < 0
    placed, tools = place_nominal(nominal, q[known], points[known], None if tp_index is None else tp_index[known])
    return with_tools(lines_from_model(placed, home), placed, tools)


def with_tools(lines: AxisLines, model: DHModel, tools: Array) -> AxisLines:
    """``lines`` with every tracked point ``tools`` (k, 3, in frame n of ``model``) at the home readings."""
    flange = frames_from_joints(model, lines.home[None, :])[0, -1]
    at_home = tools @ flange[:3, :3].T + flange[:3, 3]
    return replace(lines, tp_home=at_home[0], extra_tps=at_home[1:])


def robust_scale(res: Array, leverage: Array) -> float:
    """Robust per-axis noise (weighted units) of studentised residuals: median of the squared norm over
    the median of chi-square(3)."""
    r2 = np.sum(res**2, axis=1) / np.maximum(1.0 - leverage, 0.01)  # (a nuisance row's third dimension aside)
    return float(np.sqrt(np.median(r2) / 2.365974))


@dataclass(frozen=True)
class FitData:
    """The rows a fit sees: readings ``q`` (m, n), TP ``points`` (m, 3) in the tracker frame (m), ``weights``
    (m,) = 1/sigma, ``unknown`` (m,) 0-based unread joint or -1, ``tp_index`` (m,) 0-based tracked point,
    ``group`` (m,) the row's sweep and tracked point (>= 1; 0 for free poses) and ``joint`` (m,) the joint
    its sweep moves, for the neighbour test; ``timing`` the clock correction of streamed rows (fitted from
    its current ``tau``; None without streamed rows); ``rotations`` (m, 3, 3) the measured target-frame rotation of
    orientation rows, NaN on position rows (None: no orientation row; see :class:`identify.estimator.poe.LineProblem`:
    an orientation row's weight is 1/sigma_r and its residual is in rad)."""

    q: Array
    points: Array
    weights: Array
    unknown: NDArray[np.int64]
    tp_index: NDArray[np.int64]
    group: NDArray[np.int64]
    joint: NDArray[np.int64]
    timing: Retiming | None = None
    rotations: Array | None = None

    @property
    def oriented(self) -> NDArray[np.bool_]:
        """The orientation rows (m,)."""
        if self.rotations is None:
            return np.zeros(len(self.q), dtype=bool)
        return np.all(np.isfinite(self.rotations), axis=(1, 2))

    def subset(self, rows: NDArray[np.bool_]) -> FitData:
        return FitData(self.q[rows], self.points[rows], self.weights[rows], self.unknown[rows], self.tp_index[rows],
                       self.group[rows], self.joint[rows], None if self.timing is None else self.timing.subset(rows),
                       None if self.rotations is None else self.rotations[rows])

    def timed(self, timing: Retiming | None) -> FitData:
        """The same rows with the clock correction ``timing`` (its rows must be these)."""
        return replace(self, timing=timing)

    def problem(self, lines: AxisLines, terms: JointTerms | None = None) -> LineProblem:
        return LineProblem(lines, self.q, self.points, self.weights, self.unknown, self.tp_index, terms, self.timing,
                           self.rotations)

    def fit(self, start: AxisLines, terms: JointTerms | None = None, loss: str = "linear",
            scale: float = 1.0) -> LeastSquares:
        return fit_lines(start, self.q, self.points, self.weights, self.unknown, loss, scale, self.tp_index, terms,
                         self.timing, self.rotations)


def pose_ids(data: FitData) -> NDArray[np.int64]:
    """Each row's pose (rows with equal readings, each at its own tracked point, share it); -1 for rows with an
    unread joint (their poses cannot be told apart by the readings)."""
    known = data.unknown < 0
    out = np.full(len(data.q), -1, dtype=np.int64)
    if np.any(known):
        _, index = np.unique(np.round(data.q[known], 12), axis=0, return_inverse=True)
        out[known] = index.ravel()
    return out


def _poses(data: FitData) -> NDArray[np.int64] | None:
    """The rows' poses for the outlier test's rigid-motion rescue; None with one tracked point (nothing to compare)."""
    return pose_ids(data) if len(np.unique(data.tp_index)) > 1 else None


def _outlier_test(data: FitData, res: Array, lev: Array, q: Array, poses: NDArray[np.int64] | None
                  ) -> NDArray[np.bool_]:
    """The rows :func:`identify.estimator.outliers.outlier_free` keeps, for weighted residuals ``res`` (m, 3) with
    leverages ``lev`` at joint values ``q``."""
    return outlier_free(res, lev, data.group, along_arc(q, data.joint), data.unknown, poses, data.points)


def fit(start: AxisLines, data: FitData, robust: bool, label: str, terms: JointTerms | None = None) -> LinesFit:
    """Least squares from ``start`` (with the joint errors ``terms``); if any sample fails the outlier
    test, a soft-L1 fit, the test again on its residuals, and a final least-squares fit on the samples
    kept."""
    lines, q_s, res, terms, timing = data.fit(start, terms)
    data = data.timed(timing)
    inliers = np.ones(len(data.q), dtype=bool)
    poses = _poses(data)
    jac = None
    if robust:
        zero = np.zeros(data.problem(lines, terms).size)
        jac = data.problem(lines, terms).jacobian_blocks(zero)
        lev = leverages(jac, data.unknown)
        inliers = _outlier_test(data, res, lev, q_s, poses)
        if not np.all(inliers):
            for _ in range(ROBUST_PASSES):  # the scale of a fit pulled by outliers is too wide: shrink it
                scale = max(robust_scale(res, lev), NOISE_FLOOR * float(np.median(data.weights)))
                lines, q_s, res, terms, timing = data.fit(lines, terms, "soft_l1", ROBUST_WIDTH * scale)
                data = data.timed(timing)
            inliers = _outlier_test(data, res, lev, q_s, poses)
            for _ in range(2):  # least squares on the samples kept; re-admit those it then explains
                kept_fit = data.subset(inliers).fit(lines, terms.subset(inliers))
                lines, terms = kept_fit.lines, replace(terms, coefs=kept_fit.terms.coefs)
                if timing is not None:
                    data = data.timed(replace(timing, tau=kept_fit.timing.tau))
                problem = data.problem(lines, terms)
                q_s = problem.joints(lines)
                res = problem.residuals(zero).reshape(-1, 3)
                kept = inliers
                jac = problem.jacobian_blocks(zero)
                lev = leverages(jac, data.unknown)
                inliers = _outlier_test(data, res, lev, q_s, poses)
                if np.array_equal(inliers, kept):
                    break
    cost = _soft_l1(res, _inlier_scale(res, inliers))
    return LinesFit(lines, q_s, inliers, -res / data.weights[:, None], cost, label, terms, data.timing, jac,
                    _oriented(data))


def fit_kept(start: AxisLines, data: FitData, inliers: NDArray[np.bool_], label: str, terms: JointTerms) -> LinesFit:
    """Least squares from ``start`` (with the joint errors ``terms``) on the rows ``inliers`` alone, with no outlier
    test of its own; joint values and residuals for every row."""
    kept = data.subset(inliers).fit(start, terms.subset(inliers))
    if kept.timing is not None:
        data = data.timed(replace(data.timing, tau=kept.timing.tau))
    terms = replace(terms, coefs=kept.terms.coefs)
    problem = data.problem(kept.lines, terms)
    res = problem.residuals(np.zeros(problem.size)).reshape(-1, 3)
    cost = _soft_l1(res, _inlier_scale(res, inliers))
    return LinesFit(kept.lines, problem.joints(kept.lines), inliers.copy(), -res / data.weights[:, None], cost, label,
                    terms, data.timing, oriented=_oriented(data))


def _oriented(data: FitData) -> NDArray[np.bool_] | None:
    """``data``'s orientation rows, None without any."""
    return None if data.rotations is None else data.oriented


def best_start(fits: list[LinesFit], data: FitData) -> LinesFit:
    """The fit, among those from several starts, of least soft-L1 cost on one scale for all: the smallest robust
    noise scale among them (weighted units). Each fit's own ``robust_cost`` is scaled by its own residuals, so a
    fit stalled with uniformly large residuals could cost less than a good one with heavier tails."""
    if len(fits) == 1:
        return fits[0]
    weighted = [-f.residuals * data.timed(f.timing).weights[:, None] for f in fits]
    scale = min(_inlier_scale(r, f.inliers) for r, f in zip(weighted, fits, strict=True))
    return fits[int(np.argmin([_soft_l1(r, scale) for r in weighted]))]


def _inlier_scale(res: Array, inliers: NDArray[np.bool_]) -> float:
    """Robust per-axis noise of the weighted residuals ``res`` (m, 3) of the ``inliers``, at least the floor."""
    return max(robust_scale(res[inliers], np.zeros(int(inliers.sum()))), NOISE_FLOOR)


def _soft_l1(res: Array, scale: float) -> float:
    """Soft-L1 cost of weighted residuals ``res`` (m, 3) on noise ``scale`` (the loss of the robust pass)."""
    return float(np.sum(2.0 * (np.sqrt(1.0 + np.sum(res**2, axis=1) / (ROBUST_WIDTH * scale) ** 2) - 1.0)))


def readmit(fitted: LinesFit, data: FitData) -> LinesFit:
    """``fitted`` (fit on its ``inliers`` with its joint errors) refitted with the rows it left out that its own
    model explains: the outlier test of :func:`fit` on its residuals. Rows kept stay kept, so a richer model than
    the one that chose the outliers never makes one; it only re-admits the rows whose error it holds."""
    for _ in range(2):
        rows = data.timed(fitted.timing)
        problem = rows.problem(fitted.lines, fitted.terms)
        zero = np.zeros(problem.size)
        res = problem.residuals(zero).reshape(-1, 3)
        lev = leverages(problem.jacobian_blocks(zero), rows.unknown)
        keep = fitted.inliers | _outlier_test(rows, res, lev, fitted.q, _poses(rows))
        if np.array_equal(keep, fitted.inliers):
            break
        fitted = fit_kept(fitted.lines, rows, keep, fitted.start, fitted.terms)
    return fitted


def along_arc(q: Array, joint: NDArray[np.int64]) -> Array:
    """Each sweep row's position along its arc: the value of the joint it moves (free poses: 0)."""
    swept = joint > 0
    key = np.zeros(len(q))
    key[swept] = q[np.flatnonzero(swept), joint[swept] - 1]
    return key


def fit_lines(start: AxisLines, q: Array, points: Array, weights: Array | None = None,
              unknown: NDArray[np.int64] | None = None, loss: str = "linear",
              scale: float = 1.0, tp_index: NDArray[np.int64] | None = None,
              terms: JointTerms | None = None, timing: Retiming | None = None,
              rotations: Array | None = None) -> LeastSquares:
    """Least-squares axis lines and TP for readings ``q`` (m, n) and TP ``points`` (m, 3) (and the target frame's
    ``rotations`` (m, 3, 3) of orientation rows, NaN elsewhere: see :class:`LineProblem`).

    ``weights`` (m,) = 1/sigma per sample; ``unknown`` marks rows whose one joint was not read, ``tp_index``
    each row's tracked point, ``terms`` the joint errors and ``timing`` the clock correction to fit (see
    :class:`LineProblem`);
    ``loss``/``scale`` select a robust loss of scipy's ``least_squares`` (scale in weighted units).
    """
    weights = np.ones(len(q)) if weights is None else weights
    problem = LineProblem(start, q, points, weights, unknown, tp_index, terms, timing, rotations)
    n_nuisance = int(np.sum(problem.unknown >= 0))
    linear = loss == "linear"
    method = "lm" if linear and 3 * len(q) >= problem.size + n_nuisance else "trf"
    tall = is_tall(3 * len(q), problem.size)
    if method == "lm" and tall:
        x = solve_tall(problem.residuals, problem.jacobian, _warm_start(problem), STOP_SIGMAS)
    else:
        # a tall robust fit only serves to find the outliers: every WARM_STRIDE-th row holds thousands, and the
        # residuals of every row below are taken at its lines
        fitted = _every(problem, WARM_STRIDE) if tall else problem
        tol = converged_tolerance(3 * len(fitted.q)) if linear else 1e-8
        x = least_squares(fitted.residuals, np.zeros(fitted.size), jac=fitted.jacobian, method=method,
                          loss=loss, f_scale=scale, x_scale="jac", xtol=tol, ftol=tol, gtol=tol,
                          max_nfev=200 if linear else 60).x
    lines, _ = problem.lines(x)
    lines = _canonical(lines)
    coefs, tau = problem.coefs(x), problem.tau(x)
    q_solved = problem.joints(lines, coefs, tau)
    residuals = problem.residuals_at(lines, q_solved)
    return LeastSquares(lines, q_solved, residuals, JointTerms(problem.terms.regressors, problem.terms.joints, coefs),
                        None if timing is None else replace(timing, tau=tau))


WARM_STRIDE = 10  # a tall fit starts from a fit of every 10th row (√10 σ off, one step away); a robust one stops there


def _every(problem: LineProblem, stride: int) -> LineProblem:
    """The same problem (same parameters) on every ``stride``-th row of ``problem``."""
    rows = np.arange(0, len(problem.q), stride)
    sub = LineProblem(problem.start, problem.q[rows], problem.points[rows], problem.weights[rows],
                      problem.unknown[rows], None if problem.tp_index is None else problem.tp_index[rows],
                      problem.terms.subset(rows), None if problem.timing is None else problem.timing.subset(rows),
                      None if problem.rotations is None else problem.rotations[rows])
    return sub if sub.oriented_tps == problem.oriented_tps else problem  # (the same parameters, or every row)


def _warm_start(problem: LineProblem) -> Array:
    """The parameters (increments on ``problem``'s start) fitted to every :data:`WARM_STRIDE`-th row: from there one
    Gauss–Newton step on every row reaches the optimum, and one more Jacobian of every row confirms it (three
    without this start, whose first step is large)."""
    sub = _every(problem, WARM_STRIDE)
    return solve_tall(sub.residuals, sub.jacobian, np.zeros(sub.size), STOP_SIGMAS)


def _canonical(lines: AxisLines) -> AxisLines:
    """Each revolute line's point moved to the foot of the perpendicular from the TP at home."""
    pts = lines.points.copy()
    for i, t in enumerate(lines.joint_types):
        if t == "R":
            d = lines.directions[i]
            pts[i] = pts[i] + ((lines.tp_home - pts[i]) @ d) * d
    return AxisLines(lines.joint_types, pts, np.array([unit(d) for d in lines.directions]), lines.home,
                     lines.tp_home, lines.extra_tps, lines.orientations)
