"""A camera watching an ArUco marker, a board, or markers on a rigid body on the flange (OpenCV).

URL form (``--tracker``)::

    aruco:SOURCE?camera=FILE[&marker=ID&size=M | &board=grid&cols=N&rows=N&size=M&gap=M
                 | &board=charuco&cols=N&rows=N&square=M&size=M | &layout=FILE][&dict=NAME][&first=ID]
                 [&tp=X,Y,Z][&refine=edges|apriltag|subpix|contour|none][&frames=N][&max_rms=PX]
                 [&timeout=S][&retries=N][&latency=S][&mount=cell|flange][&square_sigma=M | &size_sigma=M]

``SOURCE``: a camera index (``0``), a device path (``/dev/video0``), a network camera's URL (an MJPEG stream or a
snapshot URL, ``aruco:http://HOST[:PORT]/PATH[?QUERY]#OPTIONS``: the options follow ``#`` since the ``?`` belongs
to the URL; drivers/camera/network.py), a video file, an image folder or a glob (``run/*.png``; replay of a recorded
run, ``frames`` images per reading), or ``sim`` (images rendered from the simulated robot, mock mode only:
``--robot mock:MODEL``).

Target (units: metres):
  ``marker``  id of a single marker (default 0 when no board or layout is given); ``size`` its side (the
              black square; default 0.05)
  ``board``   ``grid``: ``cols`` x ``rows`` markers of side ``size``, ``gap`` apart (default size/5);
              ``charuco``: ``cols`` x ``rows`` squares of side ``square``, markers of side ``size``
  ``first``   id of a board's first marker (default 0)
  ``layout``  a YAML file of markers on a rigid body (drivers/camera/targets.py)
  ``dict``    the ArUco dictionary (default ``4X4_50``; e.g. ``5X5_100``, ``ARUCO_ORIGINAL``, ``APRILTAG_36h11``)
  ``tp``      the tracked point in the target frame (origin at the marker / board centre, x right, y up,
              z out of the printed face), ``X,Y,Z`` in metres (default ``0,0,0``: the centre)
Where the camera is (drivers/camera/flange_camera.py):
  ``mount``   ``cell`` (default): the camera stands in the cell and the target rides on the flange; ``flange``: the
              camera rides on the flange (eye-in-hand) and sees a board fixed in the cell; the readings are the
              board's pose in the camera frame and the session is a ``sensor: flange`` one
  ``flatness`` m: the print may be this far out of flat (default 0: flat); ``lens_sigma``: the calibration's k1 and
              k2 may be this far off (default 0); ``focal_sigma``: its fx, fy, relative (0); ``centre_sigma`` px: its
              principal point (0): the board's shape and the lens's errors are estimated from every frame so far and
              each reading corrected, their uncertainty in its ``shared`` (drivers/camera/board_and_lens.py)
  ``square_sigma`` (ChArUco) / ``size_sigma`` (grid, marker): the board was measured (``square=`` / ``size=`` is
              the caliper's value) with this standard uncertainty, m: the scale reference (without it the print is
              unverified and identify checks the scale against the robot's nominal lengths)
Camera and measurement:
  ``camera``  the intrinsics file (OpenCV FileStorage: camera_matrix, distortion_coefficients,
              image_width, image_height); required except for ``sim``
  ``refine``  marker corner refinement (default ``edges``: lines fitted to the marker's outer edges,
              drivers/camera/refinement.py, the most accurate and fast; OpenCV's ``apriltag``, ``subpix``,
              ``contour``, ``none`` compared in docs/benchmarks.md); ChArUco chessboard corners are always
              refined by ``cornerSubPix``
  ``frames``  frames averaged into one reading (default 5); ``max_rms`` pixels: a frame whose reprojection
              RMS exceeds it is rejected (motion blur, a bent print; default 1.0)
  ``timeout`` s to wait for one frame (default 2); ``retries`` failed frames tolerated per reading beyond
              ``frames`` (default 5), then the reading fails with one line
  ``latency`` s from a frame's exposure to its delivery: a stop-and-go reading skips the frames delivered before its
              request plus it, exposed while the arm may still have been arriving, and says so in its status
              (drivers/camera/latency.py). Default: a network camera's measured latency where it is one
              (drivers/camera/network.py), else 0; below ``timeout``; ``aruco:sim`` renders with it too
Simulated camera (``aruco:sim`` only): ``width``, ``height`` pixels (640, 480), ``fov`` horizontal degrees (60),
``k1`` radial distortion (0), ``noise`` grey levels (2), ``blur`` pixels (0.5), ``motion`` pixels of motion streak
(0), ``fps`` Hz (30), ``latency`` as above (the frames are rendered that late), ``distance`` m from
the camera to the TP at home (1.0), ``tilt`` and ``roll`` degrees of the flange at home (20, 10; ``mount=flange``:
of the board seen from the camera at home), ``printed`` (``mount=flange``: the true board's size over the declared
one, 1), a real camera's errors (drivers/camera/imperfections.py: ``dk1``, ``dk2`` distortion left after
calibration, ``dfocal`` relative, ``dcx``, ``dcy`` px its focal length and principal point, ``shutter`` s rolling
shutter, ``exposure`` s motion blur, ``gain``, ``gradient``, ``glare`` light, ``bow`` m a board not flat), ``seed``
(the robot's), ``fault`` as the mock tracker's (``target_lost``, ``bad_reading``: a second copy, ``slow``,
``disconnect``); for streams ``drop`` (probability of a lost frame, 0)
and ``lost=D[@S]`` (the target hidden for D s from S s, default 2, into every stream). Other options: one line.

Streaming (continuous motion, drivers/camera/stream.py): every frame at the camera's frame rate, stamped with its
capture time (the identity's ``stream_timestamps`` says which clock), measured in a worker thread like a polled
frame, one row each; frames where the target is not seen or fails a check, and frames the camera lost, are gaps.

A reading: the TP of every frame (pose by drivers/camera/pose.py), frames farther than 5 robust sigmas
from the median rejected, the rest averaged. Its ``sigma`` is the standard uncertainty per axis (m), one
number as the measurement contract has it: ``sqrt(trace(C) / 3)`` of the mean's covariance C. C is the
pose covariance propagated to the TP, divided by the frames kept. With ``refine=edges`` the corners'
covariance comes from the edge-line fits (drivers/camera/refinement.py: corners of one side are correlated),
scaled up when the reprojection residuals are larger than it predicts; otherwise the corners are taken as
independent with the noise of the pooled reprojection residuals (never below ``drivers.camera.pose.SIGMA_PX_FLOOR``). If
the frames scatter significantly more than C says (F-test), their spread is used instead. Beyond that noise, the
detection errs by a fixed amount for each view of the target (the corners' localisation bias at that angle and
scale: the same in every frame and every reading of a still view, so averaging does not reduce it). Each reading
states it as ``shared`` (m) and ``shared_r`` (rad) (drivers.camera.pose.Pose.view_bias) and adds it in quadrature to
sigma and sigma_r; the orchestrator divides only the rest by the number of readings of a step. For the orientation:
the pose's sensitivity to a corner error of ``VIEW_TURN_BIAS_PX`` per coordinate, independent from corner to
corner. For the TP: a coherent error of the target's apparent size (the corners' image scaled by ``VIEW_BIAS_PX`` at
its RMS radius, over cos² of the obliquity), a depth error along the line of sight that grows with the obliquity.
Measured on rendered images (``bench/camera_honesty.py``, docs/benchmarks.md section 23): without them a step's
orientation errors were 2.7x, its positions' 2.4x their stated sigmas at a calibration plan's views (1.9x at random
views about home); with them 1.2x at fresh plan views for both, positions 1.06-1.08x at random views. A camera's
error is mostly along its line of sight (depth: typically 5-10x a lateral one), so sigma, the RMS over
the axes, is ~1.7x too large across and ~0.6x of the depth error. Consequence for the weights
(1 / sigma² per sample): the sum of squared weighted residuals has the expectation it would have for
isotropic noise of that sigma (reduced chi-square ~1), the relative weights of the samples are right
(an oblique or distant view weighs less), but the fit cannot down-weight depth against lateral errors
(unbiased, not minimum variance), and identify's outlier test must allow anisotropic residuals
(identify/estimator/refine.py ``inlier_mask``).

Faults: no frame within ``timeout`` -> the camera is reopened once, then DeviceTimeout; target not seen
-> TargetLost; an id seen twice -> BadReading (DuplicateMarker); too few points, no pose, or a reprojection
error above ``max_rms`` -> BadReading; each after ``retries`` failed frames, naming the count.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from drivers.averaging import CHI3_MEDIAN, frame_sigma, mean_orientation
from drivers.base import Array, Correction, DeviceIdentity, TrackerReading, check_measure_request
from drivers.camera import pose as pose_math
from drivers.camera.board_and_lens import BoardAndLens
from drivers.camera.flange_camera import MOUNTS
from drivers.camera.flange_camera import scale_sigma as flange_scale_sigma
from drivers.camera.imperfections import OPTIONS as IMPERFECTIONS
from drivers.camera.intrinsics import CameraIntrinsics, IntrinsicsError, read_intrinsics
from drivers.camera.latency import FreshFrames, latency_in_use
from drivers.camera.options import number, sim_settings, spec_error
from drivers.camera.pose import CornerNoise, Pose, estimate_pose
from drivers.camera.stream import FrameStreaming
from drivers.camera.targets import (
    REFINEMENTS,
    DuplicateMarker,
    Target,
    charuco_board,
    dictionary_id,
    grid_board,
    load_layout,
    single_marker,
)
from drivers.errors import BadReading, DeviceTimeout, MeasurementError, SpecError, TargetLost
from drivers.spec import TrackerSpec

OPTIONS = ("camera", "marker", "size", "board", "cols", "rows", "gap", "square", "first", "layout", "dict", "tp",
           "refine", "frames", "max_rms", "timeout", "retries", "mount", "square_sigma", "size_sigma", "flatness",
           "lens_sigma", "focal_sigma", "centre_sigma", "latency")
SIM_OPTIONS = ("width", "height", "fov", "k1", "noise", "blur", "motion", "fps", "drop", "lost", "distance",
               "tilt", "roll", "seed", "fault", "printed", *IMPERFECTIONS)
OUTLIER_SIGMAS = 5.0


@dataclass(frozen=True)
class Settings:
    """Typed options of an ``aruco:`` spec (module docstring)."""

    target: Target
    tp: Array
    refine: str
    frames: int
    max_rms: float
    timeout: float
    retries: int
    camera_file: Path | None
    sim: dict[str, Any]
    mount: str = "cell"  # where the camera is: "cell" or "flange" (drivers/camera/flange_camera.py)
    scale_sigma: float | None = None  # relative uncertainty of the measured board's scale (None: not measured)
    flatness: float = 0.0  # m: the print's shape modes' prior (drivers/camera/board_and_lens.py)
    lens_sigma: float = 0.0  # the calibrated k1's and k2's prior uncertainty
    focal_sigma: float = 0.0  # the calibrated fx's and fy's relative prior uncertainty
    centre_sigma: float = 0.0  # px: the calibrated principal point's prior uncertainty per axis
    latency: float | None = None  # s from exposure to delivery (None: the source's; drivers/camera/latency.py)


def parse_settings(spec: TrackerSpec, site: Any = None) -> Settings:
    """The options of ``spec`` (site ``tracker_settings`` below them), typed and checked; SpecError."""
    raw: dict[str, Any] = {}
    raw.update({k: v for k, v in dict(getattr(site, "tracker_settings", None) or {}).items() if v is not None})
    raw.update(spec.options)
    simulated = spec.target == "sim"
    known = OPTIONS + (SIM_OPTIONS if simulated else ())
    for key in raw:
        if key not in known:
            extra = " (only for aruco:sim)" if key in SIM_OPTIONS else ""
            raise spec_error(spec, f"unknown option {key!r}{extra} (known: {', '.join(known)})")
    try:
        dictionary = dictionary_id(str(raw.get("dict", "4X4_50")))
    except ValueError as exc:
        raise spec_error(spec, str(exc)) from None
    target = _target(spec, raw, dictionary)
    try:
        tp = np.array([float(v) for v in str(raw.get("tp", "0,0,0")).split(",")])
    except ValueError:
        tp = np.zeros(0)
    if tp.shape != (3,) or not np.all(np.isfinite(tp)):
        raise spec_error(spec, f"option tp={raw.get('tp')} must be X,Y,Z in metres")
    refine = str(raw.get("refine", "edges"))
    if refine not in REFINEMENTS:
        raise spec_error(spec, f"option refine={refine} must be one of {', '.join(REFINEMENTS)}")
    camera = raw.get("camera")
    if camera is None and not simulated:
        url = spec.target.startswith(("http://", "https://")) and "camera=" in spec.target
        raise spec_error(spec, "option camera=FILE (the intrinsics) is required for a real camera" +
                         (" (a network camera's options follow '#': the '?' belongs to its URL)" if url else ""))
    sim = sim_settings(spec, raw) if simulated else {}
    mount = str(raw.get("mount", "cell"))
    if mount not in MOUNTS:
        raise spec_error(spec, f"option mount={mount} must be cell or flange")
    timeout = number(spec, raw, "timeout", 2.0)
    latency = number(spec, raw, "latency", None, low=0, strict=False)
    if latency is not None and latency >= timeout:
        raise spec_error(spec, f"option latency={raw['latency']} must be below timeout={timeout:g} s (a reading "
                         "waits that long for its first frame exposed after the request)")
    return Settings(target, tp, refine, number(spec, raw, "frames", 5, int, 1, strict=False),
                    number(spec, raw, "max_rms", 1.0), timeout, number(spec, raw, "retries", 5, int, 0, strict=False),
                    None if camera is None else Path(str(camera)), sim, mount, _scale_sigma(spec, raw, target),
                    *(number(spec, raw, key, 0.0, low=0, strict=False)
                      for key in ("flatness", "lens_sigma", "focal_sigma", "centre_sigma")), latency)


def _scale_sigma(spec: TrackerSpec, raw: dict[str, Any], target: Target) -> float | None:
    """The measured board's relative scale uncertainty from ``square_sigma`` (ChArUco) or ``size_sigma``."""
    key = "square_sigma" if target.kind == "charuco" else "size_sigma"
    other = "size_sigma" if key == "square_sigma" else "square_sigma"
    if other in raw:
        raise spec_error(spec, f"option {other}= does not measure a {target.kind} target (give {key}=)")
    if key not in raw:
        return None
    if target.kind == "layout":
        raise spec_error(spec, "a layout's scale comes from its file; size_sigma= is for a marker or a board")
    sigma = number(spec, raw, key, 0.0, low=0, strict=False)
    size = float(raw["square" if key == "square_sigma" else "size"]) if key.split("_")[0] in raw else None
    if size is None:
        raise spec_error(spec, f"option {key}= needs {key.split('_')[0]}= (the measured length, m)")
    return flange_scale_sigma(size, sigma)


