"""Help text from a module's docstring, for the commands' ``--help``."""

from __future__ import annotations

import re
import textwrap


def description(paragraph: str, width: int = 79) -> str:
    """The first paragraph of a command module's docstring as its --help description: ``literal`` quotes and the
    parenthesised note on the module's role (``(the edge where files are read)``) dropped, wrapped to ``width``."""
    text = " ".join(paragraph.replace("``", "").split())
    text = re.sub(r" \(the edge where files are read[^)]*\)", "", text)
    return textwrap.fill(text, width)
