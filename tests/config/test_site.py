"""The site file (config/site.py, config/site_example.yaml): defaults, a full file, every kind of bad value."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from config.robots import ConfigError
from config.site import FIELDS, SiteConfig, load_site, site_from_dict

EXAMPLE = Path(__file__).resolve().parents[2] / "config" / "site_example.yaml"

FULL = """\
schema: 1
robot:
  model: ur10e
  host: 10.0.0.5
  hosts: {UR5e: 192.168.1.10, ur10e: 192.168.1.11}
  speed_fraction: 0.5
  acceleration_fraction: 0.25
  speed: [0.4, 0.4, 0.4, 0.6, 0.6, 0.6]
  acceleration: [1, 1, 1, 2, 2, 2]
tracker:
  spec: "serial:/dev/ttyUSB0?baud=115200"
  noise: 1.0e-5
  settings: {averaging: 3, mode: fast, beep: false}
  measure_time: 0.2
plan:
  tp_guess: [0.1, 0, -0.05]
  samples_per_step: 10
  settle_time: 1.5
  steps_per_sweep: 24
  joints: [6, 5, 1]
  sweep_ranges: [null, [-2.5, -0.5], [0.5, 2.5], null, null, [-3.0, 3.0]]
  free_poses: 40
  check_poses: 12
  home_check_every: 0
  min_axis_distance: 0.03
