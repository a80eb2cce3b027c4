"""Change over time: has the robot changed between two calibrations, which parameters, and by how much at the TP?

Pure numpy/scipy on :class:`~identify.applications.calibrated.CalibratedModel` objects (results of the same robot).

For a pair (A earlier, B later) the DH parameters free in both (base and tool describe the cell and the target,
not the robot, and are reported apart) give the change ``Δ = x_B - x_A`` (angles wrapped) with the combined
covariance ``Σ = Σ_A + Σ_B`` (independent calibrations). A link whose parameters are fixed differently in A and B
(a parallel-axis convention in one and exact DH in the other) is left out of the parameter test and seen through
the TP displacement only. The family-wise false alarm is held at ``alpha`` by a closed test: first the whole
vector (``T = Δᵀ Σ⁺ Δ``, chi-square with rank(Σ) degrees of freedom); only if that rejects, each parameter by its
``z = Δ / σ`` with Holm's step-down correction. With several results, consecutive pairs are compared and ``alpha``
is shared among them (Bonferroni).

The predicted TP displacement: ``p_B(q) - p_A(q)`` in the robot's base frame (DH frame 0), both with A's TP, at
random poses within the joint limits; its RMS and maximum, beside the RMS the two results' uncertainties alone
would give (what "no change" looks like). Units: m and rad inside; the text says mm and deg.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2, norm

from identify.applications.calibrated import CalibratedModel
from identify.estimator.dh_vector import parameter_names
from identify.simulators.simulate import random_poses
from kinematics.dh import DH_NAMES

Array = NDArray[np.float64]

ALPHA = 0.01  # family-wise false-alarm rate of the whole comparison
POSES = 500  # random poses for the TP displacement
PARALLEL_TOL = 0.01  # rad: consecutive axes closer to parallel than this have an ill-conditioned exact-DH d
RANK_TOL = 1e-10  # relative eigenvalue of the correlation matrix below which a direction counts as absent
_LABEL = {"theta": "offset", "d": "d", "a": "a", "alpha": "twist"}


class CompareError(ValueError):
    """Results that cannot be compared (different robots or joint types); the message is one line."""


@dataclass(frozen=True)
class ParameterChange:
    """One DH parameter's change B - A: ``delta`` and its combined standard uncertainty ``std`` (m or rad), ``z``,
    Holm-adjusted ``p``, and whether it is ``significant`` (the whole-vector test rejected too)."""

    name: str
    delta: float
    std: float
    z: float
    p: float
    significant: bool

    @property
    def angular(self) -> bool:
        return self.name.rstrip("0123456789") in ("theta", "alpha")

    def text(self) -> str:
        """e.g. ``joint 3 offset (theta3) changed by +0.0500° ± 0.0012°``."""
        kind = self.name.rstrip("0123456789")
        joint = self.name[len(kind):]
        scale, unit = (math.degrees(1.0), "°") if self.angular else (1e3, " mm")
        return (f"joint {joint} {_LABEL[kind]} ({self.name}) changed by {self.delta * scale:+.4f}{unit} ± "
                f"{self.std * scale:.4f}{unit} (z = {self.z:.1f})")


@dataclass(frozen=True)
class PairComparison:
    """The comparison of results ``a`` and ``b`` (labels): the whole-vector test (``statistic``, ``dof``,
    ``p_value`` against ``alpha``), per-parameter ``changes``, the TP displacement (``displacement_rms``,
    ``displacement_max``, ``expected_rms`` from the uncertainties alone; m), how far the base and the TP moved
    (m, rad; the cell, not the robot), parameters ``excluded`` from the test and why, and the ``verdict`` line."""

    a: str
    b: str
    statistic: float
    dof: int
    p_value: float
    alpha: float
    changes: tuple[ParameterChange, ...]
    displacement_rms: float
    displacement_max: float
    expected_rms: float
    base_shift: float
    base_turn: float
    tool_shift: float
    excluded: tuple[str, ...] = ()
    verdict: str = ""

    @property
    def significant(self) -> bool:
        return self.p_value < self.alpha

    @property
    def changed(self) -> tuple[ParameterChange, ...]:
        return tuple(c for c in self.changes if c.significant)


@dataclass(frozen=True)
class Comparison:
    """Consecutive pairs of a series of results, and one verdict line for the series."""

    labels: tuple[str, ...]
    pairs: tuple[PairComparison, ...]
    alpha: float
    verdict: str = field(default="")
    poses: Array | None = None  # (k, n) readings the TP displacement was computed at
    notes: tuple[str, ...] = ()  # where the poses lie against each input's domain

    @property
    def significant(self) -> bool:
        return any(p.significant for p in self.pairs)


def check_same_robot(models: list[CalibratedModel], robots: list[str | None], labels: list[str]) -> None:
    """CompareError (one line) unless every result has the same joint types and names the same robot (where any
    names one)."""
    types = models[0].model.joint_types
    for model, label in zip(models[1:], labels[1:], strict=True):
        if model.model.joint_types != types:
            raise CompareError(f"{labels[0]} has joints {types}, {label} {model.model.joint_types}: different robots "
                               "cannot be compared")
    named = [(r, label) for r, label in zip(robots, labels, strict=True) if r]
    for r, label in named[1:]:
        if r.lower() != named[0][0].lower():
            raise CompareError(f"{named[0][1]} is a {named[0][0]}, {label} a {r}: different robots cannot be compared")


def _block(model: CalibratedModel, index: NDArray[np.int64]) -> Array:
    """The covariance of full-vector parameters ``index`` (all free in ``model``)."""
    assert model.free is not None and model.covariance is not None
    pos = np.cumsum(model.free) - 1
    sel = pos[index]
    return model.covariance[np.ix_(sel, sel)]


def _values(model: CalibratedModel) -> Array:
    return np.concatenate([np.zeros(9), model.model.dh_table().ravel()])


def compare_pair(a: CalibratedModel, b: CalibratedModel, labels: tuple[str, str], q: Array,
                 alpha: float = ALPHA) -> PairComparison:
    """The comparison of ``a`` (earlier) and ``b`` (later) at the random poses ``q`` (k, n) for the displacement."""
    n = a.n_joints
    if a.free is None or b.free is None:
        raise CompareError("both results need their covariance (identify them again with this version)")
    names = parameter_names(n)
    use = a.free & b.free
    use[:9] = False
    excluded = []
    for i, why in _unstable_links(a, b).items():
        use[9 + 4 * i:13 + 4 * i] = False
        excluded.append(f"link {i + 1}: {why}: seen through the TP displacement only")
    index = np.flatnonzero(use)
    delta = _values(b)[index] - _values(a)[index]
    angular = np.array([names[k].rstrip("0123456789") in ("theta", "alpha") for k in index], dtype=bool)
    delta[angular] = np.angle(np.exp(1j * delta[angular]))
    cov = _block(a, index) + _block(b, index)
    std = np.sqrt(np.maximum(np.diag(cov), 1e-300))
    corr = cov / np.outer(std, std)
    values, vectors = np.linalg.eigh(corr)
    keep = values > RANK_TOL * values[-1]
    white = (vectors[:, keep].T @ (delta / std)) / np.sqrt(values[keep])
    statistic, dof = float(white @ white), int(keep.sum())
    p_value = float(chi2.sf(statistic, dof)) if dof else 1.0
    z = delta / std
    p_raw = 2 * norm.sf(np.abs(z))
    p_holm = _holm(p_raw)
    gate = p_value < alpha
    changes = tuple(ParameterChange(names[k], float(d), float(s), float(zz), float(p), bool(gate and p < alpha))
                    for k, d, s, zz, p in zip(index, delta, std, z, p_holm, strict=True))
    disp, expected = displacement(a, b, q)
    rms, worst = float(np.sqrt(np.mean(np.sum(disp**2, axis=1)))), float(np.max(np.linalg.norm(disp, axis=1)))
    turn = np.linalg.inv(a.base[:3, :3]) @ b.base[:3, :3]
    result = PairComparison(labels[0], labels[1], statistic, dof, p_value, alpha, changes, rms, worst, expected,
                            float(np.linalg.norm(b.base[:3, 3] - a.base[:3, 3])),
                            float(np.arccos(np.clip((np.trace(turn) - 1) / 2, -1.0, 1.0))),
                            float(np.linalg.norm(b.tool() - a.tool())), tuple(excluded))
    return _with_verdict(result)


def _unstable_links(a: CalibratedModel, b: CalibratedModel) -> dict[int, str]:
    """0-based links whose DH values cannot be compared one by one, and why: fixed differently in the two results
    (a parallel-axis convention in one, exact DH in the other), or exact DH of a near-parallel pair (its ``d`` is
    metres or more and nonlinear in the data); the next link, which compensates such a ``d``, goes with it."""
    assert a.free is not None and b.free is not None
    out: dict[int, str] = {}
    n = a.n_joints
    for i in range(n):
        cols = slice(9 + 4 * i, 13 + 4 * i)
        d_free = a.free[9 + 4 * i + 1] or b.free[9 + 4 * i + 1]
        parallel = min(abs(math.sin(m.model.alpha[i])) for m in (a, b)) < math.sin(PARALLEL_TOL)
        why = ("parameters fixed differently in the two results (a parallel-axis convention in one, exact DH in "
               "the other)" if not np.array_equal(a.free[cols], b.free[cols]) else
               "exact DH of near-parallel axes (its d is ill-conditioned)" if parallel and d_free else None)
        if why is not None:
            out.setdefault(i, why)
            if i + 1 < n:
                out.setdefault(i + 1, f"compensates link {i + 1}, {why}")
    return dict(sorted(out.items()))


def displacement(a: CalibratedModel, b: CalibratedModel, q: Array) -> tuple[Array, float]:
    """``p_B(q) - p_A(q)`` (k, 3) in the base frame with A's TP, m, and the RMS the two uncertainties alone give."""
    tool = a.tool()
    a0, b0 = a.with_base(np.eye(4)), b.with_base(np.eye(4))
    disp = b0.points(q, tool=tool) - a0.points(q, tool=tool)
    cov = a.point_covariances(q, tool=tool, frame="base") + b.point_covariances(q, tool=tool, frame="base")
    model_error2 = 3 * (a.model_error**2 + b.model_error**2)
    return disp, float(np.sqrt(np.mean(np.trace(cov, axis1=1, axis2=2)) + model_error2))


