"""Motion rehearsal (``acquire --tracker none``): move the arm through a checked plan, measuring nothing.

The plan is the one a real session would run, built with reduced speeds (``--speed-fraction``, 0.25 by
default in this mode). The loop only sequences: wait until the robot is ready, move to each step, next; every
move has the site's move timeout; a robot fault or a lost connection stops the motion and ends the run as
failed; Ctrl-C, SIGTERM or SIGHUP stops the motion and ends it as aborted. Nothing is recorded but how the run
ended (returned, and logged by the caller).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from acquire.running.orchestrator import RunResult, StopRequest
from common import stop_signals
from drivers.base import Robot, RobotState
from drivers.errors import ConnectionFailed, DeviceTimeout, RobotFault
from kinematics.joint_errors import Coupling
from session.plan import Plan, Step


def rehearse(robot: Robot, plan: Plan, move_timeout: float, stop: StopRequest,
             on_step: Callable[[Step, int, int], None] | None = None, coupling: Coupling | None = None) -> RunResult:
    """Move ``robot`` through every step of ``plan`` in order at the plan's speeds; ``move_timeout`` s per move.

    ``on_step(step, done, total)`` after each move; ``coupling``: the robot's (its controller is commanded the
    readings that give each step's DH values). Returns how the run ended (``recorded`` counts the steps
    reached; ``missing`` is 0: nothing is measured)."""
    stop.on_request = robot.stop
    reached = 0
    try:
        for step in plan.steps:
            if stop.requested:
                return RunResult("aborted", stop.reason, reached, 0)
            state = robot.state()
            if state is not RobotState.READY:
                raise RobotFault(f"robot is not ready ({state.value}) before step {step.index}")
            q = step.q if coupling is None else coupling.readings_from_dh(np.array([step.q]))[0]
            robot.move_joints(q, plan.speed, plan.acceleration, move_timeout)
            if stop.requested:
                return RunResult("aborted", stop.reason, reached, 0)
            reached += 1
            if on_step is not None:
                on_step(step, reached, len(plan.steps))
    except (RobotFault, ConnectionFailed, DeviceTimeout) as exc:
        robot.stop()
        if stop.requested:
            return RunResult("aborted", stop.reason, reached, 0)
        return RunResult("failed", f"{type(exc).__name__}: {exc}", reached, 0)
    except KeyboardInterrupt as exc:  # a second stop signal
        robot.stop()
        return RunResult("aborted", stop_signals.reason_of(exc), reached, 0)
    return RunResult("complete", "", reached, 0)
