"""``identify INPUT``: identify DH parameters from a measurement CSV (the edge where files are read).

Its options, subcommands and exit codes: identify/commands/options.py (``identify --help``); the entry point that
answers those before the heavy imports: identify/commands/launch.py.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from common import __version__, fit_width, stop_signals
from common.errors import InputError, install_hint
from common.outputs import check_outputs, write_output
from common.units import as_typed
from config.robots import RobotModel
from identify.applications.calibrated import recorded_model, robot_model
from identify.commands.options import SUBCOMMANDS, build_parser
from identify.estimator.measurements import Measurements
from identify.io.csvio import format_measurements, read_measurements
from identify.io.result_io import result_to_dict
from identify.io.session_measurements import open_session, read_session
from identify.io.verification_io import load_verification
from identify.report.terminal import format_reference, format_report
from identify.results.pipeline import Identification, identify, split_holdout
from identify.sensors.evidence import camera_text, checked, documented, for_estimator
from kinematics.dh import frames_from_joints
from kinematics.joint_errors import Coupling
from session.schema import is_session_file


def _check_exports(args: argparse.Namespace, joint_types: str) -> None:
    """Refuse, before any work, exports that cannot be made."""
    if args.ur_calibration and joint_types != "RRRRRR":
        raise InputError(f"--ur-calibration needs a 6R UR arm; the data have joints {joint_types}")
    if args.verification and not args.report:
        raise InputError("--verification goes with --report (it is shown in the report's headline)")
    if args.report and args.verification:
        load_verification(args.verification, str(args.input))
        try:
            import identify.report.html  # noqa: F401
        except ImportError:
            raise InputError(f"--report needs matplotlib: {install_hint('report')}") from None


def _write_exports(args: argparse.Namespace, ident: Identification, meas: Measurements, doc: dict[str, Any],
                   robot: RobotModel | None, reference: tuple[str, Any] | None = None, note: str = ""
                   ) -> list[tuple[str, str]]:
    """Every export asked for, each written atomically; the model files written, each with what it carries."""
    name = robot.name if robot else "identified_robot"
    limits = robot.limits if robot else None
    written: list[tuple[str, str]] = []  # (path, what it carries)

    def comment(carries: str) -> str:
        return "\n".join([f"identified from {args.input} by dh-calib {__version__}", carries, *export_notes(ident)])

    exact = export_figure(ident, meas, "exact")
    if ident.lines.orientations is not None:  # full-pose data: the tool link is the measured target frame
        exact += "; tool: the measured target frame (tool_frame)"
    plain = export_figure(ident, meas, "plain")
    if args.urdf or args.ur_calibration:
        flange = frames_from_joints(ident.model, ident.lines.home[None, :])[0, -1]
    if args.urdf:
        from identify.exports.urdf import urdf_from_lines

        velocities = robot.max_speed if robot else None
        text = urdf_from_lines(ident.lines, ident.model.base, flange, name, limits, velocities,
                               comment=comment(f"carries: {exact}"), tp_ids=ident.tp_ids)
        _write_atomic(Path(args.urdf), text)
        written.append((args.urdf, exact))
    if args.ur_calibration:
        from identify.exports.ur_calibration import calibration_from_lines, format_calibration

        try:
            text = format_calibration(calibration_from_lines(ident.lines, ident.model.base, flange),
                                      comment=comment(f"carries: {exact}"))
        except ValueError as exc:
            raise InputError(f"--ur-calibration: {exc}") from None
        _write_atomic(Path(args.ur_calibration), text)
        written.append((args.ur_calibration, exact))
    if args.rtb:
        from identify.exports.rtb import rtb_snippet

        head = "".join(f"# {line}\n" for line in comment(f"carries: {plain}").splitlines())
        _write_atomic(Path(args.rtb), head + rtb_snippet(ident.model, name, limits))
        written.append((args.rtb, plain))
    if args.json_out:
        from identify.exports.rtb import result_json

        _write_atomic(Path(args.json_out), result_json(doc))
    if args.csv:
        _write_atomic(Path(args.csv), format_measurements(meas, {"source": str(args.input)}))
    if args.report:
        from identify.report.html import report_html

        session = open_session(Path(args.input)) if is_session_file(Path(args.input)) else None
        try:
            page = report_html(ident, meas, robot.nominal if robot else None, robot.name if robot else None,
                               session=session, source=str(args.input), reference=reference,
                               reference_note=note or None, verification=None if args.verification is None else
                               load_verification(args.verification, str(args.input)))
        finally:
            if session is not None:
                session.close()
        _write_atomic(Path(args.report), page)
    return written


def export_figure(ident: Identification, meas: Measurements, carried: str) -> str:
    """What an export carries, with its held-out figure: ``plain`` (the DH table), ``exact`` (the plain model's exact
    axes: URDF, UR calibration); the extended model's figure beside it when the format cannot hold joint errors."""
    if carried == "plain":
        what, v = "plain model (DH table)", ident.validations.get("plain")
        rms = None if v is None else v.rms
    else:
        what = "plain model (exact axes)"
        check = meas.subset(meas.check & np.all(np.isfinite(meas.q), axis=1))
        predictor = replace(ident.plain.predictor, coupling=ident.coupling)
        rms = None if not len(check) else float(np.sqrt(np.mean(np.sum(
            (check.points - predictor.points(check.q, check.tp)) ** 2, axis=1))))
    text = f"{what}, held-out {rms * 1e3:.4f} mm" if rms is not None else f"{what}, not validated (no held-out rows)"
    ext = ident.validations.get("extended")
    if ident.use == "extended":
        text += " (joint errors not carried: extended model" + (f" {ext.rms * 1e3:.4f} mm)" if ext else ")")
    return text


