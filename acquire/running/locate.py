"""The locate phase's motion (a flange camera: acquire/planning/flange_locate.py): move to each locate view, wait
until still, read the joints, measure the board; then back to the start pose.

Only sequencing, as the acquisition loop does it (acquire/running/orchestrator.py): every move, settle and
measurement has the site's timeout; a failed measurement is tried again up to ``retries`` times, then the view is
left out; a robot fault or a lost connection stops the motion and ends the phase as failed; Ctrl-C, SIGTERM or
SIGHUP stops the motion at once and ends it as aborted. Nothing is recorded in a session: the views only place
the camera and the board for the plan that follows.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from acquire.running.orchestrator import StopRequest, Timeouts, average_frames, average_points
from common import stop_signals
from drivers.base import Robot, RobotState, Tracker
from drivers.errors import ConnectionFailed, DeviceTimeout, MeasurementError, RobotFault
from kinematics.joint_errors import Coupling
from session.plan import Plan

Array = NDArray[np.float64]


@dataclass
class LocateRun:
    """How the locate phase ended (``outcome`` complete / aborted / failed, with ``reason``) and what it saw: per
    view that saw the board, the joints read ``q`` (DH values), the board's pose ``view`` (camera <- board, 4x4)
    and its stated ``sigma`` (m) and ``sigma_r`` (rad); ``tried`` views measured, ``missed`` reasons of the others."""

    outcome: str = "complete"
    reason: str = ""
    q: list[Array] = field(default_factory=list)
    view: list[Array] = field(default_factory=list)
    sigma: list[float] = field(default_factory=list)
    sigma_r: list[float] = field(default_factory=list)
    tried: int = 0
    missed: list[str] = field(default_factory=list)


def run_locate(robot: Robot, tracker: Tracker, plan: Plan, timeouts: Timeouts, retries: int, stop: StopRequest,
               coupling: Coupling | None = None) -> LocateRun:
    """Measure the board at every step of ``plan`` (the locate views, DH values; ``plan.home`` the start pose),
    then move back to the start pose (module docstring)."""
    stop.on_request = robot.stop
    run = LocateRun()

    def command(q: tuple[float, ...]) -> tuple[float, ...]:
        return q if coupling is None else tuple(float(v) for v in coupling.readings_from_dh(np.array([q]))[0])

    try:
        for step in (*plan.steps, None):
            if stop.requested:
                return _ended(run, "aborted", stop.reason)
            state = robot.state()
            if state is not RobotState.READY:
                raise RobotFault(f"robot is not ready ({state.value}) before locate view {run.tried + 1}")
            robot.move_joints(command(plan.home if step is None else step.q), plan.speed, plan.acceleration,
                              timeouts.move)
            if stop.requested:
                return _ended(run, "aborted", stop.reason)
            if step is None:  # back at the start pose
                break
            robot.wait_until_still(plan.settle_time, timeouts.settle)
            q = np.asarray(robot.read_joints(), dtype=float)
            if coupling is not None:
                q = coupling.dh_from_readings(q[None, :])[0]
            run.tried += 1
            _measure(tracker, run, q, timeouts.measure, retries, stop)
    except (RobotFault, ConnectionFailed, DeviceTimeout) as exc:
        robot.stop()
        if stop.requested:
            return _ended(run, "aborted", stop.reason)
        return _ended(run, "failed", f"{type(exc).__name__}: {exc}")
    except KeyboardInterrupt as exc:  # a second stop signal
        robot.stop()
        return _ended(run, "aborted", stop_signals.reason_of(exc))
    return run


def _ended(run: LocateRun, outcome: str, reason: str) -> LocateRun:
    run.outcome, run.reason = outcome, reason
    return run


def _measure(tracker: Tracker, run: LocateRun, q: Array, timeout: float, retries: int, stop: StopRequest) -> None:
    """One reading of the board at ``q`` into ``run`` (or the reason it was not seen)."""
    reason = ""
    for _ in range(retries + 1):
        try:
            readings = tracker.measure(1, timeout)
        except (MeasurementError, DeviceTimeout) as exc:
            reason = f"{type(exc).__name__}: {exc}"
            if stop.requested:
                break
            continue
        points, used = average_points(readings)
        frames = average_frames(readings, used)
        if not frames or points[0].sigma is None or frames[0].sigma_r is None:
            reason = "the camera gave no orientation with its uncertainty"
            break
        view = np.eye(4)
        view[:3, :3] = Rotation.from_rotvec(frames[0].rotvec).as_matrix()
        view[:3, 3] = points[0].position
        run.q.append(q)
        run.view.append(view)
        run.sigma.append(float(points[0].sigma))
        run.sigma_r.append(float(frames[0].sigma_r))
        return
    run.missed.append(f"view {run.tried}: {reason}")
