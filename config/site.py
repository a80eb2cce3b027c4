"""The site file (``acquire --config site.yaml``): hosts, tracker, plan settings, timeouts (schema 1).

Every key is optional except ``schema``; a missing key takes the default of :class:`SiteConfig`, an
unknown key is rejected. Sections and keys (units: m, rad, s; per-joint values base to tip)::

    schema: 1
    robot:    {model, host, hosts, speed_fraction, acceleration_fraction, speed, acceleration}
    tracker:  {spec, noise, settings, measure_time}
    plan:     {tp_guess, samples_per_step, settle_time, steps_per_sweep, joints, sweep_ranges,
               free_poses, check_poses, home_check_every, min_axis_distance, stream_speed, stream_rate}
    cell:     {margin, mounting_offset, mounting_clearance, tool_a, tool_b, tool_radius, boxes, cylinders,
               camera_pose, camera_half_fov, camera_max_tilt, target_normal}
    timeouts: {connect, move, settle, measure}
    verify:   {cube_centre, cube_edge, cycles}
    retries:  3

The loaded configuration is a flat frozen :class:`SiteConfig` (``site.tracker_noise``,
``site.move_timeout``, ...); :data:`FIELDS` maps each field to its place in the file.
``config/site_example.yaml`` documents every key.

>>> site = load_site("site.yaml").with_overrides(samples_per_step=args.samples)  # None: not given
>>> session_header["config"] = site.as_dict()                                    # the resolved values
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, NamedTuple

from config.files import ConfigError, check_schema, got, read_yaml

SCHEMA_VERSION = 1

# field name -> (section or None for a top-level key, key in the file)
FIELDS: dict[str, tuple[str | None, str]] = {
    "robot_model": ("robot", "model"),
    "host": ("robot", "host"),
    "hosts": ("robot", "hosts"),
    "speed_fraction": ("robot", "speed_fraction"),
    "acceleration_fraction": ("robot", "acceleration_fraction"),
    "speed": ("robot", "speed"),
    "acceleration": ("robot", "acceleration"),
    "tracker": ("tracker", "spec"),
    "tracker_noise": ("tracker", "noise"),
    "tracker_settings": ("tracker", "settings"),
    "measure_time": ("tracker", "measure_time"),
    "tp_guess": ("plan", "tp_guess"),
    "samples_per_step": ("plan", "samples_per_step"),
    "settle_time": ("plan", "settle_time"),
    "steps_per_sweep": ("plan", "steps_per_sweep"),
    "sweep_joints": ("plan", "joints"),
    "sweep_ranges": ("plan", "sweep_ranges"),
    "free_poses": ("plan", "free_poses"),
    "check_poses": ("plan", "check_poses"),
    "home_check_every": ("plan", "home_check_every"),
    "min_axis_distance": ("plan", "min_axis_distance"),
    "stream_speed": ("plan", "stream_speed"),
    "stream_rate": ("plan", "stream_rate"),
    "cell_margin": ("cell", "margin"),
    "mounting_offset": ("cell", "mounting_offset"),
    "mounting_clearance": ("cell", "mounting_clearance"),
    "tool_a": ("cell", "tool_a"),
    "tool_b": ("cell", "tool_b"),
    "tool_radius": ("cell", "tool_radius"),
    "boxes": ("cell", "boxes"),
    "cylinders": ("cell", "cylinders"),
    "camera_pose": ("cell", "camera_pose"),
    "camera_half_fov": ("cell", "camera_half_fov"),
    "camera_max_tilt": ("cell", "camera_max_tilt"),
    "target_normal": ("cell", "target_normal"),
    "connect_timeout": ("timeouts", "connect"),
    "move_timeout": ("timeouts", "move"),
    "settle_timeout": ("timeouts", "settle"),
    "measure_timeout": ("timeouts", "measure"),
    "verify_centre": ("verify", "cube_centre"),
    "verify_edge": ("verify", "cube_edge"),
    "verify_cycles": ("verify", "cycles"),
    "retries": (None, "retries"),
}
SECTIONS = ("robot", "tracker", "plan", "cell", "timeouts", "verify")
TOP_KEYS = ("schema", *SECTIONS, "retries")

Range = tuple[float, float]


class Timeouts(NamedTuple):
    """Every wait's limit, s."""

    connect: float
    move: float
    settle: float
    measure: float


