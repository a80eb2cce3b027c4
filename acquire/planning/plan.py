"""The acquisition plan: what to move where, decided before anything moves (pure, no devices).

A plan (its data types, as a session stores them: session/plan.py) is an ordered list of steps. Sweeps move one
joint through increments with the others at home (last joint first, as in the paper); free poses move every joint
(extra data for the fit and for validation); home checks return to the home pose every N steps to watch the
tracker/robot drift.
Joint values: rad (revolute) / m (prismatic).

Functions (all pure): :func:`build_plan` (robot model + site configuration -> plan, free poses by a
greedy optimal design, every step and move clear of the cell: :mod:`config.cell`), :func:`check_plan`
(every limit violation, one line each; nothing moves unless it is empty), :func:`plan_clearance` (the
closest approach of a plan to its cell) and :func:`estimate_duration`. What the operator is told about a
plan (accuracy, dry-run text, Plan JSON) is in :mod:`acquire.planning.plan_report`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from acquire.planning.camera_view import visible
from acquire.planning.design import greedy_design
from config.cell import Clearance, Contact, cell_from_config, clearance_of, contact_at, first_contact, free_interval
from config.robots import RobotModel
from config.site import SiteConfig
from drivers.motion import motion_time
from identify.simulators.simulate import random_poses
from kinematics.collision import STEP, Cell, approach, moves_samples
from kinematics.dh import DHModel, frames_from_joints
from kinematics.truth import axis_distances
from session.plan import STEP_KINDS, Plan, Step

# ------------------------------------------------------------------------------------------ building a plan

Array = NDArray[np.float64]

FREE_MARGIN = 0.1  # free poses stay this share of each joint's range inside it
CAMERA_SPAN = 0.8  # rad / m: with a camera, free pose candidates are drawn within home ± this
CANDIDATES = 1500  # size of the seeded pool free poses are chosen from
EVAL_POSES = 200  # random held-out poses the design and the accuracy estimate average over
PARTIAL_ARC = math.radians(20.0)  # half-width of the "±20° sweeps" of the comparison
HOME_SWEEP = 0  # sweep id of the home checks (they are not a fitting sweep)


class PlanError(ValueError):
    """A site configuration that cannot be turned into a plan for this robot; the message is one line."""


def sweep_values(joint_type: str, home: float, limits: tuple[float, float], steps: int,
                 span: tuple[float, float] | None = None) -> Array:
    """Commanded values (steps,) of one joint's sweep, increasing (rad / m).

    With ``span`` = (min, max) from the site: those ends, not clipped (``check_plan`` judges them); a
    revolute span of a full turn or more does not repeat its end point. Without: a revolute joint turns
    a full turn home ± π in ``steps`` equal increments (home included, the end point not repeated) when
    the limits allow it, else as far as the limits allow on either side, clipped; a prismatic joint
    covers its limits.
    """
    lo, hi = limits
    k = np.arange(steps)
    if span is not None:
        a, b = span
        if joint_type == "R" and b - a >= 2 * np.pi - 1e-12:
            return a + 2 * np.pi * k / steps
        return np.linspace(a, b, steps)
    if joint_type == "R":
        values = home + 2 * np.pi * (k - steps // 2) / steps
        if values[0] >= lo and values[-1] + 2 * np.pi / steps <= hi:
            return values
        return np.linspace(max(lo, home - np.pi), min(hi, home + np.pi), steps)
    return np.linspace(lo, hi, steps)


def tp_model(robot: RobotModel, tp_guess: Any) -> DHModel:
    """The robot's nominal model with the TP guess (m, flange frame) as its tool."""
    return replace(robot.nominal, tool=np.asarray(tp_guess, dtype=float))


