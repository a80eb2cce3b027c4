"""``identify compensate RESULT --targets FILE --out FILE``: joint values (or controller poses) that bring the real

Its options and help: identify/commands/sub_options.py (light, so that --help answers at once).
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from common import __version__
from common.arguments import comma_numbers
from common.errors import InputError
from common.fit_width import say
from common.outputs import check_outputs, write_output
from identify.applications.calibrated import CalibratedModel, ResultError, nominal_name, recorded_model, robot_model
from identify.applications.compensate import (
    Compensation,
    compensate,
    controller_poses,
    pose_matrices,
    rotvecs,
    ur_pose,
    why_not,
)
from identify.applications.controller import check_same_robot, controller_model
from identify.applications.domain import result_outside
from identify.commands.sub_options import compensate_parser as build_parser
from identify.io.result_io import load_result

MAX_COORDINATE = 10.0  # m: a target farther than this from the origin is almost surely in millimetres


def read_targets(path: str | Path) -> tuple[dict[str, np.ndarray], list[str]]:
    """Numeric columns of a targets CSV (name -> (k,) array) and the ``id`` column as text (or empty)."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: no such targets file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot be read as UTF-8 text ({exc})") from None
    lines = [(k + 1, line) for k, line in enumerate(text.splitlines()) if line.strip() and not line.startswith("#")]
    if not lines:
        raise InputError(f"{path}: no header row and no targets")
    header = [h.strip().lower() for h in next(csv.reader([lines[0][1]]))]
    if len(set(header)) != len(header):
        raise InputError(f"{path}: repeated column names in the header {header}")
    columns: dict[str, list[float]] = {h: [] for h in header if h != "id"}
    ids: list[str] = []
    for number, row in zip((n for n, _ in lines[1:]), csv.reader(line for _, line in lines[1:]), strict=True):
        if len(row) != len(header):
            raise InputError(f"{path}: line {number} has {len(row)} fields, the header {len(header)}")
        for name, value in zip(header, row, strict=True):
            if name == "id":
                ids.append(value.strip())
                continue
            try:
                v = float(value)
            except ValueError:
                raise InputError(f"{path}: line {number}: {name} = {value!r} is not a number") from None
            if not np.isfinite(v):
                raise InputError(f"{path}: line {number}: {name} is not finite")
            columns[name].append(v)
    if len(lines) < 2:
        raise InputError(f"{path}: a header but no targets")
    return {k: np.array(v) for k, v in columns.items()}, ids


def _need(columns: dict[str, np.ndarray], names: list[str], path: str, why: str) -> np.ndarray:
    missing = [c for c in names if c not in columns]
    if missing:
        raise InputError(f"{path}: {why} needs the columns {','.join(names)}; missing {','.join(missing)}")
    return np.column_stack([columns[c] for c in names])


