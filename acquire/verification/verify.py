"""The verification run's plan (pure): an ISO 9283-style test of a calibration on the real arm (its analysis:
:mod:`acquire.verification.verify_analysis`).

Five poses on the diagonal plane of a test cube (:mod:`identify.applications.iso9283`), in the robot's base frame (DH
frame 0 of the identified model), are each visited ``cycles`` times in the standard order: first commanded with the
nominal model (what the controller does today: "before"), then with the identified model ("after",
:mod:`identify.applications.compensate`). A pose is the tracked point's position and, with six joints or more, the
flange's orientation at home. Each visit of a pose is made from each of three orthogonal directions (ISO 9283 7.2, for
vAP): the arm first goes to an approach pose :data:`APPROACH_SHARE` of the cube's edge away from the pose along
the base's +x, +y or +z axis (the same orientation, solved with the mode's model), then to the pose. The approach
poses are plan steps like the others (limits, cell, duration, dry run); they are measured too, as every plan step
is, and their readings are kept in the session but not used. AP, RP, AD, RD and drift use the visits from the
first direction (+x), as the standard's one-directional test; vAP compares the three.

Before judging anything the test re-registers the tracker: trackers go back on their tripods, so the result's
tracker <- base transform is not trusted. The plan starts with :data:`REGISTER_POSES` registration poses of its
own (the corners of a cube of :data:`REGISTER_SHARE` of the test cube's edge, the flange tilted by
:data:`REGISTER_TILT` alternately about its x and y axes), commanded with the identified model; none is an ISO
pose, and no ISO measurement enters the registration, so the frame is fitted on other data than the figures it
serves. The registration is :func:`identify.applications.holds.check_models` (``identify check``'s rigid 6-DoF fit and
its cross-validated residuals) with the model the result says to use; the ISO measurements are brought into the
calibration's tracker frame through it, and then into the base frame. When even the registered residuals miss
far beyond the result's prediction (the check fails: another arm or another tool), the verdict is ``fail``.

The plan is an ordinary :class:`~session.plan.Plan` of steps of kind ``verify`` (``sweep`` = the pose number,
role ``check``), so the orchestrator, the session file (durable, resumable) and the plan checks (limits, cell)
are the acquisition's own. What a session needs to be analysed alone sits in its header under
``config.verification`` (:func:`header`): the targets, the commands, the base, the step labels, the prediction.

Units: m, rad. Frames: base (DH frame 0) unless said otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from acquire.planning.plan import _per_joint, check_plan, plan_clearance
from config.robots import RobotModel
from config.site import SiteConfig
from identify.applications.calibrated import CalibratedModel, ResultError, used_section
from identify.applications.compensate import solve_ik
from identify.applications.domain import result_outside
from identify.applications.iso9283 import cube_poses, visit_order
from identify.applications.result_models import result_models
from kinematics.dh import DHModel
from session.plan import Plan, Step

Array = NDArray[np.float64]

KIND = "verify"
MODES = ("before", "after")
MAX_EDGE = 0.3  # m: the default cube's edge at most ...
REACH_SHARE = 0.25  # ... and this share of the robot's reach (sum of its link lengths)
SHRINK = (1.0, 0.5, 0.25)  # a default cube that does not fit is tried at these shares of its edge
AFTER_ALARM = 1e-3  # false-alarm rate of the test of "after" AP against what the result predicts
DISTANCE_POSES = (2, 4)  # ISO 9283 7.3 measures distance accuracy between P2 and P4
REGISTER = "register"  # the label of the registration steps
REGISTER_POSES = 8
REGISTER_SHARE = 0.7  # the registration poses: the corners of a cube of this share of the test cube's edge ...
REGISTER_TILT = math.radians(45.0)  # ... the flange tilted by this angle (six joints or more)
APPROACH = "approach"  # the label of the approach steps: ["approach", mode, cycle, pose, direction]
APPROACH_SHARE = 0.2  # an approach pose lies this share of the cube's edge from its pose ...
APPROACH_AXES = np.eye(3)  # ... along the base's +x, +y, +z (direction 1, 2, 3)


class VerifyError(ValueError):
    """A verification that cannot be planned or analysed; the message is one line."""


@dataclass(frozen=True)
class Design:
    """What the test commands: cube ``centre`` (3,) and ``edge`` (m), ``targets`` (5, 3) P1..P5 (TP positions),
    ``rotation`` (3, 3) of the flange at every pose (None with fewer than six joints), commands ``q`` per mode
    (5, n; DH joint values, as every plan: a coupled controller is commanded their readings), ``predicted`` per
    mode (5,): the identified model's prediction of AP (before: where the nominal command lands; after: 0),
    ``expected`` (5,): the 3D uncertainty of those predictions, m; ``notes``; ``register``: the registration
    poses' DH joint values; ``approach`` per mode (5, 3, n): the DH joint values of each pose's approach poses
    (directions +x, +y, +z)."""

    centre: Array
    edge: float
    targets: Array
    rotation: Array | None
    q: dict[str, Array]
    predicted: dict[str, Array]
    expected: Array
    notes: tuple[str, ...]
    register: Array  # (REGISTER_POSES, n) DH joint values of the registration poses, commanded with the model
    approach: dict[str, Array]


def reach(robot: RobotModel) -> float:
    """Sum of the nominal model's link lengths and prismatic strokes (m): the size of the robot's workspace."""
    m = robot.nominal
    strokes = np.where(m.revolute, 0.0, robot.limits[:, 1] - robot.limits[:, 0])
    return float(np.sum(np.hypot(m.a, m.d)) + np.sum(strokes))


def design(identified: CalibratedModel, robot: RobotModel, site: SiteConfig, plan_ok: Any = None,
           before: DHModel | None = None) -> Design:
    """The test's poses and commands for ``identified`` (a result) on ``robot`` in ``site``; VerifyError (one
    line) when the poses cannot be reached or planned. ``plan_ok(q, approach, q_register)`` (``q`` and ``approach``
    per mode, as in :class:`Design`) returns the
    reasons a candidate cannot run (none: it can); a default cube that fails is tried lower, higher, then smaller
    (noted). ``before``: the model the controller moves with today
    (:func:`identify.applications.controller.controller_model`; default the nominal), which commands the "before"
    visits."""
    ident = identified.with_base(np.eye(4))
    nominal = CalibratedModel.exact(replace(robot.nominal if before is None else before, tool=ident.tool()),
                                    robot.name)
    home = np.array(robot.home, dtype=float)
    at_home = nominal.points(home)[0]
    given_centre = site.verify_centre is not None
    given = site.verify_edge is not None
    edge0 = site.verify_edge if given else min(MAX_EDGE, REACH_SHARE * reach(robot))
    rotation = nominal.flanges(home)[0, :3, :3] if robot.n_joints >= 6 else None
    rot = None if rotation is None else np.broadcast_to(rotation, (5, 3, 3))
    coupled = not np.array_equal(ident.reading_jacobian(), np.eye(robot.n_joints))  # limits bound DH values
    last, tried = "", []
    for share in (1.0,) if given else SHRINK:
        edge = edge0 * share
        # the default centre is the TP at home; where the arm leaves no room above or below it, the cube moves down
        # or up by 40 % of its edge (P2..P5 then reach home's height)
        shifts = (0.0,) if given_centre else (0.0, -0.4, 0.4)
        for shift in shifts:
            centre = np.array(site.verify_centre) if given_centre else at_home + np.array([0.0, 0.0, shift * edge])
            tried.append((edge, centre))
            targets = cube_poses(centre, edge)
            before = solve_ik(nominal, targets, np.tile(home, (5, 1)), robot.limits, rot)  # DH joint values
            after = solve_ik(ident, targets, ident.readings(before.q), None if coupled else robot.limits, rot)
            bad = [f"P{k + 1} {s}" for k, s in enumerate(before.status) if s != "ok"]
            bad += [f"P{k + 1} {s} (identified)" for k, s in enumerate(after.status) if s != "ok"]
            register, approach, q = None, {}, {"before": before.q, "after": ident.dh_values(after.q)}
            if not bad:
                approach, bad = _approach_poses(nominal, ident, targets, edge, rot, q, robot, coupled)
            if not bad and plan_ok is not None:
                bad = list(plan_ok(q, approach, None))
            if not bad:
                check = None if plan_ok is None else partial(plan_ok, q, approach)
                register, bad = _register_poses(ident, centre, edge, rotation, after.q, robot, coupled, check)
            if bad:
                last = "; ".join(bad)
                continue
            notes = [] if len(tried) == 1 else [
                f"the default cube (the TP at home, edge {edge0 * 1e3:.0f} mm) did not fit ({last}); centre "
                f"{', '.join(f'{v * 1e3:.1f}' for v in centre)} mm, edge {edge * 1e3:.0f} mm"]
            predicted = {"before": np.linalg.norm(ident.points(ident.readings(before.q)) - targets, axis=1),
                         "after": np.zeros(5)}
            # the attained positions reach the base frame through the identified base: its uncertainty counts
            expected = identified.expected_errors(after.q)
            assert register is not None
            return Design(centre, edge, targets, rotation, q, predicted, expected, tuple(notes), register, approach)
    edge, centre = tried[-1]
    where = f"centre {', '.join(f'{v:.3f}' for v in centre)} m, edge {edge * 1e3:.0f} mm"
    if not (given and given_centre):
        where += f"; {len(tried)} default cubes tried, edges {edge0 * 1e3:.0f} mm down to {edge * 1e3:.0f} mm"
    raise VerifyError(f"the test cube ({where}) cannot be run: {last}; set verify.cube_centre and cube_edge in the "
                      "site file")


def _approach_poses(nominal: CalibratedModel, ident: CalibratedModel, targets: Array, edge: float,
                    rot: Array | None, q: dict[str, Array], robot: RobotModel, coupled: bool
                    ) -> tuple[dict[str, Array], list[str]]:
    """The approach poses (DH values, per mode (5, 3, n)): each target moved by :data:`APPROACH_SHARE` of ``edge``
    along each of :data:`APPROACH_AXES`, solved with the mode's model (before: ``nominal``; after: ``ident``) from
    the pose's own command. Returns them and the reasons they cannot run (limits, no solution)."""
    out, bad = {}, []
    rots = None if rot is None else np.repeat(rot, 3, axis=0)
    points = (targets[:, None, :] + APPROACH_SHARE * edge * APPROACH_AXES[None, :, :]).reshape(-1, 3)
    for mode, model in (("before", nominal), ("after", ident)):
        seeds = np.repeat(model.readings(q[mode]), 3, axis=0)
        solved = solve_ik(model, points, seeds, None if coupled and mode == "after" else robot.limits, rots)
        dh = model.dh_values(solved.q)
        inside = np.all((dh >= robot.limits[:, 0]) & (dh <= robot.limits[:, 1]), axis=1)
        bad += [f"P{k // 3 + 1}'s approach from {'xyz'[k % 3]} {s if s != 'ok' else 'beyond the joint limits'}"
                + (" (identified)" if mode == "after" else "")
                for k, s in enumerate(solved.status) if s != "ok" or not inside[k]]
        out[mode] = dh.reshape(5, 3, -1)
    return out, bad