def axis_distances_many(model: DHModel, q: Array) -> Array:
    """:func:`kinematics.truth.axis_distances` for many poses at once: (m, n) m, inf for prismatic."""
    frames = frames_from_joints(model, q)
    last = frames[:, -1]
    tp = last[:, :3, :3] @ model.tool + last[:, :3, 3]
    rel = tp[:, None, :] - frames[:, :-1, :3, 3]
    z = frames[:, :-1, :3, 2]
    radial = rel - np.sum(rel * z, axis=2, keepdims=True) * z
    out = np.linalg.norm(radial, axis=2)
    out[:, ~model.revolute] = np.inf
    return out


def _per_joint(robot: RobotModel, site: SiteConfig, name: str) -> Array:
    values = getattr(site, name)
    default = robot.default_speed if name == "speed" else robot.default_acceleration
    if values is not None and len(values) != robot.n_joints:
        raise PlanError(f"{site.source}: robot.{name} has {len(values)} values for the {robot.n_joints} joints "
                        f"of {robot.name}")
    base = default if values is None else np.asarray(values, dtype=float)
    return base * getattr(site, f"{name}_fraction")


def _joint_box(robot: RobotModel, site: SiteConfig) -> Array:
    """Per joint the (min, max) the joint may visit: its sweep range, clipped to the limits (n, 2)."""
    box = np.empty((robot.n_joints, 2))
    for j, kind in enumerate(robot.joint_types):
        lo, hi = robot.limits[j]
        span = site.sweep_ranges[j] if site.sweep_ranges is not None else None
        if span is not None:
            box[j] = max(lo, span[0]), min(hi, span[1])
        elif kind == "R":
            box[j] = max(lo, robot.home[j] - np.pi), min(hi, robot.home[j] + np.pi)
        else:
            box[j] = lo, hi
        if box[j, 0] >= box[j, 1]:  # a site range wholly outside the limits: stay at home
            box[j] = robot.home[j], robot.home[j]
    return box


def _fmt(value: float, kind: str) -> str:
    return f"{math.degrees(value):.1f}°" if kind == "R" else f"{value * 1e3:.1f} mm"


