"""The robot in its cell, for the planner: build the collision model and ask it questions (pure, no devices).

:func:`cell_from_config` joins a robot model's capsules (``config/robots/*.yaml``) and a site's cell
(``cell:`` in the site file) into an :class:`kinematics.collision.Cell`; :func:`free_interval` finds how far
one joint may turn from home with the others at home; :func:`first_contact` the first sample of a move
that comes too close; :func:`clearance_of` the closest approach over a whole sequence of poses and the moves
between them; :func:`envelope` the space a plan sweeps, for showing it.
Joint values in rad / m, lengths in m, all in the robot's base frame (DH frame 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from config.geometry import TOOL
from config.robots import ConfigError, RobotModel
from config.site import SiteConfig
from kinematics.collision import (
    STEP,
    Bodies,
    Cell,
    approach,
    body_segments,
    checked_pairs,
    fixed_height_frames,
    moves_samples,
    path_samples,
    reach_per_joint,
    segment_distances,
)
from kinematics.dh import DHModel, frames_from_joints

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Contact:
    """A configuration ``q`` that comes too close: the pair ``what`` at ``distance`` m where a checked sample
    needs ``required`` m (the cell's margin or clearance plus the guard for the motion between samples)."""

    q: Array
    what: str
    distance: float
    required: float


@dataclass(frozen=True)
class Clearance:
    """Over a sequence of poses and the moves between them: the closest approach ``distance`` (m, surface to
    surface, or to the mounting plane) of the pair ``what`` on move ``move`` (0 = from the first pose to the
    second) at configuration ``q``; and the least ``slack`` (m, distance beyond the cell's margin or clearance
    at a checked sample; below ``guard`` the plan may not run) of the pair ``slack_what`` on move
    ``slack_move``, ``slack_distance`` m apart."""

    distance: float
    what: str
    move: int
    q: Array
    slack: float
    slack_what: str
    slack_move: int
    slack_distance: float
    guard: float = STEP


def cell_from_config(robot: RobotModel, site: SiteConfig) -> Cell | None:
    """The collision model of ``robot`` in the cell of ``site``; None when the model has no geometry."""
    geo = robot.geometry
    if geo is None:
        return None
    n = robot.n_joints
    tool_b = site.tp_guess if site.tool_b is None else site.tool_b
    cable = site.cable
    if any(c["frame"] > n for c in cable):
        raise ConfigError(site.source, "cell.cable", f"frames 0..{n} (the base to the flange of {robot.name})",
                          [c["frame"] for c in cable])
    bodies = Bodies((*geo.names, TOOL, *(f"cable {i + 1}" for i in range(len(cable)))),
                    np.array([*geo.frame, n, *(c["frame"] for c in cable)], dtype=np.int64),
                    np.vstack([geo.a, site.tool_a, *(c["a"] for c in cable)]),
                    np.vstack([geo.b, tool_b, *(c["b"] for c in cable)]),
                    np.array([*geo.radius, site.tool_radius, *(c["radius"] for c in cable)]))
    model = robot.nominal
    boxes = site.boxes
    cylinders = site.cylinders
    pairs = checked_pairs(model, bodies, robot.home, set(geo.ignore))
    if cable:  # a cable is strapped beside the links it follows: not checked against what it lies within the margin
        pairs = _beside_dropped(model, bodies, pairs, robot.home, len(cable), site.cell_margin + STEP)  # of at home
    return Cell(
        model=model, bodies=bodies, pairs=pairs,
        normal=geo.normal, offset=geo.offset if site.mounting_offset is None else site.mounting_offset,
        clearance=site.mounting_clearance, margin=site.cell_margin,
        boxes_lo=np.array([b["min"] for b in boxes], dtype=float).reshape(-1, 3),
        boxes_hi=np.array([b["max"] for b in boxes], dtype=float).reshape(-1, 3),
        box_names=tuple(b["name"] for b in boxes),
        cyl_a=np.array([c["a"] for c in cylinders], dtype=float).reshape(-1, 3),
        cyl_b=np.array([c["b"] for c in cylinders], dtype=float).reshape(-1, 3),
        cyl_radius=np.array([c["radius"] for c in cylinders], dtype=float),
        cyl_names=tuple(c["name"] for c in cylinders),
        reach=reach_per_joint(model, bodies, robot.limits),
        floor_from=fixed_height_frames(model, robot.home, geo.normal) + 1,
    )


def _beside_dropped(model: DHModel, bodies: Bodies, pairs: NDArray[np.int64], home: Array, count: int,
                    near: float) -> NDArray[np.int64]:
    """``pairs`` without those of the last ``count`` bodies (the cable's) closer than ``near`` m at ``home``."""
    frames = frames_from_joints(model, np.asarray(home, dtype=float)[None])[0, bodies.frame]
    a = np.einsum("kij,kj->ki", frames[:, :3, :3], bodies.a) + frames[:, :3, 3]
    b = np.einsum("kij,kj->ki", frames[:, :3, :3], bodies.b) + frames[:, :3, 3]
    i, j = pairs[:, 0], pairs[:, 1]
    gap = segment_distances(a[i], b[i], a[j], b[j]) - bodies.radius[i] - bodies.radius[j]
    cable = (i >= len(bodies.names) - count) | (j >= len(bodies.names) - count)
    return pairs[~(cable & (gap < near))]


def contact_at(cell: Cell, q: Array) -> Contact | None:
    """The contact at the one configuration ``q`` (n,), None when it is clear."""
    return first_contact(cell, q, q)


def first_contact(cell: Cell, q_from: Array, q_to: Array, step: float = STEP) -> Contact | None:
    """The first sample of the move ``q_from`` → ``q_to`` (ends included) that comes too close, or None."""
    q = path_samples(cell, q_from, q_to, step)
    return _first_bad(cell, q)


def _first_bad(cell: Cell, q: Array) -> Contact | None:
    app = approach(cell, q)
    bad = np.flatnonzero(app.slack < cell.guard)
    if not len(bad):
        return None
    i = int(bad[0])
    return Contact(q[i], app.label(i), float(app.distance[i]), float(app.distance[i] - app.slack[i] + cell.guard))


def free_interval(cell: Cell, home: Array, joint: int, lo: float, hi: float,
                  step: float = STEP) -> tuple[float, float, Contact | None]:
    """How far joint ``joint`` (0-based) may move from ``home[joint]`` towards ``lo`` and ``hi`` with the other
    joints at home and every sample clear: ``(low, high, contact)``, ``contact`` the first one met (the
    nearer to home of the two directions' ends) or None when the whole [lo, hi] is clear.

    Sampled so that no body point travels more than ``step`` between samples; the returned ends are
    clear samples (home itself must be clear: check it first)."""
    h = float(home[joint])
    spacing = step / cell.reach[joint]
    found: list[Contact] = []
    ends = []
    for end in (lo, hi):
        count = max(int(np.ceil(abs(end - h) / spacing)), 1)
        values = h + (end - h) * np.arange(count + 1) / count
        q = np.tile(np.asarray(home, dtype=float), (len(values), 1))
        q[:, joint] = values
        app = approach(cell, q)
        bad = np.flatnonzero(app.slack < cell.guard)
        if len(bad):
            k = int(bad[0])
            required = float(app.distance[k] - app.slack[k] + cell.guard)
            found.append(Contact(q[k], app.label(k), float(app.distance[k]), required))
            ends.append(float(values[max(k - 1, 0)]))
        else:
            ends.append(float(end))
    nearest = min(found, key=lambda c: abs(c.q[joint] - h)) if found else None
    return ends[0], ends[1], nearest


def clearance_of(cell: Cell, poses: Array, step: float = STEP) -> Clearance:
    """Closest approach over the moves between consecutive rows of ``poses`` (p, n), every sample checked."""
    q, owner = moves_samples(cell, np.asarray(poses, dtype=float), step)
    app = approach(cell, q)
    i, k = int(np.argmin(app.closest)), int(np.argmin(app.slack))
    return Clearance(float(app.closest[i]), app.labels[int(app.closest_what[i])], int(owner[i]), q[i],
                     float(app.slack[k]), app.label(k), int(owner[k]), float(app.distance[k]), cell.guard)


def envelope(cell: Cell, poses: Array, step: float = 0.05, limit: int = 4000) -> Array:
    """Points (k, 3), base frame, m, that the arm's bodies pass through moving along ``poses`` (p, n): the ends
    and middles of every capsule axis at samples no more than ``step`` of travel apart, at most ``limit``
    of them (evenly thinned). For showing the space a plan sweeps, not for checking it."""
    q, _ = moves_samples(cell, np.asarray(poses, dtype=float), step)
    a, b = body_segments(cell, q)
    points = np.concatenate([a, b, 0.5 * (a + b)], axis=1).reshape(-1, 3)
    if len(points) > limit:
        points = points[np.linspace(0, len(points) - 1, limit).astype(int)]
    return points
