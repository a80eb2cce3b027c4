"""``acquire``: plan, move, measure and record a session, then identify (the operator's main job).

Its options, subcommands and exit codes: acquire/commands/options.py (``acquire --help``). The run itself, its progress
and what a complete session leaves beside it (result YAML, HTML report): acquire/running/runner.py.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import sys
import time
from pathlib import Path

from acquire.commands.options import build_parser
from acquire.commands.prepare import (
    UsageError,
    check_start,
    check_units,
    confirm,
    motion_problems,
    open_devices,
    site_from_args,
    tracker_site,
    without_faults,
)
from acquire.planning.plan import check_plan, estimate_duration, plan_clearance
from acquire.planning.plan_continuous import estimate_continuous_duration
from acquire.planning.plan_flange import flange_json, flange_lines, is_flange_camera, located_record
from acquire.planning.plan_modes import build_mode_plan, format_modes, mode_site, plan_mode
from acquire.planning.plan_report import format_clearance, format_plan, plan_json, predicted_accuracy
from acquire.planning.plan_target import TargetError, candidates, choose, format_tradeoff, replan_for_rate
from acquire.running.orchestrator import RunResult, StopRequest
from acquire.running.resume import ResumeRefused, resume_settings, session_model
from acquire.running.runner import finish, run_session
from acquire.running.session import Session
from acquire.running.stream_loop import check_streams
from common import stop_signals
from common.errors import InputError
from common.fit_width import say
from common.outputs import OutputError, check_outputs, check_target, same_file
from config.robots import ConfigError, RobotModel, load_robot
from config.site import SiteConfig
from drivers.clock import VirtualClock, WallClock
from drivers.errors import DriverError
from drivers.spec import RobotSpec, TrackerSpec
from session.plan import Plan
from session.schema import SessionError

log = logging.getLogger("acquire")


def run(args: argparse.Namespace) -> int:
    if args.probe:
        from acquire.commands.probe import probe

        return probe(args)
    _check_files(args)
    if args.log:  # our own handler: basicConfig would do nothing where logging is already configured
        handler = logging.FileHandler(args.log, encoding="utf-8")
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
        log.addHandler(handler)
        log.setLevel(logging.INFO)
    if not args.resume:
        return _run(args, None)
    if args.dry_run:
        with Session.open(args.resume) as session:  # a dry run only reads: no lock, works beside a writer
            return _run(args, session)
    # the write lock first: a second writer is refused here, before any device is opened
    with Session.open(args.resume, write=True) as session:
        return _run(args, session)


def _check_files(args: argparse.Namespace) -> None:
    """Refuse, before anything is opened or moved, files that would overwrite data: a new session that exists
    or has no folder, a result or report beside it that exists (without --force), a log that is an input."""
    if args.remeasure_missing and not args.resume:
        raise UsageError("--remeasure-missing goes with --resume SESSION")
    inputs = [p for p in (args.resume, args.config) if p is not None]
    for option, log_file in (("--log", args.log), ("--trace-io", args.trace_io)):  # appended to, never replaced
        if log_file is not None and any(same_file(log_file, p) for p in [*inputs, args.session] if p is not None):
            raise UsageError(f"{option} {log_file} is the session or the site file; a log is a file of its own")
    if args.resume or args.dry_run or args.session is None:
        return
    try:
        check_target(args.session, force=False, option="--session")
    except OutputError as exc:  # --force replaces derived files, never a session
        raise UsageError(str(exc).replace("pass --force to replace it",
                                          "a session file is never overwritten")) from None
    check_outputs(inputs, [("--session", args.session), ("result", args.session.with_suffix(".result.yaml")),
                           ("report", args.session.with_suffix(".report.html"))], args.force)


def _run(args: argparse.Namespace, session: Session | None) -> int:
    """Plan (or the session's plan), show it, then connect and record; ``session`` is the session to resume
    (open for writing, or for reading in a dry run) or None for a new one."""
    changes: tuple[str, ...] = ()
    model_note = ""
    if session is not None:
        if "verification" in (session.header.get("config") or {}):
            raise UsageError(f"{session.path} is a verification session: resume it with acquire verify --resume")
        options = {"--steps": args.steps, "--samples": args.samples, "--free-poses": args.free_poses}
        settings = resume_settings(session.header, args.robot, args.tracker, args.config, options)
        # a rehearsal's injected faults happened in the run that stopped; the resumed run starts clear
        robot_spec = settings.robot if args.robot else without_faults(settings.robot)
        tracker_spec = settings.tracker if args.tracker else without_faults(settings.tracker)
        site, plan, path, changes = settings.site, session.plan, args.resume, settings.changes
        base_site, no_stream = site, ""
        robot_model, model_note = session_model(session.header, robot_spec)
        if not args.dry_run and _died_after_its_last_step(session, args.remeasure_missing):
            if model_note:
                print(model_note)
            session.begin_run()  # closes the dead run; nothing connects or moves
            session.end_run("complete")
            return finish(RunResult("complete", "", 0, len(session.missing_indices())), session, args.resume,
                           robot_model)
        if not args.dry_run and _nothing_to_do(session, args.remeasure_missing):
            return 0
    else:
        # streams carry the fit: no free poses unless asked
        robot_spec = RobotSpec.parse(args.robot if args.robot is not None else "mock:ur5e").resolved()
        tracker_arg = args.tracker or "mock"
        tracker_spec = None if tracker_arg == "none" else TrackerSpec.parse(tracker_arg)
        base_site, no_stream = tracker_site(site_from_args(args), args, tracker_spec)  # what the tracker states
        site = mode_site(base_site, args.mode, args.free_poses)
        check_units(args, site, tracker_spec)
        path, plan, robot_model = None, None, None
    if args.json and not args.dry_run:
        raise UsageError("--json goes with --dry-run (the plan) or --probe (the readings)")
    flange = is_flange_camera(tracker_spec)
    if flange and (args.mode in ("continuous", "both") or args.target_accuracy is not None
                   or args.max_robot_time is not None):
        raise UsageError("a camera on the flange (mount=flange) plans stop-and-go views of its board: --mode "
                         "continuous/both, --target-accuracy and --max-robot-time are not for it")
    rehearsal = tracker_spec is None
    if tracker_spec is not None and tracker_spec.backend == "emscon":  # durations with the tracker's own time
        from drivers.trackers.emscon_options import parse_settings

        meas_time = parse_settings(tracker_spec, site).meas_time
        site = site.with_overrides(measure_time=max(meas_time, site.measure_time))
    if not args.dry_run and not rehearsal:
        from drivers.sim.pairing import check_pairing

        check_pairing(robot_spec, tracker_spec)  # before the plan is shown: one simulated world or none
    if robot_model is None:
        robot_model = load_robot(robot_spec.model)
    setup = None
    if flange:  # located (a new run), the camera's body and cable in the cell model, its views around the board
        assert tracker_spec is not None
        from acquire.commands.flange_locate import LocateEnded, locate
        from acquire.planning.flange_locate import rough_mount
        from acquire.planning.plan_flange import build_flange_plan, camera_site, flange_setup, recorded_setup

        setup = flange_setup(robot_model, tracker_spec, site, rough_mount(args.camera_mount,
                                                                          args.camera_mount_tolerance))
        if session is not None:  # a resume keeps its plan; the mount and board as the locate found them
            setup = recorded_setup(setup, session.header.get("config") or {}, plan)
        elif not args.dry_run:
            try:
                setup = locate(args, robot_spec, tracker_spec, site, robot_model, setup)
            except LocateEnded as exc:
                return exc.code
        site = camera_site(site, setup)
        if plan is None:
            plan = build_flange_plan(robot_model, site, setup)
    planned = args.target_accuracy is not None or args.max_robot_time is not None
    tradeoff = None
    if planned:
        site, plan, tradeoff = _plan_for_target(args, robot_model, session, rehearsal, base_site, no_stream)
    if plan is None:
        plan = build_mode_plan(args.mode, robot_model, site)
    elif args.mode is not None and args.mode != plan_mode(plan):
        raise UsageError(f"--mode {args.mode}: the session's plan is {plan_mode(plan)}; a resume keeps its plan")
    if plan.continuous and rehearsal:
        raise UsageError("--tracker none rehearses stop-and-go plans; use --mode step")
    problems = check_plan(plan, robot_model)
    clearance = plan_clearance(plan, robot_model, site)
    problems += motion_problems(plan, robot_model, robot_spec, clearance, site)
    if problems:
        for line in problems:
            print(f"acquire: plan refused: {line}", file=sys.stderr)
        return 2
    camera = None
    if tracker_spec is not None and tracker_spec.backend == "aruco" and not plan.continuous and not flange:
        from acquire.planning.camera_rehearsal import camera_assumptions  # OpenCV: only for a camera

        camera = camera_assumptions(plan, robot_model, site, tracker_spec, args.noise)
    if plan.continuous:
        duration = estimate_continuous_duration(plan, site.measure_time)
        accuracy = None
    else:
        measure_time = setup.reading_seconds if setup is not None else site.measure_time
        duration = estimate_duration(plan, robot_model, 0.0 if rehearsal else measure_time)
        accuracy = None if rehearsal or flange else predicted_accuracy(
            plan if camera is None else camera.seen_plan(plan), robot_model, site.tp_guess,
            site.tracker_noise if camera is None else camera.noise)
    flange_accuracy = None
    if setup is not None and (setup.located is not None or session is None):
        from acquire.planning.plan_flange import flange_accuracy as bound

        flange_accuracy = bound(robot_model, plan, setup)
    if args.json:
        doc = plan_json(plan, clearance, duration, accuracy)
        if camera is not None:
            doc["camera"] = camera.as_dict(plan)
        if setup is not None:
            doc["flange_camera"] = flange_json(plan, setup, flange_accuracy)
        print(json.dumps(doc, allow_nan=False))
        return 0
    if session is not None:
        say(_resuming(session))
    if model_note:
        say(model_note)
    say(format_plan(plan, robot_model, duration, accuracy, "camera" if camera is not None else "tracker"))
    if camera is not None:
        say("\n".join(["", *camera.lines(plan)]))
    if setup is not None:
        from acquire.planning.plan_flange import locate_seconds

        locate = locate_seconds(robot_model, site, setup) if setup.located is None and session is None else None
        say("\n".join(["", *flange_lines(plan, setup, flange_accuracy, locate)]))
    if tracker_spec is not None and tracker_spec.backend == "emscon":  # what the tracker will be asked to do
        from drivers.trackers.emscon_options import describe

        sweeps = sum(step.kind == "stream" for step in plan.steps)
        say("\n".join(["", *describe(tracker_spec, site, plan.samples_per_step, len(plan.steps) - sweeps, sweeps,
                                      site.stream_rate)]))
    say(format_clearance(clearance, plan, site))
    if tradeoff is not None:
        say(tradeoff)
    elif args.dry_run and not rehearsal and session is None:
        say("modes: stop-and-go only for a camera on the flange (its views keep the board in sight)" if flange
            else "modes: not compared for a camera (which streamed frames it would see is not modelled)" if camera
            else format_modes(robot_model, base_site, plan, args.free_poses, no_stream))
    if args.dry_run:
        print("dry run: nothing was connected or moved")
        return 0
    if rehearsal:
        return _rehearse(robot_spec, args, plan, site)
    if session is None:
        path = args.session or _default_session_path(robot_model.name)
    confirm(robot_spec, args, plan)
    opening = time.monotonic()
    robot, tracker, clock = open_devices(robot_spec, tracker_spec, args.realtime, site, args.trace_io, robot_model)
    connected = clock.now() - (time.monotonic() - opening)  # the connect's wall time, on the run's clock
    released = False
    try:
        first = 0 if session is None else session.next_index()
        if first is not None:
            check_start(robot, plan, robot_model, site, first, session)
            note, rate = check_streams(robot, tracker, plan, site.timeouts.measure, site.stream_rate)  # before a move
            if note:
                print(f"tracker: {note}")
                plan, line, refused = replan_for_rate(plan, robot_model, site, rate, args.target_accuracy,
                                                      session is not None)
                if refused:
                    print(f"acquire: plan refused: {line}", file=sys.stderr)
                    return 2
                print(f"plan: {line}")
        if session is None:
            config = {"robot_spec": str(robot_spec), "tracker_spec": str(tracker_spec), "site": site.as_dict(),
                      "command": " ".join(sys.argv),
                      **({"flange_locate": located_record(setup)} if setup and setup.located else {}),
                      **({"robot_model": robot_model.document} if robot_model.document is not None else {})}
            session = Session.create(path, plan, config, robot.identity(), tracker.identity(), robot_model.coupling)
        elif changes:
            session.set_connection(settings.connection(), "resumed with new connection details: " + "; ".join(changes))
        print(f"session: {path}")
        result = run_session(robot, tracker, session, clock, site, args.quiet)
        robot.close()  # released before the identification: it needs neither device
        tracker.close()
        released = True
        held = f"{clock.now() - connected:.1f} s"
        if isinstance(clock, VirtualClock):  # mock devices: their time is simulated, and says so
            held += f" simulated ({time.monotonic() - opening:.1f} s wall)"
        print(f"robot released: held {held} since connecting")
        return finish(result, session, path, robot_model)
    finally:
        if not released:
            robot.close()
            tracker.close()
        if session is not None:
            session.close()


def _plan_for_target(args: argparse.Namespace, robot: RobotModel, session: Session | None, rehearsal: bool,
                     site: SiteConfig, no_stream: str = "") -> tuple[SiteConfig, Plan, str]:
    """(site, plan, trade-off table) of ``--target-accuracy`` / ``--max-robot-time`` (acquire/planning/plan_target.py):
    the quickest candidate predicted to reach the target, or the most accurate within the time alone."""
    if session is not None:
        raise UsageError("--target-accuracy and --max-robot-time plan a new session; a resume keeps its plan")
    if rehearsal:
        raise UsageError("--target-accuracy and --max-robot-time plan a measurement; --tracker none measures nothing")
    if args.mode == "both":
        raise UsageError("--target-accuracy and --max-robot-time plan step or continuous sessions, not both")
    modes = ("step", "continuous") if args.mode is None else (args.mode,)
    if no_stream:
        modes = ("step",)  # a polled tracker: no continuous candidate
    found = candidates(modes, robot, site, args.steps, args.free_poses)
    try:
        chosen = choose(found, args.target_accuracy, args.max_robot_time)
    except TargetError as exc:
        say(format_tradeoff(found, None, args.target_accuracy, args.max_robot_time))
        raise UsageError(str(exc)) from None
    return chosen.site, chosen.plan, format_tradeoff(found, chosen, args.target_accuracy, args.max_robot_time)


def _default_session_path(robot: str) -> Path:
    """sessions/<robot>-<time>.session; the one folder of the default (not any folder the operator names) is
    made if missing."""
    folder = Path("sessions")
    with contextlib.suppress(FileExistsError):
        folder.mkdir()
    path = folder / f"{robot}-{time.strftime('%Y%m%d-%H%M%S')}.session"
    check_target(path, option="session")
    return path


def _resuming(session: Session) -> str:
    """What a resume continues: ``resuming S: 12 of 256 steps recorded (1 missing); run 1 aborted (stopped by
    SIGTERM)``; the plan printed after it is the session's own."""
    total = len(session.plan.steps)
    missing = len(session.missing_indices())
    text = f"resuming {session.path}: {len(session.recorded_indices())} of {total} steps recorded" + (
        f" ({missing} missing)" if missing else "")
    runs = session.runs()
    if runs:
        last = runs[-1]
        how = ("ended without closing (the process died)" if last.outcome == "running"
               else last.outcome + (f" ({last.reason})" if last.reason else ""))
        text += f"; run {last.id} {how}"
    return text + "; the session's plan:"


def _died_after_its_last_step(session: Session, remeasure: bool) -> bool:
    """True (after saying so) when every step is recorded (or only missing ones not to be measured again) but the
    process that recorded the last one died before it closed its run and identified the session."""
    if session.next_index() is not None or session.outcome() != "running":
        return False
    if remeasure and session.missing_indices():
        return False
    print(f"{session.path}: every step is recorded, but the run that recorded them ended without closing; "
          "closing it and identifying the session (nothing connects or moves)")
    return True


def _nothing_to_do(session: Session, remeasure: bool) -> bool:
    """True (after saying so) when a resumed session has every step recorded and no missing step is to be
    measured again: nothing connects, nothing moves."""
    if session.next_index() is not None:
        return False
    missing = session.missing_indices()
    total = len(session.plan.steps)
    if not missing:
        print(f"{session.path} is complete: all {total} steps recorded; nothing to do")
        return True
    if not remeasure:
        print(f"{session.path} is complete: {total} steps recorded, {len(missing)} missing (steps "
              f"{', '.join(map(str, missing))}); nothing moved. --remeasure-missing measures them again")
        return True
    return False


def _rehearse(robot_spec: RobotSpec, args: argparse.Namespace, plan: Plan, site: SiteConfig) -> int:
    """``--tracker none``: move through the plan at the reduced speed after confirmation, measuring nothing."""
    from acquire.running.rehearsal import rehearse
    from drivers.registry import open_robot

    confirm(robot_spec, args, plan, f"Rehearse the motion: move {robot_spec} through these {len(plan.steps)} "
            f"steps at {site.speed_fraction:g} x the default speed, measuring nothing? Type 'yes' to start: ")
    rig = None
    if robot_spec.backend == "mock":
        from drivers.sim.rig import SimulatedRig

        rig = SimulatedRig.from_spec(robot_spec, None, WallClock() if args.realtime else VirtualClock())
    robot = open_robot(robot_spec, rig=rig, site=site)
    robot.connect(site.timeouts.connect)
    try:
        check_start(robot, plan, load_robot(robot_spec.model), site, 0)
    except UsageError:
        robot.close()
        raise

    from acquire.running.orchestrator import Progress
    from acquire.running.progress import ProgressDisplay

    clock = rig.clock if rig is not None else WallClock()  # the rehearsal's own clock (virtual in mock mode)
    display = ProgressDisplay(plan, 0.0, args.quiet, simulated=isinstance(clock, VirtualClock))
    display.plan_steps(list(plan.steps))
    started = clock.now()

    def show(step, done: int, total: int) -> None:  # after each move: this step reached, the next one starts
        display.done(Progress(step, done, total, clock.now() - started, 0.0, 0, "reached", None))
        if done < total:
            display.start(plan.steps[done], done + 1, total)

    stop = StopRequest()
    try:
        if plan.steps:
            display.start(plan.steps[0], 1, len(plan.steps))
        with stop.installed():
            result = rehearse(robot, plan, site.timeouts.move, stop, show, load_robot(robot_spec.model).coupling)
    finally:
        display.close()
        robot.close()
    log.info("rehearsal %s%s; %d of %d steps reached", result.outcome, f" ({result.reason})" if result.reason else "",
             result.recorded, len(plan.steps))
    if result.outcome != "complete":
        print(f"acquire: rehearsal {result.outcome}: {result.reason}; {result.recorded} of {len(plan.steps)} steps "
              "reached", file=sys.stderr)
        return 130 if result.outcome == "aborted" else 1
    print(f"rehearsal complete: {result.recorded} steps reached, nothing measured or recorded")
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    with stop_signals.raising():  # SIGTERM and SIGHUP stop like Ctrl-C (common/stop_signals.py)
        return _main(argv)


def _main(argv: list[str]) -> int:
    try:
        if argv[:1] in (["export"], ["backup"]):  # acquire/commands/session_commands.py
            from acquire.commands.session_commands import backup, export

            return (export if argv[0] == "export" else backup)(argv[1:])
        if argv[:1] == ["verify"]:  # ISO 9283-style verification of a calibration: acquire/commands/verify_cli.py
            from acquire.commands.verify_cli import main as verify_main

            return verify_main(argv[1:])
        if argv[:1] in (["calibrate-camera"], ["print-board"]):  # camera tools: acquire/commands/camera_cli.py
            from acquire.commands.camera_cli import main as camera_main

            return camera_main(argv)
        return run(build_parser().parse_args(argv))
    except (UsageError, ResumeRefused, ConfigError, SessionError, InputError, DriverError, ValueError) as exc:
        print(f"acquire: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # outside a run (a run records its stop and prints its own line)
        print(f"acquire: {stop_signals.reason_of(exc)}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
