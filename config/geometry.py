"""A robot model's collision geometry: the ``collision`` block of a file in ``config/robots/`` (schema 1).

::

    collision:
      source: where the dimensions come from
      mounting: {normal: [0, 0, 1], offset: 0.0}   # the surface the arm stands on, in the base frame (m)
      bodies:                                      # capsules; a sphere has a == b
        - {name: base, frame: 0, a: [0, 0, 0], b: [0, 0, 0.1625], radius: 0.075}
      ignore: [[wrist 2, tool]]                    # body pairs never checked ('tool': the site's tool)

``frame`` is the DH frame the capsule is fixed in (0 = base, i = after joint i; n = the flange), ``a`` and
``b`` its ends in that frame (m), ``radius`` m. ``mounting.normal`` points away from the surface (up, for an
arm on a table); the site file may move the surface (``cell.mounting_offset``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from config.files import ConfigError, got

Array = NDArray[np.float64]

KEYS = ("source", "mounting", "bodies", "ignore")
BODY_KEYS = ("name", "frame", "a", "b", "radius")
TOOL = "tool"  # the name of the site's tool capsule (on the flange), usable in ``ignore``


@dataclass(frozen=True, eq=False)
class RobotGeometry:
    """Capsules of a robot (see the module docstring): ``names`` (K,), ``frame`` (K,) int, ``a``, ``b`` (K, 3)
    m, ``radius`` (K,) m; ``normal`` (3,) unit and ``offset`` m of the mounting surface in the base frame;
    ``ignore`` name pairs; ``source`` text."""

    source: str
    names: tuple[str, ...]
    frame: NDArray[np.int64]
    a: Array
    b: Array
    radius: Array
    normal: Array
    offset: float
    ignore: frozenset[frozenset[str]]


def geometry_from_dict(path: Path, data: Any, n_joints: int) -> RobotGeometry:
    """Validate a ``collision`` block for a chain of ``n_joints``; ConfigError (one line) on any problem."""
    def fail(key: str, expected: str, value: Any) -> ConfigError:
        return ConfigError(path, f"collision.{key}" if key else "collision", expected, got(value))

    def vector(key: str, value: Any) -> Array:
        ok = isinstance(value, list) and len(value) == 3
        ok = ok and all(not isinstance(v, bool) and isinstance(v, int | float) and math.isfinite(v) for v in value)
        if not ok:
            raise fail(key, "[x, y, z] of finite numbers (m)", value)
        return np.array(value, dtype=float)

    if not isinstance(data, dict) or set(data) - set(KEYS) or not {"source", "bodies"} <= set(data):
        raise fail("", "a mapping with the keys source, bodies and optionally mounting, ignore", data)
    if not isinstance(data["source"], str) or not data["source"].strip():
        raise fail("source", "a non-empty string naming where the dimensions come from", data["source"])
    mounting = data.get("mounting", {"normal": [0, 0, 1], "offset": 0.0})
    if not isinstance(mounting, dict) or set(mounting) != {"normal", "offset"}:
        raise fail("mounting", "a mapping {normal: [x, y, z], offset: m}", mounting)
    normal = vector("mounting.normal", mounting["normal"])
    if np.linalg.norm(normal) < 1e-9:
        raise fail("mounting.normal", "a non-zero vector", mounting["normal"])
    offset = mounting["offset"]
    if isinstance(offset, bool) or not isinstance(offset, int | float) or not math.isfinite(offset):
        raise fail("mounting.offset", "a finite number (m)", offset)

    bodies = data["bodies"]
    if not isinstance(bodies, list) or not bodies:
        raise fail("bodies", "a non-empty list of capsules {name, frame, a, b, radius}", bodies)
    names, frames, ends_a, ends_b, radii = [], [], [], [], []
    for i, body in enumerate(bodies):
        key = f"bodies[{i}]"
        if not isinstance(body, dict) or set(body) != set(BODY_KEYS):
            raise fail(key, "a mapping with exactly the keys name, frame, a, b, radius", body)
        name = body["name"]
        if not isinstance(name, str) or not name.strip() or name.strip() in (*names, TOOL):
            raise fail(f"{key}.name", "a non-empty name, unique among the bodies, not 'tool'", name)
        frame = body["frame"]
        if isinstance(frame, bool) or not isinstance(frame, int) or not 0 <= frame <= n_joints:
            raise fail(f"{key}.frame", f"a DH frame number 0..{n_joints} (0: base, {n_joints}: flange)", frame)
        radius = body["radius"]
        if isinstance(radius, bool) or not isinstance(radius, int | float) or not (0 < radius < math.inf):
            raise fail(f"{key}.radius", "a number > 0 (m)", radius)
        names.append(name.strip())
        frames.append(frame)
        ends_a.append(vector(f"{key}.a", body["a"]))
        ends_b.append(vector(f"{key}.b", body["b"]))
        radii.append(float(radius))

    ignore: set[frozenset[str]] = set()
    known = [*names, TOOL]
    for i, pair in enumerate(data.get("ignore") or []):
        if not isinstance(pair, list) or len(pair) != 2 or not all(p in known for p in pair) or pair[0] == pair[1]:
            raise fail(f"ignore[{i}]", "a pair of two different body names from collision.bodies (or 'tool')", pair)
        ignore.add(frozenset(pair))
    return RobotGeometry(data["source"].strip(), tuple(names), np.array(frames, dtype=np.int64), np.array(ends_a),
                         np.array(ends_b), np.array(radii), normal / np.linalg.norm(normal), float(offset),
                         frozenset(ignore))
