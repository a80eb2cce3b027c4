"""The UR ROS driver's kinematics calibration file (the ``kinematics:`` YAML ``ur_calibration`` writes).

For each joint (``shoulder``, ``upper_arm``, ``forearm``, ``wrist_1``, ``wrist_2``, ``wrist_3``) the file gives
the joint's origin in its parent link, ``x, y, z`` (m) and ``roll, pitch, yaw`` (rad, URDF convention
``Rz(yaw) Ry(pitch) Rx(roll)``); the description chains them as ``origin_1 Rz(q_1) origin_2 Rz(q_2) …`` from
the robot's base frame (``base_link_inertia``, the controller's base frame) to ``wrist_3_link``.

With the forward model (kinematics/dh.py), ``A_i = Rz(q_i) D_i`` and ``D_i = Rz(theta_i) Tz(d_i) Tx(a_i)
Rx(alpha_i)``; this module splits each ``D_i`` at its ``Tz(d_i)``, so that joint ``i``'s origin is
``Tx(a_{i-1}) Rx(alpha_{i-1}) Rz(theta_i) Tz(d_i)`` (``a_0 = alpha_0 = 0``): the nominal UR values then give
exactly the numbers of the stock files (e.g. ``forearm: x = a_2``), and ``wrist_3_link`` is DH frame 6, which
requires ``a_6 = alpha_6 = 0`` (the UR convention, which the identification keeps for the last link).

Frames: the identified model's DH frame 0 stands for the robot's base frame; the base transform
(tracker <- frame 0) is not part of this file. The tool is not either, except where the calibration measured the
target frame (full-pose data: a 6-DoF probe, a camera's board; the result's ``tool_frame``): the document then has a
``tcp`` key beside ``kinematics`` (which the driver ignores) with the target frame in ``wrist_3_link`` (the frame
``tool0`` follows), ``{x, y, z, rx, ry, rz}``: m and a rotation vector in rad, the pose the controller's TCP setting
takes (it shows the position in mm).

:func:`calibration_from_lines` writes an axis-lines model instead: each joint's origin is then a full frame on its
exact axis (``identify/exports/joint_frames.py``), with no DH singularity for nearly parallel axes.

``hash``: the driver compares it with the checksum the controller reports for its own calibration and warns
when they differ; that is expected here, since this model is not the controller's. We write
``calib_<n>`` with ``n`` a 64-bit number derived from the values, so the same model gives the same hash.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from identify.estimator.poe import AxisLines
from identify.exports.joint_frames import joint_frames
from identify.exports.urdf import rpy_from_matrix, transform_from_xyz_rpy
from kinematics.dh import DHModel, transform_from_dh

Array = NDArray[np.float64]

SEGMENTS = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
KEYS = ("x", "y", "z", "roll", "pitch", "yaw")
LAST_LINK_TOL = 1e-12  # a_6 and |sin(alpha_6)| above this cannot be written (wrist_3_link must be frame 6)


def origins_from_model(model: DHModel) -> Array:
    """The six joint origins (6, 4, 4) ``Tx(a_{i-1}) Rx(alpha_{i-1}) Rz(theta_i) Tz(d_i)``.

    Raises ValueError unless ``model`` is 6R with ``a_6 = 0`` and ``alpha_6 = 0``.
    """
    if model.joint_types != "RRRRRR":
        raise ValueError(f"the UR calibration file describes six revolute joints; the model has {model.joint_types}")
    if abs(model.a[-1]) > LAST_LINK_TOL or abs(np.sin(model.alpha[-1])) > LAST_LINK_TOL or np.cos(model.alpha[-1]) < 0:
        raise ValueError(f"the UR description puts tool0 on DH frame 6 with a6 = alpha6 = 0; the model has "
                         f"a6 = {model.a[-1]:g} m, alpha6 = {model.alpha[-1]:g} rad")
    a_prev = np.concatenate([[0.0], model.a[:-1]])
    alpha_prev = np.concatenate([[0.0], model.alpha[:-1]])
    before = transform_from_dh(0.0, 0.0, a_prev, alpha_prev)  # Tx(a) Rx(alpha)
    after = transform_from_dh(model.theta, model.d, 0.0, 0.0)  # Rz(theta) Tz(d)
    return before @ after


def model_hash(origins: ArrayLike) -> str:
    """``calib_<n>``: a 64-bit number from the origins' values rounded to 1e-12 (same model, same hash)."""
    values = np.round(np.asarray(origins, dtype=float)[:, :3, :], 12) + 0.0  # + 0.0 folds -0.0 into 0.0
    digest = hashlib.sha256(values.tobytes()).digest()
    return f"calib_{int.from_bytes(digest[:8], 'big')}"


def calibration_from_model(model: DHModel, hash_value: str | None = None) -> dict[str, Any]:
    """The calibration document ``{"kinematics": {segment: {x, y, z, roll, pitch, yaw}, ..., "hash": ...}}``.

    ``hash_value`` replaces the derived hash (e.g. to reuse the controller's, at your own risk).
    """
    return _document(origins_from_model(model), hash_value)