def run(args: argparse.Namespace) -> tuple[dict[str, Any], int]:
    """Compensate per ``args``; returns the summary and the exit code. InputError for bad input."""
    robot_file = args.robot if args.robot and Path(args.robot).is_file() else None
    check_outputs([args.result, args.targets or args.program, robot_file, args.config], [("--out", args.out)],
                  args.force)
    try:
        identified, doc = load_result(args.result)
    except ResultError as exc:
        raise InputError(str(exc)) from None
    status = (doc.get("verdict") or {}).get("status")
    if status == "fail":
        raise InputError(f"{args.result} fails its verdict: its model must not be used (see the result's checks)")
    robot = (robot_model(args.robot) if args.robot is not None
             else robot_model(nominal_name(doc), recorded_model(doc), str(args.result)))
    n = identified.n_joints
    misfit = None
    if robot is not None:  # another robot model's joint values mean another arm: refused before any work
        misfit = check_same_robot(doc, identified.model.joint_types, robot, result=str(args.result),
                                  identified=identified)
    if args.program:
        from identify.commands.program_cli import run_program

        return run_program(args, identified, doc, robot, status)
    if args.output == "controller-pose" and robot is None:
        raise InputError("--as controller-pose needs the controller's model: give --robot (the result names none)")
    tcp, tcp_rot = identified.tool(), np.eye(3)
    if args.tool:
        values = comma_numbers(args.tool, "--tool", (3, 6), lengths=3)
        tcp = np.array(values[:3])
        if len(values) == 6:
            tcp_rot = pose_matrices(np.zeros(3), np.array(values[3:]))[0, :3, :3]
    columns, ids = read_targets(args.targets)
    qnames = [f"q{i}" for i in range(1, n + 1)]
    k = len(next(iter(columns.values()))) if columns else len(ids)
    home = robot.home if robot is not None else (np.array((doc.get("axis_lines") or {}).get("home") or np.zeros(n)))
    given = all(c in columns for c in qnames)
    seeds = _need(columns, qnames, args.targets, "a seed") if given else np.tile(home, (k, 1))
    in_base = args.frame == "base" or args.joints_from is not None
    nominal = planned = None
    before = "none"
    if robot is not None:  # the controller's model ("before": what the arm runs today), in the targets' frame
        base = np.eye(4) if in_base else identified.base
        ctrl, before = controller_model(doc, robot)
        nominal = CalibratedModel.exact(replace(ctrl, base=base, tool=identified.tool()), before)
        planned = CalibratedModel.exact(replace(robot.nominal, base=base, tool=identified.tool()), robot.name)
    model = identified.with_base(np.eye(4)) if in_base else identified
    rotations = None
    if args.joints_from:
        if planned is None:
            raise InputError("--joints-from nominal needs the nominal model: give --robot (the result names none)")
        flange = planned.flanges(identified.dh_values(seeds))  # rows are readings; the nominal takes DH values
        points = flange[:, :3, :3] @ tcp + flange[:, :3, 3]
        rotations = flange[:, :3, :3] @ tcp_rot if n >= 6 else None
    else:
        points = _need(columns, ["x", "y", "z"], args.targets, f"--frame {args.frame}")
        far = np.linalg.norm(points, axis=1) > MAX_COORDINATE
        if far.any():
            distance = float(np.linalg.norm(points, axis=1).max())
            raise InputError(f"{args.targets}: target {int(np.argmax(far)) + 1} is {distance:.4g} m away: positions "
                             "are metres (millimetres?)")
        if args.frame == "base" and any(c in columns for c in ("rx", "ry", "rz")):
            rotations = pose_matrices(points, _need(columns, ["rx", "ry", "rz"], args.targets, "an orientation"))[
                :, :3, :3]  # the tool's orientation: solve_ik matches flange x tool rotation to it
    limits = robot.limits if robot is not None else None
    frame = "base" if in_base else "tracker"
    tool = tcp if args.tool else None  # the identified TP keeps its own uncertainty; a given tool is exact
    result = compensate(model, points, seeds, limits, rotations, tool, tcp_rot if rotations is not None else None,
                        nominal, frame)
    poses = None
    if args.output == "controller-pose":
        poses = controller_poses(replace(nominal, model=replace(nominal.model, base=np.eye(4))),
                                 identified.dh_values(result.solution.q), tcp, tcp_rot)
    text = _output_csv(args, result, ids, poses, n, tcp, tcp_rot, identified, before)
    write_output(args.out, text, force=args.force)
    summary = _summary(result, args, status, robot)
    summary["before"] = before
    if misfit is not None:
        summary["note"] = (f"the result records no robot model: {robot.name} taken as its nominal (it fits the "
                           f"identified arm within {misfit * 1e3:.2g} mm RMS)")
    summary["domain"] = result_outside(doc, result.solution.q[result.solution.reached])[1]
    return summary, 0 if bool(np.all(result.solution.reached)) else 3


