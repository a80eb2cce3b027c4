"""What the operator and other tools are told about a plan (pure): its predicted accuracy, the dry-run text,
the clearance line and the plan as JSON (``acquire --dry-run --json``).

:func:`predicted_accuracy` (Cramér-Rao bounds of the held-out TP error for the plan and for comparisons),
:func:`format_plan` (the dry-run table), :func:`format_clearance` (the closest approach of the plan to its cell)
and :func:`plan_json` (``acquire --dry-run --json``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from acquire.planning.design import SUBSPACE_TOL, gram, whitened
from acquire.planning.plan import EVAL_POSES, PARTIAL_ARC, Array, _fmt, tp_model
from common.units import hms
from config.cell import Clearance
from config.robots import RobotModel
from config.site import SiteConfig
from identify.simulators.simulate import random_poses
from kinematics.collision import STEP
from kinematics.dh import DHModel
from session.plan import STEP_KINDS, Plan, Step


def _partial_sweeps(plan: Plan, robot: RobotModel) -> Array:
    """The plan's sweeps with each revolute one cut to home ± ``PARTIAL_ARC`` (same step counts)."""
    rows = []
    for j in dict.fromkeys(s.joint for s in plan.steps if s.kind == "sweep"):
        count = sum(1 for s in plan.steps if s.kind == "sweep" and s.joint == j)
        q = np.tile(np.array(plan.home), (count, 1))
        if robot.joint_types[j - 1] == "R":
            lo, hi = robot.limits[j - 1]
            q[:, j - 1] = np.linspace(max(lo, plan.home[j - 1] - PARTIAL_ARC),
                                      min(hi, plan.home[j - 1] + PARTIAL_ARC), count)
        else:
            q[:, j - 1] = [s.q[j - 1] for s in plan.steps if s.kind == "sweep" and s.joint == j]
        rows.append(q)
    return np.vstack(rows) if rows else np.zeros((0, robot.n_joints))


def prediction_bound(model: DHModel, q_fit: Array, q_eval: Array, sigma: float) -> float:
    """Cramér-Rao bound (m) on the RMS TP error at ``q_eval`` for data at ``q_fit`` with noise ``sigma``,
    as :func:`identify.estimator.bounds.prediction_rms_bound`, but inf when the data leave a combination of
    parameters that changes the predictions at ``q_eval`` undetermined."""
    g_fit, g_eval = whitened(model, q_fit, q_eval)
    info = gram(g_fit)
    values = np.linalg.eigvalsh(info)
    if not len(values) or values[0] <= SUBSPACE_TOL**2 * values[-1]:
        return math.inf
    cov = np.linalg.inv(info)
    target = gram(g_eval)
    return float(sigma * np.sqrt(np.trace(cov @ target) / len(q_eval)))


def predicted_accuracy(plan: Plan, robot: RobotModel, tp_guess: Any, noise: float, rng_seed: int = 1,
                       eval_poses: int = EVAL_POSES) -> dict[str, float]:
    """Cramér-Rao bounds (m) of the RMS TP prediction error at ``eval_poses`` random held-out poses within
    the limits, on the nominal model with the TP guess as tool, for tracker ``noise`` (m per axis per
    reading; a step averages ``samples_per_step`` readings, so its noise is ``noise / √samples``).

    Keys: ``with_free`` (the plan's sweeps and fitted free poses), ``sweeps_only`` (without the free
    poses), ``partial`` (±20° revolute sweeps, no free poses), ``partial_with_free`` (those plus the
    free poses), ``noise``, ``step_noise`` (m), ``eval_poses``. ``inf`` where the data leave the
    predictions undetermined. Home checks and check poses are not counted as fitted data.
    """
    model = tp_model(robot, tp_guess)
    step_noise = noise / math.sqrt(max(plan.samples_per_step, 1))
    q_eval = random_poses(robot.limits, eval_poses, np.random.default_rng(rng_seed))
    sweeps = np.array([s.q for s in plan.steps if s.kind == "sweep"]).reshape(-1, robot.n_joints)
    free = np.array([s.q for s in plan.steps if s.kind == "free" and s.role == "fit"]).reshape(-1, robot.n_joints)
    partial = _partial_sweeps(plan, robot)

    def bound(q: Array) -> float:
        return prediction_bound(model, q, q_eval, step_noise) if len(q) else math.inf

    return {
        "with_free": bound(np.vstack([sweeps, free])),
        "sweeps_only": bound(sweeps),
        "partial": bound(partial),
        "partial_with_free": bound(np.vstack([partial, free])),
        "noise": float(noise),
        "step_noise": step_noise,
        "eval_poses": float(eval_poses),
    }


def _per_joint_text(values: tuple[float, ...], types: str, unit_r: str, unit_p: str) -> str:
    return ", ".join(f"{math.degrees(v):.1f}{unit_r}" if t == "R" else f"{v * 1e3:.0f}{unit_p}"
                     for v, t in zip(values, types, strict=False))


