"""The record of one plan step as a session stores it (see acquire/session.py for the file).

Units: metres (positions, sigma), radians / metres (joints), seconds since the epoch (times).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from acquire.plan import Step
from drivers.base import TrackerReading

STATUSES = ("ok", "missing")


@dataclass(frozen=True, eq=False)
class StepRecord:
    """What happened at one plan step.

    ``q_cmd``: commanded joints; ``q_act``: joints read after settling (rad / m), None if never read;
    ``position``: averaged TP (x, y, z) in the tracker frame, m, None for a missing step; ``sigma``:
    per-axis standard uncertainty of that average, m, or None; ``samples``/``rejected``: readings kept /
    rejected (they add up to ``len(readings)``); ``status``: "ok" or "missing" (then ``reason`` says why);
    ``t_start``/``t_end``: s since the epoch; ``readings``: every raw reading, ``used`` parallel flags.
    Equality compares values (NaN equals NaN), so a record read back equals the one written.
    """

    plan_index: int
    kind: str
    sweep: int
    joint: int
    role: str
    q_cmd: tuple[float, ...]
    q_act: tuple[float, ...] | None
    position: tuple[float, float, float] | None
    sigma: float | None
    samples: int
    rejected: int
    status: str
    reason: str
    t_start: float
    t_end: float
    readings: tuple[TrackerReading, ...] = ()
    used: tuple[bool, ...] = ()

    def __post_init__(self) -> None:
        put = object.__setattr__
        put(self, "q_cmd", tuple(float(v) for v in self.q_cmd))
        if self.q_act is not None:
            put(self, "q_act", tuple(float(v) for v in self.q_act))
        if self.position is not None:
            put(self, "position", tuple(float(v) for v in self.position))
        if self.sigma is not None:
            put(self, "sigma", float(self.sigma))
        put(self, "readings", tuple(self.readings))
        put(self, "used", tuple(bool(u) for u in self.used))
        if self.status not in STATUSES:
            raise ValueError(f"step {self.plan_index}: status must be 'ok' or 'missing', got {self.status!r}")
        if self.status == "ok":
            if self.position is None or len(self.position) != 3 or not all(map(math.isfinite, self.position)):
                raise ValueError(f"step {self.plan_index}: an ok step needs a finite position (x, y, z)")
            if self.q_act is None:
                raise ValueError(f"step {self.plan_index}: an ok step needs the actual joints q_act")
        elif self.position is not None and len(self.position) != 3:
            raise ValueError(f"step {self.plan_index}: position must have 3 coordinates")
        if len(self.used) != len(self.readings):
            raise ValueError(f"step {self.plan_index}: {len(self.readings)} readings but {len(self.used)} used flags")
        if self.samples != sum(self.used) or self.samples + self.rejected != len(self.readings):
            raise ValueError(f"step {self.plan_index}: samples {self.samples} + rejected {self.rejected} must match "
                             f"the {sum(self.used)} used of {len(self.readings)} readings")

    @classmethod
    def from_step(cls, step: Step, **fields: Any) -> StepRecord:
        """A record of the plan ``step`` (index, kind, sweep, joint, role, commanded q taken from it)."""
        return cls(plan_index=step.index, kind=step.kind, sweep=step.sweep, joint=step.joint, role=step.role,
                   q_cmd=step.q, **fields)

    def _key(self) -> tuple[Any, ...]:
        readings = tuple((_floats(r.position), nan_none(r.timestamp), nan_none(r.sigma), r.status)
                         for r in self.readings)
        return (self.plan_index, self.kind, self.sweep, self.joint, self.role, _floats(self.q_cmd),
                _floats(self.q_act), _floats(self.position), nan_none(self.sigma), self.samples, self.rejected,
                self.status, self.reason, self.t_start, self.t_end, readings, self.used)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, StepRecord):
            return NotImplemented
        return self._key() == other._key()


def nan_none(v: float | None) -> float | None:
    """None for None or NaN (SQLite stores NaN as NULL), else the float."""
    return None if v is None or math.isnan(v) else float(v)


def _floats(values: Any) -> tuple[float | None, ...] | None:
    return None if values is None else tuple(nan_none(float(v)) for v in np.asarray(values, dtype=float).ravel())