@dataclass(frozen=True)
class SiteConfig:
    """A resolved site configuration; every field has a default (``SiteConfig.default()``).

    Robot: ``robot_model`` the default ``--robot`` spec; ``host`` for any model and ``hosts`` per model
    name (lower case); resolved joint speeds are ``speed_fraction`` × (``speed`` per joint, rad/s or
    m/s, or the model's ``default_speed``), accelerations likewise. Tracker: ``tracker`` device spec,
    ``tracker_noise`` m per axis per reading, ``tracker_settings`` passed to its backend, ``measure_time``
    s per reading (for the duration estimate).
    Plan: ``tp_guess`` the TP in the flange (last DH) frame, m; ``sweep_joints`` 1-based joints to sweep
    (None: all); ``sweep_ranges`` one ``(min, max)`` or None per joint (None: as wide as the limits
    allow); ``free_poses`` fitted free poses and ``check_poses`` held-out ones; a home check every
    ``home_check_every`` steps (0: none); ``min_axis_distance`` m, the least TP distance from a revolute
    axis. Cell (base frame of the robot, m; see :mod:`kinematics.collision`): ``cell_margin`` the least
    distance between two bodies (links, tool, boxes, cylinders); the mounting surface is the robot model's
    (z = 0 for an arm on a table), moved to ``mounting_offset`` when given, kept ``mounting_clearance``
    away; the tool is a capsule ``tool_a``-``tool_b`` (flange frame; ``tool_b`` None: the TP guess) of
    ``tool_radius``; ``boxes`` ``{name, min, max}`` (axis-aligned corners) and ``cylinders``
    ``{name, a, b, radius}`` (axis ends). A camera cell: ``camera_pose`` (base frame ← camera frame, 4x4;
    None: no camera view check), ``camera_half_fov`` and ``camera_max_tilt`` (rad) and ``target_normal``
    (flange frame): see :mod:`acquire.camera_view`. Timeouts in s; ``retries`` per failed measurement. Verification
    (``acquire verify``, :mod:`identify.iso9283`): the test cube's ``verify_centre`` (base frame, m; None: the TP at
    home) and ``verify_edge`` (m; None: from the robot's reach), ``verify_cycles`` per pose. ``source`` names where
    it came from.
    """

    robot_model: str | None = None
    host: str | None = None
    hosts: dict[str, str] = field(default_factory=dict)
    speed_fraction: float = 1.0
    acceleration_fraction: float = 1.0
    speed: tuple[float, ...] | None = None
    acceleration: tuple[float, ...] | None = None
    tracker: str | None = None
    tracker_noise: float = 5e-5
    tracker_settings: dict[str, Any] = field(default_factory=dict)
    measure_time: float = 0.05
    tp_guess: tuple[float, float, float] = (0.05, 0.03, 0.08)
    samples_per_step: int = 5
    settle_time: float = 0.5
    steps_per_sweep: int = 36
    sweep_joints: tuple[int, ...] | None = None
    sweep_ranges: tuple[Range | None, ...] | None = None
    free_poses: int = 24
    check_poses: int = 8
    home_check_every: int = 36
    min_axis_distance: float = 0.02
    stream_speed: float | None = None  # continuous sweeps: a cap on the swept joint's speed, rad/s or m/s
    stream_rate: float = 250.0  # continuous sweeps: the tracker stream rate asked for, Hz
    cell_margin: float = 0.02
    mounting_offset: float | None = None
    mounting_clearance: float = 0.05
    tool_a: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tool_b: tuple[float, float, float] | None = None
    tool_radius: float = 0.03
    boxes: tuple[dict[str, Any], ...] = ()
    cylinders: tuple[dict[str, Any], ...] = ()
    camera_pose: tuple[tuple[float, ...], ...] | None = None
    camera_half_fov: float = 0.5
    camera_max_tilt: float = 1.05
    target_normal: tuple[float, float, float] = (0.0, 0.0, 1.0)
    connect_timeout: float = 10.0
    move_timeout: float = 120.0
    settle_timeout: float = 10.0
    measure_timeout: float = 10.0
    retries: int = 3
    verify_centre: tuple[float, float, float] | None = None
    verify_edge: float | None = None
    verify_cycles: int = 30  # ISO 9283 (identify.iso9283.ISO_CYCLES)
    source: str = field(default="<defaults>", compare=False)

    @classmethod
    def default(cls) -> SiteConfig:
        return cls()

    @classmethod
    def from_dict(cls, data: Any, source: str | Path = "<dict>") -> SiteConfig:
        """The configuration saved by :meth:`as_dict` (e.g. in a session), validated: :func:`site_from_dict`."""
        return site_from_dict(data, source)

    @property
    def timeouts(self) -> Timeouts:
        return Timeouts(self.connect_timeout, self.move_timeout, self.settle_timeout, self.measure_timeout)

    def host_for(self, model: str) -> str | None:
        """The host of robot ``model`` (case-insensitive): ``hosts[model]``, else ``host``, else None."""
        return self.hosts.get(model.strip().lower(), self.host)

    def as_dict(self) -> dict[str, Any]:
        """The configuration as a site-file mapping (plain lists and dicts; ``site_from_dict`` reads it
        back to an equal ``SiteConfig``)."""
        out: dict[str, Any] = {"schema": SCHEMA_VERSION, **{s: {} for s in SECTIONS}}
        for name, (section, key) in FIELDS.items():
            value = _plain(getattr(self, name))
            if section is None:
                out[key] = value
            else:
                out[section][key] = value
        return out

    def with_overrides(self, **overrides: Any) -> SiteConfig:
        """A copy with the given fields replaced (command-line flags); a value of None means not given.

        Values are validated like the file's, the error naming ``command line`` and the key.
        """
        unknown = sorted(set(overrides) - set(FIELDS))
        if unknown:
            raise ConfigError("command line", unknown[0], f"one of the settings {', '.join(FIELDS)}",
                              "an unknown setting")
        given = {k: v for k, v in overrides.items() if v is not None}
        if not given:
            return self
        data = self.as_dict()
        for name, value in given.items():
            section, key = FIELDS[name]
            (data if section is None else data[section])[key] = _plain(value)
        checked = site_from_dict(data, "command line")
        return replace(checked, source=f"{self.source} + command line")


