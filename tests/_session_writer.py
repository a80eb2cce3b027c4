"""Helper process for the session crash test (tests/session/test_session.py): records a small deterministic plan.

    python -m tests._session_writer write SESSION [SLEEP]   create or reopen SESSION and record every step left
    python -m tests._session_writer serve SESSION [SLEEP]   imports once, then per line "go" on stdin forks a
                                                            child that does "write" and prints "pid N"; the test
                                                            kills children with SIGKILL (a fresh interpreter
                                                            costs ~1 s of imports per kill)

While writing, a process prints "ready" once the session is open and a run begun, then the plan index of
each step after ``record_step`` has returned (so the test knows which steps must survive a kill). Every
value of step i is a function of i alone, so an interrupted and resumed session equals an uninterrupted one.
"""

from __future__ import annotations

import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from acquire.running.session import Session
from drivers.base import DeviceIdentity, TrackerReading
from session.plan import Plan, Step
from session.records import StepRecord

JOINT_TYPES = "RRR"
STEPS_PER_SWEEP = 10
HOME = (0.0, -1.0, 0.5)
ROBOT = DeviceIdentity("robot", "test-arm", "A-1", "1.0")
TRACKER = DeviceIdentity("tracker", "test-tracker", "T-9", "2.3", {"rate": "100 Hz"})
CONFIG = {"robot_spec": "mock:test-arm", "tracker_spec": "mock", "site": {"samples": 4}}


def small_plan() -> Plan:
    """Sweeps of joints 3, 2, 1 (10 steps each), a home check after each sweep and 4 free poses (2 check)."""
    steps: list[Step] = []

    def add(kind: str, sweep: int, joint: int, q: tuple[float, ...], role: str = "fit") -> None:
        steps.append(Step(len(steps), kind, sweep, joint, q, role))

    add("home", 0, 0, HOME, "check")
    for sweep, joint in enumerate((3, 2, 1), start=1):
        for k in range(STEPS_PER_SWEEP):
            q = list(HOME)
            q[joint - 1] += -1.2 + 2.4 * k / (STEPS_PER_SWEEP - 1)
            add("sweep", sweep, joint, tuple(q))
        add("home", 0, 0, HOME, "check")
    for k in range(4):
        add("free", 10 + k, 0, (0.3 * k, -0.7 + 0.1 * k, 0.2 * k), "check" if k % 2 else "fit")
    return Plan("test-arm", JOINT_TYPES, HOME, tuple(steps), samples_per_step=4, settle_time=0.0)


def record_for(plan: Plan, i: int) -> StepRecord:
    """The deterministic record of step ``i``: 3-6 readings, some rejected, every 9th step missing."""
    step = plan.steps[i]
    q_act = tuple(v + 1e-4 * math.sin(7 * i + j) for j, v in enumerate(step.q))
    t0 = 1.7e9 + 10.0 * i
    count = 3 + i % 4
    base = np.array([0.5 + 0.3 * math.cos(sum(q_act)), 0.3 * math.sin(sum(q_act)), 0.2 + 0.01 * i])
    readings = [TrackerReading(base + 1e-5 * np.array([math.sin(i + k), math.cos(i + k), math.sin(2 * k)]),
                               t0 + 1.0 + 0.1 * k, 2e-5 + 1e-6 * k, "ok") for k in range(count)]
    used = [not (k == count - 1 and i % 3 == 0) for k in range(count)]
    if i % 9 == 4:  # tracker failed: every reading garbage, nothing kept
        readings = [TrackerReading(np.array([math.nan, math.nan, math.nan]), t0 + 1.0 + 0.1 * k, None, "garbage")
                    for k in range(count)]
        return StepRecord.from_step(step, q_act=q_act, position=None, sigma=None, samples=0, rejected=count,
                                    status="missing", reason="no valid reading", t_start=t0, t_end=t0 + 2.0,
                                    readings=readings, used=[False] * count)
    kept = np.array([r.position for r, u in zip(readings, used, strict=True) if u])
    return StepRecord.from_step(step, q_act=q_act, position=tuple(kept.mean(axis=0)), sigma=2e-5 / math.sqrt(len(kept)),
                                samples=len(kept), rejected=count - len(kept), status="ok", reason="",
                                t_start=t0, t_end=t0 + 2.0, readings=readings, used=used)


def write(path: Path, sleep: float = 0.0, say=None) -> None:
    """Create (or reopen) the session at ``path`` and record every step not yet recorded, in plan order."""
    say = say or (lambda text: None)
    if path.exists():
        session = Session.open(path, write=True)
    else:
        session = Session.create(path, small_plan(), CONFIG, ROBOT, TRACKER)
    with session:
        session.begin_run()
        say("ready")
        while (i := session.next_index()) is not None:
            session.record_step(record_for(session.plan, i))
            say(str(i))
            if sleep:
                time.sleep(sleep)
        session.end_run("complete")


def _say(text: str) -> None:
    os.write(1, f"{text}\n".encode())  # unbuffered: a line printed is a line the test can read, even after a kill


def _serve(path: Path, sleep: float) -> None:
    for line in sys.stdin:
        if line.strip() != "go":
            break
        pid = os.fork()
        if pid == 0:  # the child: opens the session itself (nothing of SQLite is shared across the fork)
            code = 0
            try:
                write(path, sleep, _say)
            except BaseException as exc:
                _say(f"error {type(exc).__name__}: {exc}")
                code = 1
            os._exit(code)
        _say(f"pid {pid}")
        _, status = os.waitpid(pid, 0)
        _say(f"exit {os.waitstatus_to_exitcode(status)}")


if __name__ == "__main__":
    mode, target = sys.argv[1], Path(sys.argv[2])
    pause = float(sys.argv[3]) if len(sys.argv) > 3 else 0.0
    if mode == "serve":
        _serve(target, pause)
    else:
        write(target, pause, _say)
