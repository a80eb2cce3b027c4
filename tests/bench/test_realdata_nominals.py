"""The bench's nominal robot models (bench/realdata/robots/*.yaml) are exact standard-DH conversions of the modified
(Craig) DH tables their sources publish: forward kinematics of both agree at random joints to 1e-9 m.

The modified tables are typed here as the sources print them (units as printed), and their forward model is written
here from Craig's convention, T_i = Rx(alpha_{i-1}) Tx(a_{i-1}) Rz(theta_i + q_i) Tz(d_i), independent of the
product's kinematics that reads the YAML files.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from config.robots import load_robot
from kinematics.dh import points_from_joints

ROBOTS = Path("bench/realdata/robots")
PI = np.pi


def craig_points(rows: np.ndarray, q: np.ndarray, tool: np.ndarray) -> np.ndarray:
    """Points (m) of ``tool`` (m, last frame) at joints ``q`` (m x n, rad); ``rows`` are alpha_{i-1} (rad),
    a_{i-1} (m), d_i (m), theta_i (rad)."""
    out = []
    for joints in q:
        frame = np.eye(4)
        for (alpha, a, d, theta), qi in zip(rows, joints, strict=True):
            ca, sa, ct, st = np.cos(alpha), np.sin(alpha), np.cos(theta + qi), np.sin(theta + qi)
            rx_tx = np.array([[1, 0, 0, a], [0, ca, -sa, 0], [0, sa, ca, 0], [0, 0, 0, 1.0]])
            rz_tz = np.array([[ct, -st, 0, 0], [st, ct, 0, 0], [0, 0, 1, d], [0, 0, 0, 1.0]])
            frame = frame @ rx_tx @ rz_tz
        out.append(frame[:3, :3] @ tool + frame[:3, 3])
    return np.array(out)


def mm_deg(rows: list[tuple[float, float, float, float]]) -> np.ndarray:
    """alpha (deg), a (mm), d (mm), theta (deg) -> rad, m."""
    table = np.array(rows, dtype=float)
    return np.column_stack([np.radians(table[:, 0]), table[:, 1] * 1e-3, table[:, 2] * 1e-3, np.radians(table[:, 3])])


SOURCES = {
    # robotkinematicscatalogue 1.1.2, Staubli_TX2_90L.py: columns alpha [rad], a [mm], d [mm], theta [rad]
    "staubli_tx2_90l": np.array([[0, 0, 478 - 478, 0], [-PI / 2, 50, 50, -PI / 2], [0, 500, 0, -PI / 2],
                                 [-PI / 2, 0, 550, 0], [PI / 2, 0, 0, 0], [-PI / 2, 0, 100, PI]])
                       * [1, 1e-3, 1e-3, 1],
    # Franka Emika FCI documentation (as in psh117/kinematics_calibration): alpha [rad], a [m], d [m], theta
    "franka_panda": np.array([[0, 0, 0.333, 0], [-PI / 2, 0, 0, 0], [PI / 2, 0, 0.316, 0], [PI / 2, 0.0825, 0, 0],
                              [-PI / 2, -0.0825, 0.384, 0], [PI / 2, 0, 0, 0], [PI / 2, 0.088, 0.107, 0]]),
    # dongjy-s/LM_PyTorch data/dh.csv: alpha, a, d, theta (deg, mm)
    "rokae_lm_pytorch": mm_deg([(0, 0, 487, 0), (-90, 85, 0, -90), (0, 640, 0, 0), (-90, 205, 720, 0),
                                (90, 0, 0, 0), (-90, 0, 75, 180)]),
    # dongjy-s/dh_optimize RokaeRobot.modified_dh_params: [theta, d, alpha, a] (deg, mm), reordered here
    "rokae_dh_optimize": mm_deg([(alpha, a, d, theta) for theta, d, alpha, a in
                                 [(0, 380, 0, 0), (-90, 0, -90, 30), (0, 0, 0, 440), (0, 435, -90, 35),
                                  (0, 0, 90, 0), (180, 83, -90, 0)]]),
}


@pytest.mark.parametrize("name", sorted(SOURCES))
def test_the_nominal_is_the_sources_modified_table_exactly(name: str) -> None:
    robot = load_robot(ROBOTS / f"{name}.yaml")
    rng = np.random.default_rng(37)
    q = rng.uniform(-PI, PI, (50, len(robot.joint_types)))
    tool = np.array([0.03, -0.02, 0.12])
    nominal = robot.nominal
    ours = points_from_joints(type(nominal)(nominal.joint_types, nominal.theta, nominal.d, nominal.a, nominal.alpha,
                                            tool=tool), q)
    assert np.max(np.abs(ours - craig_points(SOURCES[name], q, tool))) < 1e-9


def test_the_motoman_nominal_is_the_toolbox_table_rows_s_to_t() -> None:
    """loadMotomanLeica.m rightArm rows S1..T1, columns a, d, alpha, offset (standard DH, offset = theta)."""
    toolbox = np.array([[0.150, 1.4159, -PI / 2, 0.0], [0.614, 0.0, PI, -PI / 2], [0.200, 0.0, -PI / 2, 0.0],
                        [0.0, -0.640, PI / 2, 0.0], [0.030, 0.0, PI / 2, -PI / 2], [0.0, 0.200, 0.0, 0.0]])
    n = load_robot(ROBOTS / "motoman_right_arm.yaml").nominal
    assert np.array_equal(np.column_stack([n.a, n.d, n.alpha, n.theta]), toolbox)