def _target(spec: TrackerSpec, raw: dict[str, Any], dictionary: int) -> Target:
    board, layout = raw.get("board"), raw.get("layout")
    if sum(x is not None for x in (board, layout, raw.get("marker"))) > 1:
        raise spec_error(spec, "give one of marker=, board= and layout=")
    given = [k for k in ("cols", "rows", "gap", "square") if k in raw]
    try:
        if layout is not None:
            if given or "size" in raw:
                raise spec_error(spec, f"layout= takes its geometry from the file, not {(given or ['size'])[0]}=")
            return load_layout(str(layout), dictionary if "dict" in raw else None)
        if board is None:
            if given:
                raise spec_error(spec, f"option {given[0]}= belongs to a board (board=grid or board=charuco)")
            return single_marker(number(spec, raw, "marker", 0, int, 0, strict=False),
                                 number(spec, raw, "size", 0.05), dictionary)
        cols, rows = number(spec, raw, "cols", 0, int), number(spec, raw, "rows", 0, int)
        if not cols or not rows:
            raise spec_error(spec, f"board={board} needs cols= and rows=")
        size, first = number(spec, raw, "size", 0.0), number(spec, raw, "first", 0, int, 0, strict=False)
        if not size:
            raise spec_error(spec, f"board={board} needs size= (the marker side, m)")
        if board == "grid":
            if "square" in raw:
                raise spec_error(spec, "square= belongs to board=charuco")
            return grid_board(cols, rows, size, number(spec, raw, "gap", size / 5), dictionary, first)
        if board == "charuco":
            if "gap" in raw or "square" not in raw:
                raise spec_error(spec, "board=charuco needs square= (the chessboard square, m) and takes no gap=")
            return charuco_board(cols, rows, number(spec, raw, "square", 0.0), size, dictionary, first)
        raise spec_error(spec, f"option board={board} must be grid or charuco")
    except ValueError as exc:
        if isinstance(exc, SpecError):
            raise
        raise spec_error(spec, str(exc)) from None


