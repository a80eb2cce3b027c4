"""What the arm runs today ("before"): the robot controller's own model, and the check that a robot model given on
the command line is the one a result calibrated.

A UR controller holds a factory calibration (its DH values, read by drivers/ur/info.py and kept in the session
header); when the result records it (``controller:`` written by ``identify`` from a session), that is the model
the controller moves with, else the robot's nominal model. The result's ``controller`` section::

    controller:
      model: factory calibration
      dh: {theta: [6], d: [6], a: [6], alpha: [6]}   # rad, m; UR's convention (identify/applications/factory.py)

Frames: the model returned has the identity base (robot frame 0) and a zero tool. Units: m, rad.
"""

from __future__ import annotations

from typing import Any

from common.errors import InputError
from identify.applications.factory import KEYS, factory_model
from kinematics.dh import DHModel

FACTORY = "factory calibration"


def controller_section(calibration: dict[str, Any] | None, joint_types: str) -> dict[str, Any] | None:
    """The result's ``controller`` section for a controller's recorded calibration (see
    :func:`session.rows.factory_calibration`), or None when there is none or it is not a usable DH table."""
    if calibration is None:
        return None
    try:
        factory_model(calibration, joint_types)
    except ValueError:
        return None
    return {"model": FACTORY, "dh": {key: [float(v) for v in calibration[key]] for key in KEYS}}


def controller_model(doc: dict[str, Any], robot: Any) -> tuple[DHModel, str]:
    """The model the controller of the calibrated arm moves with today and its name: the factory calibration the
    result ``doc`` records (``controller.dh``), else ``robot``'s nominal model (a
    :class:`config.robots.RobotModel`). Base identity, zero tool. InputError (one line) for a recorded
    calibration that is not a DH table of ``robot``'s joints."""
    section = doc.get("controller") if isinstance(doc, dict) else None
    if isinstance(section, dict) and isinstance(section.get("dh"), dict):
        try:
            model = factory_model(section["dh"], robot.joint_types)
        except ValueError as exc:
            raise InputError(f"the result's controller section: {exc}") from None
        return model, f"{FACTORY} of the {robot.name}'s controller"
    return robot.nominal, f"nominal {robot.name}"


def check_same_robot(doc: dict[str, Any], joint_types: str, robot: Any, option: str = "--robot",
                     result: str = "the result") -> None:
    """Refuse (InputError, one line) a ``robot`` (a :class:`config.robots.RobotModel`) other than the model the
    result ``doc`` with ``joint_types`` was calibrated against (``nominal.name``), or with other joint types:
    its joint values would mean another arm. The same check serves every command that takes a result and a
    robot."""
    from identify.applications.calibrated import nominal_name

    name = nominal_name(doc)
    if name is not None and name.lower() != robot.name.lower():
        raise InputError(f"{result} is a calibration of {name}; {option} {robot.name} is another robot model")
    if joint_types.upper() != robot.joint_types.upper():
        raise InputError(f"{result} has joints {joint_types}, {option} {robot.name} {robot.joint_types}")
