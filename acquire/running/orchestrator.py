"""The acquisition loop: move, wait until still, read the joints, measure, reject outliers, record.

A plain loop over the plan's unrecorded steps (a continuous sweep, kind ``stream``, is one step:
acquire/running/stream_loop.py) (so a resumed session continues where it stopped), then
one more attempt at each step recorded as missing (the first attempt stays in the session). Each step is
committed to the session before the next move. Tracker failures are retried a bounded number
of times, then the step is recorded as missing and the run goes on; robot faults, lost connections and any other
device error (one a continuous sweep cannot go on with) stop the motion, end the run as failed and return (the
session says how to resume); Ctrl-C, SIGTERM or SIGHUP
stops the motion at once and ends the run as aborted. Every device call has a timeout.

The plan is in DH joint values; a robot whose controller reports coupled readings (the session's ``coupling``,
e.g. FANUC J2/J3) is commanded the readings that give them, and its readings are recorded as they come. A
tracker that sees several points gives readings of each (``tp``): each point is averaged on its own, and a
step is recorded when at least one point was seen.
"""

from __future__ import annotations

import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from acquire.running.session import Session
from common import stop_signals
from drivers.averaging import mean_orientation, robust_mean
from drivers.base import Correction, Robot, RobotState, Tracker, TrackerReading
from drivers.clock import Clock
from drivers.errors import ConnectionFailed, DeviceTimeout, DriverError, MeasurementError, RobotFault
from identify.estimator.geometry import circle_2d_algebraic, perpendicular_basis, plane_from_points
from session.plan import Plan, Step
from session.records import FrameRecord, PointRecord, StepRecord

Array = NDArray[np.float64]

OUTLIER_SIGMAS = 5.0  # a sample farther than this many robust sigmas from the step's median is rejected


@dataclass(frozen=True)
class Timeouts:
    """Seconds allowed for each kind of wait."""

    move: float = 120.0
    settle: float = 10.0
    measure: float = 10.0


@dataclass(frozen=True)
class RunResult:
    """How a run ended: ``outcome`` complete / aborted / failed, with ``reason``; steps recorded for the first
    time in this run, and how many steps of the session are still missing."""

    outcome: str
    reason: str
    recorded: int
    missing: int


@dataclass(frozen=True)
class Progress:
    """What the progress display shows after each step."""

    step: Step
    done: int
    total: int
    elapsed: float
    remaining: float
    samples: int
    status: str
    residual: float | None
    again: bool = False  # a step recorded missing, measured once more: ``done``/``total`` count that pass


def average_readings(readings: list[TrackerReading]) -> tuple[Array, float | None, NDArray[np.bool_]]:
    """Mean TP (m) of the readings kept after rejecting outliers (:func:`drivers.averaging.robust_mean`), its
    per-axis standard uncertainty (m; None for fewer than 3 kept readings without a device sigma), and the mask
    of kept readings."""
    mean, spread_sigma, used = robust_mean(np.array([r.position for r in readings], dtype=float), OUTLIER_SIGMAS)
    device = [r.sigma for r in readings if r.sigma is not None]
    # the device's own figure is steadier than the spread of a handful of readings; use the spread only
    # when the device gives none
    if device:
        shared = [r.shared for r in readings if r.shared is not None]
        return mean, mean_sigma(float(np.median(device)), float(np.median(shared)) if shared else 0.0,
                                int(used.sum())), used
    return mean, (spread_sigma if used.sum() >= 3 else None), used


def mean_sigma(sigma: float, shared: float, n: int) -> float:
    """Per-axis standard uncertainty of the mean of ``n`` readings of one still view, each of ``sigma`` of which
    ``shared`` (in quadrature) is common to all of them (TrackerReading.shared): only the rest averages down."""
    if shared == 0.0:
        return sigma / np.sqrt(n)  # independent readings: exactly as before
    return float(np.sqrt(max(sigma**2 - shared**2, 0.0) / n + shared**2))


