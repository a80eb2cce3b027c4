"""ISO 9283-style pose accuracy (AP) and repeatability (RP) of positions (pure numpy).

The test cube (edges parallel to the robot's base axes, centre ``c``, edge ``L``) and its measuring plane: the
diagonal plane through the two cube edges parallel to the base y axis at (x-, z-) and (x+, z+). Its four
corners lie on two space diagonals of the cube; P1 is the cube's centre, P2..P5 lie on those diagonals at
10 % of the diagonal's length from the corners (ISO 9283, 6.8.3). Each cycle visits P1, P5, P4, P3, P2 in that
order (7.2.1), each approached the same way; ISO asks for 30 cycles.

For one pose commanded at ``x_c`` and attained at ``x_j`` (j = 1..N, measured):

- AP = |x̄ - x_c|, the distance of the barycentre of the attained positions from the commanded one;
- RP = l̄ + 3 S_l, with l_j = |x_j - x̄| and S_l = sqrt(Σ(l_j - l̄)² / (N - 1)).

Beyond AP and RP, from the same visits:

- distance accuracy and repeatability (7.3) between two poses visited in each cycle (P2 and P4 here): with
  D_c = |x_c,a - x_c,b| and D_j = |x_a,j - x_b,j| in cycle j, AD = D̄ - D_c and RD = 3 S_D,
  S_D = sqrt(Σ(D_j - D̄)² / (n - 1));
- drift of the pose characteristics (7.6) over the run: dAP = |AP_first - AP_last| and dRP = |RP_first - RP_last|,
  AP and RP of one pose over the first and the last third of its visits (the standard's 8-hour drift test is not
  run: this is the drift within the test);
- multi-directional pose accuracy variation (7.2): vAP = max |x̄_h - x̄_k| over the barycentres reached from
  different approach directions (:func:`multi_directional`, :func:`directions_result`);
- orientation accuracy and repeatability (7.2.1, 7.2.2) where three or more points on the tool are measured: the
  attained orientation of each visit is the rotation of the rigid fit (:func:`fitted_rotation`) of the points the
  commanded pose puts them at to the measured ones; its deviation from the commanded orientation, as rotations
  a, b, c about the frame's x, y, z axes (:func:`deviation_angles`), gives AP_a = ā, RP_a = 3 S_a and so on
  (:func:`orientation_result`).

Uncertainties: :func:`monte_carlo` gives the standard uncertainty of any set of figures by recomputing them on
synthetic repeats of the test, each visit's measurement drawn again around the barycentre of its pose with the
spread of its visits, pooled with that of the run's other poses and the tracker's stated noise
(:func:`spread_covariances`).
Units: metres, radians; frame: whatever the positions are given in (the robot's base frame in ``acquire verify``).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

Array = NDArray[np.float64]

ISO_ORDER = (1, 5, 4, 3, 2)  # the poses of one cycle, in the order visited
CORNER_SHARE = 0.1  # P2..P5 lie this share of the diagonal's length from the corners
ISO_CYCLES = 30
FROM_FRAMES = "6-DoF readings of the target frame"  # what an orientation AP/RP was measured from ...
FROM_POINTS = "rigid fit of the tracked points"  # ... (acquire verify's summary, orientation.source)
MC_DRAWS = 400  # synthetic repeats of :func:`monte_carlo`: a standard deviation to about 3.5 %
NOISE_PRIOR = 2.0  # visits' worth of the tracker's stated noise pooled with a group's spread (monte_carlo) ...
GROUP_PRIOR = 10.0  # ... and visits' worth of that group's spread pooled with each set's own


def cube_poses(centre: Array, edge: float) -> Array:
    """P1..P5 (5, 3) of the test cube with ``centre`` (3,) and ``edge`` (m), in the cube's frame's axes."""
    c = np.asarray(centre, dtype=float)
    h = edge / 2.0
    corners = np.array([[-h, -h, -h], [-h, h, -h], [h, h, h], [h, -h, h]])  # the measuring plane, in order
    return np.vstack([c, c + (1.0 - 2.0 * CORNER_SHARE) * corners])


def visit_order(cycles: int) -> list[tuple[int, int]]:
    """(cycle, pose) pairs, 1-based, in the order the test visits them."""
    return [(k, p) for k in range(1, cycles + 1) for p in ISO_ORDER]


@dataclass(frozen=True)
class PoseResult:
    """AP and RP of one pose (m): ``commanded`` (3,), ``barycentre`` (3,) of ``n`` attained positions, ``ap``,
    ``ap_xyz`` (3,) the barycentre minus the commanded position, ``rp``, ``l_mean`` and ``s_l``; ``ap_std`` the
    standard uncertainty of ``ap`` from the spread of the attained positions (N readings; m)."""

    pose: int
    n: int
    commanded: Array
    barycentre: Array
    ap: float
    ap_xyz: Array
    rp: float
    l_mean: float
    s_l: float
    ap_std: float


def pose_result(pose: int, commanded: Array, attained: Array, sigma: Array | None = None) -> PoseResult:
    """ISO 9283 AP and RP of one pose from its ``attained`` positions (N, 3), N >= 2; ``sigma`` (N,): the per-axis
    standard uncertainty of each measured position when known (then AP's uncertainty is never taken below what
    it implies: a spread estimated from a few cycles can be far too small)."""
    attained = np.atleast_2d(np.asarray(attained, dtype=float))
    n = len(attained)
    if n < 2:
        raise ValueError(f"pose P{pose}: AP and RP need at least 2 attained positions, got {n}")
    bary = attained.mean(axis=0)
    offset = bary - np.asarray(commanded, dtype=float)
    ap = float(np.linalg.norm(offset))
    lengths = np.linalg.norm(attained - bary, axis=1)
    s_l = float(np.std(lengths, ddof=1))
    # the barycentre's covariance is the spread's over N; its projection on the offset is AP's uncertainty
    cov = np.cov(attained.T, ddof=1)
    direction = offset / ap if ap > 0 else np.full(3, 1 / np.sqrt(3))
    spread = float(direction @ cov @ direction)
    if sigma is not None and len(sigma):
        spread = max(spread, float(np.mean(np.square(sigma))))
    ap_std = float(np.sqrt(max(spread, 0.0) / n))
    return PoseResult(pose, n, np.asarray(commanded, dtype=float), bary, ap, offset, float(lengths.mean() + 3 * s_l),
                      float(lengths.mean()), s_l, ap_std)


@dataclass(frozen=True)
class Accuracy:
    """AP/RP of the five poses (``poses``, P1..P5 in order) of one run (``label``, e.g. before / after), with its
    distance accuracy (``distance``) and drift (``drift``) when the run has the visits for them."""

    label: str
    poses: tuple[PoseResult, ...]
    distance: Distance | None = None
    drift: Drift | None = None
    directions: tuple[Directions, ...] = ()
    orientation: tuple[Orientation, ...] = ()
    uncertainty: dict[str, float] = field(default_factory=dict)

    @property
    def ap(self) -> float:
        """The largest AP over the poses, m (ISO reports per pose; this is the worst)."""
        return max(p.ap for p in self.poses)

    @property
    def rp(self) -> float:
        """The largest RP over the poses, m."""
        return max(p.rp for p in self.poses)

    @property
    def ap_mean(self) -> float:
        return float(np.mean([p.ap for p in self.poses]))

    def as_dict(self) -> dict[str, object]:
        """Plain data (m) for YAML and JSON."""
        return {"label": self.label, "ap_max": self.ap, "ap_mean": self.ap_mean, "rp_max": self.rp,
                "poses": [{"pose": f"P{p.pose}", "n": p.n, "commanded": p.commanded.tolist(),
                           "barycentre": p.barycentre.tolist(), "ap": p.ap, "ap_std": p.ap_std,
                           "ap_xyz": p.ap_xyz.tolist(), "rp": p.rp, "l_mean": p.l_mean, "s_l": p.s_l}
                          for p in self.poses],
                "distance": None if self.distance is None else self.distance.as_dict(),
                "drift": None if self.drift is None else self.drift.as_dict(),
                "vap": [d.as_dict() for d in self.directions],
                "orientation": [o.as_dict() for o in self.orientation],
                "figures": self.figures(), "uncertainty": dict(self.uncertainty)}

    def figures(self) -> dict[str, float]:
        """Every figure of the run by name (``ap P1``, ``rp P1``, ``ad``, ``rd``, ``dap``, ``drp``, ``vap P1``,
        ``ap_a P1``, ``rp_a P1`` ..., m or rad): what :func:`monte_carlo` gives the uncertainty of."""
        out = {}
        for p in self.poses:
            out[f"ap P{p.pose}"], out[f"rp P{p.pose}"] = p.ap, p.rp
        if self.distance is not None:
            out["ad"], out["rd"] = self.distance.ad, self.distance.rd
        if self.drift is not None:
            out["dap"], out["drp"] = self.drift.dap, self.drift.drp
        for d in self.directions:
            out[f"vap P{d.pose}"] = d.vap
        for o in self.orientation:
            for k, axis in enumerate("abc"):
                out[f"ap_{axis} P{o.pose}"], out[f"rp_{axis} P{o.pose}"] = float(o.ap[k]), float(o.rp[k])
        return out


def accuracy(label: str, commanded: Array, attained: dict[int, Array], sigma: dict[int, Array] | None = None
             ) -> Accuracy:
    """AP/RP of every pose with attained positions: ``commanded`` (5, 3) P1..P5, ``attained`` pose -> (N, 3),
    ``sigma`` pose -> (N,) per-axis standard uncertainties of those positions (optional)."""
    sigma = sigma or {}
    return Accuracy(label, tuple(pose_result(p, commanded[p - 1], attained[p], sigma.get(p)) for p in sorted(attained)
                                 if len(attained[p]) >= 2))


@dataclass(frozen=True)
class Distance:
    """ISO 9283 distance accuracy ``ad`` and repeatability ``rd`` (7.3) between poses ``a`` and ``b`` over ``n``
    cycles: ``commanded`` D_c and ``mean`` D̄ (m); ``ad_std``, ``rd_std`` their standard uncertainties (m)."""

    a: int
    b: int
    n: int
    commanded: float
    mean: float
    ad: float
    ad_std: float
    rd: float
    rd_std: float

    def as_dict(self) -> dict[str, object]:
        return {"poses": f"P{self.a}-P{self.b}", "n": self.n, "commanded": self.commanded, "mean": self.mean,
                "ad": self.ad, "ad_std": self.ad_std, "rd": self.rd, "rd_std": self.rd_std}


def distance_result(a: int, b: int, commanded_a: Array, commanded_b: Array, attained_a: Array, attained_b: Array
                    ) -> Distance:
    """AD and RD from the positions of poses ``a`` and ``b`` attained in the same cycles (n, 3) each, n >= 2,
    row j of both from cycle j. Uncertainties: S_D / sqrt(n) for AD, RD / sqrt(2 (n - 1)) for RD (Gaussian)."""
    xa, xb = np.atleast_2d(np.asarray(attained_a, dtype=float)), np.atleast_2d(np.asarray(attained_b, dtype=float))
    n = len(xa)
    if n < 2 or xb.shape != xa.shape:
        raise ValueError(f"P{a}-P{b}: distance accuracy needs both poses in the same 2 or more cycles")
    d_c = float(np.linalg.norm(np.asarray(commanded_a, dtype=float) - np.asarray(commanded_b, dtype=float)))
    d = np.linalg.norm(xa - xb, axis=1)
    s_d = float(np.std(d, ddof=1))
    return Distance(a, b, n, d_c, float(d.mean()), float(d.mean()) - d_c, float(s_d / np.sqrt(n)), 3 * s_d,
                    float(3 * s_d / np.sqrt(2 * (n - 1))))


@dataclass(frozen=True)
class Drift:
    """Drift of pose ``pose``'s characteristics over a run (7.6): AP and RP of its ``first`` and ``last`` visits
    (each a :class:`PoseResult`), ``dap`` = |AP_first - AP_last| and ``drp`` = |RP_first - RP_last| (m), with
    ``dap_std`` (the two APs' uncertainties combined, m)."""

    pose: int
    first: PoseResult
    last: PoseResult
    dap: float
    dap_std: float
    drp: float

    def as_dict(self) -> dict[str, object]:
        return {"pose": f"P{self.pose}", "visits_each": self.first.n, "ap_first": self.first.ap,
                "ap_last": self.last.ap, "dap": self.dap, "dap_std": self.dap_std, "rp_first": self.first.rp,
                "rp_last": self.last.rp, "drp": self.drp}


def drift(pose: int, commanded: Array, attained: Array, sigma: Array | None = None) -> Drift:
    """dAP and dRP of one pose from its ``attained`` positions (N, 3) in visit order, N >= 4: AP and RP over the
    first and the last third of the visits (at least 2 each); ``sigma`` (N,) as in :func:`pose_result`."""
    attained = np.atleast_2d(np.asarray(attained, dtype=float))
    n = len(attained)
    if n < 4:
        raise ValueError(f"pose P{pose}: drift needs at least 4 visits, got {n}")
    k = max(2, n // 3)
    sig = None if sigma is None or not len(sigma) else np.asarray(sigma, dtype=float)
    first = pose_result(pose, commanded, attained[:k], None if sig is None else sig[:k])
    last = pose_result(pose, commanded, attained[-k:], None if sig is None else sig[-k:])
    return Drift(pose, first, last, abs(first.ap - last.ap), float(np.hypot(first.ap_std, last.ap_std)),
                 abs(first.rp - last.rp))


def multi_directional(barycentres: Array) -> float:
    """vAP (7.2): the largest distance between the barycentres (k, 3), k >= 2, of one pose reached from k
    approach directions, m."""
    b = np.atleast_2d(np.asarray(barycentres, dtype=float))
    if len(b) < 2:
        raise ValueError("vAP needs the barycentres of at least 2 approach directions")
    return float(np.max(np.linalg.norm(b[:, None, :] - b[None, :, :], axis=2)))


@dataclass(frozen=True)
class Directions:
    """vAP of pose ``pose`` (7.2): the barycentres (k, 3) of its visits from k approach directions, ``n`` visits
    each at least, and ``vap`` the largest distance between two of them (m)."""

    pose: int
    n: int
    barycentres: Array
    vap: float

    def as_dict(self) -> dict[str, object]:
        return {"pose": f"P{self.pose}", "visits_each": self.n, "barycentres": self.barycentres.tolist(),
                "vap": self.vap}


def directions_result(pose: int, attained: list[Array]) -> Directions:
    """vAP of one pose from its attained positions per approach direction (each (N_h, 3), N_h >= 1)."""
    sets = [np.atleast_2d(np.asarray(a, dtype=float)) for a in attained]
    bary = np.array([a.mean(axis=0) for a in sets])
    return Directions(pose, min(len(a) for a in sets), bary, multi_directional(bary))


def fitted_rotation(commanded: Array, measured: Array) -> Array:
    """The rotation R (3, 3) of the least-squares rigid fit R x + t of the points ``commanded`` (m, 3), m >= 3 not
    on a line, onto ``measured`` (m, 3), both in one frame (Kabsch: scipy's ``Rotation.align_vectors`` on the
    centred points, as ``identify check``'s registration starts)."""
    a = np.asarray(commanded, dtype=float)
    b = np.asarray(measured, dtype=float)
    rotation, _ = Rotation.align_vectors(b - b.mean(axis=0), a - a.mean(axis=0))
    return rotation.as_matrix()


def deviation_angles(commanded: Array, measured: Array) -> Array:
    """Rotations a, b, c (rad) about the frame's x, y, z axes (in that order, fixed axes) that take the orientation
    the points ``commanded`` (m, 3) stand in to the one the ``measured`` points (m, 3) stand in."""
    return Rotation.from_matrix(fitted_rotation(commanded, measured)).as_euler("xyz")


@dataclass(frozen=True)
class Orientation:
    """Orientation accuracy and repeatability of pose ``pose`` from ``n`` visits: ``ap`` (3,) = (ā, b̄, c̄), the
    mean deviation of the attained orientation from the commanded one, and ``rp`` (3,) = 3 (S_a, S_b, S_c), rad."""

    pose: int
    n: int
    ap: Array
    rp: Array

    def as_dict(self) -> dict[str, object]:
        return {"pose": f"P{self.pose}", "n": self.n, "ap_abc": self.ap.tolist(), "rp_abc": self.rp.tolist()}


def orientation_result(pose: int, angles: Array) -> Orientation:
    """ISO 9283 AP_a,b,c and RP_a,b,c of one pose from the deviations (N, 3), N >= 2, of its visits (rad; from
    :func:`deviation_angles`, so the commanded a, b, c are zero)."""
    angles = np.atleast_2d(np.asarray(angles, dtype=float))
    if len(angles) < 2:
        raise ValueError(f"pose P{pose}: orientation AP and RP need at least 2 visits, got {len(angles)}")
    return Orientation(pose, len(angles), angles.mean(axis=0), 3.0 * np.std(angles, axis=0, ddof=1))


def monte_carlo(figures: Callable[[dict[Hashable, Array]], dict[str, float]], sets: dict[Hashable, Array],
                noise: dict[Hashable, float], draws: int = MC_DRAWS, seed: int = 0,
                groups: dict[Hashable, Hashable] | None = None) -> dict[str, float]:
    """Standard uncertainty of every figure ``figures(sets)`` returns: its standard deviation over ``draws``
    synthetic repeats of the test. In a repeat every row of each set (k: (N, d), one visit's measurement) is drawn
    again from N(mean_k, C_k) (:func:`spread_covariances`: the set's sample covariance pooled with its group's and
    the measurement's stated ``noise``). A figure missing from a repeat is left out there. Seeded: the same data
    give the same answer."""
    rng = np.random.default_rng(seed)
    covs = spread_covariances(sets, noise, groups)
    shapes = {}
    for key, rows in sets.items():
        w, v = np.linalg.eigh(covs[key])
        shapes[key] = (np.atleast_2d(rows).mean(axis=0), v * np.sqrt(np.maximum(w, 0.0)), len(np.atleast_2d(rows)))
    values: dict[str, list[float]] = {}
    for _ in range(draws):
        synthetic = {k: mean + rng.standard_normal((n, len(mean))) @ scale.T for k, (mean, scale, n) in shapes.items()}
        for name, value in figures(synthetic).items():
            values.setdefault(name, []).append(value)
    return {name: float(np.std(v, ddof=1)) for name, v in values.items() if len(v) > 1}


def spread_covariances(sets: dict[Hashable, Array], noise: dict[Hashable, float],
                       groups: dict[Hashable, Hashable] | None = None) -> dict[Hashable, Array]:
    """The covariance a visit of each set (k: (N, d)) is redrawn with: its sample covariance S_k (N - 1 degrees of
    freedom) pooled with :data:`GROUP_PRIOR` visits' worth of its group's covariance (``groups``: key -> group,
    default one group per set), itself the groups' sets' sample covariances pooled with :data:`NOISE_PRIOR` visits'
    worth of the stated noise (``noise[k]``² I). A covariance estimated from a few visits is both too small and
    too anisotropic by chance, and the spread of figures such as RP grows with anisotropy: pooling the poses of a
    run (one tracker, one arm) keeps a handful of cycles honest, and with ISO's 30 each pose's own spread leads."""
    groups = groups or {k: k for k in sets}
    members = Counter(groups[k] for k in sets)
    scatter: dict[Hashable, Array] = {}
    dof: dict[Hashable, float] = {}
    own = {}
    for key, rows in sets.items():
        rows = np.atleast_2d(np.asarray(rows, dtype=float))
        n, d = rows.shape
        own[key] = (np.cov(rows.T, ddof=1).reshape(d, d) * (n - 1) if n > 1 else np.zeros((d, d)), n - 1)
        g, prior = groups[key], NOISE_PRIOR / members[groups[key]] if noise.get(key) else 0.0
        scatter[g] = scatter.get(g, 0.0) + own[key][0] + prior * noise.get(key, 0.0) ** 2 * np.eye(d)
        dof[g] = dof.get(g, 0.0) + (n - 1) + prior
    group_cov = {g: scatter[g] / max(dof[g], 1.0) for g in scatter}
    return {k: (s + GROUP_PRIOR * group_cov[groups[k]]) / (m + GROUP_PRIOR) for k, (s, m) in own.items()}
