"""Session files: header and step round trips, refusal of bad files, duplicates and overwrites, export to the
measurement CSV, and durability under SIGKILL at random moments (resumed with no duplicate and no gap)."""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from acquire.running.session import Session
from common import __version__
from drivers.base import TrackerReading
from identify.io.csvio import read_measurements
from session.plan import Plan
from session.records import StepRecord
from session.schema import SCHEMA_VERSION, SessionError
from tests._session_writer import CONFIG, ROBOT, TRACKER, record_for, small_plan, write

ROOT = Path(__file__).resolve().parents[2]
WRITER = "tests._session_writer"  # run with -m: tests/ holds packages named like the project's (tests/session/...)


@pytest.fixture
def plan() -> Plan:
    return small_plan()


@pytest.fixture
def session(tmp_path: Path, plan: Plan):
    with Session.create(tmp_path / "s.session", plan, CONFIG, ROBOT, TRACKER) as s:
        yield s


def _record_all(s: Session, indices) -> list[StepRecord]:
    records = [record_for(s.plan, i) for i in indices]
    for r in records:
        s.record_step(r)
    return records


# --- header and steps round trip ------------------------------------------------------------------------------


def test_create_open_round_trip(tmp_path: Path, plan: Plan) -> None:
    path = tmp_path / "a.session"
    before = time.time()
    with Session.create(path, plan, CONFIG, ROBOT, TRACKER) as s:
        run = s.begin_run()
        written = _record_all(s, [0, 1, 2, 3, 4, 5])
        s.event("pause", "operator paused")
        s.end_run("complete")
    assert not list(tmp_path.glob(".*creating*"))
    with Session.open(path) as s:
        h = s.header
        assert h["schema"] == SCHEMA_VERSION == 1
        assert before <= h["created"] <= time.time()
        assert h["software"] == __version__
        assert h["config"] == CONFIG
        assert h["robot"] == ROBOT.as_dict() and h["tracker"] == TRACKER.as_dict()
        assert h["tracker"]["details"] == {"rate": "100 Hz"}
        assert h["plan"] == json.loads(plan.to_json())
        assert s.plan == plan
        steps = s.steps()
        assert steps == written
        assert [r.plan_index for r in steps] == [0, 1, 2, 3, 4, 5]
        # readings come back in order, values and flags intact (NaN positions of garbage readings too)
        r4 = steps[4]
        assert len(r4.readings) == 3 and r4.used == (False, False, False) and r4.rejected == 3
        assert np.all(np.isnan(r4.readings[0].position)) and r4.readings[0].status == "garbage"
        assert r4.position is None and r4.status == "missing" and r4.reason == "no valid reading"
        assert r4.q_act == written[4].q_act and r4.sigma is None and r4.readings[2].sigma is None
        r0, w0 = steps[0], written[0]
        assert r0.used == (True, True, False) and r0.samples == 2 and r0.rejected == 1
        for a, b in zip(r0.readings, w0.readings, strict=True):
            np.testing.assert_array_equal(a.position, b.position)
            assert (a.timestamp, a.sigma, a.status) == (b.timestamp, b.sigma, b.status)
        assert r0.position == w0.position and r0.q_act == w0.q_act and r0.q_cmd == plan.steps[0].q
        assert r0.q_act != r0.q_cmd
        assert [(r.id, r.outcome, r.reason) for r in s.runs()] == [(run, "complete", "")]
        assert s.outcome() == "complete"
        assert [(e[1], e[2], e[3]) for e in s.events()] == [(run, "pause", "operator paused")]


def test_step_record_equality_is_by_value() -> None:
    plan = small_plan()
    a, b = record_for(plan, 5), record_for(plan, 5)
    assert a == b and a is not b
    assert a != record_for(plan, 6)
    with pytest.raises(ValueError, match="samples"):
        StepRecord.from_step(plan.steps[1], q_act=(0, 0, 0), position=(0, 0, 0), sigma=None, samples=2,
                             rejected=0, status="ok", reason="", t_start=0.0, t_end=1.0,
                             readings=[TrackerReading(np.zeros(3), 0.0)], used=[True])
    with pytest.raises(ValueError, match="finite position"):
        StepRecord.from_step(plan.steps[1], q_act=(0, 0, 0), position=None, sigma=None, samples=0, rejected=0,
                             status="ok", reason="", t_start=0.0, t_end=1.0)


