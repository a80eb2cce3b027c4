"""True robots for simulation: a nominal DH model with seeded perturbations, placed at a random pose in the
tracker frame with its tracked point (TP) off every revolute axis.

Shared by the simulated rig of mock mode (drivers/sim/) and the simulated measurements of tests and benchmarks
(identify/simulators/simulate.py). Every random draw comes from the ``numpy.random.Generator`` passed in; lengths in
metres, angles in radians.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from kinematics.dh import DHModel, frames_from_joints, points_from_joints

Array = NDArray[np.float64]


def random_base(rng: np.random.Generator, distance: float = 2.0) -> Array:
    """A random tracker <- robot-base transform: any orientation, base about ``distance`` m away."""
    base = np.eye(4)
    base[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    direction = rng.normal(size=3)
    base[:3, 3] = direction / np.linalg.norm(direction, axis=-1, keepdims=True) * distance * rng.uniform(0.75, 1.25)
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
