"""Reading a configuration file: the one-line :class:`ConfigError`, the strict YAML reader (duplicate keys
rejected), the schema-version check, and finding a bundled file by name or a file by path.

Shared by the robot models (:mod:`config.robots`), their collision geometry (:mod:`config.geometry`), the site
file (:mod:`config.site`) and the tracker profiles (``drivers/trackers/ascii_profile.py``).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from config.model_path import names_a_file


class ConfigError(ValueError):
    """A configuration file or name (robot, site, tracker profile) that cannot be used; the message is one
    line: where, expected value, found value.

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


def check_schema(source: object, schema: object, supported: int) -> None:
    """Raise ConfigError unless ``schema`` is an integer file-format version this software reads."""
    if isinstance(schema, bool) or not isinstance(schema, int) or schema < 1:
        raise ConfigError(source, "schema", f"an integer schema version (supported: <= {supported})",
                          got(schema))
    if schema > supported:
        raise ConfigError(source, "schema", f"a schema version <= {supported} (the newest this software "
                          "reads; a newer file needs a newer version)", got(schema))


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


def _shown(path: str | Path) -> str:
    """``path`` relative to the working directory when it lies below it, else as given."""
    if isinstance(path, Path):
        try:
            return str(path.resolve().relative_to(Path.cwd().resolve()))
        except ValueError:
            return str(path)
    return path


def got(value: object) -> str:
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


def read_yaml(path: Path) -> Any:
    """The plain data of the YAML file at ``path``; ConfigError (one line, with the line and column of a syntax
    error) if it cannot be read or parsed, or repeats a key."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(path, None, "a readable UTF-8 YAML file", got(str(exc))) from exc
    try:
        return yaml.load(text, Loader=_StrictLoader)  # a SafeLoader: builds plain data only
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        problem = getattr(exc, "problem", None) or str(exc)
        line, column = (mark.line + 1, mark.column + 1) if mark is not None else (None, None)
        raise ConfigError(path, None, f"valid YAML (parser: {problem})", line=line, column=column) from exc
