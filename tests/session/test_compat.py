"""Sessions written before several tracked points and coupled readings existed still open, export and resume as
before.

The fixture ``data/session_v1.sql`` is the SQL dump (``sqlite3`` ``iterdump``) of a real session file written
by the code of commit e5199c1 (before the ``tp`` column and ``step_points``): ``acquire --robot
"mock:ur5e?seed=7&fault=protective_stop@24" --tracker "mock?seed=7&fault=target_lost@5x4" --steps 6 --samples 2
--free-poses 2``, stopped by the protective stop with step 4 missing; ``data/session_v1.csv`` is what that
code's ``acquire export`` wrote for it.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest

from acquire.commands.cli import main
from acquire.running.session import Session
from session.schema import columns

DATA = Path(__file__).parents[1] / "data"


def _old_session(folder: Path) -> Path:
    """The fixture rebuilt as a session file (the dump does not carry the schema number: 1)."""
    path = folder / "old.session"
    with sqlite3.connect(path) as db:
        db.executescript((DATA / "session_v1.sql").read_text())
        db.execute("PRAGMA user_version = 1")
    db.close()
    return path


def _csv_body(path: Path) -> list[str]:
    """The exported CSV without the lines that name the session's path or the exporting version."""
    return [line for line in path.read_text().splitlines() if not line.startswith(("# session:", "# exported by:"))]


def test_an_old_session_reads_and_exports_as_before(tmp_path: Path) -> None:
    path = _old_session(tmp_path)
    with sqlite3.connect(path) as db:
        assert "tp" not in columns(db, "readings") and not columns(db, "step_points")
    db.close()
    with Session.open(path) as session:  # a reader changes nothing
        steps = session.steps()
        meas = session.to_measurements()
        assert session.coupling is None and session.header["schema"] == 1
        assert len(session.drift()) == sum(s.kind == "home" and s.status == "ok" for s in steps)
    assert all(r.tp == 1 for s in steps for r in s.readings) and not any(s.points for s in steps)
    assert meas.tp_ids == [1] and meas.coupling is None
    out = tmp_path / "old.csv"
    assert main(["export", str(path), "--csv", str(out)]) == 0
    assert _csv_body(out) == _csv_body(DATA / "session_v1.csv")
    with sqlite3.connect(path) as db:
        assert "tp" not in columns(db, "readings")
    db.close()


@pytest.mark.slow
def test_an_old_session_resumes_and_keeps_its_records(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _old_session(tmp_path)
    with Session.open(path) as session:
        before = session.steps()
    assert [s.plan_index for s in before if s.status == "missing"] == [4]
    assert main(["--resume", str(path), "--quiet"]) == 0
    capsys.readouterr()
    with Session.open(path) as session:
        after = {s.plan_index: s for s in session.steps()}
        assert session.outcome() == "complete" and session.header["schema"] == 1
        assert session.attempts(4) == 2 and after[4].status == "ok"
    assert all(after[s.plan_index] == s for s in before if s.plan_index != 4)  # the recorded steps, unchanged
    with sqlite3.connect(path) as db:  # still schema 1: one tracked point, readings as the DH values
        assert db.execute("PRAGMA user_version").fetchone()[0] == 1
        assert db.execute("SELECT count(*) FROM step_points").fetchone()[0] == 0
        assert db.execute("SELECT DISTINCT tp FROM readings").fetchall() == [(1,)]
    db.close()
    out = tmp_path / "resumed.csv"
    assert main(["export", str(path), "--csv", str(out)]) == 0
    old_rows = set(_csv_body(DATA / "session_v1.csv"))
    new_rows = _csv_body(out)
    assert old_rows <= set(new_rows) and len(new_rows) > len(old_rows)
    header = [line for line in new_rows if line.startswith("sweep,")]
    assert header == ["sweep,joint,q1,q2,q3,q4,q5,q6,x,y,z,sigma,role"]  # no tp column for one point
    data = [line.split(",")[8:11] for line in new_rows if not line.startswith(("#", "sweep,"))]
    assert np.isfinite(np.array(data, dtype=float)).all()
