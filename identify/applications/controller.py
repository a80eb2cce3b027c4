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

from dataclasses import replace
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
                     result: str = "the result", identified: Any = None) -> float | None:
    """Refuse (InputError, one line) a ``robot`` (a :class:`config.robots.RobotModel`) other than the model the
    result ``doc`` with ``joint_types`` was calibrated against (``nominal.name``), or with other joint types:
    its joint values would mean another arm. A result that records no model (identified without ``--robot``) is
    compared with ``robot`` by what it is: ``identified`` (its CalibratedModel) must fit the robot's nominal within
    :data:`MISFIT` (:func:`nominal_misfit`). Returns that misfit (m RMS), None when the result names its model.
    The same check serves every command that takes a result and a robot."""
    from identify.applications.calibrated import nominal_name

    name = nominal_name(doc)
    if name is not None and name.lower() != robot.name.lower():
        raise InputError(f"{result} is a calibration of {name}; {option} {robot.name} is another robot model")
    if joint_types.upper() != robot.joint_types.upper():
        raise InputError(f"{result} has joints {joint_types}, {option} {robot.name} {robot.joint_types}")
    if name is not None or identified is None:
        return None
    misfit = nominal_misfit(identified, robot)
    if misfit > MISFIT:
        raise InputError(f"{result} records no robot model, and {option} {robot.name} is not the arm it calibrated: "
                         f"its nominal misses the identified arm by {misfit * 1e3:.3g} mm RMS (the same model: about "
                         f"1 mm); give the model the arm is")
    return misfit


MISFIT = 5e-3  # m RMS: a robot model whose points miss the identified arm's by more is another model


def nominal_misfit(identified: Any, robot: Any, poses: int = 40, seed: int = 0) -> float:
    """RMS distance (m, 3D) between the tracked point of ``identified`` (a CalibratedModel) and ``robot``'s nominal
    model at ``poses`` random readings within the robot's limits, after the best rigid placement of the nominal
    and the best TP on its flange (9 parameters: the frames' and the tool's conventions cancel). A calibration of
    the same model misses by its own errors (about a millimetre), another model (a UR10e for a UR5e) by
    centimetres to decimetres."""
    import numpy as np
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    from kinematics.dh import flange_frames

    limits = np.clip(np.asarray(robot.limits, dtype=float), -np.pi, np.pi)
    q = np.random.default_rng(seed).uniform(limits[:, 0], limits[:, 1], (poses, robot.n_joints))
    seen = np.asarray(identified.points(q), dtype=float)
    q_dh = q if robot.coupling is None else robot.coupling.dh_from_readings(q)
    turns, origins = flange_frames(replace(robot.nominal, base=np.eye(4)), q_dh)

    def residuals(x: Any) -> Any:
        points = np.einsum("mij,j->mi", turns, x[6:9]) + origins
        return (points @ Rotation.from_rotvec(x[:3]).as_matrix().T + x[3:6] - seen).ravel()

    # start: the rotation that best maps the flange origins onto the points (Kabsch), no tool
    a, b = origins - origins.mean(axis=0), seen - seen.mean(axis=0)
    u, _, vt = np.linalg.svd(b.T @ a)
    rot = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    start = np.r_[Rotation.from_matrix(rot).as_rotvec(), seen.mean(axis=0) - origins.mean(axis=0) @ rot.T, 0, 0, 0]
    fit = least_squares(residuals, start, method="lm")
    return float(np.sqrt(np.mean(np.sum(fit.fun.reshape(-1, 3) ** 2, axis=1))))
