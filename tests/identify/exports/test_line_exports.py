"""Exports of the exact axis lines (URDF, UR calibration): every joint a full frame, so the written files
reproduce ``identify.estimator.poe.points_from_lines`` to 1e-9 m at random readings, also where nearly parallel axes
would give an exact DH table metres or kilometres of ``d``; no origin is then far from the arm."""

from __future__ import annotations

import io
from dataclasses import replace

import numpy as np
import pytest
import yaml

from config.robots import load_robot
from identify.estimator.cpa import dh_from_axes
from identify.estimator.poe import points_from_lines
from identify.exports.joint_frames import joint_frames
from identify.exports.ur_calibration import (
    calibration_from_lines,
    format_calibration,
    frames_from_origins,
    read_calibration,
)
from identify.exports.urdf import urdf_from_lines
from identify.simulators.simulate import lines_from_model, random_poses, tilted_truth
from kinematics.dh import frames_from_joints
from kinematics.truth import random_base, random_truth

TOL = 1e-9  # m
FAMILIES = ["ur5e", "scara", "iiwa7", "track_ur5e", "gantry"]


def _lines(name: str, seed: int, tilt: float = 1e-3, tps: int = 1):
    """A tilted truth of robot ``name`` (axes turned by ``tilt`` rad, shifted by 0.5 mm) with ``tps`` tracked
    points, and 40 random readings within the limits."""
    robot = load_robot(name)
    rng = np.random.default_rng(seed)
    lines = tilted_truth(robot.nominal, robot.home, rng, tilt=tilt)
    if tps > 1:
        lines = replace(lines, extra_tps=lines.tp_home + rng.uniform(-0.15, 0.15, (tps - 1, 3)))
    return robot, lines, random_poses(robot.limits, 40, rng, margin=0.0)


def _near_parallel_ur3(seed: int = 3):
    """A UR3 whose parallel axes 2-4 are off by 1e-7 rad: positions-only sweeps at very low noise resolve that,
    and exact DH then puts the common normals hundreds of kilometres away (d2 = 6.8e5 m)."""
    return _lines("ur3", seed, tilt=1e-7)


