"""Maximum-likelihood refinement of every model parameter against every fitted sample.

Parameters, in this order (the "full" vector): base rotation (3, a rotation vector applied on the
left of the start base rotation), base translation (3, m), tool (3, m, in DH frame n), then per joint
theta, d, a, alpha (rad, m, m, rad). Parameters the data cannot separate are fixed (see
:func:`select_free`); consecutive axes parallel within a tolerance keep their conventional ``d`` so no
``d`` blows up. The fit is ``scipy.optimize.least_squares`` with an analytic Jacobian: first with a
soft-L1 loss to find gross outliers, then a plain least-squares fit on the inliers.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.stats import chi2

from identify.estimator.dh_vector import (  # the full vector's pieces, used here and imported from here elsewhere
    dh_index,
    full_jacobian,
    model_from_vector,
    orientation_jacobian,
    parameter_names,
    prior_rows,
    vector_from_model,
)
from identify.estimator.linalg import triangle
from identify.estimator.orientation import (
    inverse_left_jacobians,
    left_jacobians,
    matrices_from_rotvecs,
    mean_rotation,
    rotation_residuals,
)
from identify.estimator.outliers import NOISE_FLOOR, inlier_mask
from identify.estimator.poe import STOP_SIGMAS, converged_tolerance
from identify.estimator.tall_lsq import is_tall, solve_tall
from kinematics.dh import DH_NAMES, DHModel, flange_frames, points_from_joints

Array = NDArray[np.float64]

RANK_TOL = 1e-7
RESIDUAL_FLOOR = 1e-12  # m: rounding level of residuals, floor of the noise in the significance test
RELEASE_PROBABILITY = 1e-3  # false-alarm rate of the test that releases the parallel-axis convention
DEFAULT_MAX_OFFSET = float("inf")  # m: exact DH wherever the data resolve a near-parallel pair's misalignment


def parallel_links(model: DHModel, parallel_tol: float) -> list[int]:
    """1-based links i whose axes z_{i-1} and z_i are parallel within ``parallel_tol`` rad.

    The last link is excluded (its frame is a convention anyway). Near such a pair, DH's polar
    description of z_i about z_{i-1} is singular: the values it cannot resolve stay conventional."""
    return [i + 1 for i in range(model.n_joints - 1) if abs(np.sin(model.alpha[i])) < np.sin(parallel_tol)]


def _priority(types: str) -> list[int]:
    """Order in which parameters are kept free; redundant ones late in the list get fixed.

    Base and tool first (they absorb the free choices of frame 0 and frame n), then links from the tip,
    each theta, alpha, a, d; prismatic a and d and the first link's theta and d last.
    """
    n = len(types)
    first, late = list(range(9)), []
    for j in range(n, 0, -1):
        for name in DH_NAMES:
            index = dh_index(j, name)
            prismatic_offset = types[j - 1] == "P" and name in ("a", "d")
            (late if prismatic_offset or (j == 1 and name in ("theta", "d")) else first).append(index)
    return first + late


def select_free(model: DHModel, q: Array, parallel: Collection[int], tol: float = RANK_TOL) -> NDArray[np.bool_]:
    """Mask of the full vector: the parameters that the samples at ``q`` determine.

    Evaluated on the model with the ``parallel`` links (1-based) made exactly parallel, so a ``d`` whose
    value only a tiny misalignment could reveal is fixed rather than left to blow up. Greedy in the
    order of :func:`_priority`: a parameter is kept when its (normalised) Jacobian column adds more
    than ``tol`` to the span of those kept before it.
    """
    ideal = model.alpha.copy()
    for i in parallel:
        ideal[i - 1] = np.round(ideal[i - 1] / np.pi) * np.pi
    _, jac = full_jacobian(replace(model, alpha=ideal), q)
    columns = jac.reshape(-1, jac.shape[2])
    if columns.shape[0] > columns.shape[1]:  # the unit columns' geometry in p dimensions instead of 3m
        columns = triangle(columns, unit_columns=True)
    else:
        columns = columns / np.maximum(np.linalg.norm(columns, axis=0), 1e-300)
    free = np.zeros(columns.shape[1], dtype=bool)
    basis = np.zeros((columns.shape[0], 0))
    for index in _priority(model.joint_types):
        c = columns[:, index]
        r = c - basis @ (basis.T @ c)
        r = r - basis @ (basis.T @ r)
        norm = np.linalg.norm(r)
        if norm > tol:
            free[index] = True
            basis = np.column_stack([basis, r / norm])
    return free


@dataclass(frozen=True)
class Refinement:
    """Result of the refinement. ``covariance`` is over the free parameters (``free`` mask of the full
    vector), in the full vector's units. ``noise`` is the per-axis noise the residuals imply (m).
    ``inliers`` masks the fitted samples; ``residuals`` (m, 3) are measured minus predicted (m)."""

    model: DHModel
    free: NDArray[np.bool_]
    covariance: Array
    noise: float
    inliers: NDArray[np.bool_]
    residuals: Array
    condition: float
    cost: float
    q: Array
    points: Array
    notes: list[str] = field(default_factory=list)
    tools: Array | None = None  # every tracked point's tool (k, 3, frame n) when fitted with several

    def std(self) -> Array:
        """Standard uncertainty of every full-vector parameter (0 for fixed ones)."""
        out = np.zeros(len(self.free))
        out[self.free] = np.sqrt(np.diag(self.covariance))
        return out


class _Problem:
    """Residuals and Jacobian over the free parameters, weighted by 1/sigma when given. With several tracked
    points (``tp_index`` (m,), 0-based), the parameters end with the other points' tools (3 each, frame n):
    ``tools`` (k, 3) holds every point's, the first being the model's. Orientation rows (``rotations`` (m, 3, 3)
    finite: a full-pose target's measured frame, weight 1/sigma_r) have the rotation residual
    ``log(R_n(q) T_p R_measuredᵀ)`` (rad) with ``T_p`` their tracked point's target frame in frame n
    (``frames`` (k, 3, 3) start; a turn ω of it, ``exp(ω) T_p``, 3 parameters per oriented point, last)."""

    def __init__(self, start: DHModel, q: Array, points: Array, weights: Array, free: NDArray[np.bool_],
                 tp_index: NDArray[np.int64] | None = None, tools: Array | None = None,
                 rotations: Array | None = None, frames: Array | None = None,
                 prior: tuple[Array, Array] | None = None):
        self.start, self.q, self.points, self.weights, self.free = start, q, points, weights, free
        self.prior = prior
        self.tp_index = np.zeros(len(q), dtype=np.int64) if tp_index is None else tp_index
        self.extra = np.zeros((0, 3)) if tools is None else np.asarray(tools, dtype=float)[1:]
        self.template = np.concatenate([vector_from_model(start), self.extra.ravel()])
        self.size = len(self.free)
        self.rotations = rotations
        self.turning = (np.zeros(len(q), dtype=bool) if rotations is None
                        else np.all(np.isfinite(rotations), axis=(1, 2)))
        self.oriented_tps = [int(p) for p in np.unique(self.tp_index[self.turning])]
        self.frames = frames
        if self.oriented_tps and (frames is None or not np.all(np.isfinite(frames[self.oriented_tps]))):
            self.frames = target_frames(start, q, rotations, self.tp_index, len(self.extra) + 1, frames)
        self.n_position = int(self.free.sum()) + self.extra.size  # parameters before the frames' turns

    @property
    def x0(self) -> Array:
        return np.concatenate([self.template[: self.size][self.free], self.extra.ravel(),
                               np.zeros(3 * len(self.oriented_tps))])

    def full(self, x: Array) -> Array:
        v = self.template[: self.size].copy()
        v[self.free] = x[: int(self.free.sum())]
        return v

    def tools(self, x: Array) -> Array:
        """Every tracked point's tool (k, 3) at ``x``."""
        return np.vstack([self.full(x)[6:9], x[int(self.free.sum()):self.n_position].reshape(-1, 3)])

    def target_frames(self, x: Array) -> Array | None:
        """Every tracked point's target frame in frame n (k, 3, 3) at ``x`` (NaN where not measured; None: none)."""
        if not self.oriented_tps:
            return self.frames
        out = self.frames.copy()
        out[self.oriented_tps] = matrices_from_rotvecs(x[self.n_position:].reshape(-1, 3)) @ out[self.oriented_tps]
        return out

    def _turned(self, x: Array, res: Array) -> Array:
        """``res`` (m, 3) with the orientation rows' rotation residuals (rad, unweighted) at ``x``."""
        o = self.turning
        if np.any(o):
            rotation, _ = flange_frames(self.model(x), self.q[o])
            res[o] = rotation_residuals(rotation @ self.target_frames(x)[self.tp_index[o]], self.rotations[o])
        return res

    def _orientation_blocks(self, x: Array, out: Array) -> None:
        """In place: the orientation rows' blocks of the (unweighted) Jacobian ``out`` (m, 3, size)."""
        o = self.turning
        if not np.any(o):
            return
        v = self.full(x)
        model = model_from_vector(self.start, v)
        rotation, jac = orientation_jacobian(model, self.q[o], omega=v[:3])
        block = np.zeros((int(o.sum()), 3, out.shape[2]))
        block[:, :, : int(self.free.sum())] = jac[:, :, self.free]
        turns = left_jacobians(x[self.n_position:].reshape(-1, 3))
        frames = self.target_frames(x)
        tps = self.tp_index[o]
        for slot, p in enumerate(self.oriented_tps):
            mine = tps == p
            block[mine, :, self.n_position + 3 * slot:self.n_position + 3 * slot + 3] = rotation[mine] @ turns[slot]
        residual = rotation_residuals(rotation @ frames[tps], self.rotations[o])
        out[o] = inverse_left_jacobians(residual) @ block

    def model(self, x: Array) -> DHModel:
        return model_from_vector(self.start, self.full(x))

    def residuals(self, x: Array) -> Array:
        model, tools = self.model(x), self.tools(x)
        predicted = np.empty_like(self.points)
        for k, tool in enumerate(tools):
            rows = self.tp_index == k
            predicted[rows] = points_from_joints(replace(model, tool=tool), self.q[rows])
        return (self._turned(x, predicted - self.points) * self.weights[:, None]).ravel()

    def objective(self, x: Array) -> Array:
        """What the fit minimises: the residuals, then the prior's rows (when one is given)."""
        out = self.residuals(x)
        return out if self.prior is None else np.concatenate([out, self._prior_rows(x)])

    def objective_jacobian(self, x: Array) -> Array:
        data = self.jacobian(x)
        return data if self.prior is None else np.vstack([data, self._prior_jacobian(data.shape[1])])

    def _prior_rows(self, x: Array) -> Array:
        """The free values' offsets from ``prior``'s, in its sigmas (only where they are finite)."""
        values, sigma = self.prior
        keep = np.isfinite(sigma[self.free])
        return ((self.full(x) - values) / sigma)[self.free][keep]

    def _prior_jacobian(self, columns: int) -> Array:
        rows = prior_rows(self.free, self.prior[1])
        return np.hstack([rows, np.zeros((len(rows), columns - rows.shape[1]))])

    def jacobian(self, x: Array) -> Array:
        v = self.full(x)
        model, tools = model_from_vector(self.start, v), self.tools(x)
        n_free, n_extra = int(self.free.sum()), 3 * (len(tools) - 1)
        if np.any(self.turning):
            n_turns = 3 * len(self.oriented_tps)
            out = np.zeros((len(self.q), 3, n_free + n_extra + n_turns))
            out[:, :, :n_free + n_extra] = self._position_blocks(x, model, tools, n_free, n_extra)
            self._orientation_blocks(x, out)
            out *= self.weights[:, None, None]
            return out.reshape(-1, out.shape[2])
        if not n_extra:  # one tracked point: its columns as they come (no second (m, 3, p) copy)
            out = np.compress(self.free, full_jacobian(replace(model, tool=tools[0]), self.q, omega=v[:3])[1], axis=2)
            if np.any(self.weights != 1.0):
                out *= self.weights[:, None, None]
            return out.reshape(-1, out.shape[2])
        out = self._position_blocks(x, model, tools, n_free, n_extra)
        out *= self.weights[:, None, None]
        return out.reshape(-1, out.shape[2])

    def _position_blocks(self, x: Array, model: DHModel, tools: Array, n_free: int, n_extra: int) -> Array:
        """The unweighted position Jacobian (m, 3, n_free + n_extra) of every row, each at its tracked point."""
        v = self.full(x)
        out = np.zeros((len(self.q), 3, n_free + n_extra))
        for k, tool in enumerate(tools):
            rows = self.tp_index == k
            _, jac = full_jacobian(replace(model, tool=tool), self.q[rows], omega=v[:3])
            if k:  # this point's tool has its own parameters
                out[rows, :, n_free + 3 * (k - 1): n_free + 3 * k] = jac[:, :, 6:9]
                jac[:, :, 6:9] = 0.0
            out[rows, :, :n_free] = jac[:, :, self.free]
        return out


def orientation_blocks(model: DHModel, free: NDArray[np.bool_], q: Array, rotations: Array, frame: Array,
                       weights: Array) -> Array:
    """Weighted Jacobian (m, 3, free + 3) of orientation rows (measured frames ``rotations`` (m, 3, 3) at joint values
    ``q``, weights 1/sigma_r) over the ``free`` full-vector values and the turn of the target ``frame`` (3, 3, in
    frame n), at ``model``."""
    problem = _Problem(model, q, np.zeros((len(q), 3)), weights, free, None, None, rotations, frame[None])
    return problem.jacobian(problem.x0).reshape(len(q), 3, -1)


def target_frames(model: DHModel, q: Array, rotations: Array, tp_index: NDArray[np.int64], count: int,
                  frames: Array | None = None) -> Array:
    """Each of ``count`` tracked points' target frame in DH frame n (count, 3, 3) that best fits the measured
    ``rotations`` (m, 3, 3; NaN rows: positions only) at joint values ``q``: the chordal mean of ``R_n(q)ᵀ R`` over
    its rows; ``frames``' value (or NaN) for a point without any."""
    out = np.full((count, 3, 3), np.nan) if frames is None else np.array(frames, dtype=float)
    given = np.all(np.isfinite(rotations), axis=(1, 2))
    for p in range(count):
        rows = given & (tp_index == p)
        if np.any(rows):
            rotation, _ = flange_frames(model, q[rows])
            out[p] = mean_rotation(np.swapaxes(rotation, 1, 2) @ rotations[rows])
    return out


def _solve(problem: _Problem, x0: Array, loss: str, scale: float) -> Array:
    """Least-squares solve; the robust (outlier-finding) pass needs less precision than the final one."""
    linear = loss == "linear"
    method = "lm" if linear and len(problem.points) * 3 >= len(x0) else "trf"
    if method == "lm" and is_tall(len(problem.points) * 3, len(x0)):
        return solve_tall(problem.objective, problem.objective_jacobian, x0, STOP_SIGMAS)
    tol = converged_tolerance(len(problem.points) * 3) if linear else 1e-8
    fit = least_squares(
        problem.objective,
        x0,
        jac=problem.objective_jacobian,
        method=method,
        loss=loss,
        f_scale=scale,
        x_scale="jac",
        xtol=tol,
        ftol=tol,
        gtol=tol,
        max_nfev=200 if linear else 50,
    )
    return fit.x


@dataclass(frozen=True)
class TableFit:
    """A DH table fitted by :func:`fit_table`: the ``model``, the ``free`` mask of the full vector, every tracked
    point's ``tools`` (k, 3, frame n), the ``inliers`` mask and ``notes`` on the conventions applied; ``frames``
    (k, 3, 3) each point's target frame in frame n where orientations were measured (NaN elsewhere; None: none)."""

    model: DHModel
    free: NDArray[np.bool_]
    tools: Array
    inliers: NDArray[np.bool_]
    notes: list[str]
    frames: Array | None = None


def fit_table(
    start: DHModel,
    q: Array,
    points: Array,
    sigma: Array | None = None,
    conventional: Array | None = None,
    parallel: Collection[int] = (),
    noise_guess: float = 1e-4,
    robust: bool = True,
    max_offset: float = DEFAULT_MAX_OFFSET,
    tp_index: NDArray[np.int64] | None = None,
    tools: Array | None = None,
    rotations: Array | None = None,
    prior: tuple[Array, Array] | None = None,
) -> TableFit:
    """The maximum-likelihood DH table of :func:`refine`, without its covariance (arguments as there); ``rotations``
    (m, 3, 3): the measured target frame of orientation rows (NaN on position rows; their ``sigma`` is sigma_r,
    rad), fitted with a target frame in frame n per tracked point (``TableFit.frames``); with a ``prior`` (values
    and sigmas of the full vector, in the weighted rows' units; ``inf`` where none), the maximum a posteriori
    table."""
    tp_index = np.zeros(len(q), dtype=np.int64) if tp_index is None else np.asarray(tp_index)
    tools = start.tool[None, :] if tools is None else np.asarray(tools, dtype=float)
    weights = np.ones(len(q)) if sigma is None else 1.0 / np.asarray(sigma, dtype=float)
    free = select_free(start, q, parallel)
    notes: list[str] = []
    # values the data cannot determine take their conventional ones; the fit absorbs the change
    model, moved = _with_conventions(start, free, conventional)
    problem = _Problem(model, q, points, weights, free, tp_index, tools, rotations, prior=prior)
    x = _solve(problem, problem.x0, "linear", 1.0)
    inliers = np.ones(len(q), dtype=bool)
    if robust and rotations is not None:
        raise ValueError("the robust DH fit is for positions; orientation rows come from the lines' fit")
    if robust:
        inliers = inlier_mask(problem.residuals(x).reshape(-1, 3), int(free.sum()))
    if not np.all(inliers):
        scale = max(noise_guess, NOISE_FLOOR) * 3.0 * (1.0 if sigma is None else float(np.median(weights)))
        x = _solve(problem, x, "soft_l1", scale)
        inliers = inlier_mask(problem.residuals(x).reshape(-1, 3), int(free.sum()))
        model, tools = problem.model(x), problem.tools(x)
        problem = _Problem(model, q[inliers], points[inliers], weights[inliers], free, tp_index[inliers], tools,
                           prior=prior)
        x = _solve(problem, problem.x0, "linear", 1.0)
    model, tools, frames = problem.model(x), problem.tools(x), problem.target_frames(x)
    if (len(tools) > 1 or rotations is not None) and max_offset > 0:
        raise ValueError("releasing the parallel-axis convention is for one tracked point")
    free_exact = select_free(start, q, ()) if parallel and max_offset > 0 else free
    if np.any(free_exact & ~free):  # with no offset allowed, the convention stays
        model, free, note = _release_parallel(
            model, q[inliers], points[inliers], weights[inliers], free, free_exact, conventional, max_offset
        )
        notes += [note] if note else []
    if moved:
        notes.append(f"{moved} undetermined parameter(s) set to their conventional values")
    return TableFit(model, free, tools, inliers, notes, frames)


def refine(
    start: DHModel,
    q: Array,
    points: Array,
    sigma: Array | None = None,
    conventional: Array | None = None,
    parallel: Collection[int] = (),
    noise_guess: float = 1e-4,
    robust: bool = True,
    max_offset: float = DEFAULT_MAX_OFFSET,
    tp_index: NDArray[np.int64] | None = None,
    tools: Array | None = None,
) -> Refinement:
    """Maximum-likelihood DH model for joint readings ``q`` (m, n) and TP ``points`` (m, 3, tracker frame).

    ``start`` must be close (the geometric step). ``sigma`` (m,) are per-sample standard uncertainties
    (m) used as weights. ``conventional`` (n, 4) holds the values fixed parameters are moved to (the
    nominal DH or zeros) when the data leave them free. ``noise_guess`` (m) scales the robust loss.
    ``parallel``: 1-based links whose consecutive axes are treated as parallel (their ``d`` stays
    conventional unless the data resolve the misalignment). ``max_offset`` (m): the most a near-parallel
    pair's ``d`` may move from its conventional value when the data resolve the pair's misalignment
    (see :func:`_release_parallel`). Several tracked points: ``tp_index`` (m,) 0-based and their ``tools`` (k, 3,
    frame n) as a start; each keeps its own tool (``Refinement.tools``), all share the table.
    """
    tp_index = np.zeros(len(q), dtype=np.int64) if tp_index is None else np.asarray(tp_index)
    weights = np.ones(len(q)) if sigma is None else 1.0 / np.asarray(sigma, dtype=float)
    table = fit_table(start, q, points, sigma, conventional, parallel, noise_guess, robust, max_offset, tp_index, tools)
    model, free, tools, inliers, notes = table.model, table.free, table.tools, table.inliers, table.notes
    problem = _Problem(model, q[inliers], points[inliers], weights[inliers], free, tp_index[inliers], tools)
    x = problem.x0
    jac = problem.jacobian(x)
    res_w = problem.residuals(x)
    dof = max(len(res_w) - int(free.sum()), 1)
    cost = float(res_w @ res_w)
    scale2 = cost / dof
    _, s, vt = np.linalg.svd(jac, full_matrices=False)
    cov = (vt.T / s**2) @ vt
    n_free = int(free.sum())
    covariance = (cov * (scale2 if sigma is None else 1.0))[:n_free, :n_free]
    col_norm = np.linalg.norm(jac, axis=0)
    s_scaled = np.linalg.svd(jac / col_norm, compute_uv=False)
    everyone = _Problem(model, q, points, np.ones(len(q)), free, tp_index, tools)
    residuals = -everyone.residuals(x).reshape(-1, 3)
    noise = float(np.sqrt(np.sum((residuals[inliers]) ** 2) / dof))
    if sigma is not None:
        notes.append(f"reduced chi-square {scale2:.3g} (1 when the given sigma is right)")
    return Refinement(model, free, covariance, noise, inliers, residuals, float(s_scaled[0] / s_scaled[-1]), cost,
                      q, points, notes, tools)


def _with_conventions(model: DHModel, free: NDArray[np.bool_], conventional: Array | None) -> tuple[DHModel, int]:
    """``model`` with its fixed DH values set to the conventional ones (nominal DH or zeros)."""
    n = model.n_joints
    target = np.zeros((n, 4)) if conventional is None else np.asarray(conventional, dtype=float)
    table = model.dh_table()
    fixed_dh = ~free[9:].reshape(n, 4)
    delta = np.where(fixed_dh, target - table, 0.0)
    delta[:, 0] = np.angle(np.exp(1j * delta[:, 0]))
    return model.with_dh_table(table + delta), int(np.count_nonzero(np.abs(delta) > 1e-12))


def _release_parallel(
    model: DHModel, q: Array, points: Array, weights: Array, free: NDArray[np.bool_],
    free_exact: NDArray[np.bool_], conventional: Array | None, max_offset: float,
) -> tuple[DHModel, NDArray[np.bool_], str | None]:
    """Free the values the parallel-axis convention fixed, if the data demand it and no ``d`` blows up.

    The convention costs nothing when a near-parallel pair's misalignment is below the noise. When a
    likelihood-ratio test (chi-square, false-alarm rate RELEASE_PROBABILITY) says the data resolve it,
    exact DH is used, unless a ``d`` would move more than ``max_offset`` from its conventional value:
    then the convention is kept and the returned note says what it costs.
    """
    exact = _Problem(model, q, points, weights, free_exact)
    x0 = exact.x0
    residuals = exact.residuals(x0)
    cost_c = float(residuals @ residuals)
    dof = max(3 * len(q) - int(free_exact.sum()), 1)
    floor = (RESIDUAL_FLOOR * float(np.median(weights))) ** 2
    extra = free_exact & ~free
    limit = chi2.ppf(1 - RELEASE_PROBABILITY, int(extra.sum()))
    # score test first: the cost one Gauss-Newton step of the exact model would remove (cheap, and
    # asymptotically the likelihood-ratio statistic); only a significant one is worth the exact fit
    jac = exact.jacobian(x0)
    jac /= np.linalg.norm(jac, axis=0)
    step, *_ = np.linalg.lstsq(jac, residuals, rcond=None)
    reduction = float(np.sum((jac @ step) ** 2))
    if reduction / max((cost_c - reduction) / dof, floor) <= limit:
        return model, free, None
    x = _solve(exact, x0, "linear", 1.0)
    cost_e = float(np.sum(exact.residuals(x) ** 2))
    statistic = (cost_c - cost_e) / max(cost_e / dof, floor)
    if statistic <= limit:
        return model, free, None
    candidate = model_from_vector(model, exact.full(x))
    n = model.n_joints
    target = np.zeros((n, 4)) if conventional is None else np.asarray(conventional, dtype=float)
    extra_d = extra[9:].reshape(n, 4)[:, 1]
    shift = np.abs(candidate.d - target[:, 1])[extra_d]
    names = [parameter_names(n)[i] for i in np.flatnonzero(extra)]
    if shift.size and shift.max() > max_offset:
        rms_c, rms_e = (np.sqrt(c / len(q)) for c in (cost_c, cost_e))
        return model, free, (
            f"near-parallel axes are measurably misaligned (chi-square {statistic:.3g}), but exact standard DH "
            f"would move d by {shift.max():.3g} m; kept the convention at an RMS cost of {rms_c * 1e3:.4f} vs "
            f"{rms_e * 1e3:.4f} mm (raise --max-offset for exact DH)"
        )
    return candidate, free_exact, (
        f"released the parallel-axis convention for {', '.join(names)}: the data resolve the misalignment "
        f"(chi-square {statistic:.3g})"
    )
