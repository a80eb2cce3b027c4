"""``acquire --robot mock:ur5e --tracker emscon:sim?...`` end to end: the emScon client speaks the TPI over loopback to
the simulated server measuring the mock robot's rig (drivers/trackers/emscon_sim.py); faults scheduled on the server
(a broken beam, a restart, garbage, silence) lose no step, and the session identifies the simulated truth."""

from __future__ import annotations

import json
import sqlite3

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

ROBOT = "mock:ur5e?seed=3"
SMALL = ["--steps", "12", "--samples", "3", "--free-poses", "6", "--quiet"]
NOISE = 5e-5  # emscon:sim's default noise, m per axis
TRACKER = "emscon:sim?meas_time=0.01&timeout=0.3&fault=beam_broken@20x2,drop@40,garbage@60,silence@80"


@pytest.mark.slow
def test_emscon_sim_session_with_faults_identifies_the_truth(tmp_path, capsys):
    path = tmp_path / "s.session"
    assert main(["--robot", ROBOT, "--tracker", TRACKER, "--session", str(path), *SMALL]) == 0
    assert "validation of the plain model on" in capsys.readouterr().out
    with Session.open(path) as session:
        assert session.outcome() == "complete" and not session.missing_indices()
        steps, meas = session.steps(), session.to_measurements()
        retries = [e[3] for e in session.events() if e[2] == "retry"]
        assert [s.plan_index for s in steps] == list(range(len(session.plan.steps)))  # none lost, none twice
    assert len(retries) == 2 and all("BeamLost" in r and "status 10004" in r for r in retries)
    with sqlite3.connect(path) as db:
        tracker = json.loads(dict(db.execute("SELECT key, value FROM meta").fetchall())["tracker"])
    assert tracker["model"].startswith("Leica emScon tracker") and tracker["details"]["units"].startswith("m, rad")
    assert tracker["details"]["environment"].startswith("20 degC, 1013.25 mbar, 50 %RH")
    assert tracker["details"]["reflector"].startswith("RRR 1.5in (id 1")
    truth = SimulatedRig.from_spec(RobotSpec.parse(ROBOT), TrackerSpec.parse("mock"), VirtualClock()).truth
    model = model_from_dict(yaml.safe_load(path.with_suffix(".result.yaml").read_text()))
    q_check = random_poses(load_robot("ur5e").limits, 200, np.random.default_rng(0))
    err = points_from_joints(model, q_check) - points_from_joints(truth, q_check)
    rms = np.sqrt(np.mean(np.sum(err**2, axis=1)))
    assert rms < 2.5 * prediction_rms_bound(truth, meas.q[~meas.check], q_check, NOISE / np.sqrt(3))


def test_emscon_sim_options_are_checked_in_one_line(tmp_path, capsys):
    for tracker, words in (("emscon:sim?fault=explode", "fault 'explode' must be NAME"),
                           ("emscon:sim?noise=-1", "noise=-1"),
                           ("emscon:sim?probe=7dof", "option probe=7dof must be none or 6dof"),
                           ("emscon:sim?angle_noise=1", "angle_noise=1"),
                           ("emscon:127.0.0.9", "needs mock devices on both sides")):
        code = main(["--robot", ROBOT, "--tracker", tracker, "--session", str(tmp_path / "x.session"), *SMALL])
        err = capsys.readouterr().err
        assert code == 2 and words in err and err.count("\n") == 1, err


