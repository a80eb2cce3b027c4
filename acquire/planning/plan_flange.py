"""The stop-and-go plan of a camera on the flange seeing a fixed board (``aruco:sim?...&mount=flange``).

Frames (metres, radians): the board's pose in the base frame is where the nominal model puts it when the camera, at
its nominal pose on the flange (``mount``: flange <- camera), sees it at home as the spec says (``distance`` m down
its line of sight, turned by ``tilt`` and ``roll``: drivers/camera/flange_camera.py ``facing_board``). The views
(acquire/planning/flange_views.py) keep the whole board in the image, between :data:`NEAR` and :data:`FAR` times the
home distance and within :data:`MAX_ANGLE` of the board's normal; each is solved with the nominal model.

The plan: a home step first and last (the drift check; both are fit rows), then ``site.free_poses`` fitted views and
``site.check_poses`` held-out ones (role ``check``), in nearest-neighbour order, one reading (``frames`` images) each.
With collision geometry the cell's tool capsule is the camera's body (flange origin to the camera's centre, radius
:data:`CAMERA_RADIUS`, unless the site file gives ``cell.tool_b``), and a view in contact is drawn again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from acquire.planning.flange_views import FlangeCamera, flange_view_poses
from acquire.planning.plan import HOME_SWEEP, PlanError, _nearest_order, _per_joint
from config.cell import cell_from_config, contact_at
from config.robots import RobotModel
from config.site import SiteConfig
from drivers.spec import TrackerSpec
from kinematics.dh import frames_from_joints
from session.plan import Plan, Step

Array = NDArray[np.float64]

NEAR, FAR = 2.0 / 3.0, 5.0 / 3.0  # the views' depth range, times the board's distance at home
MAX_ANGLE = math.radians(40.0)  # the largest angle between a view's line of sight and the board's normal
MARGIN = 0.04  # share of the image's width kept free at its edges
CAMERA_RADIUS = 0.04  # m: the camera's body as a capsule from the flange's origin to the camera's centre
BATCHES = 4  # draws of views before the plan is refused for want of collision-free ones


def is_flange_camera(spec: TrackerSpec | None) -> bool:
    """Whether ``spec`` is a camera on the flange (``aruco:...&mount=flange``)."""
    return spec is not None and spec.backend == "aruco" and spec.options.get("mount") == "flange"


@dataclass(frozen=True)
class FlangeSetup:
    """What the flange plan assumes: ``mount`` flange <- camera (4x4), ``board`` base <- board (4x4, nominal),
    ``camera`` the view test, ``distance`` m at home, ``frames`` images per reading, ``fps`` the camera's frame rate
    (Hz), ``scale_sigma`` the board's measured relative scale uncertainty (None: not measured), ``board_text``."""

    mount: Array
    board: Array
    camera: FlangeCamera
    distance: float
    frames: int
    fps: float
    scale_sigma: float | None
    board_text: str


def flange_setup(robot: RobotModel, spec: TrackerSpec, site: SiteConfig) -> FlangeSetup:
    """The :class:`FlangeSetup` of ``spec`` (SpecError for a bad spec; PlanError for a camera that is not ``sim``:
    a real camera's pose on the flange and the board's place are not known before the run)."""
    from drivers.camera.flange_camera import CAMERA_MOUNT, facing_board
    from drivers.camera.intrinsics import CameraIntrinsics
    from drivers.camera.tracker import parse_settings

    settings = parse_settings(spec, site)
    if spec.target != "sim":
        raise PlanError("acquire plans a flange camera's views for aruco:sim only: for a real camera the camera's "
                        "pose on the flange and the board's place are not known before the run (--probe reads them; "
                        "identify takes a '# sensor: flange' CSV)")
    sim = settings.sim
    intrinsics = CameraIntrinsics.from_fov(sim["width"], sim["height"], sim["fov"], [sim["k1"], 0, 0, 0, 0])
    distance = float(sim["distance"])
    facing = facing_board(distance, math.radians(sim["tilt"]), math.radians(sim["roll"]))
    at_home = frames_from_joints(robot.nominal, np.asarray(robot.home, dtype=float)[None])[0, -1]
    camera = FlangeCamera(intrinsics.matrix, (intrinsics.width, intrinsics.height), settings.target.extent,
                          near=NEAR * distance, far=FAR * distance, max_angle=MAX_ANGLE, margin=MARGIN)
    w, h = settings.target.extent
    return FlangeSetup(CAMERA_MOUNT, at_home @ CAMERA_MOUNT @ facing, camera, distance, settings.frames,
                       float(sim["fps"]), settings.scale_sigma,
                       f"{settings.target.kind} {w * 1e3:.0f} x {h * 1e3:.0f} mm")