def _base(lines) -> np.ndarray:
    """A robot base frame as a DH model has one: z on the first axis, origin on it (tracker <- base)."""
    z = lines.directions[0]
    x = np.cross(z, [0.3, 0.5, 0.8])
    x /= np.linalg.norm(x)
    base = np.eye(4)
    base[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    base[:3, 3] = lines.points[0] - 0.1 * z
    return base


def test_near_parallel_axes_would_give_a_huge_dh_d():
    """The case the exports must carry: exact DH of these lines has |d| beyond 10 m."""
    _, lines, _ = _near_parallel_ur3()
    model = dh_from_axes(lines.joint_types, list(lines.points), list(lines.directions), lines.home, lines.tp_home,
                         np.zeros((6, 4)), parallel_tol=1e-12)
    assert np.abs(model.d).max() > 10.0


@pytest.mark.parametrize("name", [*FAMILIES, "ur3-near-parallel"])
def test_urdf_from_lines_reproduces_the_lines(name):
    yourdfpy = pytest.importorskip("yourdfpy")
    robot, lines, q = _near_parallel_ur3() if name == "ur3-near-parallel" else _lines(name, 1, tps=3)
    base = random_base(np.random.default_rng(5))
    text = urdf_from_lines(lines, base, limits=robot.limits, velocities=robot.max_speed, tp_ids=[1, 4, 7][
        :len(lines.tps)])
    urdf = yourdfpy.URDF.load(io.StringIO(text), load_meshes=False, build_collision_scene_graph=False)
    assert urdf.actuated_joint_names == [f"joint_{i}" for i in range(1, len(robot.joint_types) + 1)]
    links = ["tp", "tp_4", "tp_7"][:len(lines.tps)]
    expected = [points_from_lines(lines, q, np.full(len(q), k)) for k in range(len(lines.tps))]
    for row, qk in enumerate(q):
        urdf.update_cfg(qk)
        for k, link in enumerate(links):
            assert np.abs(urdf.get_transform(link, "tracker")[:3, 3] - expected[k][row]).max() < TOL
        assert np.abs(urdf.get_transform("base_link", "tracker") - base).max() < TOL


@pytest.mark.parametrize("seed", [1, 2])
def test_ur_calibration_from_lines_reproduces_the_lines(seed):
    for _, lines, q in (_lines("ur10e", seed, tps=2), _near_parallel_ur3(seed)):
        base = _base(lines)
        frames = joint_frames(lines, base)
        origins, _ = read_calibration(format_calibration(calibration_from_lines(lines, base)))
        chain = base @ frames_from_origins(origins, q)
        for k in range(len(lines.tps)):
            expected = points_from_lines(lines, q, np.full(len(q), k))
            got = np.einsum("kij,j->ki", chain[:, :3, :3], frames.tps[k]) + chain[:, :3, 3]
            assert np.abs(got - expected).max() < TOL
        assert np.abs(origins[:, :3, 3]).max() < 1.5  # every origin within the arm's size (UR10e: 1.3 m reach)


def test_origins_stay_small_where_dh_would_not():
    """Whatever the tilt of the parallel axes, each origin is within the arm's size of its parent (UR3: links of
    0.24 and 0.21 m, 0.15 m offsets)."""
    for tilt in (1e-3, 1e-7, 0.0):
        _, lines, _ = _lines("ur3", 4, tilt=tilt)
        frames = joint_frames(lines, _base(lines))
        assert np.abs(frames.origins[:, :3, 3]).max() < 0.3


def test_with_the_flange_the_last_link_is_the_dh_flange():
    """Lines of an exact DH model with a6 = alpha6 = 0, given that model's flange at home: ``wrist_3_link`` is DH
    frame 6 at every reading, as the UR description expects (tool0 follows it)."""
    robot = load_robot("ur5e")
    rng = np.random.default_rng(6)
    model = random_truth(robot.nominal, robot.home, rng)
    table = model.dh_table()
    table[-1, 2:] = 0.0
    model = model.with_dh_table(table)
    lines = lines_from_model(model, robot.home)
    flange = frames_from_joints(model, robot.home[None, :])[0, -1]
    origins, _ = read_calibration(format_calibration(calibration_from_lines(lines, model.base, flange)))
    q = random_poses(robot.limits, 30, rng)
    expected = np.linalg.inv(model.base) @ frames_from_joints(model, q)[:, -1]
    assert np.abs(frames_from_origins(origins, q) - expected).max() < TOL


def test_ur_calibration_from_lines_refuses_other_arms():
    _, lines, _ = _lines("iiwa7", 1)
    with pytest.raises(ValueError, match="six revolute"):
        calibration_from_lines(lines, np.eye(4))
    assert yaml.safe_load(format_calibration(calibration_from_lines(_lines("ur5e", 1)[1], np.eye(4))))[
        "kinematics"]["hash"].startswith("calib_")


def test_full_pose_lines_export_the_target_frame_as_the_tool():
    """Lines with measured target frames (full-pose data): the URDF's tp links and the UR calibration's ``tcp`` are
    the target frames, so both files reproduce the predicted target pose (rotation and origin) at random readings
    to 1e-9; positions-only lines write no ``tcp``, as before."""
    yourdfpy = pytest.importorskip("yourdfpy")
    from scipy.spatial.transform import Rotation

    from identify.estimator.poe import target_rotations
    from identify.exports.ur_calibration import tcp_from_calibration

    robot, lines, q = _lines("ur5e", 7, tps=2)
    turns = Rotation.random(2, random_state=8).as_matrix()
    turns[1] = np.nan  # the second point's orientation not measured: its link keeps the last link's axes
    six = replace(lines, orientations=turns)
    base = _base(six)
    frames = joint_frames(six, base)
    urdf = yourdfpy.URDF.load(io.StringIO(urdf_from_lines(six, base, limits=robot.limits, tp_ids=[1, 2])),
                              load_meshes=False, build_collision_scene_graph=False)
    expected = target_rotations(six, q, np.zeros(len(q), dtype=np.int64))
    points = points_from_lines(six, q, np.zeros(len(q), dtype=np.int64))
    chain = frames.chain(six.joint_types, q)
    for row, qk in enumerate(q):
        urdf.update_cfg(qk)
        pose = urdf.get_transform("tp", "tracker")
        assert np.abs(pose[:3, :3] - expected[row]).max() < TOL and np.abs(pose[:3, 3] - points[row]).max() < TOL
        assert np.abs(urdf.get_transform("tp_2", "tracker")[:3, :3] - chain[row, :3, :3]).max() < TOL
    doc = yaml.safe_load(format_calibration(calibration_from_lines(six, base)))
    origins, _ = read_calibration(yaml.safe_dump(doc))
    tcp = base @ frames_from_origins(origins, q) @ tcp_from_calibration(doc)
    assert np.abs(tcp[:, :3, :3] - expected).max() < TOL and np.abs(tcp[:, :3, 3] - points).max() < TOL
    assert tcp_from_calibration(calibration_from_lines(lines, base)) is None
