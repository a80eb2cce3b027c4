"""Nominal robot models: the YAML files in ``config/robots/`` and their loader.

A model file (schema 1) holds exactly the keys in :data:`KEYS`; ``dh`` is a standard DH table, base to tip,
for the forward model of kinematics/dh.py (``theta``, ``alpha`` in radians; ``d``, ``a`` in metres). Per-joint values
are radians for revolute joints and metres for prismatic ones: ``limits`` and ``home`` in rad / m,
``max_speed`` and ``default_speed`` in rad/s / m/s, ``default_acceleration`` in rad/s² / m/s².

>>> robot = load_robot("UR5e")              # a bundled model, case-insensitive
>>> robot = load_robot("cell/my_ur.yaml")   # or any file with the same schema
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from config.files import ConfigError as ConfigError  # re-exported: the error of every config file
from config.files import check_schema, config_file, got, read_yaml
from config.geometry import RobotGeometry, geometry_from_dict
from kinematics.dh import Array, DHModel, check_joint_types
from kinematics.joint_errors import Coupling, LinkMasses

SCHEMA_VERSION = 1
KEYS = ("schema", "name", "vendor", "description", "source", "joints", "dh", "limits", "home", "max_speed",
        "default_speed", "default_acceleration", "collision", "coupling", "dynamics")
OPTIONAL_KEYS = ("collision", "coupling", "dynamics")  # every bundled model has collision geometry
TEXT_KEYS = ("name", "vendor", "description", "source")
DH_KEYS = ("theta", "d", "a", "alpha")
ROBOTS_DIR = Path(__file__).resolve().parent / "robots"


@dataclass(frozen=True, eq=False)
class RobotModel:
    """A nominal robot: DH table, joint limits and motion defaults, as read from ``path``.

    ``nominal`` has ``base`` = identity and ``tool`` = zeros (the TP at the origin of the last DH frame).
    Arrays (read-only): ``limits`` (n, 2) and ``home`` (n,) in rad / m; ``max_speed``, ``default_speed``
    (n,) in rad/s / m/s; ``default_acceleration`` (n,) in rad/s² / m/s². ``geometry``: the collision
    capsules (:mod:`config.geometry`), None when the file has none (then no plan can be checked for collisions).
    ``coupling``: how the controller's readings give the DH joint values (None: they are the DH values);
    ``links``: link masses and centres of mass (None when the file has no ``dynamics``), for compliance.
    Limits, home and speeds are in DH joint values. ``document``: the plain data of a model that is not bundled
    (None for a bundled one, known by its name), which sessions and results record (:func:`model_document`).
    """

    name: str
    vendor: str
    description: str
    source: str
    joint_types: str
    nominal: DHModel
    limits: Array
    home: Array
    max_speed: Array
    default_speed: Array
    default_acceleration: Array
    path: Path
    geometry: RobotGeometry | None = None
    coupling: Coupling | None = None
    links: LinkMasses | None = None
    document: dict[str, Any] | None = None

    @property
    def n_joints(self) -> int:
        return len(self.joint_types)


def robot_names() -> list[str]:
    """Names of the bundled models (the file stems in ``config/robots/``), sorted."""
    return sorted(p.stem for p in ROBOTS_DIR.glob("*.yaml"))


def load_robot(name_or_path: str | Path) -> RobotModel:
    """Load and validate a bundled model by name (case-insensitive) or a YAML file by path.

    A ``Path``, or a string containing a path separator or ending in ``.yaml``/``.yml``, is read as a file;
    anything else is a bundled name. Raises :class:`ConfigError` on any problem.
    """
    path = config_file(name_or_path, ROBOTS_DIR, "robot", robot_names)
    return _model_from_dict(path, read_yaml(path))


def model_document(robot: RobotModel) -> dict[str, Any] | None:
    """What a session or a result records of ``robot`` so that it reads where the model's file is not: the plain
    data of a model file of the operator's (:func:`robot_from_document` reads it back); None for a bundled model,
    which its name finds."""
    return robot.document


def robot_from_document(data: Any, source: str) -> RobotModel:
    """The model a session or a result records (:func:`model_document`); ``source`` names it in a ConfigError."""
    return _model_from_dict(Path(source), data, recorded=True)


def _number(path: Path, key: str, value: Any, expected: str = "a finite number") -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(path, key, expected, got(value))
    return float(value)


def _per_joint(path: Path, key: str, value: Any, n: int, what: str) -> list[Any]:
    if not isinstance(value, list) or len(value) != n:
        size = f"{len(value)} entries" if isinstance(value, list) else got(value)
        raise ConfigError(path, key, f"a list of {n} {what} (one per joint)", size)
    return value


def _numbers(path: Path, key: str, value: Any, n: int, unit: str, positive: bool = False) -> Array:
    items = _per_joint(path, key, value, n, f"numbers ({unit})")
    out = [_number(path, f"{key}[{i}]", v, f"a finite number ({unit})") for i, v in enumerate(items)]
    for i, v in enumerate(out):
        if positive and v <= 0:
            raise ConfigError(path, f"{key}[{i}]", f"a number > 0 ({unit})", got(items[i]))
    return np.array(out)


def _model_from_dict(path: Path, data: Any, recorded: bool = False) -> RobotModel:
    if not isinstance(data, dict):
        raise ConfigError(path, None, f"a mapping with keys {', '.join(KEYS)}", got(data))
    for key in data:
        if key not in KEYS:
            raise ConfigError(path, str(key), f"only the keys {', '.join(KEYS)}", "an unknown key")
    for key in KEYS:
        if key not in data and key not in OPTIONAL_KEYS:
            raise ConfigError(path, key, "the key to be present", "nothing (missing key)")

    check_schema(path, data["schema"], SCHEMA_VERSION)
    for key in TEXT_KEYS:
        if not isinstance(data[key], str) or not data[key].strip():
            raise ConfigError(path, key, "a non-empty string", got(data[key]))
    try:
        types = check_joint_types(data["joints"]) if isinstance(data["joints"], str) else ""
    except ValueError:
        types = ""
    if not types:
        expected = "a string of R and P, base to tip, e.g. RRRRRR"
        raise ConfigError(path, "joints", expected, got(data["joints"]))
    n = len(types)

    rows = _per_joint(path, "dh", data["dh"], n, "mappings {theta, d, a, alpha}")
    table = np.empty((n, 4))
    for i, row in enumerate(rows):
        if not isinstance(row, dict) or set(row) != set(DH_KEYS):
            found = sorted(map(str, row)) if isinstance(row, dict) else row
            expected = "a mapping with exactly the keys theta, d, a, alpha"
            raise ConfigError(path, f"dh[{i}]", expected, got(found))
        for j, name in enumerate(DH_KEYS):
            unit = "rad" if name in ("theta", "alpha") else "m"
            table[i, j] = _number(path, f"dh[{i}].{name}", row[name], f"a finite number ({unit})")

    pairs = _per_joint(path, "limits", data["limits"], n, "[min, max] pairs")
    limits = np.empty((n, 2))
    for i, pair in enumerate(pairs):
        key = f"limits[{i}]"
        if not isinstance(pair, list) or len(pair) != 2:
            raise ConfigError(path, key, "[min, max] with min < max", got(pair))
        limits[i] = [_number(path, key, v, "[min, max] of finite numbers") for v in pair]
        if not limits[i, 0] < limits[i, 1]:
            raise ConfigError(path, key, "[min, max] with min < max", got(pair))

    home = _numbers(path, "home", data["home"], n, "rad / m")
    for i, (q, (lo, hi)) in enumerate(zip(home, limits, strict=True)):
        if not lo <= q <= hi:
            expected = f"a value within limits[{i}] = [{float(lo)!r}, {float(hi)!r}]"
            raise ConfigError(path, f"home[{i}]", expected, got(float(q)))
    max_speed = _numbers(path, "max_speed", data["max_speed"], n, "rad/s / m/s", positive=True)
    default_speed = _numbers(path, "default_speed", data["default_speed"], n, "rad/s / m/s", positive=True)
    for i, (v, vmax) in enumerate(zip(default_speed, max_speed, strict=True)):
        if v > vmax:
            expected = f"a speed <= max_speed[{i}] = {float(vmax)!r}"
            raise ConfigError(path, f"default_speed[{i}]", expected, got(float(v)))
    default_acc = _numbers(path, "default_acceleration", data["default_acceleration"], n, "rad/s² / m/s²",
                           positive=True)

    nominal = DHModel(types, table[:, 0], table[:, 1], table[:, 2], table[:, 3])
    for array in (limits, home, max_speed, default_speed, default_acc):
        array.setflags(write=False)
    geometry = geometry_from_dict(path, data["collision"], n) if "collision" in data else None
    name, vendor, description, source = (data[key].strip() for key in TEXT_KEYS)
    coupling = _coupling(path, data["coupling"], n) if "coupling" in data else None
    links = _dynamics(path, data["dynamics"], n) if "dynamics" in data else None
    bundled = not recorded and path.resolve().parent == ROBOTS_DIR
    return RobotModel(name, vendor, description, source, types, nominal, limits, home, max_speed,
                      default_speed, default_acc, path, geometry, coupling, links, None if bundled else data)


def _matrix(path: Path, key: str, value: Any, n: int, unit: str) -> Array:
    rows = _per_joint(path, key, value, n, f"rows of {n} numbers")
    return np.array([_numbers(path, f"{key}[{i}]", row, n, unit) for i, row in enumerate(rows)])


def _coupling(path: Path, data: Any, n: int) -> Coupling:
    """``coupling: {matrix: [[...] x n], offset: [...], source: text}``: q_dh = matrix · readings + offset."""
    if not isinstance(data, dict) or "matrix" not in data or set(data) - {"matrix", "offset", "source"}:
        raise ConfigError(path, "coupling", "a mapping {matrix: n x n rows, offset: n numbers (optional), "
                          "source: text (optional)}", got(data))
    matrix = _matrix(path, "coupling.matrix", data["matrix"], n, "coefficient")
    offset = _numbers(path, "coupling.offset", data["offset"], n, "rad / m") if "offset" in data else np.zeros(n)
    try:
        return Coupling(matrix, offset)
    except ValueError as exc:
        raise ConfigError(path, "coupling.matrix", "an invertible matrix", str(exc)) from None


def _dynamics(path: Path, data: Any, n: int) -> LinkMasses:
    """``dynamics: {source: text, masses: n kg, centres_of_mass: n x [x, y, z] m in DH frame i}``."""
    if not isinstance(data, dict) or set(data) != {"source", "masses", "centres_of_mass"}:
        raise ConfigError(path, "dynamics", "a mapping with exactly source, masses (kg) and centres_of_mass "
                          "(m, link i in DH frame i)", got(data))
    if not isinstance(data["source"], str) or not data["source"].strip():
        raise ConfigError(path, "dynamics.source", "a non-empty string naming where the values come from",
                          got(data["source"]))
    masses = _numbers(path, "dynamics.masses", data["masses"], n, "kg", positive=True)
    rows = _per_joint(path, "dynamics.centres_of_mass", data["centres_of_mass"], n, "[x, y, z] points (m)")
    centres = np.empty((n, 3))
    for i, row in enumerate(rows):
        key = f"dynamics.centres_of_mass[{i}]"
        if not isinstance(row, list) or len(row) != 3:
            raise ConfigError(path, key, "[x, y, z] in metres", got(row))
        centres[i] = [_number(path, key, v) for v in row]
    return LinkMasses(masses, centres)
