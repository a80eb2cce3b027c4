"""``acquire verify``: the run of the verification test (its options and help:
:mod:`acquire.commands.verify_options`)."""

from __future__ import annotations

import argparse
import hashlib
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from acquire.commands.prepare import UsageError, check_start, confirm, open_devices, site_from_args, without_faults
from acquire.commands.verify_options import build_parser
from acquire.planning.plan import estimate_duration, plan_clearance
from acquire.planning.plan_flange import is_flange_camera
from acquire.planning.plan_report import format_clearance
from acquire.running.resume import resume_settings, session_model
from acquire.running.runner import run_session
from acquire.running.session import Session
from acquire.verification.verify import MODES, VerifyError, build, design, header, problems
from acquire.verification.verify_analysis import UNCERTAINTY, Outcome, analyse
from common import fit_width
from common.errors import InputError, install_hint
from common.fit_width import say
from common.outputs import check_outputs, check_target, write_output
from common.units import hms
from config.robots import RobotModel, load_robot
from drivers.spec import RobotSpec, TrackerSpec
from identify.applications.calibrated import CalibratedModel, ResultError, nominal_name
from identify.applications.controller import check_same_robot, controller_model
from identify.applications.holds import ModelCheck
from identify.applications.iso9283 import ISO_CYCLES
from identify.io.result_io import load_result
from identify.report.verify_rows import iso_rows, orientation_rows, pose_cells
from session.schema import SessionError

MM = 1e3


def _outputs(path: Path) -> tuple[Path, Path]:
    return path.with_suffix(".verify.yaml"), path.with_suffix(".report.html")


def _load(path: Path) -> tuple[CalibratedModel, dict[str, Any], str]:
    try:
        model, doc = load_result(str(path))
    except ResultError as exc:
        raise UsageError(str(exc)) from None
    if (doc.get("verdict") or {}).get("status") == "fail":
        raise UsageError(f"{path} fails its verdict: its model must not be used (see the result's checks)")
    return model, doc, hashlib.sha256(path.read_bytes()).hexdigest()


def _robot_for(args: argparse.Namespace, doc: dict[str, Any], model: CalibratedModel) -> tuple[RobotSpec, RobotModel]:
    name = nominal_name(doc)
    spec = RobotSpec.parse(args.robot if args.robot is not None else f"mock:{name or 'ur5e'}").resolved()
    robot = load_robot(spec.model)
    try:
        check_same_robot(doc, model.model.joint_types, robot, result=str(args.result), identified=model)
    except InputError as exc:
        raise UsageError(str(exc)) from None
    return spec, robot


def format_design(info: dict[str, Any], robot: RobotModel, plan, duration: float) -> str:
    """The test as the operator reads it before anything moves."""
    targets = np.array(info["targets"]) * MM
    lines = [f"verification of {info['result']} (verdict {info['result_verdict']}) on {robot.name}: ISO 9283-style, "
             f"5 poses x {info['cycles']} cycles, before ({info.get('before_model', 'nominal model')}) then after "
             "(identified model)",
             f"test cube: centre {', '.join(f'{v * MM:.1f}' for v in info['centre'])} mm, edge {info['edge'] * MM:.0f} "
             "mm (base frame); per pose: its target, the joints commanded before compensation, and the AP "
             "predicted before / after [mm]"]
    if info["cycles"] < ISO_CYCLES:
        lines.insert(1, f"note: {info['cycles']} cycles per pose; ISO 9283 asks for {ISO_CYCLES} (fewer: a quicker "
                        "test, its AP and RP less certain: see their uncertainties)")
    rows = [[f"P{k + 1}", *(f"{v:.1f}" for v in targets[k]),
             ", ".join(f"{np.degrees(v):.1f}" for v in info["q"]["before"][k]),
             f"{info['predicted']['before'][k] * MM:.3f} / 0 ± {info['expected'][k] * MM:.3f}"] for k in range(5)]
    lines += fit_width.table(["pose", "x [mm]", "y [mm]", "z [mm]", "q before [deg]", "AP before / after"], rows)
    change = np.max(np.abs(np.array(info["q"]["after"]) - np.array(info["q"]["before"])))
    lines.append(f"compensation changes the joints by up to {change * 1e3:.2f} mrad")
    if "approach" in info:
        lines.append(f"each pose visited from 3 directions (ISO 9283 vAP): first to an approach pose "
                     f"{info['approach_share'] * info['edge'] * MM:.0f} mm away along the base's +x, +y or +z, then "
                     "to the pose; the approach poses are measured like every step (not used), checked like them "
                     "and counted in the duration")
    if "register" in info:
        lines.append(f"registration first: {len(info['register']['q'])} poses of its own (not the test's), "
                     f"commanded with the {info['register']['model']} model; the tracker frame is fitted on them")
    lines += [f"note: {n}" for n in info["notes"]]
    if "domain" in info:  # sessions planned before results recorded it have none
        lines.append(f"domain: {info['domain']['text']}")
    lines.append(f"total: {len(plan.steps)} steps x {plan.samples_per_step} samples; estimated duration "
                 f"{hms(duration)}")
    return "\n".join(lines)


