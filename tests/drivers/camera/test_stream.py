"""The ArUco camera as a streaming tracker, with real OpenCV detection on rendered images: every frame at the
camera's frame rate, stamped with its capture time; occluded, out-of-view and lost frames as recorded gaps; a live
camera's timestamps (through a paced stand-in for ``cv2.VideoCapture``); a continuous mock session measured by
the rendered camera whose clock offset (the camera's latency) is recovered within its reported uncertainty."""

from __future__ import annotations

import time

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

cv2 = pytest.importorskip("cv2")

from acquire.commands.cli import main  # noqa: E402
from drivers.camera.intrinsics import CameraIntrinsics  # noqa: E402
from drivers.camera.renderer import Optics, Renderer  # noqa: E402
from drivers.camera.sources import LiveCamera, device_stamps_usable  # noqa: E402
from drivers.camera.tracker import ArucoTracker, open_tracker, parse_settings  # noqa: E402
from drivers.clock import VirtualClock  # noqa: E402
from drivers.sim.rig import SimulatedRig  # noqa: E402
from drivers.sim.robot import SimulatedRobot  # noqa: E402
from drivers.spec import RobotSpec, TrackerSpec  # noqa: E402

LATENCY = 0.03  # s from a frame's exposure to its timestamp
FPS = 30.0
TARGET = "board=grid&cols=2&rows=2&size=0.05&gap=0.01"
SIM = f"aruco:sim?{TARGET}&distance=0.8&tilt=0&latency={LATENCY}"  # 640x480, 30 Hz


class Streamed:
    """What one stream of the rendered camera delivered, and the world it saw."""

    def __init__(self, options: str = "", seconds: float = 1.0, turn: float = 0.0) -> None:
        spec = TrackerSpec.parse(f"{SIM}&{options}" if options else SIM)
        self.rig = SimulatedRig.from_spec(RobotSpec.parse("mock:ur5e?seed=2"), spec, VirtualClock())
        self.tracker = open_tracker(spec, rig=self.rig)
        self.tracker.connect(1.0)
        robot = SimulatedRobot(self.rig)
        robot.connect(1.0)
        self.t0 = self.rig.clock.now()
        self.rate = self.tracker.start_stream(250.0, 5.0)
        if turn:  # joint 1 turns while the camera streams
            target = self.rig.rest_joints
            target[0] += turn
            robot.start_move(target, [1.0] * 6, [2.0] * 6, 10.0)
        batches = []
        while self.rig.clock.now() - self.t0 < seconds - 1e-9:
            self.rig.clock.sleep(0.02)
            batches.append(self.tracker.read_stream())
            if turn:
                robot.motion_done()
        batches.append(self.tracker.stop_stream(5.0))
        self.t = np.concatenate([b.t for b in batches])
        self.points = np.vstack([b.points for b in batches])
        self.sigma = np.concatenate([b.sigma for b in batches])
        self.rotvec = np.vstack([b.rotvec for b in batches if len(b.t)])  # the board's orientation, camera frame
        self.sigma_r = np.concatenate([b.sigma_r for b in batches if len(b.t)])
        self.gaps = [g for b in batches for g in b.gaps]
        self.frames = int(np.floor((self.rig.clock.now() - LATENCY - self.t0) * FPS + 1e-6)) + 1
        self.grid = self.t0 + LATENCY + np.arange(self.frames) / FPS  # every frame's stamp

    def errors(self, shift: float = LATENCY) -> np.ndarray:
        """Streamed minus true TP (m, (k, 3)) at the stamped times minus ``shift`` (s)."""
        return self.points - self.rig.true_points(self.t - shift)[:, 0]


def _rms(errors: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(errors**2, axis=1))))


@pytest.fixture(scope="module")
def still() -> Streamed:
    return Streamed(seconds=1.5)


def test_a_still_target_streams_every_frame_at_the_frame_rate(still: Streamed):
    """Every frame, 1/30 s apart on the camera's stamps, none lost; the per-frame sigma is honest."""
    assert still.rate == FPS and still.tracker.identity().details["frame_rate"] == "30"
    assert "latency 0.03" in still.tracker.identity().details["stream_timestamps"]
    assert len(still.t) == still.frames == 45 and not still.gaps
    assert np.allclose(still.t, still.grid, rtol=0, atol=1e-6)
    assert abs((len(still.t) - 1) / (still.t[-1] - still.t[0]) - FPS) < 1e-3  # the rate delivered, Hz
    noise = _rms(still.errors())  # m, 3D, one frame: mostly along the line of sight
    print(f"per-frame error {noise * 1e3:.4f} mm 3D, median sigma {np.median(still.sigma) * 1e3:.4f} mm per axis")
    assert 1e-6 < noise < 2e-4
    assert 0.5 < noise / (np.sqrt(3) * np.median(still.sigma)) < 2.0
    # each frame's orientation (full pose, issue 35): the board's true axes within 5 of its own sigma_r per axis
    true = Rotation.from_matrix((still.rig.flange_pose() @ still.tracker.source.mount)[:3, :3])
    turns = np.linalg.norm((Rotation.from_rotvec(still.rotvec) * true.inv()).as_rotvec(), axis=1)
    assert len(still.rotvec) == len(still.t) and np.all(still.sigma_r > 0)
    assert np.all(turns < 5 * np.sqrt(3) * still.sigma_r) and np.all(still.sigma_r < np.radians(0.5)), turns