def export_notes(ident: Identification) -> list[str]:
    """What a model export (URDF, UR calibration, Robotics Toolbox) leaves out, one line each."""
    notes = []
    if ident.extensions:
        names = ", ".join(name for name, _, _ in ident.extensions)
        notes.append(f"NOT carried: the extended model's joint errors ({names}); this file carries the plain model, "
                     "fitted without them. The extended model is in the result YAML's 'extensions' section")
    else:
        notes.append("joint errors beyond DH: none selected; this file is the whole identified model")
    if ident.coupling is not None and not ident.coupling.is_identity:
        notes.append("joint values here are DH values; the controller's readings give them by q_dh = C . readings"
                     f" + offset, C = {ident.coupling.matrix.tolist()}, offset = {ident.coupling.offset.tolist()}")
    if len(ident.tp_ids) > 1:
        notes.append(f"tool: tracked point {ident.tp_ids[0]} (of {list(ident.tp_ids)}; the others are in the result "
                     "YAML's 'tools')")
    return notes


def _factory_reference(header: dict[str, Any], joint_types: str) -> tuple[tuple[str, Any] | None, str]:
    """The session robot's factory calibration as a comparison model, or None and why not."""
    from identify.applications.factory import factory_reference
    from session.rows import factory_calibration

    calibration, note = factory_calibration(header)
    return factory_reference(calibration, note, joint_types)