def _register_poses(ident: CalibratedModel, centre: Array, edge: float, rotation: Array | None, seeds: Array,
                    robot: RobotModel, coupled: bool, plan_ok: Any) -> tuple[Array | None, list[str]]:
    """The registration poses (DH joint values, (REGISTER_POSES, n)) for the cube at ``centre`` with ``edge``,
    solved with the identified model from the "after" commands ``seeds`` (readings): the flange tilted, else level,
    at :data:`REGISTER_SHARE` of the edge, else at half that, whichever first passes the joint limits and
    ``plan_ok(q_register)``. Returns the poses (None) and the reasons the last candidate cannot run."""
    bad: list[str] = []
    unit = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    axes = [np.array([1.0, 0, 0]), np.array([0, 1.0, 0])]
    for share in (REGISTER_SHARE, REGISTER_SHARE / 2):
        corners = centre + share * edge / 2.0 * unit
        seed = np.tile(seeds[0], (len(corners), 1))
        for tilt in (REGISTER_TILT, 0.0) if rotation is not None else (None,):
            rot = None if rotation is None else np.array(
                [rotation @ Rotation.from_rotvec((-1) ** (k // 2) * tilt * axes[k % 2]).as_matrix()
                 for k in range(len(corners))])
            solved = solve_ik(ident, corners, seed, None if coupled else robot.limits, rot)
            q = ident.dh_values(solved.q)
            inside = np.all((q >= robot.limits[:, 0]) & (q <= robot.limits[:, 1]), axis=1)
            bad = [f"registration pose {k + 1} {s if s != 'ok' else 'beyond the joint limits'}"
                   for k, s in enumerate(solved.status) if s != "ok" or not inside[k]]
            if not bad and plan_ok is not None:
                bad = list(plan_ok(q))
            if not bad:
                return q, []
    return None, bad


def register_header(doc: dict[str, Any], identified: CalibratedModel, q_dh: Array) -> dict[str, Any]:
    """What the registration needs to be analysed alone: the poses (DH values), the TP the result's recommended
    model predicts there (calibration's tracker frame, m) and the 3D RMS it says a prediction misses by (m),
    both from :func:`identify.applications.result_models.result_models`, as ``identify check`` uses them."""
    readings = identified.readings(q_dh)
    tp = np.ones(len(readings), dtype=np.int64)
    models = result_models(doc, readings, tp)
    model = next(m for m in models.models if m.name == models.use)
    return {"q": np.asarray(q_dh).tolist(), "predicted": np.asarray(model.points(readings, tp)).tolist(),
            "expected": model.expected, "model": model.name}


def build(robot: RobotModel, site: SiteConfig, q: dict[str, Array], cycles: int, register: Array | None = None,
          approach: dict[str, Array] | None = None) -> tuple[Plan, list[list[Any]]]:
    """The plan (the registration poses, then every mode's cycles in ISO order, each pose from each approach
    direction: its approach pose, then the pose) and its step labels ``[mode, cycle, pose, direction]``
    (``["register", 1, k]`` for the registration poses, k = 1..; ``["approach", mode, cycle, pose, direction]``
    for the approach poses). Without ``approach``, one visit per pose and cycle (``[mode, cycle, pose]``)."""
    steps, labels = [], []

    def add(q_step: Array, sweep: int, label: list[Any]) -> None:
        steps.append(Step(len(steps), KIND, sweep, 0, tuple(float(v) for v in q_step), "check"))
        labels.append(label)

    for k, pose in enumerate([] if register is None else register):
        add(pose, 0, [REGISTER, 1, k + 1])
    for mode in MODES:
        for cycle, pose in visit_order(cycles):
            if approach is None:
                add(q[mode][pose - 1], pose, [mode, cycle, pose])
                continue
            for h in range(len(APPROACH_AXES)):
                add(approach[mode][pose - 1, h], pose, [APPROACH, mode, cycle, pose, h + 1])
                add(q[mode][pose - 1], pose, [mode, cycle, pose, h + 1])
    visits = f"5 poses x {cycles} cycles" + ("" if approach is None else " x 3 approach directions (+x, +y, +z)")
    plan = Plan(robot.name, robot.joint_types, tuple(float(v) for v in robot.home), tuple(steps),
                site.samples_per_step, site.settle_time, tuple(float(v) for v in _per_joint(robot, site, "speed")),
                tuple(float(v) for v in _per_joint(robot, site, "acceleration")),
                (f"ISO 9283-style verification: {0 if register is None else len(register)} registration poses, "
                 f"then {visits}, commanded with the nominal model, then with the identified one",))
    return plan, labels


def problems(plan: Plan, robot: RobotModel, site: SiteConfig) -> list[str]:
    """Why ``plan`` may not run: limits (:func:`acquire.planning.plan.check_plan`) and the cell (the closest approach of
    any step or move, :func:`acquire.planning.plan.plan_clearance`, against the margins)."""
    out = check_plan(plan, robot)
    clearance = plan_clearance(plan, robot, site)
    if clearance is not None and clearance.slack < clearance.guard:
        step = plan.steps[clearance.slack_move]
        out.append(f"the move to step {step.index} (P{step.sweep}) comes too close: {clearance.slack_what} "
                   f"{clearance.slack_distance * 1e3:.1f} mm apart")
    return out


def header(d: Design, labels: list[list[Any]], identified: CalibratedModel, result: str, sha256: str,
           verdict: str | None, cycles: int, doc: dict[str, Any], before: str = "nominal model") -> dict[str, Any]:
    """What the session keeps to be analysed alone (JSON-able; m, rad); ``doc`` the result document, ``before``
    the name of the model that commands the "before" visits; ``domain``: the test poses against the joint ranges the
    result was fitted on (its stated accuracy, and so the AP "after" this test expects, holds inside them)."""
    found, line = result_outside(doc, d.q["after"])
    domain = {"text": line, **({} if found is None else found.as_dict())}
    return {"domain": domain, "register": register_header(doc, identified, d.register), "result": result,
            "result_sha256": sha256, "before_model": before,
            "result_verdict": verdict, "cycles": cycles,
            "centre": d.centre.tolist(), "edge": d.edge, "targets": d.targets.tolist(),
            "rotation": None if d.rotation is None else d.rotation.tolist(),
            "base": identified.base.tolist(), "q": {m: d.q[m].tolist() for m in MODES},
            "predicted": {m: d.predicted[m].tolist() for m in MODES}, "expected": d.expected.tolist(),
            "noise": identified.noise, "steps": labels, "notes": list(d.notes),
            "approach": {m: d.approach[m].tolist() for m in MODES}, "approach_share": APPROACH_SHARE,
            "tool": identified.tool().tolist(),
            "tools": {str(k): np.asarray(v).tolist() for k, v in (identified.tools or {}).items()},
            "tool_frame": tool_frame(doc)}


def tool_frame(doc: dict[str, Any]) -> list[list[float]] | None:
    """The rotation (3x3, last DH frame <- target frame) of the full-pose target the result measured (its
    recommended model's ``tool_frame``), or None when the calibration measured positions only."""
    try:
        frame = used_section(doc).get("tool_frame")
    except ResultError:
        frame = None
    frame = frame if frame is not None else doc.get("tool_frame")
    return None if frame is None else np.asarray(frame, dtype=float)[:3, :3].tolist()