def load_site(path: str | Path) -> SiteConfig:
    """Read and validate a site file; raises :class:`ConfigError` (one line: file, key, expected value)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(path, None, "an existing site YAML file", "no such file")
    return site_from_dict(read_yaml(path), path)


def site_from_dict(data: Any, source: str | Path = "<dict>") -> SiteConfig:
    """Validate a site mapping (as read from YAML or written by :meth:`SiteConfig.as_dict`)."""
    v = _Validator(source)
    if not isinstance(data, dict):
        raise ConfigError(source, None, f"a mapping with the keys {', '.join(TOP_KEYS)}", got(data))
    v.known(None, data, TOP_KEYS)
    if "schema" not in data:
        raise ConfigError(source, "schema", f"the schema version ({SCHEMA_VERSION})", "nothing (missing key)")
    check_schema(source, data["schema"], SCHEMA_VERSION)
    sections: dict[str, dict[str, Any]] = {}
    for name in SECTIONS:
        value = data.get(name)
        if value is None:
            value = {}
        if not isinstance(value, dict):
            raise ConfigError(source, name, "a mapping (or nothing)", got(value))
        allowed = [key for section, key in FIELDS.values() if section == name]
        v.known(name, value, allowed)
        sections[name] = value

    values: dict[str, Any] = {}
    defaults = SiteConfig()
    for name, (section, key) in FIELDS.items():
        mapping = data if section is None else sections[section]
        if key not in mapping:
            continue
        dotted = key if section is None else f"{section}.{key}"
        values[name] = _CHECKS[name](v, dotted, mapping[key])
    site = replace(defaults, **values, source=str(source))
    _check_consistency(v, site)
    return site


class _Validator:
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

    def integer(self, key: str, value: Any, low: int) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise self.fail(key, f"an integer >= {low}", value)
        return value

    def numbers(self, key: str, value: Any, expected: str, count: int | None = None,
                positive: bool = False) -> tuple[float, ...]:
        if not isinstance(value, list) or not value or (count is not None and len(value) != count):
            raise self.fail(key, expected, value)
        low = 0.0 if positive else -math.inf
        return tuple(self.number(f"{key}[{i}]", x, expected, low, strict=positive) for i, x in enumerate(value))


def _positive(unit: str) -> Any:
    return lambda v, key, x: v.number(key, x, f"a number > 0 ({unit})", 0.0, strict=True)


def _hosts(v: _Validator, key: str, value: Any) -> dict[str, str]:
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


def _settings(v: _Validator, key: str, value: Any) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise v.fail(key, "a mapping of setting names to numbers, strings or booleans", value)
    for name, item in value.items():
        if not isinstance(name, str) or not (item is None or isinstance(item, str | int | float | bool)):
            raise v.fail(f"{key}.{name}", "a number, string or boolean", item)
    return dict(value)


def _joints(v: _Validator, key: str, value: Any) -> tuple[int, ...] | None:
    if value is None:
        return None
    expected = "a list of distinct 1-based joint numbers (or null for all joints)"
    if not isinstance(value, list) or not value:
        raise v.fail(key, expected, value)
    out = tuple(v.integer(f"{key}[{i}]", j, 1) for i, j in enumerate(value))
    if len(set(out)) != len(out):
        raise v.fail(key, expected, value)
    return out


def _ranges(v: _Validator, key: str, value: Any) -> tuple[Range | None, ...] | None:
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


def _optional_numbers(unit: str) -> Any:
    def check(v: _Validator, key: str, value: Any) -> tuple[float, ...] | None:
        if value is None:
            return None
        return v.numbers(key, value, f"a list of numbers > 0 ({unit}), one per joint, or null", positive=True)

    return check


def _obstacles(keys: tuple[str, ...], example: str) -> Any:
    def check(v: _Validator, key: str, value: Any) -> tuple[dict[str, Any], ...]:
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


def _optional_point(v: _Validator, key: str, value: Any) -> tuple[float, ...] | None:
    if value is None:
        return None
    return v.numbers(key, value, "[x, y, z] in the flange frame (m), or null for the TP guess", 3)


def _optional_offset(v: _Validator, key: str, value: Any) -> float | None:
    if value is None:
        return None
    return v.number(key, value, "a number (m along the surface normal), or null for the robot model's", -math.inf,
                    strict=True)


def _camera_pose(v: _Validator, key: str, value: Any) -> tuple[tuple[float, ...], ...] | None:
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


_CHECKS: dict[str, Any] = {
    "robot_model": lambda v, key, x: v.text(key, x),
    "host": lambda v, key, x: v.text(key, x),
    "hosts": _hosts,
    "speed_fraction": _positive("a fraction of the speed"),
    "acceleration_fraction": _positive("a fraction of the acceleration"),
    "speed": _optional_numbers("rad/s / m/s"),
    "acceleration": _optional_numbers("rad/s² / m/s²"),
    "tracker": lambda v, key, x: v.text(key, x),
    "tracker_noise": _positive("m per axis"),
    "tracker_settings": _settings,
    "measure_time": lambda v, key, x: v.number(key, x, "a number >= 0 (s per reading)", 0.0, strict=False),
    "tp_guess": lambda v, key, x: v.numbers(key, x, "[x, y, z] in the flange frame (m)", 3),
    "samples_per_step": lambda v, key, x: v.integer(key, x, 1),
    "settle_time": lambda v, key, x: v.number(key, x, "a number >= 0 (s)", 0.0, strict=False),
    "steps_per_sweep": lambda v, key, x: v.integer(key, x, 3),
    "sweep_joints": _joints,
    "sweep_ranges": _ranges,
    "free_poses": lambda v, key, x: v.integer(key, x, 0),
    "check_poses": lambda v, key, x: v.integer(key, x, 0),
    "home_check_every": lambda v, key, x: v.integer(key, x, 0),
    "min_axis_distance": lambda v, key, x: v.number(key, x, "a number >= 0 (m)", 0.0, strict=False),
    "stream_speed": lambda v, key, x: None if x is None else v.number(key, x, "a speed > 0 (rad/s or m/s), or null",
                                                                        0.0, strict=True),
    "stream_rate": lambda v, key, x: v.number(key, x, "a rate > 0 (Hz)", 0.0, strict=True),
    "cell_margin": lambda v, key, x: v.number(key, x, "a number >= 0 (m)", 0.0, strict=False),
    "mounting_offset": _optional_offset,
    "mounting_clearance": lambda v, key, x: v.number(key, x, "a number >= 0 (m)", 0.0, strict=False),
    "tool_a": lambda v, key, x: v.numbers(key, x, "[x, y, z] in the flange frame (m)", 3),
    "tool_b": _optional_point,
    "tool_radius": _positive("m"),
    "boxes": _obstacles(("name", "min", "max"), "{name: fixture, min: [0.4, -0.2, 0], max: [0.6, 0.2, 0.3]}"),
    "cylinders": _obstacles(("name", "a", "b", "radius"),
                            "{name: tracker stand, a: [1.5, 0, 0], b: [1.5, 0, 1.2], radius: 0.15}"),
    "camera_pose": _camera_pose,
    "camera_half_fov": lambda v, key, x: v.number(key, x, "an angle > 0 (rad)", 0.0, strict=True),
    "camera_max_tilt": lambda v, key, x: v.number(key, x, "an angle > 0 (rad)", 0.0, strict=True),
    "target_normal": lambda v, key, x: v.numbers(key, x, "[x, y, z] in the flange frame, not zero", 3),
    "connect_timeout": _positive("s"),
    "move_timeout": _positive("s"),
    "settle_timeout": _positive("s"),
    "measure_timeout": _positive("s"),
    "retries": lambda v, key, x: v.integer(key, x, 0),
    "verify_centre": lambda v, key, x: None if x is None else v.numbers(key, x, "[x, y, z] in the base frame (m), or "
                                                                         "null for the TP at home", 3),
    "verify_edge": lambda v, key, x: None if x is None else v.number(key, x, "a number > 0 (m), or null for a size "
                                                                       "from the robot's reach", 0.0, strict=True),
    "verify_cycles": lambda v, key, x: v.integer(key, x, 2),
}
assert set(_CHECKS) == set(FIELDS) == {f.name for f in fields(SiteConfig)} - {"source"}


def _check_consistency(v: _Validator, site: SiteConfig) -> None:
    """Checks across keys that do not need the robot model (those are made when the plan is built)."""
    if site.settle_timeout < site.settle_time:
        raise v.fail("timeouts.settle", f"a timeout >= plan.settle_time = {site.settle_time!r} s",
                     site.settle_timeout)
    for name in ("speed", "acceleration"):
        values = getattr(site, name)
        if values is not None and site.sweep_ranges is not None and len(values) != len(site.sweep_ranges):
            raise v.fail(f"robot.{name}", f"one value per joint ({len(site.sweep_ranges)}, as in "
                         "plan.sweep_ranges)", list(values))


def _plain(value: Any) -> Any:
    """Tuples to lists and dicts copied, recursively: what YAML and JSON write."""
    if isinstance(value, tuple | list):
        return [_plain(x) for x in value]
    if isinstance(value, dict):
        return {k: _plain(x) for k, x in value.items()}
    return value
