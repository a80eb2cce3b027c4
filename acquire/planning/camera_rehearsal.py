"""What a dry run with a camera tracker (``aruco:``) assumes, and what it expects to lose.

A camera is not a laser tracker: its error is set by the corner noise in pixels, the target's size and its
distance (depth error grows with the square of the distance), and it sees the target only while the target is
in its view and faces it. :func:`camera_assumptions` states, for a stop-and-go plan:

- **the camera's pose** in the robot's base frame: the site file's ``cell.camera_pose``; for ``aruco:sim`` the
  simulated camera's own placement (the TP ``distance`` m down the camera's axis at home, turned by ``tilt`` and
  ``roll``, as :func:`drivers.sim.rig.facing_flange` places it); for a real camera without ``cell.camera_pose``
  it is unknown, and the steps the camera will miss cannot be told in advance;
- **the camera's noise** per axis per reading (m): the TP covariance of the target's pose (``Pose.point_covariance``)
  at every step expected to be seen (the home view when the pose is unknown), for independent corners with the
  noise of :data:`CORNER_NOISE_PX`, as the RMS over x, y, z (the readings' own ``sigma`` convention) divided by
  √frames, then the RMS over the steps. It errs high: with the README's camera example it predicts 0.063 mm where
  the recorded readings' sigma is 0.051 mm RMS, and 2.8x their sigma at the home view, where the edge fits' corners
  on a large frontal marker are better than 0.03 px (tests/acquire/test_camera_rehearsal.py);
- **the steps it expects to lose**: those where the target faces away (beyond ``cell.camera_max_tilt``) or leaves
  the view (the simulated camera's own field of view, else ``cell.camera_half_fov``), counted by kind and reason.
  The predicted accuracy is then computed on the steps expected to be recorded.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from acquire.planning.camera_view import visible
from acquire.planning.plan import tp_model
from config.robots import RobotModel
from config.site import SiteConfig
from drivers.spec import TrackerSpec
from kinematics.dh import frames_from_joints
from session.plan import Plan

Array = NDArray[np.float64]

#: corner noise (pixels per coordinate) assumed per corner refinement method: measured on renders with 2 grey
#: levels of noise (docs/benchmarks.md, ArUco camera tracker): ``edges`` 0.02-0.03 px, ``apriltag`` 0.07-0.12 px,
#: ``subpix`` 0.1-0.2 px, ``none`` and ``contour`` 0.5-0.7 px (biased inwards; taken as noise here)
CORNER_NOISE_PX = {"edges": 0.03, "apriltag": 0.12, "subpix": 0.2, "contour": 0.7, "none": 0.7}
UNKNOWN_DISTANCE = 1.0  # m: the camera-to-target distance assumed for the noise when the camera's pose is unknown


@dataclass(frozen=True)
class CameraAssumptions:
    """What the dry run assumes about a camera: ``pose`` base frame ← camera frame (4x4, m; None: unknown) and
    where it comes from; ``noise`` m per axis per reading and how it was found; ``lost`` the plan indices
    expected not to be seen, with ``reasons`` (index -> why)."""

    pose: Array | None
    pose_source: str
    noise: float
    noise_source: str
    distance: float
    lost: tuple[int, ...] = ()
    reasons: dict[int, str] = field(default_factory=dict)

    def seen_plan(self, plan: Plan) -> Plan:
        """``plan`` without the steps expected to be lost (what the accuracy is predicted from)."""
        lost = set(self.lost)
        return replace(plan, steps=tuple(s for s in plan.steps if s.index not in lost))

    def lines(self, plan: Plan) -> list[str]:
        """The dry run's camera section."""
        out = ["camera (aruco):", f"  pose: {self.pose_source}",
               f"  noise: {self.noise * 1e3:.4g} mm per axis per reading ({self.noise_source})"]
        if self.pose is None:
            out.append("  steps expected to be lost: unknown: every step is attempted; a step where the target faces "
                       "away or leaves the view is recorded missing and tried once more at the end, and the "
                       "predicted accuracy above assumes every step is seen; give cell.camera_pose to leave such "
                       "steps out of the plan and count them")
            return out
        total = len(plan.steps)
        if not self.lost:
            out.append(f"  steps expected to be lost: none of {total} (every step in view, facing the camera)")
            return out
        kinds = Counter(_kind(plan, i) for i in self.lost)
        why = Counter(self.reasons[i] for i in self.lost)
        out.append(f"  steps expected to be lost: {len(self.lost)} of {total} ({100 * len(self.lost) / total:.0f} %; "
                   + ", ".join(f"{n} {k}" for k, n in kinds.items()) + "): "
                   + "; ".join(f"{r} ({n})" for r, n in why.items())
                   + "; recorded missing, tried once more at the end; the predicted accuracy above is without them"
                   + ("" if self.pose_source.startswith("cell.camera_pose") else
                      "; give cell.camera_pose to leave them out of the plan"))
        return out

    def as_dict(self, plan: Plan) -> dict[str, object]:
        """The JSON form (``acquire --dry-run --json``): metres, plan indices."""
        return {"pose_known": self.pose is not None, "pose_source": self.pose_source, "noise_m": self.noise,
                "noise_source": self.noise_source, "distance_m": self.distance,
                "lost_steps": None if self.pose is None else list(self.lost), "planned_steps": len(plan.steps)}


