"""Issue 13: files and sessions that never lose data.

Each case a new user met: an output that is an input, an existing output, missing folders, a session copied
alone, a second writer, and resumes that ignored what the operator said. Every refusal is one line with exit 2
and leaves the input's bytes as they were. Real SQLite files throughout.
"""

from __future__ import annotations

import os
import shutil
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from acquire.commands.cli import main as acquire_main
from acquire.running.resume import ResumeRefused, resume_settings
from acquire.running.session import Session
from identify.commands.cli import main as identify_main
from session.backup import backup_session
from session.schema import SessionBusy, SessionError
from tests._session_writer import CONFIG, ROBOT, TRACKER, record_for, small_plan

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "identify" / "data" / "sample_ur5e.csv"
SMALL = ["--steps", "12", "--samples", "3", "--free-poses", "6", "--quiet"]
SIDE_FILES = ("-journal", "-wal", "-shm")


def _one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, lines
    return lines[0]


def _side_files(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(SIDE_FILES) or ".tmp" in p.name
                  or ".creating-" in p.name)


@pytest.fixture(scope="module")
def session_file(tmp_path_factory) -> Path:
    """A complete mock session (made once; tests copy it)."""
    folder = tmp_path_factory.mktemp("made")
    path = folder / "s.session"
    assert acquire_main(["--robot", "mock:ur5e?seed=3", "--tracker", "mock", "--session", str(path), *SMALL]) == 0
    return path


@pytest.fixture
def session_copy(tmp_path: Path, session_file: Path) -> Path:
    path = tmp_path / "s.session"
    shutil.copyfile(session_file, path)
    return path


# --- outputs: never an input, never an existing file without --force, never a folder made --------------------