def rig_settings(spec: TrackerSpec) -> tuple[tuple[Any, ...], int | None, tuple[float, float, float]]:
    """What the simulated rig takes from ``aruco:sim?...``: its faults, its seed, and the camera's view
    (distance m, tilt rad, roll rad) for :meth:`drivers.sim.rig.SimulatedRig.face_tracker`."""
    sim = parse_settings(spec).sim
    return sim["fault"], sim["seed"], (sim["distance"], math.radians(sim["tilt"]), math.radians(sim["roll"]))


class ArucoTracker(FrameStreaming):
    """The camera tracker (implements :class:`drivers.base.Tracker` and ``StreamingTracker``, the stream in
    drivers/camera/stream.py). ``source``: a frame source (drivers/camera/sources.py or the simulated camera);
    ``camera``: its intrinsics."""

    def __init__(self, spec: TrackerSpec, settings: Settings, source: Any, camera: CameraIntrinsics) -> None:
        from drivers.camera.targets import Detector

        self.spec, self.settings, self.source, self.camera = spec, settings, source, camera
        self.detector = Detector(settings.target, settings.refine, camera)
        self.reference: Array | None = None  # rotation of the last pose: keeps IPPE solutions on one branch
        self._observation: Any = None  # the last frame's detected points (BoardAndLens reads them)
        self.shape = BoardAndLens.of(settings.flatness, settings.lens_sigma, settings.target.extent,
                                     settings.focal_sigma, settings.centre_sigma, settings.frames)
        self.frames_used = self.frames_failed = 0
        self.fresh, self.latency_basis = FreshFrames(source, settings.latency or 0.0), ""
        self._init_stream()

    def connect(self, timeout: float) -> None:
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout!r}")
        self.source.open(timeout)
        latency, self.latency_basis = latency_in_use(self.settings.latency, self.source)
        if latency >= self.settings.timeout:  # a network camera's measured one
            self.source.close()
            raise spec_error(self.spec, f"the camera's latency {latency:g} s ({self.latency_basis}) is not below "
                             f"timeout={self.settings.timeout:g} s: give a longer timeout= or latency=")
        self.fresh = FreshFrames(self.source, latency)

    def close(self) -> None:
        try:
            self.stop_stream(self.settings.timeout)
        finally:
            self.source.close()

    def identity(self) -> DeviceIdentity:
        s, k = self.settings, self.camera.matrix
        target = s.target
        details = {"source": self.source.description, "target": target.kind, "markers": str(len(target.corners)),
                   "refine": s.refine, "frames": str(s.frames), "image": f"{self.camera.width}x{self.camera.height}",
                   "tp": ",".join(repr(float(v)) for v in s.tp),
                   # the intrinsics used, at full precision, so that a recorded session can be replayed
                   "camera_matrix": json.dumps(k.tolist()),
                   "distortion_coefficients": json.dumps(self.camera.distortion.tolist()),
                   "camera_file": "" if s.camera_file is None else str(s.camera_file),
                   "stream_timestamps": getattr(self.source, "stamps", "none: this source cannot stream"),
                   "mount": s.mount, "scale_sigma": "" if s.scale_sigma is None else repr(s.scale_sigma)}
        if math.isfinite(getattr(self.source, "rate", math.nan)):
            details["frame_rate"] = f"{self.source.rate:g}"
        for key, name in (("latency_measured", "measured_latency"), ("latency_spread", "latency_spread")):
            if math.isfinite(getattr(self.source, name, math.nan)):  # a network camera's (s)
                details[key] = f"{getattr(self.source, name):.6g}"
        details["latency"], details["latency_basis"] = f"{self.fresh.latency:.6g}", self.latency_basis
        return DeviceIdentity("tracker", "ArUco camera (OpenCV)", serial=str(self.spec.target),
                              firmware=f"opencv {cv2.__version__}", details=details)

    def measure(self, count: int, timeout: float) -> list[TrackerReading]:
        """``count`` readings of the TP (m, camera frame), each the average of ``frames`` frames with its
        own sigma. Raises TargetLost, BadReading, DeviceTimeout, ConnectionFailed (one line each)."""
        check_measure_request(count, timeout)
        self._refuse_while_streaming(self.source.description)
        self.fresh.request()
        self.source.start_measurement()
        return [self._reading() for _ in range(count)]

    def _reading(self) -> TrackerReading:
        s = self.settings
        poses: list[tuple[Pose, float]] = []
        flat: list[Correction | None] = []  # how each frame moves with the board's shape and the lens
        failures: list[MeasurementError] = []
        while len(poses) < s.frames:
            image, stamp = self._grab(s.timeout)
            while not self.fresh.fresh(stamp):  # exposed before the request (drivers/camera/latency.py)
                image, stamp = self._grab(self.fresh.time_left(stamp, s.timeout))
            try:
                pose, correction = self._pose(image), None
                if self.shape is not None:  # corrected for the board's shape seen so far (this frame included)
                    pose, correction = self.shape.take(pose, self._observation, self.camera, s.tp)
                poses.append((pose, stamp))
                flat.append(correction)
            except MeasurementError as exc:
                failures.append(exc)
                self.frames_failed += 1
                if len(failures) > s.retries:
                    raise _summary(failures, len(poses) + len(failures)) from None
        self.frames_used += len(poses)
        return self._average(poses, flat)

    def _grab(self, timeout: float) -> tuple[Any, float]:
        try:
            image, stamp = self.source.grab(timeout)
        except DeviceTimeout:
            self.source.close()  # a stalled camera: reopen once
            self.source.open(timeout)
            try:
                image, stamp = self.source.grab(timeout)
            except DeviceTimeout as exc:
                raise DeviceTimeout(f"{self.source.description} stopped delivering frames (none within "
                                    f"{timeout:g} s, also after reopening it)") from exc
        shape = image.shape[:2]
        if shape != (self.camera.height, self.camera.width):
            raise BadReading(f"frame size {shape[1]}x{shape[0]} differs from the calibration's "
                             f"{self.camera.width}x{self.camera.height} (camera= file)")
        return image, stamp

    def _pose(self, image: Any) -> Pose:
        obs = self._observation = self.detector.detect(image)
        if not obs.ids:
            raise TargetLost("the target is not visible")
        square = self.settings.target.kind == "marker"
        pose = estimate_pose(obs, self.camera.matrix, self.camera.distortion, square, self.reference)
        if pose is None:
            raise BadReading(f"no pose from {len(obs.image_points)} points (markers {list(obs.ids)})")
        if pose.rms > self.settings.max_rms:
            raise BadReading(f"reprojection error {pose.rms:.2f} px above max_rms={self.settings.max_rms:g} "
                             "(motion blur or a bent target?)")
        self.reference = pose.rotation
        return pose

    def _average(self, poses: list[tuple[Pose, float]], flat: list[Correction | None]) -> TrackerReading:
        tp = self.settings.tp
        pts = np.array([p.point(tp) for p, _ in poses])
        noise = CornerNoise()
        for p, _ in poses:
            noise.add(p)
        covs = np.array([noise.covariance(p, tp) for p, _ in poses])
        dof = noise.dof
        model = math.sqrt(float(np.trace(covs.mean(axis=0))) / 3)  # per-axis RMS, one frame
        median = np.median(pts, axis=0)
        dist = np.linalg.norm(pts - median, axis=1)
        robust = max(float(np.median(dist)) / CHI3_MEDIAN, model)
        kept = dist <= OUTLIER_SIGMAS * robust if len(pts) >= 3 else np.ones(len(pts), dtype=bool)
        n = int(kept.sum())
        sigma = frame_sigma(model, pts[kept], dof) / math.sqrt(n)
        stamp = float(np.mean([t for (_, t), k in zip(poses, kept, strict=True) if k]))
        rejected = f"{len(pts) - n} of {len(pts)} frames rejected" if n < len(pts) else ""
        notes = "; ".join(filter(None, [self.fresh.note(), rejected]))
        status = f"ok ({notes})" if notes else "ok"
        # the target frame (the board's axes at the TP): the kept frames' mean orientation, its sigma as the TP's
        rotvecs = np.array([cv2.Rodrigues(p.rotation)[0].ravel() for (p, _), k in zip(poses, kept, strict=True) if k])
        rotvec, _ = mean_orientation(rotvecs)
        turns = (Rotation.from_rotvec(rotvecs) * Rotation.from_rotvec(rotvec).inv()).as_rotvec()
        model_r = math.sqrt(float(np.mean([np.trace(noise.orientation_covariance(p)) for (p, _), k
                                           in zip(poses, kept, strict=True) if k])) / 3)
        sigma_r = frame_sigma(model_r, turns, dof) / math.sqrt(n)
        # the detection's bias for this view: the same in every frame and every reading of it (not averaged)
        bias = np.array([p.view_bias(tp, pose_math.VIEW_BIAS_PX, pose_math.VIEW_TURN_BIAS_PX)
                         for (p, _), k in zip(poses, kept, strict=True) if k])
        mine = [c for c, k in zip(flat, kept, strict=True) if k and c is not None]
        correction = Correction.mean(mine) if mine else None
        estimated = (0.0, 0.0) if correction is None else (correction.bias, correction.bias_r)  # the estimate's share
        shared, shared_r = np.sqrt(np.mean(bias**2, axis=0) + np.square(estimated))
        return TrackerReading(pts[kept].mean(axis=0), stamp, sigma=math.hypot(sigma, shared), status=status,
                              rotvec=rotvec, sigma_r=math.hypot(sigma_r, shared_r), shared=float(shared),
                              shared_r=float(shared_r), correction=correction)


