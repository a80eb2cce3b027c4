"""A fitted lines model written as the DH model a reader takes away, with its uncertainty and its cost.

The identification keeps two models (:mod:`identify.results.pipeline`): the plain one (DH, no joint errors) and, when
the data support joint errors, the extended one. Each is fitted as axis lines (:mod:`identify.estimator.estimate`) and
written here as standard DH (:mod:`identify.results.dh_output`): exact, except where a near-parallel pair's exact ``d``
would move beyond ``max_offset`` (the robot's size by default, :func:`robot_size`); such a link keeps the
parallel-axis convention and the table is refitted under it, every tracked point included, so what it costs is
measured (the ``dh_table`` check). Frames: tracker; units: m, rad.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from identify.estimator.adequacy import Adequacy
from identify.estimator.dh_vector import full_jacobian, parameter_names, prior_rows
from identify.estimator.estimate import FitData, LinesFit
from identify.estimator.extensions import TermSet
from identify.estimator.identifiability import LEVEL
from identify.estimator.linalg import project_out, scaled_inverse
from identify.estimator.poe import AxisLines, LineProblem, points_from_lines
from identify.estimator.refine import Refinement, TableFit, fit_table, orientation_blocks
from identify.results import verdict as checks
from identify.results.dh_output import DHOutput, axis_angle, dh_output, near_parallel
from identify.results.hold import (
    Hold,
    NominalPrior,
    held_fit,
    line_metric,
    line_names,
    table_prior,
    undetermined,
)
from identify.results.predict import Predictor
from kinematics.dh import DHModel, flange_frames, frames_from_joints

Array = NDArray[np.float64]


@dataclass(frozen=True)
class FixedParameter:
    """A parameter held at ``value`` (rad or m) by a convention, for ``reason``; ``sigma`` (rad or m): the value's
    own uncertainty where it is the nominal's (frame n placed as the catalogue places the flange: a tool given on
    the flange carries it), 0 for a pure convention."""

    name: str
    value: float
    reason: str
    sigma: float = 0.0


@dataclass(frozen=True)
class WrittenModel:
    """One model as written: ``name`` (``plain`` or ``extended``), the DH ``model`` (tool: the first tracked
    point) with every point's ``tools`` (k, 3, frame n), the standard uncertainty of every full-vector parameter
    (``std``; 0 where ``fixed``), the ``refinement`` record, the links kept at the parallel-axis convention
    (``capped``, 1-based, with the ``d`` shift exact DH would need, m), the ``dh_check`` of what that costs, and
    the exact model it was written from: the fitted ``lines`` with the joint-error ``terms`` and the ``predictor``
    (lines, terms, covariance). ``covariance`` is over the fit's whole problem (clock parameters last);
    ``expected``: RMS 3D prediction uncertainty at the fitted poses, model error included (m)."""

    name: str
    fit: LinesFit
    adequacy: Adequacy
    model: DHModel
    tools: Array
    std: Array
    fixed: list[FixedParameter]
    refinement: Refinement
    capped: dict[int, float]
    dh_check: checks.Check
    terms: TermSet
    predictor: Predictor
    lines_covariance: Array
    covariance: Array
    condition: float
    expected: float
    problem: LineProblem
    jacobian_blocks: Array
    frames: Array | None = None  # each tracked point's target frame in frame n (k, 3, 3), NaN where not measured
    held: Hold | None = None  # what the data alone left undetermined, held at the nominal
    turn_covariance: Array | None = None  # the free DH values, then the first point's target-frame turn (rad, frame n)

    @property
    def frame_std(self) -> Array | None:
        """Standard uncertainty (3,) rad of the first tracked point's target frame, a turn about frame n's axes."""
        if self.turn_covariance is None:
            return None
        return np.sqrt(np.clip(np.diag(self.turn_covariance)[-3:], 0.0, None))

    def dh_rotations(self, q: Array, tp_index: NDArray[np.int64]) -> Array:
        """The target frames' rotations (m, 3, 3), tracker frame, the written numbers predict at DH joint values
        ``q`` (m, n) for tracked points ``tp_index`` (0-based; NaN where no orientation was measured)."""
        rotation, _ = flange_frames(self.model, self.dh_joints(q))
        assert self.frames is not None
        return rotation @ self.frames[tp_index]

    @property
    def lines(self) -> AxisLines:
        return self.fit.lines

    @property
    def fit_rms(self) -> float:
        """RMS 3D residual of the fitted inliers' positions (m)."""
        res = self.fit.residuals[self.fit.inliers & self.fit.positions]
        return float(np.sqrt(np.mean(np.sum(res**2, axis=1))))

    @property
    def coefs(self) -> Array:
        """The joint-error coefficients (units in :data:`identify.estimator.extensions.UNITS`)."""
        return self.predictor.coefs

    def dh_joints(self, q: Array) -> Array:
        """The joint values the written DH table takes at DH joint values ``q`` (m, n): with the joint errors."""
        return self.terms.terms(q, self.coefs).corrected(q)

    def dh_points(self, q: Array, tp_index: NDArray[np.int64]) -> Array:
        """Tracked points (m, 3), tracker frame, the written numbers predict at DH joint values ``q`` (m, n)."""
        return points_with_tools(self.model, self.tools, self.dh_joints(q), tp_index)


