"""The site file's value checks (config/site.py reads the file): :data:`CHECKS` holds, for every field of
``SiteConfig``, a function ``check(validator, dotted_key, value)`` that returns the value to store or raises
:class:`ConfigError` (one line: source, dotted key, expected value, found value).

Units as in the file: m, rad, s; poses are 4x4 (base frame ← camera); per-joint values base to tip.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from common.arguments import SIZES
from config.files import ConfigError, got, read_yaml

Range = tuple[float, float]  # [min, max] of a joint, rad / m


class Validator:
    """Value checks; every failure is a :class:`ConfigError` naming ``source`` and the dotted key."""

    def __init__(self, source: str | Path) -> None:
        self.source = source

    def fail(self, key: str, expected: str, value: Any) -> ConfigError:
        return ConfigError(self.source, key, expected, got(value))

    def known(self, section: str | None, mapping: dict[str, Any], allowed: Any) -> None:
        for key in mapping:
            if key not in allowed:
                dotted = str(key) if section is None else f"{section}.{key}"
                where = "at the top level" if section is None else f"in '{section}'"
                raise ConfigError(self.source, dotted, f"only the keys {', '.join(allowed)} {where}",
                                  "an unknown key")

    def text(self, key: str, value: Any) -> str | None:
        if value is None:
            return None
        if not isinstance(value, str) or not value.strip():
            raise self.fail(key, "a non-empty string (or null)", value)
        return value.strip()

    def number(self, key: str, value: Any, expected: str, low: float, strict: bool) -> float:
        ok = not isinstance(value, bool) and isinstance(value, int | float) and math.isfinite(value)
        if not ok or value < low or (strict and value == low):
            raise self.fail(key, expected, value)
        return float(value)

    def integer(self, key: str, value: Any, low: int, size: str | None = None) -> int:
        """``value``, an integer >= ``low`` and, for a size of :data:`common.arguments.SIZES`, at most its bound."""
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise self.fail(key, f"an integer >= {low}", value)
        if size is not None and value > SIZES[size][1]:
            _, high, why = SIZES[size]
            raise self.fail(key, f"an integer from {low} to {high} ({why})", value)
        return value

    def numbers(self, key: str, value: Any, expected: str, count: int | None = None,
                positive: bool = False) -> tuple[float, ...]:
        if not isinstance(value, list) or not value or (count is not None and len(value) != count):
            raise self.fail(key, expected, value)
        low = 0.0 if positive else -math.inf
        return tuple(self.number(f"{key}[{i}]", x, expected, low, strict=positive) for i, x in enumerate(value))


def positive(unit: str) -> Any:
    return lambda v, key, x: v.number(key, x, f"a number > 0 ({unit})", 0.0, strict=True)


def hosts(v: Validator, key: str, value: Any) -> dict[str, str]:
    expected = "a mapping from robot model name to host, e.g. {ur5e: 192.168.1.10}"
    if not isinstance(value, dict):
        raise v.fail(key, expected, value)
    out = {}
    for name, host in value.items():
        if not isinstance(name, str) or not name.strip():
            raise v.fail(key, expected, name)
        out[name.strip().lower()] = v.text(f"{key}.{name}", host) or ""
        if not out[name.strip().lower()]:
            raise v.fail(f"{key}.{name}", "a host name or address", host)
    return out


def settings(v: Validator, key: str, value: Any) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise v.fail(key, "a mapping of setting names to numbers, strings or booleans", value)
    for name, item in value.items():
        if not isinstance(name, str) or not (item is None or isinstance(item, str | int | float | bool)):
            raise v.fail(f"{key}.{name}", "a number, string or boolean", item)
    return dict(value)


def joints(v: Validator, key: str, value: Any) -> tuple[int, ...] | None:
    if value is None:
        return None
    expected = "a list of distinct 1-based joint numbers (or null for all joints)"
    if not isinstance(value, list) or not value:
        raise v.fail(key, expected, value)
    out = tuple(v.integer(f"{key}[{i}]", j, 1) for i, j in enumerate(value))
    if len(set(out)) != len(out):
        raise v.fail(key, expected, value)
    return out


def ranges(v: Validator, key: str, value: Any) -> tuple[Range | None, ...] | None:
    if value is None:
        return None
    expected = "a list with one [min, max] (rad / m) or null per joint"
    if not isinstance(value, list) or not value:
        raise v.fail(key, expected, value)
    out: list[Range | None] = []
    for i, item in enumerate(value):
        if item is None:
            out.append(None)
            continue
        pair = v.numbers(f"{key}[{i}]", item, "[min, max] (rad / m) with min < max, or null", 2)
        if not pair[0] < pair[1]:
            raise v.fail(f"{key}[{i}]", "[min, max] (rad / m) with min < max, or null", item)
        out.append((pair[0], pair[1]))
    return tuple(out)


def optional_numbers(unit: str) -> Any:
    def check(v: Validator, key: str, value: Any) -> tuple[float, ...] | None:
        if value is None:
            return None
        return v.numbers(key, value, f"a list of numbers > 0 ({unit}), one per joint, or null", positive=True)

    return check


def obstacles(keys: tuple[str, ...], example: str) -> Any:
    def check(v: Validator, key: str, value: Any) -> tuple[dict[str, Any], ...]:
        expected = f"a list of mappings {example}"
        if value is None:
            return ()
        if not isinstance(value, list):
            raise v.fail(key, expected, value)
        out, names = [], set()
        for i, item in enumerate(value):
            where = f"{key}[{i}]"
            if not isinstance(item, dict) or set(item) != set(keys):
                raise v.fail(where, f"a mapping with exactly the keys {', '.join(keys)}, e.g. {example}", item)
            name = v.text(f"{where}.name", item["name"])
            if name is None or name in names:
                raise v.fail(f"{where}.name", "a name, unique among the boxes and cylinders", item["name"])
            names.add(name)
            entry: dict[str, Any] = {"name": name}
            for k in keys[1:]:
                if k == "radius":
                    entry[k] = v.number(f"{where}.radius", item[k], "a number > 0 (m)", 0.0, strict=True)
                else:
                    entry[k] = list(v.numbers(f"{where}.{k}", item[k], "[x, y, z] in the base frame (m)", 3))
            if "min" in entry and not all(lo < hi for lo, hi in zip(entry["min"], entry["max"], strict=True)):
                raise v.fail(where, "min < max on every axis", item)
            out.append(entry)
        return tuple(out)

    return check


def cable(v: Validator, key: str, value: Any) -> tuple[dict[str, Any], ...]:
    """A camera's cable as capsules fixed to the arm's links: ``{frame, a, b, radius}`` each, ``frame`` the DH frame
    (0 the base, n the flange) the capsule ``a``-``b`` (m, in that frame) rides with."""
    example = "{frame: 6, a: [0, -0.06, 0.04], b: [0, -0.09, -0.05], radius: 0.006}"
    if value is None:
        return ()
    if not isinstance(value, list):
        raise v.fail(key, f"a list of mappings {example}", value)
    out = []
    for i, item in enumerate(value):
        where = f"{key}[{i}]"
        if not isinstance(item, dict) or set(item) != {"frame", "a", "b", "radius"}:
            raise v.fail(where, f"a mapping with exactly the keys frame, a, b, radius, e.g. {example}", item)
        out.append({"frame": v.integer(f"{where}.frame", item["frame"], 0),
                    "a": list(v.numbers(f"{where}.a", item["a"], "[x, y, z] in that DH frame (m)", 3)),
                    "b": list(v.numbers(f"{where}.b", item["b"], "[x, y, z] in that DH frame (m)", 3)),
                    "radius": v.number(f"{where}.radius", item["radius"], "a number > 0 (m)", 0.0, strict=True)})
    return tuple(out)


def optional_point(v: Validator, key: str, value: Any) -> tuple[float, ...] | None:
    if value is None:
        return None
    return v.numbers(key, value, "[x, y, z] in the flange frame (m), or null for the TP guess", 3)


def optional_offset(v: Validator, key: str, value: Any) -> float | None:
    if value is None:
        return None
    return v.number(key, value, "a number (m along the surface normal), or null for the robot model's", -math.inf,
                    strict=True)


def camera_pose(v: Validator, key: str, value: Any) -> tuple[tuple[float, ...], ...] | None:
    """A 4x4 pose (base frame ← camera), or the path of a result YAML whose ``base`` is camera ← base."""
    if value is None:
        return None
    expected = ("a 4x4 pose of the camera in the robot's base frame, or the path of a result YAML of a session "
                "with this camera")
    if isinstance(value, str):
        import numpy as np

        where = Path(v.source).parent if isinstance(v.source, Path) else Path.cwd()
        path = where / value
        if not path.is_file():
            raise v.fail(key, expected, value)
        doc = read_yaml(path)
        base = doc.get("base") if isinstance(doc, dict) else None
        if not (isinstance(base, list) and len(base) == 4):
            raise v.fail(key, f"{expected} (with a 4x4 'base')", value)
        matrix = np.array([v.numbers(f"{key}.base[{i}]", row, "4 numbers", 4) for i, row in enumerate(base)])
        inverse = np.eye(4)
        inverse[:3, :3] = matrix[:3, :3].T
        inverse[:3, 3] = -matrix[:3, :3].T @ matrix[:3, 3]
        value = inverse.tolist()
    if not isinstance(value, list) or len(value) != 4:
        raise v.fail(key, expected, value)
    rows = tuple(v.numbers(f"{key}[{i}]", row, "a row of 4 numbers", 4) for i, row in enumerate(value))
    rotation = [row[:3] for row in rows[:3]]
    ortho = all(abs(sum(rotation[k][i] * rotation[k][j] for k in range(3)) - (i == j)) < 1e-6
                for i in range(3) for j in range(3))
    if rows[3] != (0.0, 0.0, 0.0, 1.0) or not ortho:
        raise v.fail(key, f"{expected}: a rotation and a translation, last row 0, 0, 0, 1", value)
    return rows


CHECKS: dict[str, Any] = {
    "robot_model": lambda v, key, x: v.text(key, x),
    "host": lambda v, key, x: v.text(key, x),
    "hosts": hosts,
    "speed_fraction": positive("a fraction of the speed"),
    "acceleration_fraction": positive("a fraction of the acceleration"),
    "speed": optional_numbers("rad/s / m/s"),
    "acceleration": optional_numbers("rad/s² / m/s²"),
    "tracker": lambda v, key, x: v.text(key, x),
    "tracker_noise": positive("m per axis"),
    "tracker_settings": settings,
    "measure_time": lambda v, key, x: v.number(key, x, "a number >= 0 (s per reading)", 0.0, strict=False),
    "tp_guess": lambda v, key, x: v.numbers(key, x, "[x, y, z] in the flange frame (m)", 3),
    "samples_per_step": lambda v, key, x: v.integer(key, x, 1, "samples"),
    "settle_time": lambda v, key, x: v.number(key, x, "a number >= 0 (s)", 0.0, strict=False),
    "steps_per_sweep": lambda v, key, x: v.integer(key, x, 3, "steps"),
    "sweep_joints": joints,
    "sweep_ranges": ranges,
    "free_poses": lambda v, key, x: v.integer(key, x, 0, "free_poses"),
    "check_poses": lambda v, key, x: v.integer(key, x, 0, "check_poses"),
    "home_check_every": lambda v, key, x: v.integer(key, x, 0),
    "min_axis_distance": lambda v, key, x: v.number(key, x, "a number >= 0 (m)", 0.0, strict=False),
    "stream_speed": lambda v, key, x: None if x is None else v.number(key, x, "a speed > 0 (rad/s or m/s), or null",
                                                                        0.0, strict=True),
    "stream_rate": lambda v, key, x: v.number(key, x, "a rate > 0 (Hz)", 0.0, strict=True),
    "cell_margin": lambda v, key, x: v.number(key, x, "a number >= 0 (m)", 0.0, strict=False),
    "mounting_offset": optional_offset,
    "mounting_clearance": lambda v, key, x: v.number(key, x, "a number >= 0 (m)", 0.0, strict=False),
    "tool_a": lambda v, key, x: v.numbers(key, x, "[x, y, z] in the flange frame (m)", 3),
    "tool_b": optional_point,
    "tool_radius": positive("m"),
    "boxes": obstacles(("name", "min", "max"), "{name: fixture, min: [0.4, -0.2, 0], max: [0.6, 0.2, 0.3]}"),
    "cylinders": obstacles(("name", "a", "b", "radius"),
                           "{name: tracker stand, a: [1.5, 0, 0], b: [1.5, 0, 1.2], radius: 0.15}"),
    "cable": cable,
    "camera_pose": camera_pose,
    "camera_half_fov": lambda v, key, x: v.number(key, x, "an angle > 0 (rad)", 0.0, strict=True),
    "camera_max_tilt": lambda v, key, x: v.number(key, x, "an angle > 0 (rad)", 0.0, strict=True),
    "target_normal": lambda v, key, x: v.numbers(key, x, "[x, y, z] in the flange frame, not zero", 3),
    "connect_timeout": positive("s"),
    "move_timeout": positive("s"),
    "settle_timeout": positive("s"),
    "measure_timeout": positive("s"),
    "retries": lambda v, key, x: v.integer(key, x, 0),
    "verify_centre": lambda v, key, x: None if x is None else v.numbers(key, x, "[x, y, z] in the base frame (m), or "
                                                                         "null for the TP at home", 3),
    "verify_edge": lambda v, key, x: None if x is None else v.number(key, x, "a number > 0 (m), or null for a size "
                                                                       "from the robot's reach", 0.0, strict=True),
    "verify_cycles": lambda v, key, x: v.integer(key, x, 2, "cycles"),
}
