"""A session's streams (continuous motion): writing a stream step's samples in batches, and the attempt's last
position (the step's record).

The tables are in session/schema.py. Writing (:class:`StreamRecorder`): an attempt of a stream step is a
``streams`` row (status ``recording``); its samples and gaps are committed in batches (the orchestrator's stream
loop commits at least every second, so a crash loses at most the last second); the attempt then ends
``complete`` or ``interrupted``. A new attempt of the same step supersedes the earlier ones: their samples stay
in the file but are never read as measurements.

Reading them back (:class:`StreamData`, :func:`current_streams`) is session/stream_data.py's job. Units: metres,
radians / metres, seconds (each device's own clock for samples; the host's for batches).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from drivers.base import JointStreamBatch, TrackerStreamBatch
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
        rows_t = [(self.id, float(t), *map(float, p), int(tp), _value(s), *map(_value, r))
                  for b in trackers for t, p, tp, s, r in zip(b.t, b.points, b.tp, b.sigma, _turns(b), strict=True)]
        gaps = [(self.id, "robot", float(a), float(b)) for batch in joints for a, b in batch.gaps]
        gaps += [(self.id, "tracker", float(a), float(b)) for batch in trackers for a, b in batch.gaps]
        with self.session._transaction(f"record stream samples of step {self.plan_index}"):
            db = self.session._db
            db.executemany("INSERT INTO joint_samples (stream, t, q) VALUES (?, ?, ?)", rows_j)
            db.executemany("INSERT INTO tracker_samples (stream, t, x, y, z, tp, sigma, rx, ry, rz, sigma_r) "
                           "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)", rows_t)
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

    def last_point(self) -> tuple[tuple[float, float, float], float | None] | None:
        """The attempt's last streamed position (tracker frame, m) of its smallest tracked-point id, with its sigma
        (m; None: not given); None when the tracker streamed no position."""
        row = self.session._db.execute("SELECT x, y, z, sigma FROM tracker_samples WHERE stream = ? AND x IS NOT NULL "
                                       "ORDER BY t DESC, tp LIMIT 1", (self.id,)).fetchone()
        if row is None:
            return None
        return (float(row[0]), float(row[1]), float(row[2])), None if row[3] is None else float(row[3])


def _value(v: float) -> float | None:
    """A sample's number as stored: NaN as NULL."""
    return None if np.isnan(v) else float(v)


def _turns(batch: TrackerStreamBatch) -> np.ndarray:
    """The batch's orientations per sample (k, 4): rx, ry, rz (rad), sigma_r (rad); NaN without them."""
    out = np.full((len(batch.t), 4), np.nan)
    if batch.rotvec is not None:
        out[:, :3] = batch.rotvec
        if batch.sigma_r is not None:
            out[:, 3] = batch.sigma_r
    return out
