"""``acquire --robot mock:ur5e --tracker emscon:sim?...`` end to end: the emScon client speaks the TPI over loopback to
the simulated server measuring the mock robot's rig (drivers/trackers/emscon_sim.py); faults scheduled on the server
(a broken beam, a restart, garbage, silence) lose no step, and the session identifies the simulated truth."""

from __future__ import annotations

import json
import sqlite3

import numpy as np
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
                           ("emscon:127.0.0.9", "needs mock devices on both sides")):
        code = main(["--robot", ROBOT, "--tracker", tracker, "--session", str(tmp_path / "x.session"), *SMALL])
        err = capsys.readouterr().err
        assert code == 2 and words in err and err.count("\n") == 1, err


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