def _write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` whole or not at all (common/outputs.py); :func:`_check_outputs` has refused,
    before any work, an output that is an input or exists without ``--force``."""
    write_output(path, text, force=True)


def _check_outputs(args: argparse.Namespace) -> None:
    """Refuse, before anything is read or computed, outputs that would overwrite an input, each other, or an
    existing file without ``--force`` (one line, exit 2)."""
    robot_file = args.robot if args.robot and Path(args.robot).is_file() else None
    check_outputs([args.input, robot_file], [(f"--{name.replace('_', '-')}", getattr(args, name)) for name in
                                             ("out", "report", "urdf", "ur_calibration", "rtb", "json_out", "csv")],
                  args.force)


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Identify per ``args``; returns the result document. Raises InputError for bad input."""
    if not 0.0 <= args.holdout < 1.0:
        raise InputError(f"--holdout must be in [0, 1), got {args.holdout}")
    if not 0.0 <= args.parallel_tol < math.pi / 2:
        raise InputError(f"--parallel-tol must be an angle in [0, pi/2) rad, got {args.parallel_tol}")
    if args.max_offset is not None and not args.max_offset >= 0.0:
        raise InputError(f"--max-offset must be a length >= 0, got {args.max_offset} m")
    _check_outputs(args)
    header = None
    if is_session_file(Path(args.input)):
        content, header = read_session(Path(args.input))
    else:
        content = read_measurements(args.input, args.joints, args.units)
    meas = _rows(split_holdout(content.measurements, args.holdout, args.seed), args.rows)
    # a session knows its robot; --robot '' is refused, not taken for no --robot
    robot_name = args.robot if args.robot is not None else (header or {}).get("robot_model")
    recorded = (recorded_model(header), str(args.input)) if args.robot is None and header is not None else (None, None)
    robot = robot_model(robot_name, *recorded)
    nominal, nominal_name = (robot.nominal, robot.name) if robot else (None, None)
    if nominal is not None and nominal.joint_types != meas.joint_types:
        raise InputError(f"--robot {nominal_name} has joints {nominal.joint_types}, the data have "
                         f"{meas.joint_types}")
    _check_exports(args, meas.joint_types)
    meas = _with_coupling(meas, args.coupling, robot, content.notes)
    rows = for_estimator(meas)  # a flange camera's rows turned round (identify/sensors/flange.py)
    ident = identify(rows.meas, nominal, args.parallel_tol, robust=not args.no_robust, max_offset=args.max_offset,
                     noise=args.noise, links=robot.links if robot else None, extensions=args.extensions == "auto",
                     noise_typed=as_typed(args, "noise"))
    ident.warnings[:0] = content.notes
    ident, scale = checked(ident, rows, nominal)
    if header is not None:  # a session: how much of its plan was recorded is part of the verdict
        from identify.results import verdict as checks

        ident = replace(ident, verdict=checks.with_session_check(ident.verdict,
                                                                  checks.missing_steps(*header["missing_steps"])))
    doc = result_to_dict(ident, nominal, nominal_name, source=str(args.input),
                         nominal_model=robot.document if robot else None)
    doc = documented(doc, rows, scale, ident, robot.limits if robot else None)
    if header is not None:  # the controller's own calibration: what the arm runs today ("before")
        from identify.applications.controller import controller_section
        from session.rows import factory_calibration

        if section := controller_section(factory_calibration(header)[0], meas.joint_types):
            doc["controller"] = section
    if args.out:
        _write_atomic(Path(args.out), yaml.safe_dump(doc, sort_keys=False, width=120))
    reference, note = _factory_reference(header, meas.joint_types) if header is not None else (None, "")
    written = _write_exports(args, ident, meas, doc, robot, reference, note)
    models = [f"{path}: {carries}" for path, carries in written]  # each model file with what it carries
    if args.json:
        print(json.dumps(doc, allow_nan=False))
        if models:
            print("\n".join(models), file=sys.stderr)
        return doc
    print(format_report(ident, nominal, nominal_name))
    for line in camera_text(doc):
        print(line)
    if reference is not None or note:
        print(format_reference(ident, *reference) if reference is not None else f"note: {note}")
    said = []
    if args.out:
        used = ident.validation
        figure = f", held-out {used.rms * 1e3:.4f} mm" if used is not None else ", not validated"
        said.append(f"{args.out}: the result (use: its {ident.use} model{figure})")
    announced = {path for path, _ in written}
    for option, what in WRITTEN:  # every other file written
        path = getattr(args, option)
        if path and option != "out" and path not in announced:
            said.append(f"{what} written to {path}")
    if said or models:
        print("\n".join(fit_width.wrap_lines(said + models)))
    return doc


#: the files identify writes, by option, as it announces them
WRITTEN = (("out", "result"), ("report", "report"), ("urdf", "URDF"), ("ur_calibration", "UR calibration"),
           ("rtb", "Robotics Toolbox script"), ("json_out", "JSON result"), ("csv", "measurement CSV"))


def _rows(meas: Measurements, rows: str) -> Measurements:
    """``meas`` with only the ``rows`` kind fitted (``--rows``): ``step`` the rows not streamed, ``streamed`` the
    streamed ones; held-out rows stay with both. InputError when no row of that kind is left to fit."""
    if rows == "all":
        return meas
    fitted = ~meas.streamed if rows == "step" else meas.streamed
    if not np.any(fitted & ~meas.check):
        raise InputError(f"--rows {rows}: the data hold no {'stop-and-go' if rows == 'step' else 'streamed'} rows "
                         "to fit")
    fit = fitted & ~meas.check
    if rows == "step" and not np.any(fit & (meas.joint > 0)):  # free poses only, e.g. a continuous session's
        points = len(np.unique(meas.tp[fit]))
        poses = len(np.unique(np.round(meas.q[fit], 9), axis=0))
        unknowns = 4 * meas.n_joints + 6 + 3 * points  # the DH table, the base and each tracked point
        if 3 * poses * points <= unknowns:
            raise InputError(f"--rows step: the stop-and-go rows are {poses} poses and no sweep (a continuous "
                             f"session's range starts and home): too few for the {unknowns} parameters of a fit "
                             "from free poses; use --rows all or --rows streamed")
    return meas.subset(fitted | meas.check)


def _with_coupling(meas: Measurements, path: str | None, robot: RobotModel | None, notes: list[str]) -> Measurements:
    """``meas`` with its readings' coupling: ``--coupling FILE``, else the file's, else the robot model's."""
    n = meas.n_joints
    if path is not None:
        try:
            doc = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise InputError(f"--coupling {path}: no such file") from None
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
            raise InputError(f"--coupling {path}: cannot be read as YAML ({exc.__class__.__name__})") from None
        matrix, offset = (doc.get("matrix"), doc.get("offset")) if isinstance(doc, dict) else (doc, None)
        try:
            matrix = np.array(matrix, dtype=float)
            offset = None if offset is None else np.array(offset, dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"--coupling {path}: expected a {n}x{n} list of numbers, or {{matrix: ..., offset: "
                             "[...]}") from None
        try:
            coupling = Coupling(matrix, offset)
        except ValueError as exc:
            raise InputError(f"--coupling {path}: {exc}") from None
        if coupling.n_joints != n:
            raise InputError(f"--coupling {path}: a {coupling.n_joints}x{coupling.n_joints} matrix for {n} joints")
        return replace(meas, coupling=coupling)
    if meas.coupling is None and robot is not None and robot.coupling is not None:
        notes.append(f"readings coupled as the {robot.name} model declares (q_dh = C . readings)")
        return replace(meas, coupling=robot.coupling)
    if meas.coupling is not None and robot is not None and robot.coupling is not None and not (
            np.allclose(meas.coupling.matrix, robot.coupling.matrix)):
        notes.append(f"the file's '# coupling:' differs from the {robot.name} model's; the file's is used")
    return meas


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] and argv[0] in SUBCOMMANDS:
        from importlib import import_module

        return import_module(f"identify.commands.{argv[0]}_cli").main(argv[1:])
    args = build_parser().parse_args(argv)
    try:
        doc = run(args)
    except InputError as exc:
        print(f"identify: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("identify: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader of stdout went away (| head): the entry point stops quietly
        raise
    except Exception as exc:  # numerical failure: one line, not a traceback; --debug-free by design
        stop_signals.raise_pending()  # unless a stop signal became this error (an interrupted import)
        print(f"identify: error: identification failed: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    if doc["verdict"]["status"] == "fail":
        print("identify: the result FAILS its verdict: do not use this model (see the checks above)", file=sys.stderr)
        return 3
    return 0


if __name__ == "__main__":
    sys.exit(main())
