"""ISO 9283-style pose accuracy (AP) and repeatability (RP) of positions (pure numpy).

The test cube (edges parallel to the robot's base axes, centre ``c``, edge ``L``) and its measuring plane: the
diagonal plane through the two cube edges parallel to the base y axis at (x-, z-) and (x+, z+). Its four
corners lie on two space diagonals of the cube; P1 is the cube's centre, P2..P5 lie on those diagonals at
10 % of the diagonal's length from the corners (ISO 9283, 6.8.3). Each cycle visits P1, P5, P4, P3, P2 in that
order (7.2.1), each approached the same way; ISO asks for 30 cycles.

For one pose commanded at ``x_c`` and attained at ``x_j`` (j = 1..N, measured):

- AP = |x̄ - x_c|, the distance of the barycentre of the attained positions from the commanded one;
- RP = l̄ + 3 S_l, with l_j = |x_j - x̄| and S_l = sqrt(Σ(l_j - l̄)² / (N - 1)).

Only positions are measured here (one tracked point), so the orientation terms of ISO 9283 are not reported.
Units: metres; frame: whatever the positions are given in (the robot's base frame in ``acquire verify``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

ISO_ORDER = (1, 5, 4, 3, 2)  # the poses of one cycle, in the order visited
CORNER_SHARE = 0.1  # P2..P5 lie this share of the diagonal's length from the corners
ISO_CYCLES = 30


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
    """AP/RP of the five poses (``poses``, P1..P5 in order) of one run (``label``, e.g. before / after)."""

    label: str
    poses: tuple[PoseResult, ...]

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
                          for p in self.poses]}


def accuracy(label: str, commanded: Array, attained: dict[int, Array], sigma: dict[int, Array] | None = None
             ) -> Accuracy:
    """AP/RP of every pose with attained positions: ``commanded`` (5, 3) P1..P5, ``attained`` pose -> (N, 3),
    ``sigma`` pose -> (N,) per-axis standard uncertainties of those positions (optional)."""
    sigma = sigma or {}
    return Accuracy(label, tuple(pose_result(p, commanded[p - 1], attained[p], sigma.get(p)) for p in sorted(attained)
                                 if len(attained[p]) >= 2))
