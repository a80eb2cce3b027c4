"""The continuous-motion plan (``acquire --mode continuous``): each sweep one constant-speed move while both devices
stream, plus a short stop-and-go part (pure, no devices).

Built from the stop-and-go plan of the same robot and site (:func:`acquire.planning.plan.build_plan`), so that the sweep
ranges are the same (the joint limits, the site's ``plan.sweep_ranges``, clipped to the collision-free interval
around home) and so are the free and check poses. Each swept joint gets a stop-and-go pose at the range start
(kind ``free``, a sweep id of its own: it pins the timing down and is a stop-and-go sample), then a ``stream``
step that moves the joint from the start to the range end at a constant speed. ``acquire --mode continuous`` asks
for none of the fitted free poses unless ``--free-poses`` is given: the streamed sweeps alone predict a smaller
held-out error than the whole stop-and-go plan (the dry run shows both).

**Check poses: as many as validation needs** (:func:`validation_poses`): enough that the held-out RMS is known to
about 20 % (5 poses with one reflector), at most the site's ``plan.check_poses``; they validate only (role
``check``), as in every plan.

**Order: the least travel.** Home first; then the sweeps and the check (and fitted free) poses in the tour of
:func:`acquire.planning.plan_order.order_visits`, which chooses the order of the joints, the direction of each sweep and
where the poses fall between the sweeps to make the moves between them short (they run at the sweeps' own speed
cap: :func:`transfer_speed`); home last, for the drift check. Home in between only where the plan needs it:
every direct move between two visits is checked against the cell, and one that would come too close goes
through home instead (clear by construction: the ranges are clear from home, and the poses are chosen reachable
from it). The move of a stream step is a joint-space line like every other move, so
:func:`acquire.planning.plan.plan_clearance` checks it the same way (sampled so that no body point travels more than
1 cm between checks); :func:`build_continuous_plan` also checks the TP's
distance to every revolute axis along it (1° steps) and, in a camera cell, that the camera sees the target
there (acquire/planning/camera_view.py), and keeps the longest stretch where both hold.

**Speed of a sweep** (rad/s or m/s of the swept joint): the model's ``max_speed`` times ``robot.speed_fraction``,
capped by :data:`STREAM_SPEED_CAP` (a conservative 1 rad/s, UR's default joint speed), by the site's
``plan.stream_speed`` and by the deflection model: the arm's dynamic deflection must stay below
:data:`DEFLECTION_SHARE` of the tracker noise. The model, for a
revolute joint j with link masses (``dynamics:`` in the robot model): the outboard links' inertia about the
axis at home, ``I_j = Σ_k m_k d_k²`` (kg·m², ``d_k`` the distance of link k's centre of mass from the axis),
a joint compliance :data:`JOINT_COMPLIANCE` (rad/(N·m)) and the TP's distance ``r_j`` from the axis give a TP
deflection ``δ = c · I_j · r_j · max(ω², α)`` under the acceleration α of the ramps and, conservatively, the
same for the centripetal load ω² at cruise. So ``ω ≤ sqrt(share·σ / (c·I_j·r_j))`` and α is capped the same
way. A model without link masses, or a prismatic joint, sweeps at :data:`DEFAULT_STREAM_SPEED` at most, and so
does every sweep of a stream at :data:`SPARSE_STREAM_RATE` or less (an I++ DME server at the standard's 10 reports
per second): such a stream's points are stamped by the host when they arrive, whose scheduling delay varies by
tenths of a millisecond and more, an error of that delay times the TP's speed (about 0.8 m/s at 1 rad/s on a UR5e);
a slower sweep makes it smaller and takes more reports per radian.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from acquire.planning.camera_view import visible
from acquire.planning.design import SUBSPACE_TOL, gram, whitened
from acquire.planning.plan import EVAL_POSES, HOME_SWEEP, Array, axis_distances_many, build_plan, tp_model
from acquire.planning.plan_order import order_visits
from config.cell import cell_from_config, first_contact
from config.robots import RobotModel
from config.site import SiteConfig
from drivers.motion import motion_time
from identify.simulators.simulate import random_poses
from kinematics.collision import Cell
from kinematics.dh import DHModel, frames_from_joints
from session.plan import Plan, Step

DEFLECTION_SHARE = 0.2  # the dynamic deflection stays below this share of the tracker noise
JOINT_COMPLIANCE = 1e-5  # rad/(N·m): a joint's assumed compliance (a UR-size harmonic drive, conservatively)
DEFAULT_STREAM_SPEED = 0.25  # rad/s (m/s): the cap without link masses, and for prismatic joints
STREAM_SPEED_CAP = 1.0  # rad/s (m/s): no sweep is faster, whatever the model allows
AXIS_CHECK_STEP = math.radians(1.0)  # rad (or 1 mm): the TP's axis distance is checked this finely along a sweep
STREAM_START_SLACK = 0.5  # s: streams start this long before the move and stop this long after it
SPARSE_STREAM_RATE = 10.0  # Hz: streams this slow (host-stamped) sweep at DEFAULT_STREAM_SPEED at most
HELD_OUT_RELATIVE_ERROR = 0.2  # the relative standard error of the held-out RMS the check poses aim for


#: one step of a plan being built: kind, joint, q, role, a stream's start, a stream's (speed, acceleration)
_Pose = tuple[str, int, tuple[float, ...], str, tuple[float, ...] | None, tuple[float, float] | None]


def deflection_limits(robot: RobotModel, model: DHModel, j: int, noise: float) -> tuple[float, float]:
    """(speed, acceleration) limits (rad/s, rad/s²) of joint ``j`` (1-based) from the deflection model of the
    module docstring at home, for tracker ``noise`` (m per axis); (inf, inf) where the model does not apply."""
    if robot.links is None or robot.joint_types[j - 1] != "R":
        return math.inf, math.inf
    frames = frames_from_joints(replace(model, base=np.eye(4)), np.asarray(robot.home, dtype=float))[0]
    axis_point, axis = frames[j - 1, :3, 3], frames[j - 1, :3, 2]
    inertia = 0.0
    for k in range(j, robot.n_joints + 1):  # links j..n move with joint j; link k's frame is DH frame k
        centre = frames[k, :3, :3] @ robot.links.centres[k - 1] + frames[k, :3, 3] - axis_point
        radial = centre - (centre @ axis) * axis
        inertia += float(robot.links.masses[k - 1]) * float(radial @ radial)
    reach = float(axis_distances_many(model, np.asarray(robot.home, dtype=float)[None, :])[0, j - 1])
    load = JOINT_COMPLIANCE * inertia * max(reach, 1e-3)
    if load <= 0:
        return math.inf, math.inf
    limit = DEFLECTION_SHARE * noise / load
    return math.sqrt(limit), limit


def stream_speed(robot: RobotModel, site: SiteConfig, plan: Plan, j: int) -> tuple[float, float]:
    """(speed, acceleration) of the continuous sweep of joint ``j`` (1-based): the module docstring's speed, and
    the plan's acceleration capped by the deflection model."""
    model = tp_model(robot, site.tp_guess)
    v_max, a_max = deflection_limits(robot, model, j, site.tracker_noise)
    speed = min(float(robot.max_speed[j - 1]) * site.speed_fraction, STREAM_SPEED_CAP, v_max)
    if math.isinf(v_max) or site.stream_rate <= SPARSE_STREAM_RATE:
        speed = min(speed, DEFAULT_STREAM_SPEED)
    if site.stream_speed is not None:
        speed = min(speed, site.stream_speed)
    return speed, min(plan.acceleration[j - 1], a_max)


