"""Joint frames of an axis-lines model, for formats that give every joint a full frame (URDF, UR calibration).

An :class:`identify.estimator.poe.AxisLines` model holds each joint's axis as a line in the tracker frame with the arm
at the readings ``lines.home``; joint ``i`` at reading ``q_i`` turns about (or slides along) its line by ``q_i -
home_i``, after every joint beyond it has moved (``identify.estimator.poe.points_from_lines``). Give joint ``i`` a frame
``F_i`` at home (tracker frame) whose z axis is its line; then the chain
``base · O_1 · J_1(q_1) · O_2 · J_2(q_2) · … · O_n · J_n(q_n)`` with ``J_i`` = ``Rz(q_i)`` (revolute) or
``Tz(q_i)`` (prismatic) and the fixed origins ``O_i = F_{i-1}⁻¹ · F_i · J_i(-home_i)`` (``F_0 = base``) is that
model exactly, with its zero at reading 0; a tracked point sits at ``F_n⁻¹ · tp`` in the last link's frame, and a
measured target frame (full-pose data: ``lines.orientations``, its rotation at home) at ``F_n⁻¹ · R_home``.

Frames are placed so that no origin is far from the arm, whatever the axes' geometry (no common normal is ever
taken, so nearly parallel axes give no huge offsets): ``F_i``'s origin is the foot of the perpendicular from
``F_{i-1}``'s origin on line ``i`` (a prismatic joint keeps ``F_{i-1}``'s origin: where its line lies does not
matter), and its x axis is ``F_{i-1}``'s x made perpendicular to the line (its y where x is along the line).
With ``flange`` (tracker <- flange frame at home), the last frame takes the flange's x and the foot of the
flange's origin instead, so that it is the flange frame up to the flange's own misalignment with the last axis.

Units: m, rad. Joint values are the lines' (DH joint values: the readings through a coupling, if any).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from identify.estimator.poe import AxisLines
from kinematics.dh import transform_from_dh

Array = NDArray[np.float64]

PARALLEL = 1e-6  # a previous x closer than this (sine) to the new axis is replaced by the previous y


@dataclass(frozen=True)
class JointFrames:
    """``origins`` (n, 4, 4): each joint's fixed origin in its parent's frame (the first in ``base``);
    ``tps`` (k, 3): the tracked points in the last link's frame, m; ``base`` (4, 4): tracker <- root frame;
    ``tp_rotations`` (k, 3, 3): each tracked point's target frame in the last link's frame (NaN where its
    orientation was not measured), None for positions-only lines."""

    origins: Array
    tps: Array
    base: Array
    tp_rotations: Array | None = None

    def tool_frame(self, k: int = 0) -> Array:
        """Tracked point ``k``'s frame in the last link's frame (4, 4), m: the measured target frame where
        ``tp_rotations`` has it, else the last link's axes at the point."""
        out = np.eye(4)
        out[:3, 3] = self.tps[k]
        if self.tp_rotations is not None and np.all(np.isfinite(self.tp_rotations[k])):
            out[:3, :3] = self.tp_rotations[k]
        return out

    def chain(self, joint_types: str, q: Array) -> Array:
        """The last link's frame (m, 4, 4) in the tracker frame at joint values ``q`` (m, n)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        out = np.tile(self.base, (len(q), 1, 1))
        for i, t in enumerate(joint_types):
            motion = transform_from_dh(q[:, i], 0.0, 0.0, 0.0) if t == "R" else transform_from_dh(0.0, q[:, i], 0.0,
                                                                                                    0.0)
            out = out @ self.origins[i] @ motion
        return out


def joint_frames(lines: AxisLines, base: Array | None = None, flange: Array | None = None) -> JointFrames:
    """The joint frames of ``lines`` (see the module's docstring). ``base`` (4, 4): tracker <- the root frame the
    chain starts from (default the tracker frame itself); ``flange`` (4, 4): tracker <- flange frame at home."""
    base = np.eye(4) if base is None else np.asarray(base, dtype=float)
    n = len(lines.joint_types)
    frames = [base]
    for i, t in enumerate(lines.joint_types):
        prev = frames[-1]
        z = lines.directions[i] / np.linalg.norm(lines.directions[i])
        origin, x = prev[:3, 3], prev[:3, 0]
        if i == n - 1 and flange is not None:
            origin, x = np.asarray(flange, dtype=float)[:3, 3], np.asarray(flange, dtype=float)[:3, 0]
        if t == "R":
            origin = lines.points[i] + ((origin - lines.points[i]) @ z) * z
        x = x - (x @ z) * z
        if np.linalg.norm(x) < PARALLEL:
            x = prev[:3, 1] - (prev[:3, 1] @ z) * z
        x = x / np.linalg.norm(x)
        frame = np.eye(4)
        frame[:3, :3] = np.column_stack([x, np.cross(z, x), z])
        frame[:3, 3] = origin
        frames.append(frame)
    origins = np.empty((n, 4, 4))
    for i, t in enumerate(lines.joint_types):
        back = transform_from_dh(-lines.home[i], 0.0, 0.0, 0.0) if t == "R" else transform_from_dh(
            0.0, -lines.home[i], 0.0, 0.0)
        origins[i] = _inverse(frames[i]) @ frames[i + 1] @ back
    last = _inverse(frames[-1])
    tps = lines.tps @ last[:3, :3].T + last[:3, 3]
    turns = None if lines.orientations is None else last[:3, :3] @ lines.orientations
    return JointFrames(origins, tps, base, turns)


def _inverse(transform: Array) -> Array:
    out = np.eye(4)
    out[:3, :3] = transform[:3, :3].T
    out[:3, 3] = -transform[:3, :3].T @ transform[:3, 3]
    return out
