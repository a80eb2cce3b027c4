"""The verification run's plan and its analysis (pure): an ISO 9283-style test of a calibration on the real arm.

Five poses on the diagonal plane of a test cube (:mod:`identify.iso9283`), in the robot's base frame (DH frame 0
of the identified model), are each visited ``cycles`` times in the standard order: first commanded with the
nominal model (what the controller does today: "before"), then with the identified model ("after",
:mod:`identify.compensate`). A pose is the tracked point's position and, with six joints or more, the flange's
orientation at home. The tracker measures each visit; positions are taken into the base frame through the
identified base (tracker <- frame 0), and AP and RP follow per pose and run.

The plan is an ordinary :class:`~session.plan.Plan` of steps of kind ``verify`` (``sweep`` = the pose number,
role ``check``), so the orchestrator, the session file (durable, resumable) and the plan checks (limits, cell)
are the acquisition's own. What a session needs to be analysed alone sits in its header under
``config.verification`` (:func:`header`): the targets, the commands, the base, the step labels, the prediction.

Units: m, rad. Frames: base (DH frame 0) unless said otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from acquire.plan import _per_joint, check_plan, plan_clearance
from config.robots import RobotModel
from config.site import SiteConfig
from identify.calibrated import CalibratedModel
from identify.compensate import solve_ik
from identify.iso9283 import Accuracy, accuracy, cube_poses, visit_order
from session.plan import Plan, Step

Array = NDArray[np.float64]

KIND = "verify"
MODES = ("before", "after")
MAX_EDGE = 0.3  # m: the default cube's edge at most ...
REACH_SHARE = 0.25  # ... and this share of the robot's reach (sum of its link lengths)
SHRINK = (1.0, 0.5, 0.25)  # a default cube that does not fit is tried at these shares of its edge
AFTER_ALARM = 1e-3  # false-alarm rate of the test of "after" AP against what the result predicts


class VerifyError(ValueError):
    """A verification that cannot be planned or analysed; the message is one line."""


@dataclass(frozen=True)
class Design:
    """What the test commands: cube ``centre`` (3,) and ``edge`` (m), ``targets`` (5, 3) P1..P5 (TP positions),
    ``rotation`` (3, 3) of the flange at every pose (None with fewer than six joints), commands ``q`` per mode
    (5, n; DH joint values, as every plan: a coupled controller is commanded their readings), ``predicted`` per
    mode (5,): the identified model's prediction of AP (before: where the nominal command lands; after: 0),
    ``expected`` (5,): the 3D uncertainty of those predictions, m; ``notes``."""

    centre: Array
    edge: float
    targets: Array
    rotation: Array | None
    q: dict[str, Array]
    predicted: dict[str, Array]
    expected: Array
    notes: tuple[str, ...]


def reach(robot: RobotModel) -> float:
    """Sum of the nominal model's link lengths and prismatic strokes (m): the size of the robot's workspace."""
    m = robot.nominal
    strokes = np.where(m.revolute, 0.0, robot.limits[:, 1] - robot.limits[:, 0])
    return float(np.sum(np.hypot(m.a, m.d)) + np.sum(strokes))


def design(identified: CalibratedModel, robot: RobotModel, site: SiteConfig, plan_ok: Any = None) -> Design:
    """The test's poses and commands for ``identified`` (a result) on ``robot`` in ``site``; VerifyError (one
    line) when the poses cannot be reached or planned. ``plan_ok(q_before, q_after)`` returns the reasons a
    candidate cannot run (none: it can); a default cube that fails is tried lower, higher, then smaller (noted)."""
    ident = identified.with_base(np.eye(4))
    nominal = CalibratedModel.exact(replace(robot.nominal, tool=ident.tool()), robot.name)
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
            if not bad and plan_ok is not None:
                bad = list(plan_ok(before.q, after.q))
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
            return Design(centre, edge, targets, rotation, {"before": before.q, "after": ident.dh_values(after.q)},
                          predicted, expected, tuple(notes))
    edge, centre = tried[-1]
    where = f"centre {', '.join(f'{v:.3f}' for v in centre)} m, edge {edge * 1e3:.0f} mm"
    if not (given and given_centre):
        where += f"; {len(tried)} default cubes tried, edges {edge0 * 1e3:.0f} mm down to {edge * 1e3:.0f} mm"
    raise VerifyError(f"the test cube ({where}) cannot be run: {last}; set verify.cube_centre and cube_edge in the "
                      "site file")


def build(robot: RobotModel, site: SiteConfig, q: dict[str, Array], cycles: int) -> tuple[Plan, list[list[Any]]]:
    """The plan (every mode's cycles in ISO order) and its step labels ``[mode, cycle, pose]``."""
    steps, labels = [], []
    for mode in MODES:
        for cycle, pose in visit_order(cycles):
            steps.append(Step(len(steps), KIND, pose, 0, tuple(float(v) for v in q[mode][pose - 1]), "check"))
            labels.append([mode, cycle, pose])
    plan = Plan(robot.name, robot.joint_types, tuple(float(v) for v in robot.home), tuple(steps),
                site.samples_per_step, site.settle_time, tuple(float(v) for v in _per_joint(robot, site, "speed")),
                tuple(float(v) for v in _per_joint(robot, site, "acceleration")),
                (f"ISO 9283-style verification: 5 poses x {cycles} cycles, commanded with the nominal model, then "
                 "with the identified one",))
    return plan, labels


def problems(plan: Plan, robot: RobotModel, site: SiteConfig) -> list[str]:
    """Why ``plan`` may not run: limits (:func:`acquire.plan.check_plan`) and the cell (the closest approach of any
    step or move, :func:`acquire.plan.plan_clearance`, against the margins)."""
    out = check_plan(plan, robot)
    clearance = plan_clearance(plan, robot, site)
    if clearance is not None and clearance.slack < clearance.guard:
        step = plan.steps[clearance.slack_move]
        out.append(f"the move to step {step.index} (P{step.sweep}) comes too close: {clearance.slack_what} "
                   f"{clearance.slack_distance * 1e3:.1f} mm apart")
    return out


def header(d: Design, labels: list[list[Any]], identified: CalibratedModel, result: str, sha256: str,
           verdict: str | None, cycles: int) -> dict[str, Any]:
    """What the session keeps to be analysed alone (JSON-able; m, rad)."""
    return {"result": result, "result_sha256": sha256, "result_verdict": verdict, "cycles": cycles,
            "centre": d.centre.tolist(), "edge": d.edge, "targets": d.targets.tolist(),
            "rotation": None if d.rotation is None else d.rotation.tolist(),
            "base": identified.base.tolist(), "q": {m: d.q[m].tolist() for m in MODES},
            "predicted": {m: d.predicted[m].tolist() for m in MODES}, "expected": d.expected.tolist(),
            "noise": identified.noise, "steps": labels, "notes": list(d.notes)}


@dataclass(frozen=True)
class Outcome:
    """The measured AP/RP per mode (``runs``; a mode with no complete pose is absent), the verdict
    (pass | warn | fail | incomplete) and the line that says why, with numbers."""

    runs: dict[str, Accuracy]
    status: str
    message: str
    missing: int

    def as_dict(self, info: dict[str, Any]) -> dict[str, Any]:
        return {"verdict": {"status": self.status, "message": self.message},
                "runs": {m: a.as_dict() for m, a in self.runs.items()}, "missing_steps": self.missing,
                "predicted": info["predicted"], "expected": info["expected"], "targets": info["targets"],
                "result": info["result"], "cycles": info["cycles"], "edge": info["edge"], "centre": info["centre"]}


def analyse(info: dict[str, Any], records: list[Any]) -> Outcome:
    """AP/RP per mode from the session's step ``records`` (ok ones, positions in the tracker frame) and its
    ``verification`` header ``info``; the verdict compares "after" with what the result predicts."""
    base = np.array(info["base"], dtype=float)
    inv_r, shift = base[:3, :3].T, base[:3, 3]
    targets = np.array(info["targets"], dtype=float)
    attained: dict[str, dict[int, list[Array]]] = {m: {} for m in MODES}
    sigmas: dict[str, dict[int, list[float]]] = {m: {} for m in MODES}
    missing = 0
    for record in records:
        mode, _, pose = info["steps"][record.plan_index]
        if record.status != "ok":
            missing += 1
            continue
        attained[mode].setdefault(int(pose), []).append(inv_r @ (np.array(record.position) - shift))
        if record.sigma is not None:
            sigmas[mode].setdefault(int(pose), []).append(record.sigma)
    runs = {}
    for mode in MODES:
        known = {p: np.array(v) for p, v in sigmas[mode].items() if len(v) == len(attained[mode][p])}
        acc = accuracy(mode, targets, {p: np.array(v) for p, v in attained[mode].items()}, known)
        if acc.poses:
            runs[mode] = acc
    status, message = _verdict(runs, info)
    return Outcome(runs, status, message, missing)


def _verdict(runs: dict[str, Accuracy], info: dict[str, Any]) -> tuple[str, str]:
    """pass: every pose's "after" AP within what the result's uncertainty and the measurement's spread allow
    (chi-square, 3 degrees of freedom, 0.1 % false alarms); warn: beyond that but better than "before"; fail: not
    better; incomplete: a run or a pose missing."""
    if set(runs) != set(MODES) or any(len(a.poses) < 5 for a in runs.values()):
        return "incomplete", "not every pose of both runs has 2 or more measurements: resume the session"
    before, after = runs["before"], runs["after"]
    expected = np.array(info["expected"], dtype=float)
    scale = chi2.ppf(1 - AFTER_ALARM, 3) / 3  # a 3D error's square over its mean square, at the alarm rate
    limits = [math.sqrt(scale * (e**2 + 3 * p.ap_std**2)) for e, p in zip(expected, after.poses, strict=True)]
    worst = max(range(5), key=lambda k: after.poses[k].ap / limits[k])
    summary = (f"AP before {before.ap * 1e3:.4f} mm, after {after.ap * 1e3:.4f} mm (worst pose); RP before "
               f"{before.rp * 1e3:.4f} mm, after {after.rp * 1e3:.4f} mm")
    p = after.poses[worst]
    if all(a.ap <= lim for a, lim in zip(after.poses, limits, strict=True)):
        return "pass", f"{summary}: every pose within what the result predicts (P{p.pose}: {p.ap * 1e3:.4f} mm " \
                       f"<= {limits[worst] * 1e3:.4f} mm)"
    if after.ap < before.ap:
        return "warn", f"{summary}: better than before, but P{p.pose} misses by {p.ap * 1e3:.4f} mm, more than the " \
                       f"{limits[worst] * 1e3:.4f} mm the result's uncertainty allows: the model holds less than it " \
                       "claims (recalibrate, or check the tool and the mounting)"
    return "fail", f"{summary}: compensation does not improve the arm: do not use this model"