def _holm(p: Array) -> Array:
    """Holm's step-down adjusted p-values (family-wise error control)."""
    m = len(p)
    if not m:
        return p
    order = np.argsort(p)
    adjusted = np.minimum(1.0, np.maximum.accumulate((m - np.arange(m)) * p[order]))
    out = np.empty(m)
    out[order] = adjusted
    return out


def _mm(x: float) -> str:
    return f"{x * 1e3:.4f} mm"


def _with_verdict(r: PairComparison) -> PairComparison:
    tp = (f"TP displacement over the workspace RMS {_mm(r.displacement_rms)}, max {_mm(r.displacement_max)} "
          f"(the uncertainties alone give {_mm(r.expected_rms)} RMS)")
    if not r.significant:
        largest = max(r.changes, key=lambda c: abs(c.z), default=None)
        extra = f"; largest |z| {abs(largest.z):.1f} ({largest.name})" if largest is not None else ""
        text = (f"{r.a} -> {r.b}: no significant change (chi-square {r.statistic:.1f} for {r.dof} parameters, "
                f"p = {r.p_value:.3g} >= {r.alpha:.3g}{extra}); {tp}")
    else:
        named = "; ".join(c.text() for c in sorted(r.changed, key=lambda c: -abs(c.z))) or (
            "the parameters together, none alone")
        text = (f"{r.a} -> {r.b}: SIGNIFICANT CHANGE (chi-square {r.statistic:.1f} for {r.dof} parameters, p = "
                f"{r.p_value:.3g} < {r.alpha:.3g}): {named}; {tp}: check what happened to the robot between the "
                "two calibrations (a collision, a repair, a motor or encoder change)")
    return replace(r, verdict=text)


