"""Collision checks of the arm against its cell and itself (pure: numpy arrays in, distances out).

Every body is a capsule: a segment (ends ``a``, ``b``, m) and a radius (m); a sphere is a capsule whose
ends coincide. The robot's capsules are fixed in its DH frames (``frame`` 0 = the base, i = the frame
after joint i, as :func:`kinematics.dh.frames_from_joints` numbers them), the tool's in the flange
(last DH) frame. The cell is given in the robot's base frame (DH frame 0):

- the mounting surface, the plane ``normal · p = offset`` (``normal`` a unit vector pointing away from
  it); every body whose height above it can change (frame >= ``floor_from``: not on the base, nor behind
  only joints turning about the surface's normal or sliding along the surface, such as a UR's joint 1 or a
  linear track) keeps ``clearance`` (m) above it;
- axis-aligned boxes (``lo``, ``hi`` corners, m) and cylinders, a cylinder checked as the capsule that
  contains it (conservative by up to its radius beyond its end faces);
- two bodies of the arm, or a body and a box or cylinder, keep ``margin`` (m) apart. Pairs of the arm's
  own bodies on the same frame, listed as ``ignore`` by the robot model, or touching at the home pose (the
  housings of one joint, which overlap by construction) are not checked against each other.

Motion is joint-space linear interpolation (the driver's ``moveJ``), sampled so that no point of any body
travels more than ``step`` (m, default 1 cm) between samples (:func:`path_samples`). Between two samples every
point stays within ``step / 2`` of where it is at the nearer one, so no distance can be more than ``step``
below its value there: the planner asks every sample for ``guard`` = ``step`` beyond the margins, and the
margins then hold all along the motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kinematics.dh import DHModel, frames_from_joints

Array = NDArray[np.float64]

STEP = 0.01  # m: the most any point of any body travels between two checked samples of a move
_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0
_SEARCH_ITERATIONS = 32  # golden-section steps of the segment-box distance: 0.618^32 ~ 2e-7 of the length
_EPS = 1e-12


@dataclass(frozen=True)
class Bodies:
    """Capsules fixed in frames: ``names`` (K,), ``frame`` (K,) int, ends ``a``, ``b`` (K, 3) m in that frame,
    ``radius`` (K,) m."""

    names: tuple[str, ...]
    frame: NDArray[np.int64]
    a: Array
    b: Array
    radius: Array


@dataclass(frozen=True)
class Cell:
    """The arm's bodies and everything around them, in the base frame (see the module docstring).

    ``model`` gives the DH frames (its base and tool are not used); ``pairs`` (P, 2) the body pairs checked
    against each other; ``floor_from`` the first frame whose bodies are checked against the mounting surface;
    ``guard`` m asked for beyond the margins at every checked sample (the most a distance can drop between
    samples); ``reach`` (n,) m: the most any body point moves per rad (revolute) or m (prismatic)
    of each joint, for sampling moves; ``boxes_lo``, ``boxes_hi`` (B, 3); cylinders as capsules
    ``cyl_a``, ``cyl_b`` (C, 3), ``cyl_radius`` (C,); names of each for messages.
    """

    model: DHModel
    bodies: Bodies
    pairs: NDArray[np.int64]
    normal: Array
    offset: float
    clearance: float
    margin: float
    boxes_lo: Array
    boxes_hi: Array
    box_names: tuple[str, ...]
    cyl_a: Array
    cyl_b: Array
    cyl_radius: Array
    cyl_names: tuple[str, ...]
    reach: Array
    floor_from: int = 1
    guard: float = STEP


@dataclass(frozen=True)
class Approach:
    """Per configuration (m,): ``slack`` (m), the least distance minus what it must be (< 0: too close), of the
    pair ``what`` (index into ``labels``, e.g. "wrist 3 vs mounting surface") at ``distance`` (m, surface to
    surface, or to the plane); ``closest`` (m), the least distance of any pair, which is ``closest_what``."""

    slack: Array
    distance: Array
    what: NDArray[np.int64]
    labels: tuple[str, ...]
    closest: Array
    closest_what: NDArray[np.int64]

    def label(self, i: int) -> str:
        return self.labels[int(self.what[i])]


# ------------------------------------------------------------------------------------------------ geometry

def segment_distances(p0: Array, p1: Array, q0: Array, q1: Array) -> Array:
    """Least distance (m) between segments ``p0``-``p1`` and ``q0``-``q1``; arrays (..., 3) broadcast together.

    Closest points by minimising over both segment parameters in closed form, clamped to [0, 1]; a segment
    whose ends coincide is a point. Computed per coordinate (x, y, z planes), which numpy runs fastest."""
    p0, p1, q0, q1 = (np.moveaxis(v, -1, 0) for v in np.broadcast_arrays(*(np.asarray(v, dtype=float)
                                                                           for v in (p0, p1, q0, q1))))
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0

    def dot(u: Array, v: Array) -> Array:
        return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]

    a, e, b, c, f = dot(d1, d1), dot(d2, d2), dot(d1, d2), dot(d1, r), dot(d2, r)
    a, e, b, c, f = np.broadcast_arrays(a, e, b, c, f)
    point_p, point_q = a <= _EPS, e <= _EPS
    safe_a, safe_e = np.where(point_p, 1.0, a), np.where(point_q, 1.0, e)
    denom = a * e - b * b
    parallel = denom <= _EPS * np.maximum(a * e, _EPS)
    s = np.where(parallel | point_p, 0.0, np.clip((b * f - c * e) / np.where(parallel, 1.0, denom), 0.0, 1.0))
    t = np.where(point_q, 0.0, (b * s + f) / safe_e)
    s = np.where(t < 0.0, np.clip(-c / safe_a, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / safe_a, 0.0, 1.0), s))
    s = np.where(point_q, np.clip(-c / safe_a, 0.0, 1.0), s)  # a point: the closest point of the segment
    s = np.where(point_p, 0.0, s)
    t = np.clip(t, 0.0, 1.0)
    gap = r + d1 * s - d2 * t
    return np.sqrt(dot(gap, gap))


def segment_box_distances(p0: Array, p1: Array, lo: Array, hi: Array) -> Array:
    """Least distance (m) from segments ``p0``-``p1`` to axis-aligned boxes; arrays (..., 3) broadcast.

    The squared distance to a convex set along a segment is convex in the segment parameter, so a
    golden-section search finds its minimum (to ~1e-7 of the segment length); computed per coordinate."""
    p0, p1, lo, hi = (np.moveaxis(v, -1, 0) for v in np.broadcast_arrays(*(np.asarray(v, dtype=float)
                                                                           for v in (p0, p1, lo, hi))))
    d = p1 - p0

    def at(t: Array) -> Array:
        total = np.zeros_like(t)
        for k in range(3):
            x = p0[k] + d[k] * t
            gap = np.maximum(np.maximum(lo[k] - x, x - hi[k]), 0.0)
            total += gap * gap
        return total

    left, right = np.zeros(p0.shape[1:]), np.ones(p0.shape[1:])
    for _ in range(_SEARCH_ITERATIONS):
        x1, x2 = right - _GOLDEN * (right - left), left + _GOLDEN * (right - left)
        lower = at(x1) <= at(x2)
        right = np.where(lower, x2, right)
        left = np.where(lower, left, x1)
    best = np.minimum(np.minimum(at(0.5 * (left + right)), at(np.zeros_like(left))), at(np.ones_like(left)))
    return np.sqrt(best)


# ------------------------------------------------------------------------------------------------- checks

def body_segments(cell: Cell, q: Array) -> tuple[Array, Array]:
    """Ends of every body in the base frame at joint values ``q`` (m, n): two arrays (m, K, 3), m."""
    frames = frames_from_joints(cell.model, np.atleast_2d(np.asarray(q, dtype=float)))
    f = frames[:, cell.bodies.frame]  # (m, K, 4, 4)
    rot, pos = f[..., :3, :3], f[..., :3, 3]
    a = (rot @ cell.bodies.a[:, :, None])[..., 0] + pos
    b = (rot @ cell.bodies.b[:, :, None])[..., 0] + pos
    return a, b


def approach(cell: Cell, q: Array) -> Approach:
    """Closest approach of each configuration in ``q`` (m, n) to violating the cell (:class:`Approach`)."""
    a, b = body_segments(cell, q)
    names, r = cell.bodies.names, cell.bodies.radius
    slacks, dists, labels = [], [], []

    moving = np.flatnonzero(cell.bodies.frame >= cell.floor_from)
    if len(moving):
        height = np.minimum(a[:, moving] @ cell.normal, b[:, moving] @ cell.normal) - cell.offset - r[moving]
        dists.append(height)
        slacks.append(height - cell.clearance)
        labels += [f"{names[k]} vs mounting surface" for k in moving]
    if len(cell.pairs):
        i, j = cell.pairs[:, 0], cell.pairs[:, 1]
        dist = segment_distances(a[:, i], b[:, i], a[:, j], b[:, j]) - r[i] - r[j]
        dists.append(dist)
        slacks.append(dist - cell.margin)
        labels += [f"{names[x]} vs {names[y]}" for x, y in cell.pairs]
    if len(cell.box_names):
        dist = segment_box_distances(a[:, :, None], b[:, :, None], cell.boxes_lo, cell.boxes_hi) - r[:, None]
        dists.append(dist.reshape(len(a), -1))
        slacks.append(dists[-1] - cell.margin)
        labels += [f"{names[k]} vs {box}" for k in range(len(names)) for box in cell.box_names]
    if len(cell.cyl_names):
        dist = segment_distances(a[:, :, None], b[:, :, None], cell.cyl_a, cell.cyl_b) - r[:, None] - cell.cyl_radius
        dists.append(dist.reshape(len(a), -1))
        slacks.append(dists[-1] - cell.margin)
        labels += [f"{names[k]} vs {cyl}" for k in range(len(names)) for cyl in cell.cyl_names]
    if not slacks:
        inf, zero = np.full(len(a), np.inf), np.zeros(len(a), dtype=np.int64)
        return Approach(inf, inf, zero, ("nothing",), inf, zero)
    slack, dist = np.hstack(slacks), np.hstack(dists)
    what, near = np.argmin(slack, axis=1), np.argmin(dist, axis=1)
    rows = np.arange(len(a))
    return Approach(slack[rows, what], dist[rows, what], what, tuple(labels), dist[rows, near], near)


def path_samples(cell: Cell, q_from: Array, q_to: Array, step: float = STEP) -> Array:
    """Configurations (k, n) along the joint-space line ``q_from`` → ``q_to``, both ends included, spaced so
    that no body point travels more than ``step`` (m) between neighbours (bounded by ``cell.reach``)."""
    q_from, q_to = np.asarray(q_from, dtype=float), np.asarray(q_to, dtype=float)
    travel = float(np.abs(q_to - q_from) @ cell.reach)
    count = max(int(np.ceil(travel / step)), 1)
    t = np.linspace(0.0, 1.0, count + 1)[:, None]
    return q_from + t * (q_to - q_from)


def moves_samples(cell: Cell, poses: Array, step: float = STEP) -> tuple[Array, NDArray[np.int64]]:
    """Samples of every move between consecutive rows of ``poses`` (p, n): configurations (k, n) and the
    index (k,) of the move (0 = ``poses[0]`` → ``poses[1]``) each belongs to."""
    chunks, owner = [], []
    for i in range(len(poses) - 1):
        s = path_samples(cell, poses[i], poses[i + 1], step)
        chunks.append(s)
        owner.append(np.full(len(s), i))
    if not chunks:
        return np.asarray(poses, dtype=float).reshape(-1, cell.model.n_joints), np.zeros(len(poses), dtype=np.int64)
    return np.vstack(chunks), np.concatenate(owner)


def reach_per_joint(model: DHModel, bodies: Bodies, limits: Array) -> Array:
    """(n,) m: a bound on how far any body point moves per unit of each joint (rad or m), at any pose.

    Revolute joint j: a body on frame f is at most the lengths of links j..f (``sqrt(a² + d²)`` each, plus
    the stroke of a prismatic one) plus the body's farthest end from its frame origin plus its radius from
    joint j's axis. Prismatic: 1 (every point beyond moves with it)."""
    length = np.hypot(model.a, model.d) + np.where(model.revolute, 0.0, np.max(np.abs(limits), axis=1))
    extent = np.maximum(np.linalg.norm(bodies.a, axis=1), np.linalg.norm(bodies.b, axis=1)) + bodies.radius
    out = np.ones(model.n_joints)
    for j in range(model.n_joints):
        if model.revolute[j]:
            beyond = bodies.frame > j  # bodies on frames j+1.. move with joint j+1 (0-based j)
            lever = [length[j:f].sum() + e for f, e in zip(bodies.frame[beyond], extent[beyond], strict=True)]
            out[j] = max(lever, default=0.0)
    return out


