"""The stop-and-go plan of a camera on the flange seeing a fixed board (``aruco:SOURCE?...&mount=flange``).

Frames (metres, radians). Where the camera sits on the flange (``mount``: flange <- camera) and where the board lies
(``board``: base <- board) come from the locate phase (acquire/planning/flange_locate.py: measured from the start
pose the operator jogged the arm to, about which the plan is built; :func:`located_setup`), for a real camera and
the simulated one alike (the simulation's true mount is never read here). Before it, for the dry run only, they are
the operator's rough mount (``--camera-mount``) and a board ``distance`` m down its line of sight at home (the
simulation's ``distance``, ``tilt`` and ``roll``; :data:`ASSUMED_DISTANCE` for a real camera): an indicative plan.
The views (acquire/planning/flange_views.py) keep the whole board in the image (the margin widened by the located
pointing error, 3 sigma), between :data:`NEAR` and :data:`FAR` times the start distance and within :data:`MAX_ANGLE`
of the board's normal; each is solved with the nominal model.

The plan: the start pose first and last (the drift check; both are fit rows), then ``site.free_poses`` fitted views
and ``site.check_poses`` held-out ones (role ``check``), in nearest-neighbour order, one reading (``frames`` images)
each. With collision geometry the cell's tool capsule is the camera's body (flange origin to the camera's centre,
radius :data:`CAMERA_RADIUS`, plus the rough mount's tolerance for the locate moves, unless the site file gives
``cell.tool_b``) and the camera's cable (``cell.cable`` in the site file: capsules fixed to the links) is in the cell
model; a view in contact is drawn again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from acquire.planning.flange_bound import DRY_SIGMA_PX, flange_bound
from acquire.planning.flange_locate import LAST_TURN, WRIST_TURN, Located, RoughMount
from acquire.planning.flange_views import FlangeCamera, flange_view_poses
from acquire.planning.plan import HOME_SWEEP, PlanError, _nearest_order, _per_joint
from config.cell import cell_from_config, contact_at
from config.robots import RobotModel
from config.site import SiteConfig
from drivers.spec import TrackerSpec
from kinematics.dh import frames_from_joints
from session.plan import Plan, Step

Array = NDArray[np.float64]

NEAR, FAR = 2.0 / 3.0, 5.0 / 3.0  # the views' depth range, times the board's distance at the start pose
MAX_ANGLE = math.radians(40.0)  # the largest angle between a view's line of sight and the board's normal
MARGIN = 0.04  # share of the image's width kept free at its edges (before the located pointing error)
CAMERA_RADIUS = 0.04  # m: the camera's body as a capsule from the flange's origin to the camera's centre
BATCHES = 4  # draws of views before the plan is refused for want of collision-free ones
ASSUMED_DISTANCE = 0.45  # m: a real camera's board down its line of sight at home, for the dry run's indicative plan
ASSUMED_FPS = 30.0  # Hz: a real camera's frame rate for the duration estimate (the simulation's is its ``fps``)


def is_flange_camera(spec: TrackerSpec | None) -> bool:
    """Whether ``spec`` is a camera on the flange (``aruco:...&mount=flange``)."""
    return spec is not None and spec.backend == "aruco" and spec.options.get("mount") == "flange"


@dataclass(frozen=True)
class FlangeSetup:
    """What the flange plan assumes: ``mount`` flange <- camera (4x4), ``board`` base <- board (4x4), ``camera`` the
    view test, ``distance`` m at the start pose, ``frames`` images per reading, ``fps`` the camera's frame rate
    (Hz), ``scale_sigma`` the board's measured relative scale uncertainty (None: not measured), ``board_text``,
    ``rough`` the operator's rough mount, ``start`` (n,) the start pose (DH values; None: the robot's home) and
    ``located`` the locate phase's result (None: the dry run's indicative setup from the rough mount), ``points``
    (M, 3) the board's corners (board frame, m) and ``sigma_px`` the corner noise (pixels) the accuracy is predicted
    with (acquire/planning/flange_bound.py: the locate's readings give it; before them it is assumed), ``latency``
    s the camera's ``latency=`` (a stop-and-go reading waits it out before its first frame; 0 when not given: a
    network camera's measured one is only known once connected)."""

    mount: Array
    board: Array
    camera: FlangeCamera
    distance: float
    frames: int
    fps: float
    scale_sigma: float | None
    board_text: str
    rough: RoughMount
    points: Array
    start: Array | None = None
    located: Located | None = None
    sigma_px: float = DRY_SIGMA_PX
    latency: float = 0.0

    @property
    def reading_seconds(self) -> float:
        """A reading's time at the stopped arm (s): the latency waited out, then its frames at the frame rate."""
        return self.latency + self.frames / self.fps


def flange_setup(robot: RobotModel, spec: TrackerSpec, site: SiteConfig, rough: RoughMount) -> FlangeSetup:
    """The dry run's :class:`FlangeSetup` of ``spec`` from the ``rough`` mount (module docstring); SpecError for a
    bad spec, InputError/ValueError for a real camera's unreadable intrinsics file."""
    from drivers.camera.flange_camera import facing_board
    from drivers.camera.intrinsics import CameraIntrinsics, read_intrinsics
    from drivers.camera.tracker import parse_settings

    settings = parse_settings(spec, site)
    sim = settings.sim
    if spec.target == "sim":
        intrinsics = CameraIntrinsics.from_fov(sim["width"], sim["height"], sim["fov"], [sim["k1"], 0, 0, 0, 0])
        distance, fps = float(sim["distance"]), float(sim["fps"])
        facing = facing_board(distance, math.radians(sim["tilt"]), math.radians(sim["roll"]))
    else:
        assert settings.camera_file is not None  # parse_settings requires it for a real camera
        intrinsics = read_intrinsics(settings.camera_file)
        distance, fps = ASSUMED_DISTANCE, ASSUMED_FPS
        facing = facing_board(distance)
    at_home = frames_from_joints(robot.nominal, np.asarray(robot.home, dtype=float)[None])[0, -1]
    w, h = settings.target.extent
    return FlangeSetup(rough.mount, at_home @ rough.mount @ facing, _view_test(intrinsics.matrix, intrinsics.size,
                       settings.target.extent, distance, MARGIN), distance, settings.frames, fps,
                       settings.scale_sigma, f"{settings.target.kind} {w * 1e3:.0f} x {h * 1e3:.0f} mm", rough,
                       _corner_points(settings.target), latency=settings.latency or 0.0)


def _corner_points(target: Any) -> Array:
    """(M, 3) the points the camera measures the board by (board frame, m): a ChArUco's chessboard corners, else
    the markers' corners."""
    if target.kind == "charuco":
        return np.asarray(target.charuco_points(), dtype=float)
    return np.vstack([np.asarray(c, dtype=float) for c in target.corners.values()])


def _view_test(matrix: Array, size: tuple[int, int], extent: tuple[float, float], distance: float,
               margin: float) -> FlangeCamera:
    return FlangeCamera(matrix, size, extent, near=NEAR * distance, far=FAR * distance, max_angle=MAX_ANGLE,
                        margin=margin)


def located_setup(setup: FlangeSetup, located: Located, start: Array, sigma_px: float) -> FlangeSetup:
    """``setup`` with the located mount and board, the views about ``start`` (DH values) at the located distance,
    the image's margin widened by 3 sigma of the located pointing error (pixels over the image's width), the
    accuracy predicted with the corner noise ``sigma_px`` the locate's readings stated."""
    camera = setup.camera
    margin = MARGIN + 3 * located.pointing() * float(camera.matrix[0, 0]) / camera.size[0]
    return replace(setup, mount=located.mount, board=located.board, distance=located.distance,
                   camera=_view_test(camera.matrix, camera.size, camera.extent, located.distance, margin),
                   start=np.asarray(start, dtype=float), located=located, sigma_px=sigma_px)


def recorded_setup(setup: FlangeSetup, config: dict[str, Any], plan: Plan) -> FlangeSetup:
    """A resumed session's setup: the mount and board its locate phase found (``config["flange_locate"]``), about
    its plan's start pose; ``setup`` about that pose when the session has no record of a locate."""
    record = config.get("flange_locate")
    if not record:
        return replace(setup, start=np.asarray(plan.home, dtype=float))
    fields = {k: v for k, v in record.items() if k != "sigma_px"}
    located = Located(**{k: np.array(v) if k in ("mount", "board") else v for k, v in _unrecorded(fields).items()})
    return located_setup(setup, located, np.asarray(plan.home, dtype=float), float(record["sigma_px"]))


def _unrecorded(record: dict[str, Any]) -> dict[str, Any]:
    """:meth:`Located.as_dict`'s keys back to :class:`Located`'s fields."""
    names = {"mount_sigma_m": "mount_position", "mount_sigma_rad": "mount_angle", "board_sigma_m": "board_position",
             "board_sigma_rad": "board_angle", "rms_m": "rms_position", "rms_rad": "rms_angle",
             "distance_m": "distance"}
    return {names.get(k, k): v for k, v in record.items()}


def camera_site(site: SiteConfig, setup: FlangeSetup, tolerance: float = 0.0) -> SiteConfig:
    """``site`` with the camera's body as the cell's tool capsule (flange frame), unless the site file gives one;
    its radius grown by ``tolerance`` m (the rough mount's, for the locate moves)."""
    if site.tool_b is not None:
        return site
    centre = tuple(float(x) for x in setup.mount[:3, 3])
    radius = CAMERA_RADIUS + tolerance
    return site.with_overrides(tool_a=(0.0, 0.0, 0.0), tool_b=centre, tool_radius=max(site.tool_radius, radius))


def build_flange_plan(robot: RobotModel, site: SiteConfig, setup: FlangeSetup, rng_seed: int = 0) -> Plan:
    """The plan (module docstring); ``site`` with the camera's body (:func:`camera_site`). PlanError when too few
    collision-free views are found."""
    home = np.asarray(robot.home if setup.start is None else setup.start, dtype=float)
    count = site.free_poses + site.check_poses
    if site.free_poses < 1:
        raise PlanError("a flange camera's plan needs at least one fitted view (--free-poses N)")
    rng = np.random.default_rng([rng_seed, 36])
    cell = cell_from_config(robot, site)
    notes = [f"flange camera: {count} views of the {setup.board_text} board, {setup.camera.near:.2f}-"
             f"{setup.camera.far:.2f} m from it, within {math.degrees(setup.camera.max_angle):.0f}° of its normal, "
             "the whole board in the image, about the start pose; "
             + ("mount and board located by the locate phase" if setup.located is not None else
                "indicative: mount and board assumed from the rough mount (the run plans from the locate phase)")]
    if cell is None:
        notes.append(f"{robot.name} has no collision geometry: the plan is checked against the joint limits only")
    else:
        notes.append(f"the camera's body: a capsule of radius {site.tool_radius * 1e3:.0f} mm from the flange to "
                     f"{[round(x, 3) for x in (site.tool_b or site.tp_guess)]} m (flange frame) in the cell model")
        notes.append(f"the camera's cable: {len(site.cable)} capsule(s) of radius up to "
                     f"{max(c['radius'] for c in site.cable) * 1e3:.0f} mm along the links (cell.cable)" if site.cable
                     else "the camera's cable is not in the cell model (cell.cable in the site file)")
    views: list[Array] = []
    drawn = 0
    for _ in range(BATCHES):
        try:
            batch = flange_view_poses(robot.nominal, home, robot.limits, setup.mount, setup.board, setup.camera,
                                      count, rng)
        except ValueError as exc:
            raise PlanError(f"flange camera: {exc} (place the board farther: distance=, or allow more joint range)"
                            ) from None
        drawn += len(batch)
        views += [q for q in batch if cell is None or contact_at(cell, q) is None]
        if len(views) >= count:
            break
    if len(views) < count:
        raise PlanError(f"flange camera: only {len(views)} of {drawn} views drawn are clear of the cell")
    if drawn > count:
        notes.append(f"{drawn - len(views)} drawn views in contact with the cell were replaced")
    roles = ["fit"] * site.free_poses + ["check"] * site.check_poses
    speed, acceleration = _per_joint(robot, site, "speed"), _per_joint(robot, site, "acceleration")
    ordered = _nearest_order(list(zip(views[:count], roles, strict=True)), home, speed)
    poses = [("home", HOME_SWEEP, home, "fit")]
    poses += [("free", k, q, role) for k, (q, role) in enumerate(ordered, start=1)]
    poses.append(("home", HOME_SWEEP, home, "fit"))
    steps = tuple(Step(i, kind, sweep, 0, tuple(float(x) for x in q), role)
                  for i, (kind, sweep, q, role) in enumerate(poses))
    return Plan(robot.name, robot.joint_types, tuple(float(x) for x in home), steps, 1, site.settle_time,
                tuple(float(x) for x in speed), tuple(float(x) for x in acceleration), tuple(notes))


def flange_accuracy(robot: RobotModel, plan: Plan, setup: FlangeSetup) -> dict[str, float]:
    """The bound of the flange's position at the plan's fitted views (acquire/planning/flange_bound.py)."""
    q = np.array([s.q for s in plan.steps if s.role == "fit"])
    return flange_bound(robot.nominal, setup.mount, setup.board, q, setup.points, setup.camera.matrix,
                        setup.sigma_px, setup.frames, robot.limits)


def locate_seconds(robot: RobotModel, site: SiteConfig, setup: FlangeSetup) -> float:
    """The locate phase's robot time (s) about home: its moves, settling and frames (the run's is about the start)."""
    from acquire.planning.flange_locate import locate_plan
    from acquire.planning.plan import estimate_duration

    plan = locate_plan(robot, site, np.asarray(robot.home, dtype=float))
    return estimate_duration(plan, robot, setup.reading_seconds) + estimate_duration(
        replace(plan, steps=plan.steps[:1], home=plan.steps[-1].q), robot, 0.0)  # and back to the start


def flange_lines(plan: Plan, setup: FlangeSetup, accuracy: dict[str, float] | None = None,
                 locate: float | None = None) -> list[str]:
    """The dry run's flange-camera section: views, images, what the run determines, how the scale is fixed, the
    predicted accuracy (``accuracy``: :func:`flange_accuracy`) and the locate phase's robot time (``locate`` s:
    :func:`locate_seconds`; None once located)."""
    views = sum(s.kind == "free" for s in plan.steps)
    held = sum(s.kind == "free" and s.role == "check" for s in plan.steps)
    readings = len(plan.steps) * plan.samples_per_step
    if setup.scale_sigma is None:
        scale = ("not measured (no square_sigma/size_sigma): the fitted lengths are checked against the robot "
                 "model's; a misprint beyond their tolerance fails the result")
    else:
        scale = f"measured: relative uncertainty {setup.scale_sigma:.2g}, added to the stated accuracy"
    where = ("the start pose" if setup.start is not None else "home")
    lines = ["flange camera (aruco, mount=flange):",
             f"  board: {setup.board_text}, {setup.distance:.3g} m down the line of sight at {where}",
             f"  views: {views} ({views - held} fitted, {held} held out) + {len(plan.steps) - views} at {where}",
             f"  images: {readings * setup.frames} ({readings} readings x {setup.frames} frames at {setup.fps:g} Hz"
             + (f", each after a {setup.latency:g} s latency" if setup.latency > 0 else "") + ")",
             "  determines: the DH parameters, the camera's pose on the flange and the board's pose in the base "
             "frame, in one fit",
             f"  scale: {scale}"]
    if accuracy is not None:
        noise = (f"corner noise {setup.sigma_px:.3g} px, from the locate's readings" if setup.located is not None
                 else f"corner noise {setup.sigma_px:.3g} px assumed (the run predicts again from the locate's "
                 "readings)")
        lines.append(f"  accuracy (Cramér-Rao bound, the camera's noise only: {noise}; view sigmas "
                     f"{accuracy['sigma_median'] * 1e3:.3f} mm, {accuracy['sigma_r_median'] * 1e3:.3f} mrad median): "
                     f"the flange to {accuracy['fit_rms'] * 1e3:.3f} mm RMS at the fitted views, "
                     f"{accuracy['random_rms'] * 1e3:.3f} mm at {accuracy['eval_poses']:.0f} random poses over the "
                     "joint ranges; the arm's departures from its DH model and the board's own errors add to it")
    if setup.located is None:
        lines.append("  the views shown are indicative: the run first locates the camera's mount and the board "
                     f"(readings at the start pose and with each wrist joint turned ±{math.degrees(WRIST_TURN):.0f}°, "
                     f"the last ±{math.degrees(LAST_TURN):.0f}°, shown and confirmed; the mount given to "
                     f"{setup.rough.position * 1e3:.0f} mm, {math.degrees(setup.rough.angle):.0f}°), then plans and "
                     "shows the views"
                     + ("" if locate is None else f"; the locate adds about {locate:.0f} s of robot time"))
    return lines


def flange_json(plan: Plan, setup: FlangeSetup, accuracy: dict[str, float] | None = None) -> dict[str, object]:
    """The JSON form of :func:`flange_lines` (``acquire --dry-run --json``): counts, metres, Hz."""
    views = [s for s in plan.steps if s.kind == "free"]
    readings = len(plan.steps) * plan.samples_per_step
    return {"views": len(views), "held_out": sum(s.role == "check" for s in views), "readings": readings,
            "images": readings * setup.frames, "frames_per_reading": setup.frames, "fps": setup.fps,
            "distance_m": setup.distance, "near_m": setup.camera.near, "far_m": setup.camera.far,
            "max_angle_rad": setup.camera.max_angle, "scale_sigma": setup.scale_sigma,
            "determines": ["dh", "sensor_frame", "target"], "accuracy": accuracy,
            "located": None if setup.located is None else located_record(setup)}


def located_record(setup: FlangeSetup) -> dict[str, Any]:
    """What the session records of the locate phase (``config["flange_locate"]``; :func:`recorded_setup` reads it)."""
    assert setup.located is not None
    return {**setup.located.as_dict(), "sigma_px": setup.sigma_px}
