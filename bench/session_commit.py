"""The cost per step of a durable session commit, by journal mode (issue 13: one session = one file).

    python -m bench.session_commit [--steps 216] [--repeats 5] [--folder DIR ...]

Records ``--steps`` steps (5 readings each, as a default mock step) through :meth:`Session.record_step` and
times each call, for three ways of making a step durable, interleaved run by run on the same folder so that a
busy disk affects all alike:

- ``wal``: the previous version, WAL journal with ``synchronous=FULL`` (one fsync of the -wal per step; the
  steps stay in the -wal file until a checkpoint, so the .session file alone does not hold them);
- ``wal+checkpoint``: the same plus ``PRAGMA wal_checkpoint(TRUNCATE)`` after each step (the .session file
  holds every step, but -wal/-shm files stay beside it while open and after a kill);
- ``delete`` (this version): rollback journal, ``synchronous=EXTRA`` (journal fsync, file fsync, journal
  deletion made durable): the .session file alone holds every step, and no side file is left between steps.

Prints the median, mean and 90th percentile per step, per mode and folder.
"""

from __future__ import annotations

import argparse
import sqlite3
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import session.store as session_module
from acquire.running.session import Session
from tests._session_writer import CONFIG, ROBOT, TRACKER, record_for, small_plan

MODES = ("wal", "wal+checkpoint", "delete")


def _configure_wal(conn: sqlite3.Connection) -> None:
    conn.execute("PRAGMA busy_timeout = 5000")
    conn.execute("PRAGMA journal_mode = WAL")
    conn.execute("PRAGMA synchronous = FULL")
    conn.execute("PRAGMA foreign_keys = ON")


def one_run(folder: Path, mode: str, steps: int) -> list[float]:
    """Seconds per ``record_step`` for ``steps`` steps in a new session under ``folder``."""
    original = session_module.configure
    if mode != "delete":
        session_module.configure = _configure_wal
    path = folder / f"bench-{mode.replace('+', '-')}-{time.time_ns()}.session"
    plan = small_plan()
    times = []
    try:
        session = Session.create(path, plan, CONFIG, ROBOT, TRACKER)
        session.begin_run()
        db = session._db
        for k in range(steps):
            i = k % len(plan.steps)
            if k and i == 0:  # the small plan has 38 steps: start again in a fresh session of the same file
                session.close()
                path.unlink()
                session = Session.create(path, plan, CONFIG, ROBOT, TRACKER)
                session.begin_run()
                db = session._db
            record = record_for(plan, i)
            t = time.perf_counter()
            session.record_step(record)
            if mode == "wal+checkpoint":
                db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
            times.append(time.perf_counter() - t)
        session.end_run("complete")
        session.close()
    finally:
        session_module.configure = original
        for p in folder.glob(f"{path.name}*"):
            p.unlink()
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=216)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--folder", type=Path, action="append",
                        help=f"where the sessions are written (default: {tempfile.gettempdir()} and /dev/shm)")
    args = parser.parse_args()
    folders = args.folder or [p for p in (Path(tempfile.gettempdir()), Path("/dev/shm")) if p.is_dir()]
    print(f"python {sys.version.split()[0]}, SQLite {sqlite3.sqlite_version}, {time.strftime('%Y-%m-%d %H:%M')}")
    for folder in folders:
        times: dict[str, list[float]] = {mode: [] for mode in MODES}
        for _ in range(args.repeats):
            for mode in MODES:
                times[mode] += one_run(folder, mode, args.steps)
        for mode in MODES:
            t = np.array(times[mode]) * 1e3
            print(f"{folder}: {mode:15s} median {np.median(t):7.3f} ms/step, mean {np.mean(t):7.3f} ms, "
                  f"p90 {np.percentile(t, 90):7.3f} ms ({len(t)} steps)")


if __name__ == "__main__":
    main()
