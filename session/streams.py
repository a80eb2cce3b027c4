"""A session's streams (continuous motion): writing a stream step's samples in batches, and reading them back.

The tables are in session/schema.py. Writing (:class:`StreamRecorder`): an attempt of a stream step is a
``streams`` row (status ``recording``); its samples and gaps are committed in batches (the orchestrator's stream
loop commits at least every second, so a crash loses at most the last second); the attempt then ends
``complete`` or ``interrupted``. A new attempt of the same step supersedes the earlier ones: their samples stay
in the file but are never read as measurements.

Reading (:func:`current_streams`): the complete, current attempt of every stream step recorded ok, as the samples
and gaps of both devices (:class:`StreamData`); identify/io/session_measurements.py turns them into measurement
rows. Units: metres, radians / metres, seconds (each device's own clock for samples; the host's for batches).
"""

from __future__ import annotations

import json
import sqlite3
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from drivers.base import JointStreamBatch, TrackerStreamBatch
from session.plan import Plan
from session.schema import dump_q

if TYPE_CHECKING:
    from session.store import SessionFile


class StreamRecorder:
    """Writes one attempt of the stream step ``plan_index`` of an open (writable) ``session`` with a run going."""

    def __init__(self, session: SessionFile, plan_index: int, started: float) -> None:
        self.session = session
        step = session.plan.steps[plan_index]
        with session._transaction(f"start the stream of step {plan_index}"):
            db = session._db
            attempt = 1 + db.execute("SELECT count(*) FROM streams WHERE plan_index = ?", (plan_index,)).fetchone()[0]
            db.execute("UPDATE streams SET superseded = 1 WHERE plan_index = ?", (plan_index,))
            db.execute("UPDATE streams SET status = 'interrupted', reason = 'the process ended while recording' "
                       "WHERE plan_index = ? AND status = 'recording'", (plan_index,))
            cur = db.execute("INSERT INTO streams (plan_index, sweep, attempt, run_id, status, started) VALUES "
                             "(?, ?, ?, ?, 'recording', ?)",
                             (plan_index, step.sweep, attempt, session._run_id, started))
        self.id, self.attempt, self.plan_index = int(cur.lastrowid), attempt, plan_index
        self.joint_samples = self.tracker_samples = 0

    def set_rates(self, joint_rate: float, tracker_rate: float) -> None:
        with self.session._transaction("record the stream rates"):
            self.session._db.execute("UPDATE streams SET joint_rate = ?, tracker_rate = ? WHERE id = ?",
                                     (joint_rate, tracker_rate, self.id))

    def commit(self, joints: list[JointStreamBatch], trackers: list[TrackerStreamBatch], now: float) -> None:
        """Store the batches' samples and gaps in one transaction (durable when this returns); ``now`` the host
        clock's time (s), recorded with the batch counts."""
        rows_j = [(self.id, float(t), dump_q(q.tolist())) for b in joints for t, q in zip(b.t, b.q, strict=True)]
        rows_t = [(self.id, float(t), *map(float, p), int(tp), None if np.isnan(s) else float(s))
                  for b in trackers for t, p, tp, s in zip(b.t, b.points, b.tp, b.sigma, strict=True)]
        gaps = [(self.id, "robot", float(a), float(b)) for batch in joints for a, b in batch.gaps]
        gaps += [(self.id, "tracker", float(a), float(b)) for batch in trackers for a, b in batch.gaps]
        with self.session._transaction(f"record stream samples of step {self.plan_index}"):
            db = self.session._db
            db.executemany("INSERT INTO joint_samples (stream, t, q) VALUES (?, ?, ?)", rows_j)
            db.executemany("INSERT INTO tracker_samples (stream, t, x, y, z, tp, sigma) VALUES (?, ?, ?, ?, ?, ?, ?)",
                           rows_t)
            db.executemany("INSERT INTO stream_gaps (stream, device, t_start, t_end) VALUES (?, ?, ?, ?)", gaps)
            db.execute("INSERT INTO stream_batches (stream, t, joint_samples, tracker_samples) VALUES (?, ?, ?, ?)",
                       (self.id, now, len(rows_j), len(rows_t)))
        self.joint_samples += len(rows_j)
        self.tracker_samples += len(rows_t)

    def end(self, status: str, reason: str, now: float) -> None:
        """End the attempt: ``complete`` or ``interrupted`` (with the reason)."""
        with self.session._transaction("end the stream"):
            self.session._db.execute("UPDATE streams SET status = ?, reason = ?, ended = ? WHERE id = ?",
                                     (status, " ".join(reason.split()), now, self.id))


@dataclass(frozen=True)
class StreamData:
    """One recorded stream attempt read back: robot times ``t_joint`` (j,) and readings ``q_joint`` (j, n), tracker
    times ``t`` (k,), ``points`` (k, 3), ``tp`` (k,), ``sigma`` (k,) (NaN: none), gaps per device."""

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


def current_streams(db: sqlite3.Connection, plan: Plan) -> list[StreamData]:
    """The complete, current attempt of every stream step recorded ok, in plan order."""
    tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    if "streams" not in tables:
        return []
    rows = db.execute("SELECT s.id, s.plan_index, s.sweep FROM streams s JOIN steps p ON p.plan_index = s.plan_index "
                      "WHERE s.status = 'complete' AND s.superseded = 0 AND p.status = 'ok' AND p.kind = 'stream' "
                      "ORDER BY s.plan_index").fetchall()
    n = len(plan.joint_types)
    out = []
    for stream, index, sweep in rows:
        joints = db.execute("SELECT t, q FROM joint_samples WHERE stream = ? ORDER BY t", (stream,)).fetchall()
        track = db.execute("SELECT t, x, y, z, tp, sigma FROM tracker_samples WHERE stream = ? ORDER BY t, tp",
                           (stream,)).fetchall()
        gaps = db.execute("SELECT device, t_start, t_end FROM stream_gaps WHERE stream = ?", (stream,)).fetchall()
        t_joint = np.array([r[0] for r in joints], dtype=float)
        q_joint = np.array([[np.nan if v is None else v for v in json.loads(r[1])] for r in joints],
                           dtype=float).reshape(len(joints), n)
        data = np.array([[np.nan if v is None else v for v in r] for r in track], dtype=float).reshape(len(track), 6)
        out.append(StreamData(index, sweep, plan.steps[index].joint, t_joint, q_joint,
                              tuple((a, b) for d, a, b in gaps if d == "robot"), data[:, 0], data[:, 1:4],
                              data[:, 4].astype(np.int64), data[:, 5],
                              tuple((a, b) for d, a, b in gaps if d == "tracker")))
    return out
