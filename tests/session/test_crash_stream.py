"""A continuous session killed mid-sweep (SIGKILL, through the real ``acquire`` command: tests/_acquire_writer.py),
then resumed with ``acquire --resume`` as a fresh process.

The run is at real speed (``--realtime``: the rig's clock is the wall clock, so the kill's time and the session's
timestamps share one clock) and the kill lands while the first continuous sweep is being recorded, at a random
moment between two of its commits. The file then holds every batch committed before the kill, up to the last
second (acquire/running/stream_loop.py commits every 0.5 s); the attempt is left ``recording`` (detectable: no process
ended it); the resume marks it interrupted and superseded, redoes the sweep from its start, completes the session
and identifies it from the redo alone.
"""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from acquire.running.session import Session
from acquire.running.stream_loop import COMMIT_PERIOD
from drivers.sim.stream import robot_time_of_stamps
from tests._acquire_writer import ROOT, Writer
from tests._fast_site import fast_site

pytestmark = [pytest.mark.skipif(not hasattr(signal, "SIGKILL") or not hasattr(os, "fork"),
                                 reason="needs SIGKILL and fork"),
              pytest.mark.realtime]  # timing-sensitive: make test runs these alone, after the rest

# quick stop-and-go moves (no settling), so the first sweep starts within a second or two; the sweeps themselves
# run at their planned speed (1 rad/s: each sweep takes 3.5-7 s)
FAST_SITE = fast_site(samples_per_step=2, check_poses=4)
LOSS = 1.0  # s: what a crash may lose at most (issue 16)
STREAM = 2  # plan index of the first stream step: home, the range start, then the sweep


def _read(path: Path, sql: str, args: tuple = ()) -> list[tuple]:
    """Rows of ``sql`` from a read-only connection (closed at once: the writer's commits wait for no reader)."""
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=5.0)
    try:
        return db.execute(sql, args).fetchall()
    finally:
        db.close()


def _committed(path: Path) -> tuple[int, int, int, float]:
    """(batches, tracker samples, joint samples, last batch time) of the stream step's first attempt, as a reader
    sees them now (committed)."""
    (batches, last), = _read(path, "SELECT count(*), max(b.t) FROM stream_batches b JOIN streams s ON s.id = b.stream "
                                   "WHERE s.plan_index = ? AND s.attempt = 1", (STREAM,))
    (tracker,), = _read(path, "SELECT count(*) FROM tracker_samples t JOIN streams s ON s.id = t.stream "
                              "WHERE s.plan_index = ? AND s.attempt = 1", (STREAM,))
    (joints,), = _read(path, "SELECT count(*) FROM joint_samples j JOIN streams s ON s.id = j.stream "
                             "WHERE s.plan_index = ? AND s.attempt = 1", (STREAM,))
    return int(batches), int(tracker), int(joints), float(last or 0.0)