def test_a_moving_target_is_where_the_arm_was_at_each_frames_capture_time(still: Streamed):
    """Joint 1 turns (the TP at up to 0.3 m/s): each streamed position matches the true TP at its stamp minus the
    latency as well as a still frame matches it; read at the stamp itself it misses by millimetres."""
    moving = Streamed(seconds=1.2, turn=0.4)
    assert len(moving.t) == moving.frames and not moving.gaps
    path = np.linalg.norm(moving.rig.true_points(moving.t[-1])[0] - moving.rig.true_points(moving.t[0])[0])
    assert path > 0.1  # m: the target really moved
    noise = _rms(still.errors())
    assert _rms(moving.errors()) < 2.0 * noise
    assert np.max(np.linalg.norm(moving.errors(), axis=1)) < 5.0 * noise
    assert _rms(moving.errors(shift=0.0)) > 20 * noise  # wrong by the latency: caught


def test_occluded_frames_are_one_recorded_gap():
    """The target hidden from 0.4 to 0.6 s into the stream: those 7 frames are not rows, and one gap runs from
    the last frame seen before to the first seen after."""
    s = Streamed("lost=0.2@0.4", seconds=1.2)
    hidden = (s.grid - LATENCY - s.t0 > 0.4 - 1e-6) & (s.grid - LATENCY - s.t0 < 0.6 + 1e-6)
    assert hidden.sum() == 7 and s.tracker.stream_counts["not_seen"] == 7
    assert np.allclose(s.t, s.grid[~hidden], rtol=0, atol=1e-6)
    first, last = np.flatnonzero(hidden)[[0, -1]]
    assert len(s.gaps) == 1 and np.allclose(s.gaps[0], (s.grid[first - 1], s.grid[last + 1]), rtol=0, atol=1e-6)


def test_a_target_leaving_the_view_is_a_gap_to_the_last_frame():
    """Joint 1 turns the target out of the camera's view and the stream ends there: the frames after the last one
    seen are a gap to the last frame's stamp, not silently missing."""
    s = Streamed(seconds=2.0, turn=1.5)
    assert 5 < len(s.t) < s.frames - 5
    counts = s.tracker.stream_counts
    assert counts["frames"] == s.frames and counts["rows"] + counts["not_seen"] + counts["rejected"] == s.frames
    assert len(s.gaps) == 1 and np.allclose(s.gaps[0], (s.t[-1], s.grid[-1]), rtol=0, atol=1e-6)


def test_frames_the_camera_drops_are_gaps():
    """A camera that loses 15 % of its frames: every lost frame lies inside a recorded gap between the rows on
    either side, and every gap holds a lost frame."""
    s = Streamed("drop=0.15", seconds=1.5)
    seen = np.isin(np.round((s.grid - s.grid[0]) * FPS), np.round((s.t - s.grid[0]) * FPS))
    lost = s.grid[~seen]
    assert 3 <= len(lost) <= 15 and np.allclose(s.t, s.grid[seen], rtol=0, atol=1e-6)
    assert s.tracker.stream_counts["missing"] == len(lost) - (not seen[0])  # none before the first frame
    inside = [any(a < x < b for a, b in s.gaps) for x in lost[lost > s.t[0]]]
    assert all(inside)
    for a, b in s.gaps:
        assert np.any((lost > a) & (lost < b)) and a in s.t and b in s.t


