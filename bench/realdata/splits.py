"""Which rows of a set fit and which check: the set's fixed split, and region splits (fit one part of the joint
space, check the other).

A split is the fit session with its ``role`` column set (fit / check) and the later sessions to score the fitted
models on (all their rows check, re-registered by the bench). Region splits hold out the fit session's rows whose
DH value of one joint lies above that joint's median over the session (ties fit), so the check rows lie outside
the range the fit saw for that joint: the models extrapolate there, as a calibration used in another part of
the workspace does. Later sessions are scored only on the fixed split (their poses are not in either region).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from bench.realdata.common import Converted


@dataclass
class Split:
    """``name`` as printed, ``slug`` for file names; ``data`` the fit session with its roles; ``sessions``
    {name: later session}."""

    name: str
    slug: str
    data: Converted
    sessions: dict[str, Converted]


def fixed(data: Converted, sessions: dict[str, Converted]) -> Split:
    """The set's own split (its converter's roles) and its later sessions."""
    return Split("fixed", "fixed", data, sessions)


def region(data: Converted, joint: int) -> Split:
    """Fit the rows whose DH value of ``joint`` (1-based) is at most its median, check the rest."""
    values = data.dh_values()[:, joint - 1]
    median = float(np.median(values))
    unit, scale = ("deg", np.degrees(1.0)) if data.joints[joint - 1] == "R" else ("mm", 1e3)
    name = f"region: fit q{joint} <= {median * scale:.1f} {unit}, check above"
    return Split(name, f"region-q{joint}", replace(data, check=values > median), {})