@pytest.mark.slow
def test_sigkill_mid_sweep_keeps_the_committed_batches_and_the_resume_redoes_the_sweep(tmp_path: Path) -> None:
    site = tmp_path / "fast.yaml"
    site.write_text(FAST_SITE)
    path = tmp_path / "c.session"
    tracker = "mock?latency=0.02"
    writer = Writer(tmp_path)
    try:
        pid = writer.start(["--robot", "mock:ur5e", "--tracker", tracker, "--mode", "continuous", "--config", site,
                            "--session", path, "--realtime", "--quiet"])
        writer.until(f"ack {STREAM - 1}")  # the range start is recorded: the sweep is next
        deadline = time.monotonic() + 30.0
        while _committed(path)[0] < 4:  # 1.5-2 s into the sweep (the streams start 0.5 s before the move)
            assert time.monotonic() < deadline, "the sweep did not start recording"
            time.sleep(0.05)
        time.sleep(float(np.random.default_rng(20261125).uniform(0.0, COMMIT_PERIOD)))  # anywhere between commits
        seen = _committed(path)
        killed_at = time.time()  # the rig's clock (--realtime: the wall clock)
        os.kill(pid, signal.SIGKILL)
        assert writer.finish() == -signal.SIGKILL
    finally:
        writer.close()

    # the file as the kill left it: every batch a reader saw, whole, up to the last second
    batches, tracker_rows, joint_rows, last_batch = _committed(path)
    assert (batches, tracker_rows, joint_rows) >= seen[:3] and last_batch >= seen[3]
    (in_batches,), = _read(path, "SELECT sum(b.tracker_samples) FROM stream_batches b JOIN streams s ON "
                                 "s.id = b.stream WHERE s.plan_index = ?", (STREAM,))
    assert in_batches == tracker_rows  # no half batch
    assert killed_at - last_batch <= LOSS
    with Session.open(path) as session:
        details = session.header["tracker"]["details"]
        assert session.recorded_indices() == {0, 1}  # the sweep step itself is not recorded
        step = session.plan.steps[STREAM]
        assert step.kind == "stream" and step.start is not None  # the tour's first sweep (joint 5 today)
    (t_last,), = _read(path, "SELECT max(t) FROM tracker_samples")
    assert killed_at - float(robot_time_of_stamps(details, t_last)) <= LOSS  # when the last kept sample was taken
    (t_joint, q_joint), = _read(path, "SELECT t, q FROM joint_samples ORDER BY t DESC LIMIT 1")
    assert killed_at - t_joint <= LOSS
    j = step.joint - 1
    q_swept = json.loads(q_joint)[j]
    lo, hi = sorted((step.start[j], step.q[j]))  # a sweep runs either way (the plan's tour chooses)
    assert lo + 0.3 < q_swept < hi - 0.3  # the kill landed mid-sweep, the arm well inside its range
    assert _read(path, "SELECT attempt, status, superseded FROM streams") == [(1, "recording", 0)]  # detectable
    assert _read(path, "SELECT outcome FROM runs") == [("running",)]  # nobody ended the run

    # resume: a fresh process, the installed entry point (virtual clock: the rest of the plan in seconds)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"}
    done = subprocess.run([sys.executable, "-m", "acquire.commands.launch", "--resume", str(path), "--quiet"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "result written" in done.stdout
    attempts = _read(path, "SELECT attempt, status, superseded, reason FROM streams WHERE plan_index = ? ORDER BY "
                           "attempt", (STREAM,))
    assert attempts == [(1, "interrupted", 1, "the process ended while recording"), (2, "complete", 0, "")]
    runs = _read(path, "SELECT outcome, reason FROM runs ORDER BY id")
    assert runs == [("failed", "interrupted: the process ended without closing the run"), ("complete", "")]
    with Session.open(path) as session:
        assert session.next_index() is None and session.outcome() == "complete"
        meas = session.to_measurements()
    old = {t for (t,) in _read(path, "SELECT t.t FROM tracker_samples t JOIN streams s ON s.id = t.stream WHERE "
                                     "s.plan_index = ? AND s.attempt = 1", (STREAM,))}
    redo = {t for (t,) in _read(path, "SELECT t.t FROM tracker_samples t JOIN streams s ON s.id = t.stream WHERE "
                                      "s.plan_index = ? AND s.attempt = 2", (STREAM,))}
    rows = set(meas.t[meas.streamed & (meas.sweep == step.sweep)].tolist())
    assert len(old) == tracker_rows and rows and rows <= redo and not rows & old  # nothing of the killed attempt
    assert len(rows) > 0.95 * len(redo)
    # identified, with the redo's clock: the offset the rig implies (no drift: -latency) within 4 sigma
    doc = yaml.safe_load(path.with_suffix(".result.yaml").read_text())
    assert doc["verdict"]["status"] in ("pass", "warn")
    clock = doc["clock"]
    assert clock["streamed_rows"] == int(meas.streamed.sum())
    truth = float(robot_time_of_stamps(details, clock["t_ref_s"])) - clock["t_ref_s"]
    assert abs(clock["offset_s"] - truth) < 4 * clock["offset_std_s"] + 1e-6
    print(f"killed {killed_at - last_batch:.3f} s after the last commit, joint {step.joint} at {q_swept:.2f} rad; "
          f"{batches} batches, {tracker_rows} tracker samples kept of the killed attempt, none fitted; the redo "
          f"{len(redo)}")
