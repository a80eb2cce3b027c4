"""URDF of an identified robot: links and joints whose origins reproduce the DH model (kinematics/dh.py) exactly
(:func:`urdf_from_model`), or an axis-lines model with a full frame per joint (:func:`urdf_from_lines`).

The forward model ``T(q) = base · A_1(q_1) · … · A_n(q_n)`` with ``A_i = M_i(q_i) · D_i``, where ``M_i`` is the
joint's motion (``Rz(q_i)`` revolute, ``Tz(q_i)`` prismatic) and ``D_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)``
its fixed part (``Rz`` and ``Tz`` commute, so the motion can come first). A URDF joint applies its fixed
``origin`` first and its motion second, so joint ``i``'s origin is ``D_{i-1}`` (identity for joint 1).

Tree (names with an optional ``prefix``)::

    tracker --fixed(base)--> base_link (DH frame 0)
      --joint_1 (origin identity, axis z)--> link_1 (DH frame 0 moved by q_1)
      --joint_2 (origin D_1, axis z)--> link_2 ... --joint_n--> link_n
      --fixed (D_n)--> flange (DH frame n) --fixed (tool)--> tp (the tracked point, flange orientation)

With full-pose data (6-DoF probe, camera board: the result's ``tool_frame``) ``tp`` is the measured target frame
itself, its origin the tracked point and its axes the target's, so a planner's tool link is the full tool frame.

Units: metres, radians. Numbers are written with 17 significant digits, so the URDF reproduces the model to
floating-point precision.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np
from numpy.typing import ArrayLike, NDArray

from identify.estimator.poe import AxisLines
from identify.exports.joint_frames import joint_frames
from kinematics.dh import DHModel, transform_from_dh

Array = NDArray[np.float64]

PRISMATIC_PLACEHOLDER = 1.0  # m: stroke written for a prismatic joint without limits (URDF requires one)


def rpy_from_matrix(rotation: ArrayLike) -> tuple[float, float, float]:
    """URDF roll, pitch, yaw (rad) of a 3x3 rotation ``R = Rz(yaw) Ry(pitch) Rx(roll)``.

    Stable at gimbal lock: yaw is taken first, then pitch and roll from what is left, so the angles
    always reproduce ``rotation`` to floating-point precision.
    """
    r = np.asarray(rotation, dtype=float)
    yaw = math.atan2(r[1, 0], r[0, 0]) if math.hypot(r[1, 0], r[0, 0]) > 1e-12 else 0.0
    cy, sy = math.cos(yaw), math.sin(yaw)
    m = np.array([[cy, sy, 0.0], [-sy, cy, 0.0], [0.0, 0.0, 1.0]]) @ r  # Rz(yaw)^T R = Ry(pitch) Rx(roll)
    pitch = math.atan2(-m[2, 0], m[0, 0])
    cp, sp = math.cos(pitch), math.sin(pitch)
    k = np.array([[cp, 0.0, -sp], [0.0, 1.0, 0.0], [sp, 0.0, cp]]) @ m  # Ry(pitch)^T m = Rx(roll)
    roll = math.atan2(k[2, 1], k[1, 1])
    return roll, pitch, yaw


def matrix_from_rpy(roll: float, pitch: float, yaw: float) -> Array:
    """3x3 rotation ``Rz(yaw) Ry(pitch) Rx(roll)`` (the URDF convention)."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                              math.cos(yaw), math.sin(yaw))
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


def transform_from_xyz_rpy(xyz: ArrayLike, rpy: ArrayLike) -> Array:
    """4x4 transform of a URDF ``origin`` (translation ``xyz`` m, rotation ``rpy`` rad)."""
    out = np.eye(4)
    out[:3, :3] = matrix_from_rpy(*(float(v) for v in rpy))
    out[:3, 3] = np.asarray(xyz, dtype=float)
    return out


def fixed_parts(model: DHModel) -> Array:
    """``D_i = Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)`` of every joint, shape (n, 4, 4)."""
    return transform_from_dh(model.theta, model.d, model.a, model.alpha)


def _num(value: float) -> str:
    text = repr(float(value))
    return "0" if text in ("0.0", "-0.0") else text


def _origin(transform: Array) -> str:
    xyz = " ".join(_num(v) for v in transform[:3, 3])
    rpy = " ".join(_num(v) for v in rpy_from_matrix(transform[:3, :3]))
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


def urdf_from_model(
    model: DHModel,
    name: str = "identified_robot",
    limits: ArrayLike | None = None,
    velocities: ArrayLike | None = None,
    prefix: str = "",
    comment: str | None = None,
    tool_frame: ArrayLike | None = None,
) -> str:
    """The URDF text (a string) of ``model``.

    ``limits`` (n, 2): joint limits in rad / m (the nominal model's); without them a revolute joint is
    ``continuous`` and a prismatic one gets a placeholder stroke of ±PRISMATIC_PLACEHOLDER m (marked in a
    comment). ``velocities`` (n,): rad/s / m/s for the ``<limit>`` elements (0 when not given; URDF requires a
    value). ``prefix`` is put before every link and joint name. ``comment`` is written at the top.
    ``tool_frame`` (4, 4; a result's ``tool_frame``): the measured target frame in DH frame n, whose axes ``tp``
    then takes (its origin is ``model.tool``); without it ``tp`` has the flange's axes.
    """
    n = model.n_joints
    parts = fixed_parts(model)
    origins = np.concatenate([np.eye(4)[None], parts[:-1]])
    tool = np.eye(4)
    if tool_frame is not None:
        tool[:3, :3] = np.asarray(tool_frame, dtype=float)[:3, :3]
    tool[:3, 3] = model.tool
    tail = [(f"link_{n}_to_flange", f"link_{n}", "flange", parts[-1]), ("flange_to_tp", "flange", "tp", tool)]
    text = comment or "identified DH model (dh-calib); frames and units: see identify/exports/urdf.py"
    return _chain_urdf(model.joint_types, model.base, origins, tail, name, limits, velocities, prefix, text)


