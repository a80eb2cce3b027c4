"""The flange camera's locate solve (acquire/planning/flange_locate.py) on views of known truth, its refusals, the
rough mount's option, and the camera's cable in the cell model (config/cell.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from acquire.planning.flange_locate import locate_poses, park_martin, refusal, rough_mount, solve_mount
from config.cell import cell_from_config, contact_at
from config.robots import load_robot
from config.site import SiteConfig
from kinematics.dh import frames_from_joints

ROBOT = load_robot("ur5e")
HOME = np.asarray(ROBOT.home, dtype=float)
SIGMA, SIGMA_R = 5e-5, 3e-4  # m, rad: a reading's stated uncertainties (the simulated camera's, 0.45 m away)


def _truth(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    mount = np.eye(4)
    mount[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.5, 3)).as_matrix()
    mount[:3, 3] = rng.uniform(-0.08, 0.08, 3)
    board = frames_from_joints(ROBOT.nominal, HOME[None])[0, -1] @ mount
    board[:3, 3] += board[:3, 2] * 0.45  # 0.45 m down the line of sight
    return mount, board


def _views(mount: np.ndarray, board: np.ndarray, rng: np.random.Generator, sigma: float, sigma_r: float
           ) -> tuple[np.ndarray, np.ndarray]:
    q = locate_poses(HOME, ROBOT.limits, ROBOT.joint_types)
    flanges = frames_from_joints(ROBOT.nominal, q)[:, -1]
    views = np.linalg.inv(flanges @ mount) @ board
    views[:, :3, 3] += rng.normal(0, sigma, (len(q), 3))
    turn = Rotation.from_rotvec(rng.normal(0, sigma_r, (len(q), 3))).as_matrix()
    views[:, :3, :3] = turn @ views[:, :3, :3]
    return flanges, views


def test_locate_poses_turn_only_the_wrist_within_the_limits() -> None:
    q = locate_poses(HOME, ROBOT.limits, ROBOT.joint_types)
    assert len(q) == 9 and np.array_equal(q[0], HOME)
    moved = np.abs(q - HOME) > 0
    assert not moved[:, :3].any() and moved[1:].any(axis=1).all()
    assert np.degrees(np.abs(q - HOME).max()) == pytest.approx(15.0)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_solve_finds_the_mount_and_the_board_within_what_it_states(seed: int) -> None:
    mount, board = _truth(seed)
    rng = np.random.default_rng([seed, 5])
    flanges, views = _views(mount, board, rng, SIGMA, SIGMA_R)
    found = solve_mount(flanges, views, np.full(len(views), SIGMA), np.full(len(views), SIGMA_R), len(views), (0, 0),
                        (0, 0))
    off = np.linalg.norm(found.mount[:3, 3] - mount[:3, 3])
    turn = np.linalg.norm(Rotation.from_matrix(found.mount[:3, :3] @ mount[:3, :3].T).as_rotvec())
    board_off = np.linalg.norm(found.board[:3, 3] - board[:3, 3])
    # 3-D errors against the largest axis's sigma: within 4 of them (chi with 3 degrees of freedom)
    assert off < 4 * found.mount_position and turn < 4 * found.mount_angle
    assert board_off < 4 * found.board_position
    # the sigmas follow the noise: the mount's position from 8-15° turns to a few tenths of a millimetre
    assert 1e-5 < found.mount_position < 1e-3 and found.rms_position == pytest.approx(SIGMA * math.sqrt(3), rel=0.5)
    assert found.views == 9 and found.distance == pytest.approx(0.45, abs=1e-3)
    assert refusal(found, rough_mount(",".join(f"{v:.6f}" for v in [*mount[:3, 3], *np.degrees(
        Rotation.from_matrix(mount[:3, :3]).as_rotvec())]), None)) == ""


def test_a_poor_locate_is_refused_with_its_numbers() -> None:
    mount, board = _truth(4)
    flanges, views = _views(mount, board, np.random.default_rng(9), 5e-3, 0.01)  # a board that moves
    found = solve_mount(flanges, views, np.full(len(views), SIGMA), np.full(len(views), SIGMA_R), len(views))
    why = refusal(found, rough_mount(None, None))
    assert why.startswith("the locate phase knows the camera's mount to ") and "3 sigma must be within 20 mm" in why
    assert f"{found.mount_position * 1e3:.1f} mm" in why


def test_too_few_views_or_axes_are_refused() -> None:
    mount, board = _truth(5)
    flanges, views = _views(mount, board, np.random.default_rng(1), SIGMA, SIGMA_R)
    with pytest.raises(ValueError, match="seen in 3 of 9 views"):
        solve_mount(flanges[:3], views[:3], np.full(3, SIGMA), np.full(3, SIGMA_R), 9)
    one_axis = [0, 5, 6]  # the start and the last joint's two turns: one axis only
    with pytest.raises(ValueError, match="fewer than two axes"):
        park_martin(flanges[one_axis], views[one_axis])


def test_the_rough_mount_option() -> None:
    rough = rough_mount("0.01,-0.06,0.04,0,0,90", "5,3")
    assert rough.given and rough.position == pytest.approx(0.005) and rough.angle == pytest.approx(math.radians(3))
    assert rough.mount[:3, 3].tolist() == [0.01, -0.06, 0.04]
    assert np.allclose(rough.mount[:3, :3] @ [1, 0, 0], [0, 1, 0])
    default = rough_mount(None, None)
    assert not default.given and default.position == pytest.approx(0.1) and default.angle == pytest.approx(math.pi)
    for values, tolerance, words in [("1,2,3", None, "X,Y,Z,RX,RY,RZ"), ("40,0,60,0,0,90", None, "metres expected"),
                                     (None, "5", "MM,DEG"), (None, "5,200", "0 < DEG <= 180")]:
        with pytest.raises(ValueError, match=words):
            rough_mount(values, tolerance)


def test_the_cable_is_in_the_cell_model() -> None:
    """A cable hanging 0.3 m from the camera (flange frame) into a box that the camera itself clears."""
    flange = frames_from_joints(ROBOT.nominal, HOME[None])[0, -1]
    end = flange[:3, :3] @ [0.0, -0.06, 0.34] + flange[:3, 3]  # the cable's end, 0.3 m past the camera
    box = {"name": "fixture", "min": list(end - 0.05), "max": list(end + 0.05)}
    site = SiteConfig().with_overrides(tool_a=(0.0, 0.0, 0.0), tool_b=(0.0, -0.06, 0.04), tool_radius=0.04,
                                       boxes=(box,))
    assert contact_at(cell_from_config(ROBOT, site), HOME) is None
    cable = ({"frame": 6, "a": [0.0, -0.06, 0.04], "b": [0.0, -0.06, 0.34], "radius": 0.006},)
    contact = contact_at(cell_from_config(ROBOT, site.with_overrides(cable=cable)), HOME)
    assert contact is not None and contact.what == "cable 1 vs fixture"