def format_plan(plan: Plan, robot: RobotModel, duration_s: float, accuracy: dict[str, float] | None,
                device: str = "tracker") -> str:
    """The dry-run summary an operator reads: one line per sweep, counts, duration, accuracy (for the noise of
    ``device``: "tracker" or "camera"), notes."""
    types = plan.joint_types
    lines = [f"Plan for {plan.robot} ({types}), {len(plan.steps)} steps"]
    sweeps: dict[int, list[Step]] = {}
    for s in plan.steps:
        if s.kind in ("sweep", "stream"):
            sweeps.setdefault(s.sweep, []).append(s)
    if sweeps:  # a plan of views alone (a camera on the flange) has no sweep table
        lines += ["", f"{'sweep':>5}  {'joint':>5}  {'from':>10}  {'to':>10}  {'steps':>5}"]
    for sweep, steps in enumerate(sweeps.values(), 1):  # numbered as the operator sees them, 1, 2, 3...
        j = steps[0].joint
        values = [s.q[j - 1] for s in steps] + [s.start[j - 1] for s in steps if s.start is not None]
        kind = types[j - 1] if 0 < j <= len(types) else "P"
        count = "cont." if steps[0].kind == "stream" else str(len(steps))
        lines.append(f"{sweep:>5}  {j:>5}  {_fmt(min(values), kind):>10}  {_fmt(max(values), kind):>10}  "
                     f"{count:>5}")
    count = {k: sum(1 for s in plan.steps if s.kind == k) for k in STEP_KINDS}
    check = sum(1 for s in plan.steps if s.kind == "free" and s.role == "check")
    starts = {s.start for s in plan.steps if s.kind == "stream"}  # a continuous sweep starts from a stop-and-go pose
    at_starts = sum(1 for s in plan.steps if s.kind == "free" and s.role != "check" and s.q in starts)
    lines += ["",
              f"free poses: {count['free'] - check - at_starts} fitted + {check} held out for checking; "
              + (f"{at_starts} stop-and-go poses at the continuous sweeps' starts; " if at_starts else "")
              + f"home checks: {count['home']}",
              f"total: {len(plan.steps)} steps x {plan.samples_per_step} samples = "
              f"{len(plan.steps) * plan.samples_per_step} samples; settle {plan.settle_time:g} s per step",
              f"speed{' between steps' if count['stream'] else ''}: "
              + _per_joint_text(plan.speed, types, "°/s", " mm/s")
              + (" (each continuous sweep at its own speed: notes)" if count["stream"] else ""),
              f"acceleration: {_per_joint_text(plan.acceleration, types, '°/s²', ' mm/s²')}",
              f"estimated duration: {hms(duration_s)}"]
    if accuracy:
        step = accuracy["step_noise"]
        lines += ["",
                  f"predicted accuracy (Cramér-Rao bound, RMS TP error at {int(accuracy['eval_poses'])} random "
                  f"held-out poses; {device} noise {accuracy['noise'] * 1e3:.4g} mm per axis, "
                  f"{plan.samples_per_step} samples per step: {step * 1e3:.4g} mm per step):"]
        rows = (("with_free", "this plan"), ("sweeps_only", "without its free poses"),
                ("partial", "±20° sweeps, no free poses"), ("partial_with_free", "±20° sweeps + free poses"))
        for key, label in rows:
            value = accuracy[key]
            shown = (f"{value * 1e3:.4f} mm = {value / step:.1f} x the noise per step" if math.isfinite(value)
                     else "undetermined (the data do not fix every parameter)")
            lines.append(f"  {label:<28} {shown}")
    if plan.notes:
        lines += ["", "notes:", *(f"  - {note}" for note in plan.notes)]
    return "\n".join(lines)


# the plan JSON's kinds: a held-out free pose is "check"
JSON_KINDS = ("sweep", "free", "check", "home", "stream")


def plan_json(plan: Plan, clearance: Clearance | None, duration_s: float | None = None,
              accuracy: dict[str, float] | None = None) -> dict[str, Any]:
    """The plan as JSON (``--dry-run --json``): ``robot``, ``joint_types``, ``home``, ``steps`` (execution order,
    ``{index, kind, joint, q}``, a held-out free pose's kind is "check") and ``clearance_m`` (m; None when the
    robot model has no collision geometry); then what the dry run prints besides: ``duration_s`` (s),
    ``predicted_accuracy`` (:func:`predicted_accuracy`'s figures, m; None for a continuous plan or a motion
    rehearsal; an undetermined figure is null) and ``notes`` (the plan's notes: clipped sweeps, the TP guess...)."""
    steps = [{"index": s.index, "kind": "check" if s.kind == "free" and s.role == "check" else s.kind,
              "joint": s.joint, "q": list(s.q)} for s in plan.steps]
    for out, s in zip(steps, plan.steps, strict=True):  # a continuous sweep: where it starts, how fast it moves
        if s.kind == "stream":
            out.update(start=list(s.start or ()), speed=s.speed, acceleration=s.acceleration)
    shown = None if accuracy is None else {k: (float(v) if math.isfinite(v) else None) for k, v in accuracy.items()}
    return {"robot": plan.robot, "joint_types": plan.joint_types, "home": list(plan.home), "steps": steps,
            "clearance_m": None if clearance is None else clearance.distance, "duration_s": duration_s,
            "predicted_accuracy": shown, "notes": list(plan.notes)}


def format_clearance(clearance: Clearance | None, plan: Plan, site: SiteConfig) -> str:
    """The dry-run's clearance lines: the plan's closest approach (between what, on which move) and its least
    margin beyond what the cell requires."""
    if clearance is None:
        return ("clearance: NOT CHECKED: the robot model has no collision geometry; only the joint limits are "
                "checked (make sure the cell is clear)")

    def where(move: int) -> str:
        step = plan.steps[move] if plan.steps else None
        return f"on the move to step {step.index} ({step.kind})" if step is not None else "at home"

    return (f"clearance: closest approach {clearance.distance * 1e3:.1f} mm, {clearance.what}, "
            f"{where(clearance.move)}\n"
            f"           least margin beyond the required {site.cell_margin * 1e3:g} mm between bodies and "
            f"{site.mounting_clearance * 1e3:g} mm above the mounting surface: {clearance.slack * 1e3:.1f} mm, "
            f"{clearance.slack_what}, {where(clearance.slack_move)}\n"
            f"           (every step and every move checked, no body point travelling more than {STEP * 1e3:g} mm "
            f"between checks; each check keeps {clearance.guard * 1e3:g} mm beyond the required, so they hold "
            "between checks too)")
