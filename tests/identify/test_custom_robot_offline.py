"""Sessions and results of a custom robot YAML read offline (issue 39, item 4): the session records the model
itself (``config.robot_model``), the result too (``nominal.model``), so ``identify SESSION``, ``identify compare``
and ``identify compensate`` work where the YAML is not (moved, or another machine); a session that names a custom
model without recording it says to give the file with ``--robot FILE``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from acquire.running.session import Session
from config.robots import robot_from_document
from drivers.base import TrackerReading
from identify.commands.cli import main
from kinematics.dh import points_from_joints
from session.records import StepRecord
from tests._session_writer import CONFIG, ROBOT, TRACKER, small_plan

ARM = {  # a 3R arm of the operator's, named as the writer's plan names its robot
    "schema": 1, "name": "test-arm", "vendor": "the lab", "description": "a planar-ish 3R test arm",
    "source": "measured by hand", "joints": "RRR",
    "dh": [{"theta": 0.0, "d": 0.3, "a": 0.05, "alpha": math.pi / 2}, {"theta": 0.0, "d": 0.0, "a": 0.4, "alpha": 0.0},
           {"theta": 0.0, "d": 0.02, "a": 0.3, "alpha": 0.0}],
    "limits": [[-3.0, 3.0]] * 3, "home": [0.0, -1.0, 0.5], "max_speed": [1.0] * 3, "default_speed": [0.5] * 3,
    "default_acceleration": [1.0] * 3,
}


def _session(path: Path, seed: int, record: bool = True) -> Path:
    """A complete session of the test arm (its nominal with a 0.1 mm twist of the truth and 20 um noise)."""
    model = robot_from_document(ARM, "test").nominal
    truth = model.__class__(model.joint_types, model.theta, model.d + 1e-4, model.a, model.alpha,
                            tool=np.array([0.05, 0.02, 0.1]))
    rng = np.random.default_rng(seed)
    config = {**CONFIG, **({"robot_model": ARM} if record else {})}
    with Session.create(path, small_plan(), config, ROBOT, TRACKER) as session:
        session.begin_run()
        for step in session.plan.steps:
            point = points_from_joints(truth, np.array([step.q]))[0] + rng.normal(0, 2e-5, 3)
            reading = TrackerReading(point, 0.5, 2e-5, "ok")
            session.record_step(StepRecord.from_step(step, q_act=step.q, position=tuple(point), sigma=2e-5,
                                                     samples=1, rejected=0, status="ok", reason="", t_start=0.0,
                                                     t_end=1.0, readings=[reading], used=[True]))
        session.end_run("complete")
    return path


def test_a_session_and_its_result_read_their_recorded_custom_model(tmp_path, capsys):
    one, two = _session(tmp_path / "one.session", 1), _session(tmp_path / "two.session", 2)
    result = tmp_path / "one.yaml"
    assert main([str(one), "--out", str(result)]) in (0, 3)  # no test-arm.yaml anywhere: the session's own model
    doc = yaml.safe_load(result.read_text())
    assert doc["nominal"]["name"] == "test-arm" and doc["nominal"]["model"]["dh"][0]["d"] == pytest.approx(0.3)
    assert doc["source_path"] == str(one.resolve())  # what the data file is, for --verification (item 5)
    capsys.readouterr()
    assert main(["compare", str(one), str(two)]) in (0, 3)
    assert "unknown name" not in capsys.readouterr().err
    targets = tmp_path / "t.csv"
    targets.write_text("x,y,z\n0.3,0.1,0.5\n")
    assert main(["compensate", str(result), "--targets", str(targets), "--out", str(tmp_path / "o.csv")]) in (0, 3)
    assert "nominal test-arm" in capsys.readouterr().out


def test_a_session_that_names_a_custom_model_it_does_not_record_says_to_give_the_file(tmp_path, capsys):
    old = _session(tmp_path / "old.session", 1, record=False)
    assert main([str(old)]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "--robot FILE" in err and "does not record" in err, err
    arm = tmp_path / "arm.yaml"
    arm.write_text(yaml.safe_dump(ARM))
    assert main([str(old), "--robot", str(arm)]) in (0, 3)