def average_points(readings: list[TrackerReading]) -> tuple[list[PointRecord], list[bool]]:
    """Each tracked point's readings averaged apart (:func:`average_readings`): the points in ascending id, and
    the kept flag of every reading (parallel to ``readings``)."""
    used = [False] * len(readings)
    points = []
    for tp in sorted({r.tp for r in readings}):
        mine = [k for k, r in enumerate(readings) if r.tp == tp]
        mean, sigma, kept = average_readings([readings[k] for k in mine])
        for k, keep in zip(mine, kept, strict=True):
            used[k] = bool(keep)
        points.append(PointRecord(tp, tuple(float(v) for v in mean), sigma, int(kept.sum()), int((~kept).sum())))
    return points, used


def average_frames(readings: list[TrackerReading], used: list[bool]) -> tuple[FrameRecord, ...]:
    """Each tracked point's averaged target-frame orientation over its kept readings that carry one (full-pose
    devices; empty otherwise): the chordal mean, with the device's sigma_r over sqrt(kept) when it states one (its
    shared part not divided: :func:`mean_sigma`), else the readings' spread (None for fewer than 3)."""
    out = []
    for tp in sorted({r.tp for r in readings if r.rotvec is not None}):
        mine = [r for r, keep in zip(readings, used, strict=True) if keep and r.tp == tp and r.rotvec is not None]
        if not mine:
            continue
        mean, spread = mean_orientation(np.array([r.rotvec for r in mine], dtype=float))
        device = [r.sigma_r for r in mine if r.sigma_r is not None]
        shared = [r.shared_r for r in mine if r.shared_r is not None]
        sigma_r = (mean_sigma(float(np.median(device)), float(np.median(shared)) if shared else 0.0, len(mine))
                   if device else spread)
        out.append(FrameRecord(tp, tuple(float(v) for v in mean), sigma_r))
    return tuple(out)


def average_corrections(readings: list[TrackerReading], used: list[bool]) -> tuple[tuple[int, Correction], ...]:
    """Each tracked point's kept readings' shape-and-lens corrections averaged (drivers/base.py
    ``Correction.mean``), for a camera that makes them (empty otherwise)."""
    out = []
    for tp in sorted({r.tp for r in readings if r.correction is not None}):
        mine = [r.correction for r, keep in zip(readings, used, strict=True) if keep and r.tp == tp]
        if mine and all(c is not None for c in mine):
            out.append((tp, Correction.mean(mine)))
    return tuple(out)


class StopRequest:
    """Set by a stop signal (Ctrl-C, SIGTERM or SIGHUP: common/stop_signals.py); the loop checks it between
    phases. A second signal raises at once."""

    def __init__(self) -> None:
        self.requested = False
        self.signum: int | None = None
        self.on_request: Callable[[], None] | None = None

    @property
    def reason(self) -> str:
        """Why the run stopped, as the session records it: ``stopped by the operator (Ctrl-C)``, ``stopped by
        SIGTERM``..."""
        return stop_signals.reason(self.signum)

    def request(self, signum: int = signal.SIGINT) -> None:
        if self.requested:
            raise KeyboardInterrupt if signum == signal.SIGINT else stop_signals.Stopped(signum)
        self.requested = True
        self.signum = signum
        if self.on_request is not None:
            self.on_request()

    @contextmanager
    def installed(self) -> Iterator[StopRequest]:
        """Route the stop signals to :meth:`request` while inside the block (main thread only)."""
        with stop_signals.routed(self.request):
            yield self


