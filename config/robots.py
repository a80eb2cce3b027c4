"""Nominal robot models: the YAML files in ``config/robots/`` and their loader.

A model file (schema 1) holds exactly the keys in :data:`KEYS`; ``dh`` is a standard DH table, base to tip,
for the forward model of DESIGN.md (``theta``, ``alpha`` in radians; ``d``, ``a`` in metres). Per-joint values
are radians for revolute joints and metres for prismatic ones: ``limits`` and ``home`` in rad / m,
``max_speed`` and ``default_speed`` in rad/s / m/s, ``default_acceleration`` in rad/s² / m/s².

>>> robot = load_robot("UR5e")              # a bundled model, case-insensitive
>>> robot = load_robot("cell/my_ur.yaml")   # or any file with the same schema
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from config.geometry import RobotGeometry, geometry_from_dict
from config.model_path import names_a_file
from kinematics.dh import Array, DHModel, check_joint_types
from kinematics.joint_errors import Coupling, LinkMasses

SCHEMA_VERSION = 1
KEYS = ("schema", "name", "vendor", "description", "source", "joints", "dh", "limits", "home", "max_speed",
        "default_speed", "default_acceleration", "collision", "coupling", "dynamics")
OPTIONAL_KEYS = ("collision", "coupling", "dynamics")  # every bundled model has collision geometry
TEXT_KEYS = ("name", "vendor", "description", "source")
DH_KEYS = ("theta", "d", "a", "alpha")
ROBOTS_DIR = Path(__file__).resolve().parent / "robots"


class ConfigError(ValueError):
    """A robot file or name that cannot be used; the message is one line: where, expected value, found value.

    ``path`` is the file (or the name asked for) and ``key`` the offending key, e.g. ``limits[2]``
    (``None`` when the problem is not tied to a key, such as a YAML syntax error); ``line`` is 1-based.
    """

    def __init__(self, path: str | Path, key: str | None, expected: str, got: str | None = None, *,
                 line: int | None = None, column: int | None = None) -> None:
        self.path, self.key, self.line = path, key, line
        where = _shown(path)
        if line is not None:
            where += f": line {line}" + ("" if column is None else f", column {column}")
        if key is not None:
            where += f": key '{key}'"
        text = f"{where}: expected {expected}" + ("" if got is None else f", got {got}")
        super().__init__(" ".join(text.split()))


@dataclass(frozen=True, eq=False)
class RobotModel:
    """A nominal robot: DH table, joint limits and motion defaults, as read from ``path``.

    ``nominal`` has ``base`` = identity and ``tool`` = zeros (the TP at the origin of the last DH frame).
    Arrays (read-only): ``limits`` (n, 2) and ``home`` (n,) in rad / m; ``max_speed``, ``default_speed``
    (n,) in rad/s / m/s; ``default_acceleration`` (n,) in rad/s² / m/s². ``geometry``: the collision
    capsules (:mod:`config.geometry`), None when the file has none (then no plan can be checked for collisions).
    ``coupling``: how the controller's readings give the DH joint values (None: they are the DH values);
    ``links``: link masses and centres of mass (None when the file has no ``dynamics``), for compliance.
    Limits, home and speeds are in DH joint values.
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

    @property
    def n_joints(self) -> int:
        return len(self.joint_types)


def check_schema(source: object, schema: object, supported: int) -> None:
    """Raise ConfigError unless ``schema`` is an integer file-format version this software reads."""
    if isinstance(schema, bool) or not isinstance(schema, int) or schema < 1:
        raise ConfigError(source, "schema", f"an integer schema version (supported: <= {supported})",
                          _got(schema))
    if schema > supported:
        raise ConfigError(source, "schema", f"a schema version <= {supported} (the newest this software "
                          "reads; a newer file needs a newer version)", _got(schema))


def robot_names() -> list[str]:
    """Names of the bundled models (the file stems in ``config/robots/``), sorted."""
    return sorted(p.stem for p in ROBOTS_DIR.glob("*.yaml"))


