"""The layout shows the architecture and keeps it: every import between the project's packages points one way, no
two modules import each other (directly or round a circle), identify's math reads no files, folders hold at most
20 modules and modules at most 500 lines, package ``__init__`` files stay light, and the README's "Layout" section
names every folder.

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
MAX_LINES = 500  #: a module of the product
MAX_TEST_LINES = 550  #: a test or benchmark module
MAX_MODULES = 20  #: modules in one folder of the product (``__init__`` not counted)


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
    def long(paths: list[Path], limit: int) -> dict[str, int]:
        return {str(p.relative_to(ROOT)): n for p in paths if (n := len(p.read_text(encoding="utf-8").splitlines()))
                > limit}

    assert long(list(MODULES.values()), MAX_LINES) == {}
    assert long([*sorted((ROOT / "tests").rglob("*.py")), *sorted((ROOT / "bench").rglob("*.py"))],
                MAX_TEST_LINES) == {}


def test_no_folder_holds_more_than_twenty_modules() -> None:
    folders: dict[str, int] = {}
    for path in MODULES.values():
        if path.name != "__init__.py":
            folder = str(path.parent.relative_to(ROOT))
            folders[folder] = folders.get(folder, 0) + 1
    assert {f: n for f, n in folders.items() if n > MAX_MODULES} == {}


def _module_of(target: str) -> str | None:
    """The project module an import names: ``a.b`` or, for ``from a.b import c`` of a name, ``a.b``."""
    if target in MODULES:
        return target
    head = target.rpartition(".")[0]
    return head if head in MODULES else None


def test_no_import_circle_between_modules() -> None:
    """Function-level imports count: a circle closed inside a function is still a circle for the reader."""
    graph: dict[str, set[str]] = {}
    for name, imports in IMPORTS.items():
        for target, _ in imports:
            module = _module_of(target)
            if module is not None and module != name and not (MODULES[module].name == "__init__.py"
                                                               and name.startswith(module + ".")):
                graph.setdefault(name, set()).add(module)
    assert _cycles(graph) == []


def test_the_readme_layout_names_every_folder() -> None:
    """Every package folder of the product has its own line in the README's "Layout" section."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text[text.index("\n## Layout"):]
    section = section[: section.find("\n## ", 1) if "\n## " in section[1:] else len(section)]
    folders = sorted({str(p.parent.relative_to(ROOT)) for p in MODULES.values() if p.name == "__init__.py"})
    missing = [f for f in folders if f"- `{f}/`:" not in section]
    assert missing == []


def test_only_the_session_package_speaks_sql() -> None:
    """The session file's tables are ``session``'s to know: no other package imports sqlite3."""
    wrong = [f"{_where(name, line)}: {name} imports {target}" for name, imports in IMPORTS.items()
             if not _within(name, ("session",)) for target, line in imports if _within(target, ("sqlite3",))]
    assert not wrong, "\n".join(wrong)


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
