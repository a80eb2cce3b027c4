"""A session file's rows: step records written and read back, per-point averages and drift; and the header
fields that need reading (the coupling, the controller's factory calibration). The measurements made of these rows
are identify's (identify/io/session_measurements.py).

Works on an open ``sqlite3`` connection to a session file (session/schema.py), of any version this one
reads: files without the ``tp`` column or the ``step_points`` table are read as if every reading saw tracked
point 1. Units: metres (positions, sigma), radians / metres (joint readings), seconds since the epoch (times).
"""

from __future__ import annotations

import json
import sqlite3
from typing import Any

import numpy as np

from drivers.base import Correction, TrackerReading
from kinematics.joint_errors import Coupling
from session.records import FrameRecord, PointRecord, StepRecord
from session.schema import ORIENTATION_COLUMNS, STEP_COLUMNS, SessionError, columns, dump_q, load_q, nan_of


def insert_step(db: sqlite3.Connection, record: StepRecord, readings: list[tuple[Any, ...]], run_id: int) -> None:
    """Insert ``record``, the rows of its raw ``readings`` (``readings`` table columns) and its per-point averages,
    recorded in run ``run_id`` (inside the caller's transaction)."""
    i = record.plan_index
    x, y, z = record.position if record.position is not None else (None, None, None)
    db.execute(
        "INSERT INTO steps (plan_index, kind, sweep, joint, role, q_cmd, q_act, x, y, z, sigma, samples,"
        " rejected, status, reason, t_start, t_end, run_id) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?,"
        " ?, ?, ?, ?, ?)",
        (i, record.kind, record.sweep, record.joint, record.role, dump_q(record.q_cmd),
         dump_q(record.q_act), x, y, z, record.sigma, record.samples, record.rejected, record.status,
         record.reason, record.t_start, record.t_end, run_id))
    db.executemany("INSERT INTO readings (plan_index, x, y, z, sigma, t, status, used, tp, rx, ry, rz, sigma_r)"
                   " VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", readings)
    db.executemany("INSERT INTO step_points (plan_index, tp, x, y, z, sigma, samples, rejected)"
                   " VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                   [(i, p.tp, *p.position, p.sigma, p.samples, p.rejected) for p in record.points])
    db.executemany("INSERT INTO step_orientations (plan_index, tp, rx, ry, rz, sigma_r) VALUES (?, ?, ?, ?, ?, ?)",
                   [(i, f.tp, *f.rotvec, f.sigma_r) for f in record.frames])
    db.executemany("INSERT INTO step_corrections (plan_index, tp, correction) VALUES (?, ?, ?)",
                   [(i, tp, json.dumps(c.as_dict())) for tp, c in record.corrections])


def retire_step(db: sqlite3.Connection, plan_index: int) -> None:
    """Move step ``plan_index`` and its readings to ``retired_steps``/``retired_readings`` as its next attempt
    (1, 2, ...), leaving its place free (inside the caller's transaction)."""
    i = plan_index
    names = ", ".join(STEP_COLUMNS)
    attempt = 1 + db.execute("SELECT count(*) FROM retired_steps WHERE plan_index = ?", (i,)).fetchone()[0]
    db.execute(f"INSERT INTO retired_steps (attempt, run_id, {names}) SELECT ?, run_id, {names}"
               " FROM steps WHERE plan_index = ?", (attempt, i))
    db.execute("INSERT INTO retired_readings (plan_index, attempt, x, y, z, sigma, t, status, used, tp, rx, ry, rz,"
               " sigma_r) SELECT plan_index, ?, x, y, z, sigma, t, status, used, tp, rx, ry, rz, sigma_r FROM readings"
               " WHERE plan_index = ? ORDER BY id", (attempt, i))
    db.execute("DELETE FROM step_orientations WHERE plan_index = ?", (i,))
    db.execute("DELETE FROM step_corrections WHERE plan_index = ?", (i,))
    db.execute("DELETE FROM readings WHERE plan_index = ?", (i,))
    db.execute("DELETE FROM steps WHERE plan_index = ?", (i,))


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
    have = columns(db, "readings")
    tp = "tp" if "tp" in have else "1"
    turn = ", ".join(name if name in have else "NULL" for name in ORIENTATION_COLUMNS)
    out: dict[int, list[tuple[TrackerReading, bool]]] = {}
    for i, x, y, z, sigma, t, status, used, point, rx, ry, rz, sigma_r in db.execute(
            f"SELECT plan_index, x, y, z, sigma, t, status, used, {tp}, {turn} FROM readings ORDER BY id"):
        rotvec = None if rx is None else np.array([rx, ry, rz], dtype=float)
        reading = TrackerReading(np.array([nan_of(x), nan_of(y), nan_of(z)]), nan_of(t), sigma, status, int(point),
                                 rotvec, sigma_r)
        out.setdefault(i, []).append((reading, bool(used)))
    return out


def frame_rows(db: sqlite3.Connection) -> dict[int, list[FrameRecord]]:
    """Plan index -> the averaged target-frame orientations of a step measured by a full-pose device, ascending ids
    (empty for files without them)."""
    if not columns(db, "step_orientations"):
        return {}
    out: dict[int, list[FrameRecord]] = {}
    for i, tp, rx, ry, rz, sigma_r in db.execute(
            "SELECT plan_index, tp, rx, ry, rz, sigma_r FROM step_orientations ORDER BY plan_index, tp"):
        out.setdefault(i, []).append(FrameRecord(tp, (rx, ry, rz), sigma_r))
    return out


def correction_rows(db: sqlite3.Connection) -> dict[int, list[tuple[int, Correction]]]:
    """Plan index -> (tracked point id, its readings' correction) of a step measured by a camera that corrects for
    its board's shape and its lens, ascending ids (empty for files without them)."""
    if not columns(db, "step_corrections"):
        return {}
    out: dict[int, list[tuple[int, Correction]]] = {}
    for i, tp, text in db.execute("SELECT plan_index, tp, correction FROM step_corrections ORDER BY plan_index, tp"):
        try:
            out.setdefault(i, []).append((tp, Correction.from_dict(json.loads(text))))
        except (ValueError, KeyError, TypeError) as exc:  # json's errors are ValueErrors
            raise SessionError(f"step {i}: its camera correction is unreadable ({type(exc).__name__}: {exc}); the "
                               "file was changed by something other than dh-calib") from None
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


def spread_sigmas(db: sqlite3.Connection) -> set[tuple[int, int]]:
    """(plan index, tracked point) of every step average whose ``sigma`` is the spread of its own kept readings: none
    of them carried a device sigma (an I++ server, a profile without one), so the orchestrator estimated it."""
    tp = "tp" if "tp" in columns(db, "readings") else "1"
    return {(int(i), int(t)) for i, t in db.execute(
        f"SELECT plan_index, {tp} FROM readings WHERE used = 1 GROUP BY plan_index, {tp} HAVING count(sigma) = 0")}


def points_seen(row: dict[str, Any],
                points: dict[int, list[PointRecord]]) -> list[tuple[int, tuple[float, ...], float | None]]:
    """(tp, position, sigma) of every point an ok step saw."""
    several = points.get(row["plan_index"])
    if several:
        return [(p.tp, p.position, p.sigma) for p in several]
    return [(1, row["position"], row["sigma"])]


def drift_from(homes: list[dict[str, Any]], points: dict[int, list[PointRecord]]) -> list[tuple[float, float]]:
    """Home re-measurements (ok home step rows) as (t, displacement): t = the step's end time (s), displacement
    = the mean distance (m) of its tracked points from where each was first seen at home (the first one: 0)."""
    first: dict[int, Any] = {}
    out = []
    for row in homes:
        seen = points_seen(row, points)
        gaps = [float(np.linalg.norm(np.array(p) - first[tp])) for tp, p, _ in seen if tp in first]
        for tp, p, _ in seen:
            first.setdefault(tp, np.array(p))
        if gaps or not out:
            out.append((row["t_end"], float(np.mean(gaps)) if gaps else 0.0))
    return out


def factory_calibration(header: dict[str, Any]) -> tuple[dict[str, Any] | None, str]:
    """The robot controller's factory calibration recorded in a session ``header`` (the robot identity's
    ``details.factory_calibration``: JSON of UR's DH values, or ``unavailable (reason)``), and a note saying
    why there is none. Robots that have none to report (simulated ones, other makes) and sessions older than
    this field give (None, "")."""
    text = ((header.get("robot") or {}).get("details") or {}).get("factory_calibration")
    if text is None:
        return None, ""
    try:
        value = json.loads(text)
    except (TypeError, ValueError):
        return None, f"the factory calibration could not be read from the controller: {text}"
    if not isinstance(value, dict):
        return None, f"the recorded factory calibration is not a table: {text[:80]}"
    return value, ""
