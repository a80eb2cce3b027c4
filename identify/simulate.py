"""Simulated measurements from the forward model alone: the basis of tests, benchmarks and mock mode.

A true robot is a nominal DH model with seeded perturbations, placed at a random pose in the tracker
frame with a TP off every axis. Sweeps move one joint at a time about a home pose; free poses move
all joints. The tracker sees the true TP plus isotropic Gaussian noise (metres) and optional gross
outliers. Every random draw comes from the ``numpy.random.Generator`` passed in.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from identify.geometry import unit
from identify.kinematics import DHModel, frames_from_joints, points_from_joints
from identify.measurements import Measurements

Array = NDArray[np.float64]


def random_base(rng: np.random.Generator, distance: float = 2.0) -> Array:
    """A random tracker <- robot-base transform: any orientation, base about ``distance`` m away."""
    base = np.eye(4)
    base[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    base[:3, 3] = unit(rng.normal(size=3)) * distance * rng.uniform(0.75, 1.25)
    return base


def perturbed_model(
    nominal: DHModel,
    rng: np.random.Generator,
    length_sigma: float = 5e-4,
    angle_sigma: float = 1e-3,
) -> DHModel:
    """``nominal`` with every DH value perturbed (metres / radians, standard deviations)."""
    n = nominal.n_joints
    return replace(
        nominal,
        theta=nominal.theta + rng.normal(0, angle_sigma, n),
        d=nominal.d + rng.normal(0, length_sigma, n),
        a=nominal.a + rng.normal(0, length_sigma, n),
        alpha=nominal.alpha + rng.normal(0, angle_sigma, n),
    )


def axis_distances(model: DHModel, q: Array) -> Array:
    """Distance (m) of the TP from each revolute joint's axis at one pose ``q`` (n,); inf for prismatic."""
    frames = frames_from_joints(model, q[None, :])[0]
    tp = points_from_joints(model, q[None, :])[0]
    out = np.full(model.n_joints, np.inf)
    for i in np.flatnonzero(model.revolute):
        rel = tp - frames[i, :3, 3]
        z = frames[i, :3, 2]
        out[i] = np.linalg.norm(rel - (rel @ z) * z)
    return out


def random_truth(
    nominal: DHModel, home: Array, rng: np.random.Generator, min_radius: float = 0.03, tool_reach: float = 0.12
) -> DHModel:
    """A perturbed ``nominal`` at a random base pose with a random TP at least ``min_radius`` m off
    every revolute axis at the ``home`` pose."""
    model = perturbed_model(nominal, rng)
    for _ in range(1000):
        tool = rng.uniform(-tool_reach, tool_reach, 3)
        candidate = replace(model, base=random_base(rng), tool=tool)
        if np.all(axis_distances(candidate, home) >= min_radius):
            return candidate
    raise RuntimeError("could not place a TP off every axis; widen tool_reach")


def sweep_readings(
    joint_types: str,
    home: Array,
    limits: Array,
    steps: int = 36,
    arc: float | None = None,
    stroke: float = 0.2,
) -> tuple[Array, NDArray[np.int64], NDArray[np.int64]]:
    """Joint readings for one sweep per joint, last joint first (as in the paper).

    Revolute joints cover a full turn about home in ``steps`` increments, or ``home ± arc`` radians;
    prismatic joints ``home ± stroke/2`` metres; both clipped to ``limits`` (n, 2).
    Returns (q (m, n), sweep ids (m,), moved joint 1-based (m,)).
    """
    n = len(joint_types)
    blocks, sweeps, joints = [], [], []
    for number, j in enumerate(reversed(range(n)), start=1):
        lo, hi = limits[j]
        if joint_types[j] == "R" and arc is None:
            values = home[j] + 2 * np.pi * (np.arange(steps) - steps // 2) / steps
            if values.min() < lo or values.max() > hi:
                values = np.linspace(max(lo, home[j] - np.pi), min(hi, home[j] + np.pi), steps)
        else:
            half = arc if joint_types[j] == "R" else stroke / 2
            values = np.linspace(max(lo, home[j] - half), min(hi, home[j] + half), steps)
        q = np.tile(home, (steps, 1))
        q[:, j] = values
        blocks.append(q)
        sweeps.append(np.full(steps, number))
        joints.append(np.full(steps, j + 1))
    return np.vstack(blocks), np.concatenate(sweeps), np.concatenate(joints)


def random_poses(limits: Array, count: int, rng: np.random.Generator, margin: float = 0.1) -> Array:
    """``count`` poses drawn uniformly inside ``limits`` (n, 2), shrunk by ``margin`` of each range."""
    lo, hi = limits[:, 0], limits[:, 1]
    span = hi - lo
    return rng.uniform(lo + margin * span, hi - margin * span, size=(count, len(lo)))


def observe(
    truth: DHModel,
    q: Array,
    rng: np.random.Generator,
    noise: float,
    outliers: int = 0,
    outlier_size: float = 5e-3,
) -> tuple[Array, NDArray[np.int64]]:
    """TP positions seen by a tracker with isotropic noise ``noise`` (m per axis) and ``outliers``
    gross errors of ``outlier_size`` m in random directions. Returns (points (m, 3), outlier rows)."""
    points = points_from_joints(truth, q) + rng.normal(0.0, noise, size=(len(q), 3))
    bad = rng.choice(len(q), size=outliers, replace=False) if outliers else np.zeros(0, dtype=np.int64)
    points[bad] += unit(rng.normal(size=(len(bad), 3))) * outlier_size
    return points, np.sort(bad)


def simulate(
    truth: DHModel,
    home: Array,
    limits: Array,
    rng: np.random.Generator,
    noise: float = 5e-5,
    steps: int = 36,
    arc: float | None = None,
    free_poses: int = 0,
    check_poses: int = 0,
    outliers: int = 0,
) -> tuple[Measurements, NDArray[np.int64]]:
    """A full data set: sweeps of every joint, ``free_poses`` fitted free poses and ``check_poses``
    held-out (role ``check``) free poses. Outliers are put among the sweep samples only.

    Returns the measurements and the row indices of the outliers.
    """
    q, sweep, joint = sweep_readings(truth.joint_types, home, limits, steps, arc)
    points, bad = observe(truth, q, rng, noise, outliers)
    extra = free_poses + check_poses
    if extra:
        q_free = random_poses(limits, extra, rng)
        p_free, _ = observe(truth, q_free, rng, noise)
        q = np.vstack([q, q_free])
        points = np.vstack([points, p_free])
        next_id = int(sweep.max()) + 1
        sweep = np.concatenate([sweep, np.arange(next_id, next_id + extra)])
        joint = np.concatenate([joint, np.zeros(extra, dtype=np.int64)])
    check = np.zeros(len(q), dtype=bool)
    if check_poses:
        check[-check_poses:] = True
    meas = Measurements(truth.joint_types, q, points, sweep, joint, check=check, has_role=check_poses > 0)
    return meas, bad
