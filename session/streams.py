"""A session's streams (continuous motion): writing a stream step's samples in batches, and reading them back as
measurement rows.

The tables are in session/schema.py. Writing (:class:`StreamRecorder`): an attempt of a stream step is a
``streams`` row (status ``recording``); its samples and gaps are committed in batches (the orchestrator's stream
loop commits at least every second, so a crash loses at most the last second); the attempt then ends
``complete`` or ``interrupted``. A new attempt of the same step supersedes the earlier ones: their samples stay
in the file but are never read as measurements.

Reading (:func:`with_streams`): every complete, current attempt whose stream step is recorded ok becomes rows:
one per tracker sample (each tracked point), ``t`` its tracker time, ``q`` the joint stream interpolated
(linearly) at robot time ``t + clock_offset``; ``clock_offset`` is the coarse estimate of
:func:`identify.timing.coarse_clock_offset` over all the session's sweeps. Rows whose robot time lies outside
the recorded joint stream or within one sample of a joint-stream gap are dropped (counted). Units: metres,
radians / metres, seconds (each device's own clock for samples; the host's for batches).
"""

from __future__ import annotations

import json
import sqlite3
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from acquire.plan import Plan
from drivers.base import JointStreamBatch, TrackerStreamBatch
from identify.measurements import Measurements
from identify.timing import SweepStreams, coarse_clock_offset, interpolate_joints
from session.schema import dump_q

if TYPE_CHECKING:
    from session.store import Session


class StreamRecorder:
    """Writes one attempt of the stream step ``plan_index`` of an open (writable) ``session`` with a run going."""

    def __init__(self, session: Session, plan_index: int, started: float) -> None:
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


@dataclass(frozen=True)
class StreamSummary:
    """What the export did with the streams: the clock offset (s, robot = tracker + offset) and each sweep's own
    estimate, tracker rows kept and dropped (outside the joint stream or at a joint-stream gap), gaps seen."""

    clock_offset: float
    per_sweep: tuple[float, ...]
    kept: int
    dropped: int
    gaps: int

    def line(self) -> str:
        spread = np.array(self.per_sweep, dtype=float)
        spread = spread[np.isfinite(spread)]
        span = f" (sweeps {1e3 * spread.min():.2f} .. {1e3 * spread.max():.2f} ms)" if spread.size > 1 else ""
        return (f"streams: {self.kept} streamed rows, {self.dropped} dropped (outside the joint stream or at one of "
                f"{self.gaps} gaps); coarse clock offset {1e3 * self.clock_offset:.2f} ms{span}")


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


def with_streams(db: sqlite3.Connection, plan: Plan, steps: Measurements) -> tuple[Measurements, StreamSummary | None]:
    """``steps`` (the stop-and-go rows) followed by the streamed rows of every current stream (module docstring),
    with the session's coarse clock offset; the summary is None when there is no stream to read."""
    streams = [s for s in current_streams(db, plan) if len(s.t) and len(s.t_joint) >= 2]
    if not streams:
        return steps, None
    first = [s.tp == s.tp.min() for s in streams]
    estimate = coarse_clock_offset([SweepStreams(s.t[k], s.points[k], s.t_joint, s.q_joint)
                                    for s, k in zip(streams, first, strict=True)])
    offset = estimate.offset
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("q", "points", "sweep", "joint", "sigma", "tp", "t")}
    dropped = 0
    for s in streams:
        q, ok = interpolate_joints(s.t_joint, s.q_joint, s.t + offset, s.joint_gaps)
        dropped += int((~ok).sum())
        parts["q"].append(q[ok])
        parts["points"].append(s.points[ok])
        parts["sweep"].append(np.full(int(ok.sum()), s.sweep, dtype=np.int64))
        parts["joint"].append(np.full(int(ok.sum()), s.joint, dtype=np.int64))
        parts["sigma"].append(s.sigma[ok])
        parts["tp"].append(s.tp[ok])
        parts["t"].append(s.t[ok])
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    m0, m1 = len(steps), len(cat["t"])
    sigma = None
    if steps.sigma is not None or m0 == 0:
        joined = np.concatenate([steps.sigma if steps.sigma is not None else np.zeros(0), cat["sigma"]])
        sigma = None if np.any(np.isnan(joined)) else joined
    t_steps = steps.t if steps.t is not None else np.full(m0, np.nan)
    meas = replace(steps, q=np.vstack([steps.q, cat["q"]]), points=np.vstack([steps.points, cat["points"]]),
                   sweep=np.concatenate([steps.sweep, cat["sweep"]]), joint=np.concatenate([steps.joint, cat["joint"]]),
                   sigma=sigma, check=np.concatenate([steps.check, np.zeros(m1, dtype=bool)]),
                   row=np.arange(1, m0 + m1 + 1), tp=np.concatenate([steps.tp, cat["tp"]]),
                   t=np.concatenate([t_steps, cat["t"]]),
                   streamed=np.concatenate([np.zeros(m0, bool), np.ones(m1, bool)]),
                   clock_offset=offset)
    gaps = sum(len(s.joint_gaps) + len(s.tracker_gaps) for s in streams)
    return meas, StreamSummary(offset, estimate.per_sweep, m1, dropped, gaps)


def stream_summary(session: Session) -> StreamSummary | None:
    """What :func:`with_streams` makes of ``session``'s streams (None without any)."""
    from session.rows import measurements_from, point_rows, step_rows

    steps = measurements_from(step_rows(session._db, "WHERE status = 'ok' AND kind != 'stream'"),
                              point_rows(session._db), session.plan.joint_types, session.coupling)
    return with_streams(session._db, session.plan, steps)[1]
