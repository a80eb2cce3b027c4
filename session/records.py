"""The record of one plan step as a session stores it (see session/store.py for the file).

Units: metres (positions, sigma), radians / metres (joints), seconds since the epoch (times).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.base import Correction, TrackerReading
from session.plan import Step

STATUSES = ("ok", "missing")


@dataclass(frozen=True)
class PointRecord:
    """The average of one tracked point at a step: ``tp`` its id, ``position`` (x, y, z) m in the tracker frame,
    ``sigma`` its per-axis standard uncertainty (m) or None, ``samples``/``rejected`` its readings kept / rejected."""

    tp: int
    position: tuple[float, float, float]
    sigma: float | None
    samples: int
    rejected: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "tp", int(self.tp))
        object.__setattr__(self, "position", tuple(float(v) for v in self.position))
        if self.sigma is not None:
            object.__setattr__(self, "sigma", float(self.sigma))
        if self.tp < 1 or len(self.position) != 3 or not all(map(math.isfinite, self.position)):
            raise ValueError(f"tracked point {self.tp}: needs an id >= 1 and a finite position (x, y, z)")


@dataclass(frozen=True)
class FrameRecord:
    """The averaged orientation of one tracked point's target frame at a step (full-pose devices): ``tp`` its id,
    ``rotvec`` (rx, ry, rz) the frame's rotation in the tracker frame as a rotation vector, rad, ``sigma_r`` its
    per-axis standard uncertainty (rad) or None."""

    tp: int
    rotvec: tuple[float, float, float]
    sigma_r: float | None

    def __post_init__(self) -> None:
        object.__setattr__(self, "tp", int(self.tp))
        object.__setattr__(self, "rotvec", tuple(float(v) for v in self.rotvec))
        if self.sigma_r is not None:
            object.__setattr__(self, "sigma_r", float(self.sigma_r))
        if self.tp < 1 or len(self.rotvec) != 3 or not all(map(math.isfinite, self.rotvec)):
            raise ValueError(f"tracked point {self.tp}: an orientation needs an id >= 1 and a finite rx, ry, rz")


@dataclass(frozen=True, eq=False)
class StepRecord:
    """What happened at one plan step.

    ``q_cmd``: commanded joints; ``q_act``: joints read after settling (rad / m), None if never read (both
    the controller's readings: with a coupled robot not the DH values, see the session's ``coupling``);
    ``position``: averaged TP (x, y, z) in the tracker frame, m, None for a missing step; ``sigma``:
    per-axis standard uncertainty of that average, m, or None; ``samples``/``rejected``: readings kept /
    rejected (they add up to ``len(readings)``); ``status``: "ok" or "missing" (then ``reason`` says why);
    ``t_start``/``t_end``: s since the epoch; ``readings``: every raw reading, ``used`` parallel flags.
    ``points``: with a tracker that sees several points, the average of each point seen (ascending ids; the
    readings carry their ``tp``); ``position`` and ``sigma`` are then the first one's, ``samples`` and
    ``rejected`` the totals. Empty when every reading sees point 1: ``position`` is then point 1's. ``frames``:
    with a full-pose device, each tracked point's averaged orientation (:class:`FrameRecord`, ascending ids).
    ``corrections``: with a camera that corrects for its board's shape and its lens, each tracked point's
    (id, drivers/base.py ``Correction``) of its kept readings averaged, so that identify can correct the step again
    with the session's final estimate (identify/sensors/recorrection.py); the position stored is as measured.
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
    points: tuple[PointRecord, ...] = ()
    frames: tuple[FrameRecord, ...] = ()
    corrections: tuple[tuple[int, Correction], ...] = ()

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
        put(self, "points", tuple(self.points))
        put(self, "frames", tuple(self.frames))
        put(self, "corrections", tuple((int(tp), c) for tp, c in self.corrections))
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
        self._check_points()

    def _check_points(self) -> None:
        """The per-point averages agree with the readings and with ``position``/``sigma`` (class docstring)."""
        where = f"step {self.plan_index}"
        if not self.points:
            if any(r.tp != 1 for r in self.readings):
                raise ValueError(f"{where}: readings of several tracked points need their averages (points)")
            return
        ids = [p.tp for p in self.points]
        if self.status != "ok" or ids != sorted(set(ids)):
            raise ValueError(f"{where}: points need an ok step and distinct ascending ids, got {ids}")
        first = self.points[0]
        if self.position != first.position or nan_none(self.sigma) != nan_none(first.sigma):
            raise ValueError(f"{where}: position and sigma must be those of the first tracked point ({first.tp})")
        for p in self.points:
            kept = sum(u for r, u in zip(self.readings, self.used, strict=True) if r.tp == p.tp)
            total = sum(r.tp == p.tp for r in self.readings)
            if p.samples != kept or p.samples + p.rejected != total:
                raise ValueError(f"{where}: tracked point {p.tp} has samples {p.samples} + rejected {p.rejected}; its "
                                 f"readings say {kept} of {total}")
        if any(r.tp not in ids for r in self.readings):
            raise ValueError(f"{where}: a reading's tracked point has no average in points")

    def positions(self) -> dict[int, tuple[tuple[float, float, float], float | None]]:
        """Tracked point id -> (averaged position m, sigma m or None) of every point seen (empty when missing)."""
        if self.points:
            return {p.tp: (p.position, p.sigma) for p in self.points}
        return {} if self.position is None else {1: (self.position, self.sigma)}

    @classmethod
    def from_step(cls, step: Step, **fields: Any) -> StepRecord:
        """A record of the plan ``step`` (index, kind, sweep, joint, role and, unless ``q_cmd`` is given (the
        readings commanded to a coupled robot), the commanded q taken from it)."""
        fields.setdefault("q_cmd", step.q)
        return cls(plan_index=step.index, kind=step.kind, sweep=step.sweep, joint=step.joint, role=step.role,
                   **fields)

    def _key(self) -> tuple[Any, ...]:
        readings = tuple((_floats(r.position), nan_none(r.timestamp), nan_none(r.sigma), r.status, r.tp,
                          _floats(r.rotvec), nan_none(r.sigma_r)) for r in self.readings)
        points = tuple((p.tp, _floats(p.position), nan_none(p.sigma), p.samples, p.rejected) for p in self.points)
        return (self.plan_index, self.kind, self.sweep, self.joint, self.role, _floats(self.q_cmd),
                _floats(self.q_act), _floats(self.position), nan_none(self.sigma), self.samples, self.rejected,
                self.status, self.reason, self.t_start, self.t_end, readings, self.used, points, self.frames,
                tuple((tp, json.dumps(c.as_dict())) for tp, c in self.corrections))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, StepRecord):
            return NotImplemented
        return self._key() == other._key()


def nan_none(v: float | None) -> float | None:
    """None for None or NaN (SQLite stores NaN as NULL), else the float."""
    return None if v is None or math.isnan(v) else float(v)


def _floats(values: Any) -> tuple[float | None, ...] | None:
    return None if values is None else tuple(nan_none(float(v)) for v in np.asarray(values, dtype=float).ravel())