def checked_pairs(model: DHModel, bodies: Bodies, home: Array, ignore: set[frozenset[str]]) -> NDArray[np.int64]:
    """Body pairs (P, 2) to check against each other: on different frames, not in ``ignore`` (name pairs),
    and apart at ``home`` (bodies touching there are joined by construction)."""
    k = len(bodies.names)
    i, j = np.triu_indices(k, 1)
    keep = bodies.frame[i] != bodies.frame[j]
    keep &= np.array([frozenset((bodies.names[x], bodies.names[y])) not in ignore for x, y in zip(i, j, strict=True)],
                     dtype=bool)
    frames = frames_from_joints(model, np.asarray(home, dtype=float)[None])[0, bodies.frame]
    a = np.einsum("kij,kj->ki", frames[:, :3, :3], bodies.a) + frames[:, :3, 3]
    b = np.einsum("kij,kj->ki", frames[:, :3, :3], bodies.b) + frames[:, :3, 3]
    apart = segment_distances(a[i], b[i], a[j], b[j]) - bodies.radius[i] - bodies.radius[j] > 0.0
    keep &= apart
    return np.column_stack([i[keep], j[keep]]).astype(np.int64)


def fixed_height_frames(model: DHModel, home: Array, normal: Array, tol: float = 1e-9) -> int:
    """How many leading joints turn about axes along ``normal`` (base frame) or slide across it: the bodies
    on frames up to that number keep their height above the mounting surface at every pose."""
    frames = frames_from_joints(model, np.asarray(home, dtype=float)[None])[0]
    count = 0
    for j in range(model.n_joints):
        axis = frames[j, :3, 2]
        along = np.linalg.norm(np.cross(axis, normal)) <= tol
        across = abs(float(axis @ normal)) <= tol
        if not (along if model.revolute[j] else across):
            break
        count += 1
    return count
