"""Exports of an identified model: URDF, UR ROS driver calibration YAML, Robotics Toolbox snippet, JSON, CSV.

Each export must reproduce the forward model (``points_from_joints``) to floating-point
precision at random configurations, checked with the consuming tool where it installs.
"""

from __future__ import annotations

import ast
import io
import json
import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml

from config.robots import load_robot
from identify.exports.rtb import result_json, rtb_snippet, write_measurements_csv, write_result_json
from identify.exports.ur_calibration import (
    SEGMENTS,
    calibration_from_model,
    format_calibration,
    frames_from_origins,
    origins_from_model,
    read_calibration,
    write_calibration,
)
from identify.exports.urdf import matrix_from_rpy, rpy_from_matrix, urdf_from_model, write_urdf
from identify.io.csvio import read_measurements
from identify.io.result_io import result_to_dict
from identify.results.pipeline import identify
from identify.simulators.simulate import random_poses, simulate
from kinematics.dh import DHModel, frames_from_joints, points_from_joints, transform_from_dh
from kinematics.truth import random_truth

FAMILIES = ["ur5e", "scara", "iiwa7", "track_ur5e", "gantry"]
UR_MODELS = ["ur3", "ur5", "ur10", "ur3e", "ur5e", "ur10e", "ur16e", "ur20", "ur30"]
TOL = 1e-9  # m


def _truth(name: str, seed: int = 1):
    robot = load_robot(name)
    rng = np.random.default_rng(seed)
    return robot, random_truth(robot.nominal, robot.home, rng), random_poses(robot.limits, 50, rng, margin=0.0)


def _ur_truth(name: str, seed: int = 1):
    """A perturbed UR whose last link keeps a6 = alpha6 = 0, as the identification leaves it (convention)."""
    robot, model, q = _truth(name, seed)
    table = model.dh_table()
    table[-1, 2:] = robot.nominal.dh_table()[-1, 2:]
    return robot, model.with_dh_table(table), q


