"""The language-neutral part of a program filter: a program's targets with their spans in the text, the lines left
as written with the reason, and the rewrite that replaces spans and comments the changed lines.

A :class:`Language` module finds the targets (:class:`Target`: joint values or a Cartesian pose, the span of the
literal to replace) and formats new literals and comments; :func:`rewrite` changes those spans and nothing else.
Units: as the language writes them (the URScript module: m and rad).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
KINDS = ("joints", "pose")


@dataclass(frozen=True)
class Target:
    """One target of a program: ``kind`` ``joints`` (joint values) or ``pose`` (a Cartesian tool pose, 4x4 in
    ``pose``); ``values`` as written (joint values, or the language's pose numbers); ``start:end`` the span of
    the literal in the program text; ``line`` its 1-based line; ``name`` the named pose it is assigned to (None:
    a literal in a motion command); ``use`` the character offset of its first use by a motion command (the
    order in which the arm meets the targets)."""

    kind: str
    values: tuple[float, ...]
    start: int
    end: int
    line: int
    use: int
    name: str | None = None
    pose: Array | None = field(default=None, compare=False)


@dataclass(frozen=True)
class Skipped:
    """A line the filter keeps as written although it moves the arm: its 1-based ``line``, its ``text`` and the
    ``reason`` (e.g. a target computed at run time)."""

    line: int
    text: str
    reason: str


@dataclass(frozen=True)
class Parsed:
    """A program read by a :class:`Language`: its ``text``, its ``targets`` in the order the arm meets them,
    and the motion lines it could not rewrite (``skipped``)."""

    text: str
    targets: list[Target]
    skipped: list[Skipped]
    tcp: tuple[float, ...] | None = None  # the tool centre point the program sets, in the language's units
    tcp_problem: str = ""  # why the program's TCP cannot be known here (set at run time, several), "" if it can


class Language(Protocol):
    """One robot language: reads a program's targets and writes new literals and comments."""

    name: str

    def parse(self, text: str, n_joints: int) -> Parsed:
        """The targets and skipped lines of ``text`` for an arm of ``n_joints``; ValueError (one line) for a
        program that cannot be filtered at all."""

    def joints(self, q: Array) -> str:
        """A joint-values literal."""

    def pose(self, pose: Array, near: tuple[float, ...] | None = None) -> str:
        """A Cartesian pose literal of a 4x4 pose; ``near``: the pose as written (the same rotation may have
        several sets of numbers: the nearest is kept)."""

    def comment(self, text: str) -> str:
        """``text`` as an end-of-line comment (with its leading separator)."""


def line_of(text: str, offset: int) -> int:
    """1-based line number of character ``offset`` in ``text``."""
    return text.count("\n", 0, offset) + 1


def line_text(text: str, line: int) -> str:
    """The 1-based ``line`` of ``text`` without its line ending."""
    return text.splitlines()[line - 1] if line <= len(text.splitlines()) else ""


def rewrite(text: str, changes: Sequence[tuple[Target, str, str]], language: Language) -> str:
    """``text`` with each change's target span replaced by its literal and, at the end of the line where the
    span ends (before the line ending), the changes' comments joined by ``; ``. Nothing else changes: a literal
    written over several lines keeps its line breaks (:func:`same_layout`), so every line keeps its number."""
    edits = [(target.start, target.end, same_layout(text[target.start:target.end], literal))
             for target, literal, _ in changes]
    notes: dict[int, list[str]] = {}
    for target, _, note in changes:
        end = len(text)
        for ending in ("\n", "\r"):
            found = text.find(ending, target.end)
            end = min(end, found) if found >= 0 else end
        notes.setdefault(end, []).append(note)
    edits += [(at, at, language.comment("; ".join(texts))) for at, texts in notes.items()]
    out = text
    for start, end, new in sorted(edits, key=lambda e: (e[0], e[1]), reverse=True):
        out = out[:start] + new + out[end:]
    return out


_LIST = re.compile(r"(?P<head>p?\s*\[)(?P<lead>\s*)(?P<body>.*?)(?P<trail>\s*)\]", re.S)
_SEPARATOR = re.compile(r"\s*,\s*")


def same_layout(old: str, new: str) -> str:
    """The list literal ``new`` laid out as ``old`` is (``[...]`` or ``p[...]``, as many values): the separators
    and the blanks inside the brackets of ``old`` around the values of ``new``. ``new`` as it is when ``old`` is on
    one line or is not such a list."""
    if "\n" not in old and "\r" not in old:
        return new
    a, b = _LIST.fullmatch(old), _LIST.fullmatch(new)
    if a is None or b is None:
        return new
    separators = _SEPARATOR.findall(a["body"])
    values = _SEPARATOR.split(b["body"].strip())
    if len(values) != len(separators) + 1:
        return new
    body = values[0] + "".join(sep + value for sep, value in zip(separators, values[1:], strict=True))
    return f"{a['head']}{a['lead']}{body}{a['trail']}]"
