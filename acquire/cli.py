"""``acquire``: plan, move, measure and record a session, then identify (the operator's main job).

    acquire --robot mock:ur5e --tracker mock            mock-mode rehearsal (simulated robot and tracker)
    acquire --robot ur5e@192.168.1.10 --tracker serial:/dev/ttyUSB0 --config site.yaml
    acquire --robot ur5e --tracker mock --dry-run      print the plan, its duration and accuracy; move nothing
    acquire --resume SESSION                            continue an interrupted session
    acquire export SESSION --csv out.csv                measurement CSV of a session
    acquire --tracker serial:/dev/ttyUSB0?protocol=polled-xyz --probe   check the tracker on site

Exit codes: 0 complete, 1 the run failed (robot fault, lost connection; resumable), 2 bad input or a
plan that breaks a limit, 130 stopped by the operator (resumable).
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import yaml

from acquire.orchestrator import Orchestrator, Progress, RunResult, StopRequest, Timeouts
from acquire.plan import Plan, build_plan, check_plan, estimate_duration, format_plan, predicted_accuracy
from acquire.session import Session, SessionError, factory_calibration
from config.robots import ConfigError, RobotModel, load_robot
from config.site import SiteConfig, load_site
from drivers.clock import VirtualClock, WallClock
from drivers.errors import DriverError
from drivers.spec import RobotSpec, TrackerSpec
from identify.factory import factory_reference
from identify.measurements import InputError
from identify.pipeline import identify
from identify.report import format_reference, format_report
from identify.result_io import result_to_dict

log = logging.getLogger("acquire")


class UsageError(Exception):
    """Bad input: one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="acquire", description=__doc__.splitlines()[0].replace("``", ""),
                formatter_class=argparse.RawDescriptionHelpFormatter, epilog="\n".join(__doc__.splitlines()[2:8]))
    p.add_argument("--robot", default="mock:ur5e", help="robot spec: ur5e, ur5e@HOST, mock:ur5e (mock:ur5e)")
    p.add_argument("--tracker", default="mock", help="tracker spec: serial:PORT?..., ipp://HOST, aruco:..., mock")
    p.add_argument("--config", type=Path, help="site YAML (hosts, tracker, sweep ranges, timeouts)")
    p.add_argument("--session", type=Path, help="session file to create (default sessions/<robot>-<time>.session)")
    p.add_argument("--resume", type=Path, metavar="SESSION", help="continue this session where it stopped")
    p.add_argument("--dry-run", action="store_true", help="print the plan and what it will reach; move nothing")
    p.add_argument("--yes", action="store_true", help="do not ask before moving a real robot")
    p.add_argument("--realtime", action="store_true", help="mock mode at the speed of a real run")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.add_argument("--log", type=Path, metavar="FILE", help="log every step and event to FILE")
    p.add_argument("--steps", type=int, help="steps per sweep (site default 36)")
    p.add_argument("--samples", type=int, help="tracker samples per step (site default)")
    p.add_argument("--free-poses", type=int, help="free poses added for the fit and validation")
    p.add_argument("--noise", type=float, help="tracker noise per axis, m, for the predicted accuracy")
    p.add_argument("--probe", action="store_true",
                   help="open the tracker, take --count readings, print them with their spread, and exit")
    p.add_argument("--count", type=int, default=10, help="readings taken by --probe (10)")
    p.add_argument("--json", action="store_true", help="with --probe: one JSON object per reading")
    p.add_argument("--trace-io", type=Path, metavar="FILE",
                   help="log every byte to and from the tracker (serial and I++ trackers)")
    return p


def _export(argv: list[str]) -> int:
    p = _Parser(prog="acquire export", description="Write a session's measurements as the CSV contract.")
    p.add_argument("session", type=Path)
    p.add_argument("--csv", type=Path, required=True)
    args = p.parse_args(argv)
    with Session.open(args.session) as session:
        rows = session.export_csv(args.csv)
    print(f"wrote {args.csv} ({rows} rows)")
    return 0