def _clear_stretch(model: DHModel, home: Array, j: int, lo: float, hi: float, site: SiteConfig) -> tuple[float, float]:
    """The longest stretch of [lo, hi] (joint ``j``, the others at home) where the TP stays ``site.min_axis_distance``
    m off every revolute axis and, in a camera cell (``site.camera_pose``), the camera sees the target
    (:func:`acquire.planning.camera_view.visible`), checked every :data:`AXIS_CHECK_STEP`."""
    count = max(2, math.ceil((hi - lo) / AXIS_CHECK_STEP) + 1)
    values = np.linspace(lo, hi, count)
    q = np.tile(home, (count, 1))
    q[:, j - 1] = values
    ok = np.all(axis_distances_many(model, q) >= site.min_axis_distance, axis=1)
    if site.camera_pose is not None:
        ok &= visible(model, q, np.array(site.camera_pose), np.array(site.target_normal), site.camera_half_fov,
                      site.camera_max_tilt)[0]
    best, run = (0, -1), None
    for i, good in enumerate(ok):
        if good and run is None:
            run = i
        if (not good or i == count - 1) and run is not None:
            end = i if good else i - 1
            if end - run > best[1] - best[0]:
                best = (run, end)
            run = None
    if best[1] <= best[0]:
        return lo, lo
    return float(values[best[0]]), float(values[best[1]])


