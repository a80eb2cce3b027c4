"""The camera on the flange (``aruco:...&mount=flange``): its options, the simulated flange camera (rendered images,
real detection), what a session records and what identify reads from it, and the plans acquire refuses for it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from acquire.commands.cli import main as acquire_main
from drivers.camera.flange_camera import CAMERA_MOUNT
from drivers.camera.intrinsics import CameraIntrinsics, write_intrinsics
from drivers.camera.tracker import open_tracker, parse_settings
from drivers.errors import SpecError
from drivers.sim.rig import SimulatedRig
from drivers.spec import TrackerSpec
from identify.io.session_measurements import sensor_of
from identify.sensors.metadata import UNKNOWN

BOARD = "board=charuco&cols=7&rows=5&square=0.03&size=0.022"
SIM = f"aruco:sim?mount=flange&{BOARD}&distance=0.35&tilt=5&roll=3&frames=2"


def test_options_say_where_the_camera_is_and_how_the_board_was_measured() -> None:
    flange = parse_settings(TrackerSpec.parse(f"aruco:0?camera=c.yaml&mount=flange&{BOARD}&square_sigma=0.000003"))
    assert flange.mount == "flange" and flange.scale_sigma == pytest.approx(1e-4)
    assert parse_settings(TrackerSpec.parse(f"aruco:0?camera=c.yaml&{BOARD}")).mount == "cell"
    grid = parse_settings(TrackerSpec.parse("aruco:0?camera=c.yaml&board=grid&cols=2&rows=2&size=0.04&size_sigma=4e-6"))
    assert grid.scale_sigma == pytest.approx(1e-4)
    for bad, why in (("mount=wrist", "mount=wrist must be cell or flange"),
                     ("size_sigma=0.001", "size_sigma= does not measure a charuco target"),
                     ("square_sigma=x", "square_sigma=x must be a number")):
        with pytest.raises(SpecError, match=why):
            parse_settings(TrackerSpec.parse(f"aruco:0?camera=c.yaml&{BOARD}&{bad}"))


def _reading(spec: str) -> tuple[object, np.ndarray, object]:
    rig = SimulatedRig.from_spec("mock:ur5e", spec)
    camera = open_tracker(spec, rig=rig)
    camera.connect(1.0)
    try:
        reading = camera.measure(1, 10.0)[0]
        return reading, np.linalg.inv(rig.flange_pose() @ CAMERA_MOUNT), camera
    finally:
        camera.close()


def test_the_simulated_flange_camera_measures_the_fixed_board() -> None:
    reading, truth, camera = _reading(SIM)
    assert camera.identity().details["mount"] == "flange"
    assert abs(truth[2, 3] - 0.35) < 0.02  # the board faces the camera at home, 0.35 m away
    # rendered 640x480 images, real detection: the board's pose within the reading's own uncertainty
    assert np.linalg.norm(reading.position - truth[:3, 3]) < 5 * math.sqrt(3) * reading.sigma
    turn = Rotation.from_rotvec(reading.rotvec) * Rotation.from_matrix(truth[:3, :3]).inv()
    assert turn.magnitude() < 5 * math.sqrt(3) * reading.sigma_r
    assert reading.sigma < 1e-4 and reading.sigma_r < 1e-3


def test_a_misprinted_board_is_seen_nearer_by_its_print_error() -> None:
    reading, truth, _ = _reading(SIM + "&printed=1.01")
    # a board 1 % larger than declared: every length the camera measures is 1 % short (what the scale check is for)
    np.testing.assert_allclose(reading.position, truth[:3, 3] / 1.01, atol=5 * math.sqrt(3) * reading.sigma)


def test_a_session_of_the_flange_camera_reads_as_sensor_flange() -> None:
    def header(details: dict[str, str]) -> dict[str, object]:
        return {"tracker": {"details": details}}

    assert sensor_of(header({"mount": "flange", "scale_sigma": ""})) == {"sensor": "flange", "scale_sigma": UNKNOWN}
    assert sensor_of(header({"mount": "flange", "scale_sigma": "0.0001"})) == {"sensor": "flange",
                                                                              "scale_sigma": 1e-4}
    # a camera in the cell measures in units of its printed target too
    assert sensor_of(header({"mount": "cell", "scale_sigma": ""})) == {"sensor": "fixed", "scale_sigma": UNKNOWN}
    assert sensor_of({}) == {"sensor": "fixed", "scale_sigma": None}  # a laser tracker's session


def test_acquire_plans_only_stop_and_go_views_for_a_flange_camera(tmp_path, capsys: pytest.CaptureFixture[str]
                                                                   ) -> None:
    # its views keep the board in sight (tests/acquire/test_flange_acquire.py); sweeps and streams are refused, one
    # line each; a real camera's dry run shows the indicative plan from its intrinsics file (or says it is missing)
    for extra, why in ((["--mode", "continuous"], "plans stop-and-go views of its board"),
                       (["--target-accuracy", "0.1mm"], "plans stop-and-go views of its board")):
        assert acquire_main(["--robot", "mock:ur5e", "--tracker", SIM, "--dry-run", *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and why in err[0], err
    missing = f"aruco:0?camera={tmp_path / 'none.yaml'}&mount=flange&{BOARD}"
    assert acquire_main(["--robot", "mock:ur5e", "--tracker", missing, "--dry-run"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "none.yaml" in err[0], err
    write_intrinsics(tmp_path / "cam.yaml", CameraIntrinsics.from_fov(1280, 720, 60.0))
    real = f"aruco:0?camera={tmp_path / 'cam.yaml'}&mount=flange&{BOARD}"
    assert acquire_main(["--robot", "mock:ur5e", "--tracker", real, "--dry-run", "--camera-mount",
                         "0,-0.06,0.04,0,0,90"]) == 0
    out = capsys.readouterr().out
    assert "0.45 m down the line of sight at home" in out and "frames at 30 Hz" in out
    assert "the views shown are indicative" in out and "the mount given to 20 mm, 10°" in out
