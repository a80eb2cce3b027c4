"""Full-pose readings in a session (issue 35): the mock tracker's 6-DoF mode (``mock?orientation=SIGMA_R``) records
each reading's target-frame orientation and each step's average (``readings.rx..sigma_r``, ``step_orientations``),
the session's measurements carry them, and an old session (schema of commit e5199c1, no such columns) gains them
when resumed while its earlier records read as before."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from acquire.commands.cli import main
from acquire.running.session import Session
from drivers.sim.rig import SimulatedRig
from identify.io.session_measurements import read_session
from kinematics.dh import flange_frames
from session.schema import columns
from tests.session.test_compat import _old_session

SIGMA_R = 2e-4  # rad per axis, per reading


def test_a_six_dof_session_records_orientations_and_identify_uses_them(tmp_path: Path,
                                                                        capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "six.session"
    tracker = f"mock?seed=3&orientation={SIGMA_R}"
    assert main(["--robot", "mock:ur5e?seed=3", "--tracker", tracker, "--session", str(path), "--steps", "8",
                 "--samples", "4", "--free-poses", "4", "--quiet"]) == 0
    capsys.readouterr()
    with Session.open(path) as session:
        steps = [s for s in session.steps() if s.status == "ok"]
    assert steps and all(len(s.frames) == 1 and s.frames[0].tp == 1 for s in steps)
    assert all(r.rotvec is not None and r.sigma_r == SIGMA_R for s in steps for r in s.readings)
    # each step's average is the kept readings' mean, with the device's sigma_r over sqrt(kept)
    for s in steps[:5]:
        kept = [r.rotvec for r, u in zip(s.readings, s.used, strict=True) if u]
        mean = Rotation.from_rotvec(np.array(kept)).mean().as_rotvec()
        np.testing.assert_allclose(s.frames[0].rotvec, mean, atol=1e-12)
        assert s.frames[0].sigma_r == pytest.approx(SIGMA_R / np.sqrt(len(kept)))
    # and the averages lie within their noise of the rig's true target frame at the measured joints
    rig = SimulatedRig.from_spec("mock:ur5e?seed=3", tracker)
    errors = []
    for s in steps:
        flange, _ = flange_frames(rig.truth, np.array(s.q_act)[None])
        true = Rotation.from_matrix(flange[0] @ rig.target_frames[0])
        errors.append((Rotation.from_rotvec(s.frames[0].rotvec) * true.inv()).as_rotvec() / s.frames[0].sigma_r)
    errors = np.array(errors)
    assert np.sum(errors**2) / errors.size == pytest.approx(1.0, abs=5 * np.sqrt(2.0 / errors.size))
    content, _ = read_session(path)
    meas = content.measurements
    assert np.all(meas.oriented) and len(meas) == len(steps)
    np.testing.assert_allclose(meas.sigma_r, [s.frames[0].sigma_r for s in steps])


def test_an_old_session_resumed_with_a_six_dof_tracker_keeps_its_records(tmp_path: Path,
                                                                          capsys: pytest.CaptureFixture[str]) -> None:
    path = _old_session(tmp_path)
    with Session.open(path) as session:
        before = session.steps()
    with sqlite3.connect(path) as db:
        assert "rx" not in columns(db, "readings") and not columns(db, "step_orientations")
    db.close()
    assert main(["--resume", str(path), "--quiet"]) == 0
    capsys.readouterr()
    with sqlite3.connect(path) as db:  # the writer added the columns; old readings have none
        assert {"rx", "ry", "rz", "sigma_r"} <= columns(db, "readings") and columns(db, "step_orientations")
        assert db.execute("SELECT count(*) FROM readings WHERE rx IS NOT NULL").fetchone()[0] == 0
        assert db.execute("PRAGMA user_version").fetchone()[0] == 1
    db.close()
    with Session.open(path) as session:
        after = {s.plan_index: s for s in session.steps()}
        meas = session.to_measurements()
    assert all(after[s.plan_index] == s for s in before if s.plan_index != 4)
    assert meas.rotvec is None and not meas.oriented.any()
