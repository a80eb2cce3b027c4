"""A session file's rows read back: step records, per-point averages, measurements and drift.

Works on an open ``sqlite3`` connection to a session file (session/schema.py), of any version this one
reads: files without the ``tp`` column or the ``step_points`` table are read as if every reading saw tracked
point 1. Units: metres (positions, sigma), radians / metres (joint readings), seconds since the epoch (times).
"""

from __future__ import annotations

import sqlite3
from typing import Any

import numpy as np

from drivers.base import TrackerReading
from identify.measurements import Measurements
from kinematics.joint_errors import Coupling
from session.records import PointRecord
from session.schema import STEP_COLUMNS, columns, load_q, nan_of


def coupling_of(header: dict[str, Any]) -> Coupling | None:
    """The coupling a session ``header`` records (DH joint values = matrix · readings + offset), or None: its
    readings are the DH joint values."""
    value = header.get("coupling")
    if not value:
        return None
    return Coupling(np.array(value["matrix"], dtype=float), np.array(value["offset"], dtype=float))


def step_rows(db: sqlite3.Connection, where: str = "") -> list[dict[str, Any]]:
    """Step columns (no readings) as StepRecord keyword arguments, in plan order."""
    cur = db.execute(f"SELECT {', '.join(STEP_COLUMNS)} FROM steps {where} ORDER BY plan_index")
    out = []
    for values in cur:
        row = dict(zip(STEP_COLUMNS, values, strict=True))
        x, y, z = row.pop("x"), row.pop("y"), row.pop("z")
        row.update(q_cmd=load_q(row["q_cmd"]), q_act=load_q(row["q_act"]),
                   position=None if x is None else (x, y, z))
        out.append(row)
    return out


def reading_rows(db: sqlite3.Connection) -> dict[int, list[tuple[TrackerReading, bool]]]:
    """Plan index -> every raw reading of the step with its ``used`` flag, in the order recorded."""
    tp = "tp" if "tp" in columns(db, "readings") else "1"
    out: dict[int, list[tuple[TrackerReading, bool]]] = {}
    for i, x, y, z, sigma, t, status, used, point in db.execute(
            f"SELECT plan_index, x, y, z, sigma, t, status, used, {tp} FROM readings ORDER BY id"):
        reading = TrackerReading(np.array([nan_of(x), nan_of(y), nan_of(z)]), nan_of(t), sigma, status, int(point))
        out.setdefault(i, []).append((reading, bool(used)))
    return out


def point_rows(db: sqlite3.Connection) -> dict[int, list[PointRecord]]:
    """Plan index -> the per-point averages of a step that saw several tracked points, ascending ids."""
    if not columns(db, "step_points"):
        return {}
    out: dict[int, list[PointRecord]] = {}
    for i, tp, x, y, z, sigma, samples, rejected in db.execute(
            "SELECT plan_index, tp, x, y, z, sigma, samples, rejected FROM step_points ORDER BY plan_index, tp"):
        out.setdefault(i, []).append(PointRecord(tp, (x, y, z), sigma, samples, rejected))
    return out


def _seen(row: dict[str, Any], points: dict[int, list[PointRecord]]) -> list[tuple[int, tuple[float, ...],
                                                                                    float | None]]:
    """(tp, position, sigma) of every point an ok step saw."""
    several = points.get(row["plan_index"])
    if several:
        return [(p.tp, p.position, p.sigma) for p in several]
    return [(1, row["position"], row["sigma"])]


def measurements_from(rows: list[dict[str, Any]], points: dict[int, list[PointRecord]], joint_types: str,
                      coupling: Coupling | None) -> Measurements:
    """The measurement-CSV rows of ok step ``rows`` (plan order): one row per tracked point seen, q = the actual
    readings, ``coupling`` as recorded. Home re-measurements become held-out free poses (joint 0, role check);
    ``sigma`` only when every row has one; ``tp`` the point's id."""
    entries = [(r, *seen) for r in rows for seen in _seen(r, points)]
    n, m = len(joint_types), len(entries)
    q = np.array([r["q_act"] for r, *_ in entries], dtype=float).reshape(m, n)
    xyz = np.array([p for _, _, p, _ in entries], dtype=float).reshape(m, 3)
    home = np.array([r["kind"] == "home" for r, *_ in entries], dtype=bool)
    joint = np.where(home, 0, np.array([r["joint"] for r, *_ in entries], dtype=np.int64)).astype(np.int64)
    sweep = np.array([r["sweep"] for r, *_ in entries], dtype=np.int64)
    check = home | np.array([r["role"] == "check" for r, *_ in entries], dtype=bool)
    sigmas = [s for *_, s in entries]
    sigma = np.array(sigmas, dtype=float) if entries and None not in sigmas else None
    tp = np.array([t for _, t, _, _ in entries], dtype=np.int64)
    return Measurements(joint_types, q, xyz, sweep, joint, sigma, check, has_role=True, tp=tp, coupling=coupling)


def drift_from(homes: list[dict[str, Any]], points: dict[int, list[PointRecord]]) -> list[tuple[float, float]]:
    """Home re-measurements (ok home step rows) as (t, displacement): t = the step's end time (s), displacement
    = the mean distance (m) of its tracked points from where each was first seen at home (the first one: 0)."""
    first: dict[int, Any] = {}
    out = []
    for row in homes:
        seen = _seen(row, points)
        gaps = [float(np.linalg.norm(np.array(p) - first[tp])) for tp, p, _ in seen if tp in first]
        for tp, p, _ in seen:
            first.setdefault(tp, np.array(p))
        if gaps or not out:
            out.append((row["t_end"], float(np.mean(gaps)) if gaps else 0.0))
    return out