def test_measure_is_refused_while_streaming_and_stop_joins_the_worker():
    spec = TrackerSpec.parse(SIM)
    rig = SimulatedRig.from_spec(RobotSpec.parse("mock:ur5e?seed=2"), spec, VirtualClock())
    tracker = open_tracker(spec, rig=rig)
    tracker.connect(1.0)
    tracker.start_stream(250.0, 5.0)
    worker = tracker._reader
    with pytest.raises(RuntimeError, match="is streaming"):
        tracker.measure(1, 5.0)
    rig.clock.sleep(0.2)
    assert len(tracker.stop_stream(5.0).t) == 6
    assert not worker.is_alive() and not tracker.streaming
    assert len(tracker.measure(1, 5.0)) == 1  # polled again
    tracker.start_stream(250.0, 5.0)
    worker = tracker._reader
    tracker.close()  # closing stops the stream too
    assert not worker.is_alive()


def test_a_camera_lost_mid_stream_fails_the_read_and_keeps_what_was_measured():
    from drivers.errors import ConnectionFailed

    spec = TrackerSpec.parse(SIM)
    rig = SimulatedRig.from_spec(RobotSpec.parse("mock:ur5e?seed=2"), spec, VirtualClock())
    tracker = open_tracker(spec, rig=rig)
    tracker.connect(1.0)
    tracker.start_stream(250.0, 5.0)
    worker = tracker._reader
    rig.clock.sleep(0.2)
    first = tracker.read_stream()
    rig.tracker_connected = False  # the cable is pulled
    rig.clock.sleep(0.2)
    with pytest.raises(ConnectionFailed):
        tracker.read_stream()
    with pytest.raises(ConnectionFailed):
        tracker.stop_stream(5.0)
    assert not worker.is_alive() and not tracker.streaming
    rest = tracker.stop_stream(5.0)  # what the worker measured before the link went
    assert len(first.t) + len(rest.t) == 6 and np.all(np.diff(np.concatenate([first.t, rest.t])) > 0)


def test_a_replay_cannot_stream_in_one_line(tmp_path):
    from drivers.camera.intrinsics import write_intrinsics

    write_intrinsics(tmp_path / "cam.yaml", CameraIntrinsics.from_fov(64, 48, 60))
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((48, 64), np.uint8))
    tracker = open_tracker(f"aruco:{tmp_path}?marker=1&camera={tmp_path / 'cam.yaml'}")
    tracker.connect(1.0)
    with pytest.raises(ValueError, match="cannot stream") as info:
        tracker.start_stream(30.0, 1.0)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("spec, words", [
    ("aruco:sim?lost=soon", "lost=soon must be DURATION[@START]"),
    ("aruco:sim?drop=1", "drop must be a probability below 1"),
    ("aruco:sim?latency=-0.1", "latency=-0.1 must be >= 0"),
    ("aruco:0?marker=1&camera=c.yaml&drop=0.1", "only for aruco:sim"),
])
def test_bad_stream_options_give_one_line(spec, words):
    from drivers.errors import SpecError

    with pytest.raises(SpecError) as info:
        open_tracker(spec)
    assert words in str(info.value) and "\n" not in str(info.value)


# --- a live camera: cv2.VideoCapture's timestamps --------------------------------------------------------------


class PacedCapture:
    """A stand-in for ``cv2.VideoCapture`` of a live camera: a frame every 1/fps s of real time showing ``image``
    (``blank`` for the frame numbers in ``hidden``); frames in ``skip`` are dropped by the camera (never
    delivered); ``CAP_PROP_POS_MSEC`` is the camera's clock (``epoch`` + k / fps s) or 0 without one."""

    def __init__(self, image: np.ndarray, fps: float, device_clock: bool, skip=(), hidden=(),
                 epoch: float = 5000.0) -> None:
        self.image, self.blank = image, np.full_like(image, 110)
        self.fps, self.device_clock, self.epoch = fps, device_clock, epoch
        self.skip, self.hidden = set(skip), set(hidden)
        self.k, self.start, self.current = 0, time.monotonic(), -1

    def isOpened(self) -> bool:  # noqa: N802 (OpenCV's name)
        return True

    def set(self, prop: int, value: float) -> bool:
        return True

    def getBackendName(self) -> str:  # noqa: N802
        return "PACED"

    def grab(self) -> bool:
        while self.k in self.skip:
            self.k += 1
        time.sleep(max(self.start + self.k / self.fps - time.monotonic(), 0.0))
        self.current, self.k = self.k, self.k + 1
        return True

    def get(self, prop: int) -> float:
        assert prop == cv2.CAP_PROP_POS_MSEC
        return 1e3 * (self.epoch + self.current / self.fps) if self.device_clock else 0.0

    def retrieve(self) -> tuple[bool, np.ndarray]:
        return True, (self.blank if self.current in self.hidden else self.image).copy()

    def release(self) -> None:
        pass


@pytest.mark.parametrize("device_clock", [True, pytest.param(False, marks=pytest.mark.realtime)],
                         ids=["camera-clock", "host-time"])  # host time: a loaded host delays grabs into gaps
