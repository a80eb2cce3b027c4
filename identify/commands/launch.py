"""The ``identify`` command's entry point: ``--help``, ``--version`` and usage errors before the heavy imports.

Parsing with the light parser (identify/commands/options.py) answers them at once; anything else goes on to the command
(identify/commands/cli.py, or a subcommand's module), which parses again. A stop signal (Ctrl-C, SIGTERM) during
start-up, imports included, or during the run stops the command with one line and exit code 130.
"""

from __future__ import annotations

import sys
from pathlib import Path

from common.stop_signals import deferred, guarded


def main(argv: list[str] | None = None) -> int:
    """``identify``; see :func:`identify.commands.cli.main`."""
    argv = sys.argv[1:] if argv is None else argv
    return guarded("identify", lambda: _main(argv))


def _main(argv: list[str]) -> int:
    with deferred():  # a stop during the imports is raised after them, never inside one (common/stop_signals.py)
        from identify.commands.options import SUBCOMMANDS, build_parser

        if not argv[:1] or argv[0] not in SUBCOMMANDS:
            args = build_parser().parse_args(argv)  # --help, --version and usage errors exit here
            if not Path(args.input).exists():
                print(f"identify: error: {args.input}: no such file", file=sys.stderr)
                return 2
        else:  # a subcommand's --help and usage errors too, before its imports
            from identify.commands import sub_options

            getattr(sub_options, f"{argv[0]}_parser")().parse_args(argv[1:])
        from importlib import import_module

        from identify.commands.cli import main as full_main

        if argv[:1] and argv[0] in SUBCOMMANDS:
            import_module(f"identify.commands.{argv[0]}_cli")  # the subcommand's own imports, here too
    return full_main(argv)


if __name__ == "__main__":
    sys.exit(main())