# --- refusing bad files ---------------------------------------------------------------------------------------


def _one_line_error(path: Path) -> str:
    with pytest.raises(SessionError) as info:
        Session.open(path)
    message = str(info.value)
    assert "\n" not in message
    return message


def test_newer_schema_refused(tmp_path: Path, plan: Plan) -> None:
    path = tmp_path / "new.session"
    Session.create(path, plan, CONFIG, ROBOT, TRACKER).close()
    with sqlite3.connect(path) as db:
        db.execute("PRAGMA user_version = 7")
    assert _one_line_error(path) == (f"{path} was written by schema 7; this version reads up to 3: upgrade dh-calib")
    # the meta row alone says newer too
    with sqlite3.connect(path) as db:
        db.execute("PRAGMA user_version = 1")
        db.execute("UPDATE meta SET value = '4' WHERE key = 'schema'")
    assert _one_line_error(path) == f"{path} was written by schema 4; this version reads up to 3: upgrade dh-calib"


def _truncated(path: Path, data: bytes) -> None:
    path.write_bytes(data[: len(data) // 2])


def test_corrupt_or_foreign_files_refused(tmp_path: Path, plan: Plan) -> None:
    good = tmp_path / "good.session"
    with Session.create(good, plan, CONFIG, ROBOT, TRACKER) as s:
        s.begin_run()
        _record_all(s, range(20))
        s.end_run("complete")
    data = good.read_bytes()
    assert data.startswith(b"SQLite format 3\x00") and len(data) >= 4 * 4096
    rng = np.random.default_rng(5)
    garbage_pages = bytearray(data)
    garbage_pages[4096:] = rng.integers(0, 256, len(data) - 4096, dtype=np.uint8).tobytes()
    foreign = tmp_path / "foreign.db"
    with sqlite3.connect(foreign) as db:
        db.execute("CREATE TABLE t (x)")
    cases = {
        "text.session": b"sweep,joint,q1,x,y,z\n1,1,0.1,0.2,0.3,0.4\n",
        "random.session": rng.integers(0, 256, 8192, dtype=np.uint8).tobytes(),
        "empty.session": b"",
        "garbage-pages.session": bytes(garbage_pages),
        "half.session": data[: len(data) // 2],
    }
    for name, content in cases.items():
        (tmp_path / name).write_bytes(content)
    for path in [*(tmp_path / name for name in cases), foreign]:
        assert _one_line_error(path) == f"{path} is not a session file (corrupt or not SQLite)", path.name
    assert (tmp_path / "text.session").read_bytes() == cases["text.session"]  # refused files are left alone
    assert _one_line_error(tmp_path / "nope.session") == f"{tmp_path / 'nope.session'}: no such session file"
    assert not (tmp_path / "nope.session").exists()


def test_create_refuses_to_overwrite(tmp_path: Path, plan: Plan) -> None:
    path = tmp_path / "x.session"
    path.write_text("precious")
    with pytest.raises(SessionError, match="already exists"):
        Session.create(path, plan, CONFIG, ROBOT, TRACKER)
    assert path.read_text() == "precious"
    other = tmp_path / "y.session"
    Session.create(other, plan, CONFIG, ROBOT, TRACKER).close()
    with pytest.raises(SessionError, match="already exists"):
        Session.create(other, plan, {"different": True}, ROBOT, TRACKER)
    with Session.open(other) as s:
        assert s.header["config"] == CONFIG


def test_config_must_be_json(tmp_path: Path, plan: Plan) -> None:
    with pytest.raises(SessionError, match="JSON"):
        Session.create(tmp_path / "c.session", plan, {"path": Path("x")}, ROBOT, TRACKER)
    assert not (tmp_path / "c.session").exists()


# --- recording -------------------------------------------------------------------------------------------------


def _readings_per_step(path: Path) -> dict[int, int]:
    with sqlite3.connect(path) as db:
        return dict(db.execute("SELECT plan_index, count(*) FROM readings GROUP BY plan_index").fetchall())


def test_duplicate_step_refused(session: Session) -> None:
    session.begin_run()
    first = _record_all(session, [0, 1])
    with pytest.raises(SessionError, match=r"step 1 already recorded$"):
        session.record_step(record_for(session.plan, 1))
    assert session.steps() == first
    assert _readings_per_step(session.path) == {0: 3, 1: 4}


def test_record_needs_a_run_and_the_plan(session: Session) -> None:
    with pytest.raises(SessionError, match="begin_run"):
        session.record_step(record_for(session.plan, 0))
    session.begin_run()
    other = record_for(session.plan, 2)
    with pytest.raises(SessionError, match="does not match the plan"):
        session.record_step(StepRecord(**{**other.__dict__, "plan_index": 0}))
    with pytest.raises(SessionError, match="not in the plan"):
        session.record_step(StepRecord(**{**other.__dict__, "plan_index": len(session.plan.steps)}))
    with pytest.raises(SessionError, match="q_act has 2 values"):
        session.record_step(StepRecord(**{**other.__dict__, "q_act": (0.0, 0.0)}))
    assert session.recorded_indices() == set()


def test_step_and_readings_are_one_transaction(session: Session) -> None:
    """A reading that fails inside the transaction leaves neither it, its siblings, nor the step."""
    session.begin_run()
    good = record_for(session.plan, 1)
    bad = TrackerReading(np.zeros(3), 1.0, None, None)  # type: ignore[arg-type]  # status NULL: refused by the DB
    broken = StepRecord(**{**good.__dict__, "readings": (*good.readings[:-1], bad)})
    with pytest.raises(SessionError, match="cannot record step 1"):
        session.record_step(broken)
    assert session.recorded_indices() == set() and _readings_per_step(session.path) == {}
    session.record_step(good)
    assert session.steps() == [good]


def test_next_index_after_partial_recording(session: Session) -> None:
    n = len(session.plan.steps)
    assert n == 38 and session.next_index() == 0
    session.begin_run()
    _record_all(session, [0, 1, 2])
    assert session.next_index() == 3
    _record_all(session, [4, 5])
    assert session.next_index() == 3 and session.recorded_indices() == {0, 1, 2, 4, 5}
    _record_all(session, [3, *range(6, n)])
    assert session.next_index() is None
    assert [s.plan_index for s in session.steps()] == list(range(n))


def test_runs_outcomes_and_interrupted_run(tmp_path: Path, plan: Plan) -> None:
    path = tmp_path / "r.session"
    s = Session.create(path, plan, CONFIG, ROBOT, TRACKER)
    assert s.outcome() is None
    first = s.begin_run()
    _record_all(s, [0])
    s._conn.close()  # the process "dies": the run is never ended (and its lock goes with it)
    s._conn = None
    os.close(s._lock_fd)
    with Session.open(path, write=True) as s:
        assert s.outcome() == "running"
        second = s.begin_run()
        assert s.runs()[0].outcome == "failed" and "interrupted" in s.runs()[0].reason
        assert [(e[1], e[2]) for e in s.events()] == [(second, "resume")]
        s.end_run("aborted", "stopped by the operator (Ctrl-C)")
        s.begin_run()
        with pytest.raises(ValueError, match="reason"):
            s.end_run("failed")
        s.end_run("failed", "robot fault: protective stop\nline two")
        runs = s.runs()
    assert [(r.id, r.outcome) for r in runs] == [(first, "failed"), (second, "aborted"), (second + 1, "failed")]
    assert runs[2].reason == "robot fault: protective stop line two"
    assert all(r.ended is not None and r.ended >= r.started for r in runs)
    with Session.open(path, write=True) as s:  # closing with a run still going ends it as failed
        s.begin_run()
    with Session.open(path) as s:
        assert s.outcome() == "failed" and "closed before the run ended" in s.runs()[-1].reason
    with pytest.raises(RuntimeError), Session.open(path, write=True) as s:  # an exception: the run failed, with it
        s.begin_run()
        raise RuntimeError("tracker cable\npulled")
    with pytest.raises(KeyboardInterrupt), Session.open(path, write=True) as s:  # Ctrl-C: aborted by the operator
        s.begin_run()
        raise KeyboardInterrupt
    with Session.open(path) as s:
        assert [(r.outcome, r.reason) for r in s.runs()[-2:]] == [
            ("failed", "RuntimeError: tracker cable pulled"), ("aborted", "stopped by the operator (Ctrl-C)")]


# --- export ----------------------------------------------------------------------------------------------------


def test_to_measurements_uses_actual_joints(session: Session) -> None:
    plan = session.plan
    session.begin_run()
    records = _record_all(session, range(len(plan.steps)))
    meas = session.to_measurements()
    ok = [r for r in records if r.status == "ok"]
    assert len(meas) == len(ok) == 34  # 4 of 38 steps missing (4, 13, 22, 31)
    np.testing.assert_array_equal(meas.q, np.array([r.q_act for r in ok]))
    assert not np.allclose(meas.q, np.array([r.q_cmd for r in ok]), atol=1e-6, rtol=0)
    np.testing.assert_array_equal(meas.points, np.array([r.position for r in ok]))
    np.testing.assert_array_equal(meas.sigma, np.array([r.sigma for r in ok]))
    np.testing.assert_array_equal(meas.sweep, [r.sweep for r in ok])
    np.testing.assert_array_equal(meas.joint, [0 if r.kind == "home" else r.joint for r in ok])
    np.testing.assert_array_equal(meas.check, [r.kind == "home" or r.role == "check" for r in ok])
    assert meas.has_role and meas.joint_types == "RRR"
    assert meas.sweeps_of(3) == [1] and meas.sweeps_of(1) == [3]


def test_export_csv_reads_back(tmp_path: Path, session: Session) -> None:
    session.begin_run()
    _record_all(session, range(len(session.plan.steps)))
    out = tmp_path / "out.csv"
    assert session.export_csv(out) == 34
    content = read_measurements(out)
    meas, back = session.to_measurements(), content.measurements
    assert back.joint_types == meas.joint_types
    for name in ("q", "points", "sigma", "sweep", "joint", "check"):
        np.testing.assert_array_equal(getattr(back, name), getattr(meas, name), err_msg=name)
    assert content.metadata["session"] == str(session.path)
    assert content.metadata["robot"] == "test-arm serial A-1 firmware 1.0"
    assert content.metadata["tracker"] == "test-tracker serial T-9 firmware 2.3"
    assert content.metadata["units"] == "m, rad"


def test_drift_of_home_checks(session: Session) -> None:
    session.begin_run()
    records = _record_all(session, range(len(session.plan.steps)))
    homes = [r for r in records if r.kind == "home" and r.status == "ok"]
    assert len(homes) == 3  # home checks 0, 11, 33 (22 is missing)
    drift = session.drift()
    assert [t for t, _ in drift] == [r.t_end for r in homes]
    expected = [math.dist(r.position, homes[0].position) for r in homes]
    np.testing.assert_allclose([d for _, d in drift], expected, rtol=0, atol=1e-15)
    assert drift[0][1] == 0.0 and drift[-1][1] > 0.01


# --- durability: SIGKILL at random moments, then resume -------------------------------------------------------


def _read_until(server: subprocess.Popen, state: dict, stop) -> None:
    """Read the server's lines into ``state`` until ``stop(state)`` or the child's exit line."""
    while not stop(state) and state["exit"] is None:
        line = server.stdout.readline()
        assert line, "the writer server died"
        word, _, rest = line.strip().partition(" ")
        if word == "pid":
            state["pid"] = int(rest)
        elif word == "exit":
            state["exit"] = int(rest)
        elif word == "ready":
            state["ready"] = True
        elif word == "error":
            raise AssertionError(f"writer failed: {rest}")
        else:
            state["acked"].append(int(word))


@pytest.mark.skipif(not hasattr(signal, "SIGKILL") or not hasattr(os, "fork"), reason="needs SIGKILL and fork")
def test_sigkill_at_random_moments_then_resume(tmp_path: Path) -> None:
    rng = np.random.default_rng(20240611)
    path = tmp_path / "killed.session"
    reference = tmp_path / "clean.session"
    write(reference)  # uninterrupted
    n = len(small_plan().steps)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
           "MKL_NUM_THREADS": "1"}
    with (tmp_path / "server.err").open("w") as err:
        server = subprocess.Popen([sys.executable, "-m", WRITER, "serve", str(path), "0.002"], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, stderr=err, text=True, cwd=ROOT, env=env)
    kills, acked_total, progress = 0, set(), []
    try:
        for _attempt in range(200):
            state = {"pid": None, "exit": None, "ready": False, "acked": []}
            server.stdin.write("go\n")
            server.stdin.flush()
            _read_until(server, state, lambda s: s["pid"] is not None)
            if rng.random() < 0.2:  # early: while creating / opening / starting the run
                time.sleep(rng.uniform(0.0, 0.015))
            else:  # after k more steps have been acknowledged, at a random moment of the next one
                k = int(rng.integers(0, 4))
                _read_until(server, state, lambda s, k=k: s["ready"] and len(s["acked"]) >= k)
                time.sleep(rng.uniform(0.0, 0.004))
            if state["exit"] is None:
                with contextlib.suppress(ProcessLookupError):  # it may have just finished
                    os.kill(state["pid"], signal.SIGKILL)
            _read_until(server, state, lambda s: False)
            acked_total.update(state["acked"])
            if state["exit"] == 0:
                break
            assert state["exit"] == -signal.SIGKILL
            kills += 1
            if not path.exists():  # killed before the session existed: nothing half-made is left in its place
                assert not state["ready"]
                continue
            with Session.open(path) as s:  # reopens cleanly; no gap; every acknowledged step survived
                recorded = s.recorded_indices()
                assert recorded == set(range(len(recorded)))
                assert acked_total <= recorded
                assert s.next_index() == (len(recorded) if len(recorded) < n else None)
                progress.append(len(recorded))
        else:
            raise AssertionError("the writer never finished")
    finally:
        server.stdin.close()
        server.wait(timeout=10)
    assert kills >= 15
    assert len(set(progress)) >= 10, progress  # the kills were spread over the run
    with Session.open(path) as killed, Session.open(reference) as clean:
        steps, expected = killed.steps(), clean.steps()
        assert [s.plan_index for s in steps] == list(range(n))
        assert steps == expected
        assert killed.outcome() == "complete"
        runs = killed.runs()
        # every earlier run was killed: left running, then closed as interrupted by the next begin_run (or it had
        # ended complete and the kill came just after)
        assert all((r.outcome == "failed" and "interrupted" in r.reason) or r.outcome == "complete" for r in runs[:-1])
        assert sum(r.outcome == "failed" for r in runs) >= 10
    counts = _readings_per_step(path)
    assert counts == {s.plan_index: s.samples + s.rejected for s in steps}
    assert counts == {s.plan_index: len(s.readings) for s in expected}


def test_a_dead_creators_hidden_file_and_its_journal_are_removed_a_live_ones_kept(tmp_path: Path) -> None:
    from session.lock import remove_dead_creations

    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()  # a pid that no longer runs (reaped)
    path = tmp_path / "run.session"
    dead = [tmp_path / f".run.session.creating-{child.pid}{end}" for end in ("", "-journal")]
    live = [tmp_path / f".run.session.creating-{os.getpid()}{end}" for end in ("", "-journal")]
    other = tmp_path / ".other.session.creating-1"
    for p in (*dead, *live, other):
        p.write_bytes(b"x")
    remove_dead_creations(path)
    assert [p.exists() for p in dead] == [False, False]
    assert all(p.exists() for p in (*live, other))