def build_plan(robot: RobotModel, site: SiteConfig, rng_seed: int = 0) -> Plan:
    """The plan for ``robot`` under ``site``: sweeps, free poses and home checks.

    Sweeps: the joints ``site.sweep_joints`` (default all), last to first, ``site.steps_per_sweep`` values
    each (:func:`sweep_values`), the other joints at home; a sweep pose where the TP guess comes within
    ``site.min_axis_distance`` of a revolute axis is dropped (and noted). Free poses (kind "free", joint 0,
    one sweep id each): ``site.check_poses`` random held-out ones (role "check") and ``site.free_poses``
    chosen from a seeded pool by :func:`greedy_design`, inside every joint's sweep range (clipped to the
    limits, shrunk by ``FREE_MARGIN``) with the TP off every axis; visited in nearest-neighbour order.
    Home checks (kind "home", sweep ``HOME_SWEEP``): first, after every ``site.home_check_every`` other
    steps, and last. Raises :class:`PlanError` when the TP guess is too close to an axis at home or the
    site does not fit the robot.
    """
    n, types, home = robot.n_joints, robot.joint_types, robot.home
    model = tp_model(robot, site.tp_guess)
    if site.sweep_ranges is not None and len(site.sweep_ranges) != n:
        raise PlanError(f"{site.source}: plan.sweep_ranges has {len(site.sweep_ranges)} entries for the {n} "
                        f"joints of {robot.name}")
    joints = list(range(1, n + 1)) if site.sweep_joints is None else list(site.sweep_joints)
    if any(j > n for j in joints):
        raise PlanError(f"{site.source}: plan.joints lists joint {max(joints)}; {robot.name} has joints 1..{n}")
    speed, acceleration = _per_joint(robot, site, "speed"), _per_joint(robot, site, "acceleration")
    minimum = site.min_axis_distance
    at_home = axis_distances(model, home)
    if np.any(at_home < minimum):
        j = int(np.argmin(at_home))
        raise PlanError(f"the TP guess {list(site.tp_guess)} m is {at_home[j]:.4f} m from the axis of joint "
                        f"{j + 1} at home (< {minimum} m): mount the target off the axis and set plan.tp_guess")
    notes = [f"TP guess {list(site.tp_guess)} m in the flange frame, kept >= {minimum * 1e3:g} mm off every "
             "revolute axis"]
    if robot.coupling is not None and not robot.coupling.is_identity:
        notes.append("joint values here are DH values; the controller reports coupled readings (coupling in "
                     f"{robot.path.name}): each step is commanded, and recorded, as the readings that give them")

    cell = cell_from_config(robot, site)
    if cell is None:
        notes.append(f"{robot.name} has no collision geometry: the plan is checked against the joint limits only")
    else:
        contact = contact_at(cell, home)
        if contact is not None:
            raise PlanError(f"{site.source}: the home pose is not clear: {_contact_text(contact)}; move the "
                            "obstacle or lower cell.margin / cell.mounting_clearance")

    poses: list[tuple[str, int, int, Array, str]] = []  # kind, sweep, joint, q, role
    sweep_id = 0
    for j in sorted(joints, reverse=True):
        span = site.sweep_ranges[j - 1] if site.sweep_ranges is not None else None
        values = sweep_values(types[j - 1], float(home[j - 1]), tuple(robot.limits[j - 1]), site.steps_per_sweep,
                              span)
        if cell is not None:
            values = _safe_sweep(cell, robot, site, j, values, span is not None, notes)
            if values is None:
                continue
        q = np.tile(home, (len(values), 1))
        q[:, j - 1] = values
        dist = np.array([axis_distances(model, row) for row in q])
        ok = np.all(dist >= minimum, axis=1)
        if not ok.all():
            near = sorted({int(i) + 1 for i in np.flatnonzero(np.any(dist[~ok] < minimum, axis=0))})
            notes.append(f"joint {j} sweep: {int((~ok).sum())} of {len(q)} poses dropped (TP within "
                         f"{minimum * 1e3:g} mm of the axis of joint {', '.join(map(str, near))})")
        ok &= _seen(site, model, q, f"joint {j} sweep", notes)
        if ok.any():
            sweep_id += 1
            poses += [("sweep", sweep_id, j, row, "fit") for row in q[ok]]
    if cell is None and any(types[j - 1] == "R" and (site.sweep_ranges is None or site.sweep_ranges[j - 1] is None)
                            for j in joints):
        notes.append("default revolute sweeps turn as far as the limits allow (up to a full turn): make sure "
                     "the cell is clear, or restrict them with plan.sweep_ranges")

    free = _free_poses(robot, site, model, np.array([p[3] for p in poses]).reshape(-1, n), rng_seed, notes, cell)
    start = poses[-1][3] if poses else home
    for q, role in _nearest_order(free, start, speed):
        sweep_id += 1
        poses.append(("free", sweep_id, 0, q, role))

    steps: list[Step] = []

    def add(kind: str, sweep: int, joint: int, q: Array, role: str = "fit") -> None:
        steps.append(Step(len(steps), kind, sweep, joint, tuple(float(x) for x in q), role))

    every = site.home_check_every
    ordered: list[tuple[str, int, int, Array, str]] = []
    if every and poses:
        ordered.append(("home", HOME_SWEEP, 0, home, "fit"))
    for count, pose in enumerate(poses, start=1):
        ordered.append(pose)
        if every and (count % every == 0 or count == len(poses)):
            ordered.append(("home", HOME_SWEEP, 0, home, "fit"))
    for pose in _via_home(cell, ordered, home, notes) if cell is not None else ordered:
        add(*pose)
    return Plan(robot.name, types, tuple(float(x) for x in home), tuple(steps), site.samples_per_step,
                site.settle_time, tuple(float(x) for x in speed), tuple(float(x) for x in acceleration),
                tuple(notes))