def points_with_tools(model: DHModel, tools: Array, q: Array, tp_index: NDArray[np.int64]) -> Array:
    """Tracked points (m, 3) of ``model`` at joint values ``q`` (m, n), row r at tool ``tools[tp_index[r]]``."""
    rotation, origin = flange_frames(model, q)
    tool = np.asarray(tools, dtype=float)[tp_index]
    return np.einsum("kij,kj->ki", rotation, tool) + origin


def robot_size(lines: AxisLines, points: Array) -> float:
    """The robot's size (m): the farthest measured tracked point from the first joint's axis point. No joint of
    the arm lies farther out, so no DH ``d`` of a real near-parallel pair needs to reach beyond it.

    A prismatic joint's axis has a direction and no position (its point is a convention, which may lie next to the
    tracked point): an arm that starts with one (a track, a lifting column, a gantry) measures from its first
    revolute axis instead, and at least the span of the measured points (the travel the data cover)."""
    revolute = [k for k, kind in enumerate(lines.joint_types) if kind == "R"]
    if revolute and revolute[0] == 0:
        return float(np.max(np.linalg.norm(points - lines.points[0], axis=1)))
    span = 2.0 * float(np.max(np.linalg.norm(points - points.mean(axis=0), axis=1)))
    if not revolute:
        return span
    return max(span, float(np.max(np.linalg.norm(points - lines.points[revolute[0]], axis=1))))


def dh_covariance(model: DHModel, free: NDArray[np.bool_], q: Array, weights: Array,
                  unknown: NDArray[np.int64], rotations: Array | None = None, frames: Array | None = None,
                  prior: Array | None = None, turn: bool = False) -> Array:
    """Unit-variance covariance of the ``free`` DH values (weighted units), rows of unread joints (``unknown``,
    0-based, -1 for none) projected on the complement of their nuisance joint value; orientation rows
    (``rotations`` finite, of the first tracked point, whose target frame in frame n is ``frames[0]``) with the
    frame's turn as a parameter fitted with them; ``prior`` (k, free count): rows of a further measurement of the
    DH values, in the same units, stacked with the data's. ``turn`` (with orientation rows): the covariance of the
    free values and then the frame's turn ω (``exp(ω) frames[0]``, rad about frame n's axes), (free + 3) square."""
    count = int(free.sum())
    if rotations is not None and np.any(_finite(rotations)):
        t = _finite(rotations)
        turns = orientation_blocks(model, free, q[t], rotations[t], frames[0], weights[t])
        positions = np.zeros((int(np.sum(~t)), 3, turns.shape[2]))
        positions[:, :, :count] = _position_blocks(model, free, q[~t], weights[~t], unknown[~t])
        flat = np.vstack([positions, turns]).reshape(-1, turns.shape[2])
    else:
        flat = _position_blocks(model, free, q, weights, unknown).reshape(-1, count)
    if prior is not None:
        flat = np.vstack([flat, np.hstack([prior, np.zeros((len(prior), flat.shape[1] - count))])])
    size = count + 3 if turn and flat.shape[1] > count else count
    return scaled_inverse(flat)[0][:size, :size]


