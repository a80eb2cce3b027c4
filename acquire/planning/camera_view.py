"""Which poses a camera tracker can see (pure): the target must face the camera and stay in its view.

A camera cell (``aruco:`` trackers) gives ``cell.camera_pose`` in the site file: the camera's frame in the
robot's base frame (4x4, m; OpenCV convention: the camera looks along its +z), or a result YAML of an earlier
session with this camera, whose ``base`` (camera frame ← robot base) is inverted. For a configuration ``q``
the target's centre is the TP guess and its face normal ``cell.target_normal`` (flange frame, default +z: a
target on the flange face). It is seen when

- the direction from the camera to the TP is within ``half_fov`` (rad) of the camera's axis, and
- the target faces the camera: its normal within ``max_tilt`` (rad) of the direction to the camera.

:func:`visible` answers for many configurations at once, with a reason for each one that is not.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from kinematics.dh import DHModel, frames_from_joints

Array = NDArray[np.float64]

FACES_AWAY = "the target faces away from the camera"
OUT_OF_VIEW = "the target leaves the camera's view"


def visible(model: DHModel, q: Array, camera_pose: Array, target_normal: Array, half_fov: float,
            max_tilt: float) -> tuple[NDArray[np.bool_], list[str]]:
    """(m,) whether the camera sees the target at each configuration of ``q`` (m, n), and per configuration the
    reason it does not ("" when it does). ``model.tool`` is the target's centre in the flange frame (m);
    ``camera_pose`` base frame ← camera frame; angles in rad."""
    frames = frames_from_joints(model, np.atleast_2d(np.asarray(q, dtype=float)))
    flange = frames[:, -1]
    centre = flange[:, :3, :3] @ model.tool + flange[:, :3, 3]
    normal = flange[:, :3, :3] @ (np.asarray(target_normal, dtype=float) / np.linalg.norm(target_normal))
    camera, axis = camera_pose[:3, 3], camera_pose[:3, 2]
    sight = centre - camera
    sight /= np.linalg.norm(sight, axis=1, keepdims=True)
    in_view = sight @ axis >= np.cos(half_fov)
    facing = np.einsum("mi,mi->m", normal, -sight) >= np.cos(max_tilt)
    reasons = ["" if f and v else (FACES_AWAY if not f else OUT_OF_VIEW)
               for f, v in zip(facing, in_view, strict=True)]
    return facing & in_view, reasons


def camera_from_base(base: Array) -> Array:
    """The camera's pose in the robot's base frame from a result's ``base`` (camera frame ← robot base)."""
    base = np.asarray(base, dtype=float)
    out = np.eye(4)
    out[:3, :3] = base[:3, :3].T
    out[:3, 3] = -base[:3, :3].T @ base[:3, 3]
    return out
