"""Where a result was fitted, and what it says about poses outside that.

A result records its ``domain``: the range of every DH joint value over its fit rows (rad, or m for a prismatic
joint). The accuracies it states hold inside it; a calibration used outside extrapolates whatever the data could
not pin down (joint errors above all). Every command that applies a result says how many of its poses lie
outside, by how much, and what is known there: the parameters' covariance propagated to those poses, which covers
the noise of the fit but not the errors the model cannot hold, so it is a lower bound, said as such.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from identify.applications.calibrated import CalibratedModel, ResultError

Array = NDArray[np.float64]

SLACK = 1e-9  # rad or m: a pose on the boundary is inside


@dataclass(frozen=True)
class Outside:
    """Poses outside a result's domain: ``count`` of ``total``; ``worst`` (n,) the largest distance beyond the
    range per joint (rad or m, 0 inside); ``joint_types`` to say it in degrees or mm; ``inside_rms``,
    ``outside_rms`` (m): the predicted 3D standard uncertainty from the parameters' covariance, RMS over the poses
    inside and outside (None when not computed)."""

    count: int
    total: int
    worst: Array
    joint_types: str
    inside_rms: float | None = None
    outside_rms: float | None = None

    def as_dict(self) -> dict[str, Any]:
        return {"poses_outside": self.count, "poses": self.total,
                "beyond_by_joint": [float(v) for v in self.worst],
                "covariance_rms_inside": self.inside_rms, "covariance_rms_outside": self.outside_rms}

    def text(self) -> str:
        """One line: how many poses lie outside, the joints that leave it most, and what is known there."""
        if self.count == 0:
            return f"all {self.total} poses lie inside the result's fitted joint ranges (its domain)"
        joints = [j for j in np.argsort(-self.worst) if self.worst[j] > 0][:3]
        far = ", ".join(f"joint {j + 1} by {_amount(self.worst[j], self.joint_types[j])}" for j in joints)
        known = ("" if self.outside_rms is None else
                 f"; there the parameters' covariance gives {self.outside_rms * 1e3:.3g} mm RMS"
                 + ("" if self.inside_rms is None else f" (inside: {self.inside_rms * 1e3:.3g} mm)")
                 + ", a lower bound: errors the model cannot hold are not known outside the data")
        return (f"{self.count} of {self.total} poses lie outside the result's fitted joint ranges (its domain; "
                f"farthest: {far}): the stated accuracy holds inside it{known}")


def _amount(value: float, kind: str) -> str:
    return f"{math.degrees(value):.3g} deg" if kind == "R" else f"{value * 1e3:.3g} mm"


def domain_to_dict(domain: Array | None) -> dict[str, Any] | None:
    """The result YAML's ``domain`` section."""
    if domain is None:
        return None
    return {"joints": [[None if not np.isfinite(v) else float(v) for v in row] for row in domain],
            "note": "range of each DH joint value over the fit rows (rad; m for prismatic joints): the stated "
                    "accuracies hold inside it"}


def domain_from_document(doc: dict[str, Any]) -> Array | None:
    """The domain (n, 2) a result document records (None for results written before it, or a malformed one;
    NaN for a joint with no range)."""
    section = doc.get("domain") if isinstance(doc, dict) else None
    rows = section.get("joints") if isinstance(section, dict) else None
    if not isinstance(rows, list):
        return None
    try:
        out = np.array([[np.nan if v is None else float(v) for v in row] for row in rows], dtype=float)
    except (TypeError, ValueError):
        return None
    return out if out.ndim == 2 and out.shape[1] == 2 else None


def outside(domain: Array, q: Array, joint_types: str, rms_at: Callable[[Array], float] | None = None) -> Outside:
    """Which of the DH joint values ``q`` (k, n) lie outside ``domain`` (n, 2), and how far per joint; with
    ``rms_at(q_rows)`` (the predicted 3D standard uncertainty, m, RMS over those rows) what is known inside and
    outside."""
    q = np.asarray(q, dtype=float)
    with np.errstate(invalid="ignore"):
        beyond = np.fmax(np.fmax(domain[:, 0] - q, q - domain[:, 1]), 0.0)  # NaN (no range, unread): inside
    beyond = np.where(np.isfinite(beyond) & (beyond > SLACK), beyond, 0.0)
    out = np.any(beyond > 0.0, axis=1)
    worst = beyond.max(axis=0) if len(q) else np.zeros(domain.shape[0])
    inside_rms = outside_rms = None
    if rms_at is not None:
        inside_rms = float(rms_at(q[~out])) if np.any(~out) else None
        outside_rms = float(rms_at(q[out])) if np.any(out) else None
    return Outside(int(out.sum()), len(q), worst, joint_types, inside_rms, outside_rms)


def result_outside(doc: dict[str, Any], q: Array) -> tuple[Outside | None, str]:
    """The poses at controller readings ``q`` (k, n) against the domain of result ``doc`` (its recommended
    model's covariance for what is known there), and one line saying it (for results that record no domain,
    that they do not)."""
    domain = domain_from_document(doc)
    if domain is None:
        return None, "the result records no domain (written before results did): where it holds is not known"
    try:
        model = CalibratedModel.from_document(doc)
    except ResultError:
        model = None
    q = np.asarray(q, dtype=float)
    if domain.shape[0] != q.shape[1]:
        return None, f"the result's domain has {domain.shape[0]} joints, the poses {q.shape[1]}: not compared"
    q_dh = q if model is None else model.dh_values(q)
    types = "".join(j.get("type", "R") if isinstance(j, dict) else "R" for j in doc.get("joints") or [])
    types = types if len(types) == q.shape[1] else "R" * q.shape[1]

    def rms_at(rows: Array) -> float:
        cov = model.point_covariances(model.readings(rows))  # type: ignore[union-attr]
        return float(np.sqrt(np.mean(np.trace(cov, axis1=1, axis2=2))))

    found = outside(domain, q_dh, types, None if model is None or model.covariance is None else rms_at)
    return found, found.text()
