"""Lengths and durations on the command line: a number with its unit (``0.05mm``, ``50um``, ``2 cm``; ``90s``,
``1.5min``); a bare number is metres or seconds.

Every option that takes a length (``--noise``, ``--max-offset``, a marker's ``--size``...) parses it here, so a
tracker noise meant in millimetres can be written as such instead of being read as metres; so does every option
that takes a duration (``--max-robot-time``).
"""

from __future__ import annotations

import argparse
import math
import re

#: metres per unit; ``um``, ``µm`` (micro sign) and ``μm`` (Greek mu) are the same micrometre
LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "μm": 1e-6, "in": 0.0254}
_SHOWN = ("m", "cm", "mm", "um", "in")  # as the error message lists them

#: seconds per unit
TIME_UNITS = {"s": 1.0, "min": 60.0, "h": 3600.0}

_QUANTITY = re.compile(r"\s*(?P<number>[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?)\s*(?P<unit>[^\d\s.+-]*)\s*")


def _quantity(text: str, units: dict[str, float], kind: str, shown: tuple[str, ...] | list[str], examples: str,
              bare: str) -> float:
    """``text``, a number with one of ``units`` (or none: the base unit, named ``bare``), in the base unit.
    ValueError (one line naming the accepted units and ``examples``) for anything else, non-finite numbers
    included."""
    match = _QUANTITY.fullmatch(text)
    unit = match["unit"] if match else None
    if match is None or unit not in ("", *units):
        raise ValueError(f"{text!r} is not a {kind}: write a number with a unit ({', '.join(shown)}), e.g. {examples}; "
                         f"a bare number is {bare}")
    value = float(match["number"]) * (units[unit] if unit else 1.0)
    if not math.isfinite(value):
        raise ValueError(f"{text!r} is not a finite {kind}")
    return value


def parse_length(text: str) -> float:
    """``text`` as metres: ``0.05mm`` -> 5e-05, ``50um`` -> 5e-05, ``5e-5`` -> 5e-05. ValueError (one line, naming
    the accepted units) for anything else, non-finite numbers included."""
    return _quantity(text, LENGTH_UNITS, "length", _SHOWN, "0.05mm or 50um", "metres")


def length(text: str) -> float:
    """argparse ``type=`` for a length option (metres)."""
    try:
        return parse_length(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def positive_length(text: str) -> float:
    """argparse ``type=`` for a length that must be > 0 (metres)."""
    value = length(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text!r}: must be a positive length")
    return value


def parse_duration(text: str) -> float:
    """``text`` as seconds: ``90s`` -> 90.0, ``1.5min`` -> 90.0, ``2h`` -> 7200.0, ``90`` -> 90.0. ValueError (one
    line, naming the accepted units) for anything else, non-finite numbers included."""
    return _quantity(text, TIME_UNITS, "duration", list(TIME_UNITS), "90s or 1.5min", "seconds")


def hms(seconds: float) -> str:
    """``seconds`` as H:MM:SS, rounded to the second (negative: 0:00:00)."""
    seconds = max(0, round(seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


def positive_duration(text: str) -> float:
    """argparse ``type=`` for a duration that must be > 0 (seconds)."""
    try:
        value = parse_duration(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text!r}: must be a positive duration")
    return value
