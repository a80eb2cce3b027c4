"""A camera's readings, corrected reading by reading with its shape-and-lens estimate so far, corrected again with the
session's final estimate (identify/sensors/recorrection.py), and the record of that through a session file."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")
from scipy.spatial.transform import Rotation  # noqa: E402
from scipy.stats import chi2  # noqa: E402

from acquire.running.session import Session  # noqa: E402
from drivers.base import Correction, TrackerReading  # noqa: E402
from drivers.camera.board_and_lens import BoardAndLens  # noqa: E402
from drivers.camera.imperfections import Imperfections  # noqa: E402
from drivers.camera.intrinsics import CameraIntrinsics  # noqa: E402
from identify.estimator.measurements import Measurements  # noqa: E402
from identify.io.session_measurements import session_measurements  # noqa: E402
from identify.sensors.recorrection import final_estimate, recorrected  # noqa: E402
from tests._session_writer import CONFIG, ROBOT, TRACKER, record_for, small_plan  # noqa: E402

CAMERA = CameraIntrinsics.from_fov(1280, 720, 60.0)
CORNERS = np.array([[(i - 4.5) * 0.025, (j - 3.0) * 0.025, 0.0] for i in range(10) for j in range(7)])  # A4 ChArUco
EXTENT = (0.275, 0.2)
NOISE_PX = 0.03  # per corner coordinate and frame


@dataclass(frozen=True)
class _Pose:
    rotation: np.ndarray
    translation: np.ndarray
    rms: float = 0.0


@dataclass(frozen=True)
class _Seen:
    object_points: np.ndarray
    image_points: np.ndarray


def _session(seed: int, views: int = 16) -> tuple[list[np.ndarray], list[TrackerReading]]:
    """A flange camera's readings (one frame a view) of the A4 board through a camera whose focal length is 0.2 %
    long and principal point (3, -2) px off (declared: focal_sigma 0.005, centre_sigma 5 px), each corrected by the
    tracker's estimate so far (TP: the board's centre, m, camera frame; sigma: 0.01 mm hypot the estimate's share);
    and the same images' poses through the true camera (the board centres the readings would be with the lens's
    errors known: their corner noise alone)."""
    rng = np.random.default_rng([seed, 36])
    true_camera = Imperfections(dfocal=0.002, dcx=3.0, dcy=-2.0).lens(CAMERA)
    shape = BoardAndLens(0.0, 0.0, EXTENT, focal_sigma=0.005, centre_sigma=5.0)
    exact, readings, noise = [], [], 1e-5
    for k in range(views):
        angle = math.radians(40.0) * math.sqrt(rng.uniform()) if k else math.radians(8.0)
        azimuth = rng.uniform(0.0, 2 * math.pi)
        rotation = (Rotation.from_rotvec([angle * math.cos(azimuth), angle * math.sin(azimuth), 0.0])
                    * Rotation.from_rotvec([0.0, 0.0, rng.uniform(-1.5, 1.5)])).as_matrix() @ np.diag([1, -1, -1])
        translation = np.array([rng.uniform(-0.05, 0.05), rng.uniform(-0.03, 0.03), rng.uniform(0.3, 0.75)])
        image = cv2.projectPoints(CORNERS, cv2.Rodrigues(rotation)[0], translation, true_camera.matrix,
                                  true_camera.distortion)[0].reshape(-1, 2) + rng.normal(0.0, NOISE_PX, (70, 2))
        _, rvec, tvec = cv2.solvePnP(CORNERS, image, CAMERA.matrix, CAMERA.distortion)
        corrected, correction = shape.take(_Pose(cv2.Rodrigues(rvec)[0], tvec.ravel()), _Seen(CORNERS, image),
                                           CAMERA, np.zeros(3))
        readings.append(TrackerReading(corrected.translation, float(k), sigma=math.hypot(noise, correction.bias),
                                       rotvec=Rotation.from_matrix(corrected.rotation).as_rotvec(),
                                       sigma_r=math.hypot(1e-5, correction.bias_r), correction=correction))
        exact.append(cv2.solvePnP(CORNERS, image, true_camera.matrix, true_camera.distortion)[2].ravel())
    return exact, readings


def _rows(readings: list[TrackerReading]) -> Measurements:
    m = len(readings)
    return Measurements("R", np.zeros((m, 1)), np.array([r.position for r in readings]), np.zeros(m, dtype=np.int64),
                        np.zeros(m, dtype=np.int64), np.array([r.sigma for r in readings]),
                        rotvec=np.array([r.rotvec for r in readings]), sigma_r=np.array([r.sigma_r for r in readings]))


def test_readings_corrected_with_the_final_estimate_are_closer_and_state_what_is_left() -> None:
    """The tracker's readings carry the error of the estimate they were corrected with (from one view for the first):
    0.19-0.36 mm RMS over 16 readings in these three sessions. Corrected again with each session's final estimate,
    what is left of the lens's error is over 2.5x smaller in each, and it is what the restated sigmas say: its RMS
    over their estimate's share is, pooled over the sessions, within the 0.1 % bounds of a chi-square of 9 degrees of
    freedom (the final estimate's error is one draw a session, over about three directions that matter)."""
    left, stated = [], []
    for seed in (1, 2, 3):
        exact, readings = _session(seed)
        final = final_estimate([r.correction for r in readings])
        meas = _rows(readings)
        again = recorrected(meas, [r.correction for r in readings])
        before = np.linalg.norm(meas.points - exact, axis=1)
        after = np.linalg.norm(again.points - exact, axis=1)
        assert np.sqrt(np.mean(after**2)) < np.sqrt(np.mean(before**2)) / 2.5, (seed, before, after)
        left.append(np.mean(after**2))
        stated.append(3 * np.mean([r.correction.shares(final.covariance)[0] ** 2 for r in readings]))
    ratio = math.sqrt(sum(left) / sum(stated))
    assert math.sqrt(chi2.ppf(0.001, 9) / 9) < ratio < math.sqrt(chi2.ppf(0.999, 9) / 9), ratio


def test_the_move_the_sigma_and_the_final_estimate_follow_the_record() -> None:
    """A row moves by its response times the final estimate minus what was applied; its sigma's share of the estimate
    is replaced by the final estimate's; the final estimate is the one of least total variance, whatever its
    place; a row without a correction stays as it was."""
    response = np.arange(12.0).reshape(6, 2) * 1e-3
    early = Correction(("bow_x", "dfocal"), response, response @ [0.1, 0.2], np.array([0.1, 0.2]),
                       np.diag([0.04, 0.09]), 0.5e-3, 0.2e-3)
    best = Correction(("bow_x", "dfocal"), response, response @ [0.3, 0.1], np.array([0.3, 0.1]),
                      np.diag([1e-4, 4e-4]), 0.02e-3, 0.01e-3)
    later = Correction(("bow_x", "dfocal"), response, response @ [0.3, 0.1], np.array([0.25, 0.15]),
                       np.diag([1e-3, 4e-3]), 0.05e-3, 0.03e-3)  # a resumed run's: fewer views behind it
    assert final_estimate([early, best, later]) is best
    meas = Measurements("R", np.zeros((3, 1)), np.ones((3, 3)), np.zeros(3, dtype=np.int64),
                        np.zeros(3, dtype=np.int64), np.full(3, 1e-3), rotvec=np.zeros((3, 3)),
                        sigma_r=np.full(3, 1e-3))
    again = recorrected(meas, [early, None, best])
    move = response @ np.array([0.3, 0.1]) - early.applied
    np.testing.assert_allclose(again.points[0], 1.0 - move[:3], atol=1e-15)
    np.testing.assert_allclose(again.points[1:], meas.points[1:], atol=0)
    np.testing.assert_allclose(Rotation.from_rotvec(again.rotvec[0]).as_rotvec(), -move[3:], atol=1e-12)
    bias, bias_r = early.shares(best.covariance)
    assert again.sigma[0] == pytest.approx(math.sqrt(1e-6 - 0.25e-6 + bias**2), rel=1e-12)
    assert again.sigma_r[0] == pytest.approx(math.sqrt(1e-6 - 0.04e-6 + bias_r**2), rel=1e-12)
    own = best.shares(best.covariance)[0]
    assert again.sigma[1] == 1e-3
    assert again.sigma[2] == pytest.approx(math.sqrt(1e-6 - 0.02e-3**2 + own**2), rel=1e-12)
    with pytest.raises(ValueError, match="2 corrections for 3 rows"):
        recorrected(meas, [early, best])


def test_a_session_keeps_each_steps_correction_and_its_measurements_are_corrected_again(tmp_path: Path) -> None:
    """Steps recorded with their readings' corrections read back equal (the JSON round trip keeps every float), the
    positions stored as measured; the session's measurements are those positions corrected again with the session's
    final estimate (the step of least variance), rows in plan order."""
    plan = small_plan()
    response = np.linspace(-1.0, 1.0, 18).reshape(6, 3) * 1e-3
    records = []
    for i in range(6):
        record = record_for(plan, i)
        if record.status == "ok":
            theta = np.array([0.1, -0.2, 0.05]) * (1 + i)
            correction = Correction(("bow_x", "dfocal", "dcx"), response + i * 1e-5, (response + i * 1e-5) @ theta,
                                    theta, np.eye(3) / (1 + i) ** 2, 3e-6, 1e-6)
            record = replace(record, corrections=((1, correction),))
        records.append(record)
    path = tmp_path / "camera.session"
    with Session.create(path, plan, CONFIG, ROBOT, TRACKER) as session:
        session.begin_run()
        for record in records:
            session.record_step(record)
        session.end_run("complete")
    with Session.open(path) as session:
        assert session.steps() == records
        meas = session_measurements(session)
    ok = [r for r in records if r.status == "ok"]
    final = ok[-1].corrections[0][1]  # the step of least variance: the last
    for row, record in zip(meas.points, ok, strict=True):
        c = record.corrections[0][1]
        np.testing.assert_allclose(row, np.array(record.position) - (c.response @ final.estimate - c.applied)[:3],
                                   rtol=0, atol=1e-15)


def test_an_unreadable_correction_is_one_line_and_exit_2(tmp_path: Path, capsys) -> None:
    """A session whose stored correction was damaged by another program: ``identify`` says which step, in one line,
    exits 2 and writes nothing."""
    import sqlite3

    from identify.commands.cli import main as identify_main

    plan = small_plan()
    path = tmp_path / "camera.session"
    correction = Correction(("dfocal",), np.full((6, 1), 1e-3), np.zeros(6), np.zeros(1), np.eye(1), 1e-6, 1e-6)
    with Session.create(path, plan, CONFIG, ROBOT, TRACKER) as session:
        session.begin_run()
        for i in range(len(plan.steps)):
            record = record_for(plan, i)
            session.record_step(replace(record, corrections=((1, correction),)) if record.status == "ok" else record)
        session.end_run("complete")
    with sqlite3.connect(path) as db:
        db.execute("UPDATE step_corrections SET correction = ? WHERE plan_index = 3", ('{"names": ["a"]}',))
    db.close()
    before = path.read_bytes()
    assert identify_main([str(path), "--out", str(tmp_path / "r.yaml")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "step 3: its camera correction is unreadable" in err, err
    assert not (tmp_path / "r.yaml").exists() and path.read_bytes() == before
