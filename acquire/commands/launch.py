"""The ``acquire`` command's entry point: refuses a second writer of a session before the heavy imports.

``acquire --resume SESSION`` while another process writes SESSION is refused by the session's write lock
(session/lock.py). That refusal should come at once, but importing the acquisition and identification
code takes most of a second; so this module, which imports only the lock, takes the lock of the session named
by ``--resume`` first: if another process holds it, it prints the same one line as the full command and exits 2;
otherwise the lock stays held and :func:`acquire.commands.cli.main` claims it when it opens the session (so of two
writers started together, one is refused within milliseconds). Every other command goes straight through.
"""

from __future__ import annotations

import sys
from pathlib import Path

from common.stop_signals import deferred, guarded


def resume_target(argv: list[str]) -> Path | None:
    """The session a writing ``--resume`` names in ``argv`` (None for a dry run, another command, or none)."""
    if not argv or argv[0] in ("export", "backup", "calibrate-camera", "print-board") or "--dry-run" in argv:
        return None
    for k, arg in enumerate(argv):
        if arg == "--resume" and k + 1 < len(argv):
            return Path(argv[k + 1])
        if arg.startswith("--resume="):
            return Path(arg.split("=", 1)[1])
    return None


def main(argv: list[str] | None = None) -> int:
    """``acquire`` with a fast refusal of a second writer; see :func:`acquire.commands.cli.main` for the rest. A stop
    signal (Ctrl-C, SIGTERM, SIGHUP) while the command starts up stops it with one line and exit code 130: this module
    imports nothing else before its handlers are set."""
    argv = sys.argv[1:] if argv is None else argv
    return guarded("acquire", lambda: _main(argv))


SUBCOMMANDS = ("export", "backup", "verify", "calibrate-camera", "print-board")  # parsed by their own modules


def _main(argv: list[str]) -> int:
    # a stop during the imports is raised after them, never inside one (common/stop_signals.py)
    if argv[:1] in (["export"], ["backup"]):  # they need neither the lock nor the acquisition code
        with deferred():
            from acquire.commands.session_commands import main as session_command
        return session_command(argv)
    with deferred():
        if argv[:1] == ["verify"] and {"-h", "--help"} & set(argv[1:]):  # help without the estimator's imports
            from acquire.commands.verify_options import build_parser

            build_parser().parse_args(argv[1:])  # prints the help and exits 0
        if argv[:1] in (["calibrate-camera"], ["print-board"]):  # help and usage errors before OpenCV's imports
            from acquire.commands.camera_options import calibrate_parser, print_parser

            (calibrate_parser if argv[0] == "calibrate-camera" else print_parser)().parse_args(argv[1:])
        if not argv[:1] or argv[0] not in SUBCOMMANDS:
            refusal = _quick_refusal(argv)  # --help, --version, a bad option or spec: before the heavy imports
            if refusal is not None:
                return refusal
        from session.lock import Locked, busy_message, drop_held, hold

    target = resume_target(argv)
    if target is not None:
        try:
            hold(target)  # claimed by Session.open(write=True) in the full command
        except Locked as exc:
            print(f"acquire: error: {busy_message(target, exc.holder)}", file=sys.stderr)
            return 2
        except OSError:
            pass  # a missing or unreadable file: the full command says so in its own words
    try:
        with deferred():
            from importlib import import_module

            from acquire.commands.cli import main as full_main

            if argv[:1] in (["verify"], ["calibrate-camera"], ["print-board"]):  # the subcommand's imports too
                import_module("acquire.commands." + ("verify_cli" if argv[0] == "verify" else "camera_cli"))
        return full_main(argv)
    finally:
        drop_held()  # a lock the command never claimed (it stopped before opening the session)


def _quick_refusal(argv: list[str]) -> int | None:
    """Parse ``argv`` with the light parser (``--help`` and ``--version`` exit here) and check the device specs;
    the exit code of a refusal (its one line printed), or None to go on."""
    from acquire.commands.options import build_parser
    from drivers.errors import SpecError
    from drivers.spec import RobotSpec, TrackerSpec

    args = build_parser().parse_args(argv)
    try:
        if args.robot is not None:
            RobotSpec.parse(args.robot)
        if args.tracker is not None and args.tracker != "none":
            TrackerSpec.parse(args.tracker)
    except SpecError as exc:
        print(f"acquire: error: {exc}", file=sys.stderr)
        return 2
    return None


if __name__ == "__main__":
    sys.exit(main())