timeouts: {connect: 5, move: 60, settle: 20, measure: 3.5}
retries: 0
"""


def _write(tmp_path: Path, text: str, name: str = "site.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_defaults() -> None:
    site = SiteConfig.default()
    assert site == SiteConfig()
    assert site.tp_guess == (0.05, 0.03, 0.08)
    assert site.steps_per_sweep == 36
    assert site.samples_per_step == 5
    assert site.sweep_ranges is None and site.sweep_joints is None
    assert site.free_poses == 24 and site.check_poses == 8
    assert site.home_check_every == 36
    assert site.speed_fraction == 1.0 and site.speed is None
    assert site.tracker is None and site.tracker_noise == 5e-5
    assert site.min_axis_distance == 0.02
    assert site.retries == 3
    assert site.measure_time == 0.05
    assert site.timeouts == (10.0, 120.0, 10.0, 10.0)
    assert site.host_for("ur5e") is None


def test_minimal_file_is_all_defaults(tmp_path: Path) -> None:
    site = load_site(_write(tmp_path, "schema: 1\n"))
    assert site == SiteConfig.default()
    assert site.source.endswith("site.yaml")


def test_full_file(tmp_path: Path) -> None:
    site = load_site(_write(tmp_path, FULL))
    assert site.robot_model == "ur10e"
    assert site.host_for("UR5E") == "192.168.1.10"
    assert site.host_for("ur10e") == "192.168.1.11"
    assert site.host_for("ur3") == "10.0.0.5"
    assert site.speed_fraction == 0.5 and site.acceleration_fraction == 0.25
    assert site.speed == (0.4, 0.4, 0.4, 0.6, 0.6, 0.6)
    assert site.acceleration == (1.0, 1.0, 1.0, 2.0, 2.0, 2.0)
    assert site.tracker == "serial:/dev/ttyUSB0?baud=115200"
    assert site.tracker_noise == 1e-5
    assert site.tracker_settings == {"averaging": 3, "mode": "fast", "beep": False}
    assert site.measure_time == 0.2
    assert site.tp_guess == (0.1, 0.0, -0.05)
    assert (site.samples_per_step, site.settle_time, site.steps_per_sweep) == (10, 1.5, 24)
    assert site.sweep_joints == (6, 5, 1)
    assert site.sweep_ranges == (None, (-2.5, -0.5), (0.5, 2.5), None, None, (-3.0, 3.0))
    assert (site.free_poses, site.check_poses, site.home_check_every) == (40, 12, 0)
    assert site.min_axis_distance == 0.03
    assert (site.connect_timeout, site.move_timeout, site.settle_timeout, site.measure_timeout) == (5, 60, 20, 3.5)
    assert site.retries == 0
    assert site.timeouts == (5, 60, 20, 3.5)
    assert site.timeouts.connect == 5 and site.timeouts.measure == 3.5


def test_as_dict_round_trip_through_yaml(tmp_path: Path) -> None:
    site = load_site(_write(tmp_path, FULL))
    data = site.as_dict()
    assert data["schema"] == 1 and data["plan"]["tp_guess"] == [0.1, 0.0, -0.05]
    text = yaml.safe_dump(data, sort_keys=False)
    again = load_site(_write(tmp_path, text, "again.yaml"))
    assert again == site
    assert site_from_dict(SiteConfig.default().as_dict()) == SiteConfig.default()
    assert SiteConfig.from_dict(data, "session") == site
    # every field appears once in the saved mapping
    assert sum(len(v) if isinstance(v, dict) else 1 for k, v in data.items() if k != "schema") == len(FIELDS)


def test_example_file_loads() -> None:
    site = load_site(EXAMPLE)
    assert site.robot_model == "ur5e"
    assert site.host_for("ur5e") == "192.168.1.10"
    assert site.tracker == "mock"
    defaults = SiteConfig.default()
    for name in ("tp_guess", "samples_per_step", "steps_per_sweep", "free_poses", "check_poses", "retries"):
        assert getattr(site, name) == getattr(defaults, name)


def test_overrides() -> None:
    site = SiteConfig.default()
    assert site.with_overrides(samples_per_step=None, tracker=None) is site
    changed = site.with_overrides(samples_per_step=3, tp_guess=(0.1, 0, 0), tracker="mock", free_poses=0,
                                  sweep_ranges=[None, (-1.0, 1.0)])
    assert changed.samples_per_step == 3
    assert changed.tp_guess == (0.1, 0.0, 0.0)
    assert changed.tracker == "mock"
    assert changed.free_poses == 0
    assert changed.sweep_ranges == (None, (-1.0, 1.0))
    assert changed.steps_per_sweep == site.steps_per_sweep
    assert "command line" in changed.source
    with pytest.raises(ConfigError, match=r"^command line: key 'plan.samples_per_step': expected an integer >= 1, "
                       r"got 0$"):
        site.with_overrides(samples_per_step=0)
    with pytest.raises(ConfigError, match=r"key 'sample_per_step'.*unknown setting"):
        site.with_overrides(sample_per_step=3)


BAD = [
    # (file text, key named in the message, a fragment of the expected value)
    ("robot: {}\n", "schema", "schema version"),
    ("schema: 2\n", "schema", "schema version <= 1"),
    ("schema: one\n", "schema", "integer schema version"),
    ("schema: 1\nrobots: {}\n", "robots", "only the keys"),
    ("schema: 1\nplan: {samples: 3}\n", "plan.samples", "only the keys"),
    ("schema: 1\nplan: [1, 2]\n", "plan", "a mapping"),
    ("schema: 1\nplan: {samples_per_step: 0}\n", "plan.samples_per_step", "an integer >= 1"),
    ("schema: 1\nplan: {samples_per_step: 2.5}\n", "plan.samples_per_step", "an integer >= 1"),
    ("schema: 1\nplan: {samples_per_step: true}\n", "plan.samples_per_step", "an integer >= 1"),
    ("schema: 1\nplan: {samples_per_step: null}\n", "plan.samples_per_step", "an integer >= 1"),
    ("schema: 1\nplan: {steps_per_sweep: 2}\n", "plan.steps_per_sweep", "an integer >= 3"),
    ("schema: 1\nplan: {settle_time: -1}\n", "plan.settle_time", "a number >= 0 (s)"),
    ("schema: 1\nplan: {tp_guess: [0.1, 0.2]}\n", "plan.tp_guess", "[x, y, z]"),
    ("schema: 1\nplan: {tp_guess: [0.1, 0.2, .nan]}\n", "plan.tp_guess[2]", "[x, y, z]"),
    ("schema: 1\nplan: {tp_guess: here}\n", "plan.tp_guess", "[x, y, z]"),
    ("schema: 1\nplan: {sweep_ranges: [[1.0, 0.0]]}\n", "plan.sweep_ranges[0]", "min < max"),
    ("schema: 1\nplan: {sweep_ranges: [null, [0, 1, 2]]}\n", "plan.sweep_ranges[1]", "[min, max]"),
    ("schema: 1\nplan: {sweep_ranges: wide}\n", "plan.sweep_ranges", "one [min, max]"),
    ("schema: 1\nplan: {joints: [0, 1]}\n", "plan.joints[0]", "an integer >= 1"),
    ("schema: 1\nplan: {joints: [2, 2]}\n", "plan.joints", "distinct"),
    ("schema: 1\nplan: {free_poses: -1}\n", "plan.free_poses", "an integer >= 0"),
    ("schema: 1\nplan: {min_axis_distance: -0.01}\n", "plan.min_axis_distance", "a number >= 0 (m)"),
    ("schema: 1\ntracker: {noise: 0}\n", "tracker.noise", "a number > 0 (m per axis)"),
    ("schema: 1\ntracker: {spec: ''}\n", "tracker.spec", "a non-empty string"),
    ("schema: 1\ntracker: {measure_time: -0.1}\n", "tracker.measure_time", "a number >= 0 (s per reading)"),
    ("schema: 1\ntracker: {settings: {mode: [1, 2]}}\n", "tracker.settings.mode", "a number, string or boolean"),
    ("schema: 1\nrobot: {hosts: 192.168.1.10}\n", "robot.hosts", "a mapping from robot model name to host"),
    ("schema: 1\nrobot: {speed_fraction: 0}\n", "robot.speed_fraction", "a number > 0"),
    ("schema: 1\nrobot: {speed: [0.5, -1]}\n", "robot.speed[1]", "numbers > 0"),
    ("schema: 1\nrobot: {speed: [0.5, 0.5], acceleration: [1, 1, 1]}\nplan: {sweep_ranges: [null, null, null]}\n",
     "robot.speed", "one value per joint (3"),
    ("schema: 1\ntimeouts: {move: fast}\n", "timeouts.move", "a number > 0 (s)"),
    ("schema: 1\ntimeouts: {settle: 0.1}\nplan: {settle_time: 1.0}\n", "timeouts.settle", "plan.settle_time"),
    ("schema: 1\nretries: -1\n", "retries", "an integer >= 0"),
    ("schema: 1\ncell: {margin: -0.01}\n", "cell.margin", "a number >= 0 (m)"),
    ("schema: 1\ncell: {mounting_offset: low}\n", "cell.mounting_offset", "a number (m along the surface normal)"),
    ("schema: 1\ncell: {mounting_clearance: -1}\n", "cell.mounting_clearance", "a number >= 0 (m)"),
    ("schema: 1\ncell: {tool_radius: 0}\n", "cell.tool_radius", "a number > 0 (m)"),
    ("schema: 1\ncell: {tool_b: [0, 0]}\n", "cell.tool_b", "[x, y, z] in the flange frame"),
    ("schema: 1\ncell: {boxes: [{name: a, min: [0, 0, 0]}]}\n", "cell.boxes[0]", "exactly the keys name, min, max"),
    ("schema: 1\ncell: {boxes: [{name: a, min: [0, 0, 0], max: [1, 1, 0]}]}\n", "cell.boxes[0]", "min < max"),
    ("schema: 1\ncell: {boxes: [{name: a, min: [0, 0, 0], max: [1, 1, 1]}, {name: a, min: [0, 0, 0], "
     "max: [1, 1, 1]}]}\n", "cell.boxes[1].name", "unique"),
    ("schema: 1\ncell: {cylinders: [{name: s, a: [0, 0, 0], b: [0, 0, 1], radius: -1}]}\n",
     "cell.cylinders[0].radius", "a number > 0 (m)"),
    ("schema: 1\ncell: {cable: [{frame: 6, a: [0, 0, 0], b: [0, 0, 1]}]}\n", "cell.cable[0]",
     "exactly the keys frame, a, b, radius"),
    ("schema: 1\ncell: {cable: [{frame: 6, a: [0, 0, 0], b: [0, 0], radius: 0.01}]}\n", "cell.cable[0].b",
     "[x, y, z] in that DH frame (m)"),
    ("schema: 1\ncell: {walls: []}\n", "cell.walls", "only the keys"),
    ("schema: 1\ncell: {camera_pose: nowhere.yaml}\n", "cell.camera_pose", "a 4x4 pose of the camera"),
    ("schema: 1\ncell: {camera_pose: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 2]]}\n", "cell.camera_pose",
     "last row 0, 0, 0, 1"),
    ("schema: 1\ncell: {camera_pose: [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}\n", "cell.camera_pose",
     "a rotation and a translation"),
    ("schema: 1\ncell: {camera_half_fov: 0}\n", "cell.camera_half_fov", "an angle > 0 (rad)"),
    ("- 1\n- 2\n", None, "a mapping with the keys"),
]


@pytest.mark.parametrize(("text", "key", "expected"), BAD)
def test_bad_values_name_file_key_and_expected(tmp_path: Path, text: str, key: str | None, expected: str) -> None:
    path = _write(tmp_path, text, "cell.yaml")
    with pytest.raises(ConfigError) as info:
        load_site(path)
    message = str(info.value)
    assert "\n" not in message
    assert "cell.yaml" in message
    assert expected in message
    assert "expected" in message
    if key is not None:
        assert f"key '{key}'" in message
        assert info.value.key == key


def test_yaml_syntax_error_names_the_line(tmp_path: Path) -> None:
    path = _write(tmp_path, "schema: 1\nplan: {free_poses: 3\n", "broken.yaml")
    with pytest.raises(ConfigError, match=r"broken\.yaml: line \d+.*expected valid YAML"):
        load_site(path)


def test_duplicate_key_rejected(tmp_path: Path) -> None:
    path = _write(tmp_path, "schema: 1\nretries: 1\nretries: 2\n", "dup.yaml")
    with pytest.raises(ConfigError, match="duplicate key"):
        load_site(path)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"nope\.yaml: expected an existing site YAML file"):
        load_site(tmp_path / "nope.yaml")
