"""Motion timing shared by the simulated robot and the planner's duration estimate (pure; s, rad or m)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray


def motion_time(distance: Any, speed: Any, acceleration: Any) -> NDArray[np.float64]:
    """Time (s) of a trapezoidal (or, when too short to reach ``speed``, triangular) velocity profile
    over ``distance`` (rad or m) from rest to rest, at ``speed`` and ``acceleration``; elementwise."""
    d, v, a = (np.abs(np.asarray(x, dtype=float)) for x in (distance, speed, acceleration))
    return np.where(d * a >= v * v, d / v + v / a, 2 * np.sqrt(d / a))


def move_duration(start: Sequence[float], target: Sequence[float], speed: Sequence[float],
                  acceleration: Sequence[float]) -> float:
    """Duration (s) of a synchronised joint move: the trapezoidal profile (triangular for short moves) of
    the slowest joint, accelerating at ``acceleration`` up to ``speed`` and braking at ``acceleration``."""
    return float(np.max(joint_durations(start, target, speed, acceleration), initial=0.0))


def joint_durations(start: Sequence[float], target: Sequence[float], speed: Sequence[float],
                    acceleration: Sequence[float]) -> NDArray[np.float64]:
    """Each joint's own move time (s) from ``start`` to ``target``: (n,)."""
    return motion_time(np.asarray(target, dtype=float) - np.asarray(start, dtype=float), speed, acceleration)


def profile_fraction(t: float, duration: float, speed: float, acceleration: float, distance: float) -> float:
    """Share of the distance covered at time ``t`` of a trapezoidal profile lasting ``duration``."""
    if duration <= 0 or distance <= 0 or t >= duration:
        return 1.0
    ramp = min(speed / acceleration, duration / 2)
    peak = acceleration * ramp
    if t < ramp:
        covered = 0.5 * acceleration * t * t
    elif t <= duration - ramp:
        covered = 0.5 * acceleration * ramp * ramp + peak * (t - ramp)
    else:
        covered = distance - 0.5 * acceleration * (duration - t) ** 2
    return min(max(covered / distance, 0.0), 1.0)


def leading_joint_limits(start: Sequence[float], target: Sequence[float], speed: Sequence[float],
                         acceleration: Sequence[float]) -> tuple[float, float]:
    """The one speed and acceleration of a synchronised move given for its leading joint (the largest travel), as
    a UR moveJ takes them: the largest that keep every moving joint within its own ``speed`` / ``acceleration``
    (rad/s or m/s, rad/s² or m/s²; a joint that travels ``r`` times the leader's moves ``r`` times as fast). With
    nothing to travel, the smallest of each."""
    travel = np.abs(np.asarray(target, dtype=float) - np.asarray(start, dtype=float))
    v, a = np.asarray(speed, dtype=float), np.asarray(acceleration, dtype=float)
    lead = float(np.max(travel, initial=0.0))
    moving = travel > 1e-12 * max(lead, 1.0)
    if lead <= 0 or not moving.any():
        return float(np.min(v)), float(np.min(a))
    ratio = lead / travel[moving]
    return float(np.min(v[moving] * ratio)), float(np.min(a[moving] * ratio))
