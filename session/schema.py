"""The session file's format: tables, SQLite settings and the small conversions of its columns.

The file (stdlib ``sqlite3``, rollback journal ``DELETE``, ``synchronous=EXTRA``, foreign keys on) holds:

- ``meta(key, value)``: the header, each value JSON: ``schema`` (int), ``created`` (s since the epoch),
  ``software`` (``identify.__version__``), ``config`` (the resolved configuration, an object), ``robot`` and
  ``tracker`` (``DeviceIdentity.as_dict()``; a UR robot's ``details.factory_calibration`` holds the
  controller's DH values, see :func:`session.rows.factory_calibration`), ``plan`` (``Plan.to_json()``). ``PRAGMA
  user_version`` holds the schema too; a file of a newer schema is refused, never modified.
- ``runs(id, started, ended, outcome, reason)``: one row per run (start or resume); ``outcome`` is
  ``running``, ``complete``, ``aborted`` (by the operator) or ``failed`` (with the reason). A run left
  ``running`` by a process that died is closed as ``failed`` ("interrupted") by the next ``begin_run``.
- ``steps(plan_index PRIMARY KEY, ...)``: one row per plan step, commanded and actual joints, averaged TP,
  its per-axis sigma, sample counts, status (``ok``/``missing``), reason, timestamps and run id. The
  primary key makes recording a step twice impossible.
- ``readings(id, plan_index, x, y, z, sigma, t, status, used, tp)``: every raw tracker reading of a step and
  whether it was kept after outlier rejection; ``tp`` the id of the tracked point it sees (1 when the tracker
  sees one). SQLite stores NaN as NULL; NULL coordinates read back NaN.
- ``step_points(plan_index, tp, x, y, z, sigma, samples, rejected)``: with a tracker that sees several points,
  the average of every point seen at an ok step (``steps`` then holds the smallest id's); no rows otherwise.
- ``step_orientations(plan_index, tp, rx, ry, rz, sigma_r)``: with a full-pose device (6-DoF probe, camera target),
  the averaged orientation of every point seen at an ok step (a rotation vector in the tracker frame, rad, and its
  per-axis sigma, rad); the raw readings' own are the ``rx, ry, rz, sigma_r`` columns of ``readings`` (NULL: a
  position only). Added by :func:`migrate` like ``tp``: a reader of an older version ignores them and reads the
  positions, which stay right, so the schema number does not change.
- ``step_corrections(plan_index, tp, correction)``: with a camera that corrects its readings for its board's shape
  and its lens, how every point's average at an ok step moves with their estimate (JSON of drivers/base.py
  ``Correction``), so that identify corrects it again with the session's final estimate; the positions stored
  stay as measured. A reader of an older version ignores it and reads the readings as corrected at the time.
- ``events(id, t, run_id, kind, message)``: pauses, faults, retries, resumes, changed connection details.
- ``retired_steps`` / ``retired_readings``: earlier attempts of steps measured again (``attempt`` 1, 2...),
  with the columns of ``steps`` / ``readings``; ``steps`` always holds the latest attempt.
- ``writer(pid, host, since, command)``: the process that last opened the file for writing (for messages).
  The last three tables, ``step_points`` and the ``tp`` columns are created by the first writer that needs
  them (:func:`migrate`); files without them are schema 1 too, and read as if every reading saw tracked point 1.

Continuous motion (session/streams.py): ``streams(id, plan_index, sweep, attempt, run_id, status,
superseded, joint_rate, tracker_rate, started, ended, reason)``: one row per attempt of a stream step (status
``recording`` until it ends ``complete`` or ``interrupted``; a new attempt supersedes the earlier ones, whose
samples stay); ``joint_samples(stream, t, q)`` (robot clock, s; q a JSON list), ``tracker_samples(stream, t, x, y,
z, tp, sigma, rx, ry, rz, sigma_r)`` (tracker clock, s; m; a full-pose device's target-frame rotation vector in the
tracker frame and its per-axis sigma, rad, NULL for a position only: added by :func:`migrate` as the readings' are, so
older readers read the positions and older files open), ``stream_gaps(stream, device, t_start, t_end)`` (robot / tracker
clock) and ``stream_batches(stream, t, joint_samples, tracker_samples)`` (each commit: the host clock's time, s, and the
samples it held). **Schema 3** (:data:`STREAMS_SCHEMA`) marks a session whose plan has stream steps (set at creation);
older versions refuse it.

Tables and columns are added, never changed, so that every reader of schema 1 reads every file of schema 1.
**Schema 2** (:data:`NEWEST_SCHEMA`) has the same tables; it marks a file that a reader of schema 1 would
misread: one whose steps saw several tracked points (``step_points`` rows), or whose joint readings are a
coupled controller's (header key ``coupling``: ``{matrix, offset, equation}``, DH joint values = matrix ·
readings + offset; ``q_cmd`` and ``q_act`` hold the controller's readings). Only such files are written as
schema 2 (a session becomes one in the transaction of its first step with several points); every other file
stays schema 1, readable by older versions.
"""

