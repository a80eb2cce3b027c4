"""6-DoF probes (T-Mac class) through the emScon client with ``probe=6dof`` (drivers/trackers/emscon_probe.py,
emscon_stream.py) against the loopback emulator (tests/emscon_device.py): readings are full poses whose tip and
orientation are the emulator's truth within its stated noise, a result that says its pose is not valid is retried
on the same link, and a continuous 6-DoF measurement streams the tip's positions and the probe's orientations."""

from __future__ import annotations

import struct
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers.clock import WallClock
from drivers.errors import BadReading
from drivers.sim.rig import SimulatedRig
from drivers.trackers import emscon_protocol as es
from drivers.trackers import emscon_server as served
from drivers.trackers.emscon_probe import InvalidPose
from tests.emscon_device import EmsconServer, open_emscon

NOISE, ANGLE = 2e-5, 3e-4  # the emulator's noise: m per axis, rad per axis
TOL, TOL_R = 5 * NOISE, 5 * np.sqrt(3) * ANGLE  # per axis; a 3D turn (5 sigma of its chi-3 spread)


@pytest.fixture
def rig() -> SimulatedRig:
    return SimulatedRig("ur5e", seed=2, clock=WallClock())


def test_continuous_probe_result_layout_and_round_trip() -> None:
    # ProbeContinuousResultT: 68 bytes of head (the environment at 44), 212 per ProbeMeasValueT (lTime1 at 12, the
    # tip at 20, the quaternion at 100, the rotation angles' deviations at 156)
    q = [[0.5, 0.5, 0.5, 0.5], [1.0, 0.0, 0.0, 0.0]]
    packet = served.probe_continuous_result([0, 3], [5001, 5001], [4000, 8000], [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]],
                                            [[1e-5, 2e-5, 3e-5]] * 2, q, [[1e-4, 2e-4, 3e-4]] * 2, (21.0, 990.0, 40.0),
                                            rotation_status=[1, 3])
    assert len(packet) == 68 + 2 * 212 and struct.unpack_from("<iI", packet) == (492, es.DT_PROBE_CONTINUOUS)
    assert struct.unpack_from("<iI", packet, 12) == (2, es.MM_6D_CONTINUOUS_TIME)
    assert struct.unpack_from("<3d", packet, 44) == (21.0, 990.0, 40.0)
    second = 68 + 212
    assert struct.unpack_from("<IIiii", packet, second) == (3, 0, 3, 5001, 8000)
    assert struct.unpack_from("<3d", packet, second + 20) == (4.0, 5.0, 6.0)
    assert struct.unpack_from("<4d", packet, second + 100) == (1.0, 0.0, 0.0, 0.0)
    assert struct.unpack_from("<3d", packet, second + 156) == (1e-4, 2e-4, 3e-4)
    result = es.decode(packet)
    assert isinstance(result, es.ProbeMultiResult) and result.mode == es.MM_6D_CONTINUOUS_TIME
    assert result.point_status.tolist() == [0, 3] and result.rotation_status.tolist() == [1, 3]
    assert result.time2.tolist() == [4000, 8000] and result.values.tolist() == [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]
    assert result.quaternion.tolist() == q and result.std.tolist() == [[1e-5, 2e-5, 3e-5]] * 2
    assert es.rotation_ok(result.rotation_status).tolist() == [True, False]  # bit 1: Error6D
    assert not es.rotation_ok(0) and not es.rotation_ok(1 | 32) and es.rotation_ok(1 | 4)  # invalid, frozen; LEDs
    with pytest.raises(BadReading, match="says it holds 3 points"):
        es.decode(packet[:12] + struct.pack("<i", 3) + packet[16:])


def test_probe_readings_are_full_poses_of_the_truth(rig: SimulatedRig) -> None:
    with EmsconServer(rig, noise=NOISE, seed=6, angle_noise=ANGLE, faults=(("pose_invalid", 4, 1),)) as server:
        tracker = open_emscon(server, probe="6dof")
        readings = tracker.measure(3, 2.0)
        truths = list(server.probe_truths)
        with pytest.raises(InvalidPose, match="not a valid pose"):
            tracker.measure(1, 2.0)  # the 4th measurement: rotation status 0b111 (error)
        readings += tracker.measure(12, 5.0)
        truths += list(server.probe_truths)[4:]
        identity, connections = tracker.identity(), server.connections
        tracker.close()
    assert connections == 1 and tracker.reconnects == 0  # an invalid pose is measured again on the same link
    assert server.mode == es.MM_6D_STATIONARY and "6-DoF probe" in identity.details["measurement"]
    tip = np.array([r.position - t[:3, 3] for r, t in zip(readings, truths, strict=True)])
    turn = np.array([np.linalg.norm((Rotation.from_rotvec(r.rotvec) * Rotation.from_matrix(t[:3, :3]).inv())
                                    .as_rotvec()) for r, t in zip(readings, truths, strict=True)])
    assert 0 < np.abs(tip).max() < TOL and 0 < turn.max() < TOL_R  # the truth, with its noise
    # the turns' per-axis RMS is the stated noise (15 draws of 3 axes: within 40 %)
    assert 0.6 * ANGLE < np.sqrt(np.mean(turn**2) / 3) < 1.4 * ANGLE
    assert all(r.sigma == pytest.approx(NOISE) and r.sigma_r == pytest.approx(ANGLE) and r.status == "ok"
               for r in readings)
    # the probe frame is the rig's target frame, not the flange's: a client reading the quaternion's other
    # convention (its inverse) would be off by the frame's whole rotation
    frame = rig.target_frames[0]
    assert np.linalg.norm(Rotation.from_matrix(frame).as_rotvec()) > 0.1


def test_a_continuous_6dof_measurement_streams_the_tips_positions_and_the_probes_orientations(
        rig: SimulatedRig) -> None:
    with EmsconServer(rig, noise=NOISE, seed=7, angle_noise=ANGLE) as server:
        tracker = open_emscon(server, probe="6dof")
        tracker.start_stream(200.0, 2.0)
        batches = []
        for _ in range(8):
            time.sleep(0.05)
            batches.append(tracker.read_stream())
        batches.append(tracker.stop_stream(2.0))
        sent, mode = list(server.streamed), server.mode
        true_turns = Rotation.from_matrix([server.probe_pose(tau)[:3, :3] for tau, _ in sent])
        tracker.close()
    assert mode == es.MM_6D_CONTINUOUS_TIME
    points = np.concatenate([b.points for b in batches])
    sigma = np.concatenate([b.sigma for b in batches])
    assert len(points) == len(sent) >= 40 and not any(b.gaps for b in batches)
    error = points - np.array([p for _, p in sent])
    assert 0 < np.abs(error).max() < TOL and np.allclose(sigma, NOISE)  # each point's stated deviation
    # each point's orientation: the probe frame in the tracker frame (the quaternion read as the stationary result's)
    rotvec = np.concatenate([b.rotvec for b in batches if len(b.t)])  # (an empty batch has none)
    sigma_r = np.concatenate([b.sigma_r for b in batches if len(b.t)])
    turn = np.linalg.norm((Rotation.from_rotvec(rotvec) * true_turns.inv()).as_rotvec(), axis=1)
    assert 0 < turn.max() < TOL_R and np.allclose(sigma_r, ANGLE)
    # the turns are the stated noise, not a copy of the truth or a smoothed one: RMS within 20 % (about 40 x 3 axes)
    assert 0.8 * np.sqrt(3) * ANGLE < np.sqrt(np.mean(turn**2)) < 1.2 * np.sqrt(3) * ANGLE
