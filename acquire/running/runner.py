"""A session run on the devices, as the operator sees it: the orchestrator over the remaining steps (Ctrl-C stops
the motion) with progress lines, then the end of the run: its outcome, the home drift and, for a complete session,
the identification with its result YAML and HTML report beside the session file. Used by ``acquire`` and
``acquire verify`` (acquire/commands/cli.py, acquire/commands/verify_cli.py)."""

from __future__ import annotations

import logging
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import yaml

from acquire.running.orchestrator import Orchestrator, RunResult, StopRequest, Timeouts
from acquire.running.progress import ProgressDisplay
from acquire.running.session import Session
from common.errors import install_hint
from common.fit_width import say
from common.outputs import write_output
from config.robots import ConfigError, RobotModel
from config.site import SiteConfig
from drivers.clock import VirtualClock
from identify.applications.controller import controller_section
from identify.applications.factory import factory_reference
from identify.io.result_io import result_to_dict
from identify.io.session_measurements import missing_steps
from identify.report.terminal import format_reference, format_report
from identify.results.pipeline import identify
from identify.results.verdict import missing_steps as missing_steps_check
from identify.results.verdict import with_session_check
from identify.sensors.evidence import camera_text, checked, documented, for_estimator
from session.rows import factory_calibration

log = logging.getLogger("acquire")


def run_session(robot, tracker, session: Session, clock, site: SiteConfig, quiet: bool) -> RunResult:
    """Run ``session``'s remaining steps on the devices (Ctrl-C, SIGTERM or SIGHUP stops the motion; the site's
    timeouts and retries), showing progress unless ``quiet`` (acquire/running/progress.py)."""
    stop = StopRequest()
    display = ProgressDisplay(session.plan, site.measure_time, quiet, simulated=isinstance(clock, VirtualClock))
    done = session.recorded_indices()
    steps = session.plan.steps
    display.plan_steps([s for s in steps if s.index not in done] + [steps[i] for i in session.missing_indices()])
    orchestrator = Orchestrator(robot, tracker, session, clock,
                                Timeouts(site.timeouts.move, site.timeouts.settle, site.timeouts.measure),
                                site.retries, progress_printer(quiet, display), stop, site.stream_rate,
                                on_start=display.start)
    try:
        with stop.installed():
            return orchestrator.run()
    finally:
        display.close()


def finish(result: RunResult, session: Session, path: Path, robot: RobotModel) -> int:
    log.info("run %s%s; %d step(s) recorded, %d missing", result.outcome,
             f" ({result.reason})" if result.reason else "", result.recorded, result.missing)
    if result.outcome != "complete":
        print(f"acquire: run {result.outcome} ({result.reason}); {result.recorded} step(s) recorded this run; "
              f"resume with: acquire --resume {path}", file=sys.stderr)
        return 130 if result.outcome == "aborted" else 1
    if result.missing:
        say(f"note: {result.missing} step(s) still missing after a second attempt (tracker failures); the "
              f"identification uses the rest; acquire --resume {path} --remeasure-missing tries them again")
    drift = session.drift()
    if len(drift) > 1:
        worst = max(d for _, d in drift)
        minutes = (drift[-1][0] - drift[0][0]) / 60
        say(f"home drift: {len(drift)} re-measurements over {minutes:.1f} min, largest {worst * 1e3:.4f} mm "
              "from the first")
    doc = identify_session(session, path, robot)
    if doc["verdict"]["status"] == "fail":
        print("acquire: the identification FAILS its verdict: do not use this model (see the checks above)",
              file=sys.stderr)
        return 3
    return 0




def progress_printer(quiet: bool, display: ProgressDisplay):
    """What the orchestrator calls after each step: the display's :meth:`~ProgressDisplay.done` (logs the step,
    and shows it unless ``quiet``)."""
    return display.done


def cell_view(session: Session, robot: RobotModel) -> dict[str, Any] | None:
    """The mounting surface and the plan's swept envelope (DH frame 0) for the report's 3D view."""
    import numpy as np

    from config.cell import cell_from_config, envelope

    try:
        site = SiteConfig.from_dict(session.header["config"]["site"])
    except (KeyError, TypeError, ConfigError):
        return None
    cell = cell_from_config(robot, site)
    if cell is None:
        return None
    plan = session.plan
    poses = np.array([plan.home, *(s.q for s in plan.steps)])
    return {"normal": cell.normal, "offset": cell.offset, "envelope": envelope(cell, poses)}


def identify_session(session: Session, session_path: Path, robot: RobotModel) -> dict[str, Any]:
    rows = for_estimator(session.to_measurements())  # a flange camera's rows turned round (identify/sensors/)
    meas = rows.meas
    ident, scale = checked(identify(meas, robot.nominal, links=robot.links), rows, robot.nominal)
    # how much of the plan was recorded is part of the verdict (and so of the report's first screen)
    ident = replace(ident, verdict=with_session_check(ident.verdict, missing_steps_check(*missing_steps(session))))
    print(format_report(ident, robot.nominal, robot.name))
    calibration, why = factory_calibration(session.header)  # the controller's own, for comparison
    reference, note = factory_reference(calibration, why, robot.joint_types)
    if reference is not None or note:
        print(format_reference(ident, *reference) if reference is not None else f"note: {note}")
    doc = result_to_dict(ident, robot.nominal, robot.name, source=str(session_path), nominal_model=robot.document)
    doc = documented(doc, rows, scale, ident, robot.limits)  # a flange camera's mount, board, flange accuracy
    for line in camera_text(doc):
        say(line)
    if section := controller_section(calibration, robot.joint_types):  # what the arm runs today ("before")
        doc["controller"] = section
    out = session_path.with_suffix(".result.yaml")
    # the session's own outputs: checked before a new session started (refused if they existed, without --force),
    # brought up to date by each run of the session that completes; written whole or not at all
    write_output(out, yaml.safe_dump(doc, sort_keys=False, width=120), force=True)
    print(f"result written to {out}")
    try:
        from identify.report.html import report_html
    except ImportError:
        print(f"note: no HTML report (it needs matplotlib: {install_hint('report')})")
        return doc
    report = session_path.with_suffix(".report.html")
    write_output(report, report_html(ident, meas, robot.nominal, robot.name, session=session, source=str(session_path),
                                     reference=reference, reference_note=note or None,
                                     cell=cell_view(session, robot)), force=True)
    print(f"report written to {report}")
    return doc
