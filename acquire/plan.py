"""The acquisition plan: what to move where, decided before anything moves (pure, no devices).

A plan is an ordered list of steps. Sweeps move one joint through increments with the others at home
(last joint first, as in the paper); free poses move every joint (extra data for the fit and for
validation); home checks return to the home pose every N steps to watch the tracker/robot drift.
Joint values: rad (revolute) / m (prismatic).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any

STEP_KINDS = ("sweep", "free", "home")


@dataclass(frozen=True)
class Step:
    """One commanded pose. ``index`` is its 0-based place in the plan; ``sweep`` the CSV sweep id;
    ``joint`` the 1-based joint a sweep moves (0 for free poses and home checks); ``q`` the commanded
    joint values; ``role`` is "fit" or "check" (held out for validation)."""

    index: int
    kind: str
    sweep: int
    joint: int
    q: tuple[float, ...]
    role: str = "fit"


@dataclass(frozen=True)
class Plan:
    """Everything the orchestrator needs to run, and that the session stores to resume.

    ``speed`` (rad/s or m/s) and ``acceleration`` per joint; ``settle_time`` s to wait still before
    measuring; ``samples_per_step`` tracker readings averaged per step.
    """

    robot: str
    joint_types: str
    home: tuple[float, ...]
    steps: tuple[Step, ...]
    samples_per_step: int = 5
    settle_time: float = 0.5
    speed: tuple[float, ...] = ()
    acceleration: tuple[float, ...] = ()
    notes: tuple[str, ...] = field(default_factory=tuple)

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_json(cls, text: str) -> Plan:
        data: dict[str, Any] = json.loads(text)
        steps = tuple(Step(**{**s, "q": tuple(s["q"])}) for s in data.pop("steps"))
        tuples = {k: tuple(data[k]) for k in ("home", "speed", "acceleration", "notes")}
        return cls(steps=steps, **{**data, **tuples})