def _seen(site: SiteConfig, model: DHModel, q: Array, what: str, notes: list[str]) -> NDArray[np.bool_]:
    """(m,) which configurations a camera tracker sees the target at (all without ``cell.camera_pose``); the
    others are left out, noted with their reasons."""
    if site.camera_pose is None or not len(q):
        return np.ones(len(q), dtype=bool)
    seen, reasons = visible(model, q, np.array(site.camera_pose), np.array(site.target_normal),
                            site.camera_half_fov, site.camera_max_tilt)
    if not seen.all():
        counts = {r: reasons.count(r) for r in dict.fromkeys(r for r in reasons if r)}
        notes.append(f"{what}: {int((~seen).sum())} of {len(q)} left out for the camera ("
                     + "; ".join(f"{n}: {r}" for r, n in counts.items()) + ")")
    return seen


def _contact_text(contact: Contact) -> str:
    return (f"{contact.what} {contact.distance * 1e3:.1f} mm apart (needs {contact.required * 1e3:.0f} mm with "
            f"{STEP * 1e3:g} mm for the motion between checks)")


def _safe_sweep(cell: Cell, robot: RobotModel, site: SiteConfig, j: int, values: Array, requested: bool,
                notes: list[str]) -> Array | None:
    """The sweep of joint ``j`` (1-based) kept to the collision-free interval around home.

    A requested range (``plan.sweep_ranges``) that is not clear all the way from home is refused
    (:class:`PlanError` naming the joint, the value and the bodies); a default one is clipped to the clear
    interval around home (noted), or left out (None, noted) when there is no room to move."""
    kind, h = robot.joint_types[j - 1], float(robot.home[j - 1])
    lo, hi = min(h, float(values.min())), max(h, float(values.max()))
    low, high, contact = free_interval(cell, robot.home, j - 1, lo, hi)
    if contact is None:
        return values
    at = _fmt(float(contact.q[j - 1]), kind)
    if requested:
        raise PlanError(f"{site.source}: plan.sweep_ranges[{j - 1}]: joint {j} at {at} collides: "
                        f"{_contact_text(contact)}; narrow the range")
    if high - low < 1e-9:
        notes.append(f"joint {j} sweep left out: no room to move from home ({_contact_text(contact)})")
        return None
    notes.append(f"joint {j} sweep clipped to {_fmt(low, kind)} .. {_fmt(high, kind)}, the collision-free "
                 f"interval around home (at {at}: {_contact_text(contact)})")
    return np.linspace(low, high, len(values))


def _via_home(cell: Cell, ordered: list[tuple[str, int, int, Array, str]], home: Array,
              notes: list[str]) -> list[tuple[str, int, int, Array, str]]:
    """``ordered`` with a home step before every pose whose direct move from the one before (home at the
    start) would come too close; moves from and to home are clear by construction (sweeps inside their clear
    interval, free poses chosen with a clear path from home)."""
    q = np.array([home, *(p[3] for p in ordered)])
    samples, owner = moves_samples(cell, q)
    bad = set(np.unique(owner[approach(cell, samples).slack < cell.guard]).tolist())
    out: list[tuple[str, int, int, Array, str]] = []
    for i, pose in enumerate(ordered):
        if i in bad:
            out.append(("home", HOME_SWEEP, 0, home, "fit"))
        out.append(pose)
    if bad:
        notes.append(f"{len(bad)} move(s) go through home: the direct move would come too close")
    return out


def plan_clearance(plan: Plan, robot: RobotModel, site: SiteConfig) -> Clearance | None:
    """Closest approach of the plan run from home (every step and every move between them, sampled so that no
    body point travels more than 1 cm between samples) in the cell of ``site``; None without robot geometry.
    ``Clearance.move`` is the index of the step the move leads to."""
    cell = cell_from_config(robot, site)
    if cell is None:
        return None
    return clearance_of(cell, np.array([plan.home, *(s.q for s in plan.steps)]))


