"""Coupled readings and joint-error truths through acquisition: a FANUC-style session on the simulated rig (readings
as the controller reports them), the joint errors the mock spec implies (checked against an independent
computation), and ``acquire`` in mock mode end to end with them."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from acquire.commands.cli import main
from acquire.running.session import Session
from config.robots import load_robot
from drivers.clock import VirtualClock
from drivers.sim.rig import SimulatedRig
from drivers.sim.robot import SimulatedRobot
from drivers.sim.tracker import SimulatedTracker
from identify.io.csvio import read_measurements
from kinematics.dh import frames_from_joints, points_from_joints
from tests.acquire.test_points import record_session

NOISE = 2e-5
FANUC = load_robot("fanuc_lrmate200id")


@pytest.fixture(scope="module")
def fanuc_session(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, SimulatedRig]:
    path = tmp_path_factory.mktemp("fanuc") / "f.session"
    return path, record_session(path, "mock:fanuc_lrmate200id?seed=3", f"mock?seed=3&noise={NOISE:g}", samples=2)


def test_a_coupled_robot_is_commanded_and_recorded_in_its_readings(fanuc_session, tmp_path: Path) -> None:
    path, rig = fanuc_session
    csv = tmp_path / "f.csv"
    assert main(["export", str(path), "--csv", str(csv)]) == 0
    assert "# coupling: [[1.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0, 0.0, 0.0], [0.0, 1.0, 1.0, 0.0, 0.0, " \
           "0.0]," in csv.read_text()
    content = read_measurements(csv)
    meas = content.measurements
    np.testing.assert_array_equal(meas.coupling.matrix, FANUC.coupling.matrix)
    # the controller's J3 is measured against the horizontal: the DH value of joint 3 is J2 + J3
    q_dh = meas.q.copy()
    q_dh[:, 2] = meas.q[:, 1] + meas.q[:, 2]
    err = meas.points - points_from_joints(rig.truth, q_dh)
    sigma = NOISE / np.sqrt(2)
    assert np.abs(err).max() < 6 * sigma and 0.7 < np.sqrt(np.mean(err**2)) / sigma < 1.3
    assert np.abs(meas.points - points_from_joints(rig.truth, meas.q)).max() > 0.05  # readings are not DH values
    with Session.open(path) as session:
        assert session.header["schema"] == 2 and session.header["coupling"]["matrix"] == FANUC.coupling.matrix.tolist()
        steps, plan = session.steps(), session.plan
    q_cmd = np.array([s.q_cmd for s in steps])
    planned = np.array([plan.steps[s.plan_index].q for s in steps])  # the plan is in DH values
    np.testing.assert_allclose(FANUC.coupling.dh_from_readings(q_cmd), planned, atol=1e-12)
    moved = [s for s in steps if s.kind == "sweep" and s.joint == 2]
    assert np.ptp([s.q_cmd[2] for s in moved]) > 0.5  # a J2 sweep moves two readings at once


def test_coupled_limits_are_the_dh_values() -> None:
    rig = SimulatedRig("fanuc_lrmate200id")
    arm = SimulatedRobot(rig)
    arm.connect(1.0)
    speed, acc = FANUC.default_speed, FANUC.default_acceleration
    # J2 = J3 = 1.5 rad are each inside their limits, but the DH value of joint 3 (3.0 rad) is not
    with pytest.raises(ValueError, match=r"joint 3 target 3 is outside its limits"):
        arm.move_joints([0, 1.5, 1.5, 0, 1.5, 0], speed, acc, 60.0)
    arm.move_joints([0, 1.0, -0.5, 0, 1.5, 0], speed, acc, 60.0)  # DH joint 3 at 0.5 rad
    np.testing.assert_allclose(arm.read_joints(), [0, 1.0, -0.5, 0, 1.5, 0], atol=2e-5)
    np.testing.assert_allclose(rig.true_joints()[:3], [0, 1.0, 0.5], atol=2e-5)


def _gravity_torques(model, masses, centres, q: np.ndarray) -> np.ndarray:
    """Gravity's torque about each revolute joint's axis (N m), written here from scratch: the weight of every link
    beyond the joint about a point of the axis, projected on the axis; gravity -9.80665 m/s² along z of frame 0."""
    frames = frames_from_joints(model, q[None])[0]
    base_inv = np.linalg.inv(frames[0])
    frames = np.einsum("ij,kjl->kil", base_inv, frames)  # frames in DH frame 0
    torques = []
    for i in range(len(q)):
        axis, origin = frames[i][:3, 2], frames[i][:3, 3]
        total = np.zeros(3)
        for k in range(i, len(q)):
            c = frames[k + 1][:3, :3] @ centres[k] + frames[k + 1][:3, 3]
            total += np.cross(c - origin, masses[k] * np.array([0.0, 0.0, -9.80665]))
        torques.append(total @ axis)
    return np.array(torques)


def test_joint_errors_move_the_points_by_the_delta_q_the_spec_implies() -> None:
    spec = "mock:ur10e?seed=4&scale=1e-4&eccentricity=0.01&compliance=1e-6&repeatability=0&ring=0"
    rig = SimulatedRig.from_spec(spec, "mock?noise=0", VirtualClock())
    errors, model = rig.joint_errors, rig.model
    np.testing.assert_array_equal(np.abs(errors.scale), 1e-4)  # S times a random sign per joint
    np.testing.assert_allclose(np.hypot(errors.ecc_sin, errors.ecc_cos), math.radians(0.01), rtol=1e-12)
    np.testing.assert_array_equal(errors.compliance, 1e-6)
    arm, tracker = SimulatedRobot(rig), SimulatedTracker(rig)
    arm.connect(1.0)
    tracker.connect(1.0)
    recorded = json.loads(arm.identity().details["joint_errors"])  # the truth, in the session header
    np.testing.assert_array_equal(recorded["ecc_cos"], errors.ecc_cos)
    rng = np.random.default_rng(1)
    home = np.array(model.home)
    shifts = []
    for _ in range(4):
        q = home + rng.uniform(-0.6, 0.6, 6)
        arm.move_joints(q, model.default_speed, model.default_acceleration, 60.0)
        measured = tracker.measure(1, 1.0)[0].position
        tau = _gravity_torques(rig.truth, model.links.masses, model.links.centres, q)
        dq = errors.scale * q + errors.ecc_sin * np.sin(q) + errors.ecc_cos * np.cos(q) + 1e-6 * tau
        expected = points_from_joints(rig.truth, (q + dq)[None])[0]
        np.testing.assert_allclose(measured, expected, atol=1e-9)
        shifts.append(np.linalg.norm(measured - points_from_joints(rig.truth, q[None])[0]))
    assert min(shifts) > 5e-5  # tenths of a millimetre: what the identification has to find


@pytest.mark.slow
def test_acquire_runs_the_issue_mock_spec_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path, csv = tmp_path / "m.session", tmp_path / "m.csv"
    code = main(["--robot", "mock:ur10e?compliance=1e-6&points=3", "--tracker", "mock", "--session", str(path),
                 "--steps", "8", "--samples", "2", "--free-poses", "4", "--quiet"])
    assert code == 0  # complete, and its identification passes its verdict
    doc = yaml.safe_load(path.with_suffix(".result.yaml").read_text())
    assert set(doc["tools"]) == {1, 2, 3}
    assert doc["use"] == "extended" and "compliance_2" in {t["name"] for t in doc["extensions"]["terms"]}
    # every term selected passed its own test (a kind found on one joint no longer brings the others along)
    assert all(s["likelihood_ratio"] > s["limit"] for s in doc["extensions"]["selection"] if s["selected"])
    assert main(["export", str(path), "--csv", str(csv)]) == 0
    assert read_measurements(csv).measurements.tp_ids == [1, 2, 3]
    capsys.readouterr()


def test_compliance_without_link_masses_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["--robot", "mock:fanuc_lrmate200id?compliance=1e-6", "--tracker", "mock", "--session",
                 str(tmp_path / "x.session"), "--steps", "6", "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "\n" not in err and "compliance needs link masses" in err and "dynamics:" in err
    assert not (tmp_path / "x.session").exists()
