"""``identify compare A B [C ...]``: has the robot changed between calibrations? (the edge where files are read)

Its options and help: identify/commands/sub_options.py (light, so that --help answers at once).
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

from common import fit_width
from common.errors import InputError
from common.outputs import check_outputs, same_file, write_output
from identify.applications.calibrated import CalibratedModel, ResultError, nominal_name, recorded_model, robot_model
from identify.applications.compare import CompareError, Comparison, check_same_robot, compare
from identify.applications.domain import domain_from_document, outside
from identify.commands.sub_options import compare_parser as build_parser
from identify.io.result_io import load_result
from session.schema import is_session_file


def load_input(path: str) -> tuple[CalibratedModel, str | None, str | None, float | None, np.ndarray | None,
                                   dict[str, Any] | None]:
    """The model of a result or session, its robot name, robot serial, time (s since the epoch, or None), domain
    (n, 2: the DH joint ranges it was fitted on, None when a result records none) and the robot model it records
    (a model that is not bundled; else None)."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{path}: no such result or session")
    if not is_session_file(p):
        try:
            model, doc = load_result(path, p.stem)
        except ResultError as exc:
            raise InputError(str(exc)) from None
        if (doc.get("verdict") or {}).get("status") == "fail":
            raise InputError(f"{path} fails its verdict: its model cannot be compared")
        return model, nominal_name(doc), None, p.stat().st_mtime, domain_from_document(doc), recorded_model(doc)
    from config.robots import ConfigError
    from identify.io.session_measurements import session_measurements
    from identify.results.pipeline import identify
    from session.schema import SessionError
    from session.store import SessionFile

    try:
        with SessionFile.open(p) as session:
            header = session.header
            if "verification" in (header.get("config") or {}):
                raise InputError(f"{path} is a verification session (acquire verify): compare calibrations")
            meas, robot_name = session_measurements(session), session.plan.robot
        robot = robot_model(robot_name, recorded_model(header), path)
    except (SessionError, ConfigError) as exc:
        raise InputError(str(exc)) from None
    ident = identify(meas, robot.nominal, links=robot.links)  # as acquire identifies its sessions
    if ident.verdict.status == "fail":
        raise InputError(f"{path}: its identification fails its verdict ({ident.verdict.summary()})")
    serial = (header.get("robot") or {}).get("serial") or None
    return (CalibratedModel.from_identification(ident, p.stem), robot.name, serial, header.get("created"),
            ident.domain, robot.document)


def run(args: argparse.Namespace) -> tuple[Comparison, dict[str, Any]]:
    """Compare per ``args``; InputError for bad input."""
    if len(args.inputs) < 2:
        raise InputError("give at least two results or sessions to compare, oldest first")
    if not 0 < args.alpha < 1 or args.poses < 1:
        raise InputError(f"--alpha must be in (0, 1) and --poses >= 1, got {args.alpha} and {args.poses}")
    for k, a in enumerate(args.inputs):
        for b in args.inputs[k + 1:]:
            if same_file(a, b):
                raise InputError(f"{a} and {b} are the same file: compare calibrations made at different times")
    robot_file = args.robot if args.robot and Path(args.robot).is_file() else None
    check_outputs([*args.inputs, robot_file], [("--html", args.html)], args.force)
    loaded = [load_input(path) for path in args.inputs]
    models = [m for m, *_ in loaded]
    labels = _labels(args.inputs)
    try:
        check_same_robot(models, [r for _, r, *_ in loaded], labels)
    except CompareError as exc:
        raise InputError(str(exc)) from None
    serials = {(s, label) for (_, _, s, *_), label in zip(loaded, labels, strict=True) if s}
    if len({s for s, _ in serials}) > 1:
        a, b = sorted(serials)[:2]
        raise InputError(f"{a[1]} is robot serial {a[0]}, {b[1]} serial {b[0]}: different robots cannot be compared")
    named = next(((r, doc, path) for (_, r, _, _, _, doc), path in zip(loaded, args.inputs, strict=True) if r),
                 (None, None, None))
    robot = robot_model(args.robot) if args.robot is not None else robot_model(*named)
    if robot is not None and robot.joint_types != models[0].model.joint_types:
        raise InputError(f"--robot {robot.name} has joints {robot.joint_types}, the inputs "
                         f"{models[0].model.joint_types}")
    try:
        result = compare(models, labels, None if robot is None else robot.limits, args.alpha, args.poses, args.seed)
    except CompareError as exc:
        raise InputError(str(exc)) from None
    times = [t for _, _, _, t, _, _ in loaded]
    if args.html:
        from identify.report.compare_html import compare_html

        write_output(args.html, compare_html(result, models, times), force=args.force)
    notes = _domains(result, models, [d for _, _, _, _, d, _ in loaded])
    result = replace(result, notes=notes)
    return result, as_dict(result)