def urdf_from_lines(
    lines: AxisLines,
    base: ArrayLike | None = None,
    flange: ArrayLike | None = None,
    name: str = "identified_robot",
    limits: ArrayLike | None = None,
    velocities: ArrayLike | None = None,
    prefix: str = "",
    comment: str | None = None,
    tp_ids: Sequence[int] | None = None,
) -> str:
    """The URDF text of an axis-lines model: every joint a full frame (origin xyz/rpy, axis z), so the exact axis
    geometry with no DH singularity (see :mod:`identify.exports.joint_frames`); each joint's zero is reading 0.

    ``base`` (4, 4): tracker <- ``base_link`` (e.g. the DH model's ``base``; default: the tracker frame);
    ``flange`` (4, 4): tracker <- flange frame at the home readings, which ``link_n`` then follows. Tracked points
    are fixed links on ``link_n``: ``tp`` (the first) and ``tp_<id>`` for the others (``tp_ids``: the ids of
    ``lines.tps``' rows, default 1, 2, ...), each with its measured target frame's axes where ``lines.orientations``
    has one (full-pose data), else ``link_n``'s. Other arguments as :func:`urdf_from_model`.
    """
    frames = joint_frames(lines, None if base is None else np.asarray(base, dtype=float),
                          None if flange is None else np.asarray(flange, dtype=float))
    n = len(lines.joint_types)
    ids = list(range(1, len(frames.tps) + 1)) if tp_ids is None else [int(i) for i in tp_ids]
    if len(ids) != len(frames.tps):
        raise ValueError(f"{len(ids)} tracked point ids for {len(frames.tps)} tracked points")
    tail = []
    for k, tp_id in enumerate(ids):
        child = "tp" if k == 0 else f"tp_{tp_id}"
        tail.append((f"link_{n}_to_{child}", f"link_{n}", child, frames.tool_frame(k)))
    text = comment or "identified axis lines (dh-calib); frames and units: see identify/exports/joint_frames.py"
    return _chain_urdf(lines.joint_types, frames.base, frames.origins, tail, name, limits, velocities, prefix, text)


def _chain_urdf(joint_types: str, base: Array, origins: Array, tail: list[tuple[str, str, str, Array]], name: str,
                limits: ArrayLike | None, velocities: ArrayLike | None, prefix: str, comment: str) -> str:
    """tracker --fixed(base)--> base_link --joint_i (origins[i], axis z)--> link_i ..., then the fixed ``tail``
    joints (name, parent, child, origin)."""
    n = len(joint_types)
    lim = None if limits is None else np.asarray(limits, dtype=float).reshape(n, 2)
    vel = np.zeros(n) if velocities is None else np.asarray(velocities, dtype=float).reshape(n)
    p = prefix
    out = ['<?xml version="1.0"?>']
    out.append(f"<!-- {comment.replace('--', '- -')} -->")
    out.append(f"<robot name={quoteattr(name)}>")
    links = [f"{p}tracker", f"{p}base_link", *(f"{p}link_{i}" for i in range(1, n + 1)),
             *(f"{p}{child}" for _, _, child, _ in tail)]
    out.extend(f'  <link name="{link}"/>' for link in links)
    out.append(f'  <joint name="{p}tracker_to_base" type="fixed">')
    out.append(f'    <parent link="{p}tracker"/>\n    <child link="{p}base_link"/>\n    {_origin(base)}')
    out.append("  </joint>")
    for i in range(n):
        parent = f"{p}base_link" if i == 0 else f"{p}link_{i}"
        revolute = joint_types[i] == "R"
        note = ""
        if lim is not None:
            kind = "revolute" if revolute else "prismatic"
            lower, upper = lim[i]
        elif revolute:
            kind, lower, upper = "continuous", None, None
        else:
            kind, lower, upper = "prismatic", -PRISMATIC_PLACEHOLDER, PRISMATIC_PLACEHOLDER
            note = "    <!-- no limits given: placeholder stroke -->\n"
        out.append(f'  <joint name="{p}joint_{i + 1}" type="{kind}">')
        out.append(f'    <parent link="{parent}"/>\n    <child link="{p}link_{i + 1}"/>\n    {_origin(origins[i])}')
        out.append('    <axis xyz="0 0 1"/>')
        if lower is None:
            out.append(f'    <limit effort="0" velocity="{_num(vel[i])}"/>')
        else:
            out.append(f'{note}    <limit lower="{_num(lower)}" upper="{_num(upper)}" effort="0" '
                       f'velocity="{_num(vel[i])}"/>')
        out.append("  </joint>")
    for joint, parent, child, transform in tail:
        out.append(f'  <joint name="{p}{joint}" type="fixed">')
        out.append(f'    <parent link="{p}{parent}"/>\n    <child link="{p}{child}"/>\n    {_origin(transform)}')
        out.append("  </joint>")
    out.append("</robot>")
    return "\n".join(out) + "\n"


def write_urdf(path: str | Path, text: str) -> None:
    """Write ``text`` (from :func:`urdf_from_model`) to ``path``, UTF-8."""
    Path(path).write_text(text, encoding="utf-8")
