"""One continuous sweep (a plan step of kind ``stream``): move to the range start, start both streams, move the
joint through its range at constant speed while reading both streams, stop the streams, record.

Sequencing only: the devices stream (drivers/base.py: StreamingRobot, StreamingTracker), the session stores
(session/streams.py). Batches are committed at least every :data:`COMMIT_PERIOD` s of the clock (the
virtual clock in mock mode), so a crash loses at most that much. Every wait has a timeout: the move's own
duration plus the site's move timeout (also the bound given to the robot's ``start_move``). Faults: the tracker's
gaps (target lost) and the robot's (lost packets) are recorded with the samples and the sweep goes on; a robot
fault, a lost connection, a timeout or any other driver error stops the motion and the streams, marks the attempt
interrupted and re-raises (the run ends resumable; a resume redoes the sweep from its start); Ctrl-C
(``stop.requested``) stops the motion and returns a missing record.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable

from acquire.running.session import Session
from drivers.base import JointStreamBatch, RobotState, TrackerStreamBatch
from drivers.clock import Clock
from drivers.errors import DeviceTimeout, DriverError, RobotFault
from drivers.motion import motion_time
from session.plan import Plan, Step
from session.records import StepRecord
from session.streams import StreamRecorder

COMMIT_PERIOD = 0.5  # s between commits of the streamed samples (at most 1 s of data is ever at risk)
POLL_PERIOD = 0.02  # s between reads of the streams while the joint moves
STREAM_SLACK = 0.5  # s: the streams start this long before the move and stop this long after it (the ramps'
#   edges and the settling are recorded; acquire/planning/plan_continuous.py counts it in the duration)


class StreamingUnsupported(DriverError):
    """A device of the run cannot stream (continuous mode needs both to)."""


def _require_streams(robot, tracker) -> None:
    for device, method in ((robot, "start_joint_stream"), (tracker, "start_stream")):
        if not callable(getattr(device, method, None)):
            raise StreamingUnsupported(f"continuous mode needs a robot and a tracker that stream; "
                                       f"{type(device).__name__} does not (use --mode step)")


def check_streams(robot, tracker, plan: Plan, timeout: float, rate: float) -> tuple[str, float]:
    """Before anything moves: when ``plan`` has stream steps, start and stop both devices' streams once (``rate``
    Hz asked of the tracker, ``timeout`` s per call); StreamingUnsupported (one line) when either cannot stream,
    e.g. a polled serial profile or an I++ server without event reports. Returns the tracker's one line on the rate
    it took instead of ``rate`` ("" if none: ``rate_note`` of drivers/trackers/ipp_stream.py) and the rate it runs at
    (Hz; ``rate`` for a plan without streams)."""
    if not plan.continuous:
        return "", rate
    _require_streams(robot, tracker)
    taken = rate
    for device, start, stop in ((robot, lambda: robot.start_joint_stream(timeout), robot.stop_joint_stream),
                                (tracker, lambda: tracker.start_stream(rate, timeout), tracker.stop_stream)):
        try:
            started = start()
            stop(timeout)
        except (ValueError, DriverError) as exc:
            advice = "" if "--mode step" in str(exc) or "stream_rate" in str(exc) else " (use --mode step)"
            raise StreamingUnsupported(f"this plan streams, and {type(device).__name__} cannot: {exc}{advice}") \
                from None
        if device is tracker:
            taken = float(started)
    return str(getattr(tracker, "rate_note", "") or ""), taken


def run_stream(robot, tracker, session: Session, clock: Clock, step: Step, plan: Plan, timeouts,
               stop, command: Callable[[tuple[float, ...]], tuple[float, ...]], rate: float) -> StepRecord:
    """Record the stream step ``step`` (module docstring); ``command`` turns DH values into the readings to command,
    ``rate`` the tracker rate asked for (Hz), ``timeouts`` the orchestrator's. Returns the step's record (ok: the
    samples are in the session; missing: stopped by the operator, or no tracker sample at all)."""
    _require_streams(robot, tracker)
    assert step.start is not None and step.speed is not None and step.acceleration is not None
    t_start = clock.now()
    state = robot.state()
    if state is not RobotState.READY:
        raise RobotFault(f"robot is not ready ({state.value}) before step {step.index}")
    robot.move_joints(command(step.start), plan.speed, plan.acceleration, timeouts.move)
    if stop.requested:
        return _missing(step, command, t_start, clock, "stopped by the operator")
    robot.wait_until_still(plan.settle_time, timeouts.settle)
    recorder = StreamRecorder(session, step.index, clock.now())
    joints: list[JointStreamBatch] = []
    tracks: list[TrackerStreamBatch] = []
    last = [clock.now()]

    def pump(final: bool = False) -> None:
        joints.append(robot.stop_joint_stream(timeouts.measure) if final else robot.read_joint_stream())
        tracks.append(tracker.stop_stream(timeouts.measure) if final else tracker.read_stream())
        if final or clock.now() - last[0] >= COMMIT_PERIOD:
            recorder.commit(joints, tracks, clock.now())
            joints.clear()
            tracks.clear()
            last[0] = clock.now()

    speed = list(plan.speed)
    acceleration = list(plan.acceleration)
    speed[step.joint - 1], acceleration[step.joint - 1] = step.speed, step.acceleration
    streaming = False
    try:
        joint_rate = robot.start_joint_stream(timeouts.measure)
        streaming = True
        tracker_rate = tracker.start_stream(rate, timeouts.measure)
        recorder.set_rates(joint_rate, tracker_rate)
        _pump_for(clock, STREAM_SLACK, pump)
        span = step.q[step.joint - 1] - step.start[step.joint - 1]
        limit = float(motion_time(span, step.speed, step.acceleration)) + timeouts.move  # the sweep plus the slack
        deadline = clock.now() + limit  # of a move: the robot's own bound and this loop's are the same
        robot.start_move(command(step.q), speed, acceleration, limit)
        while not robot.motion_done():
            if stop.requested:
                robot.stop()
            elif clock.now() > deadline:
                robot.stop()
                raise DeviceTimeout(f"the continuous sweep of step {step.index} did not end within its timeout")
            clock.sleep(POLL_PERIOD)
            pump()
        if not stop.requested:
            _pump_for(clock, STREAM_SLACK, pump)
        pump(final=True)
        streaming = False
    except (DriverError, KeyboardInterrupt) as exc:  # a fault, a lost link, a timeout, a stream that cannot be read
        robot.stop()
        if streaming:
            with contextlib.suppress(DriverError, ValueError):
                pump(final=True)
        recorder.end("interrupted", f"{type(exc).__name__}: {exc}", clock.now())
        raise
    if stop.requested:
        recorder.end("interrupted", "stopped by the operator", clock.now())
        return _missing(step, command, t_start, clock, "stopped by the operator")
    recorder.end("complete", "", clock.now())
    q_act = tuple(float(v) for v in robot.read_joints())
    last_point = recorder.last_point()  # the arm at rest at the range end
    if last_point is None:
        return _missing(step, command, t_start, clock, "the tracker streamed no sample", q_act)
    position, sigma = last_point
    return StepRecord.from_step(step, q_cmd=command(step.q), q_act=q_act, position=position, sigma=sigma, samples=0,
                                rejected=0, status="ok", reason=f"{recorder.tracker_samples} tracker and "
                                f"{recorder.joint_samples} joint samples streamed", t_start=t_start, t_end=clock.now())


def _pump_for(clock: Clock, seconds: float, pump: Callable[[], None]) -> None:
    end = clock.now() + seconds
    while clock.now() < end:
        clock.sleep(min(POLL_PERIOD, end - clock.now()))
        pump()


def _missing(step: Step, command, t_start: float, clock: Clock, reason: str,
             q_act: tuple[float, ...] | None = None) -> StepRecord:
    return StepRecord.from_step(step, q_cmd=command(step.q), q_act=q_act, position=None, sigma=None, samples=0,
                                rejected=0, status="missing", reason=reason, t_start=t_start, t_end=clock.now())