def test_identify_out_equal_to_the_input_csv_is_refused(tmp_path: Path, capsys) -> None:
    good = tmp_path / "good.csv"
    shutil.copyfile(SAMPLE, good)
    before = good.read_bytes()
    assert identify_main([str(good), "--out", str(good)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith("identify: error: --out") and "is the input" in line
    assert good.read_bytes() == before
    # the same file under another name (a hard link, a symbolic link, a relative path) is the same file
    os.link(good, tmp_path / "hard.csv")
    os.symlink(good, tmp_path / "soft.csv")
    for other in (tmp_path / "hard.csv", tmp_path / "soft.csv", Path(os.path.relpath(good))):
        assert identify_main([str(good), "--csv", str(other), "--force"]) == 2
        assert "is the input" in _one_line(capsys.readouterr().err)
    assert good.read_bytes() == before


@pytest.mark.slow
def test_identify_out_equal_to_the_input_session_is_refused(session_copy: Path, capsys) -> None:
    before = session_copy.read_bytes()
    for option in ("--out", "--report", "--json-out", "--csv"):
        assert identify_main([str(session_copy), option, str(session_copy), "--force"]) == 2
        assert f"error: {option} " in _one_line(capsys.readouterr().err)
    assert session_copy.read_bytes() == before
    with Session.open(session_copy) as session:
        assert session.outcome() == "complete"


def test_two_outputs_on_one_file_are_refused_before_any_work(tmp_path: Path, capsys) -> None:
    out = tmp_path / "r.yaml"
    t = time.perf_counter()
    assert identify_main([str(SAMPLE), "--out", str(out), "--json-out", str(out)]) == 2
    assert time.perf_counter() - t < 0.5  # refused before the identification
    assert "also the output of --out" in _one_line(capsys.readouterr().err)
    assert not out.exists()


def test_existing_output_needs_force_and_is_replaced_whole(tmp_path: Path, capsys) -> None:
    out = tmp_path / "r.yaml"
    out.write_text("precious: true\n")
    assert identify_main([str(SAMPLE), "--out", str(out)]) == 2
    line = _one_line(capsys.readouterr().err)
    assert "already exists; pass --force to replace it" in line
    assert out.read_text() == "precious: true\n"
    assert identify_main([str(SAMPLE), "--out", str(out), "--force"]) == 0
    assert "joints" in yaml.safe_load(out.read_text())
    assert _side_files(tmp_path) == []


def test_missing_folders_are_an_error_not_created(tmp_path: Path, capsys) -> None:
    target = tmp_path / "nonexistent" / "dir" / "r.yaml"
    assert identify_main([str(SAMPLE), "--out", str(target)]) == 2
    assert "does not exist (it is not created" in _one_line(capsys.readouterr().err)
    assert not (tmp_path / "nonexistent").exists()
    assert acquire_main(["--robot", "mock:ur5e", "--tracker", "mock", "--session", str(target.with_suffix(".session")),
                         *SMALL]) == 2
    assert "does not exist" in _one_line(capsys.readouterr().err)
    assert not (tmp_path / "nonexistent").exists()


def test_acquire_export_never_replaces_silently(session_copy: Path, tmp_path: Path, capsys) -> None:
    existing = tmp_path / "existing.csv"
    existing.write_text("sweep,joint,q1,x,y,z\n" + "1,1,0,0,0,0\n" * 260)
    before, session_bytes = existing.read_bytes(), session_copy.read_bytes()
    assert acquire_main(["export", str(session_copy), "--csv", str(existing)]) == 2
    assert "already exists; pass --force" in _one_line(capsys.readouterr().err)
    assert existing.read_bytes() == before
    assert acquire_main(["export", str(session_copy), "--csv", str(session_copy), "--force"]) == 2
    assert "is the input" in _one_line(capsys.readouterr().err)
    assert session_copy.read_bytes() == session_bytes
    assert acquire_main(["export", str(session_copy), "--csv", str(existing), "--force"]) == 0
    assert existing.read_bytes() != before and existing.read_text().count("\n") > 50
    assert session_copy.read_bytes() == session_bytes  # a reader leaves the session as it was
    assert _side_files(tmp_path) == []


def test_a_log_is_never_written_into_the_session(session_copy: Path, capsys) -> None:
    before = session_copy.read_bytes()
    for option in ("--log", "--trace-io"):
        assert acquire_main(["--resume", str(session_copy), option, str(session_copy)]) == 2
        assert "a log is a file of its own" in _one_line(capsys.readouterr().err)
    assert session_copy.read_bytes() == before


def test_a_new_session_never_replaces_a_file_or_its_result(tmp_path: Path, capsys) -> None:
    path = tmp_path / "s.session"
    result = tmp_path / "s.result.yaml"
    result.write_text("precious: true\n")
    assert acquire_main(["--robot", "mock:ur5e", "--tracker", "mock", "--session", str(path), *SMALL]) == 2
    assert "result" in _one_line(capsys.readouterr().err)
    assert not path.exists() and result.read_text() == "precious: true\n"
    path.write_text("not mine")
    assert acquire_main(["--robot", "mock:ur5e", "--tracker", "mock", "--session", str(path), *SMALL, "--force"]) == 2
    assert "a session file is never overwritten" in _one_line(capsys.readouterr().err)
    assert path.read_text() == "not mine"


# --- one session = one file ----------------------------------------------------------------------------------


def test_the_session_file_alone_holds_every_committed_step(tmp_path: Path) -> None:
    path = tmp_path / "a.session"
    with Session.create(path, small_plan(), CONFIG, ROBOT, TRACKER) as session:
        session.begin_run()
        for i in range(len(session.plan.steps)):
            session.record_step(record_for(session.plan, i))
            copy = tmp_path / f"copy-{i}.session"
            shutil.copyfile(path, copy)  # while the writer has it open
            with Session.open(copy) as c:
                assert sorted(c.recorded_indices()) == list(range(i + 1))
                assert c.steps()[-1] == record_for(session.plan, i)
            copy.unlink()
            assert _side_files(tmp_path) == []  # no -wal, -shm or -journal between steps
        session.end_run("complete")
    assert [p.name for p in tmp_path.iterdir()] == ["a.session"]


def test_an_old_wal_session_is_read_and_converted_by_its_next_writer(tmp_path: Path) -> None:
    path = tmp_path / "old.session"
    with Session.create(path, small_plan(), CONFIG, ROBOT, TRACKER) as session:
        session.begin_run()
        session.record_step(record_for(session.plan, 0))
        session.end_run("failed", "robot fault")
    with sqlite3.connect(path) as db:  # as the previous version left it
        db.execute("PRAGMA journal_mode = WAL")
    with Session.open(path) as reader:
        assert reader.recorded_indices() == {0}
    with Session.open(path, write=True) as writer:
        writer.begin_run()
        writer.record_step(record_for(writer.plan, 1))
        writer.end_run("aborted", "")
    assert path.read_bytes()[18:20] == b"\x01\x01"  # rollback journal
    assert [p.name for p in tmp_path.iterdir()] == ["old.session"]


def test_backup_of_a_live_session(tmp_path: Path, capsys) -> None:
    path = tmp_path / "live.session"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "tests._session_writer", "write", str(path), "0.01"],
                            stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout.readline().strip() == "ready"
        acked = set()
        for k in range(5):
            acked.update(int(proc.stdout.readline()) for _ in range(3))
            dest = tmp_path / f"backup-{k}.session"
            assert acquire_main(["backup", str(path), str(dest)]) == 0
            assert "copied" in capsys.readouterr().out
            with Session.open(dest) as copy:
                got = copy.recorded_indices()
                assert acked <= got and got == set(range(len(got)))
                assert copy.steps() == [record_for(copy.plan, i) for i in sorted(got)]
    finally:
        proc.wait(timeout=60)
    assert proc.returncode == 0
    before = (tmp_path / "backup-0.session").read_bytes()
    assert acquire_main(["backup", str(path), str(tmp_path / "backup-0.session")]) == 2
    assert "already exists" in _one_line(capsys.readouterr().err)
    assert acquire_main(["backup", str(path), str(path), "--force"]) == 2
    assert "is the input" in _one_line(capsys.readouterr().err)
    assert (tmp_path / "backup-0.session").read_bytes() == before
    assert backup_session(path, tmp_path / "backup-0.session", force=True) == len(small_plan().steps)
    assert _side_files(tmp_path) == []


# --- one writer ----------------------------------------------------------------------------------------------


def test_a_second_writer_is_refused_naming_the_holder_and_readers_still_work(tmp_path: Path, capsys) -> None:
    path = tmp_path / "w.session"
    with Session.create(path, small_plan(), CONFIG, ROBOT, TRACKER) as writer:
        writer.begin_run()
        writer.record_step(record_for(writer.plan, 0))
        t = time.perf_counter()
        with pytest.raises(SessionBusy, match=f"is being written by process {os.getpid()} "):
            Session.open(path, write=True)
        assert time.perf_counter() - t < 0.5
        with Session.open(path) as reader:  # readers take no lock
            assert reader.recorded_indices() == {0}
            with pytest.raises(SessionError, match="opened for reading only"):
                reader.event("pause", "a reader never writes")
        assert acquire_main(["--resume", str(path), "--quiet"]) == 2
        line = _one_line(capsys.readouterr().err)
        assert line.startswith("acquire: error: ") and f"process {os.getpid()}" in line
        writer.record_step(record_for(writer.plan, 1))  # the refused writer changed nothing
        writer.end_run("aborted", "")
    with Session.open(path, write=True) as again:  # the lock went with the writer
        assert again.recorded_indices() == {0, 1} and len(again.runs()) == 1


def test_the_entry_point_refuses_a_second_writer_before_the_heavy_imports(tmp_path: Path, capsys) -> None:
    from acquire.commands.launch import main as launch_main
    from acquire.commands.launch import resume_target

    assert resume_target(["--resume", "a.session", "--quiet"]) == Path("a.session")
    assert resume_target(["--resume=b.session"]) == Path("b.session")
    assert resume_target(["--resume", "a.session", "--dry-run"]) is None
    assert resume_target(["export", "a.session", "--csv", "x.csv"]) is None
    path = tmp_path / "l.session"
    with Session.create(path, small_plan(), CONFIG, ROBOT, TRACKER):
        assert launch_main(["--resume", str(path)]) == 2
        assert f"is being written by process {os.getpid()}" in _one_line(capsys.readouterr().err)
    assert launch_main(["--resume", str(path), "--log", str(path)]) == 2  # refused by the full command...
    assert "a log is a file of its own" in _one_line(capsys.readouterr().err)
    with Session.open(path, write=True):  # ... and the lock it took first was released
        pass
    assert launch_main(["--resume", str(tmp_path / "none.session")]) == 2
    assert "no such session file" in _one_line(capsys.readouterr().err)


# --- resume does what the operator means ---------------------------------------------------------------------


def _interrupted(tmp_path: Path) -> Path:
    path = tmp_path / "r.session"
    assert acquire_main(["--robot", "mock:ur5e?seed=3&fault=protective_stop@10", "--tracker", "mock",
                         "--session", str(path), *SMALL]) == 1
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith("r.session")] == ["r.session"]  # one file
    return path


