"""A session: one SQLite file holding everything an acquisition recorded, durable and resumable. ``acquire`` writes
it (acquire/running/session.py adds the measurements); identify's edge reads it (identify/io/session_measurements.py).
The file's tables and settings: session/schema.py; a step's rows: session/rows.py.

Drift is not a table: home re-measurements are steps of kind ``home``, and :meth:`SessionFile.drift` computes their
displacement from the first one on read (one source of truth, nothing to keep in sync).

Durability: a step and all its readings are written in one transaction, committed (fsync'd) before
:meth:`SessionFile.record_step` returns; a ``kill -9`` at any moment leaves the whole step or none of it. With the
rollback journal the session file itself holds every committed step after each commit: copying the ``.session`` file
alone between steps copies them all, and a closed (finished, stopped or killed between steps) session is one file with
no ``-wal``/``-shm``/``-journal`` beside it. Only while SQLite writes a step's pages (microseconds) is the file alone
in flux; ``acquire backup`` copies a live session safely. A writer killed while SQLite created its journal can leave an
empty one beside the file: SQLite ignores it (it is not a step in flight) and the next writer removes it.
Creation is atomic too: the file is built under a temporary name and linked into place complete.

One writer: opening for writing (:meth:`SessionFile.create`, ``SessionFile.open(path, write=True)``) takes an exclusive
``flock`` on the file, held until :meth:`SessionFile.close`; a second writer is refused at once with a
:class:`SessionBusy` naming the holder's PID (session/lock.py). Readers take no lock and work while a session is
written. :func:`session.backup.backup_session` copies a live session.

Units: metres (positions, sigma), radians / metres (joints), seconds since the epoch (times).
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sqlite3
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import numpy as np

from common import __version__, stop_signals
from common.outputs import OutputError, check_target, commit_file
from drivers.base import Correction, DeviceIdentity
from kinematics.joint_errors import Coupling
from session.lock import lock_for_writing, remove_dead_creations
from session.lock import unlock as _unlock
from session.plan import Plan
from session.records import FrameRecord, PointRecord, StepRecord
from session.rows import (
    correction_rows,
    coupling_of,
    drift_from,
    frame_rows,
    insert_step,
    point_rows,
    reading_rows,
    retire_step,
    spread_sigmas,
    step_rows,
)
from session.schema import (
    NEWEST_SCHEMA,
    POINTS_SCHEMA,
    SCHEMA_VERSION,
    STREAMS_SCHEMA,
    SessionError,
    check_magic,
    configure,
    fsync_path,
    initialise,
    migrate,
    newer,
    not_a_session,
    read_meta,
)
from session.stream_data import StreamData, current_streams

OUTCOMES = ("running", "complete", "aborted", "failed")


@dataclass(frozen=True)
class RunInfo:
    """One run: ``started``/``ended`` s since the epoch (``ended`` None while running)."""

    id: int
    started: float
    ended: float | None
    outcome: str
    reason: str


class SessionFile:
    """An open session file (its contents, written and read back). Create with :meth:`create`, reopen with
    :meth:`open`; use as a context manager. ``acquire.running.session.Session`` adds its measurements."""

    def __init__(self, path: Path, conn: sqlite3.Connection, header: dict[str, Any], plan: Plan,
                 lock_fd: int | None = None) -> None:
        """Internal: use :meth:`create` or :meth:`open`."""
        self.path = path
        self._conn: sqlite3.Connection | None = conn
        self._header = header
        self._plan = plan
        self._run_id: int | None = None
        self._lock_fd = lock_fd

    # --- creating and opening -------------------------------------------------------------------------------

    @classmethod
    def create(cls, path: str | Path, plan: Plan, config: dict[str, Any], robot: DeviceIdentity,
               tracker: DeviceIdentity, coupling: Coupling | None = None) -> Self:
        """A new session file at ``path`` with its header, open for writing (locked); refuses to overwrite
        anything and to create folders (SessionError). ``coupling``: how the robot's readings give its DH joint
        values (the robot model's; None or the identity: they are the DH values); a coupled session is schema 2.

        The file appears complete or not at all: it is written under a temporary name, then linked into place.
        """
        path = Path(path)
        try:
            check_target(path, force=False, option="session")
        except OutputError as exc:
            raise SessionError(f"{exc}".replace("; pass --force to replace it", "; a session file is never "
                                                "overwritten (choose another name)")) from None
        if any(step.index != i for i, step in enumerate(plan.steps)):
            raise SessionError(f"{path}: plan step indices must be 0..{len(plan.steps) - 1} in order")
        coupled = coupling is not None and not coupling.is_identity
        schema = STREAMS_SCHEMA if plan.continuous else POINTS_SCHEMA if coupled else SCHEMA_VERSION
        header = {"schema": schema, "created": time.time(),
                  "software": __version__, "config": config, "robot": robot.as_dict(), "tracker": tracker.as_dict()}
        if coupled:
            assert coupling is not None
            header["coupling"] = coupling.as_dict()
        try:
            rows = [(key, json.dumps(value, allow_nan=False)) for key, value in header.items()]
        except (TypeError, ValueError) as exc:
            raise SessionError(f"{path}: the configuration cannot be stored as JSON ({exc})") from None
        rows.append(("plan", plan.to_json()))
        temp = path.with_name(f".{path.name}.creating-{os.getpid()}")
        lock_fd = None
        try:
            remove_dead_creations(path)
            temp.unlink(missing_ok=True)
            conn = sqlite3.connect(temp, isolation_level=None)
            try:
                initialise(conn, rows, header["schema"])
            finally:
                conn.close()
            fsync_path(temp)
            lock_fd = lock_for_writing(temp, path)  # the lock is on the file (inode): it stays when the file is linked
            commit_file(temp, path, force=False)  # a hard link: fails if path exists, even in a race
        except OutputError:
            _unlock(lock_fd)
            raise SessionError(f"{path} already exists; a session file is never overwritten") from None
        except sqlite3.Error as exc:
            _unlock(lock_fd)
            raise SessionError(f"{path}: cannot create the session ({exc})") from None
        except OSError as exc:
            _unlock(lock_fd)
            raise SessionError(f"{path}: cannot create the session ({exc.strerror or exc})") from None
        finally:
            with contextlib.suppress(OSError):
                temp.unlink()
        return cls._open(path, lock_fd)

    @classmethod
    def open(cls, path: str | Path, write: bool = False) -> Self:
        """Open an existing session: to read it (the default; no lock, works while another process writes it)
        or, with ``write``, to continue it (an exclusive lock, held until :meth:`close`; SessionBusy naming the
        holder if another process has it). SessionError (one line) for a missing, corrupt, non-SQLite or
        foreign file, or one written by a newer schema."""
        path = Path(path)
        check_magic(path)
        lock_fd = lock_for_writing(path, path) if write else None
        return cls._open(path, lock_fd)

    @classmethod
    def _open(cls, path: Path, lock_fd: int | None) -> Self:
        # a reader opens read-write where it may, so that SQLite can roll back a step left half-written by a
        # killed writer (a reader never writes otherwise); read-only media are read read-only
        mode = "rw" if lock_fd is not None or os.access(path, os.W_OK) else "ro"
        try:
            conn = sqlite3.connect(f"{path.resolve().as_uri()}?mode={mode}", uri=True, isolation_level=None,
                                   timeout=5.0)
        except sqlite3.Error as exc:
            _unlock(lock_fd)
            raise SessionError(f"{path}: cannot be opened ({exc})") from None
        try:
            meta = read_meta(conn, path)
            header = {key: json.loads(value) for key, value in meta.items()}
            if int(header.get("schema", 0)) > NEWEST_SCHEMA:
                raise newer(path, int(header["schema"]))
            plan = Plan.from_json(meta["plan"])
            coupling_of(header)  # a coupling that cannot be read is not a session
            if lock_fd is not None:
                configure(conn)
                conn.execute("BEGIN IMMEDIATE")
                migrate(conn)
                conn.execute("INSERT OR REPLACE INTO writer (id, pid, host, since, command) VALUES (1, ?, ?, ?, ?)",
                             (os.getpid(), socket.gethostname(), time.time(), " ".join(sys.argv)[:500]))
                conn.execute("COMMIT")
            else:
                conn.execute("PRAGMA busy_timeout = 5000")
        except SessionError:
            conn.close()
            _unlock(lock_fd)
            raise
        except sqlite3.OperationalError as exc:
            conn.close()
            _unlock(lock_fd)
            raise SessionError(f"{path}: cannot be opened ({exc})") from None
        except (sqlite3.Error, ValueError, KeyError, TypeError):
            conn.close()
            _unlock(lock_fd)
            raise not_a_session(path) from None
        return cls(path, conn, header, plan, lock_fd)

    @property
    def writable(self) -> bool:
        """True when this object holds the session's write lock."""
        return self._lock_fd is not None

    def close(self) -> None:
        """Close the file (and release the write lock). A run this object began and did not end is ended as
        failed."""
        if self._conn is None:
            return
        try:
            if self._run_id is not None:
                self.end_run("failed", "the session was closed before the run ended")
        finally:
            self._conn.close()  # before the lock: no other writer may start while SQLite still has the file
            self._conn = None
            _unlock(self._lock_fd)
            self._lock_fd = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self._run_id is not None and exc is not None and self._conn is not None:
            with contextlib.suppress(SessionError):  # never hide the exception that is propagating
                if isinstance(exc, KeyboardInterrupt):  # Ctrl-C, SIGTERM or SIGHUP (common/stop_signals.py)
                    self.end_run("aborted", stop_signals.reason_of(exc))
                else:
                    self.end_run("failed", f"{type(exc).__name__}: {exc}")
        if exc is None:
            self.close()
        else:
            with contextlib.suppress(SessionError):
                self.close()

    # --- header ---------------------------------------------------------------------------------------------

    @property
    def plan(self) -> Plan:
        """The plan the session was created with."""
        return self._plan

    @property
    def header(self) -> dict[str, Any]:
        """schema, created (s), software, config, robot, tracker (dicts), plan (as a dict); coupling when the
        robot's readings are coupled."""
        return json.loads(json.dumps(self._header))

    @property
    def coupling(self) -> Coupling | None:
        """How the recorded joint readings give the DH joint values (None: they are the DH values)."""
        return coupling_of(self._header)

    # --- runs and events ------------------------------------------------------------------------------------

    def begin_run(self) -> int:
        """Start a run (a first start or a resume); its id. Runs a dead process left ``running`` close as failed."""
        if self._run_id is not None:
            raise SessionError(f"{self.path}: run {self._run_id} is still running; end it first")
        now = time.time()
        with self._transaction("start a run"):
            stale = [row[0] for row in self._db.execute("SELECT id FROM runs WHERE outcome = 'running'")]
            self._db.execute("UPDATE runs SET outcome = 'failed', ended = ?, reason = ? WHERE outcome = 'running'",
                             (now, "interrupted: the process ended without closing the run"))
            cur = self._db.execute("INSERT INTO runs (started, outcome) VALUES (?, 'running')", (now,))
            run_id = int(cur.lastrowid)
            if stale:
                message = f"resuming after interrupted run(s) {', '.join(map(str, stale))}"
                self._db.execute("INSERT INTO events (t, run_id, kind, message) VALUES (?, ?, 'resume', ?)",
                                 (now, run_id, message))
        self._run_id = run_id
        return run_id

    def end_run(self, outcome: str, reason: str = "") -> None:
        """End the current run: ``outcome`` is "complete", "aborted" (by the operator) or "failed" (give a reason)."""
        if outcome not in OUTCOMES[1:]:
            raise ValueError(f"outcome must be one of {', '.join(OUTCOMES[1:])}, got {outcome!r}")
        if outcome == "failed" and not reason:
            raise ValueError("a failed run needs a reason")
        if self._run_id is None:
            raise SessionError(f"{self.path}: no run to end (call begin_run first)")
        with self._transaction("end the run"):
            self._db.execute("UPDATE runs SET outcome = ?, reason = ?, ended = ? WHERE id = ?",
                             (outcome, " ".join(reason.split()), time.time(), self._run_id))
        self._run_id = None

    def event(self, kind: str, message: str) -> None:
        """Log an event (pause, fault, retry, resume...) of the current run, time-stamped now."""
        with self._transaction("log an event"):
            self._db.execute("INSERT INTO events (t, run_id, kind, message) VALUES (?, ?, ?, ?)",
                             (time.time(), self._run_id, kind, message))

    def set_connection(self, connection: dict[str, Any], message: str) -> None:
        """Record new connection details (robot and tracker specs, site configuration) that a later resume
        starts from (header key ``connection``; ``config`` keeps the original), with an event saying what
        changed, in one transaction."""
        with self._transaction("record the connection details"):
            self._db.execute("INSERT OR REPLACE INTO meta (key, value) VALUES ('connection', ?)",
                             (json.dumps(connection, allow_nan=False),))
            self._db.execute("INSERT INTO events (t, run_id, kind, message) VALUES (?, ?, 'connection', ?)",
                             (time.time(), self._run_id, message))
        self._header["connection"] = json.loads(json.dumps(connection))

    def events(self) -> list[tuple[float, int | None, str, str]]:
        """Every event as (t, run_id, kind, message), oldest first."""
        return [tuple(row) for row in self._db.execute("SELECT t, run_id, kind, message FROM events ORDER BY id")]

    def runs(self) -> list[RunInfo]:
        """Every run, oldest first."""
        rows = self._db.execute("SELECT id, started, ended, outcome, reason FROM runs ORDER BY id")
        return [RunInfo(*row) for row in rows]

    def outcome(self) -> str | None:
        """How the last run ended ("running" if it has not, or if its process died), None before any run."""
        row = self._db.execute("SELECT outcome FROM runs ORDER BY id DESC LIMIT 1").fetchone()
        return None if row is None else row[0]

    # --- steps ----------------------------------------------------------------------------------------------

    def record_step(self, record: StepRecord) -> None:
        """Store a step and all its readings in one transaction, durable when this returns.

        Raises SessionError if the step was already recorded, does not match the plan, or no run is going.
        """
        i = record.plan_index
        try:
            with self._transaction(f"record step {i}"):
                self._insert_step(record)
        except SessionError as exc:
            if self._db.execute("SELECT 1 FROM steps WHERE plan_index = ?", (i,)).fetchone():
                raise SessionError(f"{self.path}: step {i} already recorded") from None
            raise exc from None

    def _insert_step(self, record: StepRecord) -> None:
        """Check ``record`` against the plan and insert it with its readings (inside the caller's transaction)."""
        i = record.plan_index
        if not 0 <= i < len(self._plan.steps):
            raise SessionError(f"{self.path}: step {i} is not in the plan (0..{len(self._plan.steps) - 1})")
        step = self._plan.steps[i]
        planned = (step.kind, step.sweep, step.joint, step.role)
        if (record.kind, record.sweep, record.joint, record.role) != planned:
            raise SessionError(f"{self.path}: step {i} does not match the plan (kind, sweep, joint, role {planned})")
        if self._run_id is None:
            raise SessionError(f"{self.path}: no run is going (call begin_run before recording steps)")
        n = len(self._plan.joint_types)
        for name, q in (("q_cmd", record.q_cmd), ("q_act", record.q_act)):
            if q is not None and len(q) != n:
                raise SessionError(f"{self.path}: step {i}: {name} has {len(q)} values; the robot has {n} joints")
        readings = []
        for reading, used in zip(record.readings, record.used, strict=True):
            p = np.asarray(reading.position, dtype=float).reshape(-1)
            if p.shape != (3,):
                raise SessionError(f"{self.path}: step {i}: a reading's position has {p.size} values, not 3")
            sigma = None if reading.sigma is None else float(reading.sigma)
            turn = (None,) * 3 if reading.rotvec is None else tuple(map(float, np.reshape(reading.rotvec, 3)))
            sigma_r = None if reading.sigma_r is None else float(reading.sigma_r)
            readings.append((i, *map(float, p), sigma, float(reading.timestamp), reading.status, int(used),
                             int(reading.tp), *turn, sigma_r))
        if record.points and self._db.execute("PRAGMA user_version").fetchone()[0] < POINTS_SCHEMA:
            self._mark_newest()
        insert_step(self._db, record, readings, self._run_id)

    def _mark_newest(self) -> None:
        """Mark the file schema 2 (inside the caller's transaction, so a rollback undoes it too): its steps now see
        several tracked points, which a reader of schema 1 would misread. The header read at open says so from the
        next open on."""
        self._db.execute(f"PRAGMA user_version = {POINTS_SCHEMA}")
        self._db.execute("UPDATE meta SET value = ? WHERE key = 'schema'", (json.dumps(POINTS_SCHEMA),))

    def retake_step(self, record: StepRecord) -> None:
        """Store a new attempt of a step recorded as missing, keeping the earlier attempt: in one transaction the
        missing record and its readings move to ``retired_steps``/``retired_readings`` (attempt 1, 2, ...) and
        ``record`` takes their place. SessionError if the step is not recorded as missing."""
        i = record.plan_index
        row = self._db.execute("SELECT status FROM steps WHERE plan_index = ?", (i,)).fetchone()
        if row is None or row[0] != "missing":
            raise SessionError(f"{self.path}: step {i} is {'not recorded' if row is None else 'ok'}; only a missing "
                               "step is measured again")
        with self._transaction(f"retire step {i}"):
            retire_step(self._db, i)
            self._insert_step(record)

    def missing_indices(self) -> list[int]:
        """Plan indices of the steps recorded as missing, in plan order."""
        return [row[0] for row in self._db.execute("SELECT plan_index FROM steps WHERE status = 'missing'"
                                                   " ORDER BY plan_index")]

    def attempts(self, plan_index: int) -> int:
        """How many times step ``plan_index`` was recorded (0 if never)."""
        now = self._db.execute("SELECT count(*) FROM steps WHERE plan_index = ?", (plan_index,)).fetchone()[0]
        tables = {r[0] for r in self._db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if "retired_steps" not in tables:
            return now
        return now + self._db.execute("SELECT count(*) FROM retired_steps WHERE plan_index = ?",
                                      (plan_index,)).fetchone()[0]

    def recorded_indices(self) -> set[int]:
        """Plan indices of every recorded step (ok or missing)."""
        return {row[0] for row in self._db.execute("SELECT plan_index FROM steps")}

    def next_index(self) -> int | None:
        """The first plan index not yet recorded; None when every step is."""
        done = self.recorded_indices()
        return next((i for i in range(len(self._plan.steps)) if i not in done), None)

    def steps(self) -> list[StepRecord]:
        """Every recorded step in plan order, with its raw readings and, when it saw several tracked points,
        their averages."""
        by_step, points, frames = reading_rows(self._db), point_rows(self._db), frame_rows(self._db)
        corrections, out = correction_rows(self._db), []
        for row in step_rows(self._db):
            raw, i = by_step.get(row["plan_index"], []), row["plan_index"]
            try:
                out.append(StepRecord(**row, readings=tuple(r for r, _ in raw), used=tuple(u for _, u in raw),
                                      points=tuple(points.get(i, ())), frames=tuple(frames.get(i, ())),
                                      corrections=tuple(corrections.get(i, ()))))
            except ValueError as exc:
                raise SessionError(f"{self.path}: inconsistent record ({exc})") from None
        return out

    # --- reading back -------------------------------------------------------------------------------------

    def measured_rows(self) -> tuple[list[dict[str, Any]], dict[int, list[PointRecord]]]:
        """What the stop-and-go measurements are made of: the ok steps other than streams as step rows (plan order,
        :func:`session.rows.step_rows`) and the per-point averages of the steps that saw several tracked points."""
        return step_rows(self._db, "WHERE status = 'ok' AND kind != 'stream'"), point_rows(self._db)

    def spread_sigmas(self) -> set[tuple[int, int]]:
        """(plan index, tracked point) of the step averages whose sigma is their readings' own spread
        (:func:`session.rows.spread_sigmas`)."""
        return spread_sigmas(self._db)

    def measured_frames(self) -> dict[int, list[FrameRecord]]:
        """The averaged target-frame orientations of the steps a full-pose device measured (plan index -> ascending
        tracked-point ids; empty without any)."""
        return frame_rows(self._db)

    def measured_corrections(self) -> dict[int, list[tuple[int, Correction]]]:
        """How the steps a shape-and-lens-correcting camera measured move with its estimate (plan index ->
        (tracked point id, drivers/base.py ``Correction``), ascending ids; empty without any)."""
        return correction_rows(self._db)

    def streams(self) -> list[StreamData]:
        """The complete, current attempt of every stream step recorded ok, in plan order (continuous motion)."""
        return current_streams(self._db, self._plan)

    def backup_to(self, target: sqlite3.Connection) -> None:
        """Copy the whole file into the open database ``target`` with SQLite's online backup API (one step: a
        consistent snapshot; a writer's commit waits the few milliseconds it takes)."""
        try:
            self._db.backup(target)
        except sqlite3.Error as exc:
            raise SessionError(f"{self.path}: cannot be copied ({exc})") from None

    def drift(self) -> list[tuple[float, float]]:
        """Home re-measurements as (t, displacement) relative to the first ok one: t = the step's end time (s),
        displacement = distance of its averaged TP from the first's (m; with several tracked points the mean over
        the points, each from where it was first seen at home)."""
        return drift_from(step_rows(self._db, "WHERE kind = 'home' AND status = 'ok'"), point_rows(self._db))

    # --- internals ------------------------------------------------------------------------------------------

    @property
    def _db(self) -> sqlite3.Connection:
        if self._conn is None:
            raise SessionError(f"{self.path}: the session is closed")
        return self._conn

    @contextlib.contextmanager
    def _transaction(self, what: str):
        db = self._db
        if self._lock_fd is None:
            raise SessionError(f"{self.path}: cannot {what}: the session was opened for reading only")
        try:
            db.execute("BEGIN IMMEDIATE")
            try:
                yield
            except BaseException:
                db.execute("ROLLBACK")
                raise
            db.execute("COMMIT")
        except sqlite3.Error as exc:
            raise SessionError(f"{self.path}: cannot {what} ({exc})") from None