def _site(args: argparse.Namespace) -> SiteConfig:
    site = load_site(args.config) if args.config else SiteConfig.default()
    return site.with_overrides(steps_per_sweep=args.steps, samples_per_step=args.samples,
                               free_poses=args.free_poses, tracker_noise=args.noise)


def _without_faults(spec):
    """``spec`` without a mock backend's ``fault`` option."""
    if spec.backend != "mock" or "fault" not in spec.options:
        return spec
    return replace(spec, options={k: v for k, v in spec.options.items() if k != "fault"})


def _confirm(robot_spec: RobotSpec, args: argparse.Namespace, plan: Plan) -> None:
    """A real robot moves only after the operator has seen the plan and said yes (or passed --yes)."""
    if robot_spec.backend == "mock" or args.yes:
        return
    if not sys.stdin.isatty():
        raise UsageError("a real robot needs confirmation: run in a terminal or pass --yes after reading the plan")
    answer = input(f"Move {robot_spec} through these {len(plan.steps)} steps? Type 'yes' to start: ").strip()
    if answer.lower() != "yes":
        raise UsageError("not confirmed; nothing moved")


TRACED_BACKENDS = ("serial", "ipp")  # trackers whose byte stream --trace-io can log


def _open_tracker(tracker_spec: TrackerSpec, rig, site: SiteConfig, trace_io: Path | None):
    from drivers.registry import open_tracker

    if trace_io is not None and tracker_spec.backend not in TRACED_BACKENDS:
        raise UsageError(f"--trace-io logs the bytes of serial and I++ trackers, not of {tracker_spec.backend!r}")
    extra = {"trace_io": trace_io} if trace_io is not None else {}
    return open_tracker(tracker_spec, rig=rig, site=site, **extra)


def _open_devices(robot_spec: RobotSpec, tracker_spec: TrackerSpec, realtime: bool, site: SiteConfig,
                  trace_io: Path | None = None):
    from drivers.registry import open_robot

    clock = WallClock() if realtime or robot_spec.backend != "mock" else VirtualClock()
    rig = None
    if robot_spec.backend == "mock" or tracker_spec.backend == "mock":
        from drivers.sim import SimulatedRig

        rig = SimulatedRig.from_spec(robot_spec, tracker_spec, clock)
    robot = open_robot(robot_spec, rig=rig, site=site)
    tracker = _open_tracker(tracker_spec, rig, site, trace_io)
    robot.connect(site.timeouts.connect)
    tracker.connect(site.timeouts.connect)
    return robot, tracker, clock


def probe(args: argparse.Namespace) -> int:
    """The operator's first check on site: open the tracker, take readings, show them and their spread.

    Exit 0 when every reading worked, 1 when any failed (each failure is one line), 2 for bad input."""
    import json

    import numpy as np

    from drivers.errors import DeviceTimeout, MeasurementError

    if args.count < 1:
        raise UsageError(f"--count must be at least 1, got {args.count}")
    site = _site(args)
    tracker_spec = TrackerSpec.parse(args.tracker)
    rig = None
    if tracker_spec.backend == "mock" or str(tracker_spec).startswith("aruco:sim"):  # a simulated tracker
        # looks at a simulated robot standing at home
        from drivers.sim import SimulatedRig

        robot_spec = RobotSpec.parse(args.robot)
        robot_spec = robot_spec if robot_spec.backend == "mock" else RobotSpec.parse(f"mock:{robot_spec.model}")
        rig = SimulatedRig.from_spec(robot_spec, tracker_spec, VirtualClock())
    tracker = _open_tracker(tracker_spec, rig, site, args.trace_io)
    tracker.connect(site.timeouts.connect)
    points, failed = [], 0
    try:
        identity = tracker.identity()
        if not args.json:
            print(f"tracker: {identity.model}" + (f", serial {identity.serial}" if identity.serial else ""))
        for k in range(1, args.count + 1):
            try:
                reading = tracker.measure(1, site.timeouts.measure)[0]
            except (MeasurementError, DeviceTimeout) as exc:
                failed += 1
                print(f"reading {k}: failed: {type(exc).__name__}: {exc}", file=sys.stderr)
                continue
            p = np.asarray(reading.position, dtype=float)
            points.append(p)
            if args.json:
                print(json.dumps({"x": p[0], "y": p[1], "z": p[2], "timestamp": reading.timestamp,
                                  "sigma": reading.sigma, "status": reading.status}))
            else:
                print(f"reading {k}: x {p[0] * 1e3:.4f}  y {p[1] * 1e3:.4f}  z {p[2] * 1e3:.4f} mm  "
                      f"({reading.status})")
    finally:
        tracker.close()
    if points and not args.json:
        pts = np.array(points)
        spread = np.std(pts, axis=0, ddof=1) if len(pts) > 1 else np.zeros(3)
        worst = np.linalg.norm(pts - pts.mean(axis=0), axis=1).max()
        print(f"{len(pts)} of {args.count} readings; spread (std) x {spread[0] * 1e3:.4f}, y {spread[1] * 1e3:.4f}, "
              f"z {spread[2] * 1e3:.4f} mm; largest distance from the mean {worst * 1e3:.4f} mm")
    return 1 if failed else 0