def _clear(cell: Cell | None, a: Array, b: Array) -> bool:
    """True when the straight joint move from ``a`` to ``b`` stays clear of the cell (always without one: the plan
    is then for a simulated robot only, and home is not needed between sweeps either)."""
    return cell is None or first_contact(cell, a, b) is None


def validation_poses(tracked_points: int = 1, relative_error: float = HELD_OUT_RELATIVE_ERROR) -> int:
    """How many check poses a continuous plan needs so that its held-out RMS is known to ``relative_error``
    (relative standard error) with ``tracked_points`` reflectors seen at each pose.

    The held-out RMS pools 3 residual components per pose and reflector; for N independent Gaussian components
    the mean square has a relative standard error sqrt(2/N), so the RMS has about sqrt(1/(2N)): N >= 1/(2e²)
    components, N / (3·tracked_points) poses (rounded up). At 20 %: 13 components, 5 poses with one reflector,
    2 with three. The home re-measurements are held out too, but are not counted: every sweep passes through
    home, so the fit has seen that pose. :func:`build_continuous_plan` counts one reflector: the plan is made
    before the tracker says how many it sees."""
    components = math.ceil(1.0 / (2.0 * relative_error**2))
    return max(1, math.ceil(components / (3 * max(1, tracked_points))))


def build_continuous_plan(robot: RobotModel, site: SiteConfig, rng_seed: int = 0) -> Plan:
    """The continuous plan of ``robot`` under ``site`` (module docstring): stream steps over the stop-and-go
    plan's sweep ranges, the range starts, :func:`validation_poses` check poses (at most ``plan.check_poses``)
    and any fitted free poses, visited in the short order of :func:`acquire.planning.plan_order.order_visits`, home
    first and last. Raises PlanError as :func:`acquire.planning.plan.build_plan` does."""
    base = build_plan(robot, replace(site, check_poses=min(site.check_poses, validation_poses())), rng_seed)
    transfer = transfer_speed(robot, site, base)
    base = replace(base, speed=tuple(float(v) for v in transfer))
    model = tp_model(robot, site.tp_guess)
    cell = cell_from_config(robot, site)
    home = np.asarray(base.home, dtype=float)
    notes = [n for n in base.notes if "sweep:" not in n and "check poses at random" not in n]
    sweeps: dict[int, list[Step]] = {}
    for s in base.steps:
        if s.kind == "sweep":
            sweeps.setdefault(s.sweep, []).append(s)
    ends: list[tuple[Array, Array]] = []
    motions: list[tuple[int, float, float]] = []  # joint, speed, acceleration of each sweep in ``ends``
    for steps in sweeps.values():
        j = steps[0].joint
        values = [s.q[j - 1] for s in steps]
        lo, hi = _clear_stretch(model, home, j, min(values), max(values), site)
        where = "the TP stays off every axis" + (" and the camera sees the target" if site.camera_pose else "")
        if hi - lo < 1e-6:
            notes.append(f"joint {j} continuous sweep left out: no stretch where {where}")
            continue
        if (lo, hi) != (min(values), max(values)):
            notes.append(f"joint {j} continuous sweep narrowed to the longest stretch where {where}")
        speed, acceleration = stream_speed(robot, site, base, j)
        start, end = home.copy(), home.copy()
        start[j - 1], end[j - 1] = lo, hi
        ends.append((start, end))
        motions.append((j, speed, acceleration))
        notes.append(f"joint {j}: one continuous sweep at {_speed_text(speed, robot.joint_types[j - 1])} "
                     f"(acceleration {_speed_text(acceleration, robot.joint_types[j - 1])}²), "
                     f"{motion_time(hi - lo, speed, acceleration):.1f} s")
    visited = [s for s in base.steps if s.kind == "free"]
    acceleration_all = np.asarray(base.acceleration, dtype=float)

    def move_time(a: Array, b: Array) -> float:
        return float(motion_time(np.asarray(b) - np.asarray(a), transfer, acceleration_all).max())

    tour = order_visits(home, ends, [np.asarray(s.q) for s in visited], move_time)
    poses: list[_Pose] = [("home", 0, tuple(home), "fit", None, None)]
    for visit in tour:
        if visit.sweep:
            start, end = ends[visit.item][::-1] if visit.reverse else ends[visit.item]
            j, speed, acceleration = motions[visit.item]
            poses.append(("free", 0, tuple(start), "fit", None, None))
            poses.append(("stream", j, tuple(end), "fit", tuple(start), (speed, acceleration)))
        else:
            s = visited[visit.item]
            poses.append((s.kind, s.joint, s.q, s.role, None, None))
    poses.append(("home", 0, tuple(home), "fit", None, None))
    poses, via_home = _via_home(cell, poses)
    if via_home:
        notes.append(f"{via_home} move(s) go through home: the direct move would come too close")
    n_check = sum(p[3] == "check" for p in poses)
    if n_check:
        notes.append(f"{n_check} check poses at random, held out: enough to know the held-out RMS to about "
                     f"{100 / math.sqrt(6 * n_check):.0f} % (acquire/planning/plan_continuous.py validation_poses)")
    steps: list[Step] = []
    sweep_id = 0
    for kind, joint, q, role, start, motion in poses:
        sweep_id += kind != "home"  # every stop-and-go pose and every stream a sweep id of its own
        speed, acceleration = motion if motion is not None else (None, None)
        steps.append(Step(len(steps), kind, HOME_SWEEP if kind == "home" else sweep_id, joint, tuple(q), role,
                          start, speed, acceleration))
    notes.insert(0, "continuous motion: every sweep is one constant-speed move recorded by both streams (speed "
                    f"from the model, plan.stream_speed and a deflection below {DEFLECTION_SHARE:g} x the tracker "
                    "noise), sweeps and poses in the order of least travel (acquire/planning/plan_continuous.py)")
    return replace(base, steps=tuple(steps), notes=tuple(notes))


