"""What both commands' light parsers share (acquire/commands/options.py, identify/commands/options.py): argparse that
reports a usage error in one line with exit code 2, a ``--version`` that looks the version up only when asked, and
options given as comma-separated numbers."""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable
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


def comma_numbers(text: str, what: str, counts: tuple[int, ...], lengths: int = 0) -> list[float]:
    """The finite numbers of an option given as ``x,y,z`` (``what`` names it in the message); the first ``lengths``
    are lengths that may carry a unit (``0,0,100mm``; bare: metres), returned in metres. InputError unless there
    are as many as one of ``counts``."""
    from common.units import parse_length

    try:
        values = [parse_length(v) if i < lengths else float(v) for i, v in enumerate(text.split(","))]
    except ValueError:
        kind = f" (the first {lengths} lengths, e.g. 0,0,100mm; a bare number is metres)" if lengths else ""
        raise InputError(f"{what} must be comma-separated numbers{kind}, got {text!r}") from None
    if len(values) not in counts or not all(math.isfinite(v) for v in values):
        raise InputError(f"{what} needs {' or '.join(map(str, counts))} finite numbers, got {text!r}")
    return values


#: The size options' bounds: name -> (least, most, why not more). Beyond ``most`` a run cannot finish in a working
#: shift (every stop of the robot takes a second or more) or its memory, or more tells nothing new; the command
#: line (:func:`size`) and the site file (config/site_checks.py) refuse it in one line before any work.
SIZES: dict[str, tuple[int, int, str]] = {
    "steps": (3, 1000, "steps per sweep: 1000 stops per joint are hours of robot time"),
    "samples": (1, 1000, "tracker readings per step: 1000 are minutes per step"),
    "free_poses": (0, 5000, "free poses: 5000 are hours of robot time"),
    "check_poses": (0, 5000, "held-out poses: 5000 are hours of robot time"),
    "cycles": (2, 1000, "visits of each pose: ISO 9283 asks for 30; 1000 are hours of robot time"),
    "count": (1, 100_000, "readings: 100000 are hours at a polled tracker's rate"),
    "poses": (1, 100_000, "random poses: more sharpen nothing the test shows"),
    "views": (1, 1000, "views at one a second"),
}


def size(name: str) -> Callable[[str], int]:
    """argparse ``type=`` for the size option ``name`` of :data:`SIZES`: an integer up to its bound, else a one-line
    error saying the bound and why (the least is checked where the value is used, with the site file's)."""
    _, high, why = SIZES[name]

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if value > high:
            raise argparse.ArgumentTypeError(f"{value} is more than {high}, the most it takes ({why})")
        return value

    return parse
