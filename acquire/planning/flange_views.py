"""Poses for a camera on the flange that keep a fixed board in view (pure: arrays in, arrays out).

Frames (metres, radians): ``board`` is the board's pose in the robot's base frame (4x4, base <- board; the board
frame of drivers/camera/targets.py: origin at its centre, z out of the printed face); ``mount`` the camera's pose
in the flange (last DH) frame (4x4, flange <- camera; OpenCV's camera frame: z along the line of sight, x right,
y down in the image). A pose ``q`` sees the board (:func:`board_in_view`) when

- every corner of the board projects inside the image, ``margin`` (a share of the image's width) from its edges,
- the board lies in front of the camera between ``near`` and ``far`` m (the depth of field the user gives), and
- the line of sight to the board's centre is within ``max_angle`` of the board's normal (a pose measured at a
  grazing angle is poor: the corners' foreshortening, and the IPPE ambiguity near a fronto-parallel one is
  harmless, but beyond about 60° the marker corners blur into each other).

:func:`look_at` places the camera on a sphere about the board's centre; :func:`flange_view_poses` draws such
views (distance, tilt from the normal, azimuth, roll about the line of sight), solves each for the joints with the
nominal model (damped least squares from the home pose, within the limits) and keeps the ones that see the board.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from kinematics.dh import DHModel, frames_from_joints

Array = NDArray[np.float64]

OUT_OF_VIEW = "the board leaves the camera's image"
TOO_NEAR = "the board is nearer than the camera's near limit"
TOO_FAR = "the board is farther than the camera's far limit"
GRAZING = "the camera sees the board at too grazing an angle"
BEHIND = "the board is behind the camera"


@dataclass(frozen=True)
class FlangeCamera:
    """What decides whether the flange camera sees the board: ``matrix`` (3x3 pixels) and ``size`` (width, height)
    of the image, the board's printed ``extent`` (width, height, m), the depth range ``near``..``far`` (m), the
    largest angle between the line of sight and the board's normal ``max_angle`` (rad), and ``margin``: the share of
    the image width kept free at its edges."""

    matrix: Array
    size: tuple[int, int]
    extent: tuple[float, float]
    near: float = 0.25
    far: float = 0.8
    max_angle: float = math.radians(45.0)
    margin: float = 0.03


def board_in_view(model: DHModel, q: Array, mount: Array, board: Array, camera: FlangeCamera
                  ) -> tuple[NDArray[np.bool_], list[str]]:
    """(m,) whether the flange camera sees the whole board at each of ``q`` (m, n) (DH joint values), and the reason
    where it does not ("" where it does). ``model``'s base is the robot's base frame (its tool is not used)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    flange = frames_from_joints(model, q)[:, -1]  # base <- flange
    return board_seen(np.linalg.inv(flange @ np.asarray(mount, dtype=float)) @ np.asarray(board, dtype=float), camera)


def board_seen(to_camera: Array, camera: FlangeCamera) -> tuple[NDArray[np.bool_], list[str]]:
    """(m,) whether a camera sees the whole board at each of the poses ``to_camera`` (m, 4, 4, camera <- board) by the
    rules of the module docstring, and the reason where it does not ("" where it does). Either may be the one that
    moves: a camera on the flange (:func:`board_in_view`) or a board on the flange seen by a camera in the cell."""
    to_camera = np.asarray(to_camera, dtype=float).reshape(-1, 4, 4)
    w, h = camera.extent
    corners = np.array([[-w / 2, -h / 2, 0, 1], [w / 2, -h / 2, 0, 1], [w / 2, h / 2, 0, 1], [-w / 2, h / 2, 0, 1]])
    seen = np.einsum("mij,kj->mki", to_camera, corners)[..., :3]  # (m, 4, 3) camera frame
    centre = to_camera[:, :3, 3]
    ok, reasons = np.ones(len(to_camera), dtype=bool), [""] * len(to_camera)
    width, height = camera.size
    pad = camera.margin * width
    for k in range(len(to_camera)):
        depth = seen[k, :, 2]
        if np.any(depth <= 1e-6):
            ok[k], reasons[k] = False, BEHIND
            continue
        pixels = (camera.matrix @ (seen[k] / depth[:, None]).T).T[:, :2]
        cosine = float(-to_camera[k, :3, 2] @ centre[k] / np.linalg.norm(centre[k]))  # normal vs line of sight
        if centre[k, 2] < camera.near:
            ok[k], reasons[k] = False, TOO_NEAR
        elif centre[k, 2] > camera.far:
            ok[k], reasons[k] = False, TOO_FAR
        elif cosine < math.cos(camera.max_angle):
            ok[k], reasons[k] = False, GRAZING
        elif np.any(pixels < pad) or np.any(pixels[:, 0] > width - 1 - pad) or np.any(pixels[:, 1] > height - 1 - pad):
            ok[k], reasons[k] = False, OUT_OF_VIEW
    return ok, reasons


