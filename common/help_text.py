"""Help text from a module's docstring, for the commands' ``--help``."""

from __future__ import annotations

import argparse
import re
import textwrap


def description(paragraph: str, width: int = 79) -> str:
    """The first paragraph of a command module's docstring as its --help description: ``literal`` quotes and the
    parenthesised note on the module's role (``(the edge where files are read)``) dropped, wrapped to ``width``."""
    text = " ".join(paragraph.replace("``", "").split())
    text = re.sub(r" \(the edge where files are read[^)]*\)", "", text)
    return textwrap.fill(text, width)


_COLUMNS = re.compile(r"^(?P<head>\s*\S(.*?\S)?)\s{2,}(?P<tail>\S.*)$")  # "  command    what it does"


def fit(text: str, width: int) -> str:
    """``text`` (a --help description or epilog, laid out by hand) within ``width`` columns. Blocks whose lines all
    fit are kept as written; in a block with a longer line, prose (unindented lines, or a ``- `` item and its
    indented continuation) is refilled, and a longer two-column row (``  command    what it does``) puts its second
    column on the next line, deeper; what is still too long is wrapped at spaces with a deeper indent."""
    width = max(width, 40)
    out: list[str] = []
    for block in re.split(r"\n\s*\n", text.strip("\n")):
        lines = block.split("\n")
        if all(len(line) <= width for line in lines):
            out.append(block)
            continue
        out.append("\n".join(_fit_block(lines, width)))
    return "\n\n".join(out)


def _fit_block(lines: list[str], width: int) -> list[str]:
    """The lines of one block (no blank line) within ``width``."""
    out: list[str] = []
    prose: list[str] = []
    lead = ""

    def flush() -> None:
        if prose:
            out.extend(textwrap.wrap(" ".join(prose), width, initial_indent=lead,
                                     subsequent_indent=" " * len(lead) if lead.strip() else lead,
                                     break_long_words=False, break_on_hyphens=False))
            prose.clear()

    merged: list[str] = []
    for line in lines:  # a row's continuation (indented to its second column) joins the row
        row = _COLUMNS.match(merged[-1]) if merged else None
        if row and len(line) - len(line.lstrip(" ")) == row.start("tail") and not _COLUMNS.match(line):
            merged[-1] += " " + line.strip()
        else:
            merged.append(line)
    for line in merged:
        indent = len(line) - len(line.lstrip(" "))
        item = line.lstrip(" ").startswith("- ")
        if indent == 0 and not item and not _COLUMNS.match(line):  # prose: joins the paragraph
            if lead.strip():
                flush()
                lead = ""
            prose.append(line.strip())
            continue
        if item and indent == 0:
            flush()
            lead = "- "
            prose.append(line.strip()[2:])
            continue
        if lead.strip() and indent == len(lead):  # an item's continuation
            prose.append(line.strip())
            continue
        flush()
        lead = ""
        out.extend(_fit_line(line, width))
    flush()
    return out


def _fit_line(line: str, width: int) -> list[str]:
    """An indented line (an example, a table row) within ``width``."""
    if len(line) <= width:
        return [line]
    indent = len(line) - len(line.lstrip(" "))
    match = _COLUMNS.match(line)
    if match:
        column = match.start("tail")
        if column <= width // 2:  # a narrow first column (an exit code): the second hangs at its place
            return textwrap.wrap(line[column:], width, initial_indent=line[:column], subsequent_indent=" " * column,
                                 break_long_words=False, break_on_hyphens=False)
        deeper = " " * (indent + 4)  # else the first column alone, the second below it, deeper
        return [*_fit_line(match["head"], width),
                *textwrap.wrap(match["tail"], width, initial_indent=deeper, subsequent_indent=deeper,
                               break_long_words=False, break_on_hyphens=False)]
    if re.match(r"(acquire|identify) ", line.strip()):  # a command: continued with a backslash, still runnable
        parts = textwrap.wrap(line.strip(), width - 2, initial_indent=" " * indent,
                              subsequent_indent=" " * (indent + 4), break_long_words=False, break_on_hyphens=False)
        return [part + " \\" for part in parts[:-1]] + parts[-1:]
    first, rest = (indent, indent + 4) if indent <= 6 else (6, 6)  # a far-indented note (a second column on its
    return textwrap.wrap(line.strip(), width, initial_indent=" " * first, subsequent_indent=" " * rest,  # own line)
                         break_long_words=False, break_on_hyphens=False)


class Formatter(argparse.RawDescriptionHelpFormatter):
    """argparse help whose hand-laid description and epilog fit the terminal (:func:`fit`), as argparse's own parts
    do (the width of ``COLUMNS``, else the terminal's, else 80)."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return "\n".join(indent + line if line else line for line in fit(text, width).split("\n"))
