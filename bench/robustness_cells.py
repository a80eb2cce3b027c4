"""Cells of :mod:`bench.robustness` that the public real-data sets (:mod:`bench.realdata`) taught us.

- :class:`GravitySag`: an elastic arm. Joints 2 and 3 give way under the gravity torque of the links beyond them
  (rad per N m), as the J2 sweep of the boby2021 set shows (a smooth error of ~1 mm at the ends of a 6-pose sweep
  that a rigid model leaves, once rejected as gross outliers).
- :func:`grid_scenario`: an arm moved on a grid of two joints (the zhang2016 set: KUKA LBR iiwa 7, A1 x A2, the
  rest of the arm rigid), cut into sweeps (one joint-2 sweep per even A1 level, one joint-1 sweep per A2 level of
  the odd A1 levels) and identified with the two-joint nominal ``bench/realdata/robots/iiwa7_a1a2.yaml``, whose
  file has no tool (the TP is ~1 m off A2).
- ``zero90`` (:data:`FANUC_SIM`): an arm the size of the boby2021 set's, 6-sample sweeps, heavy-tailed tracker
  noise, and a nominal whose joint-2 zero is 90 deg off: the fit from the nominal stalls ~100 mm off and can be
  kept over the geometric step's, as ``identify --robot`` did on the real set with such a nominal.

Tracker frame, metres, radians.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from config.robots import RobotModel
from identify.estimator.measurements import Measurements
from identify.estimator.poe import lines_from_model, points_from_lines
from identify.simulators.simulate import Scenario
from kinematics.dh import DHModel
from kinematics.joint_errors import LinkMasses, gravity_torques
from kinematics.truth import perturbed_model, random_base

Array = NDArray[np.float64]

GRID_ROBOT = str(Path(__file__).parent / "realdata" / "robots" / "iiwa7_a1a2.yaml")
FANUC_SIM = str(Path(__file__).parent / "robots" / "fanuc_large_sim.yaml")  # an arm the size of boby2021's
GRID_A1 = np.radians(np.linspace(-90, 90, 18))  # the zhang2016 grid's levels
GRID_A2 = np.radians(np.linspace(5.3, 79.4, 8))
GRID_TOOL = np.array([0.005, -0.988, 0.0003])  # m in frame 2: the links beyond A2 (0.4 + 0.4 + 0.126 m) and a tool


@dataclass(frozen=True)
class GravitySag:
    """Readings to true joint values of an arm whose joints 2 and 3 turn by ``compliance`` (rad/(N m)) times the
    gravity torque about them (``model`` with base at identity: gravity along -z of frame 0)."""

    model: DHModel
    links: LinkMasses
    compliance: float

    def true_from_reading(self, joint_types: str, readings: Array) -> Array:
        q = np.atleast_2d(np.asarray(readings, dtype=float))
        torques = gravity_torques(self.model, self.links, q)
        out = q.copy()
        out[:, 1:3] += self.compliance * torques[:, 1:3]
        return out


def gravity_sag(robot: RobotModel, truth_model: DHModel, compliance: float) -> GravitySag:
    """The sag of ``robot``'s links on the arm ``truth_model`` (its base ignored)."""
    if robot.links is None:
        raise ValueError(f"{robot.name} has no link masses: no gravity sag")
    return GravitySag(replace(truth_model, base=np.eye(4)), robot.links, compliance)


def grid_scenario(robot: RobotModel, rng: np.random.Generator, noise: float) -> Scenario:
    """The A1 x A2 grid of the zhang2016 set on a perturbed ``robot`` (two joints) at a random base, cut into
    sweeps; every fourth row of the joint-1 sweeps held out."""
    model = replace(perturbed_model(robot.nominal, rng), base=random_base(rng),
                    tool=GRID_TOOL + rng.uniform(-0.01, 0.01, 3))
    home = np.zeros(2)
    truth = lines_from_model(model, home)
    rows, sweep, joint = [], [], []
    for level, a1 in enumerate(GRID_A1):
        for a2 in GRID_A2:
            rows.append([a1, a2])
            # even A1 levels: one joint-2 sweep each; odd ones: one joint-1 sweep per A2 level
            sweep.append(level + 1 if level % 2 == 0 else 100 + int(np.argmin(np.abs(GRID_A2 - a2))))
            joint.append(2 if level % 2 == 0 else 1)
    q = np.array(rows)
    sweep_ids, joints = np.array(sweep, dtype=np.int64), np.array(joint, dtype=np.int64)
    check = np.zeros(len(q), dtype=bool)
    check[np.flatnonzero(joints == 1)[3::4]] = True
    points = points_from_lines(truth, q) + rng.normal(0.0, noise, (len(q), 3))
    meas = Measurements("RR", q, points, sweep_ids, joints, check=check, has_role=True)
    return Scenario(meas, truth, home, q, np.zeros(len(q), dtype=bool), np.zeros(0, dtype=np.int64), noise)
