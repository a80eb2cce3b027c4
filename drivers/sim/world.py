"""The simulated rig's world beyond its DH truth: reflectors on the flange and the joints' own errors.

Pure functions on numpy arrays with seeded generators passed in; the kinematics are the shared robot model's
(kinematics/: forward model, :mod:`kinematics.joint_errors`), never written again here. Units: metres, radians,
newton-metres.

- **Reflectors** (:func:`reflector_tools`): the tracked points the tracker sees, as tool vectors in the flange
  (last DH) frame. The first is the truth's TP; the others lie on a plate through it, perpendicular to the
  flange's z axis, every two of them 150-250 mm apart (:data:`PLATE_SPACING`).
- **Backlash** (:func:`backlash_play`): the play of a gear train: the link follows the motor only once the
  motor has taken up the gap, so it stays within half the backlash of it, behind it in the direction it last moved.
- **Joint errors** (:func:`joint_errors_for`): reading scale ``S`` times a seeded random sign per joint,
  once-per-turn error of amplitude ``E`` with a seeded random phase per revolute joint, and the same compliance
  ``C`` for every joint (it needs the model's link masses). :func:`true_joints` gives where the joints really
  stand: ``q_dh + Δq(q_dh)`` with ``q_dh = coupling(readings)`` and Δq of
  :meth:`kinematics.joint_errors.JointErrors.corrections` under the gravity torques of the true model.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from config.robots import RobotModel
from kinematics.dh import DHModel
from kinematics.joint_errors import Coupling, JointErrors, LinkMasses, gravity_torques
from kinematics.truth import axis_distances

Array = NDArray[np.float64]

PLATE_SPACING = (0.15, 0.25)  # m: least and largest distance between two reflectors
MIN_AXIS_DISTANCE = 0.03  # m: every reflector stays this far off every revolute axis at home
_TRIES = 4000  # candidate places per reflector before the plate is laid out again
_LAYOUTS = 50  # plate layouts tried before giving up


def reflector_tools(truth: DHModel, home: Array, count: int, rng: np.random.Generator,
                    spacing: tuple[float, float] = PLATE_SPACING, min_radius: float = MIN_AXIS_DISTANCE) -> Array:
    """Tool vectors (count, 3), m in the flange frame, of ``count`` reflectors on a plate: the first is
    ``truth.tool``; the others lie in the plane through it perpendicular to the flange's z axis, every pair
    ``spacing`` (min, max) apart, each at least ``min_radius`` off every revolute axis at ``home`` (DH values).
    ValueError if no such layout is found."""
    first = np.asarray(truth.tool, dtype=float)
    if count == 1:
        return first[None, :].copy()
    lo, hi = spacing
    for _ in range(_LAYOUTS):
        tools = [first]
        for _ in range(count - 1):
            for _ in range(_TRIES):
                radius, angle = rng.uniform(lo, hi), rng.uniform(0.0, 2 * math.pi)
                candidate = first + radius * np.array([math.cos(angle), math.sin(angle), 0.0])
                gaps = np.linalg.norm(np.array(tools) - candidate, axis=1)
                if np.all((gaps >= lo) & (gaps <= hi)) and \
                        np.all(axis_distances(replace(truth, tool=candidate), home) >= min_radius):
                    tools.append(candidate)
                    break
            else:
                break  # no place for this reflector: lay the plate out again
        if len(tools) == count:
            return np.array(tools)
    raise ValueError(f"cannot place {count} reflectors {lo * 1e3:g}-{hi * 1e3:g} mm apart on the flange")


def joint_errors_for(model: RobotModel, scale: float, eccentricity: float, compliance: float,
                     rng: np.random.Generator) -> JointErrors:
    """The true joint errors of a simulated ``model``: reading scale ``scale`` (1) times a random sign per joint,
    once-per-turn error of amplitude ``eccentricity`` (rad) with a random phase per revolute joint (none for a
    prismatic one), compliance ``compliance`` rad/(N·m) (m/N) for every joint. The draws are the same whatever
    the sizes, so a seed gives the same signs and phases. ValueError for compliance without link masses."""
    n = model.n_joints
    signs = rng.choice([-1.0, 1.0], n)
    phases = rng.uniform(0.0, 2 * math.pi, n)
    if compliance > 0 and model.links is None:
        raise ValueError(f"compliance needs link masses and centres of mass ('dynamics:' in {model.path.name}); "
                         f"the model {model.name} has none")
    amplitude = eccentricity * np.array([t == "R" for t in model.joint_types], dtype=float)
    return JointErrors(scale * signs, amplitude * np.cos(phases), amplitude * np.sin(phases), np.full(n, compliance))


def has_errors(errors: JointErrors) -> bool:
    """True when any term of ``errors`` is non-zero."""
    return any(np.any(v) for v in (errors.scale, errors.ecc_sin, errors.ecc_cos, errors.compliance))


def true_joints(readings: Array, coupling: Coupling | None, errors: JointErrors, truth: DHModel,
                links: LinkMasses | None) -> Array:
    """Where the joints really stand, DH values (m, n) or (n,) like ``readings``: the DH values of the controller's
    ``readings`` (through ``coupling``; None: the readings are DH values) plus the joint errors at them, the
    compliance under the gravity torques of ``truth`` (base transform ignored) with ``links``."""
    r = np.asarray(readings, dtype=float)
    q = np.atleast_2d(r if coupling is None else coupling.dh_from_readings(np.atleast_2d(r)))
    if has_errors(errors):
        torques = gravity_torques(truth, links, q) if np.any(errors.compliance) and links is not None else None
        q = q + errors.corrections(q, torques)
    return q.reshape(r.shape)


def errors_as_dict(errors: JointErrors) -> dict[str, list[float]]:
    """The joint errors as plain lists (for a session header): scale (1), ecc_sin and ecc_cos (rad or m),
    compliance (rad/(N·m) or m/N), per joint."""
    return {"scale": errors.scale.tolist(), "ecc_sin": errors.ecc_sin.tolist(), "ecc_cos": errors.ecc_cos.tolist(),
            "compliance": errors.compliance.tolist()}


def backlash_play(lash: Array, moved: Array, backlash: float) -> Array:
    """The link's offset from the motor (rad or m, per joint) after the motor moved by ``moved`` from where the
    offset was ``lash``: the link stays where it was until the gap is taken up, so the offset is ``lash - moved``
    held within ±``backlash`` / 2 (a move longer than the gap leaves it ``backlash`` / 2 behind; a shorter one,
    or none, leaves the link in the gap)."""
    return np.clip(np.asarray(lash, dtype=float) - np.asarray(moved, dtype=float), -0.5 * backlash, 0.5 * backlash)
