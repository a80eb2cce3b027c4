"""A site file whose real-time steps take a fraction of a second, for the tests that stop, kill or crash a running
``acquire``: moves at full speed (3.1 rad/s, 40 rad/s²), no settling, the tracker's measure time 1 ms."""

from __future__ import annotations

FAST_MOVES = """schema: 1
robot:
  speed: [3.1, 3.1, 3.1, 3.1, 3.1, 3.1]
  acceleration: [40, 40, 40, 40, 40, 40]
tracker:
  measure_time: 0.001
"""


def fast_site(**plan: object) -> str:
    """The site file's text: :data:`FAST_MOVES` and a ``plan`` section with ``settle_time: 0.0`` and ``plan``'s keys,
    each value written as it is given (a string as YAML text)."""
    lines = [f"  {key}: {value}" for key, value in {"settle_time": 0.0, **plan}.items()]
    return FAST_MOVES + "plan:\n" + "\n".join(lines) + "\n"