def _free_poses(robot: RobotModel, site: SiteConfig, model: DHModel, q_sweeps: Array, rng_seed: int,
                notes: list[str], cell: Cell | None = None) -> list[tuple[Array, str]]:
    """Check poses (random) then designed free poses from one seeded pool of safe candidates: the TP off every
    axis and, with a ``cell``, the pose and the move to it from home clear."""
    wanted = site.free_poses + site.check_poses
    if not wanted:
        return []
    rng = np.random.default_rng(rng_seed)
    box = _joint_box(robot, site)
    if site.camera_pose is not None:  # a camera sees the target near home: draw the candidates there
        box = np.column_stack([np.maximum(box[:, 0], robot.home - CAMERA_SPAN), np.minimum(box[:, 1],
                                                                                        robot.home + CAMERA_SPAN)])
    pool = random_poses(box, CANDIDATES, rng, FREE_MARGIN)
    pool = pool[np.all(axis_distances_many(model, pool) >= site.min_axis_distance, axis=1)]
    if cell is not None:
        pool = pool[approach(cell, pool).slack >= cell.guard]
    pool = pool[_seen(site, model, pool, "free pose candidates", notes)]
    if len(pool) < wanted + 1:
        raise PlanError(f"only {len(pool)} candidate free poses keep the TP off every axis, clear of the cell (and "
                        "in a camera's view); lower plan.free_poses / plan.check_poses, plan.min_axis_distance or "
                        "cell.margin")
    reachable = _reachable_test(cell, robot.home, pool)
    check_idx: list[int] = []
    for k in range(len(pool)):  # check poses: the first pool poses reachable from home
        if len(check_idx) == site.check_poses:
            break
        if reachable(k):
            check_idx.append(k)
    if len(check_idx) < site.check_poses:
        raise PlanError(f"only {len(check_idx)} candidate check poses can be reached from home without coming too "
                        "close to the cell; lower plan.check_poses or cell.margin")
    check, pool = pool[check_idx], np.delete(pool, check_idx, axis=0)
    reachable = _reachable_test(cell, robot.home, pool)
    q_eval = random_poses(robot.limits, EVAL_POSES, rng)
    chosen = greedy_design(model, q_sweeps, pool, q_eval, site.free_poses, accept=reachable)
    if len(chosen) < site.free_poses:
        raise PlanError(f"only {len(chosen)} candidate free poses can be reached from home without coming too close "
                        "to the cell; lower plan.free_poses or cell.margin")
    if site.free_poses:
        notes.append(f"{site.free_poses} free poses chosen from {len(pool)} candidates to minimise the predicted "
                     f"held-out error (greedy design on the nominal model); {site.check_poses} check poses at "
                     "random, held out for validation")
    elif site.check_poses:
        notes.append(f"{site.check_poses} check poses at random, held out for validation")
    return [(q, "fit") for q in pool[chosen]] + [(q, "check") for q in check]


def _reachable_test(cell: Cell | None, home: Array, poses: Array) -> Callable[[int], bool]:
    """A test whether the straight joint-space move from ``home`` to ``poses[k]`` stays clear (always True
    without a cell); each pose is checked once, when first asked about."""
    if cell is None:
        return lambda k: True

    def test(k: int) -> bool:
        return first_contact(cell, home, poses[k]) is None

    return test


def _nearest_order(poses: list[tuple[Array, str]], start: Array, speed: Array) -> list[tuple[Array, str]]:
    """``poses`` reordered greedily: each next one the quickest to reach (slowest joint at ``speed``)."""
    left, out, here = list(poses), [], start
    while left:
        k = min(range(len(left)), key=lambda i: float(np.max(np.abs(left[i][0] - here) / speed)))
        out.append(left.pop(k))
        here = out[-1][0]
    return out


# ------------------------------------------------------------------------------------- checking and telling

def _value(value: float, kind: str) -> str:
    if kind == "R":
        return f"{value:.4f} rad ({math.degrees(value):.2f}°)"
    return f"{value:.4f} m"