def test_a_live_camera_streams_its_own_timestamps_or_the_host_time(device_clock):
    """Through LiveCamera's reader thread: with a usable CAP_PROP_POS_MSEC the rows carry the camera's own times
    exactly; without one, the host time at grab (and the identity says which). A frame the camera dropped (a
    step of two periods) and one where the target is not seen are gaps."""
    camera = CameraIntrinsics.from_fov(640, 480, 60)
    pose = np.eye(4)
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0])
    pose[:3, 3] = [0.02, -0.01, 0.6]
    spec = TrackerSpec.parse(f"aruco:0?{TARGET}&camera=unused.yaml")
    settings = parse_settings(spec)
    image = Renderer(settings.target, camera, Optics(noise=1.0, blur=0.5)).render([pose], np.random.default_rng(1))
    fake = PacedCapture(image, FPS, device_clock, skip={20}, hidden={25})
    tracker = ArucoTracker(spec, settings, LiveCamera(0, opener=lambda device: fake), camera)
    tracker.connect(2.0)
    stamps = tracker.identity().details["stream_timestamps"]
    assert ("CAP_PROP_POS_MSEC, PACED" in stamps) if device_clock else stamps.startswith("host time at grab")
    assert abs(tracker.source.rate - FPS) < 3
    first = fake.k  # the frame number the stream starts at
    tracker.start_stream(250.0, 2.0)
    worker = tracker._reader
    time.sleep(0.9)
    out = tracker.stop_stream(2.0)
    tracker.close()
    assert not worker.is_alive()
    assert len(out.t) >= 20 and np.all(np.linalg.norm(out.points - pose[:3, 3], axis=1) < 1e-3)
    if device_clock:
        k = np.round((out.t - fake.epoch) * FPS)
        assert np.allclose(out.t, fake.epoch + k / FPS, rtol=0, atol=1e-9) and k[0] == first
        assert set(range(first, int(k[-1]) + 1)) - set(k.astype(int)) == {20, 25}
        assert [tuple(np.round((np.array(g) - fake.epoch) * FPS)) for g in out.gaps] == [(19, 21), (24, 26)]
    else:
        assert abs(out.t[-1] - time.time()) < 5.0 and len(out.gaps) == 2
        assert 0.8 / FPS < np.median(np.diff(out.t)) < 1.25 / FPS


def test_camera_timestamps_are_checked_before_they_are_used():
    host = 1.7e9 + np.arange(8) / 30
    assert device_stamps_usable(host, 1e3 * (40.0 + np.arange(8) / 30)) == (True, "")
    for device, words in ((np.zeros(8), "no time"), (np.full(8, -1.0), "no time"),
                          (1e3 * np.array([1, 2, 3, 3, 4, 5, 6, 7]) / 30, "do not increase"),
                          (np.arange(1.0, 9.0), "as fast as the host clock")):  # a frame count, not ms
        usable, why = device_stamps_usable(host, device)
        assert not usable and words in why


# --- a continuous session measured by the rendered camera ------------------------------------------------------

SITE = """schema: 1
plan:
  sweep_ranges: [[-0.3, 0.3], [-1.87, -1.27], [1.27, 1.87], [-1.87, -1.27], [-1.87, -1.27], [-0.3, 0.3]]
  check_poses: 3
  home_check_every: 0
"""


@pytest.mark.slow
def test_continuous_mock_session_with_the_camera_recovers_its_latency(tmp_path, capsys):
    """mock:ur5e swept at constant speed, the rendered camera streaming at 30 Hz with 40 ms between exposure and
    stamp: the session completes, is identified, and the fitted clock offset is -40 ms within 3 of its reported
    standard uncertainties."""
    tracker = f"aruco:sim?{TARGET}&frames=2&tilt=0&distance=0.8&latency=0.04"
    (tmp_path / "site.yaml").write_text(SITE)
    path = tmp_path / "cam.session"
    code = main(["--robot", "mock:ur5e?seed=3", "--tracker", tracker, "--config", str(tmp_path / "site.yaml"),
                 "--mode", "continuous", "--samples", "1", "--quiet", "--session", str(path)])
    assert code == 0, capsys.readouterr().err
    result = yaml.safe_load(path.with_suffix(".result.yaml").read_text())
    clock = result["clock"]
    print(clock, result["verdict"]["status"])
    assert result["verdict"]["status"] != "fail" and clock["streamed_rows"] > 400
    assert 0 < clock["offset_std_s"] < 2e-4
    assert abs(clock["offset_s"] + 0.04) < 3 * clock["offset_std_s"]
