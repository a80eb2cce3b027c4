"""A camera on the flange seeing a board fixed in the cell (``aruco:SOURCE?...&mount=flange``, eye-in-hand).

The readings are the board's pose in the camera's frame (the tracker's own readings: drivers/camera/tracker.py);
the session records ``sensor: flange`` with them, and identify turns them round (identify/sensors/flange.py): one
fit gives the arm's DH parameters, the camera's pose on the flange and the board's pose in the base frame.

The length scale: a camera measures in units of its board. ``square_sigma`` (ChArUco) or ``size_sigma`` (a grid
or a marker), metres, say that the board was measured (``square=``/``size=`` is then the caliper's value, e.g. ten
squares measured across and divided by ten) and how well: the relative uncertainty ``square_sigma / square`` is
recorded as the session's scale reference. Without it the board's print is unverified (0.1-0.5 % off is common)
and identify checks the scale against the robot's nominal lengths (identify/sensors/scale.py).

Simulated (``aruco:sim?mount=flange``, mock robots only): the camera sits on the flange at :data:`CAMERA_MOUNT`
and the rig places the board (:meth:`drivers.sim.rig.SimulatedRig.face_board`): at the home pose it lies
``distance`` m down the camera's line of sight, facing it, turned by ``tilt`` about the camera's x axis and by
``roll`` about its line of sight (the rig's "tracker frame" is the board's). ``printed`` (default 1) is the true
board's size over the declared one: the camera renders the true board, the detection uses the declared one (a
misprint the fit cannot see by itself). Frames and
units: metres, radians; 4x4 transforms ``A <- B``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivers.camera.renderer import SimulatedCamera

Array = NDArray[np.float64]

MOUNTS = ("cell", "flange")
#: flange <- camera of the simulated camera: its line of sight along the flange's z axis, its centre 60 mm off the
#: flange's axis and 40 mm in front of the flange, turned 90° about it (a typical wrist-camera bracket)
CAMERA_MOUNT = np.array([[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, -0.06], [0.0, 0.0, 1.0, 0.04], [0.0, 0.0, 0.0, 1.0]])


def facing_board(distance: float, tilt: float = 0.0, roll: float = 0.0) -> Array:
    """Camera <- board (4x4) of a board ``distance`` m down the camera's line of sight, its printed face towards the
    camera, turned by ``tilt`` rad about the camera's x axis and then ``roll`` rad about its z axis."""
    cr, sr, ct, st = math.cos(roll), math.sin(roll), math.cos(tilt), math.sin(tilt)
    turn = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]]) @ np.array([[1, 0, 0], [0, ct, -st], [0, st, ct]])
    out = np.eye(4)
    out[:3, :3] = turn @ np.diag([1.0, -1.0, -1.0])  # the board's z (out of the print) back at the camera
    out[:3, 3] = [0.0, 0.0, distance]
    return out


class SimulatedFlangeCamera(SimulatedCamera):
    """The simulated camera of :class:`drivers.camera.renderer.SimulatedCamera` on the flange (``mount``: flange <-
    camera) rendering the board fixed in the rig's tracker frame; ``printed``: the true board's size over the
    declared one (the true board at a pose renders as the declared one at the pose's translation over ``printed``)."""

    def __init__(self, *args: Any, printed: float = 1.0, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.printed = float(printed)
        self.description = f"simulated flange camera {self.camera.width}x{self.camera.height}"

    def target_pose(self, t: float) -> Array:
        """Camera frame <- board frame at rig time ``t``."""
        pose = np.linalg.inv(self.rig.flange_pose(t) @ self.mount)  # type: ignore[attr-defined]
        pose[:3, 3] /= self.printed
        return pose


def scale_sigma(target_size: float, size_sigma: float | None) -> float | None:
    """The relative standard uncertainty of the board's scale: ``size_sigma / target_size`` (None: not measured)."""
    return None if size_sigma is None else size_sigma / target_size
