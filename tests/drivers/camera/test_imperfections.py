"""A real camera's errors in the simulated one (drivers/camera/imperfections.py): each is drawn where its physics puts
the print's corners (measured by OpenCV's detection on the rendered images), a stop-and-go reading of a still arm
is immune to the timed ones, and the readings under uneven light stay within their stated accuracy. What each error
does to an identified arm is the bench's (bench/flange_camera.py --realistic, docs/benchmarks.md section 24a)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from scipy.spatial.transform import Rotation  # noqa: E402

from drivers.camera.flange_camera import CAMERA_MOUNT  # noqa: E402
from drivers.camera.imperfections import Imperfections  # noqa: E402
from drivers.camera.intrinsics import CameraIntrinsics  # noqa: E402
from drivers.camera.renderer import Optics, Renderer, SimulatedCamera  # noqa: E402
from drivers.camera.targets import Detector, charuco_board, dictionary_id  # noqa: E402
from drivers.camera.tracker import open_tracker, parse_settings  # noqa: E402
from drivers.clock import VirtualClock  # noqa: E402
from drivers.errors import SpecError  # noqa: E402
from drivers.registry import open_robot  # noqa: E402
from drivers.sim.rig import SimulatedRig  # noqa: E402
from drivers.spec import TrackerSpec  # noqa: E402

CAMERA = CameraIntrinsics.from_fov(640, 480, 60)
BOARD = charuco_board(7, 5, 0.03, 0.022, dictionary_id("4X4_50"))
CLEAN = Optics(noise=0.0, blur=0.5)
NOISE_PX = 0.05  # px: a rendered ChArUco corner's detection error without sensor noise (edges at 0.5 px blur)


def _pose(x: float = 0.0, z: float = 0.36, tilt: float = 0.0) -> np.ndarray:
    """Camera <- board: the board facing the camera ``z`` m away, ``x`` m to the side, turned ``tilt`` rad about y."""
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_rotvec([0.0, tilt, 0.0]).as_matrix() @ np.diag([1.0, -1.0, -1.0])
    pose[:3, 3] = [x, 0.0, z]
    return pose


def _project(points: np.ndarray, pose: np.ndarray, camera: CameraIntrinsics = CAMERA) -> np.ndarray:
    rvec = cv2.Rodrigues(pose[:3, :3])[0]
    return cv2.projectPoints(points, rvec, pose[:3, 3], camera.matrix, camera.distortion)[0].reshape(-1, 2)


def _corners(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    obs = Detector(BOARD, "edges", CAMERA).detect(image)
    assert len(obs.image_points) >= 20  # most of the 24 chessboard corners
    return obs.object_points, obs.image_points


def test_the_options_are_checked_in_one_line_and_only_for_the_simulated_camera() -> None:
    sim = parse_settings(TrackerSpec.parse("aruco:sim?dk1=0.001&shutter=0.03&exposure=0.01&gain=0.6&gradient=0.3"
                                           "&glare=120&bow=0.0005&dfocal=0.002&dcx=3&dcy=-2")).sim["imperfections"]
    assert sim == Imperfections(dk1=0.001, shutter=0.03, exposure=0.01, gain=0.6, gradient=0.3, glare=120.0,
                                bow=0.0005, dfocal=0.002, dcx=3.0, dcy=-2.0)
    assert parse_settings(TrackerSpec.parse("aruco:sim")).sim["imperfections"] == Imperfections()
    for bad, why in (("dk1=x", "dk1=x must be a number"), ("shutter=-0.01", "shutter=-0.01 must be >= 0"),
                     ("gain=0", "gain=0 must be > 0"), ("gradient=1", "gradient=1 must lie between -1 and 1"),
                     ("bow=0.1", "bow=0.1 must be within ±0.05 m"), ("exposure=nan", "exposure=nan must be finite"),
                     ("dfocal=-0.2", r"dfocal=-0.2 must be within ±0.1 \(relative\)"),
                     ("dcy=150", "dcy=150 must be within ±100 px"), ("focal_sigma=-1", "focal_sigma=-1 must be >= 0")):
        with pytest.raises(SpecError, match=why):
            parse_settings(TrackerSpec.parse(f"aruco:sim?{bad}"))
    with pytest.raises(SpecError, match="only for aruco:sim"):
        parse_settings(TrackerSpec.parse("aruco:0?camera=c.yaml&bow=0.0005"))
    declared = parse_settings(TrackerSpec.parse("aruco:0?camera=c.yaml&focal_sigma=0.003&centre_sigma=4"))
    assert (declared.focal_sigma, declared.centre_sigma, declared.lens_sigma) == (0.003, 4.0, 0.0)


def test_distortion_left_after_calibration_moves_the_corners_as_the_true_lens_projects_them() -> None:
    """The lens renders with k1 + dk1; the corners are where the true lens puts them (within the detection's error),
    and off the calibrated projection by the residual distortion's own amount (0.2-0.6 px near the image's edge)."""
    pose = _pose(x=0.05, z=0.3, tilt=0.3)
    wrong = Imperfections(dk1=0.004)
    points, seen = _corners(Renderer(BOARD, CAMERA, CLEAN, imperfections=wrong).render([pose]))
    true_lens = wrong.lens(CAMERA)
    assert true_lens.distortion[0] == pytest.approx(0.004) and CAMERA.distortion[0] == 0.0
    truth, calibrated = _project(points, pose, true_lens), _project(points, pose, CAMERA)
    assert np.max(np.linalg.norm(seen - truth, axis=1)) < 3 * NOISE_PX
    shift = np.linalg.norm(truth - calibrated, axis=1)
    assert shift.max() > 0.2 and np.max(np.abs(np.linalg.norm(seen - calibrated, axis=1) - shift)) < 3 * NOISE_PX


def test_a_focal_length_and_principal_point_left_off_move_the_corners_as_the_true_camera_projects_them() -> None:
    """fx, fy 0.4 % long and the principal point (3, -2) px off: the corners are where the true camera puts them
    (within the detection's error) and off the calibrated projection by over 1 px (the focal part grows with the
    distance from the image's centre)."""
    pose = _pose(x=0.05, z=0.3, tilt=0.3)
    wrong = Imperfections(dfocal=0.004, dcx=3.0, dcy=-2.0)
    points, seen = _corners(Renderer(BOARD, CAMERA, CLEAN, imperfections=wrong).render([pose]))
    true_camera = wrong.lens(CAMERA)
    assert true_camera.matrix[0, 0] == pytest.approx(1.004 * CAMERA.matrix[0, 0])
    assert true_camera.matrix[1, 2] == pytest.approx(CAMERA.matrix[1, 2] - 2.0)
    assert np.max(np.linalg.norm(seen - _project(points, pose, true_camera), axis=1)) < 3 * NOISE_PX
    assert np.min(np.linalg.norm(seen - _project(points, pose), axis=1)) > 1.0


def test_a_bowed_board_puts_its_corners_where_the_bent_print_projects() -> None:
    """bow=2 mm: a corner at x lies ``bow · (1 - (2x / width)²)`` out of the print's plane (towards the camera); seen at
    an angle that moves it in the image by up to 1-2 px, which the rendering follows within the detection's error."""
    pose, bow = _pose(z=0.3, tilt=0.5), 0.002
    points, seen = _corners(Renderer(BOARD, CAMERA, CLEAN, imperfections=Imperfections(bow=bow)).render([pose]))
    bent = points.copy()
    bent[:, 2] += bow * (1.0 - (2.0 * points[:, 0] / BOARD.extent[0]) ** 2)
    flat = _project(points, pose)
    assert np.max(np.linalg.norm(seen - _project(bent, pose), axis=1)) < 3 * NOISE_PX
    assert np.max(np.linalg.norm(_project(bent, pose) - flat, axis=1)) > 10 * NOISE_PX


class _SlidingRig:
    """Just what the simulated camera reads from a rig: a flange (here the board, camera frame) sliding sideways at
    ``speed`` m/s along the camera's x axis, on a virtual clock starting at 0."""

    tracker_connected = True

    def __init__(self, speed: float) -> None:
        self.speed, self.clock = speed, VirtualClock(0.0)

    def flange_pose(self, t: float) -> np.ndarray:
        return _pose(x=-0.03 + self.speed * t)


def _sliding_camera(speed: float, imperfections: Imperfections, latency: float = 0.0) -> SimulatedCamera:
    return SimulatedCamera(_SlidingRig(speed), BOARD, CAMERA, np.eye(4), CLEAN, latency=latency,
                           imperfections=imperfections)


def test_a_rolling_shutter_shows_each_row_at_its_own_time() -> None:
    """0.2 m/s across the image (123 px/s), 30 ms to read the rows: the bottom rows see the board ~3 px farther than
    the top ones. Every corner is where the board was when its band of rows was exposed (24 bands: ±0.08 px)."""
    shutter, speed = 0.03, 0.2
    camera = _sliding_camera(speed, Imperfections(shutter=shutter))
    points, seen = _corners(camera._image(0.0))
    rows = camera.rig.clock.now() + shutter * (np.floor(seen[:, 1] / 20.0) + 0.5) / 24.0  # each corner's band time
    at_own_time = np.array([_project(p[None], camera.rig.flange_pose(t))[0] for p, t in zip(points, rows, strict=True)])
    at_start = _project(points, camera.rig.flange_pose(0.0))
    assert np.max(np.linalg.norm(seen - at_own_time, axis=1)) < 0.08 + 3 * NOISE_PX
    lag = seen[:, 0] - at_start[:, 0]
    slope = np.polyfit(seen[:, 1], lag, 1)[0]  # px per row: the image's speed times the readout time per row
    assert slope == pytest.approx(speed / 0.36 * CAMERA.matrix[0, 0] * shutter / 480, rel=0.1)


def test_motion_blur_centres_the_corners_at_mid_exposure() -> None:
    """10 ms open while the board slides at 0.1 m/s: a 1.5 px streak, whose corners are where the board was halfway
    through the exposure (0.77 px past its start)."""
    exposure = 0.01
    camera = _sliding_camera(0.1, Imperfections(exposure=exposure))
    points, seen = _corners(camera._image(0.0))
    middle, start = _project(points, camera.rig.flange_pose(exposure / 2)), _project(points, camera.rig.flange_pose(0))
    assert np.max(np.linalg.norm(seen - middle, axis=1)) < 3 * NOISE_PX
    assert np.mean(seen[:, 0] - start[:, 0]) > 0.6


def test_latency_shows_the_arm_where_it_was_when_the_frame_was_exposed() -> None:
    """A frame grabbed at t and stamped t was exposed at t - latency: the board 0.05 s behind (3 px at 0.1 m/s)."""
    camera = _sliding_camera(0.1, Imperfections(), latency=0.05)
    image, stamp = camera.grab(1.0)
    assert stamp == camera.rig.clock.now()
    points, seen = _corners(image)
    assert np.max(np.linalg.norm(seen - _project(points, camera.rig.flange_pose(stamp - 0.05)), axis=1)) < 3 * NOISE_PX


def _settled_reading(spec: str, settle: float) -> tuple[object, np.ndarray]:
    """A stop-and-go reading of the flange camera after a move and ``settle`` s of stillness, and the true board pose
    (camera frame) at the reading."""
    rig = SimulatedRig.from_spec("mock:ur5e", spec)
    arm, camera = open_robot("mock:ur5e", rig=rig), open_tracker(spec, rig=rig)
    arm.connect(1.0)
    camera.connect(1.0)
    try:
        step = np.array([0.05, -0.03, 0.04, 0.05, -0.04, 0.06])
        arm.move_joints(np.asarray(rig.model.home) + step, [1.0] * 6, [2.0] * 6, 60.0)
        arm.wait_until_still(settle, 10.0)
        return camera.measure(1, 10.0)[0], np.linalg.inv(rig.flange_pose() @ CAMERA_MOUNT)
    finally:
        camera.close()


SIM = "aruco:sim?mount=flange&board=charuco&cols=7&rows=5&square=0.03&size=0.022&distance=0.35&tilt=5&roll=3&frames=2"


def test_a_still_arm_is_measured_alike_through_shutter_blur_and_latency() -> None:
    """The stop-and-go plan reads the arm once it has been still for the settling time (acquire: 0.5 s): a rolling
    shutter (30 ms), a 10 ms exposure and 100 ms of latency then leave the reading as the perfect camera's within the
    noise of other frames (the reading skips the 3 frames delivered within the latency of its request; the arm's
    ringing moves the board by less than STILL_PX over a frame)."""
    perfect, truth = _settled_reading(SIM, 0.5)
    timed, _ = _settled_reading(SIM + "&shutter=0.03&exposure=0.01&latency=0.1", 0.5)
    assert np.linalg.norm(timed.position - perfect.position) < 3 * math.sqrt(2) * perfect.sigma
    assert np.linalg.norm(perfect.position - truth[:3, 3]) < 5 * math.sqrt(3) * perfect.sigma
    assert perfect.status == "ok"
    assert re.fullmatch(r"ok \([23] frames exposed before the request skipped: latency 0.1 s\)", timed.status)


def test_a_latency_longer_than_the_settling_skips_the_frames_of_the_arm_still_arriving() -> None:
    """Settled for 0.2 s only (0.42 s after the move: the ringing restarts the wait), a camera with 0.6 s of latency
    delivers frames of the arm still arriving for 0.6 s after the reading is asked for: averaged in (before
    drivers/camera/latency.py) they put the reading 14 mm off with a sigma of 2 mm. The reading skips them (18 frames
    at 30 Hz) and measures the still arm: each axis within 2 sigma of the truth (measured: 1.35 sigma at most, 22.8 µm
    in 3D, sigma 12.8 µm; the perfect camera's 13.9 µm), as its sigma says. Latency 0: the reading without the option,
    bit for bit."""
    perfect, truth = _settled_reading(SIM, 0.2)
    late, _ = _settled_reading(SIM + "&latency=0.6", 0.2)
    assert np.all(np.abs(late.position - truth[:3, 3]) < 2 * late.sigma) and late.sigma < 1.5 * perfect.sigma
    assert np.linalg.norm(late.position - perfect.position) < 3 * math.sqrt(2) * perfect.sigma
    assert re.fullmatch(r"ok \(1[78] frames exposed before the request skipped: latency 0.6 s\)", late.status)
    zero, _ = _settled_reading(SIM + "&latency=0", 0.2)
    assert np.array_equal(zero.position, perfect.position) and zero.sigma == perfect.sigma and zero.status == "ok"


@pytest.mark.parametrize("light", ["gain=0.5&gradient=0.4", "glare=150"])
def test_uneven_light_leaves_the_readings_within_their_stated_accuracy(light: str) -> None:
    """A dim, uneven cell (half the light, ±40 % across the image) or a lamp's reflection saturating part of the
    print: fewer or noisier corners, and a reading within its own stated accuracy (5 sigma in 3D, as a perfect
    camera's is checked), never a confident wrong one."""
    reading, truth = _settled_reading(f"{SIM}&{light}", 0.5)
    perfect, _ = _settled_reading(SIM, 0.5)
    assert np.linalg.norm(reading.position - truth[:3, 3]) < 5 * math.sqrt(3) * reading.sigma
    turn = Rotation.from_rotvec(reading.rotvec) * Rotation.from_matrix(truth[:3, :3]).inv()
    assert turn.magnitude() < 5 * math.sqrt(3) * reading.sigma_r
    assert reading.sigma >= 0.9 * perfect.sigma  # less signal over the same sensor noise: never stated better


def test_the_flatness_model_predicts_what_a_bowed_board_does_to_the_pose() -> None:
    """A board bowed 1 mm (mode ``1/3 - x²`` at 1 mm, plus its mean height 2/3 mm along the normal), seen at 0.5 rad:
    the flat least-squares pose of its exact corners moves by the mean height along the board's normal plus the mode's
    linear response (drivers/camera/board_and_lens.py) within 2 µm and 2 % of the turn (linear at 1 mm); the mode's own
    part is over 0.1 mm and 1 mrad (3.8 mrad here)."""
    from drivers.camera.board_and_lens import pose_shifts

    pose, bow = _pose(x=0.02, z=0.3, tilt=0.5), 0.001
    points = np.array([[x, y, 0.0] for x in (-0.075, -0.045, -0.015, 0.015, 0.045, 0.075) for y in (-0.045, -0.015,
                                                                                                    0.015, 0.045)])
    bent = points.copy()
    bent[:, 2] += bow * (1.0 - (2.0 * points[:, 0] / BOARD.extent[0]) ** 2)
    rvec, tvec = cv2.Rodrigues(pose[:3, :3])[0], pose[:3, 3].reshape(3, 1)
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 100, 1e-14)
    rv, tv = cv2.solvePnPRefineLM(points, _project(bent, pose), CAMERA.matrix, CAMERA.distortion, rvec.copy(),
                                  tvec.copy(), criteria)
    shifts = pose_shifts(pose[:3, :3], pose[:3, 3], points, (BOARD.extent[0] / 2, BOARD.extent[1] / 2), CAMERA)
    moved = tv.ravel() - pose[:3, 3] - pose[:3, 2] * 2 * bow / 3
    assert np.linalg.norm(moved - bow * shifts[0, 3:]) < 2e-6 and np.linalg.norm(bow * shifts[0, 3:]) > 1e-4
    turned = Rotation.from_matrix(cv2.Rodrigues(rv)[0] @ pose[:3, :3].T).as_rotvec()  # camera frame
    assert np.linalg.norm(turned - bow * shifts[0, :3]) < 0.02 * np.linalg.norm(bow * shifts[0, :3])
    assert np.linalg.norm(bow * shifts[0, :3]) > 1e-3


