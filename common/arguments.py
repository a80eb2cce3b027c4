"""What both commands' light parsers share (acquire/commands/options.py, identify/commands/options.py): argparse that
reports a usage error in one line with exit code 2, and a ``--version`` that looks the version up only when asked."""

from __future__ import annotations

import argparse


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports usage errors in one line with exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


class VersionAction(argparse.Action):
    """``--version``: the software's version, looked up only when asked (importlib.metadata is not free)."""

    def __init__(self, option_strings: list[str], dest: str, **kwargs: object) -> None:
        super().__init__(option_strings, dest, nargs=0, help="print the version of dh-calib and exit")

    def __call__(self, parser: argparse.ArgumentParser, *args: object) -> None:
        from common import __version__

        parser.exit(0, f"{parser.prog} (dh-calib) {__version__}\n")