def config_file(name_or_path: str | Path, directory: Path, kind: str, names: Callable[[], list[str]]) -> Path:
    """The YAML file of a bundled ``kind`` (e.g. "robot") named ``name_or_path`` (case-insensitive, in
    ``directory``), or the file at that path: a ``Path``, or a string with a path separator or ending in
    ``.yaml``/``.yml``. ConfigError (one line) if it does not exist; ``names()`` lists the bundled ones."""
    text = str(name_or_path)
    if isinstance(name_or_path, Path) or names_a_file(text):
        path = Path(name_or_path)
        if not path.is_file():
            raise ConfigError(path, None, f"an existing {kind} YAML file", "no such file")
        return path
    path = directory / f"{text.strip().lower()}.yaml"
    if not path.is_file():
        raise ConfigError(repr(text), None, f"a bundled {kind} name ({', '.join(names())}) or a path to a YAML file",
                          "an unknown name")
    return path


def load_robot(name_or_path: str | Path) -> RobotModel:
    """Load and validate a bundled model by name (case-insensitive) or a YAML file by path.

    A ``Path``, or a string containing a path separator or ending in ``.yaml``/``.yml``, is read as a file;
    anything else is a bundled name. Raises :class:`ConfigError` on any problem.
    """
    path = config_file(name_or_path, ROBOTS_DIR, "robot", robot_names)
    return _model_from_dict(path, _read_yaml(path))


def _shown(path: str | Path) -> str:
    """``path`` relative to the working directory when it lies below it, else as given."""
    if isinstance(path, Path):
        try:
            return str(path.resolve().relative_to(Path.cwd().resolve()))
        except ValueError:
            return str(path)
    return path


def _got(value: object) -> str:
    """A short one-line rendering of a found value."""
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that rejects duplicate keys in a mapping."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=deep)
            if key in seen:
                mark = key_node.start_mark
                raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", mark)
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def _read_yaml(path: Path) -> Any:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(path, None, "a readable UTF-8 YAML file", _got(str(exc))) from exc
    try:
        return yaml.load(text, Loader=_StrictLoader)  # a SafeLoader: builds plain data only
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc)
        line, column = (mark.line + 1, mark.column + 1) if mark is not None else (None, None)
        raise ConfigError(path, None, f"valid YAML (parser: {problem})", line=line, column=column) from exc


def _number(path: Path, key: str, value: Any, expected: str = "a finite number") -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(path, key, expected, _got(value))
    return float(value)


def _per_joint(path: Path, key: str, value: Any, n: int, what: str) -> list[Any]:
    if not isinstance(value, list) or len(value) != n:
        size = f"{len(value)} entries" if isinstance(value, list) else _got(value)
        raise ConfigError(path, key, f"a list of {n} {what} (one per joint)", size)
    return value


def _numbers(path: Path, key: str, value: Any, n: int, unit: str, positive: bool = False) -> Array:
    items = _per_joint(path, key, value, n, f"numbers ({unit})")
    out = [_number(path, f"{key}[{i}]", v, f"a finite number ({unit})") for i, v in enumerate(items)]
    for i, v in enumerate(out):
        if positive and v <= 0:
            raise ConfigError(path, f"{key}[{i}]", f"a number > 0 ({unit})", _got(items[i]))
    return np.array(out)


