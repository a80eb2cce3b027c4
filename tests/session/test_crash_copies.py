"""Sessions under SIGKILL and concurrent writers, through the real ``acquire`` command (tests/_acquire_writer.py):

- 60 cycles: a real-time mock session is killed at a random moment, its ``.session`` file alone is copied, the
  copy is resumed to the end: every copy holds every step committed before the kill, equal to the original's
  record after the original's own resume, with no duplicate and no gap.
- Two writers started together: exactly one runs, the other exits 2 within 1 s having opened no device.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from acquire.running.session import Session
from tests._acquire_writer import Writer
from tests._fast_site import fast_site

ROOT = Path(__file__).resolve().parents[2]
# a short plan whose real-time steps take ~0.17 s: small sweeps at full speed, no settle time
FAST_SITE = fast_site(samples_per_step=2, steps_per_sweep=4, free_poses=0, check_poses=2,
                      sweep_ranges="[[-0.3, 0.3], [-1.87, -1.27], [1.27, 1.87], [-1.87, -1.27], [-1.87, -1.27], "
                                   "[-0.3, 0.3]]")
pytestmark = pytest.mark.skipif(not hasattr(signal, "SIGKILL") or not hasattr(os, "fork"),
                                reason="needs SIGKILL and fork")


def _steps(path: Path) -> dict[int, object]:
    with Session.open(path) as session:
        return {r.plan_index: r for r in session.steps()}


def _complete(path: Path) -> bool:
    with Session.open(path) as session:
        return session.next_index() is None


JOURNAL_MAGIC = bytes.fromhex("d9d505f920a163d7")  # the first bytes of a rollback journal SQLite will replay


def _hot_journal(path: Path) -> bool:
    with path.open("rb") as journal:
        return journal.read(len(JOURNAL_MAGIC)) == JOURNAL_MAGIC


@pytest.mark.slow
def test_sigkill_then_copy_the_session_file_alone_and_resume_the_copy(tmp_path: Path) -> None:
    site = tmp_path / "fast.yaml"
    site.write_text(FAST_SITE)
    base = ["--robot", "mock:ur5e", "--tracker", "mock", "--config", site, "--quiet"]
    rng = np.random.default_rng(20261124)
    writer = Writer(tmp_path)
    originals: list[Path] = []
    copies: list[tuple[Path, Path, dict[int, object]]] = []  # copy, its original, the copy's steps at the kill
    kills = in_flight = 0
    t0 = time.monotonic()
    try:
        for cycle in range(60):
            if not originals or _complete(originals[-1]):
                originals.append(tmp_path / f"original-{len(originals)}.session")
                args = [*base, "--session", originals[-1], "--realtime"]
            else:
                args = ["--resume", originals[-1], "--realtime", "--quiet"]
            original = originals[-1]
            pid = writer.start(args)
            time.sleep(float(rng.uniform(0.02, 0.45)))  # anywhere: start-up, a move, a measurement, a commit
            with contextlib.suppress(ProcessLookupError):  # it may have just ended (and been reaped)
                os.kill(pid, signal.SIGKILL)
            code = writer.finish()
            assert code in (-signal.SIGKILL, 0), (cycle, code, Path(writer.err.name).read_text()[-1000:])
            kills += code == -signal.SIGKILL
            acked = writer.acked()
            if not original.exists():  # killed before the session was created: nothing half-made in its place
                # (but the hidden file it was creating, which the next creation of that name removes)
                left = [p.name for p in tmp_path.glob(f".{original.name}*")]
                hidden = f".{original.name}.creating-{pid}"
                assert not acked and set(left) <= {hidden, f"{hidden}-journal"}, left
                originals.pop()
                continue
            journal = Path(f"{original}-journal").exists()  # killed inside a commit: that step is in flight
            copy = tmp_path / f"copy-{cycle}.session"
            shutil.copyfile(original, copy)  # the .session file alone
            committed = _steps(original)  # the original after its own recovery (a reader rolls a half step back)
            at_kill = _steps(copy)
            assert acked <= committed.keys()
            for i, record in committed.items():  # every committed step, identical
                assert i in at_kill and at_kill[i] == record, (cycle, i)
            extra = at_kill.keys() - committed.keys()  # at most the step in flight, and only inside a commit
            assert not extra or (journal and len(extra) == 1), (cycle, extra, journal)
            in_flight += bool(extra)
            assert sorted(at_kill) == list(range(len(at_kill)))  # no gap
            writer.start(["--resume", copy, "--quiet"])  # virtual clock: the rest of the plan in a fraction of a s
            assert writer.finish() == 0
            with Session.open(copy) as resumed:
                steps = resumed.steps()
                assert [r.plan_index for r in steps] == list(range(len(resumed.plan.steps)))  # no gap, no duplicate
                assert all(steps[i] == record for i, record in at_kill.items() if record.status == "ok")
                assert resumed.outcome() == "complete"
            assert not [p.name for p in tmp_path.glob(f"{copy.name}-*")]  # one file when no process has it open
            copies.append((copy, original, {i: r for i, r in at_kill.items() if i in committed}))
        for original in originals:  # each original's own resume, to the end
            if not _complete(original):
                writer.start(["--resume", original, "--quiet"])
                assert writer.finish() == 0
    finally:
        writer.close()
    finals = {original: _steps(original) for original in originals}
    for copy, original, held in copies:
        assert all(finals[original][i] == record for i, record in held.items()), copy
    assert kills >= 45, kills
    assert sum(len(held) for _, _, held in copies) > 0
    assert not [p.name for p in tmp_path.iterdir() if p.name.endswith(("-wal", "-shm"))]
    # a journal may stay beside a session killed while SQLite created it and never written again: SQLite leaves
    # such a cold journal (empty, or its header not yet written) in place and ignores it; a hot one would be a
    # step that no reader rolled back
    hot = [p.name for p in tmp_path.iterdir() if p.name.endswith("-journal") and _hot_journal(p)]
    assert not hot
    print(f"{kills} kills, {len(copies)} copies, {in_flight} held the step in flight, "
          f"{len(originals)} original sessions, {time.monotonic() - t0:.1f} s")


@pytest.mark.slow
def test_two_writers_started_together_one_runs_the_other_exits_2_at_once(tmp_path: Path) -> None:
    """Two fresh ``acquire --resume`` processes (the installed entry point, acquire/commands/launch.py) started
    together."""
    site = tmp_path / "fast.yaml"
    site.write_text(FAST_SITE)
    path = tmp_path / "s.session"
    writer = Writer(tmp_path)
    try:
        writer.start(["--robot", "mock:ur5e?fault=protective_stop@5", "--tracker", "mock", "--config", site,
                      "--session", path, "--quiet"])
        assert writer.finish() == 1  # a session to resume: 4 steps recorded
    finally:
        writer.close()
    with Session.open(path) as session:
        runs_before, steps_before = len(session.runs()), len(session.steps())
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"}
    cmd = [sys.executable, "-m", "acquire.commands.launch", "--resume", str(path), "--realtime", "--quiet"]
    started = time.monotonic()
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path)
             for _ in range(2)]
    ended: dict[int, float] = {}
    while len(ended) < 2 and time.monotonic() - started < 120:
        for k, proc in enumerate(procs):
            if k not in ended and proc.poll() is not None:
                ended[k] = time.monotonic() - started
        time.sleep(0.005)
    outputs = [proc.communicate(timeout=10) for proc in procs]
    codes = [proc.returncode for proc in procs]
    assert sorted(codes) == [0, 2], (codes, outputs)
    loser, winner = (0, 1) if codes[0] == 2 else (1, 0)
    # refused at once, not after waiting on the winner's lock: well before the winner's resumed run ends (both
    # from the start of both processes, interpreter start-up included; relative, so a loaded host cannot fail it)
    assert ended[loser] < min(5.0, 0.5 * ended[winner]), ended
    out, err = outputs[loser]
    assert out == ""  # refused before the plan was even shown: no device was opened, nothing moved
    line = _one_line_of(err)
    assert line.startswith("acquire: error: ")
    assert re.search(rf"is being written by process {procs[winner].pid}\b", line), line
    assert "session:" in outputs[winner][0]
    with Session.open(path) as session:
        assert len(session.runs()) == runs_before + 1  # only the winner ran
        assert [r.plan_index for r in session.steps()] == list(range(len(session.plan.steps)))
        assert len(session.steps()) > steps_before
    print(f"refused in {ended[loser] * 1e3:.0f} ms from the start: {line}")


def _one_line_of(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, lines
    return lines[0]