@pytest.mark.parametrize("truth, priors, expected", [
    (Imperfections(bow=0.001), (0.002, 0.0), [0.001, 0.0, 0.0]),
    (Imperfections(dk1=0.01), (0.0, 0.05), [0.0, 0.0, 0.0, 0.01, 0.0]),
    (Imperfections(dfocal=0.004, dcx=3.0, dcy=-2.0), (0.0, 0.0, 0.01, 5.0), [0.0, 0.0, 0.0, 0.004, 3.0, -2.0])],
    ids=["bowed board", "lens k1 off", "focal and centre off"])
def test_the_boards_shape_or_the_lenss_error_is_estimated_from_the_views_and_the_poses_corrected(
        truth: Imperfections, priors: tuple[float, ...], expected: list[float]) -> None:
    """Six views, two frames each, of a board bowed 1 mm (its shape estimated), seen through a lens whose k1 is 0.01
    off the calibration (dk1, dk2 estimated), or whose fx, fy are 0.4 % long and principal point (3, -2) px off
    (dfocal, dcx, dcy estimated; the views tilted up to 0.6 rad tell the focal length from a distance): the estimate
    lies within 4 of its own standard deviations of the truth (the detection's errors shared by a view's frames make
    those 1.4x too small), and the corrected poses (the board's frame: its mean plane) are within 4 of the stated
    sigmas (the estimate's part and 0.03 px of corner noise) while the flat poses missed by over 3x more (1-2 mm for
    the focal length and centre); their reprojection RMS is the corner noise's, the pattern taken out (it scales
    their sigmas). (The shape and the lens's k1, k2 together are hard to tell apart on a small board near the
    image's centre: the bench's A4 board at 1280x720 tells them, docs/benchmarks.md section 24a.)"""
    from drivers.camera.board_and_lens import BoardAndLens
    from drivers.camera.pose import estimate_pose

    renderer = Renderer(BOARD, CAMERA, Optics(noise=1.0, blur=0.5), imperfections=truth)
    shape = BoardAndLens(priors[0], priors[1], BOARD.extent, *priors[2:])
    rng = np.random.default_rng(5)
    views = [_pose(x=x, z=z, tilt=t) for x, z, t in ((0.0, 0.3, 0.0), (0.07, 0.32, 0.5), (-0.07, 0.3, -0.5),
                                                      (0.04, 0.4, 0.3), (-0.08, 0.35, -0.2), (0.08, 0.28, 0.6))]

    def flat_pose(pose: np.ndarray) -> tuple[object, object]:
        obs = Detector(BOARD, "edges", CAMERA).detect(renderer.render([pose], rng))
        return estimate_pose(obs, CAMERA.matrix, CAMERA.distortion, False, pose[:3, :3]), obs

    per_view = BoardAndLens(priors[0], priors[1], BOARD.extent, *priors[2:], frames_per_view=2)
    for pose in views:
        for _ in range(2):
            frame = flat_pose(pose)
            shape.add(*frame, CAMERA)
            per_view.add(*frame, CAMERA)
    value, covariance = shape.estimate()
    # a view's two frames counted as one view: the same estimate (within a tenth of its sd: only the prior's relative
    # weight changes), twice the variance where the data, not the prior, decide
    view_value, view_covariance = per_view.estimate()
    assert np.all(np.abs(view_value - value) <= 0.1 * np.sqrt(np.diag(covariance)))
    decided = shape.used & (np.diag(covariance) < 0.01 * shape.prior**2)
    assert decided.any()
    np.testing.assert_allclose(np.diag(view_covariance)[decided] / np.diag(covariance)[decided], 2.0, rtol=0.05)
    sd, expected = np.sqrt(np.diag(covariance)), np.array(expected)
    assert len(value) == len(expected) and np.all(np.abs(value - expected) <= 4 * sd), (value, sd)
    assert np.all(sd[expected != 0] < 0.25 * np.abs(expected[expected != 0]))  # told from noise
    corrected_errors, flat_errors, stated, rms = [], [], [], []
    for pose in views:
        flat, obs = flat_pose(pose)
        residual, moves = BoardAndLens(priors[0], priors[1], BOARD.extent, *priors[2:]).add(flat, obs, CAMERA)  # alone
        corrected, correction = shape.take(flat, obs, CAMERA, np.zeros(3))
        shared = correction.bias
        rms.append([flat.rms, corrected.rms, math.sqrt(np.mean((residual - moves @ expected) ** 2))])
        mean_plane = pose[:3, 3] + pose[:3, 2] * 2 * truth.bow / 3
        corrected_errors.append(np.linalg.norm(corrected.translation - mean_plane))
        flat_errors.append(np.linalg.norm(flat.translation - mean_plane))
        noise = math.sqrt(np.trace(flat.point_covariance(np.zeros(3), 0.03)) / 3)
        stated.append(math.sqrt(3) * math.hypot(shared, noise))
    assert np.all(np.array(corrected_errors) < 4 * np.array(stated)), (corrected_errors, stated)
    assert np.max(flat_errors) > 3 * np.max(corrected_errors)
    # the corrected poses' reprojection RMS (their corner noise, which scales their sigma) is what the true shape or
    # lens leaves (pooled over the views: within 10 %), not the flat poses', which holds their pattern (> 1.2x)
    flat_rms, corrected_rms, noise_rms = np.sqrt(np.mean(np.square(rms), axis=0))
    assert abs(corrected_rms / noise_rms - 1.0) < 0.1 and flat_rms > 1.2 * noise_rms, (flat_rms, noise_rms)
