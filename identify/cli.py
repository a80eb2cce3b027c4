"""``identify INPUT``: identify DH parameters from a measurement CSV (the edge where files are read).

Exit codes: 0 success, 2 bad input or usage (one line on stderr), 1 an identification that failed.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Any

import yaml

from identify import __version__
from identify.cpa import DEFAULT_PARALLEL_TOL
from identify.csvio import UNITS, CsvContent, read_measurements
from identify.kinematics import DHModel
from identify.measurements import InputError
from identify.pipeline import identify, split_holdout
from identify.refine import DEFAULT_MAX_OFFSET
from identify.report import format_report
from identify.result_io import result_to_dict


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors in one line with exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="identify",
        description="Identify a robot's DH parameters, base and tracked point from a measurement CSV "
        "(sweeps of one joint at a time; see README for the format).",
    )
    parser.add_argument("input", help="measurement CSV (sweep,joint,q1..qN,x,y,z) or an acquisition session file")
    parser.add_argument("--out", metavar="FILE", help="write the result YAML (DESIGN.md contract) to FILE")
    parser.add_argument("--json", action="store_true", help="print the full result as JSON instead of a table")
    parser.add_argument("--joints", metavar="TYPES", help="joint types base to tip, e.g. RRPR (overrides the file)")
    parser.add_argument("--units", choices=sorted(UNITS), help="unit of x, y, z and sigma (default: file or m)")
    parser.add_argument("--robot", metavar="MODEL", help="nominal model for comparison (e.g. ur5e, or a YAML path)")
    parser.add_argument("--holdout", type=float, default=0.3, metavar="FRACTION",
                        help="share of free poses held out for validation when there is no role column (0.3)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the hold-out draw (0)")
    parser.add_argument("--parallel-tol", type=float, default=DEFAULT_PARALLEL_TOL, metavar="RAD",
                        help=f"axes closer than this are treated as parallel ({DEFAULT_PARALLEL_TOL} rad)")
    parser.add_argument("--max-offset", type=float, default=DEFAULT_MAX_OFFSET, metavar="M",
                        help="exact DH for resolved near-parallel axes only if no d moves more than this "
                        f"({DEFAULT_MAX_OFFSET} m)")
    parser.add_argument("--no-robust", action="store_true", help="plain least squares, no outlier rejection")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    return parser


def _load_nominal(name: str) -> tuple[DHModel, str]:
    from config.robots import ConfigError, load_robot

    try:
        robot = load_robot(name)
    except ConfigError as exc:
        raise InputError(str(exc)) from None
    return robot.nominal, robot.name


def _is_session(path: Path) -> bool:
    """True for an SQLite file (an acquisition session) rather than a CSV."""
    try:
        with path.open("rb") as fh:
            return fh.read(16) == b"SQLite format 3\x00"
    except OSError:
        return False


def _read_session(path: Path) -> CsvContent:
    """The measurements of an acquisition session (the session format belongs to ``acquire``)."""
    from acquire.session import Session, SessionError

    try:
        with Session.open(path) as session:
            return CsvContent(session.to_measurements(), {"session": str(path)}, [])
    except SessionError as exc:
        raise InputError(str(exc)) from None


def _write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file in the same folder, so a crash leaves no half file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Identify per ``args``; returns the result document. Raises InputError for bad input."""
    if not 0.0 <= args.holdout < 1.0:
        raise InputError(f"--holdout must be in [0, 1), got {args.holdout}")
    if _is_session(Path(args.input)):
        content = _read_session(Path(args.input))
    else:
        content = read_measurements(args.input, args.joints, args.units)
    meas = split_holdout(content.measurements, args.holdout, args.seed)
    nominal, nominal_name = (None, None)
    if args.robot:
        nominal, nominal_name = _load_nominal(args.robot)
        if nominal.joint_types != meas.joint_types:
            raise InputError(f"--robot {nominal_name} has joints {nominal.joint_types}, the data have "
                             f"{meas.joint_types}")
    ident = identify(meas, nominal, args.parallel_tol, robust=not args.no_robust, max_offset=args.max_offset)
    ident.warnings[:0] = content.notes
    doc = result_to_dict(ident, nominal, nominal_name, source=str(args.input))
    if args.out:
        _write_atomic(Path(args.out), yaml.safe_dump(doc, sort_keys=False, width=120))
    if args.json:
        print(json.dumps(doc))
    else:
        print(format_report(ident, nominal, nominal_name))
        if args.out:
            print(f"result written to {args.out}")
    return doc


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        run(args)
    except InputError as exc:
        print(f"identify: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("identify: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # numerical failure: one line, not a traceback; --debug-free by design
        print(f"identify: error: identification failed: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