def _rot(axis: int, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    out = np.eye(4)
    out[i, i], out[i, j], out[j, i], out[j, j] = c, -s, s, c
    return out


# ------------------------------------------------------------------------------------------------------ URDF


@pytest.mark.parametrize("seed", range(20))
def test_rpy_round_trip_including_gimbal_lock(seed):
    rng = np.random.default_rng(seed)
    roll, yaw = rng.uniform(-math.pi, math.pi, 2)
    pitch = [math.pi / 2, -math.pi / 2, math.pi / 2 - 1e-9, rng.uniform(-1.5, 1.5)][seed % 4]
    rotation = matrix_from_rpy(roll, pitch, yaw)
    assert np.abs(matrix_from_rpy(*rpy_from_matrix(rotation)) - rotation).max() < 1e-15


@pytest.mark.parametrize("name", FAMILIES)
def test_urdf_forward_kinematics_equals_model(name):
    yourdfpy = pytest.importorskip("yourdfpy")
    robot, model, q = _truth(name)
    text = urdf_from_model(model, name, robot.limits, robot.max_speed)
    urdf = yourdfpy.URDF.load(io.StringIO(text), load_meshes=False, build_collision_scene_graph=False)
    assert urdf.actuated_joint_names == [f"joint_{i}" for i in range(1, model.n_joints + 1)]
    expected_points = points_from_joints(model, q)
    expected_frames = frames_from_joints(model, q)
    for k, qk in enumerate(q):
        urdf.update_cfg(qk)
        assert np.abs(urdf.get_transform("tp", "tracker")[:3, 3] - expected_points[k]).max() < TOL
        assert np.abs(urdf.get_transform("flange", "tracker") - expected_frames[k, -1]).max() < TOL
        assert np.abs(urdf.get_transform("base_link", "tracker") - model.base).max() < TOL


def test_urdf_joint_types_and_limits():
    robot, model, _ = _truth("track_ur5e")
    root = ET.fromstring(urdf_from_model(model, limits=robot.limits, velocities=robot.max_speed))
    joints = {j.get("name"): j for j in root.iter("joint")}
    for i, kind in enumerate(model.joint_types, start=1):
        joint = joints[f"joint_{i}"]
        assert joint.get("type") == ("revolute" if kind == "R" else "prismatic")
        limit = joint.find("limit")
        assert float(limit.get("lower")) == robot.limits[i - 1, 0]
        assert float(limit.get("upper")) == robot.limits[i - 1, 1]
        assert float(limit.get("velocity")) == robot.max_speed[i - 1]
    assert joints["tracker_to_base"].get("type") == "fixed"
    assert {link.get("name") for link in root.iter("link")} >= {"tracker", "base_link", "flange", "tp"}


def test_urdf_without_limits_and_prefix(tmp_path):
    _, model, _ = _truth("gantry")
    text = urdf_from_model(model, prefix="cell1_")
    root = ET.fromstring(text)
    types = [j.get("type") for j in root.iter("joint") if j.get("name").startswith("cell1_joint_")]
    assert types == ["prismatic", "prismatic", "prismatic", "continuous"]
    assert all(link.get("name").startswith("cell1_") for link in root.iter("link"))
    write_urdf(tmp_path / "robot.urdf", text)
    assert (tmp_path / "robot.urdf").read_text(encoding="utf-8") == text


# ------------------------------------------------------------------------------------- UR calibration YAML


def _chain(kinematics: dict, q: np.ndarray) -> np.ndarray:
    """wrist_3_link in the base frame as ur_description's xacro builds it: per joint origin xyz, rpy
    (Rz(yaw) Ry(pitch) Rx(roll)), then a rotation by q about the joint's z axis. Written out independently."""
    out = np.eye(4)
    for i, segment in enumerate(SEGMENTS):
        v = kinematics[segment]
        origin = _rot(2, v["yaw"]) @ _rot(1, v["pitch"]) @ _rot(0, v["roll"])
        origin[:3, 3] = [v["x"], v["y"], v["z"]]
        out = out @ origin @ _rot(2, q[i])
    return out


@pytest.mark.parametrize("name", UR_MODELS)
def test_ur_calibration_forward_kinematics_equals_model(name):
    _, model, q = _ur_truth(name)
    doc = calibration_from_model(model)
    relative = frames_from_joints(model, q)
    base_inv = np.linalg.inv(model.base)
    for k, qk in enumerate(q):
        assert np.abs(_chain(doc["kinematics"], qk) - base_inv @ relative[k, -1]).max() < TOL


def test_ur_calibration_nominal_gives_the_stock_numbers():
    doc = calibration_from_model(load_robot("ur5e").nominal)["kinematics"]
    assert doc["shoulder"]["z"] == pytest.approx(0.1625)
    assert doc["upper_arm"]["roll"] == pytest.approx(math.pi / 2)
    assert doc["forearm"]["x"] == pytest.approx(-0.425)
    assert (doc["wrist_1"]["x"], doc["wrist_1"]["z"]) == pytest.approx((-0.3922, 0.1333))
    assert doc["wrist_2"]["y"] == pytest.approx(-0.0997)
    assert doc["wrist_3"]["y"] == pytest.approx(0.0996)
    assert doc["hash"].startswith("calib_") and doc["hash"][6:].isdigit()


def test_ur_calibration_round_trip(tmp_path):
    _, model, q = _ur_truth("ur10e", seed=4)
    doc = calibration_from_model(model)
    path = tmp_path / "calibration.yaml"
    write_calibration(path, format_calibration(doc, "identified by dh-calib\nsecond line"))
    text = path.read_text(encoding="utf-8")
    assert text.startswith("# identified by dh-calib\n# second line\nkinematics:\n")
    loaded = yaml.safe_load(text)
    assert loaded == doc
    origins, hash_value = read_calibration(text)
    assert hash_value == doc["kinematics"]["hash"]
    assert np.abs(origins - origins_from_model(model)).max() < 1e-15
    expected = np.linalg.inv(model.base) @ frames_from_joints(model, q)[:, -1]
    assert np.abs(frames_from_origins(origins, q) - expected).max() < TOL
    assert calibration_from_model(model)["kinematics"]["hash"] == hash_value  # deterministic
    assert calibration_from_model(model, "calib_42")["kinematics"]["hash"] == "calib_42"


def test_ur_calibration_refuses_what_it_cannot_describe():
    _, model, _ = _ur_truth("ur5e")
    with pytest.raises(ValueError, match="six revolute"):
        calibration_from_model(load_robot("scara").nominal)
    bent = model.with_dh_table(np.vstack([model.dh_table()[:-1], [0.0, 0.1, 0.01, 0.0]]))
    with pytest.raises(ValueError, match="a6"):
        calibration_from_model(bent)
    with pytest.raises(ValueError, match="not a UR kinematics"):
        read_calibration("kinematics:\n  shoulder: {x: 0}\n")


# ------------------------------------------------------------------------------------ Robotics Toolbox


def _model_from_snippet(text: str) -> DHModel:
    """Rebuild the model from the snippet's literal numbers (no roboticstoolbox needed)."""
    types, table, base, tool = [], [], None, None
    for node in ast.walk(ast.parse(text)):
        if not isinstance(node, ast.Call):
            continue
        func = node.func
        name = func.id if isinstance(func, ast.Name) else func.attr if isinstance(func, ast.Attribute) else ""
        kw = {k.arg: ast.literal_eval(k.value) for k in node.keywords
              if k.arg in ("theta", "d", "a", "alpha", "offset")}
        if name == "RevoluteDH":
            types.append("R")
            table.append([kw["offset"], kw["d"], kw["a"], kw["alpha"]])
        elif name == "PrismaticDH":
            types.append("P")
            table.append([kw["theta"], kw["offset"], kw["a"], kw["alpha"]])
        elif name == "array":
            base = np.array(ast.literal_eval(node.args[0]))
        elif name == "Trans":
            tool = [ast.literal_eval(arg) for arg in node.args]
    table = np.array(table)
    return DHModel("".join(types), table[:, 0], table[:, 1], table[:, 2], table[:, 3], base, tool)


@pytest.mark.parametrize("name", FAMILIES)
def test_rtb_snippet_numbers_reproduce_model(name):
    robot, model, q = _truth(name)
    text = rtb_snippet(model, name, robot.limits)
    compile(text, "snippet.py", "exec")
    rebuilt = _model_from_snippet(text)
    assert rebuilt.joint_types == model.joint_types
    assert np.abs(points_from_joints(rebuilt, q) - points_from_joints(model, q)).max() < 1e-15


@pytest.mark.parametrize("name", FAMILIES)
def test_rtb_snippet_in_robotics_toolbox(name):
    pytest.importorskip("roboticstoolbox")
    robot, model, q = _truth(name)
    namespace: dict = {}
    exec(rtb_snippet(model, name, robot.limits), namespace)
    dh_robot = namespace["robot"]
    assert dh_robot.n == model.n_joints
    expected = points_from_joints(model, q)
    for k, qk in enumerate(q):
        assert np.abs(dh_robot.fkine(qk).t - expected[k]).max() < TOL


# --------------------------------------------------------------------------------------------- JSON, CSV


@pytest.fixture(scope="module")
def identified():
    robot = load_robot("ur5e")
    rng = np.random.default_rng(7)
    truth = random_truth(robot.nominal, robot.home, rng)
    meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=5e-5, steps=12, free_poses=6, check_poses=6)
    return meas, identify(meas, robot.nominal), robot