def _model_from_dict(path: Path, data: Any) -> RobotModel:
    if not isinstance(data, dict):
        raise ConfigError(path, None, f"a mapping with keys {', '.join(KEYS)}", _got(data))
    for key in data:
        if key not in KEYS:
            raise ConfigError(path, str(key), f"only the keys {', '.join(KEYS)}", "an unknown key")
    for key in KEYS:
        if key not in data and key not in OPTIONAL_KEYS:
            raise ConfigError(path, key, "the key to be present", "nothing (missing key)")

    check_schema(path, data["schema"], SCHEMA_VERSION)
    for key in TEXT_KEYS:
        if not isinstance(data[key], str) or not data[key].strip():
            raise ConfigError(path, key, "a non-empty string", _got(data[key]))
    try:
        types = check_joint_types(data["joints"]) if isinstance(data["joints"], str) else ""
    except ValueError:
        types = ""
    if not types:
        expected = "a string of R and P, base to tip, e.g. RRRRRR"
        raise ConfigError(path, "joints", expected, _got(data["joints"]))
    n = len(types)

    rows = _per_joint(path, "dh", data["dh"], n, "mappings {theta, d, a, alpha}")
    table = np.empty((n, 4))
    for i, row in enumerate(rows):
        if not isinstance(row, dict) or set(row) != set(DH_KEYS):
            found = sorted(map(str, row)) if isinstance(row, dict) else row
            expected = "a mapping with exactly the keys theta, d, a, alpha"
            raise ConfigError(path, f"dh[{i}]", expected, _got(found))
        for j, name in enumerate(DH_KEYS):
            unit = "rad" if name in ("theta", "alpha") else "m"
            table[i, j] = _number(path, f"dh[{i}].{name}", row[name], f"a finite number ({unit})")

    pairs = _per_joint(path, "limits", data["limits"], n, "[min, max] pairs")
    limits = np.empty((n, 2))
    for i, pair in enumerate(pairs):
        key = f"limits[{i}]"
        if not isinstance(pair, list) or len(pair) != 2:
            raise ConfigError(path, key, "[min, max] with min < max", _got(pair))
        limits[i] = [_number(path, key, v, "[min, max] of finite numbers") for v in pair]
        if not limits[i, 0] < limits[i, 1]:
            raise ConfigError(path, key, "[min, max] with min < max", _got(pair))

    home = _numbers(path, "home", data["home"], n, "rad / m")
    for i, (q, (lo, hi)) in enumerate(zip(home, limits, strict=True)):
        if not lo <= q <= hi:
            expected = f"a value within limits[{i}] = [{float(lo)!r}, {float(hi)!r}]"
            raise ConfigError(path, f"home[{i}]", expected, _got(float(q)))
    max_speed = _numbers(path, "max_speed", data["max_speed"], n, "rad/s / m/s", positive=True)
    default_speed = _numbers(path, "default_speed", data["default_speed"], n, "rad/s / m/s", positive=True)
    for i, (v, vmax) in enumerate(zip(default_speed, max_speed, strict=True)):
        if v > vmax:
            expected = f"a speed <= max_speed[{i}] = {float(vmax)!r}"
            raise ConfigError(path, f"default_speed[{i}]", expected, _got(float(v)))
    default_acc = _numbers(path, "default_acceleration", data["default_acceleration"], n, "rad/s² / m/s²",
                           positive=True)

    nominal = DHModel(types, table[:, 0], table[:, 1], table[:, 2], table[:, 3])
    for array in (limits, home, max_speed, default_speed, default_acc):
        array.setflags(write=False)
    geometry = geometry_from_dict(path, data["collision"], n) if "collision" in data else None
    name, vendor, description, source = (data[key].strip() for key in TEXT_KEYS)
    coupling = _coupling(path, data["coupling"], n) if "coupling" in data else None
    links = _dynamics(path, data["dynamics"], n) if "dynamics" in data else None
    return RobotModel(name, vendor, description, source, types, nominal, limits, home, max_speed,
                      default_speed, default_acc, path, geometry, coupling, links)


def _matrix(path: Path, key: str, value: Any, n: int, unit: str) -> Array:
    rows = _per_joint(path, key, value, n, f"rows of {n} numbers")
    return np.array([_numbers(path, f"{key}[{i}]", row, n, unit) for i, row in enumerate(rows)])


def _coupling(path: Path, data: Any, n: int) -> Coupling:
    """``coupling: {matrix: [[...] x n], offset: [...], source: text}``: q_dh = matrix · readings + offset."""
    if not isinstance(data, dict) or "matrix" not in data or set(data) - {"matrix", "offset", "source"}:
        raise ConfigError(path, "coupling", "a mapping {matrix: n x n rows, offset: n numbers (optional), "
                          "source: text (optional)}", _got(data))
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
                          "(m, link i in DH frame i)", _got(data))
    if not isinstance(data["source"], str) or not data["source"].strip():
        raise ConfigError(path, "dynamics.source", "a non-empty string naming where the values come from",
                          _got(data["source"]))
    masses = _numbers(path, "dynamics.masses", data["masses"], n, "kg", positive=True)
    rows = _per_joint(path, "dynamics.centres_of_mass", data["centres_of_mass"], n, "[x, y, z] points (m)")
    centres = np.empty((n, 3))
    for i, row in enumerate(rows):
        key = f"dynamics.centres_of_mass[{i}]"
        if not isinstance(row, list) or len(row) != 3:
            raise ConfigError(path, key, "[x, y, z] in metres", _got(row))
        centres[i] = [_number(path, key, v) for v in row]
    return LinkMasses(masses, centres)