def compare(models: list[CalibratedModel], labels: list[str], limits: Array | None, alpha: float = ALPHA,
            poses: int = POSES, seed: int = 0, home: Array | None = None) -> Comparison:
    """Consecutive pairs of ``models`` (in time order), ``alpha`` shared among them; displacements at ``poses``
    random poses within ``limits`` (n, 2) (default: home ± π for revolute, ± 0.1 m for prismatic joints)."""
    if len(models) < 2:
        raise CompareError("give at least two results to compare")
    n = models[0].n_joints
    if limits is None:
        centre = np.zeros(n) if home is None else np.asarray(home, dtype=float)
        half = np.array([math.pi if t == "R" else 0.1 for t in models[0].model.joint_types])
        limits = np.column_stack([centre - half, centre + half])
    q = random_poses(np.asarray(limits, dtype=float), poses, np.random.default_rng(seed))
    share = alpha / (len(models) - 1)
    pairs = tuple(compare_pair(models[k], models[k + 1], (labels[k], labels[k + 1]), q, share)
                  for k in range(len(models) - 1))
    changed = [p for p in pairs if p.significant]
    if not changed:
        verdict = (f"no significant change over {len(models)} calibrations (family-wise false-alarm rate {alpha:g}); "
                   f"largest TP displacement RMS {_mm(max(p.displacement_rms for p in pairs))}")
    else:  # one short line: each pair's own verdict follows it (printed once, there)
        largest = [max(p.changed, key=lambda c: abs(c.z)).text() if p.changed else "the parameters together"
                   for p in changed]
        verdict = ("SIGNIFICANT CHANGE " + "; ".join(f"{p.a} -> {p.b} (largest: {w})" for p, w in
                                                      zip(changed, largest, strict=True))
                   + f"; family-wise false-alarm rate {alpha:g}; each pair's test below")
    return Comparison(tuple(labels), pairs, alpha, verdict, q)


def dh_label(name: str) -> str:
    """``theta3`` -> ``joint 3 offset (theta3)``."""
    kind = name.rstrip("0123456789")
    return f"joint {name[len(kind):]} {_LABEL.get(kind, kind)} ({name})" if kind in DH_NAMES else name