def _summary(failures: list[MeasurementError], tried: int) -> MeasurementError:
    """One line for a reading that failed: the most frequent failure and the count."""
    kinds = [type(f) for f in failures]
    worst = max(set(kinds), key=kinds.count)
    last = next(f for f in reversed(failures) if type(f) is worst)
    error = worst if worst in (TargetLost, DuplicateMarker) else BadReading
    return error(f"{last} ({len(failures)} of {tried} frames failed)")


def open_tracker(spec: TrackerSpec | str, *, rig: Any = None, site: Any = None) -> ArucoTracker:
    """The camera tracker of ``aruco:SOURCE?...`` (unconnected). ``aruco:sim`` needs ``rig`` (the simulated
    rig made from this spec); a real source refuses one."""
    spec = spec if isinstance(spec, TrackerSpec) else TrackerSpec.parse(spec)
    if spec.backend != "aruco":
        raise SpecError(f"drivers.camera.tracker opens aruco: trackers only, got {str(spec)!r}")
    settings = parse_settings(spec, site)
    camera = None
    if settings.camera_file is not None:
        try:
            camera = read_intrinsics(settings.camera_file)
        except IntrinsicsError as exc:
            raise SpecError(f"tracker spec {str(spec)!r}: {exc}") from None
    if spec.target != "sim":
        if rig is not None:
            raise ValueError("a real camera cannot see a simulated robot: use aruco:sim with a mock robot")
        from drivers.camera.network import NetworkCamera
        from drivers.camera.sources import source_for

        assert camera is not None
        try:
            source = (NetworkCamera(spec.target, camera.width, camera.height)
                      if spec.target.startswith(("http://", "https://"))
                      else source_for(spec.target, camera.width, camera.height))
        except ValueError as exc:  # a network camera's URL that does not parse
            raise SpecError(f"tracker spec {str(spec)!r}: {exc}") from None
        if settings.latency and not hasattr(source, "start_frames"):
            raise spec_error(spec, f"option latency= is for a live camera ({source.description} replays frames)")
        return ArucoTracker(spec, settings, source, camera)
    if rig is None or getattr(rig, "tracker_spec", None) != spec:
        raise ValueError("aruco:sim renders the simulated robot: pass rig=SimulatedRig.from_spec(robot_spec, "
                         "tracker_spec, clock) made from this spec")
    from drivers.camera.renderer import Optics, SimulatedCamera

    sim = settings.sim
    if camera is None:
        camera = CameraIntrinsics.from_fov(sim["width"], sim["height"], sim["fov"], [sim["k1"], 0, 0, 0, 0])
    mount = np.eye(4)
    mount[:3, 3] = rig.truth.tool - settings.tp  # the target's centre, so that its TP is the rig's true TP
    optics = Optics(noise=sim["noise"], blur=sim["blur"], motion=sim["motion"])
    if settings.mount == "flange":
        from drivers.camera.flange_camera import CAMERA_MOUNT, SimulatedFlangeCamera

        flange = SimulatedFlangeCamera(rig, settings.target, camera, CAMERA_MOUNT, optics, sim["fps"], sim["latency"],
                                       sim["drop"], sim["lost"], sim["imperfections"], printed=sim["printed"])
        return ArucoTracker(spec, settings, flange, camera)
    source = SimulatedCamera(rig, settings.target, camera, mount, optics, sim["fps"], sim["latency"], sim["drop"],
                             sim["lost"], sim["imperfections"])
    return ArucoTracker(spec, settings, source, camera)