@pytest.mark.slow
@pytest.mark.parametrize(("extra", "named"), [
    (["--steps", "20"], "--steps 20"),
    (["--samples", "9"], "--samples 9"),
    (["--robot", "mock:ur10e"], "--robot mock:ur10e"),
    (["--robot", "mock:ur5e?seed=4"], "--robot mock:ur5e?seed=4"),
    (["--tracker", "serial:/dev/ttyUSB0"], "--tracker serial:/dev/ttyUSB0"),
    (["--config", "missing.yaml"], "missing.yaml"),
    (["--config", "plan.yaml"], "plan.steps_per_sweep"),
    (["--config", "sweeps.yaml"], "plan.sweep_ranges"),
])
def test_resume_refuses_what_would_change_the_plan(tmp_path: Path, capsys, monkeypatch, extra, named) -> None:
    import drivers.registry as registry

    path = _interrupted(tmp_path)
    capsys.readouterr()
    (tmp_path / "plan.yaml").write_text("schema: 1\nplan:\n  steps_per_sweep: 36\n")
    (tmp_path / "sweeps.yaml").write_text("schema: 1\nplan:\n  sweep_ranges: [null, [-2, -1], null, null, null, null]"
                                          "\n")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(registry, "open_robot", lambda *a, **k: pytest.fail("a device was opened"))
    before = path.read_bytes()
    assert acquire_main(["--resume", str(path), "--quiet", *extra]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith("acquire: error: ") and named in line, line
    with Session.open(path) as session:
        assert len(session.runs()) == 1
    assert _side_files(tmp_path) == []
    del before  # the lock's writer record may be refreshed; the steps and runs are what must not change


@pytest.mark.slow
def test_resume_takes_new_connection_details_and_records_them(tmp_path: Path, capsys) -> None:
    path = _interrupted(tmp_path)
    site = tmp_path / "site.yaml"
    site.write_text("schema: 1\ntimeouts:\n  move: 60.0\nretries: 5\nplan:\n  steps_per_sweep: 12\n")
    assert acquire_main(["--resume", str(path), "--quiet", "--config", str(site), "--steps", "12",
                         "--tracker", "mock?fault=target_lost@2x1"]) == 0
    with Session.open(path) as session:
        events = [e for e in session.events() if e[2] == "connection"]
        assert len(events) == 1
        assert "timeouts.move: 120.0 -> 60.0" in events[0][3] and "retries: 3 -> 5" in events[0][3]
        assert "tracker: mock -> mock?fault=target_lost@2x1" in events[0][3]
        assert session.header["connection"]["site"]["retries"] == 5
        assert session.header["config"]["site"]["retries"] == 3  # the original stays
        assert [r.outcome for r in session.runs()] == ["failed", "complete"]


def test_resume_may_change_a_real_robots_address_not_the_robot() -> None:
    header = {"config": {"robot_spec": "ur5e@192.168.1.10", "tracker_spec": "ipp://10.0.0.5:1294",
                         "site": {"schema": 1, "plan": {"steps_per_sweep": 12}}}}
    settings = resume_settings(header, "ur5e@192.168.1.11", "ipp://10.0.0.6", None, {"--steps": 12})
    assert str(settings.robot) == "ur5e@192.168.1.11" and str(settings.tracker) == "ipp://10.0.0.6"
    assert settings.changes == ("robot: ur5e@192.168.1.10 -> ur5e@192.168.1.11",
                                "tracker: ipp://10.0.0.5:1294 -> ipp://10.0.0.6")
    for robot, tracker, steps in (("ur10e@192.168.1.10", None, None), ("mock:ur5e", None, None),
                                  (None, "serial:/dev/ttyUSB0", None), (None, None, 36)):
        with pytest.raises(ResumeRefused):
            resume_settings(header, robot, tracker, None, {"--steps": steps})


def test_a_complete_session_is_reported_and_nothing_moves(session_copy: Path, capsys, monkeypatch) -> None:
    import drivers.registry as registry

    monkeypatch.setattr(registry, "open_robot", lambda *a, **k: pytest.fail("a device was opened"))
    with Session.open(session_copy) as session:
        runs, steps = session.runs(), session.steps()
    assert acquire_main(["--resume", str(session_copy), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "is complete: all" in out and "nothing to do" in out
    with Session.open(session_copy) as session:
        assert session.runs() == runs and session.steps() == steps
    assert not session_copy.with_suffix(".result.yaml").exists()  # nothing rewritten (none was copied here)


@pytest.mark.slow
def test_a_run_that_died_after_its_last_step_is_closed_and_identified_on_resume(session_copy: Path, capsys,
                                                                                monkeypatch) -> None:
    """Killed after the last step's commit, before the run was closed and the session identified: the resume
    connects nothing, closes the dead run, ends its own as complete and writes the result and report."""
    import drivers.registry as registry

    with sqlite3.connect(session_copy) as db:  # what the file holds after such a kill
        db.execute("UPDATE runs SET outcome = 'running', ended = NULL, reason = '' "
                   "WHERE id = (SELECT max(id) FROM runs)")
    with Session.open(session_copy) as session:
        assert session.outcome() == "running" and session.next_index() is None
        steps, runs = session.steps(), len(session.runs())
    monkeypatch.setattr(registry, "open_robot", lambda *a, **k: pytest.fail("a device was opened"))
    assert acquire_main(["--resume", str(session_copy), "--quiet"]) == 0
    capsys.readouterr()
    with Session.open(session_copy) as session:
        assert session.outcome() == "complete" and session.steps() == steps and len(session.runs()) == runs + 1
    assert session_copy.with_suffix(".result.yaml").exists() and session_copy.with_suffix(".report.html").exists()


@pytest.mark.slow
def test_missing_steps_are_measured_again_on_request_keeping_the_first_attempt(tmp_path: Path, capsys) -> None:
    path = tmp_path / "m.session"
    log = tmp_path / "run.log"
    # from measurement 80 on (free and check poses) every reading is lost: those steps and their second
    # attempts go missing
    assert acquire_main(["--robot", "mock:ur5e?seed=3", "--tracker", "mock?fault=target_lost@80x100000",
                         "--session", str(path), *SMALL]) == 0
    with Session.open(path) as session:
        missing = session.missing_indices()
        total = len(session.plan.steps)
    assert len(missing) > 5
    capsys.readouterr()
    assert acquire_main(["--resume", str(path), "--quiet"]) == 0  # complete: nothing moves without the option
    assert f"{len(missing)} missing" in capsys.readouterr().out
    assert acquire_main(["--resume", str(path), "--remeasure-missing", "--log", str(log)]) == 0
    with Session.open(path) as session:
        assert session.missing_indices() == [] and len(session.steps()) == total
        assert all(session.attempts(i) == 3 for i in missing)  # first run: 2 attempts; this run: 1
    with sqlite3.connect(path) as db:
        kept = db.execute("SELECT plan_index, attempt, status FROM retired_steps ORDER BY plan_index, attempt")
        assert [tuple(r) for r in kept] == [(i, a, "missing") for i in missing for a in (1, 2)]
    progress = [line for line in log.read_text().splitlines() if " step " in line or " again " in line]
    assert len(progress) == len(missing) and f"again 1/{len(missing)} " in progress[0]  # counts what remains
    assert acquire_main(["--remeasure-missing"]) == 2