def _via_home(cell: Cell | None, poses: list[_Pose]) -> tuple[list[_Pose], int]:
    """``poses`` (home first) with a home step before every stop-and-go pose whose direct move from the pose
    before would come too close, and how many were added. A stream step is not checked here: it starts at the
    range-start pose before it and moves one joint inside a range checked clear. Through home is always clear:
    range starts and ends lie in ranges clear from home, and check and free poses are chosen reachable from it."""
    out, count = [poses[0]], 0
    home = poses[0][2]
    for pose in poses[1:]:
        if pose[0] not in ("stream", "home") and out[-1][0] != "home" and not _clear(cell, np.asarray(out[-1][2]),
                                                                                     np.asarray(pose[2])):
            out.append(("home", 0, home, "fit", None, None))
            count += 1
        out.append(pose)
    return out, count


def transfer_speed(robot: RobotModel, site: SiteConfig, plan: Plan) -> Array:
    """Per joint, the speed (rad/s or m/s) of the moves between the sweeps of a continuous plan: the stop-and-go
    ``plan``'s, raised to the sweeps' own cap (:data:`STREAM_SPEED_CAP`, :data:`DEFAULT_STREAM_SPEED` for a
    prismatic joint, never above ``max_speed`` times ``robot.speed_fraction``): the arm already sweeps that fast
    through the same cell, the path (and so its collision check) does not depend on the speed, and every
    stop-and-go pose is measured after the settle time. A site that sets ``robot.speed`` keeps its speeds."""
    speed = np.asarray(plan.speed, dtype=float)
    if site.speed is not None:
        return speed
    cap = np.where(np.array([t == "R" for t in robot.joint_types]), STREAM_SPEED_CAP, DEFAULT_STREAM_SPEED)
    return np.maximum(speed, np.minimum(np.asarray(robot.max_speed, dtype=float) * site.speed_fraction, cap))


def _speed_text(speed: float, kind: str) -> str:
    return f"{math.degrees(speed):.1f}°/s" if kind == "R" else f"{speed * 1e3:.0f} mm/s"