def check_plan(plan: Plan, robot: RobotModel) -> list[str]:
    """Every reason not to run ``plan`` on ``robot``, one line each; an empty list means it may run.

    Checks the robot and joint types, the joint count of the home pose, speeds, accelerations and every
    step, every joint value against the limits (inclusive), speeds against ``max_speed``, and the step
    fields (index, kind, role, samples, settle time).
    """
    n, types, limits = robot.n_joints, robot.joint_types, robot.limits
    out: list[str] = []
    if plan.robot != robot.name:
        out.append(f"plan is for robot '{plan.robot}', the model is '{robot.name}'")
    if plan.joint_types != types:
        out.append(f"plan joint types {plan.joint_types}, the model's are {types}")
    if not plan.steps:
        out.append("plan has no steps")
    if plan.samples_per_step < 1:
        out.append(f"samples_per_step = {plan.samples_per_step}, expected >= 1")
    if not (math.isfinite(plan.settle_time) and plan.settle_time >= 0):
        out.append(f"settle_time = {plan.settle_time} s, expected a number >= 0")

    def pose(where: str, q: tuple[float, ...]) -> None:
        if len(q) != n:
            out.append(f"{where}: {len(q)} joint values, {robot.name} has {n} joints")
            return
        for j, value in enumerate(q):
            lo, hi = limits[j]
            if not (math.isfinite(value) and lo <= value <= hi):
                out.append(f"{where}: joint {j + 1} = {_value(value, types[j])} outside its limits "
                           f"[{_value(lo, types[j])}, {_value(hi, types[j])}]")

    pose("home", plan.home)
    for name, values, top in (("speed", plan.speed, robot.max_speed), ("acceleration", plan.acceleration, None)):
        if len(values) != n:
            out.append(f"{name}: {len(values)} values, {robot.name} has {n} joints")
            continue
        for j, value in enumerate(values):
            unit = ("rad" if types[j] == "R" else "m") + ("/s" if name == "speed" else "/s²")
            if not (math.isfinite(value) and value > 0):
                out.append(f"{name} of joint {j + 1} = {value} {unit}, expected a number > 0")
            elif top is not None and value > top[j]:
                out.append(f"speed of joint {j + 1} = {value:.4f} {unit} above its max_speed {top[j]:.4f}")
    for i, step in enumerate(plan.steps):
        where = f"step {i} ({step.kind}, sweep {step.sweep}, joint {step.joint})"
        if step.index != i:
            out.append(f"{where}: index {step.index}, expected {i}")
        if step.kind not in STEP_KINDS:
            out.append(f"{where}: kind '{step.kind}', expected one of {', '.join(STEP_KINDS)}")
        if step.role not in ("fit", "check"):
            out.append(f"{where}: role '{step.role}', expected fit or check")
        if step.kind in ("sweep", "stream") and not 1 <= step.joint <= n:
            out.append(f"{where}: a sweep must name a joint 1..{n}")
        pose(where, step.q)
        if step.kind == "stream":
            if step.start is None or not all(v is not None and math.isfinite(v) and v > 0
                                             for v in (step.speed, step.acceleration)):
                out.append(f"{where}: a stream step needs its start, a speed > 0 and an acceleration > 0")
            else:
                pose(f"{where} start", step.start)
                if 1 <= step.joint <= n and step.speed > robot.max_speed[step.joint - 1]:
                    out.append(f"{where}: speed {step.speed:.4f} above the max_speed of joint {step.joint}")
    return out


def estimate_duration(plan: Plan, robot: RobotModel, measure_time_per_sample: float) -> float:
    """Seconds to run ``plan`` from the home pose: for each step the move from the previous pose (the
    slowest joint's trapezoidal profile at the plan's speed and acceleration), the settle time and
    ``samples_per_step`` × ``measure_time_per_sample``."""
    if not plan.steps:
        return 0.0
    q = np.array([plan.home, *(s.q for s in plan.steps)])
    moves = motion_time(np.diff(q, axis=0), plan.speed, plan.acceleration).max(axis=1)
    per_step = plan.settle_time + plan.samples_per_step * measure_time_per_sample
    return float(moves.sum() + len(plan.steps) * per_step)
