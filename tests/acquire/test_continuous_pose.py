"""Continuous motion with a full-pose device: the mock tracker's 6-DoF mode (``mock?orientation=SIGMA_R``) streams each
sample's target-frame orientation, the session stores it with the streamed sample (``tracker_samples.rx, ry, rz,
sigma_r``), its measurement rows and the CSV export carry it, and the fit's rows use it; a file written before streamed
samples had orientation columns still opens (read as positions only) and a writer adds the columns."""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from acquire.running.session import Session
from identify.estimator.measurements import orientation_rows
from identify.io.csvio import read_measurements
from kinematics.dh import flange_frames
from tests.acquire.test_continuous import _run, _session

SIGMA_R = 2e-4  # rad per axis, the mock's orientation noise


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    """A small continuous session (two wrist sweeps, two check poses) of the 6-DoF mock; its path and rig."""
    folder = tmp_path_factory.mktemp("pose")
    session, arm, sensor, rig = _session(folder, "mock:ur5e", f"mock?latency=0.02&orientation={SIGMA_R}")
    with session:
        assert _run(session, arm, sensor, rig).outcome == "complete"
    return folder / "c.session", rig


def test_streamed_rows_carry_the_target_frames_orientation(recorded, tmp_path: Path) -> None:
    path, rig = recorded
    with Session.open(path) as session:
        meas = session.to_measurements()
        exported = session.export_csv(tmp_path / "c.csv")
    streamed = meas.streamed
    assert streamed.sum() > 500 and np.all(meas.oriented)  # every row, streamed or not, has its orientation
    assert np.allclose(meas.sigma_r[streamed], SIGMA_R)  # (a step's, of its averaged readings, is less)
    # against the true target frame at the rows' (coarsely timed) joints: the noise (0.35 mrad RMS in 3D) and the
    # coarse timing's error (a few ms at under 1 rad/s: about 0.1 mrad)
    rotation, _ = flange_frames(rig.truth, meas.q[streamed])
    true = Rotation.from_matrix(rotation @ rig.target_frames[0])
    turn = np.linalg.norm((Rotation.from_rotvec(meas.rotvec[streamed]) * true.inv()).as_rotvec(), axis=1)
    assert np.sqrt(3) * SIGMA_R * 0.9 < np.sqrt(np.mean(turn**2)) < np.sqrt(3) * SIGMA_R * 1.3
    # the export keeps them; the fit's rows use every one, streamed ones included, with the row's time
    back = read_measurements(tmp_path / "c.csv").measurements
    assert exported == len(back) == len(meas) and np.array_equal(back.streamed, streamed)
    assert np.allclose(back.rotvec, meas.rotvec, rtol=0, atol=1e-9) and np.allclose(back.sigma_r, meas.sigma_r)
    rows, notes = orientation_rows(meas)
    m = len(meas)
    assert len(rows) == 2 * m and not notes
    assert np.array_equal(rows.t[m:], meas.t, equal_nan=True) and np.array_equal(rows.streamed[m:], streamed)


def test_a_file_without_streamed_orientation_columns_opens_and_a_writer_adds_them(recorded, tmp_path: Path) -> None:
    path, _ = recorded
    old = tmp_path / "old.session"
    shutil.copy(path, old)
    with sqlite3.connect(old) as db:  # as a version before streamed orientations wrote it
        for name in ("rx", "ry", "rz", "sigma_r"):
            db.execute(f"ALTER TABLE tracker_samples DROP COLUMN {name}")
    with Session.open(path) as session:
        new = session.to_measurements()
    with Session.open(old) as session:  # a reader: the file is not changed
        meas = session.to_measurements()
    streamed = meas.streamed
    assert np.array_equal(meas.points, new.points) and np.array_equal(meas.q, new.q, equal_nan=True)
    assert np.all(np.isnan(meas.rotvec[streamed])) and np.all(meas.oriented[~streamed])  # the steps keep theirs
    with sqlite3.connect(old) as db:
        assert "rx" not in {r[1] for r in db.execute("PRAGMA table_info(tracker_samples)")}
    with Session.open(old, write=True):  # a writer migrates: the columns are back, empty
        pass
    with sqlite3.connect(old) as db:
        columns = {r[1] for r in db.execute("PRAGMA table_info(tracker_samples)")}
        filled = db.execute("SELECT count(*) FROM tracker_samples WHERE rx IS NOT NULL").fetchone()[0]
    assert {"rx", "ry", "rz", "sigma_r"} <= columns and filled == 0