def _position_blocks(model: DHModel, free: NDArray[np.bool_], q: Array, weights: Array,
                     unknown: NDArray[np.int64]) -> Array:
    """The weighted position Jacobian (m, 3, free) of :func:`dh_covariance`, nuisance joint values projected out."""
    p, jac = full_jacobian(model, q)
    jac = np.compress(free, jac, axis=2)
    if np.any(weights != 1.0):
        jac *= weights[:, None, None]
    rows = np.flatnonzero(unknown >= 0)
    if len(rows):
        frames = frames_from_joints(model, q[rows])
        j = unknown[rows]
        axis = frames[np.arange(len(rows)), j, :3, 2]
        origin = frames[np.arange(len(rows)), j, :3, 3]
        revolute = model.revolute[j]
        g = np.where(revolute[:, None], np.cross(axis, p[rows] - origin), axis) * weights[rows, None]
        project_out(jac, rows, g)
    return jac


def written_model(name: str, fit: LinesFit, data: FitData, adequacy: Adequacy, terms: TermSet,
                  tp_ids: tuple[int, ...], conventional: Array, nominal: DHModel | None, parallel_tol: float,
                  max_offset: float, unit: float, declared: float | None, sigma: Array | None,
                  reference: AxisLines | None = None, size: float = 1.0) -> WrittenModel:
    """``fit`` (its inliers, joint errors ``terms``) written as DH with its covariance. ``data``: the fit rows
    (timed as ``fit``); ``unit``: the weights' scale (median sigma, or 1); ``declared``: the tracker noise
    declared (m per axis) or None; ``sigma`` (m,) per-row uncertainties or None; ``reference``: the nominal's
    lines placed on the data (None without a nominal), where the directions the data do not determine for a
    robot of ``size`` (m) are held (:mod:`identify.results.hold`); the rest as in
    :func:`identify.results.pipeline.identify`."""
    data = data.timed(fit.timing)
    lines, inl = fit.lines, fit.inliers
    problem = data.subset(inl).problem(lines, fit.terms.subset(inl))
    x0 = np.zeros(problem.size)
    jac_blocks = fit.jacobian_blocks(problem)
    res_w = problem.residuals(x0).reshape(-1, 3)
    inv, condition = scaled_inverse(jac_blocks.reshape(-1, problem.size))
    # noise variance in weighted units (1 for a right sigma column), never below the declared noise
    variance = max(adequacy.residual, declared or 0.0) ** 2 / unit**2 * adequacy.inflation
    covariance = inv * variance
    held, scale = None, 1.0
    if reference is not None:
        scale = max(adequacy.residual, declared or 0.0) * np.sqrt(adequacy.inflation)
        bias = adequacy.model_error * np.sqrt(3 * int(inl.sum())) / scale if scale > 0 else 0.0
        names = line_names(problem)
        # the nominal is a measurement of every axis, to its tolerance: it decides where the data do not; the fit
        # from the nominal itself is tried too when the data leave directions undetermined (it may lie nearer)
        prior = NominalPrior(problem, reference, size, covariance)
        wandered = len(undetermined(covariance, line_metric(problem), size, names, bias)) > 0
        fit = held_fit(fit, data, problem, prior.solve(problem, variance, [x0, prior.reference] if wandered else [x0]))
        lines = fit.lines
        problem = data.subset(inl).problem(lines, fit.terms.subset(inl))
        jac_blocks = fit.jacobian_blocks(problem)
        res_w = problem.residuals(x0).reshape(-1, 3)
        inv, condition = scaled_inverse(jac_blocks.reshape(-1, problem.size))
        # what the data alone leave undetermined at the held lines (said in fixed); the covariance with the prior
        found = undetermined(inv * variance, line_metric(problem), size, names, bias)
        held = found if len(found) else None
        scale = prior.scale
        rows = prior.jacobian() * np.sqrt(variance)  # constant: the same at the held lines as at the start
        covariance = scaled_inverse(np.vstack([jac_blocks.reshape(-1, problem.size), rows]))[0] * variance
    lines_cov = covariance[: lines.n_parameters, : lines.n_parameters]
    near, beyond = near_parallel(lines, lines_cov, conventional, nominal, parallel_tol, max_offset)
    tp_index = data.tp_index[inl]
    q_fit, weights = fit.q[inl], data.weights[inl]
    rows = _FitRows(q_fit, data.points[inl], None if sigma is None else sigma[inl], weights, tp_index, res_w,
                    variance, None if data.rotations is None else data.rotations[inl])
    # the nominal as a measurement of the table too (when it was one of the lines)
    held_table = reference is not None and nominal is not None
    out, dh_fit, tools, gap, tolerance = _written_dh(lines, conventional, nominal, near, rows, adequacy.noise,
                                                     held_table, scale, max_offset)
    if near and gap[1] > checks.dh_limit(len(near)) and len(beyond) < len(near):
        # the data resolve the misalignment: exact DH wherever it stays within max_offset
        out, dh_fit, tools, gap, tolerance = _written_dh(lines, conventional, nominal, beyond, rows, adequacy.noise,
                                                         held_table, scale, max_offset)
    first = tp_index == 0
    turned = rows.rotations_of(first)
    turning = turned is not None and bool(np.any(_finite(turned)))
    cov_turn = None  # the table's free values, then the target frame's turn (rad about frame n's axes)
    if dh_fit is None:  # exact DH: the lines' covariance carried over
        model, frames = out.model, target_frames_of(out.model, lines)
        free = np.any(out.jacobian != 0.0, axis=1)
        cov_free = (out.jacobian @ lines_cov @ out.jacobian.T)[np.ix_(free, free)]
        if turning and frames is not None:  # its turn fitted with the exact table's free values, through the same rows
            cov_turn = dh_covariance(model, free, q_fit[first], weights[first], data.unknown[inl][first], turned,
                                     frames, None, turn=True) * variance
    else:  # DH refitted under the convention: its own covariance, on the noise scale of the lines' fit
        model, free, frames = dh_fit.model, dh_fit.free, dh_fit.frames
        turning = turning and frames is not None
        prior = None if tolerance is None else prior_rows(free, tolerance / np.sqrt(variance))
        cov_turn = dh_covariance(model, free, q_fit[first], weights[first], data.unknown[inl][first], turned,
                                 frames, prior, turn=turning) * variance
        count = int(free.sum())
        cov_free, cov_turn = cov_turn[:count, :count], cov_turn if turning else None
    std = np.zeros(len(free))
    std[free] = np.sqrt(np.clip(np.diag(cov_free), 0.0, None))
    n = model.n_joints
    names = parameter_names(n)
    vector = np.concatenate([np.zeros(3), model.base[:3, 3], model.tool, model.dh_table().ravel()])
    flange = _flange_sigma(n, tolerance)
    fixed = [FixedParameter(names[k], float(vector[k]), _reason(names[k], n, model.joint_types, out.capped,
                                                                 float(flange[k])), float(flange[k]))
             for k in np.flatnonzero(~free)]
    if held is not None:
        fixed += [FixedParameter(f"held: {label}", float(std), _held_reason(float(std), held.tolerance, size))
                  for label, std in zip(held.names, held.std, strict=True)]
    kinematic = predictor_parameters(problem)
    predictor = Predictor(lines, covariance[np.ix_(kinematic, kinematic)], terms, fit.terms.coefs, None, tp_ids)
    expected = _expected_accuracy(predictor, q_fit, np.asarray(tp_ids)[tp_index], adequacy)
    dh_check = checks.dh_table(gap[0], gap[1], expected, [f"d{i}" for i in out.capped])
    ref = Refinement(model, free, cov_free, adequacy.noise, inl, fit.residuals, condition,
                     float(np.sum(res_w**2)), fit.q, data.points, [], tools)
    return WrittenModel(name, fit, adequacy, model, tools, std, fixed, ref, dict(out.capped), dh_check, terms,
                        predictor, lines_cov, covariance, condition, expected, problem, jac_blocks, frames, held,
                        cov_turn)


