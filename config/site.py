"""The site file (``acquire --config site.yaml``): hosts, tracker, plan settings, timeouts (schema 1).

Every key is optional except ``schema``; a missing key takes the default of :class:`SiteConfig`, an
unknown key is rejected. Sections and keys (units: m, rad, s; per-joint values base to tip)::

    schema: 1
    robot:    {model, host, hosts, speed_fraction, acceleration_fraction, speed, acceleration}
    tracker:  {spec, noise, settings, measure_time}
    plan:     {tp_guess, samples_per_step, settle_time, steps_per_sweep, joints, sweep_ranges,
               free_poses, check_poses, home_check_every, min_axis_distance, stream_speed, stream_rate}
    cell:     {margin, mounting_offset, mounting_clearance, tool_a, tool_b, tool_radius, boxes, cylinders, cable,
               camera_pose, camera_half_fov, camera_max_tilt, target_normal}
    timeouts: {connect, move, settle, measure}
    verify:   {cube_centre, cube_edge, cycles}
    retries:  3

The loaded configuration is a flat frozen :class:`SiteConfig` (``site.tracker_noise``,
``site.move_timeout``, ...); :data:`FIELDS` maps each field to its place in the file.
``config/site_example.yaml`` documents every key; config/site_checks.py checks each key's value.

>>> site = load_site("site.yaml").with_overrides(samples_per_step=args.samples)  # None: not given
>>> session_header["config"] = site.as_dict()                                    # the resolved values
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, NamedTuple

from config.files import ConfigError, check_schema, got, read_yaml
from config.site_checks import CHECKS, Range, Validator

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
    "cable": ("cell", "cable"),
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
    ``{name, a, b, radius}`` (axis ends); ``cable`` a camera's cable as capsules ``{frame, a, b, radius}`` fixed
    to DH frame ``frame`` (0 the base, n the flange; ends in that frame). A camera cell: ``camera_pose`` (base
    frame ← camera frame, 4x4; None: no camera view check), ``camera_half_fov`` and ``camera_max_tilt`` (rad)
    and ``target_normal`` (flange frame): see :mod:`acquire.planning.camera_view`. Timeouts in s; ``retries`` per
    failed measurement.
    Verification (``acquire verify``, :mod:`identify.applications.iso9283`): the test cube's ``verify_centre`` (base
    frame, m; None: the TP at home) and ``verify_edge`` (m; None: from the robot's reach), ``verify_cycles`` per pose.
    ``source`` names where it came from.
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
    cable: tuple[dict[str, Any], ...] = ()
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
    verify_cycles: int = 30  # ISO 9283 (identify.applications.iso9283.ISO_CYCLES)
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
    v = Validator(source)
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
        values[name] = CHECKS[name](v, dotted, mapping[key])
    site = replace(defaults, **values, source=str(source))
    _check_consistency(v, site)
    return site


assert set(CHECKS) == set(FIELDS) == {f.name for f in fields(SiteConfig)} - {"source"}


def _check_consistency(v: Validator, site: SiteConfig) -> None:
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
