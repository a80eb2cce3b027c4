"""``acquire`` with a camera on the flange: the locate phase before the views are planned (a new session only).

The operator has jogged the arm where the camera sees the whole board. Here: connect, read the start pose, build
the locate views (small turns of the wrist about it: acquire/planning/flange_locate.py), check them like every
plan (joint limits, speeds, the cell and the arm itself with the camera's body grown by the rough mount's tolerance
and its cable), show them and ask (a real robot), move and measure (acquire/running/locate.py: timeouts, Ctrl-C,
SIGTERM, SIGHUP), release the devices with the arm back at the start pose, then solve the mount and the board and
say how well they are known, or refuse in one line. The caller plans the views from the result and shows them
before anything else moves.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from acquire.commands.prepare import UsageError, confirm, motion_problems, open_devices
from acquire.planning.flange_bound import corner_noise
from acquire.planning.flange_locate import locate_plan, refusal, solve_mount
from acquire.planning.plan import check_plan, estimate_duration, plan_clearance
from acquire.planning.plan_flange import FlangeSetup, camera_site, located_setup
from acquire.planning.plan_report import format_clearance
from acquire.running.locate import run_locate
from acquire.running.orchestrator import StopRequest
from common.fit_width import say
from config.robots import RobotModel
from config.site import SiteConfig
from drivers.spec import RobotSpec, TrackerSpec
from kinematics.dh import frames_from_joints


class LocateEnded(Exception):
    """The locate phase stopped (the operator, a fault): ``code`` the exit code, the message already said."""

    def __init__(self, code: int) -> None:
        super().__init__(code)
        self.code = code


def locate(args: argparse.Namespace, robot_spec: RobotSpec, tracker_spec: TrackerSpec, site: SiteConfig,
           robot: RobotModel, setup: FlangeSetup) -> FlangeSetup:
    """Run the locate phase (module docstring) and return ``setup`` with the located mount and board about the
    start pose. UsageError (one line) when the plan is refused, the board is not seen or the solve is too poor;
    :class:`LocateEnded` when the motion was stopped."""
    checked = camera_site(site, setup, setup.rough.position)
    robot_dev, tracker, clock = open_devices(robot_spec, tracker_spec, args.realtime, site, args.trace_io, robot)
    opened = clock.now()
    try:
        start = np.asarray(robot_dev.read_joints(), dtype=float)
        if robot.coupling is not None:
            start = robot.coupling.dh_from_readings(start[None, :])[0]
        plan = locate_plan(robot, site, start)
        clearance = plan_clearance(plan, robot, checked)
        problems = check_plan(plan, robot) + motion_problems(plan, robot, robot_spec, clearance, checked)
        if problems:
            hint = "" if setup.rough.given else (
                f" (the camera's body grown by the default mount's {setup.rough.position * 1e3:.0f} mm tolerance: "
                "give --camera-mount and --camera-mount-tolerance from the bracket's drawing)")
            raise UsageError(f"locate refused at the start pose: {problems[0]}{hint}")
        duration = estimate_duration(plan, robot, setup.reading_seconds)
        turns = np.degrees(np.abs(np.array([s.q for s in plan.steps]) - start).max(axis=0))
        say("\n".join([f"locate phase: {len(plan.steps)} readings of the board about the start pose "
                       f"[{', '.join(f'{np.degrees(v):.1f}' for v in start)}]° (the wrist turned up to "
                       f"{', '.join(f'{t:.0f}' for t in turns)}° per joint), about {duration:.0f} s; the camera's "
                       f"body grown by the rough mount's tolerance ({setup.rough.position * 1e3:.0f} mm) in the cell",
                       format_clearance(clearance, plan, checked)]))
        confirm(robot_spec, args, plan, f"Locate the board: move {robot_spec} through these {len(plan.steps)} "
                "small wrist turns and back? Type 'yes' to start: ")
        stop = StopRequest()
        with stop.installed():
            run = run_locate(robot_dev, tracker, plan, site.timeouts, site.retries, stop, robot.coupling)
        held = clock.now() - opened
    finally:
        robot_dev.close()
        tracker.close()
    if run.outcome != "complete":
        print(f"acquire: locate {run.outcome}: {run.reason}; nothing recorded (run again to locate)", file=sys.stderr)
        raise LocateEnded(130 if run.outcome == "aborted" else 1)
    for line in run.missed:
        print(f"locate: board not seen at {line}")
    flanges = frames_from_joints(robot.nominal, np.array(run.q).reshape(-1, robot.n_joints))[:, -1]
    try:
        located = solve_mount(flanges, np.array(run.view).reshape(-1, 4, 4), np.array(run.sigma),
                              np.array(run.sigma_r), run.tried)
    except ValueError as exc:
        raise UsageError(f"locate refused: {exc}; jog the arm where the camera sees the whole board") from None
    sigma_px = corner_noise(setup.points, setup.camera.matrix, np.array(run.view), np.array(run.sigma_r),
                            setup.frames)
    say("\n".join([*located.lines(), f"locate: robot held {held:.1f} s; the camera's readings state a corner "
                   f"noise of {sigma_px:.3g} px"]))
    why = refusal(located, setup.rough)
    if why:
        raise UsageError(f"locate refused: {why}")
    return located_setup(setup, located, start, sigma_px)
