"""Placing a robot file's nominal model (no tool) on measured points: the base and the tool it fits.

A robot YAML carries no tool. On an arm whose flange origin does not move (two intersecting axes, the rest of
the arm rigid: the iiwa's A1/A2 grid), a zero tool gave the base fit nothing to align and the placement
stalled ~100 mm off, so the nominal check failed a fit that was at the noise.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from config.robots import load_robot
from identify.estimator.estimate import place_nominal
from kinematics.dh import points_from_joints

ROBOT = Path(__file__).parents[2] / "bench" / "realdata" / "robots" / "iiwa7_a1a2.yaml"
NOISE = 2e-5  # m per axis


def grid() -> np.ndarray:
    """A1 x A2 readings (rad), as the zhang2016 set has them."""
    return np.radians([[a1, a2] for a1 in np.linspace(-90, 90, 18) for a2 in np.linspace(5.3, 79.4, 8)])


def test_a_nominal_without_a_tool_is_placed_to_the_noise_on_two_intersecting_axes() -> None:
    nominal = load_robot(ROBOT).nominal
    assert not np.any(nominal.tool)  # the file has no tool: the placement must find it
    rng = np.random.default_rng(7)
    base = np.eye(4)
    base[:3, :3] = Rotation.from_rotvec([0.3, -0.2, 2.5]).as_matrix()
    base[:3, 3] = [1.2, -0.4, 0.3]
    truth = replace(nominal, base=base, tool=np.array([0.005, -0.988, 0.0003]))
    q = grid()
    measured = points_from_joints(truth, q) + rng.normal(0, NOISE, (len(q), 3))
    placed, tools = place_nominal(nominal, q, measured)
    gap = points_from_joints(placed, q) - measured
    # 3D RMS of the noise is NOISE * sqrt(3); the 9 fitted numbers take a little of it
    assert np.sqrt(np.mean(np.sum(gap**2, axis=1))) < 1.2 * NOISE * np.sqrt(3)
    assert np.linalg.norm(points_from_joints(placed, np.zeros((1, 2))) - points_from_joints(truth, np.zeros((1, 2)))
                          ) < 1e-4
    assert np.allclose(tools[0], placed.tool)


def test_a_six_axis_nominal_is_placed_as_before() -> None:
    nominal = load_robot("ur5e").nominal
    rng = np.random.default_rng(8)
    base = np.eye(4)
    base[:3, :3] = Rotation.from_rotvec([0.1, 0.4, -1.0]).as_matrix()
    base[:3, 3] = [-2.0, 0.5, 0.1]
    truth = replace(nominal, base=base, tool=np.array([0.03, -0.02, 0.12]))
    q = rng.uniform(-2.5, 2.5, (40, 6))
    measured = points_from_joints(truth, q) + rng.normal(0, NOISE, (40, 3))
    placed, _ = place_nominal(nominal, q, measured)
    assert np.sqrt(np.mean(np.sum((points_from_joints(placed, q) - measured) ** 2, axis=1))) < 1.2 * NOISE * np.sqrt(3)
    assert np.allclose(placed.tool, truth.tool, atol=1e-4) and np.allclose(placed.base, base, atol=1e-4)
