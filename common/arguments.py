"""What both commands' light parsers share (acquire/commands/options.py, identify/commands/options.py): argparse that
reports a usage error in one line with exit code 2, a ``--version`` that looks the version up only when asked, and
options given as comma-separated numbers."""

from __future__ import annotations

import argparse
import math
import re
from typing import Any

from common.errors import InputError

#: a negative number, with a unit or not (``-0.05mm``, ``-3 s``): an option's value, never an option's name
NEGATIVE = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\s*[^\d\s.+-]*$")


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports usage errors in one line with exit code 2, and reads a negative number with a unit
    (``--noise -0.05mm``) as a value, to be refused for its sign rather than as a missing argument."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


class VersionAction(argparse.Action):
    """``--version``: the software's version, looked up only when asked (importlib.metadata is not free)."""

    def __init__(self, option_strings: list[str], dest: str, **kwargs: object) -> None:
        super().__init__(option_strings, dest, nargs=0, help="print the version of dh-calib and exit")

    def __call__(self, parser: argparse.ArgumentParser, *args: object) -> None:
        from common import __version__

        parser.exit(0, f"{parser.prog} (dh-calib) {__version__}\n")


def comma_numbers(text: str, what: str, counts: tuple[int, ...]) -> list[float]:
    """The finite numbers of an option given as ``x,y,z`` (``what`` names it in the message); InputError unless
    there are as many as one of ``counts``."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise InputError(f"{what} must be comma-separated numbers, got {text!r}") from None
    if len(values) not in counts or not all(math.isfinite(v) for v in values):
        raise InputError(f"{what} needs {' or '.join(map(str, counts))} finite numbers, got {text!r}")
    return values
