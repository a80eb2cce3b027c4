"""Bundled robot models (config/robots/*.yaml) and their loader (config/robots.py)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from config.robots import ROBOTS_DIR, ConfigError, RobotModel, load_robot, robot_names
from kinematics.dh import frames_from_joints, points_from_joints

UR_NAMES = ["ur3", "ur5", "ur10", "ur3e", "ur5e", "ur10e", "ur16e", "ur20", "ur30"]
EXAMPLES = ["scara", "iiwa7", "track_ur5e", "gantry"]
VENDOR = ["fanuc_lrmate200id"]  # from a vendor data sheet, with a coupling

# Universal Robots, "DH Parameters for calculations of kinematics and dynamics": d1, a2, a3, d4, d5, d6 (m).
UR_PUBLISHED = {
    "ur3": (0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819),
    "ur5": (0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823),
    "ur10": (0.1273, -0.612, -0.5723, 0.163941, 0.1157, 0.0922),
    "ur3e": (0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921),
    "ur5e": (0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996),
    "ur10e": (0.1807, -0.6127, -0.57155, 0.17415, 0.11985, 0.11655),
    "ur16e": (0.1807, -0.4784, -0.36, 0.17415, 0.11985, 0.11655),
    "ur20": (0.2363, -0.862, -0.7287, 0.201, 0.1593, 0.1543),
    "ur30": (0.2363, -0.637, -0.5037, 0.201, 0.1593, 0.1543),
}
# Maximum joint speeds from the UR technical specifications, deg/s.
UR_SPEED_DEG = {
    "ur3e": [180, 180, 180, 360, 360, 360],
    "ur5e": [180] * 6,
    "ur10e": [120, 120, 180, 180, 180, 180],
    "ur20": [120, 120, 150, 210, 210, 210],
}


def test_bundled_names() -> None:
    assert robot_names() == sorted(UR_NAMES + EXAMPLES + VENDOR)


@pytest.mark.parametrize("name", sorted(UR_NAMES + EXAMPLES + VENDOR))
def test_every_bundled_model_loads_consistently(name: str) -> None:
    robot = load_robot(name)
    n = robot.n_joints
    assert isinstance(robot, RobotModel)
    assert robot.name == name
    assert robot.path == ROBOTS_DIR / f"{name}.yaml"
    assert robot.nominal.joint_types == robot.joint_types
    np.testing.assert_array_equal(robot.nominal.base, np.eye(4))
    np.testing.assert_array_equal(robot.nominal.tool, np.zeros(3))
    assert robot.limits.shape == (n, 2)
    for array in (robot.home, robot.max_speed, robot.default_speed, robot.default_acceleration):
        assert array.shape == (n,)
        assert not array.flags.writeable
    assert np.all(robot.limits[:, 0] < robot.home) and np.all(robot.home < robot.limits[:, 1])
    assert np.all(robot.default_speed > 0) and np.all(robot.default_speed <= 0.5 * robot.max_speed)
    assert np.all(robot.default_acceleration > 0)
    if name in EXAMPLES:
        assert "example geometry, not a vendor table" in robot.source


@pytest.mark.parametrize("name", UR_NAMES)
def test_ur_tables_match_published_values(name: str) -> None:
    robot = load_robot(name)
    d1, a2, a3, d4, d5, d6 = UR_PUBLISHED[name]
    m = robot.nominal
    assert robot.joint_types == "RRRRRR"
    assert robot.vendor == "Universal Robots"
    np.testing.assert_array_equal(m.theta, np.zeros(6))
    np.testing.assert_array_equal(m.d, [d1, 0.0, 0.0, d4, d5, d6])
    np.testing.assert_array_equal(m.a, [0.0, a2, a3, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(m.alpha, [math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0])
    np.testing.assert_array_equal(robot.limits, np.tile([-2 * math.pi, 2 * math.pi], (6, 1)))


@pytest.mark.parametrize("name", sorted(UR_SPEED_DEG))
def test_ur_max_speeds(name: str) -> None:
    np.testing.assert_allclose(load_robot(name).max_speed, np.radians(UR_SPEED_DEG[name]), rtol=1e-15)


def test_ur3_description_mentions_unlimited_last_joint() -> None:
    for name in ("ur3", "ur3e"):
        assert "unlimited rotation" in load_robot(name).description


def test_ur5e_flange_at_zero_matches_closed_form() -> None:
    # Standard DH at q = 0: x = a2 + a3, y = -(d4 + d6), z = d1 - d5 (worked through frame by frame).
    robot = load_robot("ur5e")
    p = points_from_joints(robot.nominal, np.zeros(6))[0]
    np.testing.assert_allclose(p, [-0.425 - 0.3922, -(0.1333 + 0.0996), 0.1625 - 0.0997], atol=1e-12)
    np.testing.assert_allclose(p, [-0.8172, -0.2329, 0.0628], atol=1e-12)


def test_iiwa7_stands_straight_up_at_zero() -> None:
    robot = load_robot("iiwa7")
    np.testing.assert_array_equal(robot.nominal.a, np.zeros(7))
    frames = frames_from_joints(robot.nominal, np.zeros(7))[0]
    np.testing.assert_allclose(frames[-1, :3, 3], [0.0, 0.0, 0.34 + 0.4 + 0.4 + 0.126], atol=1e-12)
    axes = frames[:-1, :3, 2]  # z_0 .. z_6: the axes of joints 1..7
    expected = [[0, 0, 1], [0, 1, 0], [0, 0, 1], [0, -1, 0], [0, 0, 1], [0, 1, 0], [0, 0, 1]]
    np.testing.assert_allclose(axes, expected, atol=1e-12)
    np.testing.assert_allclose(np.degrees(robot.limits[:, 1]), [170, 120, 170, 120, 170, 120, 175])


def test_scara_axes_parallel_and_quill_moves_down() -> None:
    robot = load_robot("scara")
    assert robot.joint_types == "RRPR"
    q = np.array([[0.3, -0.7, 0.0, 0.2], [0.3, -0.7, 0.15, 0.2]])
    frames = frames_from_joints(robot.nominal, q)
    np.testing.assert_allclose(np.abs(frames[:, :-1, 2, 2]), 1.0, atol=1e-12)  # every axis along +-z0
    p = points_from_joints(robot.nominal, q)
    np.testing.assert_allclose(p[1] - p[0], [0.0, 0.0, -0.15], atol=1e-12)
    at_zero = points_from_joints(robot.nominal, np.zeros(4))[0]
    np.testing.assert_allclose(at_zero, [0.35 + 0.3, 0.0, 0.4 - 0.05], atol=1e-12)
    np.testing.assert_array_equal(robot.limits[2], [0.0, 0.2])


def test_track_moves_along_z0_and_the_arm_stands_upright() -> None:
    robot = load_robot("track_ur5e")
    ur5e = load_robot("ur5e")
    assert robot.joint_types == "PRRRRRR"
    np.testing.assert_array_equal(robot.nominal.dh_table()[1:], ur5e.nominal.dh_table())
    q = np.array([robot.home, robot.home + np.r_[0.5, np.zeros(6)]])
    p = points_from_joints(robot.nominal, q)
    np.testing.assert_allclose(p[1] - p[0], [0.0, 0.0, 0.5], atol=1e-12)
    frame1 = frames_from_joints(robot.nominal, q)[0, 1]
    np.testing.assert_allclose(frame1[:3, 2], [1.0, 0.0, 0.0], atol=1e-12)  # UR base axis = x0 ("up")
    # The arm's pose relative to its own base is the UR5e's at the same arm joints.
    rel = np.linalg.inv(frame1) @ frames_from_joints(robot.nominal, q)[0, -1]
    np.testing.assert_allclose(rel, frames_from_joints(ur5e.nominal, robot.home[1:])[0, -1], atol=1e-12)
    np.testing.assert_array_equal(robot.limits[0], [0.0, 2.0])


def test_gantry_strokes_are_orthogonal() -> None:
    robot = load_robot("gantry")
    assert robot.joint_types == "PPPR"
    home = robot.home
    steps = [points_from_joints(robot.nominal, home + 0.1 * np.eye(4)[i])[0] for i in range(3)]
    moves = np.array(steps) - points_from_joints(robot.nominal, home)[0]
    np.testing.assert_allclose(moves @ moves.T, 0.01 * np.eye(3), atol=1e-12)
    np.testing.assert_allclose(robot.limits[:3, 1] - robot.limits[:3, 0], [1.0, 1.0, 0.5])


@pytest.mark.parametrize("name", sorted(UR_NAMES + EXAMPLES + VENDOR))
def test_home_is_regular_with_the_flange_off_the_axes(name: str) -> None:
    robot = load_robot(name)
    m = robot.nominal
    frames = frames_from_joints(m, robot.home)[0]
    p = points_from_joints(m, robot.home)[0]
    # The flange origin lies on the last axis by construction (a_n = 0); a tool offset moves it off.
    for i in range(m.n_joints - 1):
        if m.joint_types[i] == "R":
            z, o = frames[i, :3, 2], frames[i, :3, 3]
            v = p - o
            assert np.linalg.norm(v - (v @ z) * z) > 0.05, f"flange within 5 cm of axis {i + 1}"
    eps = 1e-6
    steps = points_from_joints(m, robot.home + eps * np.eye(m.n_joints))
    jac = ((steps - p) / eps).T
    assert np.linalg.matrix_rank(jac, tol=1e-3) == 3


def test_names_are_case_insensitive_and_paths_work(tmp_path: Path) -> None:
    by_name = load_robot(" UR5e ")
    assert by_name.name == "ur5e"
    by_path = load_robot(ROBOTS_DIR / "ur5e.yaml")
    by_str = load_robot(str(ROBOTS_DIR / "ur5e.yaml"))
    for robot in (by_path, by_str):
        np.testing.assert_array_equal(robot.nominal.dh_table(), by_name.nominal.dh_table())
    copy = tmp_path / "my_arm.yml"
    copy.write_text((ROBOTS_DIR / "scara.yaml").read_text())
    assert load_robot(copy).path == copy
    assert load_robot(str(copy)).joint_types == "RRPR"


def test_unknown_name_lists_known_names() -> None:
    with pytest.raises(ConfigError) as info:
        load_robot("ur99")
    message = str(info.value)
    assert "'ur99'" in message and "ur5e" in message and "track_ur5e" in message and "\n" not in message


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.yaml"
    with pytest.raises(ConfigError, match="no such file") as info:
        load_robot(path)
    assert _shown(path) in str(info.value)


def _shown(path: Path) -> str:
    """How an error message names ``path``: relative to the working directory when below it."""
    cwd = Path.cwd().resolve()
    return str(path.resolve().relative_to(cwd)) if path.resolve().is_relative_to(cwd) else str(path)


def _ur5e_data() -> dict[str, Any]:
    return yaml.safe_load((ROBOTS_DIR / "ur5e.yaml").read_text())


def _set(key: str, value: Any) -> Any:
    def change(data: dict[str, Any]) -> None:
        data[key] = value

    return change


def _set_item(key: str, index: int, value: Any) -> Any:
    def change(data: dict[str, Any]) -> None:
        data[key][index] = value

    return change


def _drop_dh_alpha(data: dict[str, Any]) -> None:
    del data["dh"][4]["alpha"]


def _drop_home(data: dict[str, Any]) -> None:
    del data["home"]


def _collision(change: Any) -> Any:
    def apply(data: dict[str, Any]) -> None:
        change(data["collision"])

    return apply


def _body(index: int, key: str, value: Any) -> Any:
    def change(block: dict[str, Any]) -> None:
        block["bodies"][index][key] = value

    return _collision(change)


BAD_CASES = [
    (_drop_home, "home", "missing key"),
    (_set("colour", "blue"), "colour", "unknown key"),
    (_set("schema", 2), "schema", "schema version <= 1"),
    (_set("schema", "1"), "schema", "integer schema version"),
    (_set("name", 5), "name", "non-empty string"),
    (_set("description", ""), "description", "non-empty string"),
    (_set("joints", "RRXRRR"), "joints", "string of R and P"),
    (_set("joints", "RRRRR"), "dh", "list of 5"),
    (_set_item("dh", 2, {"theta": 0.0, "d": 0.0, "a": "far"}), "dh[2]", "exactly the keys"),
    (_drop_dh_alpha, "dh[4]", "exactly the keys"),
    (_set_item("dh", 1, {"theta": 0.0, "d": 0.0, "a": math.nan, "alpha": 0.0}), "dh[1].a", "finite number"),
    (_set_item("dh", 1, {"theta": 0.0, "d": 0.0, "a": "0.4", "alpha": 0.0}), "dh[1].a", "finite number"),
    (_set_item("limits", 2, [1.0, -1.0]), "limits[2]", "min < max"),
    (_set_item("limits", 3, [1.0]), "limits[3]", "min < max"),
    (_set_item("limits", 0, [-1.0, math.inf]), "limits[0]", "finite numbers"),
    (_set("limits", [[-1.0, 1.0]] * 5), "limits", "list of 6"),
    (_set_item("home", 1, 7.0), "home[1]", "within limits[1]"),
    (_set_item("home", 0, True), "home[0]", "finite number"),
    (_set("home", [0.0] * 7), "home", "list of 6"),
    (_set_item("max_speed", 5, 0.0), "max_speed[5]", "> 0"),
    (_set_item("default_speed", 3, -0.1), "default_speed[3]", "> 0"),
    (_set_item("default_speed", 0, 4.0), "default_speed[0]", "<= max_speed[0]"),
    (_set("default_acceleration", 1.0), "default_acceleration", "list of 6"),
    (_set("collision", []), "collision", "a mapping with the keys source, bodies"),
    (_collision(lambda c: c.pop("source")), "collision", "a mapping with the keys source, bodies"),
    (_body(2, "frame", 7), "collision.bodies[2].frame", "a DH frame number 0..6"),
    (_body(1, "radius", 0), "collision.bodies[1].radius", "a number > 0 (m)"),
    (_body(1, "a", [0, 0]), "collision.bodies[1].a", "[x, y, z] of finite numbers"),
    (_body(3, "name", "base"), "collision.bodies[3].name", "unique among the bodies"),
    (_body(3, "name", "tool"), "collision.bodies[3].name", "not 'tool'"),
    (_collision(lambda c: c.update(ignore=[["wrist 2", "gripper"]])), "collision.ignore[0]", "two different body"),
    (_collision(lambda c: c.update(mounting={"normal": [0, 0, 0], "offset": 0.0})), "collision.mounting.normal",
     "a non-zero vector"),
]


@pytest.mark.parametrize(("change", "key", "expected"), BAD_CASES)
def test_bad_file_names_file_and_key(tmp_path: Path, change: Any, key: str, expected: str) -> None:
    data = _ur5e_data()
    change(data)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ConfigError) as info:
        load_robot(path)
    message = str(info.value)
    assert message.startswith(f"{_shown(path)}: key '{key}': expected ")
    assert expected in message
    assert "\n" not in message
    assert info.value.key == key and info.value.path == path


def test_bad_limits_message_in_full(tmp_path: Path) -> None:
    data = _ur5e_data()
    data["limits"][2] = [1.0, -1.0]
    path = tmp_path / "ur5e.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ConfigError) as info:
        load_robot(path)
    expected = f"{_shown(path)}: key 'limits[2]': expected [min, max] with min < max, got [1.0, -1.0]"
    assert str(info.value) == expected


@pytest.mark.parametrize(
    ("text", "line", "expected"),
    [
        ("schema: 1\nname: ur5e\njoints: RRRRRR: x\n", 3, "mapping values are not allowed"),
        ("schema: 1\nname: [ur5e\n", 3, "expected ',' or ']'"),
        ("schema: 1\nname: a\nvendor: b\nname: c\n", 4, "duplicate key 'name'"),
    ],
)
def test_yaml_syntax_error_gives_one_line_with_line_number(tmp_path: Path, text: str, line: int,
                                                           expected: str) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_robot(path)
    message = str(info.value)
    assert message.startswith(f"{_shown(path)}: line {line}, column ")
    assert "expected valid YAML" in message and expected in message and "\n" not in message
    assert info.value.line == line


def test_top_level_must_be_a_mapping(tmp_path: Path) -> None:
    path = tmp_path / "list.yaml"
    path.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="expected a mapping with keys schema, name") as info:
        load_robot(path)
    assert str(info.value).startswith(f"{_shown(path)}: expected")


def test_fanuc_model_matches_its_data_sheet_and_couples_j3_to_j2() -> None:
    """LR Mate 200iD data sheet: J2 330 mm up and 50 mm out, upper arm 330 mm, J3 offset 35 mm, forearm 335 mm,
    faceplate 80 mm; the controller's J3 is against the horizontal, so q3 = J2 + J3."""
    robot = load_robot("fanuc_lrmate200id")
    m = robot.nominal
    np.testing.assert_allclose([m.d[0], m.a[0], m.a[1], m.a[2], m.d[3], m.d[5]], [0.33, 0.05, 0.33, 0.035, 0.335, 0.08])
    assert robot.coupling is not None and robot.coupling.coupled_groups() == [[2, 1, 2]]
    readings = np.array([[0.1, 0.2, 0.3, 0.4, 0.5, 0.6]])
    np.testing.assert_allclose(robot.coupling.dh_from_readings(readings)[0, 2], 0.5)
    np.testing.assert_allclose(robot.coupling.readings_from_dh(robot.coupling.dh_from_readings(readings)), readings)


def test_ur_dynamics_match_the_published_masses() -> None:
    """UR 'DH Parameters for calculations of kinematics and dynamics': link masses (kg)."""
    published = {"ur3e": [1.98, 3.4445, 1.437, 0.871, 0.805, 0.261], "ur5e": [3.761, 8.058, 2.846, 1.37, 1.3, 0.365],
                 "ur10e": [7.369, 13.051, 3.989, 2.1, 1.98, 0.615]}
    for name, masses in published.items():
        links = load_robot(name).links
        assert links is not None
        np.testing.assert_array_equal(links.masses, masses)
        assert links.centres.shape == (6, 3)