def test_result_json_is_strict_and_complete(identified, tmp_path):
    _, ident, robot = identified
    doc = result_to_dict(ident, robot.nominal, robot.name, source="sim")
    doc["residuals"]["per_sweep"][0]["rms"] = float("nan")  # as for a sweep without inliers
    path = tmp_path / "result.json"
    write_result_json(path, doc)
    loaded = json.loads(path.read_text(encoding="utf-8"), parse_constant=lambda c: pytest.fail(c))
    assert loaded["residuals"]["per_sweep"][0]["rms"] is None
    assert loaded["joints"] == doc["joints"] and loaded["base"] == doc["base"] and loaded["tool"] == doc["tool"]
    assert set(loaded) == set(doc)
    assert result_json(doc) == path.read_text(encoding="utf-8")


def test_measurement_csv_round_trip(identified, tmp_path):
    meas, _, _ = identified
    path = tmp_path / "meas.csv"
    write_measurements_csv(path, meas, {"robot": "ur5e"})
    content = read_measurements(path)
    assert content.metadata["robot"] == "ur5e"
    back = content.measurements
    assert back.joint_types == meas.joint_types
    np.testing.assert_array_equal(back.q, meas.q)
    np.testing.assert_array_equal(back.points, meas.points)
    np.testing.assert_array_equal(back.check, meas.check)


def test_transform_helpers_agree():
    # the UR origins are built from the same DH primitives as the model
    model = load_robot("ur5e").nominal
    origins = origins_from_model(model)
    assert np.abs(origins[0] - transform_from_dh(0.0, model.d[0], 0.0, 0.0)).max() < 1e-15


def test_exports_of_an_identified_ur(identified):
    """The identification's own output (conventional last link, parallel-axis convention) exports exactly."""
    _, ident, robot = identified
    model = ident.model
    q = random_poses(robot.limits, 50, np.random.default_rng(3), margin=0.0)
    expected = frames_from_joints(model, q)
    origins, _ = read_calibration(format_calibration(calibration_from_model(model)))
    assert np.abs(frames_from_origins(origins, q) - np.linalg.inv(model.base) @ expected[:, -1]).max() < TOL
    assert np.abs(points_from_joints(_model_from_snippet(rtb_snippet(model)), q) - expected[:, -1, :3, 3]
                  - (expected[:, -1, :3, :3] @ model.tool)).max() < TOL
    yourdfpy = pytest.importorskip("yourdfpy")
    urdf = yourdfpy.URDF.load(io.StringIO(urdf_from_model(model, limits=robot.limits)), load_meshes=False,
                              build_collision_scene_graph=False)
    tp = points_from_joints(model, q)
    for k, qk in enumerate(q):
        urdf.update_cfg(qk)
        assert np.abs(urdf.get_transform("tp", "tracker")[:3, 3] - tp[k]).max() < TOL