def camera_site(site: SiteConfig, setup: FlangeSetup) -> SiteConfig:
    """``site`` with the camera's body as the cell's tool capsule (flange frame), unless the site file gives one."""
    if site.tool_b is not None:
        return site
    centre = tuple(float(x) for x in setup.mount[:3, 3])
    return site.with_overrides(tool_a=(0.0, 0.0, 0.0), tool_b=centre, tool_radius=max(site.tool_radius, CAMERA_RADIUS))


def build_flange_plan(robot: RobotModel, site: SiteConfig, setup: FlangeSetup, rng_seed: int = 0) -> Plan:
    """The plan (module docstring); ``site`` with the camera's body (:func:`camera_site`). PlanError when too few
    collision-free views are found."""
    home = np.asarray(robot.home, dtype=float)
    count = site.free_poses + site.check_poses
    if site.free_poses < 1:
        raise PlanError("a flange camera's plan needs at least one fitted view (--free-poses N)")
    rng = np.random.default_rng([rng_seed, 36])
    cell = cell_from_config(robot, site)
    notes = [f"flange camera: {count} views of the {setup.board_text} board, {setup.camera.near:.2f}-"
             f"{setup.camera.far:.2f} m from it, within {math.degrees(setup.camera.max_angle):.0f}° of its normal, "
             "the whole board in the image; board placed from the home view with the nominal model"]
    if cell is None:
        notes.append(f"{robot.name} has no collision geometry: the plan is checked against the joint limits only")
    else:
        notes.append(f"the camera's body: a capsule of radius {site.tool_radius * 1e3:.0f} mm from the flange to "
                     f"{[round(x, 3) for x in (site.tool_b or site.tp_guess)]} m (flange frame) in the cell model")
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


def flange_lines(plan: Plan, setup: FlangeSetup) -> list[str]:
    """The dry run's flange-camera section: views, images, what the run determines and how the scale is fixed."""
    views = sum(s.kind == "free" for s in plan.steps)
    held = sum(s.kind == "free" and s.role == "check" for s in plan.steps)
    readings = len(plan.steps) * plan.samples_per_step
    if setup.scale_sigma is None:
        scale = ("not measured (no square_sigma/size_sigma): the fitted lengths are checked against the robot "
                 "model's; a misprint beyond their tolerance fails the result")
    else:
        scale = f"measured: relative uncertainty {setup.scale_sigma:.2g}, added to the stated accuracy"
    return ["flange camera (aruco, mount=flange):",
            f"  board: {setup.board_text}, {setup.distance:g} m down the line of sight at home",
            f"  views: {views} ({views - held} fitted, {held} held out) + {len(plan.steps) - views} at home",
            f"  images: {readings * setup.frames} ({readings} readings x {setup.frames} frames at {setup.fps:g} Hz)",
            "  determines: the DH parameters, the camera's pose on the flange and the board's pose in the base "
            "frame, in one fit",
            f"  scale: {scale}",
            "  accuracy: stated by the result (flange_accuracy_rms, the flange's position over the fit poses); not "
            "predicted here (docs/benchmarks.md, section 24: 0.08-0.15 mm RMS over the workspace from 40 views of an "
            "A4 board with a 1280x720 camera)"]


def flange_json(plan: Plan, setup: FlangeSetup) -> dict[str, object]:
    """The JSON form of :func:`flange_lines` (``acquire --dry-run --json``): counts, metres, Hz."""
    views = [s for s in plan.steps if s.kind == "free"]
    readings = len(plan.steps) * plan.samples_per_step
    return {"views": len(views), "held_out": sum(s.role == "check" for s in views), "readings": readings,
            "images": readings * setup.frames, "frames_per_reading": setup.frames, "fps": setup.fps,
            "distance_m": setup.distance, "near_m": setup.camera.near, "far_m": setup.camera.far,
            "max_angle_rad": setup.camera.max_angle, "scale_sigma": setup.scale_sigma,
            "determines": ["dh", "sensor_frame", "target"]}