def format_registration(check: ModelCheck) -> list[str]:
    """How far the tracker moved since the calibration and how well the result's model registers (80 columns)."""
    r = check.registration
    return fit_width.wrap(
        f"tracker registered on {check.heldout.samples} poses of its own ({check.name} model): moved "
        f"{r.moved * MM:.2f} mm, turned {np.degrees(r.turned):.3f} deg since the calibration; residuals "
        f"{check.heldout.rms * MM:.4f} mm RMS held out, {check.ratio:.2f}x the {check.expected * MM:.4f} mm the "
        f"result predicts ({check.status})")


def format_iso_extras(outcome: Outcome) -> list[str]:
    """Distance accuracy and repeatability, drift within the run, vAP per pose, orientation (worst pose of each
    figure), each ± its uncertainty: tables of 80 columns or fewer, then what was not measured and why."""
    runs = {m: a.as_dict() for m, a in outcome.runs.items()}
    rows = iso_rows(runs)
    lines = fit_width.table(["ISO 9283 [mm]", "before", "after"], rows) if rows else []
    turns = orientation_rows(runs)
    if turns:
        lines += fit_width.table(["orientation [mrad]", "before", "after"], turns)
        lines += fit_width.wrap(f"orientation from {outcome.orientation_source}")
    elif outcome.orientation:
        lines += fit_width.wrap(f"orientation not measured: {outcome.orientation}")
    if outcome.runs:
        lines += fit_width.wrap(outcome.drift_note)
        lines += fit_width.wrap(f"± {UNCERTAINTY}")
    return lines


def format_outcome(outcome: Outcome, domain: str | None = None) -> str:
    """The registration, AP/RP per pose and run ± their uncertainties, the other figures, where the test poses lie
    against the result's ``domain`` (one line; None: not recorded), then the verdict line."""
    lines = [] if outcome.registration is None else format_registration(outcome.registration)
    runs = {m: a.as_dict() for m, a in outcome.runs.items()}
    rows = [[f"P{k}", *(pose_cells(runs.get(m), f, k) for f in ("ap", "rp") for m in MODES)] for k in range(1, 6)]
    lines += fit_width.table(["[mm]", "AP before", "AP after", "RP before", "RP after"], rows)
    lines += format_iso_extras(outcome)
    if domain:
        lines += fit_width.wrap(f"domain: {domain}")
    lines.append(f"verdict: {outcome.status}: {outcome.message}")
    return "\n".join(lines)


def _finish(session: Session, path: Path, robot: RobotModel) -> tuple[Outcome, dict[str, Any]]:
    info = session.header["config"]["verification"]
    outcome = analyse(info, session.steps())
    say(format_outcome(outcome, (info.get("domain") or {}).get("text")))
    summary = outcome.as_dict(info)
    yaml_path, report_path = _outputs(path)
    write_output(yaml_path, yaml.safe_dump(summary, sort_keys=False, width=120), force=True)
    print(f"verification written to {yaml_path}")
    try:
        from identify.report.verify_html import verification_html
    except ImportError:
        print(f"note: no HTML report (it needs matplotlib: {install_hint('report')})")
        return outcome, summary
    write_output(report_path, verification_html(summary, session.header, str(path), session), force=True)
    print(f"report written to {report_path}")
    return outcome, summary


def run(args: argparse.Namespace) -> int:
    if args.resume:
        if args.result or args.session:
            raise UsageError("--resume continues a session's own test: --result and --session go with a new one")
        with (Session.open(args.resume) if args.dry_run else Session.open(args.resume, write=True)) as session:
            return _resume(args, session)
    if args.result is None:
        raise UsageError("give --result RESULT (the calibration to verify) or --resume SESSION")
    if is_flange_camera(TrackerSpec.parse(args.tracker or "mock")):
        raise UsageError("acquire verify measures the tool's point from the cell (a tracker, or a camera in the cell "
                         "seeing a target on the flange); a camera on the flange (mount=flange) is not supported: its "
                         "calibration's held-out views are its check (the result's holdout checks)")
    model, doc, sha = _load(args.result)
    robot_spec, robot = _robot_for(args, doc, model)
    tracker_spec = TrackerSpec.parse(args.tracker or "mock")
    site = site_from_args(args)
    cycles = site.verify_cycles if args.cycles is None else args.cycles
    if cycles < 2:
        raise UsageError(f"--cycles must be at least 2 (AP and RP need repeated visits), got {cycles}")
    if not args.dry_run and args.session is not None:
        check_outputs([args.result, args.config], [("--session", args.session),
                                                   *zip(("result", "report"), _outputs(args.session), strict=True)],
                      args.force)
        check_target(args.session, option="--session")
    if not args.dry_run:
        from drivers.sim.pairing import check_pairing

        check_pairing(robot_spec, tracker_spec)

    def plan_ok(q: dict[str, np.ndarray], approach: dict[str, np.ndarray], q_register: np.ndarray) -> list[str]:
        # two cycles hold every distinct move
        return problems(build(robot, site, q, min(cycles, 2), q_register, approach)[0], robot, site)

    try:
        before, before_name = controller_model(doc, robot)
    except InputError as exc:
        raise UsageError(str(exc)) from None
    try:
        d = design(model, robot, site, plan_ok, before)
    except VerifyError as exc:
        print(f"acquire verify: test refused: {exc}", file=sys.stderr)
        return 2
    plan, labels = build(robot, site, d.q, cycles, d.register, d.approach)
    info = header(d, labels, model, str(args.result), sha, (doc.get("verdict") or {}).get("status"), cycles, doc,
                  before_name)
    say(format_design(info, robot, plan, estimate_duration(plan, robot, site.measure_time)))
    say(format_clearance(plan_clearance(plan, robot, site), plan, site))
    if args.dry_run:
        print("dry run: nothing was connected or moved")
        return 0
    path = args.session or _default_path(robot.name)
    confirm(robot_spec, args, plan, f"Move {robot_spec} through these {len(plan.steps)} steps? Type 'yes' to start: ")
    config = {"robot_spec": str(robot_spec), "tracker_spec": str(tracker_spec), "site": site.as_dict(),
              "command": " ".join(sys.argv), "verification": info,
              **({"robot_model": robot.document} if robot.document is not None else {})}
    return _measure(args, None, path, plan, robot_spec, tracker_spec, site, robot, config)


