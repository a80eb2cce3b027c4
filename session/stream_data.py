"""Reading a session's streams back (continuous motion): the complete, current attempt of every stream step
recorded ok, as the samples and gaps of both devices (:class:`StreamData`); identify/io/session_measurements.py
turns them into measurement rows. session/streams.py writes them; the tables are in session/schema.py.

Units: metres, radians / metres, seconds (each device's own clock).
"""

from __future__ import annotations

import json
import sqlite3
from dataclasses import dataclass

import numpy as np

from session.plan import Plan
from session.schema import ORIENTATION_COLUMNS, columns


@dataclass(frozen=True)
class StreamData:
    """One recorded stream attempt read back: robot times ``t_joint`` (j,) and readings ``q_joint`` (j, n), tracker
    times ``t`` (k,), ``points`` (k, 3), ``tp`` (k,), ``sigma`` (k,) (NaN: none), gaps per device; a full-pose
    device's ``rotvec`` (k, 3) (the target frame's rotation vector in the tracker frame, rad) and ``sigma_r`` (k,)
    (rad), NaN where a sample has none (a file written before streamed samples had them: all NaN)."""

    plan_index: int
    sweep: int
    joint: int
    t_joint: np.ndarray
    q_joint: np.ndarray
    joint_gaps: tuple[tuple[float, float], ...]
    t: np.ndarray
    points: np.ndarray
    tp: np.ndarray
    sigma: np.ndarray
    tracker_gaps: tuple[tuple[float, float], ...]
    rotvec: np.ndarray | None = None
    sigma_r: np.ndarray | None = None


def current_streams(db: sqlite3.Connection, plan: Plan) -> list[StreamData]:
    """The complete, current attempt of every stream step recorded ok, in plan order."""
    tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    if "streams" not in tables:
        return []
    rows = db.execute("SELECT s.id, s.plan_index, s.sweep FROM streams s JOIN steps p ON p.plan_index = s.plan_index "
                      "WHERE s.status = 'complete' AND s.superseded = 0 AND p.status = 'ok' AND p.kind = 'stream' "
                      "ORDER BY s.plan_index").fetchall()
    n = len(plan.joint_types)
    turns = ", ".join(ORIENTATION_COLUMNS) if set(ORIENTATION_COLUMNS) <= columns(db, "tracker_samples") else \
        ", ".join(["NULL"] * len(ORIENTATION_COLUMNS))  # a file no writer of this version has opened yet
    out = []
    for stream, index, sweep in rows:
        joints = db.execute("SELECT t, q FROM joint_samples WHERE stream = ? ORDER BY t", (stream,)).fetchall()
        track = db.execute(f"SELECT t, x, y, z, tp, sigma, {turns} FROM tracker_samples WHERE stream = ? "
                           "ORDER BY t, tp", (stream,)).fetchall()
        gaps = db.execute("SELECT device, t_start, t_end FROM stream_gaps WHERE stream = ?", (stream,)).fetchall()
        t_joint = np.array([r[0] for r in joints], dtype=float)
        q_joint = np.array([[np.nan if v is None else v for v in json.loads(r[1])] for r in joints],
                           dtype=float).reshape(len(joints), n)
        data = np.array([[np.nan if v is None else v for v in r] for r in track], dtype=float).reshape(len(track), 10)
        out.append(StreamData(index, sweep, plan.steps[index].joint, t_joint, q_joint,
                              tuple((a, b) for d, a, b in gaps if d == "robot"), data[:, 0], data[:, 1:4],
                              data[:, 4].astype(np.int64), data[:, 5],
                              tuple((a, b) for d, a, b in gaps if d == "tracker"), data[:, 6:9], data[:, 9]))
    return out