def estimate_continuous_duration(plan: Plan, measure_time_per_sample: float) -> float:
    """Seconds to run a continuous ``plan`` from home: stop-and-go steps as
    :func:`acquire.planning.plan.estimate_duration` (move, settle, samples); a stream step: the move to its start at the
    plan's speed, the constant-speed move at its own speed and acceleration, and the streams' slack before and after
    it."""
    here = np.asarray(plan.home, dtype=float)
    total = 0.0
    speed, acc = np.asarray(plan.speed), np.asarray(plan.acceleration)
    for s in plan.steps:
        if s.kind == "stream":
            assert s.start is not None and s.speed is not None and s.acceleration is not None
            start = np.asarray(s.start)
            total += float(motion_time(start - here, speed, acc).max())
            total += float(motion_time(s.q[s.joint - 1] - start[s.joint - 1], s.speed, s.acceleration))
            total += 2 * STREAM_START_SLACK
        else:
            total += float(motion_time(np.asarray(s.q) - here, speed, acc).max())
            total += plan.settle_time + plan.samples_per_step * measure_time_per_sample
        here = np.asarray(s.q, dtype=float)
    return total


def stream_poses(plan: Plan, rate: float, most: int = 400) -> tuple[Array, Array]:
    """The joint values the streams of ``plan`` will sample at ``rate`` Hz (one tracker sample each): at most
    ``most`` per sweep, evenly along it, and each one's weight (how many samples it stands for): (m, n), (m,).
    The streams run :data:`STREAM_START_SLACK` s before and after each move, with the arm at rest at the range
    ends: those samples are the ends' weights (a tracker that reports only in motion has none of them)."""
    rows, weights = [], []
    rest = rate * STREAM_START_SLACK
    for s in plan.steps:
        if s.kind != "stream" or s.start is None or s.speed is None or s.acceleration is None:
            continue
        distance = s.q[s.joint - 1] - s.start[s.joint - 1]
        count = max(2, int(rate * float(motion_time(distance, s.speed, s.acceleration))))
        used = min(count, most)
        q = np.tile(np.asarray(s.start), (used, 1))
        q[:, s.joint - 1] += np.linspace(0.0, distance, used)
        rows.append(q)
        weight = np.full(used, count / used)
        weight[[0, -1]] += rest
        weights.append(weight)
    n = len(plan.home)
    if not rows:
        return np.zeros((0, n)), np.zeros(0)
    return np.vstack(rows), np.concatenate(weights)


def predicted_accuracy_continuous(plan: Plan, robot: RobotModel, tp_guess: object, noise: float, rate: float,
                                  rng_seed: int = 1, eval_poses: int = EVAL_POSES) -> dict[str, float]:
    """Cramér-Rao bound (m) of the RMS TP error at random held-out poses (as
    :func:`acquire.planning.plan_report.predicted_accuracy`) for a continuous plan: every streamed sample with the
    tracker ``noise`` (m per axis), the stop-and-go poses (range starts, fitted free poses and, in a plan of both modes,
    the stop-and-go sweeps) with noise / √samples. Keys ``with_free``, ``sweeps_only`` (the streams alone), ``samples``
    (streamed samples expected), ``noise``. The timing error of the streams is not in the bound (the identification
    estimates the clock offset)."""
    model = tp_model(robot, tp_guess)
    q_eval = random_poses(robot.limits, eval_poses, np.random.default_rng(rng_seed))
    q_stream, weight = stream_poses(plan, rate)
    q_steps = np.array([s.q for s in plan.steps if s.kind in ("free", "sweep") and s.role == "fit"]).reshape(
        -1, robot.n_joints)
    step_noise = noise / math.sqrt(max(plan.samples_per_step, 1))

    def bound(with_steps: bool) -> float:
        if not len(q_stream):
            return math.inf
        g_stream, g_steps, g_eval = whitened(model, q_stream, q_steps if with_steps else q_steps[:0], q_eval)
        info = gram(g_stream * np.sqrt(weight)[:, None, None]) / noise**2 + gram(g_steps) / step_noise**2
        values = np.linalg.eigvalsh(info)
        if values[0] <= SUBSPACE_TOL**2 * values[-1]:
            return math.inf
        return float(np.sqrt(np.trace(np.linalg.inv(info) @ gram(g_eval)) / len(q_eval)))

    return {"with_free": bound(True), "sweeps_only": bound(False), "samples": float(weight.sum()),
            "noise": float(noise)}