from __future__ import annotations

import json
import math
import os
import sqlite3
from collections.abc import Sequence
from pathlib import Path

SCHEMA_VERSION = 1  # a plain session's
POINTS_SCHEMA = 2  # several tracked points or coupled readings
STREAMS_SCHEMA = 3  # continuous motion: stream steps in the plan, samples in the stream tables
NEWEST_SCHEMA = STREAMS_SCHEMA  # the newest this version reads
MAGIC = b"SQLite format 3\x00"
ORIENTATION_COLUMNS = ("rx", "ry", "rz", "sigma_r")  # a reading's target-frame rotation vector (rad), its sigma
STEP_COLUMNS = ("plan_index", "kind", "sweep", "joint", "role", "q_cmd", "q_act", "x", "y", "z", "sigma", "samples",
                 "rejected", "status", "reason", "t_start", "t_end")

SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE runs (
    id INTEGER PRIMARY KEY, started REAL NOT NULL, ended REAL,
    outcome TEXT NOT NULL CHECK (outcome IN ('running', 'complete', 'aborted', 'failed')),
    reason TEXT NOT NULL DEFAULT '');
CREATE TABLE steps (
    plan_index INTEGER PRIMARY KEY, kind TEXT NOT NULL, sweep INTEGER NOT NULL, joint INTEGER NOT NULL,
    role TEXT NOT NULL, q_cmd TEXT NOT NULL, q_act TEXT, x REAL, y REAL, z REAL, sigma REAL,
    samples INTEGER NOT NULL, rejected INTEGER NOT NULL,
    status TEXT NOT NULL CHECK (status IN ('ok', 'missing')), reason TEXT NOT NULL DEFAULT '',
    t_start REAL NOT NULL, t_end REAL NOT NULL, run_id INTEGER NOT NULL REFERENCES runs (id));
CREATE TABLE readings (
    id INTEGER PRIMARY KEY, plan_index INTEGER NOT NULL REFERENCES steps (plan_index),
    x REAL, y REAL, z REAL, sigma REAL, t REAL, status TEXT NOT NULL, used INTEGER NOT NULL CHECK (used IN (0, 1)),
    tp INTEGER NOT NULL DEFAULT 1);
CREATE INDEX readings_by_step ON readings (plan_index);
CREATE TABLE events (
    id INTEGER PRIMARY KEY, t REAL NOT NULL, run_id INTEGER REFERENCES runs (id), kind TEXT NOT NULL,
    message TEXT NOT NULL);
"""
# tables added after schema 1 was fixed; old files get them from their first writer, old readers ignore them
EXTRA_SCHEMA = """
CREATE TABLE IF NOT EXISTS retired_steps (
    plan_index INTEGER NOT NULL, attempt INTEGER NOT NULL, kind TEXT NOT NULL, sweep INTEGER NOT NULL,
    joint INTEGER NOT NULL, role TEXT NOT NULL, q_cmd TEXT NOT NULL, q_act TEXT, x REAL, y REAL, z REAL, sigma REAL,
    samples INTEGER NOT NULL, rejected INTEGER NOT NULL, status TEXT NOT NULL, reason TEXT NOT NULL,
    t_start REAL NOT NULL, t_end REAL NOT NULL, run_id INTEGER NOT NULL, PRIMARY KEY (plan_index, attempt));
