"""The layout shows the architecture and keeps it: every import between the project's packages points one way,
identify's math reads no files, modules stay small, package ``__init__`` files stay light.

Imports are read from the source (``ast``) of every module: module-level, function-level and ``TYPE_CHECKING``
imports alike, and the literal module names given to ``importlib.import_module``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: The top-level packages, each importing only those before it (``common`` and ``kinematics`` import none).
ORDER = ("common", "kinematics", "config", "drivers", "session", "identify", "acquire")
#: identify's modules that are not its math: the commands at its top, and its edge (files read and written).
IDENTIFY_COMMANDS = ("identify.commands", "identify.api")
IDENTIFY_EDGE = ("identify.io", "identify.report", "identify.exports")
MAX_LINES = 550


def _modules() -> dict[str, Path]:
    out = {}
    for package in ORDER:
        for path in sorted((ROOT / package).rglob("*.py")):
            name = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            out[name.removesuffix(".__init__")] = path
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> list[tuple[str, int]]:
    """(imported module or module.name, line) of every import in the module, wherever it stands."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolved against the module's package
                base = name.split(".")[: len(name.split(".")) - node.level + path.name.endswith("__init__.py")]
                module = ".".join([*base, *([node.module] if node.module else [])])
            else:
                module = node.module or ""
            out += [(f"{module}.{alias.name}", node.lineno) for alias in node.names]
        elif (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
              and getattr(node.func, "attr", getattr(node.func, "id", None)) == "import_module"
              and isinstance(node.args[0].value, str)):
            out.append((node.args[0].value, node.lineno))
    return out


def _within(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


IMPORTS = {name: _imports(name, path) for name, path in MODULES.items()}


def _where(name: str, line: int) -> str:
    return f"{MODULES[name].relative_to(ROOT)}:{line}"


def test_every_top_level_package_imports_only_those_below_it() -> None:
    wrong = []
    for name, imports in IMPORTS.items():
        rank = ORDER.index(name.split(".")[0])
        for target, line in imports:
            top = target.split(".")[0]
            if top in ORDER and ORDER.index(top) > rank:
                wrong.append(f"{_where(name, line)}: {name.split('.')[0]} imports {target}")
    assert not wrong, "imports against the order " + " <- ".join(ORDER) + ":\n" + "\n".join(wrong)


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _unit(name: str) -> str | None:
    """The package a module counts in at subpackage granularity: ``drivers.ur``, ``identify.io``... The top-level
    modules of a package count as the package; identify's commands count apart from its math."""
    parts = name.split(".")
    if parts[0] not in ORDER:
        return None
    if _within(name, IDENTIFY_COMMANDS):
        return "identify (commands)"
    sub = ".".join(parts[:2])
    return sub if (ROOT / sub.replace(".", "/") / "__init__.py").is_file() else parts[0]


@pytest.mark.parametrize("granularity", ["package", "subpackage"])
def test_no_import_cycle(granularity: str) -> None:
    graph: dict[str, set[str]] = {}
    for name, imports in IMPORTS.items():
        for target, _ in imports:
            a, b = (n.split(".")[0] for n in (name, target)) if granularity == "package" else (_unit(name),
                                                                                             _unit(target))
            if a and b and a != b and b.split(".")[0] in ORDER:
                graph.setdefault(a, set()).add(b)
    assert _cycles(graph) == []


def test_identify_math_reads_no_files_and_knows_no_devices() -> None:
    """identify's estimation imports neither devices, sessions nor acquisition, nor its own edge."""
    forbidden = ("drivers", "session", "acquire", *IDENTIFY_EDGE, *IDENTIFY_COMMANDS)
    wrong = [f"{_where(name, line)}: {name} imports {target}"
             for name, imports in IMPORTS.items()
             if name.startswith("identify.") and not _within(name, IDENTIFY_EDGE + IDENTIFY_COMMANDS)
             for target, line in imports if _within(target, forbidden)]
    assert not wrong, "\n".join(wrong)


def test_modules_stay_small() -> None:
    paths = [*MODULES.values(), *sorted((ROOT / "tests").rglob("*.py")), *sorted((ROOT / "bench").rglob("*.py"))]
    long = {str(p.relative_to(ROOT)): n for p in paths if (n := len(p.read_text(encoding="utf-8").splitlines())) >
            MAX_LINES}
    assert long == {}


def test_package_inits_import_nothing_heavy() -> None:
    """Importing a package imports none of its modules (the registry imports backends only when asked)."""
    for name, path in MODULES.items():
        if path.name == "__init__.py":
            assert all(_within(target, ("common", "importlib")) for target, _ in IMPORTS[name]), name


def test_registry_names_existing_backend_modules() -> None:
    from drivers.registry import ROBOT_BACKENDS, TRACKER_BACKENDS

    for entry in (*ROBOT_BACKENDS.values(), *TRACKER_BACKENDS.values()):
        module = entry.partition(":")[0]
        assert module in MODULES and _within(module, ("drivers",)), entry
