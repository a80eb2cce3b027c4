"""Motion timing shared by the simulated robot and the planner's duration estimate (pure)."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray


def motion_time(distance: Any, speed: Any, acceleration: Any) -> NDArray[np.float64]:
    """Time (s) of a trapezoidal (or, when too short to reach ``speed``, triangular) velocity profile
    over ``distance`` (rad or m) from rest to rest, at ``speed`` and ``acceleration``; elementwise."""
    d, v, a = (np.abs(np.asarray(x, dtype=float)) for x in (distance, speed, acceleration))
    return np.where(d * a >= v * v, d / v + v / a, 2 * np.sqrt(d / a))
