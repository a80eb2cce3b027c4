"""What the simulated rig's streams are made of: their settings (:class:`StreamSettings`: rates, clock errors,
lost target; the options are described in :mod:`drivers.sim.stream`) and a move that runs on the clock
(:class:`StreamedMove`: the synchronised trapezoidal profile of drivers/motion.py, readings at any clock time).

Both the rig (``drivers/sim/rig.py``, which owns them) and the streams (``drivers/sim/stream.py``) use them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.base import Array
from drivers.motion import joint_durations, profile_fraction

TIME_EPS = 1e-9  # s: two clock times closer than this are the same time


@dataclass(frozen=True)
class StreamSettings:
    """The rig's stream settings (see :mod:`drivers.sim.stream`): rates Hz, times s, ``drift`` a fraction."""

    joint_rate: float = 500.0
    drop: float = 0.0
    tracker_rate: float = 250.0
    clock_offset: float = 0.0
    drift: float = 0.0
    jitter: float = 0.0
    lost: tuple[float, float] = (0.0, 2.0)  # (duration, start into each stream), s

    @classmethod
    def from_settings(cls, robot: dict[str, Any], tracker: dict[str, Any]) -> StreamSettings:
        """From the typed mock options of the robot and tracker specs (``spec.mock_settings()``)."""
        return cls(robot["rate"], robot["drop"], tracker["rate"], tracker["clock_offset"], tracker["drift"],
                   tracker["stamp_jitter"], tuple(tracker["lost"]))

    def robot_options(self) -> dict[str, Any]:
        """The robot spec's options these settings came from (to check a spec against the rig)."""
        return {"rate": self.joint_rate, "drop": self.drop}

    def tracker_options(self) -> dict[str, Any]:
        return {"rate": self.tracker_rate, "clock_offset": self.clock_offset, "drift": self.drift,
                "stamp_jitter": self.jitter, "lost": self.lost}


class StreamedMove:
    """A move begun by ``start_move``: from ``start`` to ``target`` (readings, (n,)) at ``speed``/``acceleration``
    from clock time ``t0`` for ``duration`` s, every joint on the slowest one's profile; ``t_stop``: when it was
    cut short (inf: not), the arm then holding where it was."""

    def __init__(self, start: Array, target: Array, speed: Array, acceleration: Array, t0: float) -> None:
        self.start, self.target, self.t0 = start, target, t0
        durations = joint_durations(start, target, speed, acceleration)
        k = int(np.argmax(durations)) if len(durations) else 0
        self.duration = float(durations[k]) if len(durations) else 0.0
        self._profile = (float(speed[k]), float(acceleration[k]), abs(float(target[k] - start[k])))
        self.t_stop = math.inf
        self.finished = False  # set by motion_done: from then on the rig's rest-and-ring model takes over

    @property
    def t_end(self) -> float:
        """Clock time (s) at which the arm stops moving."""
        return min(self.t0 + self.duration, self.t_stop)

    def joints(self, t: Array) -> Array:
        """Readings (m, n) at clock times ``t`` (m,): the start before ``t0``, then the profile, held at ``t_end``."""
        v, a, d = self._profile
        dt = np.minimum(np.asarray(t, dtype=float), self.t_end) - self.t0
        share = np.array([profile_fraction(x, self.duration, v, a, d) if x > 0 else 0.0 for x in dt.reshape(-1)])
        return self.start + np.multiply.outer(share, self.target - self.start)

    def at(self, t: float) -> Array | None:
        """Readings (n,) at the one clock time ``t`` if the move holds the arm then (as :meth:`overlay`), else None;
        the fast path of a real-time reader (the UR emulator's stream asks thousands of times a second)."""
        if self.finished and t > self.t_end + TIME_EPS:
            return None
        v, a, d = self._profile
        dt = min(t, self.t_end) - self.t0
        share = profile_fraction(dt, self.duration, v, a, d) if dt > 0 else 0.0
        return self.start + share * (self.target - self.start)

    def overlay(self, t: Array, q: Array) -> Array:
        """``q`` (the rig's rest-and-ring model, (m, n) or (n,)) with the move's readings wherever ``t <= t_end``
        (everywhere until ``motion_done`` has seen the move end)."""
        times = np.atleast_1d(np.asarray(t, dtype=float))
        mine = times <= self.t_end + TIME_EPS if self.finished else np.ones(len(times), dtype=bool)
        if not mine.any():
            return q
        out = np.array(q, dtype=float, copy=True).reshape(len(times), -1)
        out[mine] = self.joints(times[mine])
        return out.reshape(np.shape(q))
