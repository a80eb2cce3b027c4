"""The plan as a session stores it: its steps and settings, and their JSON (the session header's ``plan``). Data
only: building and checking plans is acquire's (acquire/planning/plan.py, acquire/planning/plan_continuous.py; the Plan
JSON of ``acquire --dry-run --json``: acquire/planning/plan_report.py).

Joint values: rad (revolute) / m (prismatic); speeds rad/s or m/s, accelerations rad/s² or m/s²; times s.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any

#: verify: acquire/verification/verify.py; stream: acquire/planning/plan_continuous.py
STEP_KINDS = ("sweep", "free", "home", "verify", "stream")


@dataclass(frozen=True)
class Step:
    """One commanded pose. ``index`` is its 0-based place in the plan; ``sweep`` the CSV sweep id;
    ``joint`` the 1-based joint a sweep moves (0 for free poses and home checks); ``q`` the commanded
    joint values; ``role`` is "fit" or "check" (held out for validation). A ``stream`` step (continuous motion,
    acquire/planning/plan_continuous.py) moves ``joint`` from ``start`` to ``q`` at the constant ``speed`` (rad/s or
    m/s), ramping at ``acceleration`` (rad/s², m/s²), while both devices stream; other steps have none of the three
    (and their JSON none of the keys)."""

    index: int
    kind: str
    sweep: int
    joint: int
    q: tuple[float, ...]
    role: str = "fit"
    start: tuple[float, ...] | None = None
    speed: float | None = None
    acceleration: float | None = None


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
        data = asdict(self)
        for step in data["steps"]:  # a stop-and-go plan reads as it always did
            for key in ("start", "speed", "acceleration"):
                if step[key] is None:
                    del step[key]
        return json.dumps(data)

    @property
    def continuous(self) -> bool:
        """True when some steps are streamed (continuous motion)."""
        return any(s.kind == "stream" for s in self.steps)

    @classmethod
    def from_json(cls, text: str) -> Plan:
        data: dict[str, Any] = json.loads(text)
        steps = tuple(Step(**{**s, "q": tuple(s["q"]), **({"start": tuple(s["start"])} if s.get("start") else {})})
                      for s in data.pop("steps"))
        tuples = {k: tuple(data[k]) for k in ("home", "speed", "acceleration", "notes")}
        return cls(steps=steps, **{**data, **tuples})