@dataclass(frozen=True)
class _FitRows:
    """The inlier rows a DH table is written from: joint values ``q`` (with joint errors), ``points``, ``sigma``
    (or None), ``weights``, ``tp_index``, the lines' weighted residuals ``res_w`` and the noise ``variance``
    (weighted units); ``rotations`` the measured frames of orientation rows (NaN on position rows; None: none)."""

    q: Array
    points: Array
    sigma: Array | None
    weights: Array
    tp_index: NDArray[np.int64]
    res_w: Array
    variance: float
    rotations: Array | None = None

    @property
    def positions(self) -> NDArray[np.bool_]:
        return np.ones(len(self.q), dtype=bool) if self.rotations is None else ~_finite(self.rotations)

    def rotations_of(self, rows: NDArray[np.bool_]) -> Array | None:
        return None if self.rotations is None else self.rotations[rows]


def _finite(rotations: Array) -> NDArray[np.bool_]:
    return np.all(np.isfinite(rotations), axis=(1, 2))


def _written_dh(lines: AxisLines, conventional: Array, nominal: DHModel | None, capped: dict[int, float],
                rows: _FitRows, noise: float, held: bool = False, scale: float = 1.0, reach: float = np.inf
                ) -> tuple[DHOutput, TableFit | None, Array, tuple[float, float], Array | None]:
    """The DH conversion with ``capped`` links at the parallel-axis convention; with any capped, the DH table
    refitted under that convention on every tracked point's rows (so the cost it adds is a likelihood ratio,
    chi-square when the axes are parallel), and with ``held`` on the nominal's values too
    (:func:`identify.results.hold.table_prior`, tolerances times ``scale``); the tools (k, 3), that cost with
    the RMS gap to the lines, and
    the nominal's tolerances of the full vector (rad, m; None unless ``held``). A link between revolute axes whose
    refitted ``d`` leaves ``reach`` (m) from its conventional value is capped too."""
    out = dh_output(lines, conventional, nominal, capped, with_jacobian=not capped)
    tools = _tools(out.model, lines)
    values, tolerance = table_prior(nominal, out.model, scale) if held and nominal is not None else (None, None)
    if not capped:
        return out, None, tools, _dh_gap(out.model, tools, lines, rows), tolerance
    prior = None if tolerance is None else (values, tolerance / np.sqrt(rows.variance))  # in the rows' units
    dh_fit = fit_table(out.model, rows.q, rows.points, rows.sigma, conventional, sorted(capped), noise, False, 0.0,
                       rows.tp_index, tools, rows.rotations, prior)
    # the refit may slide along what the data leave undetermined (two nearly parallel pairs in a row: only the sum
    # of their d is known) to a d beyond the reach: that pair gets the convention too, and the table is refitted
    # (d_i beyond it: of the pairs whose normal could have slid there, the nearest to parallel, one at a time)
    types = lines.joint_types
    far = {i: abs(float(dh_fit.model.d[i - 1] - conventional[i - 1, 1])) for i in range(1, len(types))
           if i not in capped and types[i - 1] == types[i] == "R"}
    far = {i: v for i, v in far.items() if not v <= reach}
    if far:
        i = min(far, key=lambda k: axis_angle(lines, k - 1))
        return _written_dh(lines, conventional, nominal, {**capped, i: far[i]}, rows, noise, held, scale, reach)
    return out, dh_fit, dh_fit.tools, _dh_gap(dh_fit.model, dh_fit.tools, lines, rows), tolerance


