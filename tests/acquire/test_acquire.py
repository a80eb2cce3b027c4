"""The acquire command end to end in mock mode: identification against the simulated truth, dry runs,
injected faults, and crash/resume through real SIGKILLs of the real command."""

from __future__ import annotations

import contextlib
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

from acquire.commands.cli import main
from acquire.running.session import Session
from config.robots import load_robot
from drivers.clock import VirtualClock
from drivers.sim.rig import SimulatedRig
from drivers.spec import RobotSpec, TrackerSpec
from identify.estimator.bounds import prediction_rms_bound
from identify.simulators.simulate import random_poses
from kinematics.dh import model_from_dict, points_from_joints
from tests._acquire_writer import Writer
from tests._session_steps import recorded_steps

ROBOT = "mock:ur5e?seed=3"
SMALL = ["--steps", "12", "--samples", "3", "--free-poses", "6", "--quiet"]
NOISE = 5e-5  # the mock tracker's default noise, m per axis


def _run(tmp_path: Path, *extra: str, robot: str = ROBOT, tracker: str = "mock") -> tuple[int, Path]:
    path = tmp_path / "s.session"
    code = main(["--robot", robot, "--tracker", tracker, "--session", str(path), *SMALL, *extra])
    return code, path


def _truth():
    return SimulatedRig.from_spec(RobotSpec.parse(ROBOT), TrackerSpec.parse("mock"), VirtualClock()).truth


def test_mock_session_identifies_the_simulated_truth(tmp_path, capsys):
    code, path = _run(tmp_path)
    assert code == 0
    assert "validation of the plain model on" in capsys.readouterr().out
    model = model_from_dict(yaml.safe_load(path.with_suffix(".result.yaml").read_text()))
    truth = _truth()
    with Session.open(path) as session:
        meas = session.to_measurements()
        assert session.outcome() == "complete"
    fit_q = meas.q[~meas.check]
    q_check = random_poses(load_robot("ur5e").limits, 200, np.random.default_rng(0))
    err = points_from_joints(model, q_check) - points_from_joints(truth, q_check)
    rms = np.sqrt(np.mean(np.sum(err**2, axis=1)))
    assert rms < 2.5 * prediction_rms_bound(truth, fit_q, q_check, NOISE / np.sqrt(3))


