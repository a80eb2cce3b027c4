"""Terminal output that fits the terminal's width: prose lines wrapped, tables split into column blocks.

The width is ``COLUMNS`` when set, else the width of the terminal stdout writes to; output sent to a file or a
pipe (no terminal, no ``COLUMNS``) is not wrapped: a log keeps one line per item. Machines read ``--json``.
"""

from __future__ import annotations

import os
import sys
import textwrap
from collections.abc import Iterable, Sequence

MIN_WIDTH = 40  # narrower terminals get 40-column text (wrapping narrower helps no one)


def width() -> int | None:
    """Columns of the terminal the output goes to, None for no terminal (see the module docstring)."""
    try:
        columns = int(os.environ["COLUMNS"])
    except (KeyError, ValueError):
        try:
            columns = os.get_terminal_size(sys.stdout.fileno()).columns if sys.stdout.isatty() else 0
        except (AttributeError, OSError, ValueError):
            columns = 0
    return max(columns, MIN_WIDTH) if columns > 0 else None


def wrap(line: str, columns: int | None = None, indent: int = 4) -> list[str]:
    """``line`` wrapped to ``columns`` (default: :func:`width`; None: as it is); continuation lines start
    ``indent`` spaces deeper than the line's own indentation. Words are never broken (a word longer than the line
    stays whole)."""
    columns = columns or width()
    if columns is None or len(line) <= columns:
        return [line]
    lead = len(line) - len(line.lstrip(" "))
    return textwrap.wrap(line.lstrip(" "), columns, initial_indent=" " * lead, subsequent_indent=" " * (lead + indent),
                         break_long_words=False, break_on_hyphens=False) or [line]


def wrap_lines(lines: Iterable[str], columns: int | None = None) -> list[str]:
    """Every line of ``lines`` (each may hold newlines) wrapped as :func:`wrap` does."""
    columns = columns or width()
    return [part for text in lines for line in text.split("\n") for part in wrap(line, columns)]


def table(header: Sequence[str], rows: Sequence[Sequence[str]], columns: int | None = None, key: int = 1,
          gap: int = 2) -> list[str]:
    """Lines of a table with right-aligned columns ``gap`` spaces apart. When it is wider than ``columns``
    (default :func:`width`; None: no limit) the columns after the first ``key`` ones go into consecutive blocks
    that fit, each repeating the ``key`` columns, separated by a blank line."""
    columns = columns or width() or 10**9
    widths = [max(len(str(c)) for c in column) for column in zip(header, *rows, strict=True)]
    keys = list(range(min(key, len(widths))))
    blocks: list[list[int]] = [[]]
    used = sum(widths[k] for k in keys) + gap * max(len(keys) - 1, 0)
    for c in range(len(keys), len(widths)):
        need = gap + widths[c]
        if blocks[-1] and used + need > columns:
            blocks.append([])
            used = sum(widths[k] for k in keys) + gap * max(len(keys) - 1, 0)
        blocks[-1].append(c)
        used += need
    out: list[str] = []
    for n, block in enumerate(blocks):
        if n:
            out.append("")
        for cells in (header, *rows):
            out.append((" " * gap).join(str(cells[c]).rjust(widths[c]) for c in keys + block))
    return out


def say(text: str) -> None:
    """Print ``text`` (lines) to stdout wrapped to the terminal's width."""
    print("\n".join(wrap_lines([text])))