class Orchestrator:
    """Runs a session's remaining steps on a robot and a tracker."""

    def __init__(
        self,
        robot: Robot,
        tracker: Tracker,
        session: Session,
        clock: Clock,
        timeouts: Timeouts = Timeouts(),
        retries: int = 3,
        on_progress: Callable[[Progress], None] | None = None,
        stop: StopRequest | None = None,
        stream_rate: float = 250.0,
        on_start: Callable[[Step, int, int, bool], None] | None = None,
    ) -> None:
        self.robot, self.tracker, self.session, self.clock = robot, tracker, session, clock
        self.timeouts, self.retries = timeouts, retries
        self.on_progress = on_progress
        self.on_start = on_start  # (step, number in its pass, steps in the pass, measured again?) before each step
        self.stop = stop or StopRequest()
        self.plan: Plan = session.plan
        self.coupling = session.coupling
        self.stream_rate = stream_rate  # Hz asked of a streaming tracker (continuous sweeps)

    def run(self) -> RunResult:
        """Record every remaining step of the plan, then measure once more each step recorded as missing (this
        run's or earlier runs'; the first attempt is kept in the session); returns how the run ended (the
        session has it too). Progress counts the plan's steps that remain in this run (a total that does not
        change), then, in a pass of their own, the steps measured again."""
        self.stop.on_request = self.robot.stop
        self.session.begin_run()
        recorded = 0
        done = self.session.recorded_indices()
        todo = [(s, False) for s in self.plan.steps if s.index not in done]
        retakes = [self.plan.steps[i] for i in self.session.missing_indices()]
        total = len(todo)
        started = self.clock.now()
        sweep_points: dict[int, list[Array]] = {}
        count = 0
        try:
            while todo or retakes:
                if not todo:  # the main pass is over: every step missing now, once, counted on their own
                    todo = [(s, True) for s in retakes]
                    retakes = []
                    count, total = 0, len(todo)
                    self.session.event("remeasure", f"measuring {len(todo)} missing step(s) again: "
                                       + ", ".join(str(s.index) for s, _ in todo))
                step, retake = todo.pop(0)
                count += 1
                if self.stop.requested:
                    return self._end("aborted", self.stop.reason, recorded)
                if self.on_start is not None:
                    self.on_start(step, count, total, retake)
                record = self._do_step(step)
                if self.stop.requested and record.status != "ok":
                    return self._end("aborted", self.stop.reason, recorded)
                if retake:
                    self.session.retake_step(record)
                else:
                    self.session.record_step(record)
                    recorded += 1
                    if record.status != "ok":
                        retakes.append(step)
                if self.on_progress is not None:
                    self.on_progress(replace(self._progress(step, record, count, total, started, sweep_points),
                                             again=retake))
        except DriverError as exc:  # a robot fault, a lost link, a timeout, or any other device error (e.g. a
            self.robot.stop()      # tracker status a continuous sweep cannot go on with): the run ends resumable
            if self.stop.requested:  # the operator's stop interrupted the motion: not a fault
                return self._end("aborted", self.stop.reason, recorded)
            kind = {RobotFault: "robot fault", ConnectionFailed: "connection lost", DeviceTimeout: "timeout"}
            label = next((v for k, v in kind.items() if isinstance(exc, k)), "device error")
            self.session.event(label, str(exc))
            return self._end("failed", f"{label}: {exc}", recorded)
        except KeyboardInterrupt as exc:  # a second stop signal
            self.robot.stop()
            return self._end("aborted", stop_signals.reason_of(exc), recorded)
        return self._end("complete", "", recorded)

    def _end(self, outcome: str, reason: str, recorded: int) -> RunResult:
        self.session.end_run(outcome, reason)
        return RunResult(outcome, reason, recorded, len(self.session.missing_indices()))

    def _do_step(self, step: Step) -> StepRecord:
        if step.kind == "stream":  # a continuous sweep: acquire/running/stream_loop.py
            from acquire.running.stream_loop import run_stream

            return run_stream(self.robot, self.tracker, self.session, self.clock, step, self.plan, self.timeouts,
                              self.stop, lambda q: self._command(replace(step, q=q)), self.stream_rate)
        t_start = self.clock.now()
        state = self.robot.state()
        if state is not RobotState.READY:
            raise RobotFault(f"robot is not ready ({state.value}) before step {step.index}")
        q_cmd = self._command(step)
        self.robot.move_joints(q_cmd, self.plan.speed, self.plan.acceleration, self.timeouts.move)
        if self.stop.requested:
            return self._missing(step, q_cmd, t_start, "stopped by the operator")
        self.robot.wait_until_still(self.plan.settle_time, self.timeouts.settle)
        q_act = tuple(float(v) for v in self.robot.read_joints())
        readings, reason = self._measure(step)
        if not readings:
            return self._missing(step, q_cmd, t_start, reason, q_act)
        points, used = average_points(readings)
        several = getattr(self.tracker, "points", 1) > 1 or any(r.tp != 1 for r in readings)
        return StepRecord.from_step(
            step, q_cmd=q_cmd, q_act=q_act, position=points[0].position, sigma=points[0].sigma, samples=sum(used),
            rejected=len(used) - sum(used), status="ok", reason="", t_start=t_start, t_end=self.clock.now(),
            readings=readings, used=used, points=tuple(points) if several else (),
            frames=average_frames(readings, used), corrections=average_corrections(readings, used),
        )

    def _command(self, step: Step) -> tuple[float, ...]:
        """The joint readings to command for ``step`` (its DH values through the coupling, if any)."""
        if self.coupling is None:
            return step.q
        return tuple(float(v) for v in self.coupling.readings_from_dh(np.array([step.q]))[0])

    def _missing(self, step: Step, q_cmd: tuple[float, ...], t_start: float, reason: str,
                 q_act: tuple[float, ...] | None = None) -> StepRecord:
        return StepRecord.from_step(step, q_cmd=q_cmd, q_act=q_act, position=None, sigma=None, samples=0,
                                    rejected=0, status="missing", reason=reason, t_start=t_start,
                                    t_end=self.clock.now())

    def _measure(self, step: Step) -> tuple[list[TrackerReading], str]:
        """Readings of the step, retried up to ``retries`` times on measurement errors and timeouts."""
        reason = ""
        for attempt in range(self.retries + 1):
            try:
                return self.tracker.measure(self.plan.samples_per_step, self.timeouts.measure), ""
            except (MeasurementError, DeviceTimeout) as exc:
                reason = f"{type(exc).__name__}: {exc}"
                self.session.event("retry", f"step {step.index}, attempt {attempt + 1}: {reason}")
                if self.stop.requested:
                    break
        return [], f"tracker failed {self.retries + 1} times ({reason})"

    def _progress(self, step: Step, record: StepRecord, count: int, total: int, started: float,
                  sweep_points: dict[int, list[Array]]) -> Progress:
        elapsed = self.clock.now() - started
        remaining = elapsed / count * (total - count)
        residual = None
        first = record.positions().get(1)  # the same point all along the sweep
        if first is not None and step.kind == "sweep" and self.plan.joint_types[step.joint - 1] == "R":
            pts = sweep_points.setdefault(step.sweep, [])
            pts.append(np.array(first[0]))
            if len(pts) >= 5:
                residual = _circle_residual(np.array(pts))
        return Progress(step, count, total, elapsed, remaining, record.samples, record.status, residual)


def _circle_residual(points: Array) -> float | None:
    """RMS distance (m) of a sweep's points so far from a circle: a live sanity check, so the closed-form
    plane + algebraic fit (microseconds) rather than the identification's iterative one."""
    plane = plane_from_points(points)
    e1, e2 = perpendicular_basis(plane.normal)
    rel = points - plane.centroid
    xy = np.column_stack([rel @ e1, rel @ e2])
    try:
        centre, radius = circle_2d_algebraic(xy)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError):
        return None
    radial = np.linalg.norm(xy - centre, axis=1) - radius
    return float(np.sqrt(np.mean(radial**2 + (rel @ plane.normal) ** 2)))