def _dh_gap(model: DHModel, tools: Array, lines: AxisLines, rows: _FitRows) -> tuple[float, float]:
    """RMS difference (m) of the DH model's and the lines' predictions at the fitted rows, and the cost the DH
    model adds over the lines', in noise variances."""
    pos = rows.positions  # (orientation rows: their frame is fitted apart, and the gap is in positions)
    q, tp = rows.q[pos], rows.tp_index[pos]
    dh = points_with_tools(model, tools, q, tp)
    gap = dh - points_from_lines(lines, q, tp)
    res_dh = (rows.points[pos] - dh) * rows.weights[pos, None]
    added = float(np.sum(res_dh**2) - np.sum(rows.res_w[pos] ** 2)) / max(rows.variance, 1e-300)
    return float(np.sqrt(np.mean(np.sum(gap**2, axis=1)))), added


def target_frames_of(model: DHModel, lines: AxisLines) -> Array | None:
    """Every tracked point's target frame (k, 3, 3) in the last DH frame of ``model`` (whose axes are ``lines``' at
    home), NaN for a point whose orientation was not measured; None when none was."""
    if lines.orientations is None:
        return None
    flange = frames_from_joints(model, lines.home[None, :])[0, -1]
    return flange[:3, :3].T @ lines.orientations