def _resume(args: argparse.Namespace, session: Session) -> int:
    info = (session.header.get("config") or {}).get("verification")
    if info is None:
        raise UsageError(f"{args.resume} is an acquisition session, not a verification: resume it with acquire "
                         "--resume")
    options = {"--cycles": None if args.cycles is None or args.cycles == info["cycles"] else args.cycles,
               "--samples": args.samples}
    if options["--cycles"] is not None:
        raise UsageError(f"--cycles {args.cycles}: the session's test has {info['cycles']}; a resume cannot change it")
    settings = resume_settings(session.header, args.robot, args.tracker, args.config, options)
    robot, model_note = session_model(session.header, settings.robot)
    if model_note:
        print(model_note)
    robot_spec = settings.robot if args.robot else without_faults(settings.robot)
    tracker_spec = settings.tracker if args.tracker else without_faults(settings.tracker)
    if args.dry_run:
        duration = estimate_duration(session.plan, robot, settings.site.measure_time)
        say(format_design(info, robot, session.plan, duration))
        print("dry run: nothing was connected or moved")
        return 0
    if session.next_index() is None:
        print(f"{session.path} is complete: all {len(session.plan.steps)} steps recorded; nothing moved")
        outcome, _ = _finish(session, args.resume, robot)
        return _code(outcome)
    confirm(robot_spec, args, session.plan)
    return _measure(args, session, args.resume, session.plan, robot_spec, tracker_spec, settings.site, robot, None,
                    settings)


def _measure(args, session: Session | None, path: Path, plan, robot_spec: RobotSpec, tracker_spec: TrackerSpec,
             site, robot: RobotModel, config: dict[str, Any] | None, settings=None) -> int:
    """Connect, check the first move, record the steps, then analyse and write the outputs."""
    robot_dev, tracker, clock = open_devices(robot_spec, tracker_spec, args.realtime, site, model=robot)
    try:
        first = 0 if session is None else session.next_index()
        check_start(robot_dev, plan, robot, site, first or 0, session)
        if session is None:
            assert config is not None
            session = Session.create(path, plan, config, robot_dev.identity(), tracker.identity(), robot.coupling)
        elif settings is not None and settings.changes:
            session.set_connection(settings.connection(), "resumed with new connection details: "
                                   + "; ".join(settings.changes))
        print(f"session: {path}")
        result = run_session(robot_dev, tracker, session, clock, site, args.quiet)
        if result.outcome != "complete":
            print(f"acquire verify: run {result.outcome} ({result.reason}); resume with: acquire verify --resume "
                  f"{path}", file=sys.stderr)
            return 130 if result.outcome == "aborted" else 1
        outcome, _ = _finish(session, path, robot)
        return _code(outcome)
    finally:
        robot_dev.close()
        tracker.close()
        if session is not None:
            session.close()


def _code(outcome: Outcome) -> int:
    return {"pass": 0, "warn": 0, "fail": 3}.get(outcome.status, 1)


def _default_path(robot: str) -> Path:
    folder = Path("sessions")
    folder.mkdir(exist_ok=True)
    path = folder / f"{robot}-verify-{time.strftime('%Y%m%d-%H%M%S')}.session"
    check_target(path, option="session")
    return path


def main(argv: list[str]) -> int:
    """``acquire verify``; errors as one line (the caller, acquire.commands.cli.main, maps exceptions to exit 2)."""
    args = build_parser().parse_args(argv)
    try:
        return run(args)
    except SessionError as exc:
        print(f"acquire verify: error: {exc}", file=sys.stderr)
        return 2