def look_at(board: Array, distance: float, tilt: float, azimuth: float, roll: float) -> Array:
    """The camera's pose in the base frame (4x4, base <- camera) ``distance`` m from the board's centre, its line of
    sight through that centre, tilted ``tilt`` rad from the board's normal towards the board's ``azimuth`` (rad,
    from its x axis), turned ``roll`` rad about the line of sight."""
    board = np.asarray(board, dtype=float)
    direction = np.array([math.sin(tilt) * math.cos(azimuth), math.sin(tilt) * math.sin(azimuth), math.cos(tilt)])
    z = -direction  # the camera looks back at the centre
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    local = np.eye(4)
    local[:3, :3] = np.column_stack([x, np.cross(z, x), z]) @ Rotation.from_rotvec([0, 0, roll]).as_matrix()
    local[:3, 3] = distance * direction
    return board @ local


def solve_joints(model: DHModel, flange: Array, seed: Array, limits: Array) -> tuple[Array, float]:
    """Joint values (n,) that put ``model``'s flange frame at ``flange`` (4x4, base frame), from ``seed`` within
    ``limits`` (n, 2), and the remaining error: position (m) plus orientation (rad) times 0.1 m."""
    target_r, target_p = flange[:3, :3], flange[:3, 3]

    def error(q: Array) -> Array:
        pose = frames_from_joints(model, q[None, :])[0, -1]
        turn = Rotation.from_matrix(pose[:3, :3] @ target_r.T).as_rotvec()
        return np.concatenate([pose[:3, 3] - target_p, 0.1 * turn])

    lo, hi = np.asarray(limits, dtype=float).T
    fit = least_squares(error, np.clip(seed, lo + 1e-9, hi - 1e-9), bounds=(lo, hi), xtol=1e-12, ftol=1e-12)
    return fit.x, float(np.linalg.norm(fit.fun))


def flange_view_poses(model: DHModel, home: Array, limits: Array, mount: Array, board: Array, camera: FlangeCamera,
                      count: int, rng: np.random.Generator, max_reach: float = math.pi) -> Array:
    """``count`` joint configurations (count, n) in which the flange camera sees the board from drawn views:
    distance uniform in the camera's depth range (inner 80 %), tilt up to ``camera.max_angle`` (uniform over the
    spherical cap), any azimuth, roll ±90°; each solved from ``home`` and kept when it sees the board, stays within
    ``max_reach`` rad of home in every joint and the solution is exact (1e-6). ValueError when too few are found."""
    out: list[Array] = []
    mount = np.asarray(mount, dtype=float)
    inverse_mount = np.linalg.inv(mount)
    span = camera.far - camera.near
    cap = 1.0 - math.cos(0.9 * camera.max_angle)
    for _ in range(50 * count):
        distance = camera.near + span * rng.uniform(0.1, 0.9)
        tilt = math.acos(1.0 - rng.uniform(0.0, cap))
        view = look_at(board, distance, tilt, rng.uniform(0, 2 * math.pi), rng.uniform(-math.pi / 2, math.pi / 2))
        q, miss = solve_joints(model, view @ inverse_mount, home, limits)
        if miss > 1e-6 or np.any(np.abs(q - home) > max_reach):
            continue
        if board_in_view(model, q[None, :], mount, board, camera)[0][0]:
            out.append(q)
            if len(out) == count:
                return np.array(out)
    raise ValueError(f"found only {len(out)} of {count} poses in which the flange camera sees the board")
