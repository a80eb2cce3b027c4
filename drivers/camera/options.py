"""The typed options of an ``aruco:`` tracker spec (drivers/camera/tracker.py documents them): a number checked in
one line, and the simulated camera's (``aruco:sim``) options."""

from __future__ import annotations

import math
from typing import Any

from drivers.camera.imperfections import parse as parse_imperfections
from drivers.errors import SpecError
from drivers.spec import TrackerSpec, parse_faults, parse_interval

FORM = ("aruco:SOURCE?camera=FILE&marker=ID&size=M (or board=grid|charuco&cols=N&rows=N&size=M&gap=M&square=M, "
        "or layout=FILE)&tp=X,Y,Z&refine=edges|apriltag|subpix|contour|none&frames=N")


def spec_error(spec: TrackerSpec, why: str) -> SpecError:
    """One line: the spec, what is wrong with it, and the form expected."""
    return SpecError(f"tracker spec {str(spec)!r}: {why}; expected {FORM}")


def number(spec: TrackerSpec, raw: dict[str, Any], key: str, default: float, kind: type = float,
            low: float = 0.0, strict: bool = True) -> Any:
    """Option ``key`` of ``raw`` as ``kind`` (``default`` when absent), above ``low`` (``strict``) or not below it."""
    if key not in raw:
        return default
    try:
        value = kind(raw[key])
    except (TypeError, ValueError):
        kind_name = "an integer" if kind is int else "a number"
        raise spec_error(spec, f"option {key}={raw[key]} must be {kind_name}") from None
    if not math.isfinite(value) or value < low or (strict and value == low):
        raise spec_error(spec, f"option {key}={raw[key]} must be {'>' if strict else '>='} {low:g}")
    return value


def sim_settings(spec: TrackerSpec, raw: dict[str, Any]) -> dict[str, Any]:
    """The simulated camera's options (``aruco:sim``), typed and checked; SpecError."""
    out = {"width": number(spec, raw, "width", 640, int), "height": number(spec, raw, "height", 480, int),
           "fov": number(spec, raw, "fov", 60.0), "noise": number(spec, raw, "noise", 2.0, low=0, strict=False),
           "blur": number(spec, raw, "blur", 0.5, low=0, strict=False),
           "motion": number(spec, raw, "motion", 0.0, low=0, strict=False), "fps": number(spec, raw, "fps", 30.0),
           "latency": number(spec, raw, "latency", 0.0, low=0, strict=False),
           "drop": number(spec, raw, "drop", 0.0, low=0, strict=False),
           "distance": number(spec, raw, "distance", 1.0), "tilt": number(spec, raw, "tilt", 20.0, low=-90),
           "roll": number(spec, raw, "roll", 10.0, low=-360),
           "seed": None if "seed" not in raw else number(spec, raw, "seed", 0, int, 0, strict=False),
           "printed": number(spec, raw, "printed", 1.0)}
    try:
        out["k1"] = float(raw.get("k1", 0.0))
        out["fault"] = parse_faults(str(raw["fault"]), "tracker") if "fault" in raw else ()
        out["lost"] = parse_interval("lost", str(raw["lost"])) if "lost" in raw else (0.0, 0.0)
        out["imperfections"] = parse_imperfections(raw)
    except ValueError as exc:
        why = str(exc).replace("could not convert string to float", "option k1 must be a number")
        raise spec_error(spec, why) from None
    if not out["fov"] < 170:
        raise spec_error(spec, "option fov must be below 170 degrees")
    if not out["drop"] < 1:
        raise spec_error(spec, "option drop must be a probability below 1")
    return out