def test_dry_run_connects_nothing_and_refuses_plans_outside_limits(tmp_path, monkeypatch, capsys):
    import drivers.registry as registry

    def forbidden(*args, **kwargs):
        raise AssertionError("a dry run opened a driver")

    monkeypatch.setattr(registry, "open_robot", forbidden)
    monkeypatch.setattr(registry, "open_tracker", forbidden)
    assert main(["--robot", "ur5e", "--tracker", "mock", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "estimated duration" in out and "nothing was connected or moved" in out
    site = tmp_path / "site.yaml"
    # joint 6 turns the tool about the flange axis, clear of the cell at any angle: only the limit is broken (a
    # shoulder range would be refused first for driving the arm into the table: tests/acquire/test_safety.py)
    site.write_text("schema: 1\nplan:\n  sweep_ranges: [null, null, null, null, null, [-7.0, 0.0]]\n")
    assert main(["--robot", "ur5e", "--tracker", "mock", "--config", str(site), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert "plan refused" in err and "joint 6" in err and "outside its limits" in err


@pytest.mark.parametrize(("robot", "tracker"), [("ur5e@127.0.0.9", "mock"), ("mock:ur5e", "serial:/dev/ttyUSB9"),
                                               ("ur5e@127.0.0.9", "aruco:sim"), ("ur5e@127.0.0.9", "emscon:sim")])
def test_simulated_and_real_devices_are_refused_together_before_the_plan(tmp_path, capsys, robot, tracker):
    code, path = _run(tmp_path, "--yes", robot=robot, tracker=tracker)
    out, err = capsys.readouterr()
    assert code == 2 and out == "" and not path.exists()
    assert "needs mock devices on both sides" in err and err.count("\n") == 1


@pytest.mark.slow
def test_protective_stop_pauses_and_resume_completes_without_duplicates(tmp_path, capsys):
    code, path = _run(tmp_path, robot=ROBOT + "&fault=protective_stop@20")
    assert code == 1
    err = capsys.readouterr().err
    assert "protective" in err.lower() and f"acquire --resume {path}" in err
    with Session.open(path) as session:
        assert sorted(session.recorded_indices()) == list(range(19))
        total = len(session.plan.steps)
    assert main(["--resume", str(path), "--quiet"]) == 0
    with Session.open(path) as session:
        assert [s.plan_index for s in session.steps()] == list(range(total))
        assert [r.outcome for r in session.runs()] == ["failed", "complete"]


@pytest.mark.slow
def test_lost_target_is_retried_then_the_step_is_missing_and_measured_again_at_the_end(tmp_path):
    code, path = _run(tmp_path, tracker="mock?fault=target_lost@10x4")
    assert code == 0
    with Session.open(path) as session:
        steps = session.steps()
        assert all(s.status == "ok" for s in steps)  # measured again at the end of the run
        assert sum(1 for e in session.events() if e[2] == "retry") == 4
        assert [e[3] for e in session.events() if e[2] == "remeasure"] == ["measuring 1 missing step(s) again: 9"]
        assert len(steps) == len(session.plan.steps) and session.attempts(9) == 2
    with sqlite3.connect(path) as db:  # the first attempt is kept
        first = db.execute("SELECT plan_index, attempt, status, reason FROM retired_steps").fetchall()
    assert len(first) == 1 and first[0][:3] == (9, 1, "missing") and "TargetLost" in first[0][3]


@pytest.mark.parametrize(("robot", "tracker", "words"), [
    (ROBOT + "&fault=disconnect@15", "mock", "connection"),
    (ROBOT + "&fault=slow@15", "mock", "timeout"),
    (ROBOT + "&fault=emergency_stop@15", "mock", "emergency"),
])
def test_robot_faults_stop_the_run_and_keep_what_was_recorded(tmp_path, capsys, robot, tracker, words):
    code, path = _run(tmp_path, robot=robot, tracker=tracker)
    assert code == 1
    assert words in capsys.readouterr().err.lower()
    with Session.open(path) as session:
        assert sorted(session.recorded_indices()) == list(range(14))
        assert session.outcome() == "failed"


@pytest.mark.slow
def test_export_and_offline_identify_of_a_session(tmp_path, capsys):
    from identify.commands.cli import main as identify_main

    code, path = _run(tmp_path)
    assert code == 0
    csv = tmp_path / "out.csv"
    assert main(["export", str(path), "--csv", str(csv)]) == 0
    assert identify_main([str(csv), "--robot", "ur5e"]) == 0
    assert identify_main([str(path), "--robot", "ur5e"]) == 0
    out = capsys.readouterr().out
    assert out.count("Plain DH model (the result's top-level table)") == 3  # acquire, CSV, session


def test_bad_specs_and_sessions_give_one_line_and_exit_2(tmp_path, capsys):
    assert main(["--robot", "mock:ur5e", "--tracker", "seriall:/dev/x", "--dry-run"]) == 2
    assert main(["--resume", str(tmp_path / "none.session")]) == 2
    junk = tmp_path / "junk.session"
    junk.write_bytes(b"not a database at all")
    assert main(["--resume", str(junk)]) == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line]
    assert len(lines) == 3 and all(line.startswith("acquire: error:") for line in lines)


@pytest.mark.slow
def test_sigkill_at_random_moments_then_resume_equals_an_uninterrupted_run(tmp_path):
    """Kill the real command (``acquire``'s main in a forked child: tests/_acquire_writer.py, which spares each run
    the interpreter's start-up and the end-of-run identification) with SIGKILL at random moments, resume until
    complete: every plan step is recorded exactly once, with the commanded poses of the plan and positions that
    agree with an uninterrupted run of the same simulated robot within the tracker noise."""
    reference = tmp_path / "ref.session"
    first = ["--robot", ROBOT, "--tracker", "mock", *SMALL]
    path = tmp_path / "crash.session"
    rng = np.random.default_rng(7)
    kills = 0
    writer = Writer(tmp_path)
    try:
        writer.start([*first, "--session", reference])
        assert writer.finish() == 0
        for _ in range(40):
            pid = writer.start(["--resume", path, "--quiet"] if path.exists() else [*first, "--session", path])
            code = writer.until_acks(int(rng.integers(1, 10)))  # steps recorded (committed) by this run
            if code is None:
                time.sleep(float(rng.uniform(0.0, 0.003)))  # land anywhere in the next step, commit included
                with contextlib.suppress(ProcessLookupError):  # it may have just ended (and been reaped)
                    os.kill(pid, signal.SIGKILL)
                code = writer.finish()
            if code == 0:
                break
            assert code == -signal.SIGKILL, code
            kills += 1
    finally:
        writer.close()
    assert kills >= 8, kills
    with Session.open(path) as crashed, Session.open(reference) as ref:
        got, want = crashed.steps(), ref.steps()
        plan = crashed.plan
    assert [s.plan_index for s in got] == list(range(len(plan.steps)))
    assert [s.q_cmd for s in got] == [tuple(s.q) for s in plan.steps]
    ok = [(g, w) for g, w in zip(got, want, strict=True) if g.status == "ok" and w.status == "ok"]
    assert len(ok) == len(plan.steps)
    diff = np.array([np.subtract(g.position, w.position) for g, w in ok])
    assert np.abs(diff).max() < 8 * NOISE


@pytest.mark.slow
def test_ctrl_c_stops_motion_closes_the_session_and_prints_the_resume_command(tmp_path):
    """SIGINT to a real-time mock run mid-plan: exit 130, the run recorded as aborted, resumable."""
    path = tmp_path / "c.session"
    proc = subprocess.Popen([sys.executable, "-m", "acquire.commands.cli", "--robot", ROBOT, "--tracker", "mock",
                             *SMALL, "--realtime", "--session", str(path)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while recorded_steps(path) < 1 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    assert f"acquire --resume {path}" in err
    with Session.open(path) as session:
        assert session.outcome() == "aborted"
        done = len(session.recorded_indices())
        assert 1 <= done < len(session.plan.steps)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.session"]  # one file, no -journal/-wal/-shm


def test_a_real_robot_never_moves_without_confirmation(tmp_path, monkeypatch, capsys):
    """No terminal and no --yes: refused before any driver is opened."""
    import drivers.registry as registry

    def forbidden(*args, **kwargs):
        raise AssertionError("a driver was opened before the operator confirmed")

    monkeypatch.setattr(registry, "open_robot", forbidden)
    monkeypatch.setattr("sys.stdin.isatty", lambda: False)
    assert main(["--robot", "ur5e@127.0.0.1", "--tracker", "serial:/dev/ttyUSB9",
                 "--session", str(tmp_path / "r.session")]) == 2
    assert "needs confirmation" in capsys.readouterr().err
    assert not (tmp_path / "r.session").exists()


@pytest.mark.slow
def test_log_file_records_every_step(tmp_path):
    log = tmp_path / "run.log"
    code, path = _run(tmp_path, "--log", str(log))
    assert code == 0
    with Session.open(path) as session:
        total = len(session.plan.steps)
    assert sum(1 for line in log.read_text().splitlines() if " step " in line) == total
