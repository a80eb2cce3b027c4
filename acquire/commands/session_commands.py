"""``acquire export`` and ``acquire backup``: a session's measurements as a CSV, and a safe copy of a session.

Each parses its arguments before importing the session code, so ``--help`` and a usage error answer at once;
``acquire/commands/launch.py`` sends them here without importing the acquisition code at all.
"""

from __future__ import annotations

import sys
from pathlib import Path

from common.arguments import OneLineParser


def export(argv: list[str]) -> int:
    """``acquire export SESSION --csv OUT.csv [--force]``."""
    p = OneLineParser(prog="acquire export",
                      description="Write a session's measurements as a measurement CSV (the file identify reads; "
                      "its columns: README.md, File contracts). A session being written can be exported.",
                      epilog="exit codes: 0 written, 2 bad input (one line)")
    p.add_argument("session", type=Path, help="the session file to read (never changed)")
    p.add_argument("--csv", type=Path, required=True, metavar="OUT.csv", help="the CSV to write")
    p.add_argument("--force", action="store_true", help="replace the CSV if it exists")
    args = p.parse_args(argv)
    from acquire.running.session import Session
    from common.outputs import check_outputs
    from identify.io.session_measurements import stream_summary

    check_outputs([args.session], [("--csv", args.csv)], args.force)
    with Session.open(args.session) as session:
        rows = session.export_csv(args.csv, force=args.force)
        summary = stream_summary(session) if session.plan.continuous else None
        if summary is not None:
            print(summary.line())
    print(f"wrote {args.csv} ({rows} rows)")
    return 0


def backup(argv: list[str]) -> int:
    """``acquire backup SESSION DEST [--force]``."""
    p = OneLineParser(prog="acquire backup", description="Copy a session safely, even while it is being written "
                      "(SQLite's online backup API).", epilog="exit codes: 0 copied, 2 bad input (one line)")
    p.add_argument("session", type=Path, help="the session file to copy (never changed)")
    p.add_argument("dest", type=Path, help="the copy (a new file; an existing one only with --force)")
    p.add_argument("--force", action="store_true", help="replace DEST if it exists")
    args = p.parse_args(argv)
    from session.backup import backup_session

    steps = backup_session(args.session, args.dest, args.force)
    print(f"copied {args.session} to {args.dest} ({steps} steps)")
    return 0


def main(argv: list[str]) -> int:
    """``acquire export ...`` or ``acquire backup ...`` (``argv`` starts with the subcommand); a bad input is one
    line and exit code 2."""
    from common.errors import InputError
    from session.schema import SessionError

    try:
        return (export if argv[0] == "export" else backup)(argv[1:])
    except (InputError, SessionError, ValueError) as exc:
        print(f"acquire: error: {exc}", file=sys.stderr)
        return 2
