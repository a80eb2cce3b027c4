"""``identify compensate RESULT --program FILE --out FILE``: the program filter's edge (the program read, the
filtered program written, the summary printed by :mod:`identify.commands.compensate_cli`).

The program is read and written as bytes decoded as UTF-8, so line endings and every byte outside the rewritten
targets stay as they were.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from common.arguments import comma_numbers
from common.errors import InputError
from common.outputs import write_output
from identify.applications.calibrated import CalibratedModel
from identify.applications.compensate import pose_matrices
from identify.applications.controller import controller_model
from identify.applications.domain import result_outside
from identify.programs import urscript
from identify.programs.filter import Outcome, filter_targets, filtered_text

LANGUAGES = {"urscript": urscript}


def read_program(path: str) -> str:
    """The program's text, line endings as they are; InputError (one line) if it cannot be read."""
    try:
        return Path(path).read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: no such program file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot be read as UTF-8 text ({exc})") from None


def _tool(args: argparse.Namespace, program_tcp: tuple[float, ...] | None, identified: CalibratedModel
          ) -> tuple[np.ndarray, np.ndarray, bool, str]:
    """TCP position (3,) and rotation (3, 3) in the flange frame, whether it was given, and where it came from."""
    if args.tool:
        values, source = comma_numbers(args.tool, "--tool", (3, 6), lengths=3), "--tool"
    elif program_tcp is not None:
        values, source = list(program_tcp), "the program's set_tcp"
    else:
        return identified.tool(), np.eye(3), False, "the identified TP (the program sets no TCP; --tool to give it)"
    rotation = pose_matrices(np.zeros(3), np.array(values[3:]))[0, :3, :3] if len(values) == 6 else np.eye(3)
    return np.array(values[:3]), rotation, True, source


def run_program(args: argparse.Namespace, identified: CalibratedModel, doc: dict[str, Any], robot: Any,
                verdict: str | None) -> tuple[dict[str, Any], int]:
    """Filter ``args.program`` into ``args.out``; the summary and the exit code (0 every target rewritten and
    every motion line understood, 3 not)."""
    if robot is None:
        raise InputError("--program needs the controller's model (joint limits, home): give --robot (the result "
                         "names none)")
    language = LANGUAGES[args.language]
    text = read_program(args.program)
    try:
        parsed = language.parse(text, identified.n_joints)
    except ValueError as exc:
        raise InputError(f"{args.program}: {exc}") from None
    if not parsed.targets and not parsed.skipped:
        raise InputError(f"{args.program}: no movej, movel, movep or servoj target: nothing to filter")
    if parsed.tcp_problem and not args.tool:
        raise InputError(f"{args.program}: {parsed.tcp_problem}")
    tcp, tcp_rot, given, tool_source = _tool(args, parsed.tcp, identified)
    controller, before = controller_model(doc, robot)
    check, cell_note = _cell_check(args.config, robot)
    outcomes = filter_targets(parsed, identified.with_base(np.eye(4)), controller, tcp, tcp_rot, robot.home,
                              robot.limits, given, language, check)
    write_output(args.out, filtered_text(parsed, outcomes, language).encode("utf-8"), force=args.force)
    summary, code = _summary(args, parsed, outcomes, before, tool_source, verdict)
    summary["cell"] = cell_note
    done = [o.q_after for o in outcomes if o.literal is not None]
    if done:
        summary["domain"] = result_outside(doc, np.array(done))[1]
    return summary, code


def _cell_check(config: str | None, robot: Any) -> tuple[Callable[[np.ndarray], str] | None, str]:
    """The check of compensated joints against the cell of the plan checks (the site file ``config``, else the
    robot alone on its mounting surface), and what it checks."""
    from config.cell import cell_from_config, contact_at
    from config.robots import ConfigError
    from config.site import load_site, site_from_dict

    try:
        site = load_site(config) if config else site_from_dict({"schema": 1})
    except (ConfigError, OSError) as exc:
        raise InputError(str(exc)) from None
    cell = cell_from_config(robot, site)
    if cell is None:
        return None, f"not checked ({robot.name} has no collision geometry)"

    def check(q_dh: np.ndarray) -> str:
        contact = contact_at(cell, q_dh)
        if contact is None:
            return ""
        return (f"the compensated joints come too close: {contact.what} {contact.distance * 1e3:.1f} mm apart "
                f"(needs {contact.required * 1e3:.0f} mm)")

    return check, f"the cell of {config}" if config else "the robot on its mounting surface (no --config)"


def _summary(args: argparse.Namespace, parsed, outcomes: list[Outcome], before: str, tool_source: str,
             verdict: str | None) -> tuple[dict[str, Any], int]:
    done = [o for o in outcomes if o.literal is not None]
    kept = [{"line": o.target.line, "reason": o.reason, "text": _line(parsed.text, o.target.line)}
            for o in outcomes if o.literal is None]
    kept += [{"line": s.line, "reason": s.reason, "text": s.text} for s in parsed.skipped]
    expected = np.array([o.expected for o in done])
    summary = {
        "program": str(args.program), "targets": len(outcomes), "rewritten": len(done),
        "kept": sorted(kept, key=lambda k: k["line"]), "before": before, "tool": tool_source, "verdict": verdict,
        "largest_change_mm": max((o.position_change * 1e3 for o in done), default=None),
        "largest_joint_change_mrad": max((o.joint_change * 1e3 for o in done), default=None),
        "expected_median": float(np.median(expected)) if len(expected) else None,
        "expected_max": float(np.max(expected)) if len(expected) else None,
        "out": str(args.out),
    }
    return summary, 0 if not kept else 3


def _line(text: str, number: int) -> str:
    lines = text.splitlines()
    return lines[number - 1] if number <= len(lines) else ""


def format_program_summary(s: dict[str, Any]) -> str:
    """The lines the command prints for a filtered program."""
    lines = [f"{s['program']}: {s['targets']} targets, {s['rewritten']} rewritten; result verdict {s['verdict']}",
             f"before (what the controller runs today): {s['before']}; TCP: {s['tool']}",
             f"compensated joints checked against the joint limits and {s.get('cell', 'no cell')}"]
    if s["rewritten"]:
        lines.append(f"largest change: {s['largest_change_mm']:.3f} mm at the TCP, "
                     f"{s['largest_joint_change_mrad']:.3f} mrad in a joint; expected accuracy (1 sigma, 3D, base "
                     f"frame): median {s['expected_median'] * 1e3:.4f} mm, max {s['expected_max'] * 1e3:.4f} mm")
    if s["kept"]:
        lines.append(f"{len(s['kept'])} motion line(s) kept as written (NOT compensated):")
        lines += [f"  line {k['line']}: {k['reason']}: {k['text'].strip()}" for k in s["kept"]]
    if s.get("domain"):
        lines.append(f"domain: {s['domain']}")
    lines.append(f"written to {s['out']}")
    return "\n".join(lines)