def calibration_from_lines(lines: AxisLines, base: ArrayLike, flange: ArrayLike | None = None,
                           hash_value: str | None = None) -> dict[str, Any]:
    """The calibration document of an axis-lines model of a 6R arm: each joint's full frame
    (:func:`identify.exports.joint_frames.joint_frames`), so the exact axes with no DH singularity; each joint's
    zero is reading 0.

    ``base`` (4, 4): tracker <- the robot's base frame (``base_link_inertia``; e.g. the identified DH model's
    ``base``); ``flange`` (4, 4): tracker <- flange frame at the home readings, which ``wrist_3_link`` then follows
    (default: the frames' own rule, an x axis carried along from the base). The tracked points are not part of the
    file: ``joint_frames(...).tps`` gives them in ``wrist_3_link``; with full-pose data (``lines.orientations`` of
    the first tracked point measured) the document's ``tcp`` is that point's target frame in ``wrist_3_link``
    (module docstring). Raises ValueError unless the lines are 6R.
    """
    if lines.joint_types != "RRRRRR":
        raise ValueError(f"the UR calibration file describes six revolute joints; the model has {lines.joint_types}")
    frames = joint_frames(lines, np.asarray(base, dtype=float), None if flange is None else np.asarray(flange,
                                                                                                          dtype=float))
    doc = _document(frames.origins, hash_value)
    if frames.tp_rotations is not None and np.all(np.isfinite(frames.tp_rotations[0])):
        doc["tcp"] = tcp_entry(frames.tool_frame(0))
    return doc


def tcp_entry(pose: ArrayLike) -> dict[str, float]:
    """``{x, y, z, rx, ry, rz}`` of a tool pose (4, 4) in ``wrist_3_link``: m, and its rotation vector in rad."""
    pose = np.asarray(pose, dtype=float)
    values = [*pose[:3, 3], *Rotation.from_matrix(pose[:3, :3]).as_rotvec()]
    return {key: float(v) + 0.0 for key, v in zip(("x", "y", "z", "rx", "ry", "rz"), values, strict=True)}


def tcp_from_calibration(doc: dict[str, Any]) -> Array | None:
    """The ``tcp`` pose (4, 4) of a calibration document, or None when it has none."""
    tcp = doc.get("tcp") if isinstance(doc, dict) else None
    if not isinstance(tcp, dict):
        return None
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_rotvec([float(tcp[k]) for k in ("rx", "ry", "rz")]).as_matrix()
    pose[:3, 3] = [float(tcp[k]) for k in ("x", "y", "z")]
    return pose


def _document(origins: Array, hash_value: str | None) -> dict[str, Any]:
    kinematics: dict[str, Any] = {}
    for name, origin in zip(SEGMENTS, origins, strict=True):
        values = [*origin[:3, 3], *rpy_from_matrix(origin[:3, :3])]
        kinematics[name] = {key: float(v) + 0.0 for key, v in zip(KEYS, values, strict=True)}
    kinematics["hash"] = hash_value or model_hash(origins)
    return {"kinematics": kinematics}


def format_calibration(doc: dict[str, Any], comment: str | None = None) -> str:
    """YAML text of a calibration document (floats with full precision), with an optional ``#`` comment."""
    head = "".join(f"# {line}\n" for line in (comment or "").splitlines())
    return head + yaml.safe_dump(doc, sort_keys=False, default_flow_style=False)


def origins_from_calibration(doc: dict[str, Any]) -> tuple[Array, str]:
    """The six joint origins (6, 4, 4) and the hash of a calibration document (as read with ``yaml.safe_load``).

    Raises ValueError (one line) on a document without the six segments and their six numbers.
    """
    try:
        kinematics = doc["kinematics"]
        origins = np.array([transform_from_xyz_rpy([float(kinematics[s][k]) for k in KEYS[:3]],
                                                   [float(kinematics[s][k]) for k in KEYS[3:]]) for s in SEGMENTS])
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"not a UR kinematics calibration document (kinematics: {', '.join(SEGMENTS)} with "
                         f"{', '.join(KEYS)}): {exc!r}") from None
    return origins, str(kinematics.get("hash", ""))


def read_calibration(text: str) -> tuple[Array, str]:
    """Parse calibration YAML text: see :func:`origins_from_calibration`."""
    return origins_from_calibration(yaml.safe_load(text))


def frames_from_origins(origins: ArrayLike, q: ArrayLike) -> Array:
    """``wrist_3_link`` in the base frame, ``origin_1 Rz(q_1) … origin_6 Rz(q_6)``, for q (m, 6): (m, 4, 4)."""
    origins = np.asarray(origins, dtype=float)
    q = np.atleast_2d(np.asarray(q, dtype=float))
    out = np.tile(np.eye(4), (len(q), 1, 1))
    for i, origin in enumerate(origins):
        out = out @ origin @ transform_from_dh(q[:, i], 0.0, 0.0, 0.0)
    return out


def write_calibration(path: str | Path, text: str) -> None:
    """Write ``text`` (from :func:`format_calibration`) to ``path``, UTF-8."""
    Path(path).write_text(text, encoding="utf-8")
