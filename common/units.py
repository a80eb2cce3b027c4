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
from collections.abc import Callable
from typing import Any

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


class Typed(argparse.Action):
    """argparse action of a length or duration option: ``convert`` (e.g. :func:`positive_length`) gives its value
    (m or s), and the text as typed is kept (:func:`as_typed`) for messages that repeat it."""

    def __init__(self, option_strings: list[str], dest: str, convert: Callable[[str], float], **kwargs: Any) -> None:
        super().__init__(option_strings, dest, **kwargs)
        self.convert = convert

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        try:
            value = self.convert(values)
        except argparse.ArgumentTypeError as exc:
            raise argparse.ArgumentError(self, str(exc)) from None
        setattr(namespace, self.dest, value)
        setattr(namespace, TYPED, {**getattr(namespace, TYPED, {}), self.dest: values.strip()})


TYPED = "typed_texts"  # the Namespace attribute of the texts as typed: {dest: text}


def as_typed(args: argparse.Namespace, dest: str) -> str | None:
    """The text option ``dest`` was given as on the command line (None: not given, or not a :class:`Typed`)."""
    return getattr(args, TYPED, {}).get(dest)


#: a length unit 1000x smaller or larger: the unit of a slip's correction (a bare number is metres)
_FINER = {"": "mm", "m": "mm", "mm": "um", "µm": "nm", "μm": "nm", "um": "nm"}
_COARSER = {"um": "mm", "µm": "mm", "μm": "mm", "mm": "m"}


def mm(metres: float) -> str:
    """A length for a message: ``0.05 mm``, ``50 mm`` (4 significant digits)."""
    return f"{metres * 1e3:.4g} mm"


def slip_hint(option: str, typed: str | None, metres: float, too_large: bool = True) -> str:
    """What an operator is told of a length that looks 1000x off: ``--noise 0.05 is read as 50 mm; did you mean
    0.05mm?``, repeating the text as typed (``typed``; None: ``metres`` shown instead) with the unit one step
    smaller (``too_large``) or larger."""
    shown = typed if typed is not None else f"{metres:g}"
    said = f"{option} {shown} is read as {mm(metres)}"
    match = _QUANTITY.fullmatch(typed or "")
    unit = match["unit"] if match else None
    fix = (_FINER if too_large else _COARSER).get(unit) if unit is not None else None
    if fix is None or fix == "nm":
        return f"{said}; give the unit, e.g. {option} {'0.05mm' if too_large else '50um'}"
    return f"{said}; did you mean {match['number']}{fix}?"