@pytest.mark.slow
def test_dry_run_says_what_the_tracker_will_be_asked(tmp_path, capsys):
    site = tmp_path / "site.yaml"
    site.write_text("schema: 1\ntracker:\n  settings: {temperature: 21.5, pressure: 990, humidity: 40, "
                    "reflector: RRR 0.5in, meas_time: 2.5}\n")
    assert main(["--robot", "ur5e", "--tracker", "emscon:192.168.0.1", "--config", str(site), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "tracker: Leica emScon TPI at 192.168.0.1:700" in out
    assert "environment: set to 21.5 degC, 990 mbar, 40 %RH" in out and "reflector: 'RRR 0.5in'" in out
    assert "measure stationary points of 2.5 s: 5 per step" in out
    assert "more than the site's measure timeout (10 s)" in out  # 5 x 2.5 s do not fit in 10 s
    assert main(["--robot", "ur5e", "--tracker", "emscon:192.168.0.1?meas_time=1", "--config", str(site),
                 "--dry-run"]) == 0
    assert "measure timeout" not in capsys.readouterr().out  # the spec's option wins over the site file's


def test_emscon_sim_continuous_session_with_faults_identifies_the_truth(tmp_path, capsys):
    """``--mode continuous``: every sweep streamed by continuous measurement by time, stamped on the tracker's own
    clock (its origin the tracker's boot: the fitted clock offset is the server's boot on the robot's clock); flagged
    points, a restart and garbage mid-stream are gaps, no sweep is lost. (A broken beam is tested on the wall clock,
    tests/drivers/trackers/test_emscon_stream.py: its relock every 0.2 s of wall time lets most of a sweep pass on
    the mock's virtual clock.)"""
    site = tmp_path / "site.yaml"
    site.write_text("schema: 1\nplan:\n  check_poses: 4\n  stream_rate: 50\n")
    path = tmp_path / "c.session"
    # packets (10 per virtual s) 2-59 stream the first sweep, 60-140 the second: each fault well inside a sweep, the
    # garbage 35 packets from the second one's end (a reconnect's wall time lets virtual time pass unstreamed)
    tracker = "emscon:sim?timeout=0.5&fault=stream_prism@30,stream_drop@75,stream_garbage@105"
    assert main(["--robot", ROBOT, "--tracker", tracker, "--mode", "continuous", "--config", str(site),
                 "--session", str(path), "--quiet"]) == 0
    capsys.readouterr()
    with Session.open(path) as session:
        assert session.outcome() == "complete" and not session.missing_indices()
        assert all(s.status == "ok" for s in session.steps())
        meas = session.to_measurements()
        boot = session.steps()[0].t_start  # within the run's first seconds: the server starts at connect
    with sqlite3.connect(path) as db:
        gaps = db.execute("SELECT count(*) FROM stream_gaps WHERE device = 'tracker'").fetchone()[0]
        rates = {r for (r,) in db.execute("SELECT tracker_rate FROM streams")}
    assert gaps == 3 and rates == {50.0}
    doc = yaml.safe_load(path.with_suffix(".result.yaml").read_text())
    offset = doc["clock"]["offset_s"]  # robot time = tracker time + offset; tracker time = rig time - boot
    assert abs(offset - (boot - 5000.25)) < 60 and doc["clock"]["offset_std_s"] < 1e-4
    truth = SimulatedRig.from_spec(RobotSpec.parse(ROBOT), TrackerSpec.parse("mock"), VirtualClock()).truth
    model = model_from_dict(doc)
    q_check = random_poses(load_robot("ur5e").limits, 200, np.random.default_rng(0))
    err = points_from_joints(model, q_check) - points_from_joints(truth, q_check)
    rms = np.sqrt(np.mean(np.sum(err**2, axis=1)))
    bound = prediction_rms_bound(truth, meas.q[~meas.check], q_check, NOISE)
    assert rms < 2.5 * bound, (rms, bound)


def test_dry_run_of_a_continuous_plan_says_the_time_separation(tmp_path, capsys):
    site = tmp_path / "site.yaml"
    site.write_text("schema: 1\nplan:\n  stream_rate: 300\n")
    assert main(["--robot", "ur5e", "--tracker", "emscon:192.168.0.1", "--mode", "continuous", "--config", str(site),
                 "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "measure continuously by time during each of the 6 sweeps: a point every 3 ms (333.333 per second)" in out
    assert "stamped with the tracker's own clock" in out and "a gap, and the measurement started again" in out
    assert main(["--robot", "ur5e", "--tracker", "emscon:192.168.0.1", "--mode", "step", "--dry-run"]) == 0
    assert "continuously" not in capsys.readouterr().out  # a stop-and-go plan streams nothing
    assert main(["--robot", "ur5e", "--tracker", "emscon:192.168.0.1?probe=6dof", "--mode", "both", "--config",
                 str(site), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "measure a 6-DoF probe (T-Mac class)" in out and "measure stationary 6-DoF poses of 1 s" in out
    assert "6-DoF points, of which the sweep records the tip's position" in out


def test_a_tracker_error_mid_sweep_ends_the_run_resumable_in_one_line(tmp_path, capsys):
    """A status the continuous measurement cannot go on with (an error packet for StartMeasurement with status 36,
    unknown error: not a broken beam, not a lost link) stops the arm and the streams: the sweep's attempt is kept as
    interrupted, the run ends as failed with the tracker's own words, the command says so in one line (exit 1), and
    the resume redoes the sweep and completes."""
    site = tmp_path / "site.yaml"
    site.write_text("schema: 1\nplan:\n  check_poses: 4\n  stream_rate: 50\n")
    path = tmp_path / "e.session"
    args = ["--mode", "continuous", "--config", str(site), "--session", str(path), "--quiet"]
    code = main(["--robot", ROBOT, "--tracker", "emscon:sim?timeout=0.5&fault=stream_error@30", *args])
    err = capsys.readouterr().err
    assert code == 1 and err.count("\n") == 1, err
    assert "run failed (device error:" in err and "status 36 (unknown error)" in err and "--resume" in err
    with Session.open(path) as session:
        runs, events = session.runs(), session.events()
        assert session.outcome() == "failed" and "status 36" in runs[-1].reason
        assert any(kind == "device error" and "StartMeasurement failed" in text for *_, kind, text in events)
    with sqlite3.connect(path) as db:
        attempts = db.execute("SELECT plan_index, status FROM streams ORDER BY id").fetchall()
    assert len(attempts) == 1 and attempts[0][1] == "interrupted"  # the samples up to the error are kept
    assert main(["--resume", str(path), "--tracker", "emscon:sim?timeout=0.5", "--quiet"]) == 0
    capsys.readouterr()
    with Session.open(path) as session:
        assert session.outcome() == "complete" and all(s.status == "ok" for s in session.steps())
    with sqlite3.connect(path) as db:
        statuses = [s for (s,) in db.execute("SELECT status FROM streams WHERE plan_index = ? ORDER BY id",
                                             (attempts[0][0],))]
    assert statuses == ["interrupted", "complete"]  # the resume redid the sweep


@pytest.mark.slow
def test_emscon_sim_6dof_probe_streams_orientations_that_the_fit_uses(tmp_path, capsys):
    """``probe=6dof --mode continuous``: continuous 6-DoF measurement by time; every streamed sample carries the
    probe's orientation (the session's ``tracker_samples.rx, ry, rz, sigma_r``) and the identification fits them with
    the clock: every orientation row kept, their residuals at the probe's stated noise."""
    angle = 2e-5  # emscon:sim's default angle_noise, rad per axis
    site = tmp_path / "site.yaml"
    site.write_text("schema: 1\nplan:\n  check_poses: 4\n  stream_rate: 50\n")
    path = tmp_path / "c.session"
    assert main(["--robot", ROBOT, "--tracker", "emscon:sim?probe=6dof", "--mode", "continuous", "--config",
                 str(site), "--session", str(path), "--quiet"]) == 0
    capsys.readouterr()
    with Session.open(path) as session:
        meas = session.to_measurements()
    streamed = meas.streamed
    assert streamed.sum() > 1000 and np.all(meas.oriented) and np.allclose(meas.sigma_r[streamed], angle)
    doc = yaml.safe_load(path.with_suffix(".result.yaml").read_text())
    orientation = doc["residuals"]["orientation"]
    assert orientation["samples"] == int(np.sum(~meas.check)) and orientation["rejected"] == 0, orientation
    # 3D RMS of the streamed rows' sqrt(3) x 2e-5 rad (the few averaged steps' are smaller): within 10 %
    assert 0.9 * np.sqrt(3) * angle < orientation["rms_rad"] < 1.1 * np.sqrt(3) * angle, orientation