def _output_csv(args: argparse.Namespace, result: Compensation, ids: list[str], poses: np.ndarray | None, n: int,
                tcp: np.ndarray, tcp_rot: np.ndarray, identified: CalibratedModel, before: str) -> str:
    sol = result.solution
    buf = io.StringIO()
    buf.write(f"# compensated by dh-calib {__version__} from {args.result}; targets {args.targets}"
              + (" (joints planned with the nominal model)" if args.joints_from else f" ({args.frame} frame)") + "\n")
    how = "its DH table" if identified.predictor is None else "the identification's predictor (axis lines, " \
        "coupling, joint errors)"
    buf.write(f"# identified model predicts with {how}; "
              f"controller model (before): {before}; tool {', '.join(f'{v:.6g}' for v in tcp)} m, "
              f"rotation {', '.join(f'{v:.6g}' for v in rotvecs(tcp_rot[None])[0])} rad (flange frame)\n")
    buf.write("# units: m, rad. status: ok | singular | limit | unreachable; position_error / rotation_error: what "
              "the identified model misses the target by; expected: 1-sigma 3D error of the reached point from the "
              "result's covariance and model error; seed_change: largest joint change from "
              "the seed; a target not reached has no joint values, its reason says why\n")
    w = csv.writer(buf, lineterminator="\n")
    head = ["row", *(["id"] if ids else []), "status", *(f"q{i}" for i in range(1, n + 1)), "position_error",
            "rotation_error", "expected", "seed_change"]
    if poses is not None:
        head += ["x", "y", "z", "rx", "ry", "rz", "ur_pose"]
    w.writerow([*head, "reason"])
    rv = None if poses is None else rotvecs(poses)
    for i in range(len(sol.q)):
        reached = bool(sol.reached[i])  # a target not reached gets no joint values: only its reason
        row: list[Any] = [i + 1, *([ids[i]] if ids else []), sol.status[i],
                          *((f"{v:.12g}" for v in sol.q[i]) if reached else [""] * n),
                          f"{sol.position_error[i]:.3g}",
                          "" if np.isnan(sol.rotation_error[i]) else f"{sol.rotation_error[i]:.3g}",
                          "" if np.isnan(result.expected[i]) else f"{result.expected[i]:.4g}",
                          f"{sol.seed_change[i]:.4g}" if reached else ""]
        if poses is not None and rv is not None:
            row += ([*(f"{v:.12g}" for v in poses[i, :3, 3]), *(f"{v:.12g}" for v in rv[i]), ur_pose(poses[i])]
                    if reached else [""] * 7)
        w.writerow([*row, "" if reached and sol.status[i] == "ok" else why_not(str(sol.status[i]), reached)])
    return buf.getvalue()


def _summary(result: Compensation, args: argparse.Namespace, verdict: str | None, robot) -> dict[str, Any]:
    sol = result.solution
    counts = {s: int(np.sum(sol.status == s)) for s in ("ok", "singular", "limit", "unreachable")}
    reached = sol.reached
    expected = result.expected[reached]
    out: dict[str, Any] = {
        "targets": len(sol.q), "reached": int(reached.sum()), "status": counts, "verdict": verdict,
        "expected_median": float(np.median(expected)) if len(expected) else None,
        "expected_max": float(np.max(expected)) if len(expected) else None,
        "out": str(args.out),
    }
    if result.nominal is not None:
        both = reached & result.nominal.reached
        change = np.max(np.abs(sol.q[both] - result.nominal.q[both]), axis=1) if both.any() else np.zeros(0)
        out["change_from_nominal_max"] = float(change.max()) if len(change) else None
        out["change_from_nominal_median"] = float(np.median(change)) if len(change) else None
    if robot is None:
        out["note"] = "no nominal model: no joint limits, seeds from the result's home"
    return out


def format_summary(s: dict[str, Any]) -> str:
    """The summary as the lines the command prints."""
    counts = ", ".join(f"{v} {k}" for k, v in s["status"].items() if v or k == "ok")
    lines = [f"{s['targets']} targets: {counts}; result verdict {s['verdict']}"]
    if s.get("before") and s["before"] != "none":
        lines.append(f"before (what the controller runs today): {s['before']}")
    if s["expected_median"] is not None:
        lines.append(f"expected accuracy of the reached targets (1 sigma, 3D): median {s['expected_median'] * 1e3:.4f} "
                     f"mm, max {s['expected_max'] * 1e3:.4f} mm")
    if s.get("change_from_nominal_max") is not None:
        lines.append(f"joint change from the nominal solution: median {s['change_from_nominal_median'] * 1e3:.4f}, "
                     f"max {s['change_from_nominal_max'] * 1e3:.4f} mrad (mm for prismatic joints)")
    if s.get("note"):
        lines.append(f"note: {s['note']}")
    if s.get("domain"):
        lines.append(f"domain: {s['domain']}")
    if s["reached"] < s["targets"]:
        lines.append(f"{s['targets'] - s['reached']} target(s) NOT reached: see the status column")
    lines.append(f"written to {s['out']}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(sys.argv[2:] if argv is None else argv)
    try:
        summary, code = run(args)
    except InputError as exc:
        print(f"identify compensate: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("identify compensate: interrupted", file=sys.stderr)
        return 130
    if args.json:
        print(json.dumps(summary, allow_nan=False))
    elif args.program:
        from identify.commands.program_cli import format_program_summary

        say(format_program_summary(summary))  # wrapped to the terminal (a kept line quotes the program)
    else:
        say(format_summary(summary))
    return code
