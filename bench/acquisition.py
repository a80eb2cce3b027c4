"""Acquisition benchmarks: the orchestrator's own overhead per step, and a whole mock session.

    python -m bench.acquisition [--repeats 3]

1. Overhead: a mock UR5e plan (6 x 36 sweep steps x 5 samples) run on simulated devices with zero
   latency, zero ringing and a virtual clock. Time spent inside device calls is measured and taken out;
   what remains is the orchestrator (loop, averaging, outlier rejection, progress) plus the session's
   durable commit, reported apart because it is the disk's fsyncs (session on the working disk and on
   tmpfs; rollback journal, ``synchronous=EXTRA``: bench/session_commit.py compares journal modes).
   Target: under 2 ms per step. Also with three tracked points per step (``points=3``: each averaged apart,
   three times the readings and the per-point rows).
2. End to end: ``acquire --robot mock:ur5e --tracker mock`` (the default plan: sweeps, free poses, home
   checks) in-process and as a fresh process, identification included. Target: under 3 s for
   6 x 36 x 5 (the default plan has more steps; both are shown).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from acquire.planning.plan import build_plan
from acquire.running.orchestrator import Orchestrator
from acquire.running.session import Session
from config.robots import load_robot
from config.site import SiteConfig
from drivers.clock import VirtualClock
from drivers.sim.rig import SimulatedRig
from drivers.sim.robot import SimulatedRobot
from drivers.sim.tracker import SimulatedTracker


class _Timed:
    """Wraps a device and adds the wall time of every call to ``spent``."""

    def __init__(self, device: object) -> None:
        self._device, self.spent = device, 0.0

    def __getattr__(self, name: str):
        attr = getattr(self._device, name)
        if not callable(attr):
            return attr

        def timed(*args, **kwargs):
            t = time.perf_counter()
            try:
                return attr(*args, **kwargs)
            finally:
                self.spent += time.perf_counter() - t

        return timed


def overhead(folder: Path, points: int = 1) -> tuple[float, float, int]:
    """(orchestrator ms per step without the commit, commit ms per step, steps) for a sweep-only plan, the rig
    carrying ``points`` reflectors."""
    robot_model = load_robot("ur5e")
    site = replace(SiteConfig.default(), free_poses=0, check_poses=0, home_check_every=0)
    plan = build_plan(robot_model, site)
    plan = replace(plan, steps=tuple(s for s in plan.steps if s.kind == "sweep"))
    rig = SimulatedRig("ur5e", clock=VirtualClock(), latency=0.0, ring=0.0, repeatability=0.0, points=points)
    robot, tracker = _Timed(SimulatedRobot(rig)), _Timed(SimulatedTracker(rig))
    robot.connect(1.0)
    tracker.connect(1.0)
    path = folder / f"bench-{time.time_ns()}.session"
    session = Session.create(path, plan, {}, robot.identity(), tracker.identity())
    commit = 0.0
    record = session.record_step

    def timed_record(rec):
        nonlocal commit
        t = time.perf_counter()
        record(rec)
        commit += time.perf_counter() - t

    session.record_step = timed_record  # type: ignore[method-assign]
    # with a progress consumer, so the live residual is part of the measured overhead
    orchestrator = Orchestrator(robot, tracker, session, rig.clock, on_progress=lambda p: None)  # type: ignore[arg-type]
    t0 = time.perf_counter()
    result = orchestrator.run()
    total = time.perf_counter() - t0
    session.close()
    path.unlink()
    steps = result.recorded
    own = total - robot.spent - tracker.spent - commit
    return own / steps * 1e3, commit / steps * 1e3, steps


def end_to_end(folder: Path) -> tuple[float, float, int]:
    """Seconds for the default mock session in-process and as a new process; steps recorded."""
    from acquire.commands.cli import main

    path = folder / f"e2e-{time.time_ns()}.session"
    t = time.perf_counter()
    assert main(["--robot", "mock:ur5e", "--tracker", "mock", "--session", str(path), "--quiet"]) == 0
    inproc = time.perf_counter() - t
    with Session.open(path) as s:
        steps = len(s.steps())
    path2 = folder / f"e2e2-{time.time_ns()}.session"
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "acquire.commands.cli", "--robot", "mock:ur5e", "--tracker", "mock",
                    "--session", str(path2), "--quiet"], check=True, capture_output=True)
    fresh = time.perf_counter() - t
    return inproc, fresh, steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    print(f"python {sys.version.split()[0]}, {time.strftime('%Y-%m-%d')}")
    missed = []
    for label, folder in (("working disk", Path(tempfile.gettempdir())), ("tmpfs /dev/shm", Path("/dev/shm"))):
        if not folder.exists():
            continue
        for points in (1, 3):
            runs = [overhead(folder, points) for _ in range(args.repeats)]
            own = np.median([r[0] for r in runs])
            commit = np.median([r[1] for r in runs])
            print(f"orchestrator overhead ({label}, {runs[0][2]} steps, {points} tracked point(s)): {own:.3f} ms/step "
                  f"own work, {commit:.3f} ms/step durable commit (fsync), target own < 2 ms")
            if own >= 2.0:
                missed.append(f"orchestrator overhead {own:.2f} ms/step on the {label} with {points} point(s)")
    with tempfile.TemporaryDirectory() as tmp:
        inproc, fresh, steps = end_to_end(Path(tmp))
    print(f"full mock UR5e session, default plan ({steps} steps x 5 samples) + identification: "
          f"{inproc:.2f} s in-process, {fresh:.2f} s as a new process (target < 3 s for 216 steps)")
    if inproc >= 3.0:
        missed.append(f"full mock session {inproc:.2f} s")
    if missed:
        sys.exit("TARGET MISSED: " + "; ".join(missed))


if __name__ == "__main__":
    main()
