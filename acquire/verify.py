"""The verification run's plan and its analysis (pure): an ISO 9283-style test of a calibration on the real arm.

Five poses on the diagonal plane of a test cube (:mod:`identify.iso9283`), in the robot's base frame (DH frame 0
of the identified model), are each visited ``cycles`` times in the standard order: first commanded with the
nominal model (what the controller does today: "before"), then with the identified model ("after",
:mod:`identify.compensate`). A pose is the tracked point's position and, with six joints or more, the flange's
orientation at home. The tracker measures each visit; positions are taken into the base frame through the
identified base (tracker <- frame 0), and AP and RP follow per pose and run.

Before judging anything the test re-registers the tracker: trackers go back on their tripods, so the result's
tracker <- base transform is not trusted. The plan starts with :data:`REGISTER_POSES` registration poses of its
own (the corners of a cube of :data:`REGISTER_SHARE` of the test cube's edge, the flange tilted by
:data:`REGISTER_TILT` alternately about its x and y axes), commanded with the identified model; none is an ISO
pose, and no ISO measurement enters the registration, so the frame is fitted on other data than the figures it
serves. The registration is :func:`identify.holds.check_models` (``identify check``'s rigid 6-DoF fit and its
cross-validated residuals) with the model the result says to use; the ISO measurements are brought into the
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
from scipy.stats import chi2

from acquire.plan import _per_joint, check_plan, plan_clearance
from config.robots import RobotModel
from config.site import SiteConfig
from identify.calibrated import CalibratedModel
from identify.compensate import solve_ik
from identify.holds import MIN_POSES, ModelCheck, check_models, tabulated
from identify.iso9283 import Accuracy, Distance, Drift, accuracy, cube_poses, distance_result, drift, visit_order
from identify.result_models import result_models
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


class VerifyError(ValueError):
    """A verification that cannot be planned or analysed; the message is one line."""


@dataclass(frozen=True)
class Design:
    """What the test commands: cube ``centre`` (3,) and ``edge`` (m), ``targets`` (5, 3) P1..P5 (TP positions),
    ``rotation`` (3, 3) of the flange at every pose (None with fewer than six joints), commands ``q`` per mode
    (5, n; DH joint values, as every plan: a coupled controller is commanded their readings), ``predicted`` per
    mode (5,): the identified model's prediction of AP (before: where the nominal command lands; after: 0),
    ``expected`` (5,): the 3D uncertainty of those predictions, m; ``notes``; ``register``: the registration
    poses' DH joint values."""

    centre: Array
    edge: float
    targets: Array
    rotation: Array | None
    q: dict[str, Array]
    predicted: dict[str, Array]
    expected: Array
    notes: tuple[str, ...]
    register: Array  # (REGISTER_POSES, n) DH joint values of the registration poses, commanded with the model


def reach(robot: RobotModel) -> float:
    """Sum of the nominal model's link lengths and prismatic strokes (m): the size of the robot's workspace."""
    m = robot.nominal
    strokes = np.where(m.revolute, 0.0, robot.limits[:, 1] - robot.limits[:, 0])
    return float(np.sum(np.hypot(m.a, m.d)) + np.sum(strokes))


