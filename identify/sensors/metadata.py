"""The measurement CSV's device metadata (README, "File contracts"): ``# sensor:`` and ``# scale_sigma:``."""

from __future__ import annotations

import math

from common.errors import InputError

SENSORS = ("fixed", "flange")
UNKNOWN = math.inf  # ``scale_sigma`` of a device whose length scale nothing fixed


def parse_sensor(text: str) -> str:
    """The ``# sensor:`` metadata (``fixed`` or ``flange``); InputError for anything else."""
    value = text.strip().lower()
    if value not in SENSORS:
        raise InputError(f"'# sensor:' must be fixed or flange, got {text.strip()!r}")
    return value


def parse_scale_sigma(text: str) -> float:
    """``# scale_sigma:`` -> the relative standard uncertainty (a number >= 0) or :data:`UNKNOWN`; InputError."""
    value = text.strip().lower()
    if value == "unknown":
        return UNKNOWN
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not (math.isfinite(number) and number >= 0):
        raise InputError(f"'# scale_sigma:' must be a relative uncertainty >= 0 (e.g. 1e-4) or 'unknown', got "
                         f"{text.strip()!r}")
    return number


def format_scale_sigma(value: float) -> str:
    """The ``# scale_sigma:`` text of ``value`` (:data:`UNKNOWN` -> ``unknown``)."""
    return "unknown" if math.isinf(value) else repr(float(value))
