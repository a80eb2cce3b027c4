"""Whether a model named on the command line is a bundled name or a file: one rule for every option that names a
robot (``--robot`` of each command, the model in a robot spec such as ``mock:arms/cell7.yaml``)."""

from __future__ import annotations


def names_a_file(text: str) -> bool:
    """True when ``text`` is a path to a YAML file rather than a bundled name: it holds a path separator or ends
    in ``.yaml``/``.yml``."""
    return "/" in text or "\\" in text or text.lower().endswith((".yaml", ".yml"))
