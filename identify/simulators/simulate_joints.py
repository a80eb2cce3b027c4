"""Simulated arms beyond a DH chain, for tests and benchmarks: coupled readings, joint errors (scale,
once-per-turn, compliance under gravity) and several tracked points. Pure math; seeded generators passed in.
Tracker frame, metres, radians.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from identify.estimator.measurements import Measurements
from identify.simulators.simulate import random_poses, sweep_readings
from kinematics.dh import DHModel, points_from_joints
from kinematics.joint_errors import Coupling, JointErrors, LinkMasses, gravity_torques

Array = NDArray[np.float64]


@dataclass(frozen=True)
class RealArm:
    """A simulated arm: DH ``truth`` (its ``tool`` unused when ``tools`` are given), the controller's
    ``coupling`` (None: readings are DH values), ``errors`` on the DH joint values, ``links`` (for compliance)
    and the tracked points ``tools`` (k, 3) in the last DH frame."""

    truth: DHModel
    coupling: Coupling | None = None
    errors: JointErrors | None = None
    links: LinkMasses | None = None
    tools: Array | None = None

    def true_joints(self, readings: Array) -> Array:
        """The joint values the arm really stands at (m, n) for controller ``readings`` (m, n)."""
        q = readings if self.coupling is None else self.coupling.dh_from_readings(readings)
        if self.errors is None:
            return q
        torques = None if self.links is None else gravity_torques(self.truth, self.links, q)
        return q + self.errors.corrections(q, torques)

    def points(self, readings: Array, tp_index: NDArray[np.int64] | None = None) -> Array:
        """True positions (m, 3) of the tracked points ``tp_index`` (0-based rows of ``tools``; default the
        first, or the truth's tool)."""
        q = self.true_joints(readings)
        if self.tools is None:
            return points_from_joints(self.truth, q)
        index = np.zeros(len(q), dtype=np.int64) if tp_index is None else tp_index
        out = np.empty((len(q), 3))
        for k, tool in enumerate(self.tools):
            rows = index == k
            out[rows] = points_from_joints(replace(self.truth, tool=tool), q[rows])
        return out


def measure(arm: RealArm, readings: Array, sweep: NDArray[np.int64], joint: NDArray[np.int64], noise: float,
            rng: np.random.Generator, check: NDArray[np.bool_] | None = None, visible: Array | None = None
            ) -> Measurements:
    """Measurements of every tracked point at every pose (one row each, ids 1..k), with isotropic
    ``noise`` (m per axis); ``visible`` (m, k) booleans drop the points a line of sight misses. Readings are
    written as the controller reports them, with the arm's coupling declared."""
    k = 1 if arm.tools is None else len(arm.tools)
    m = len(readings)
    shown = np.ones((m, k), dtype=bool) if visible is None else visible
    pose, tp = np.nonzero(shown)
    points = arm.points(readings[pose], tp) + rng.normal(0.0, noise, (len(pose), 3))
    check = np.zeros(m, dtype=bool) if check is None else check
    return Measurements(arm.truth.joint_types, readings[pose], points, sweep[pose], joint[pose], check=check[pose],
                        has_role=bool(np.any(check)), tp=tp + 1, coupling=arm.coupling)


def reflector_plate(rng: np.random.Generator, count: int = 3, spacing: tuple[float, float] = (0.15, 0.25)) -> Array:
    """``count`` reflector positions (count, 3) in the flange frame, 60-140 mm out along z, pairwise
    ``spacing`` metres apart (a plate across the flange)."""
    for _ in range(10_000):
        points = np.column_stack([rng.uniform(-0.15, 0.15, (count, 2)), rng.uniform(0.06, 0.14, count)])
        gaps = [np.linalg.norm(points[a] - points[b]) for a in range(count) for b in range(a + 1, count)]
        if min(gaps) >= spacing[0] and max(gaps) <= spacing[1]:
            return points
    raise RuntimeError("no reflector layout with that spacing; widen it")


def sweeps_and_poses(joint_types: str, home: Array, limits: Array, rng: np.random.Generator, steps: int, free: int,
                     check: int) -> tuple[Array, NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_]]:
    """DH joint values of a sweep of every joint (``steps`` samples), ``free`` fitted and ``check`` held-out
    random free poses: (q (m, n), sweep ids, moved joint 1-based (0 free), held-out mask)."""
    q, sweep, joint = sweep_readings(joint_types, home, limits, steps)
    extra = random_poses(limits, free + check, rng)
    q = np.vstack([q, extra])
    sweep = np.concatenate([sweep, 1000 + np.arange(free + check)])
    joint = np.concatenate([joint, np.zeros(free + check, dtype=np.int64)])
    held = np.zeros(len(q), dtype=bool)
    held[len(q) - check:] = True
    return q, sweep, joint, held