def _domains(result: Comparison, models: list[CalibratedModel], domains: list[np.ndarray | None]) -> tuple[str, ...]:
    """For each input, how many of the poses the displacement was computed at lie outside its domain."""
    q = result.poses
    if q is None:
        return ()
    out = []
    for label, model, domain in zip(result.labels, models, domains, strict=True):
        if domain is None:
            out.append(f"{label}: records no domain (written before results did): where it holds is not known")
            continue
        found = outside(domain, model.dh_values(q), model.model.joint_types)
        if found.count:
            out.append(f"{label}: {found.count} of the {found.total} displacement poses lie outside its fitted joint "
                       "ranges (its domain): the displacement there extrapolates its fit")
    return tuple(out)


def _labels(paths: list[str]) -> list[str]:
    """Short names: file stems (without ``.result``), or the whole paths where they repeat."""
    stems = [Path(p).stem.removesuffix(".result") for p in paths]
    return stems if len(set(stems)) == len(stems) else list(paths)


def as_dict(c: Comparison) -> dict[str, Any]:
    """The comparison as plain data (m, rad)."""
    return {"verdict": c.verdict, "significant": c.significant, "alpha": c.alpha, "inputs": list(c.labels),
            "domain_notes": list(c.notes),
            "pairs": [{"a": p.a, "b": p.b, "significant": p.significant, "statistic": p.statistic, "dof": p.dof,
                       "p_value": p.p_value, "alpha": p.alpha, "displacement_rms": p.displacement_rms,
                       "displacement_max": p.displacement_max, "expected_rms": p.expected_rms,
                       "base_shift": p.base_shift, "base_turn": p.base_turn, "tool_shift": p.tool_shift,
                       "excluded": list(p.excluded), "verdict": p.verdict,
                       "changes": [{"parameter": ch.name, "delta": ch.delta, "std": ch.std, "z": ch.z, "p": ch.p,
                                    "significant": ch.significant} for ch in p.changes]} for p in c.pairs]}


def format_comparison(c: Comparison) -> str:
    """The verdict line, then per pair its line, its parameter table and what moved in the cell."""
    lines = [f"verdict: {c.verdict}"]
    for p in c.pairs:
        lines += ["", p.verdict, "parameter   change        ± std     z      p (Holm)"]
        for ch in sorted(p.changes, key=lambda x: -abs(x.z)):
            scale, unit = (math.degrees(1.0), "deg") if ch.angular else (1e3, "mm ")
            mark = "  *" if ch.significant else ""
            lines.append(f"{ch.name:<10} {ch.delta * scale:+10.4f} {unit} {ch.std * scale:8.4f} {ch.z:6.1f}  "
                         f"{ch.p:9.3g}{mark}")
        lines += [f"note: {e}" for e in p.excluded]
        lines.append(f"cell: base moved {p.base_shift * 1e3:.3f} mm and turned {math.degrees(p.base_turn):.4f} deg "
                     f"relative to the tracker; TP {p.tool_shift * 1e3:.3f} mm on the flange (not the robot)")
    lines += [f"domain: {n}" for n in c.notes]
    return "\n".join(fit_width.wrap_lines(lines))  # within the terminal's width


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(sys.argv[2:] if argv is None else argv)
    try:
        result, doc = run(args)
    except InputError as exc:
        print(f"identify compare: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("identify compare: interrupted", file=sys.stderr)
        return 130
    print(json.dumps(doc, allow_nan=False) if args.json else format_comparison(result))
    if args.html and not args.json:
        print(f"trend page written to {args.html}")
    return 3 if result.significant else 0