def design(identified: CalibratedModel, robot: RobotModel, site: SiteConfig, plan_ok: Any = None,
           before: DHModel | None = None) -> Design:
    """The test's poses and commands for ``identified`` (a result) on ``robot`` in ``site``; VerifyError (one
    line) when the poses cannot be reached or planned. ``plan_ok(q_before, q_after, q_register)`` returns the
    reasons a candidate cannot run (none: it can); a default cube that fails is tried lower, higher, then smaller
    (noted). ``before``: the model the controller moves with today (:func:`identify.controller.controller_model`;
    default the nominal), which commands the "before" visits."""
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
            register = None
            if not bad and plan_ok is not None:
                bad = list(plan_ok(before.q, after.q, None))
            if not bad:
                check = None if plan_ok is None else partial(plan_ok, before.q, after.q)
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
            return Design(centre, edge, targets, rotation, {"before": before.q, "after": ident.dh_values(after.q)},
                          predicted, expected, tuple(notes), register)
    edge, centre = tried[-1]
    where = f"centre {', '.join(f'{v:.3f}' for v in centre)} m, edge {edge * 1e3:.0f} mm"
    if not (given and given_centre):
        where += f"; {len(tried)} default cubes tried, edges {edge0 * 1e3:.0f} mm down to {edge * 1e3:.0f} mm"
    raise VerifyError(f"the test cube ({where}) cannot be run: {last}; set verify.cube_centre and cube_edge in the "
                      "site file")


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
    both from :func:`identify.result_models.result_models`, as ``identify check`` uses them."""
    readings = identified.readings(q_dh)
    tp = np.ones(len(readings), dtype=np.int64)
    models = result_models(doc, readings, tp)
    model = next(m for m in models.models if m.name == models.use)
    return {"q": np.asarray(q_dh).tolist(), "predicted": np.asarray(model.points(readings, tp)).tolist(),
            "expected": model.expected, "model": model.name}


def build(robot: RobotModel, site: SiteConfig, q: dict[str, Array], cycles: int, register: Array | None = None
          ) -> tuple[Plan, list[list[Any]]]:
    """The plan (the registration poses, then every mode's cycles in ISO order) and its step labels
    ``[mode, cycle, pose]`` (``["register", 1, k]`` for the registration poses, k = 1..)."""
    steps, labels = [], []
    for k, pose in enumerate([] if register is None else register):
        steps.append(Step(len(steps), KIND, 0, 0, tuple(float(v) for v in pose), "check"))
        labels.append([REGISTER, 1, k + 1])
    for mode in MODES:
        for cycle, pose in visit_order(cycles):
            steps.append(Step(len(steps), KIND, pose, 0, tuple(float(v) for v in q[mode][pose - 1]), "check"))
            labels.append([mode, cycle, pose])
    plan = Plan(robot.name, robot.joint_types, tuple(float(v) for v in robot.home), tuple(steps),
                site.samples_per_step, site.settle_time, tuple(float(v) for v in _per_joint(robot, site, "speed")),
                tuple(float(v) for v in _per_joint(robot, site, "acceleration")),
                (f"ISO 9283-style verification: {len(labels) - 10 * cycles} registration poses, then 5 poses x "
                 f"{cycles} cycles, commanded with the nominal model, then with the identified one",))
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
           verdict: str | None, cycles: int, doc: dict[str, Any], before: str = "nominal model") -> dict[str, Any]:
    """What the session keeps to be analysed alone (JSON-able; m, rad); ``doc`` the result document, ``before``
    the name of the model that commands the "before" visits."""
    return {"register": register_header(doc, identified, d.register), "result": result, "result_sha256": sha256,
            "before_model": before,
            "result_verdict": verdict, "cycles": cycles,
            "centre": d.centre.tolist(), "edge": d.edge, "targets": d.targets.tolist(),
            "rotation": None if d.rotation is None else d.rotation.tolist(),
            "base": identified.base.tolist(), "q": {m: d.q[m].tolist() for m in MODES},
            "predicted": {m: d.predicted[m].tolist() for m in MODES}, "expected": d.expected.tolist(),
            "noise": identified.noise, "steps": labels, "notes": list(d.notes)}


@dataclass(frozen=True)
class Outcome:
    """The measured AP/RP per mode (``runs``; a mode with no complete pose is absent), the verdict
    (pass | warn | fail | incomplete) and the line that says why, with numbers; ``registration``: the check that
    registered the tracker (None for a session planned without registration poses)."""

    runs: dict[str, Accuracy]
    status: str
    message: str
    missing: int
    registration: ModelCheck | None = None

    def as_dict(self, info: dict[str, Any]) -> dict[str, Any]:
        out = {"verdict": {"status": self.status, "message": self.message}}
        if self.registration is not None:
            r = self.registration
            out["registration"] = {"model": r.name, "poses": r.heldout.samples, "moved": r.registration.moved,
                                   "turned_deg": math.degrees(r.registration.turned), "heldout_rms": r.heldout.rms,
                                   "heldout_max": r.heldout.max, "expected_rms": r.expected, "ratio": r.ratio,
                                   "status": r.status, "reasons": r.reasons}
        return {**out, "runs": {m: a.as_dict() for m, a in self.runs.items()}, "missing_steps": self.missing,
                "predicted": info["predicted"], "expected": info["expected"], "targets": info["targets"],
                "result": info["result"], "result_sha256": info.get("result_sha256"), "cycles": info["cycles"],
                "edge": info["edge"], "centre": info["centre"],
                "before_model": info.get("before_model", "nominal model")}


def register(info: dict[str, Any], records: list[Any]) -> ModelCheck | str:
    """Register the tracker on the session's registration steps (``identify check``'s fit of the recommended
    model's predictions stored in ``info["register"]``); the check, or why it cannot be made (one line)."""
    reg = info["register"]
    rows = [r for r in records if r.status == "ok" and info["steps"][r.plan_index][0] == REGISTER]
    if len(rows) < MIN_POSES:
        return f"{len(rows)} of {len(reg['q'])} registration poses measured: at least {MIN_POSES} are needed"
    pose = np.array([info["steps"][r.plan_index][2] - 1 for r in rows])
    predicted = np.array(reg["predicted"], dtype=float)[pose]
    model = tabulated(reg["model"], predicted, float(reg["expected"]))
    points = np.array([r.position for r in rows], dtype=float)
    q = np.array(reg["q"], dtype=float)[pose]
    return check_models(points, q, np.ones(len(rows), dtype=np.int64), [model]).chosen


def analyse(info: dict[str, Any], records: list[Any]) -> Outcome:
    """AP/RP per mode from the session's step ``records`` (ok ones, positions in the tracker frame) and its
    ``verification`` header ``info``: the tracker is registered first (:func:`register`), the positions taken into
    the base frame; the verdict compares "after" with what the result predicts."""
    base = np.array(info["base"], dtype=float)
    inv_r, shift = base[:3, :3].T, base[:3, 3]
    check = register(info, records) if "register" in info else None
    if isinstance(check, str):
        return Outcome({}, "incomplete", f"{check}: resume the session", _missing(info, records))
    targets = np.array(info["targets"], dtype=float)
    attained: dict[str, dict[int, list[Array]]] = {m: {} for m in MODES}
    sigmas: dict[str, dict[int, list[float]]] = {m: {} for m in MODES}
    cycles: dict[str, dict[int, list[int]]] = {m: {} for m in MODES}
    for record in records:
        mode, cycle, pose = info["steps"][record.plan_index]
        if record.status != "ok" or mode not in MODES:
            continue
        position = np.array(record.position, dtype=float)
        if check is not None:  # new tracker frame -> the calibration's
            position = check.registration.to_calibration(position)
        attained[mode].setdefault(int(pose), []).append(inv_r @ (position - shift))
        cycles[mode].setdefault(int(pose), []).append(int(cycle))
        if record.sigma is not None:
            sigmas[mode].setdefault(int(pose), []).append(record.sigma)
    runs = {}
    for mode in MODES:
        known = {p: np.array(v) for p, v in sigmas[mode].items() if len(v) == len(attained[mode][p])}
        acc = accuracy(mode, targets, {p: np.array(v) for p, v in attained[mode].items()}, known)
        if acc.poses:
            runs[mode] = replace(acc, distance=_distance(targets, attained[mode], cycles[mode]),
                                 drift=_drift(targets, attained[mode], known))
    spread = np.zeros(5) if check is None else registration_variance(
        np.array(info["register"]["predicted"], dtype=float), targets @ base[:3, :3].T + shift, check.expected)
    status, message = _verdict(runs, info, spread)
    if check is not None and check.status == "fail":
        status, message = "fail", (
            f"registered on {check.heldout.samples} poses of its own, the result's {check.name} model still misses "
            f"by {check.heldout.rms * 1e3:.3f} mm RMS (held out), {check.ratio:.1f}x the {check.expected * 1e3:.3f} "
            "mm it predicts: another arm or another tool than the calibration's; do not use this model here")
    return Outcome(runs, status, message, _missing(info, records), check)


def _distance(targets: Array, attained: dict[int, list[Array]], cycles: dict[int, list[int]]) -> Distance | None:
    """AD and RD between P2 and P4 (ISO 9283's pair for 7.3) over the cycles that measured both."""
    a, b = (dict(zip(cycles.get(p, []), attained.get(p, []), strict=True)) for p in DISTANCE_POSES)
    common = sorted(set(a) & set(b))
    if len(common) < 2:
        return None
    return distance_result(*DISTANCE_POSES, targets[DISTANCE_POSES[0] - 1], targets[DISTANCE_POSES[1] - 1],
                           np.array([a[c] for c in common]), np.array([b[c] for c in common]))


def _drift(targets: Array, attained: dict[int, list[Array]], sigma: dict[int, Array]) -> Drift | None:
    """dAP and dRP of P1 over the run (first against last third of its visits), when it has 4 visits or more."""
    visits = attained.get(1, [])
    return drift(1, targets[0], np.array(visits), sigma.get(1)) if len(visits) >= 4 else None


def _missing(info: dict[str, Any], records: list[Any]) -> int:
    return sum(1 for r in records if r.status != "ok")


def registration_variance(fitted: Array, at: Array, expected: float) -> Array:
    """Variance (m², 3D) a rigid registration on the points ``fitted`` (k, 3) adds to positions ``at`` (m, 3), both
    in one frame, when each fitted point misses by ``expected`` (3D RMS, m; isotropic): the linearised fit's
    covariance sigma² (Σ J_iᵀ J_i)⁻¹ with J = [-[x]×, I], carried to each position."""
    def jacobian(x: Array) -> Array:
        skew = np.array([[0.0, x[2], -x[1]], [-x[2], 0.0, x[0]], [x[1], -x[0], 0.0]])  # -[x]x
        return np.hstack([skew, np.eye(3)])

    centre = fitted.mean(axis=0)  # any origin gives the same answer; the centroid keeps the system well scaled
    normal = sum(jacobian(x - centre).T @ jacobian(x - centre) for x in fitted)
    cov = expected**2 / 3.0 * np.linalg.inv(normal)
    return np.array([np.trace(jacobian(x - centre) @ cov @ jacobian(x - centre).T) for x in at])


def _verdict(runs: dict[str, Accuracy], info: dict[str, Any], registration: Array) -> tuple[str, str]:
    """pass: every pose's "after" AP within what the result's uncertainty, the measurement's spread and the
    registration (``registration``: its variance at each pose, m²) allow (chi-square, 3 degrees of freedom, 0.1 %
    false alarms); warn: beyond that but better than "before"; fail: not
    better; incomplete: a run or a pose missing."""
    if set(runs) != set(MODES) or any(len(a.poses) < 5 for a in runs.values()):
        return "incomplete", "not every pose of both runs has 2 or more measurements: resume the session"
    before, after = runs["before"], runs["after"]
    expected = np.array(info["expected"], dtype=float)
    scale = chi2.ppf(1 - AFTER_ALARM, 3) / 3  # a 3D error's square over its mean square, at the alarm rate
    limits = [math.sqrt(scale * (e**2 + 3 * p.ap_std**2 + r))
              for e, p, r in zip(expected, after.poses, registration, strict=True)]
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