CREATE TABLE IF NOT EXISTS retired_readings (
    id INTEGER PRIMARY KEY, plan_index INTEGER NOT NULL, attempt INTEGER NOT NULL, x REAL, y REAL, z REAL,
    sigma REAL, t REAL, status TEXT NOT NULL, used INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS step_points (
    plan_index INTEGER NOT NULL REFERENCES steps (plan_index), tp INTEGER NOT NULL, x REAL NOT NULL,
    y REAL NOT NULL, z REAL NOT NULL, sigma REAL, samples INTEGER NOT NULL, rejected INTEGER NOT NULL,
    PRIMARY KEY (plan_index, tp));
CREATE TABLE IF NOT EXISTS streams (
    id INTEGER PRIMARY KEY, plan_index INTEGER NOT NULL, sweep INTEGER NOT NULL, attempt INTEGER NOT NULL,
    run_id INTEGER, status TEXT NOT NULL CHECK (status IN ('recording', 'complete', 'interrupted')),
    superseded INTEGER NOT NULL DEFAULT 0 CHECK (superseded IN (0, 1)), joint_rate REAL, tracker_rate REAL,
    started REAL NOT NULL, ended REAL, reason TEXT NOT NULL DEFAULT '');
CREATE TABLE IF NOT EXISTS joint_samples (
    stream INTEGER NOT NULL REFERENCES streams (id), t REAL NOT NULL, q TEXT NOT NULL);
CREATE INDEX IF NOT EXISTS joint_samples_by_stream ON joint_samples (stream);
CREATE TABLE IF NOT EXISTS tracker_samples (
    stream INTEGER NOT NULL REFERENCES streams (id), t REAL NOT NULL, x REAL, y REAL, z REAL,
    tp INTEGER NOT NULL DEFAULT 1, sigma REAL);
CREATE INDEX IF NOT EXISTS tracker_samples_by_stream ON tracker_samples (stream);
CREATE TABLE IF NOT EXISTS stream_gaps (
    stream INTEGER NOT NULL REFERENCES streams (id), device TEXT NOT NULL CHECK (device IN ('robot', 'tracker')),
    t_start REAL NOT NULL, t_end REAL NOT NULL);
CREATE TABLE IF NOT EXISTS stream_batches (
    stream INTEGER NOT NULL REFERENCES streams (id), t REAL NOT NULL, joint_samples INTEGER NOT NULL,
    tracker_samples INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS step_orientations (
    plan_index INTEGER NOT NULL REFERENCES steps (plan_index), tp INTEGER NOT NULL, rx REAL NOT NULL,
    ry REAL NOT NULL, rz REAL NOT NULL, sigma_r REAL, PRIMARY KEY (plan_index, tp));
CREATE TABLE IF NOT EXISTS step_corrections (
    plan_index INTEGER NOT NULL REFERENCES steps (plan_index), tp INTEGER NOT NULL, correction TEXT NOT NULL,
    PRIMARY KEY (plan_index, tp));
CREATE TABLE IF NOT EXISTS writer (
    id INTEGER PRIMARY KEY CHECK (id = 1), pid INTEGER NOT NULL, host TEXT NOT NULL, since REAL NOT NULL,
    command TEXT NOT NULL);
"""


class SessionError(Exception):
    """A session file that cannot be created, read or written; the message is one line for the operator."""


class SessionBusy(SessionError):
    """The session is open for writing in another process (the message names it)."""


def configure(conn: sqlite3.Connection) -> None:
    """A writer's settings: rollback journal (the main file holds every commit; files of older versions in WAL
    mode are converted), each commit fsync'd with the journal's deletion (``EXTRA``), foreign keys on."""
    conn.execute("PRAGMA busy_timeout = 5000")
    mode = conn.execute("PRAGMA journal_mode = DELETE").fetchone()[0]
    if str(mode).lower() != "delete":
        raise sqlite3.OperationalError(f"cannot use the rollback journal (got {mode})")
    conn.execute("PRAGMA synchronous = EXTRA")
    conn.execute("PRAGMA foreign_keys = ON")


def columns(conn: sqlite3.Connection, table: str) -> set[str]:
    """The column names of ``table`` (empty if there is no such table)."""
    return {row[1] for row in conn.execute(f"PRAGMA table_info({table})")}


def migrate(conn: sqlite3.Connection) -> None:
    """Bring a file of an older version up to this one's tables (inside the writer's transaction): the tables of
    :data:`EXTRA_SCHEMA` and the ``tp`` column of the reading tables (1 for every reading already there)."""
    for statement in EXTRA_SCHEMA.split(";"):
        if statement.strip():
            conn.execute(statement)
    for table in ("readings", "retired_readings"):
        if "tp" not in columns(conn, table):
            conn.execute(f"ALTER TABLE {table} ADD COLUMN tp INTEGER NOT NULL DEFAULT 1")
    for table in ("readings", "retired_readings", "tracker_samples"):
        for name in ORIENTATION_COLUMNS:  # full-pose readings and streamed samples (NULL: a position only)
            if name not in columns(conn, table):
                conn.execute(f"ALTER TABLE {table} ADD COLUMN {name} REAL")


def initialise(conn: sqlite3.Connection, meta: list[tuple[str, str]], version: int) -> None:
    """Create the tables of a new file in one transaction, with its header ``meta`` rows (key, JSON value) and
    ``PRAGMA user_version`` = ``version``."""
    configure(conn)
    conn.execute("BEGIN IMMEDIATE")
    for statement in SCHEMA.split(";"):
        if statement.strip():
            conn.execute(statement)
    migrate(conn)
    conn.executemany("INSERT INTO meta (key, value) VALUES (?, ?)", meta)
    conn.execute(f"PRAGMA user_version = {version}")
    conn.execute("COMMIT")


def read_meta(conn: sqlite3.Connection, path: Path) -> dict[str, str]:
    """The header rows (key -> JSON text) of the open file ``path``, after checking that this version reads it: a
    newer schema, a file that fails SQLite's quick check or lacks the tables of schema 1 raise SessionError."""
    version = conn.execute("PRAGMA user_version").fetchone()[0]
    if version > NEWEST_SCHEMA:
        raise newer(path, version)
    if conn.execute("PRAGMA quick_check").fetchone()[0] != "ok":
        raise not_a_session(path)
    tables = {row[0] for row in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    if version < 1 or not {"meta", "runs", "steps", "readings", "events"} <= tables:
        raise not_a_session(path)
    return dict(conn.execute("SELECT key, value FROM meta").fetchall())


def is_session_file(path: Path) -> bool:
    """True when ``path`` is a readable SQLite file (a session), not a CSV; False when it cannot be read."""
    try:
        with path.open("rb") as f:
            return f.read(len(MAGIC)) == MAGIC
    except OSError:
        return False


def check_magic(path: Path) -> None:
    """SessionError unless ``path`` is a readable SQLite file."""
    try:
        with path.open("rb") as f:
            magic = f.read(len(MAGIC))
    except FileNotFoundError:
        raise SessionError(f"{path}: no such session file") from None
    except IsADirectoryError:
        raise SessionError(f"{path} is a folder, not a session file") from None
    except OSError as exc:
        raise SessionError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if magic != MAGIC:
        raise not_a_session(path)


def not_a_session(path: Path) -> SessionError:
    return SessionError(f"{path} is not a session file (corrupt or not SQLite)")


def newer(path: Path, version: int) -> SessionError:
    return SessionError(f"{path} was written by schema {version}; this version reads up to {NEWEST_SCHEMA}: "
                        "upgrade dh-calib")


def fsync_path(path: Path, directory: bool = False) -> None:
    """Flush ``path`` to disk; a directory that cannot be flushed (some platforms) is skipped."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        if directory:
            return
        raise
    try:
        os.fsync(fd)
    except OSError:
        if not directory:
            raise
    finally:
        os.close(fd)


def dump_q(q: Sequence[float] | None) -> str | None:
    return None if q is None else json.dumps([v if math.isfinite(v) else None for v in q])


def load_q(text: str | None) -> tuple[float, ...] | None:
    return None if text is None else tuple(math.nan if v is None else float(v) for v in json.loads(text))


def nan_of(v: float | None) -> float:
    return math.nan if v is None else float(v)
