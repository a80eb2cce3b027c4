"""What the data do not determine is held at the nominal model, not written where the fit wandered.

The lines fit (:mod:`identify.estimator.poe`) has a covariance over its minimal parameters (axis tilts and shifts,
tracked points, joint-error coefficients, clock). Scaled by each parameter's lever arm (how far a unit of it moves
the tracked point, RMS over the fitted poses), its eigenvectors are the directions the data know best and worst, in
metres of tracked-point motion. A direction along which three standard uncertainties move the tracked point by more
than :data:`identify.estimator.identifiability.LEVEL` of the robot's size is *not determined*: a model error the
fit cannot hold, or the noise, puts it anywhere along that direction (a UR with one reflector next to axis 6 wrote
a5 = 186 mm, alpha5 = -152 deg where the arm has 0 and -90, and a tool on the flange inherited centimetres).

With a nominal model, the nominal placed on the data is a measurement too: of each axis line
(:class:`NominalPrior`) and of each DH value (:func:`table_prior`), to tolerances a real arm keeps about its
catalogue model, widened where the data show this arm farther from it (:func:`nominal_scale`). The maximum a
posteriori fit of the data and that prior keeps what the data determine (their sigma is far below the tolerance
there, so the prior moves them by a negligible fraction of it), takes the nominal where the data say nothing, and
weighs the two in between. The covariance afterwards carries the nominal's own error, so every accuracy stated from it
accounts for the held values; the directions the data alone leave undetermined are named (:func:`undetermined`).
Units: m, rad; frames: tracker.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from identify.estimator.estimate import FitData, LinesFit, place_nominal
from identify.estimator.geometry import perpendicular_basis
from identify.estimator.identifiability import LEVEL, LOADING
from identify.estimator.poe import AxisLines, JointTerms, LineProblem, lines_from_model
from kinematics.dh import DHModel, frames_from_joints

Array = NDArray[np.float64]

HELD_TOLERANCE = 0.002  # rad, and of the robot's size (m): 1 sigma of a real arm's axes about its catalogue model's
# m, 1 sigma of one link's length or offset about the catalogue's: machined lengths up to 1 m hold +-0.3..0.8 mm
# (ISO 2768-m), and calibrated arms differ from their catalogue tables by tenths of a millimetre to a millimetre
LINK_TOLERANCE = 1e-3


@dataclass(frozen=True)
class Hold:
    """What was held at the reference: for each direction the data do not determine, its standard uncertainty from
    the data alone ``std`` (h,) (m of end-effector motion), the ``tolerance`` (m) the reference is known to along
    it, and what it moves (``names``, e.g. ``axis 6``, ``tracked point 1``); whether a model error the fit cannot
    hold counted (``model_error``)."""

    std: Array
    tolerance: float
    names: tuple[str, ...]
    model_error: bool = False

    def __len__(self) -> int:
        return len(self.std)


class NominalPrior:
    """The reference (the nominal placed on the data) as a measurement of the axis lines: each axis's tilt known
    to :data:`HELD_TOLERANCE` rad and its position across itself to :data:`HELD_TOLERANCE` of the robot's ``size``
    (m), about the reference's (:func:`increments`); tracked points, joint errors and clock are left to the data
    (a nominal says nothing of them). The tolerances are widened by :func:`nominal_scale` where the data show this
    arm farther from its nominal than they say (``covariance``: the fit's, without the prior). Its residuals are in
    units of those tolerances, so stacked with the data's (in units of their noise) they make the maximum a
    posteriori problem. Parameters as ``problem``'s (:class:`identify.estimator.poe.LineProblem`)."""

    def __init__(self, problem: LineProblem, reference: AxisLines, size: float, covariance: Array | None = None):
        self._reference = increments(problem, reference)
        sigma = []
        for kind in problem.types:
            sigma += [HELD_TOLERANCE] * 2 + ([HELD_TOLERANCE * size] * 2 if kind == "R" else [])
        self._sigma = np.array(sigma)
        self.scale = nominal_scale(self._reference[:len(sigma)], self._sigma, covariance)
        self._sigma *= self.scale
        self._size = problem.size

    @property
    def reference(self) -> Array:
        """The reference as the problem's parameters (p,)."""
        return self._reference

    def residuals(self, x: Array) -> Array:
        """Each line parameter's offset from the reference's at ``x`` (p,), in tolerances."""
        k = len(self._sigma)
        return (x[:k] - self._reference[:k]) / self._sigma

    def jacobian(self) -> Array:
        """d residuals / dx (l, p): constant."""
        out = np.zeros((len(self._sigma), self._size))
        out[:, :len(self._sigma)] = np.diag(1.0 / self._sigma)
        return out

    def solve(self, problem: LineProblem, variance: float, starts: list[Array]) -> Array:
        """The parameters (p,) that best fit ``problem``'s rows (noise ``variance``, weighted units) and this
        prior together, from each of ``starts`` (e.g. the fit itself and the reference), the lowest cost kept."""
        scale = float(np.sqrt(variance))
        prior = self.jacobian()

        def residuals(x: Array) -> Array:
            return np.concatenate([problem.residuals(x) / scale, self.residuals(x)])

        def jacobian(x: Array) -> Array:
            return np.vstack([problem.jacobian(x) / scale, prior])

        fits = [least_squares(residuals, start, jac=jacobian, method="trf", x_scale="jac", xtol=1e-10, ftol=1e-10)
                for start in starts]
        return min(fits, key=lambda f: f.cost).x


COMPARABLE = 10.0  # tolerances: a table value this far from the nominal's is another quantity (another convention)


def nominal_scale(offset: Array, sigma: Array, covariance: Array | None) -> float:
    """How many times its stated tolerances this arm lies from its nominal, judged where the data see it: the RMS
    of ``offset / sigma`` (the reference's line parameters as increments on the fit, and their tolerances, (l,))
    over the parameters the data know to a third of their tolerance or better (``covariance``, (p, p), the fit's
    without the prior); at least 1, and 1 when fewer than three are known that well. The nominal's tolerance where
    the data are silent is then the one the data show where they speak (empirical Bayes): a robot farther from its
    catalogue model than usual (a real Franka Panda misses its catalogue table by 3-6 mm) is not held to 1 mm."""
    if covariance is None:
        return 1.0
    known = np.sqrt(np.clip(np.diag(covariance)[:len(sigma)], 0.0, None)) < sigma / 3.0
    if np.sum(known) < 3:
        return 1.0
    return max(1.0, float(np.sqrt(np.mean((offset[known] / sigma[known]) ** 2))))


def table_prior(nominal: DHModel, table: DHModel, scale: float = 1.0) -> tuple[Array, Array]:
    """The nominal as a measurement of a DH ``table``'s full parameter vector (:mod:`identify.estimator.dh_vector`):
    the nominal's values and their tolerances, :data:`HELD_TOLERANCE` rad for theta and alpha,
    :data:`LINK_TOLERANCE` m for d and a, both times ``scale`` (:func:`nominal_scale`) (one link's values, where
    the axis lines' positions accumulate the errors
    of every link before them); ``inf`` (no measurement) for the base and tool, which a nominal does not give, and
    for every value of ``table`` (converted from lines that the nominal already held) more than
    :data:`COMPARABLE` tolerances from the nominal's: a value the data determine far from it, or one written under
    another convention (a prismatic joint's offset, an angle measured from the other side), not its quantity.
    Angles are given on the table's own branch (the nominal's pi for the table's -pi + 0.004: -pi)."""
    values = np.concatenate([np.zeros(9), nominal.dh_table().ravel()])
    per_joint = np.array([HELD_TOLERANCE, LINK_TOLERANCE, LINK_TOLERANCE, HELD_TOLERANCE]) * scale
    sigma = np.concatenate([np.full(9, np.inf), np.tile(per_joint, nominal.n_joints)])
    own = np.concatenate([np.zeros(9), table.dh_table().ravel()])
    offset = own - values
    angles = np.concatenate([np.zeros(9, dtype=bool), np.tile([True, False, False, True], nominal.n_joints)])
    offset[angles] = np.angle(np.exp(1j * offset[angles]))  # -pi and pi are one angle
    sigma[np.abs(offset) > COMPARABLE * sigma] = np.inf
    return own - offset, sigma  # the nominal's angles on the table's own branch


def undetermined(covariance: Array, metric: Array, size: float, names: list[str], bias: float = 0.0) -> Hold:
    """The directions of ``covariance`` (p, p; m and rad) not determined for a robot of ``size`` (m): 3 sigma of
    motion of the end effector's points, plus ``bias`` sigma for a model error the fit cannot hold, beyond
    :data:`LEVEL` of it, or known no better than the nominal is. ``metric`` (p, p): the mean square motion (m²) of those
    points per unit change of the parameters (:func:`line_metric`); ``names`` (k <= p): what
    each of the first k parameters is (e.g. ``axis 6``), the only ones held (the others, such as joint errors and
    clock, follow them through their correlation). ``bias``: the worst least-squares shift a model error ε per axis
    over N rows gives a direction of standard uncertainty σ is ``ε sqrt(3N) / s · σ`` (s the noise the covariance
    is scaled to), as in :mod:`identify.estimator.identifiability`."""
    k = len(names)
    values, vectors = np.linalg.eigh((metric[:k, :k] + metric[:k, :k].T) / 2)
    root = (vectors * np.sqrt(np.clip(values, 0.0, None))) @ vectors.T  # metric^(1/2), symmetric
    scaled = root @ covariance[:k, :k] @ root
    values, vectors = np.linalg.eigh((scaled + scaled.T) / 2)
    std = np.sqrt(np.clip(values, 0.0, None))
    far = ((3.0 + bias) * std > LEVEL * size) | ((1.0 + bias) * std > HELD_TOLERANCE * size)
    directions = np.zeros((int(far.sum()), len(covariance)))
    directions[:, :k] = vectors[:, far].T @ root
    lever = np.sqrt(np.clip(np.diag(metric)[:k], 0.0, None))
    moved = [(covariance[:k, :k] @ a[:k]) * lever for a in directions]  # what each parameter moves along it
    return Hold(std[far], HELD_TOLERANCE * size,
                tuple(_label(m / max(float(np.linalg.norm(m)), 1e-300), names) for m in moved), bias > 0.0)


def _label(vector: Array, names: list[str]) -> str:
    """The names a unit ``vector`` loads on (the norm of its entries under one name at least :data:`LOADING`)."""
    weight: dict[str, float] = {}
    for name, v in zip(names, vector, strict=True):
        weight[name] = weight.get(name, 0.0) + v * v
    return ", ".join(n for n, w in weight.items() if w >= LOADING**2) or "several parameters together"


def line_names(problem: LineProblem) -> list[str]:
    """What each of ``problem``'s line and tracked-point parameters moves: ``axis i`` or ``tracked point k``."""
    out = []
    for i, kind in enumerate(problem.types):
        out += [f"axis {i + 1}"] * (4 if kind == "R" else 2)
    for p in range(len(problem.start.tps)):
        out += [f"tracked point {p + 1}"] * 3
    return out


PROBE = 0.1  # m: the end effector's points probed beside each tracked point, this far along three directions
PROBE_POSES = 200  # poses over the joint space at which the probed points' motion is averaged


def line_metric(problem: LineProblem, rng_seed: int = 0) -> Array:
    """The mean square motion (m²) per unit change of ``problem``'s parameters (p, p) of points on the end effector:
    each tracked point and points :data:`PROBE` beside it along the last axis and two directions across it (a tool
    or a second reflector there moves with the last link), over :data:`PROBE_POSES` poses spanning the joint space
    (home ± pi for revolute joints, ± 0.1 m for prismatic ones, seeded): what the data must determine for a model
    used anywhere, not only the measured point at the measured poses."""
    lines = problem.start
    probe = replace(lines, extra_tps=np.vstack([lines.extra_tps, probe_points(lines)]))
    q = spanning_poses(lines, rng_seed)
    count = len(probe.tps)
    q_all = np.repeat(q, count, axis=0)
    tp_index = np.tile(np.arange(count), len(q))
    prob = LineProblem(probe, q_all, np.zeros((len(q_all), 3)), np.ones(len(q_all)), tp_index=tp_index,
                       terms=JointTerms(np.zeros((len(q_all), len(problem.terms))), problem.terms.joints,
                                        problem.terms.coefs))
    jac = prob.jacobian_blocks(np.zeros(prob.size), q_all, tp_index)
    own = problem.n_lines  # the lines' and real tracked points' columns; the probes' own columns are dropped
    columns = np.zeros((len(q_all), 3, problem.size))
    columns[:, :, :own] = jac[:, :, :own]
    flat = columns.reshape(-1, problem.size)
    return flat.T @ flat / len(q_all)


def probe_points(lines: AxisLines) -> Array:
    """Points (3k, 3) :data:`PROBE` beside each tracked point at home, along the last axis and two directions
    across it: where a tool or a second reflector would be, moving with the last link."""
    last = lines.directions[-1]
    across = np.array(perpendicular_basis(last))
    return (lines.tps[:, None, :] + PROBE * np.vstack([last, across])[None]).reshape(-1, 3)


def spanning_poses(lines: AxisLines, seed: int = 0) -> Array:
    """:data:`PROBE_POSES` joint values (k, n) about ``lines.home``: ± pi (revolute), ± 0.1 m (prismatic)."""
    half = np.array([np.pi if t == "R" else 0.1 for t in lines.joint_types])
    rng = np.random.default_rng(seed)
    return lines.home + rng.uniform(-1.0, 1.0, (PROBE_POSES, len(half))) * half


def increments(problem: LineProblem, reference: AxisLines) -> Array:
    """The parameters (p,) that move ``problem``'s start lines onto ``reference`` (same joints, tracked points):
    each axis tilted to the reference's direction and shifted, in the plane of the start's point perpendicular to
    its direction, to where the reference line crosses it; each tracked point moved onto the reference's; zero for
    joint errors and clock."""
    start = problem.start
    x = np.zeros(problem.size)
    k = 0
    for i, kind in enumerate(start.joint_types):
        e, d0 = problem.bases[i], start.directions[i]
        d = reference.directions[i] * (1.0 if reference.directions[i] @ d0 >= 0 else -1.0)
        x[k:k + 2] = e @ d / (d @ d0)
        if kind == "R":
            crossing = reference.points[i] + d * ((start.points[i] - reference.points[i]) @ d0) / (d @ d0)
            x[k + 2:k + 4] = e @ (crossing - start.points[i])
            k += 4
        else:
            k += 2
    x[k:k + start.tps.size] = (reference.tps - start.tps).ravel()
    return x


def nominal_lines(nominal: DHModel, q: Array, points: Array, tp_index: NDArray[np.int64], home: Array) -> AxisLines:
    """The axis lines (tracker frame, at joint values ``home``) of ``nominal`` placed on the fit rows (readings
    ``q`` (m, n) with joint errors applied, measured ``points`` (m, 3), 0-based ``tp_index``), every tracked point
    fitted on its flange (:func:`identify.estimator.estimate.place_nominal`)."""
    placed, tools = place_nominal(nominal, q, points, tp_index)
    lines = lines_from_model(placed, home)
    flange = frames_from_joints(placed, home[None, :])[0, -1]
    tps = tools @ flange[:3, :3].T + flange[:3, 3]
    return replace(lines, tp_home=tps[0], extra_tps=tps[1:])


def held_fit(fit: LinesFit, data: FitData, problem: LineProblem, x: Array) -> LinesFit:
    """``fit`` moved by the parameters ``x`` of ``problem`` (its inlier rows): new lines, joint-error coefficients
    and clock; the joint values and residuals of every row of ``data`` (the fit's rows, timed as it) recomputed."""
    lines, _ = problem.lines(x)
    terms = JointTerms(fit.terms.regressors, fit.terms.joints, problem.coefs(x))
    timing = fit.timing if fit.timing is None else replace(fit.timing, tau=problem.tau(x))
    every = data.timed(timing).problem(lines, terms)
    q = every.joints(lines, terms.coefs, every.tau(np.zeros(every.size)))
    predicted = every.residuals(np.zeros(every.size)).reshape(-1, 3) / data.weights[:, None] + data.points
    return replace(fit, lines=lines, q=q, residuals=data.points - predicted, terms=terms, timing=timing, jacobian=None)