def _tools(model: DHModel, lines: AxisLines) -> Array:
    """Every tracked point (k, 3) in the last DH frame of ``model`` (whose axes are ``lines``' at home)."""
    flange = frames_from_joints(model, lines.home[None, :])[0, -1]
    return (lines.tps - flange[:3, 3]) @ flange[:3, :3]


def predictor_parameters(problem: LineProblem) -> NDArray[np.int64]:
    """Indices of the parameters a position predictor carries: lines, tracked points and joint-error coefficients
    (the home orientations of full-pose targets and the clock correction left out; their covariance is marginal)."""
    return np.r_[0:problem.start.n_parameters, problem.n_lines:problem.n_terms].astype(np.int64)


def _expected_accuracy(predictor: Predictor, q: Array, tp: NDArray[np.int64], adequacy: Adequacy) -> float:
    """RMS 3D prediction uncertainty at the fitted configurations (DH values with joint errors: the predictor
    without coupling), model error included (m)."""
    plain = Predictor(predictor.lines, predictor.covariance, predictor.terms, np.zeros_like(predictor.coefs), None,
                      predictor.tp_ids)  # q already carries the joint errors
    return float(np.sqrt(plain.mean_variance(q, tp) + 3 * adequacy.model_error**2))


UNDETERMINED = ("not determined by these data (redundant with other parameters, e.g. joints that always move together):"
                " held at its conventional value")


def _held_reason(std: float, tolerance: float, size: float) -> str:
    """Why a direction was held at the nominal: its sigma from the data alone, ``std`` (m of end-effector motion
    over the joint space), against the nominal's ``tolerance`` and the level for a robot of ``size`` (m)."""
    if 3.0 * std > 1e3 * size:
        why = "these data do not constrain it at all"
    elif 3.0 * std > LEVEL * size:
        why = (f"3 sigma of these data move points on the end effector by {3e3 * std:.3g} mm over the joint space, "
               f"beyond {100 * LEVEL:g} % of the robot's size ({size:.3g} m)")
    else:
        why = f"these data know it to {1e3 * std:.3g} mm (1 sigma of end-effector motion), no better than the nominal"
    return (f"held at the nominal placed on the data, known to {tolerance * 1e3:.3g} mm (the nominal's own tolerance, "
            f"carried by the uncertainties): {why}; the value is the data's sigma, m of end-effector motion")


def _flange_sigma(n: int, tolerance: Array | None) -> Array:
    """The full vector's sigmas (rad or m) of frame n's DH values where they are the nominal's (``tolerance``: the
    nominal's, :func:`identify.results.hold.table_prior`; None without a nominal), zeros elsewhere."""
    out = np.zeros(9 + 4 * n)
    if tolerance is not None:
        last = slice(9 + 4 * (n - 1), 9 + 4 * n)
        out[last] = np.where(np.isfinite(tolerance[last]), tolerance[last], 0.0)
    return out


def _reason(name: str, n: int, types: str, capped: dict[int, float], sigma: float = 0.0) -> str:
    joint = int("".join(ch for ch in name if ch.isdigit()) or 0)
    if joint in capped and name.startswith("d"):
        return (f"axes {joint} and {joint + 1} are parallel within tolerance or their uncertainty, or exact DH would "
                f"move d{joint} by {capped[joint]:.3g} m, beyond the robot's reach: the common normal is placed by "
                "convention")
    if joint == 1 and name[:-1] in ("theta", "d"):
        return "redundant with the base pose (frame 0 is placed by convention)"
    if name.startswith("d") and joint > 1 and set(types[: joint - 1]) == {"P"}:
        return (f"redundant with the base position: joints 1-{joint - 1} only translate, so a shift along axis "
                f"{joint} is a shift of the base (a convention of the robot's structure, not a gap in the data)")
    if joint == n and sigma > 0:
        unit = f"{sigma * 1e3:.3g} mm" if name[:-1] in ("d", "a") else f"{np.degrees(sigma):.3g} deg"
        return ("redundant with the tool: frame n (the flange) is placed where the nominal places it, known to "
                f"{unit} (its tolerance, in the accuracy stated for a tool given on the flange); the tool carries "
                "the TP")
    if joint == n:
        return "redundant with the tool: frame n is placed by convention and the tool carries the TP"
    if types[joint - 1] == "P" and name[:-1] in ("a", "d"):
        return "a prismatic axis has no position; it is placed to meet the next axis"
    return UNDETERMINED