def _progress_printer(quiet: bool):
    """Progress to the log always, and to the terminal unless ``quiet``."""
    tty = sys.stderr.isatty()

    def show(p: Progress) -> None:
        residual = f", sweep residual {p.residual * 1e3:.3f} mm" if p.residual is not None else ""
        what = f"joint {p.step.joint} sweep" if p.step.kind == "sweep" else p.step.kind
        line = (f"step {p.done}/{p.total} ({what}): {p.samples} samples, {p.status}; "
                f"elapsed {_hms(p.elapsed)}, remaining {_hms(p.remaining)}{residual}")
        log.info(line)
        if quiet:
            return
        if tty:
            sys.stderr.write("\r" + line[:150].ljust(150))
            sys.stderr.flush()
        elif p.done == p.total or p.done % 25 == 0:
            print(line, file=sys.stderr)

    return show


def _hms(seconds: float) -> str:
    seconds = max(0, round(seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


def _identify_session(session: Session, session_path: Path, robot: RobotModel) -> dict[str, Any]:
    meas = session.to_measurements()
    ident = identify(meas, robot.nominal)
    print(format_report(ident, robot.nominal, robot.name))
    calibration, why = factory_calibration(session.header)  # the controller's own, for comparison
    reference, note = factory_reference(calibration, why, robot.joint_types)
    if reference is not None or note:
        print(format_reference(ident, *reference) if reference is not None else f"note: {note}")
    doc = result_to_dict(ident, robot.nominal, robot.name, source=str(session_path))
    out = session_path.with_suffix(".result.yaml")
    out.write_text(yaml.safe_dump(doc, sort_keys=False, width=120), encoding="utf-8")
    print(f"result written to {out}")
    try:
        from identify.report_html import report_html
    except ImportError:
        print("note: no HTML report (it needs matplotlib: pip install 'dh-calib[report]')")
        return doc
    report = session_path.with_suffix(".report.html")
    report.write_text(report_html(ident, meas, robot.nominal, robot.name, session=session, source=str(session_path),
                                  reference=reference, reference_note=note or None), encoding="utf-8")
    print(f"report written to {report}")
    return doc


def run(args: argparse.Namespace) -> int:
    if args.probe:
        return probe(args)
    if args.log:  # our own handler: basicConfig would do nothing where logging is already configured
        handler = logging.FileHandler(args.log, encoding="utf-8")
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(message)s"))
        log.addHandler(handler)
        log.setLevel(logging.INFO)
    if args.resume:
        session = Session.open(args.resume)
        header = session.header
        # a rehearsal's injected faults happened in the run that stopped; the resumed run starts clear
        robot_spec = _without_faults(RobotSpec.parse(header["config"]["robot_spec"]))
        tracker_spec = _without_faults(TrackerSpec.parse(header["config"]["tracker_spec"]))
        site = SiteConfig.from_dict(header["config"]["site"])
        plan = session.plan
        path = args.resume
    else:
        site = _site(args)
        robot_spec, tracker_spec = RobotSpec.parse(args.robot), TrackerSpec.parse(args.tracker)
        session, path = None, None
        plan = None
    if not args.dry_run:
        from drivers.sim import check_pairing

        check_pairing(robot_spec, tracker_spec)  # before the plan is shown: one simulated world or none
    robot_model = load_robot(robot_spec.model)
    if plan is None:
        plan = build_plan(robot_model, site)
    problems = check_plan(plan, robot_model)
    if problems:
        for line in problems:
            print(f"acquire: plan refused: {line}", file=sys.stderr)
        return 2
    duration = estimate_duration(plan, robot_model, site.measure_time)
    accuracy = predicted_accuracy(plan, robot_model, site.tp_guess, site.tracker_noise)
    print(format_plan(plan, robot_model, duration, accuracy))
    if args.dry_run:
        print("dry run: nothing was connected or moved")
        return 0
    _confirm(robot_spec, args, plan)
    robot, tracker, clock = _open_devices(robot_spec, tracker_spec, args.realtime, site, args.trace_io)
    try:
        if session is None:
            path = args.session or Path("sessions") / f"{robot_model.name}-{time.strftime('%Y%m%d-%H%M%S')}.session"
            path.parent.mkdir(parents=True, exist_ok=True)
            config = {"robot_spec": str(robot_spec), "tracker_spec": str(tracker_spec), "site": site.as_dict(),
                      "command": " ".join(sys.argv)}
            session = Session.create(path, plan, config, robot.identity(), tracker.identity())
        print(f"session: {path}")
        stop = StopRequest()
        orchestrator = Orchestrator(robot, tracker, session, clock,
                                    Timeouts(site.timeouts.move, site.timeouts.settle, site.timeouts.measure),
                                    site.retries, _progress_printer(args.quiet), stop)
        with stop.installed():
            result = orchestrator.run()
        if not args.quiet and sys.stderr.isatty():
            sys.stderr.write("\n")
        return _finish(result, session, path, robot_model)
    finally:
        robot.close()
        tracker.close()
        if session is not None:
            session.close()


def _finish(result: RunResult, session: Session, path: Path, robot: RobotModel) -> int:
    log.info("run %s%s; %d step(s) recorded, %d missing", result.outcome,
             f" ({result.reason})" if result.reason else "", result.recorded, result.missing)
    if result.outcome != "complete":
        print(f"acquire: run {result.outcome}: {result.reason}", file=sys.stderr)
        print(f"acquire: {result.recorded} step(s) recorded this run; resume with: acquire --resume {path}",
              file=sys.stderr)
        return 130 if result.outcome == "aborted" else 1
    if result.missing:
        print(f"note: {result.missing} step(s) missing (tracker failures); the identification uses the rest")
    drift = session.drift()
    if len(drift) > 1:
        worst = max(d for _, d in drift)
        minutes = (drift[-1][0] - drift[0][0]) / 60
        print(f"home drift: {len(drift)} re-measurements over {minutes:.1f} min, largest {worst * 1e3:.4f} mm "
              "from the first")
    doc = _identify_session(session, path, robot)
    if doc["verdict"]["status"] == "fail":
        print("acquire: the identification FAILS its verdict: do not use this model (see the checks above)",
              file=sys.stderr)
        return 3
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    try:
        if argv[:1] == ["export"]:
            return _export(argv[1:])
        if argv[:1] in (["calibrate-camera"], ["print-board"]):  # camera tools: acquire/camera_cli.py
            from acquire.camera_cli import main as camera_main

            return camera_main(argv)
        return run(build_parser().parse_args(argv))
    except (UsageError, ConfigError, SessionError, InputError, DriverError, ValueError) as exc:
        print(f"acquire: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("acquire: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
