"""Compensate a parsed program: each target moved so that the real arm (its identified model) goes where the
program meant on the controller's model, checked against the joint limits; the rewritten program text.

What a target means: a pose is where the controller puts the tool centre point (TCP); joint values mean the pose
the controller's model gives them. The controller solves a pose from the joints it is at, so each pose target is
solved from the previous target's joints (the first from ``start``), as the controller would run the program.
The compensated joints (:func:`identify.applications.compensate.compensate`, seeded by the controller's own solution)
are written back as joints, or as the pose the controller's model gives them (so its own inverse kinematics lands
on them). Frames: the robot's base frame (DH frame 0) of both models. Units: m, rad.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from identify.applications.calibrated import CalibratedModel
from identify.applications.compensate import compensate, controller_poses, solve_ik, why_not
from identify.programs.core import Array, Language, Parsed, Target, rewrite
from kinematics.dh import DHModel


@dataclass(frozen=True)
class Outcome:
    """One target after filtering: ``status`` (``ok``/``singular``: rewritten; ``limit``/``unreachable``/``cell``
    (the compensated joints fail the cell check): kept as written, ``reason`` says why); the controller's joints
    for it as written (``q_before``, (n,)) and the compensated ones (``q_after``, NaN when not reached); the
    written target's change (``position_change`` m, ``rotation_change`` rad: of the pose; of the TCP on the
    controller's model for joints) and largest joint change (``joint_change`` rad); ``expected`` the 1-sigma 3D
    error of the reached TCP (m, base frame); the new ``literal`` (None when not rewritten)."""

    target: Target
    status: str
    q_before: Array
    q_after: Array
    position_change: float
    rotation_change: float
    joint_change: float
    expected: float
    literal: str | None
    reason: str = ""


def _angle(a: Array, b: Array) -> float:
    """Angle of the rotation between two 3x3 rotations, rad."""
    return float(np.arccos(np.clip((np.trace(a.T @ b) - 1.0) / 2.0, -1.0, 1.0)))


def filter_targets(parsed: Parsed, identified: CalibratedModel, controller: DHModel, tcp: Array, tcp_rotation: Array,
                   start: Array, limits: Array | None = None, tcp_given: bool = True,
                   language: Language | None = None, check: Callable[[Array], str] | None = None) -> list[Outcome]:
    """Compensate every target of ``parsed``. ``identified``: the calibrated arm in its base frame (base
    identity); ``controller``: the controller's model (base identity); ``tcp`` (3,) m and ``tcp_rotation``
    (3, 3) the TCP in the flange frame (``tcp_given`` False: it is the identified TP, with its uncertainty);
    ``start`` (n,) the joints the program starts from; ``limits`` (n, 2) of the DH joint values; ``check``: why
    the compensated DH joint values (n,) must not be used ("" when they may: e.g. the cell's collision check)."""
    n = identified.n_joints
    ctrl = CalibratedModel.exact(replace(controller, base=np.eye(4), tool=np.asarray(tcp, dtype=float)), "controller")
    six = n >= 6
    k = len(parsed.targets)
    q_c = np.full((k, n), np.nan)
    failed: dict[int, str] = {}
    previous = np.asarray(start, dtype=float)
    for i, target in enumerate(parsed.targets):
        if target.kind == "joints":
            q_c[i] = np.asarray(target.values, dtype=float)
        else:
            assert target.pose is not None
            rot = target.pose[None, :3, :3] if six else None
            sol = solve_ik(ctrl, target.pose[None, :3, 3], identified.dh_values(previous), limits, rot, tcp,
                           tcp_rotation if six else None)
            if not sol.reached[0]:
                failed[i] = (f"the controller's model does not reach this pose from the previous target's joints "
                             f"({sol.status[0]})")
                continue
            q_c[i] = identified.readings(sol.q)[0]
        previous = q_c[i]
    solvable = np.flatnonzero(np.all(np.isfinite(q_c), axis=1))
    flange = ctrl.flanges(identified.dh_values(q_c[solvable])) if len(solvable) else np.zeros((0, 4, 4))
    points = flange[:, :3, :3] @ np.asarray(tcp, dtype=float) + flange[:, :3, 3]
    rotations = flange[:, :3, :3] @ tcp_rotation if six else None
    result = compensate(identified, points, q_c[solvable], limits, rotations, None if not tcp_given else tcp,
                        tcp_rotation if six else None, ctrl, "base") if len(solvable) else None
    outcomes = []
    for i, target in enumerate(parsed.targets):
        if i in failed:
            outcomes.append(Outcome(target, "unreachable", q_c[i], np.full(n, np.nan), np.nan, np.nan, np.nan,
                                    np.nan, None, failed[i]))
            continue
        assert result is not None
        j = int(np.searchsorted(solvable, i))
        sol = result.solution
        if not sol.reached[j]:
            outcomes.append(Outcome(target, str(sol.status[j]), q_c[i], np.full(n, np.nan), np.nan, np.nan, np.nan,
                                    np.nan, None, _reason(str(sol.status[j]))))
            continue
        q = sol.q[j]
        refused = check(identified.dh_values(q[None])[0]) if check is not None else ""
        if refused:
            outcomes.append(Outcome(target, "cell", q_c[i], q, np.nan, np.nan, np.nan, np.nan, None, refused))
            continue
        after = controller_poses(ctrl, identified.dh_values(q[None]), tcp, tcp_rotation)[0]
        before = controller_poses(ctrl, identified.dh_values(q_c[i][None]), tcp, tcp_rotation)[0]
        literal = None
        if language is not None:
            literal = language.joints(q) if target.kind == "joints" else language.pose(after, target.values)
        outcomes.append(Outcome(target, str(sol.status[j]), q_c[i], q,
                                float(np.linalg.norm(after[:3, 3] - before[:3, 3])),
                                _angle(after[:3, :3], before[:3, :3]), float(np.max(np.abs(q - q_c[i]))),
                                float(result.expected[j]), literal))
    return outcomes


def _reason(status: str) -> str:
    return f"not reached by the calibrated arm: {why_not(status, False)}"


def note(outcome: Outcome) -> str:
    """The comment a rewritten line carries: what changed, mm and mrad."""
    if outcome.target.kind == "pose":
        return (f"dh-calib: pose moved {outcome.position_change * 1e3:.3f} mm, "
                f"{outcome.rotation_change * 1e3:.3f} mrad (joints {outcome.joint_change * 1e3:.3f} mrad)")
    return (f"dh-calib: joints moved up to {outcome.joint_change * 1e3:.3f} mrad "
            f"(TCP {outcome.position_change * 1e3:.3f} mm)")


def filtered_text(parsed: Parsed, outcomes: list[Outcome], language: Language) -> str:
    """The program with every reached target rewritten and its line commented; nothing else changed."""
    changes = [(o.target, o.literal, note(o)) for o in outcomes if o.literal is not None]
    return rewrite(parsed.text, changes, language)