def _kind(plan: Plan, index: int) -> str:
    step = plan.steps[index]
    if step.kind == "free":
        return "check poses" if step.role == "check" else "free poses"
    return {"sweep": "sweep steps", "home": "home checks"}.get(step.kind, step.kind)


def camera_assumptions(plan: Plan, robot: RobotModel, site: SiteConfig, spec: TrackerSpec,
                       noise: float | None = None) -> CameraAssumptions:
    """The camera's pose, noise and expected losses for ``plan`` (see the module docstring); ``noise`` (m per
    axis per reading) when the operator gave one (``--noise``), else predicted from the camera. SpecError for a
    bad spec; IntrinsicsError for a bad intrinsics file."""
    from drivers.camera.intrinsics import CameraIntrinsics, read_intrinsics
    from drivers.camera.tracker import parse_settings, rig_settings
    from drivers.sim.rig import facing_flange

    settings = parse_settings(spec, site)
    model = tp_model(robot, site.tp_guess)
    home = np.asarray(plan.home, dtype=float)
    at_home = frames_from_joints(model, home[None, :])[0, -1]  # base <- flange
    half_fov = site.camera_half_fov
    if spec.target == "sim":
        sim = settings.sim
        camera = CameraIntrinsics.from_fov(sim["width"], sim["height"], sim["fov"], [sim["k1"], 0, 0, 0, 0])
        distance, tilt, roll = rig_settings(spec)[2]
        pose = at_home @ np.linalg.inv(facing_flange(model.tool, distance, tilt, roll))
        f = camera.matrix[0, 0]
        half_fov = math.atan(min(camera.width, camera.height) / 2 / f)  # the image's narrower half-angle
        source = (f"the simulated camera's: the TP {distance:g} m down its axis at home, tilt {math.degrees(tilt):g}°, "
                  f"roll {math.degrees(roll):g}°; field of view ±{math.degrees(half_fov):.0f}°")
    else:
        camera = read_intrinsics(settings.camera_file) if settings.camera_file is not None else None
        pose = None if site.camera_pose is None else np.array(site.camera_pose, dtype=float)
        distance = UNKNOWN_DISTANCE
        source = ("unknown (no cell.camera_pose in the site file): the noise assumes the target faces the camera "
                  f"at {UNKNOWN_DISTANCE:g} m")
    if site.camera_pose is not None:
        pose = np.array(site.camera_pose, dtype=float)
        half_fov = site.camera_half_fov
        source = f"cell.camera_pose from the site file; field of view ±{math.degrees(half_fov):.0f}°"
    if pose is not None:
        distance = float(np.linalg.norm(at_home[:3, :3] @ model.tool + at_home[:3, 3] - pose[:3, 3]))
    lost: tuple[int, ...] = ()
    reasons: dict[int, str] = {}
    q = np.array([s.q for s in plan.steps], dtype=float).reshape(-1, len(plan.home))
    if pose is not None and len(q):
        seen, why = visible(model, q, pose, np.array(site.target_normal), half_fov, site.camera_max_tilt)
        lost = tuple(s.index for s, ok in zip(plan.steps, seen, strict=True) if not ok)
        reasons = {s.index: r for s, r in zip(plan.steps, why, strict=True) if r}
        q = q[seen]
    if noise is not None:
        how = "--noise"
    elif camera is None:
        raise ValueError("the camera's noise needs its intrinsics (camera=FILE) or --noise")
    else:
        mount = np.eye(4)
        mount[:3, 3] = model.tool - settings.tp  # flange frame <- target frame: the target's TP is the TP guess
        if pose is not None and len(q):  # camera <- target at every step expected to be seen
            views = np.linalg.inv(pose) @ frames_from_joints(model, q)[:, -1] @ mount
        else:
            views = (facing_flange(model.tool, distance, 0.0, 0.0) @ mount)[None]
        px = CORNER_NOISE_PX[settings.refine]
        sigmas = [_point_sigma(settings.target.corners, v, settings.tp, camera, px) for v in views]
        noise = math.sqrt(float(np.mean(np.square(sigmas)))) / math.sqrt(settings.frames)
        corner = f"{px:g} px corner noise (independent corners)"
        how = (f"RMS over the {'steps expected to be seen' if pose is not None else 'home view'}, "
               f"{corner} for refine={settings.refine}, {settings.frames} frames per reading; "
               "the depth error is several times the lateral")
    return CameraAssumptions(pose, source, float(noise), how, distance, lost, reasons)


def _point_sigma(corners: dict[int, Array], view: Array, tp: Array, camera, sigma_px: float) -> float:
    """RMS over x, y, z (m) of the standard uncertainty of the TP (``tp``, target frame) from one frame: the
    target's corners (target frame, m) seen at ``view`` (camera frame ← target frame) with independent corner
    noise ``sigma_px`` per coordinate."""
    import cv2

    from drivers.camera.pose import Pose

    points = np.concatenate(list(corners.values())).astype(float)
    rotation = view[:3, :3]
    translation = view[:3, 3]
    rvec = cv2.Rodrigues(rotation)[0]
    _, jac = cv2.projectPoints(points, rvec, translation, camera.matrix, camera.distortion)
    pose = Pose(rotation, translation, sigma_px, len(points), jac[:, :6])
    cov = pose.point_covariance(np.asarray(tp, dtype=float), sigma_px)
    return math.sqrt(float(np.trace(cov)) / 3)
