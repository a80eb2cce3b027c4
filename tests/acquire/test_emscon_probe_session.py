"""``acquire --robot ur5e@HOST --tracker emscon:HOST:PORT?probe=6dof`` against the UR controller emulator and the
emScon emulator serving a 6-DoF probe on the emulated arm's flange (drivers/trackers/emscon_sim.py): every step is
recorded as a full pose (tip and orientation, with the server's sigma and sigma_r), the identification uses the
orientations, and its orientation residuals and written tool frame agree with the stated noise."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

pytest.importorskip("rtde_control", reason="ur_rtde is not installed (pip install 'ur-rtde==1.6.5', the ur extra)")

from acquire.commands.cli import main as acquire
from acquire.running.session import Session
from config.robots import load_robot
from drivers.sim.rig import SimulatedRig
from identify.estimator.bounds import prediction_rms_bound
from identify.simulators.simulate import random_poses
from kinematics.dh import flange_frames, model_from_dict, points_from_joints
from tests.ur_emulator import EmulatorProcess, ScaledClock

SCALE = 100.0  # emulated seconds per wall second
NOISE, ANGLE, SAMPLES = 2e-5, 1e-4, 3  # the probe's noise (m per axis, rad per axis) and readings per step
SITE = f"""schema: 1
tracker: {{noise: {NOISE:.1e}}}
plan: {{settle_time: 0.02, steps_per_sweep: 5, samples_per_step: {SAMPLES}, free_poses: 5, check_poses: 3,
        home_check_every: 20}}
timeouts: {{connect: 10.0, move: 30.0, settle: 10.0, measure: 5.0}}
"""


@pytest.mark.slow
def test_a_6dof_probe_session_records_full_poses_and_identifies_the_wrist(tmp_path, capsys) -> None:
    rig = SimulatedRig("ur5e", clock=ScaledClock(SCALE), ring=1e-5, ring_tau=0.05)
    frame = rig.target_frames[0]  # the probe's frame on the flange (the emulator's copy of this rig has the same)
    site = tmp_path / "site.yaml"
    site.write_text(SITE)
    with EmulatorProcess(rig=rig) as emu:
        port = emu.serve_emscon(NOISE, 1, "pose_invalid@7", angle_noise=ANGLE)
        code = acquire(["--robot", f"ur5e@{emu.host}", "--tracker",
                        f"emscon:127.0.0.1:{port}?meas_time=0.001&timeout=0.5&probe=6dof", "--yes", "--config",
                        str(site), "--session", str(tmp_path / "ur.session"), "--quiet"])
        _, err = capsys.readouterr()
        assert code == 0, err
        truth = emu.truth()
    with Session.open(tmp_path / "ur.session") as session:
        steps, frames = session.steps(), session.measured_frames()
        retries = [e[3] for e in session.events() if e[2] == "retry"]
        meas = session.to_measurements()
        assert session.outcome() == "complete" and all(s.status == "ok" for s in steps)
        assert "6-DoF probe" in session.header["tracker"]["details"]["measurement"]
    assert len(retries) == 1 and "InvalidPose" in retries[0]  # measured again, not lost
    moved = [s for s in steps if s.kind != "stream"]
    assert len(frames) == len(moved) and all(len(f) == 1 for f in frames.values())
    kept = {s.plan_index: s.samples for s in moved}  # the server's sigma_r over sqrt(readings kept)
    assert all(f[0].sigma_r == pytest.approx(ANGLE / np.sqrt(kept[i])) for i, f in frames.items()), (
        [(i, f[0].sigma_r, kept[i]) for i, f in frames.items()])
    doc = yaml.safe_load((tmp_path / "ur.result.yaml").read_text())
    orientation = doc["residuals"]["orientation"]
    # every fitted position row has its orientation row (residuals.samples counts both kinds)
    assert 2 * orientation["samples"] == doc["residuals"]["samples"] and orientation["rejected"] == 0, orientation
    # the rows' 3D rotation residual RMS against the averaged readings' noise, sqrt(3) ANGLE / sqrt(SAMPLES) per
    # row less the share the fit absorbs: within 30 % (about 40 rows of 3 axes: a 10 % spread)
    stated = np.sqrt(3) * ANGLE / np.sqrt(SAMPLES)
    assert 0.6 * stated < orientation["rms_rad"] < 1.3 * stated, orientation
    # the written tool frame predicts the probe's orientation at 200 random poses within a fraction of one row's
    # noise (35 rows determine it), whatever DH convention the fit wrote the last frame in
    model = model_from_dict(doc)
    tool = np.array(doc["tool_frame"], dtype=float).reshape(4, 4)[:3, :3]
    q_check = random_poses(load_robot("ur5e").limits, 200, np.random.default_rng(0))
    predicted = Rotation.from_matrix(flange_frames(model, q_check)[0] @ tool)
    true = Rotation.from_matrix(flange_frames(truth, q_check)[0] @ frame)
    turns = np.linalg.norm((predicted * true.inv()).as_rotvec(), axis=1)
    assert np.sqrt(np.mean(turns**2)) < stated, np.sqrt(np.mean(turns**2))
    err = points_from_joints(model, q_check) - points_from_joints(truth, q_check)
    rms = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    assert rms < 3.0 * prediction_rms_bound(truth, meas.q[~meas.check], q_check, NOISE / np.sqrt(SAMPLES))
