"""A robot controller's own factory calibration as a :class:`~kinematics.dh.DHModel`, for comparison.

Universal Robots controllers store calibrated standard-DH values per robot and send them as the kinematics
info of the primary client interface (read by drivers/ur/info.py, kept in the session header): ``theta``
(rad, the joint zero offset added to the joint reading), ``a`` and ``d`` (m), ``alpha`` (rad), one per joint.
UR's forward model is ``Rz(theta_i + q_i) Tz(d_i) Tx(a_i) Rx(alpha_i)`` with the same signs as the nominal
values UR publishes (e.g. the UR5e's ``a_2 = -0.425 m``), which is our forward model (kinematics/dh.py) and that of
``config/robots/ur*.yaml``: the values map one to one, without sign changes or reordering. The calibration
has no base or tool (the identified model's base and tool are in the tracker's frame), so the model returned
has the identity base and a zero tool; compare DH tables, not predicted points.

Pure: no devices, no files.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from kinematics.dh import DHModel

KEYS = ("theta", "d", "a", "alpha")
#: Largest |value| accepted: lengths (m) and angles (rad) beyond this are not a robot's DH table.
LIMITS = {"theta": 2 * np.pi, "d": 5.0, "a": 5.0, "alpha": 2 * np.pi}


def factory_model(calibration: Mapping[str, Any], joint_types: str) -> DHModel:
    """The DHModel of a controller's calibration ``{"theta": [n], "a": [n], "d": [n], "alpha": [n], ...}``
    (rad, m; other keys ignored) for a robot with ``joint_types`` (all revolute: UR arms). ValueError (one
    line) on missing keys, a wrong count, non-finite or implausible values, or prismatic joints."""
    n = len(joint_types)
    if set(joint_types.upper()) != {"R"}:
        raise ValueError(f"a factory calibration in UR's form describes revolute joints; the robot has {joint_types}")
    values = {}
    for key in KEYS:
        try:
            column = np.asarray(calibration[key], dtype=float).reshape(-1)
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"the factory calibration has no numeric '{key}' list") from None
        if column.shape != (n,) or not np.all(np.isfinite(column)):
            raise ValueError(f"the factory calibration's '{key}' must be {n} finite numbers, got {column.tolist()}")
        if np.any(np.abs(column) > LIMITS[key]):
            raise ValueError(f"the factory calibration's '{key}' {column.tolist()} is not a DH table "
                             f"(|value| > {LIMITS[key]:g})")
        values[key] = column
    return DHModel(joint_types, values["theta"], values["d"], values["a"], values["alpha"])


def factory_reference(calibration: Mapping[str, Any] | None, note: str,
                      joint_types: str) -> tuple[tuple[str, DHModel] | None, str]:
    """``(("factory calibration", model), "")`` for a recorded calibration, else ``(None, why not)``: what
    the reports show next to the nominal model. ``note``: why there is none when ``calibration`` is None
    (empty: the robot has none to report, and the reports say nothing)."""
    if calibration is None:
        return None, f"factory calibration: not available ({note})" if note else ""
    try:
        return ("factory calibration", factory_model(calibration, joint_types)), ""
    except ValueError as exc:
        return None, f"factory calibration: not usable ({exc})"
