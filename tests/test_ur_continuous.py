"""Continuous motion end to end against the UR controller emulator: the real ``ur_rtde`` client (in the driver's
worker process) recording the RTDE joint stream at the emulator's native rate, and the real serial driver reading
the emulator's simulated ``stream-csv`` tracker over loopback TCP. The emulator's rig is the one physical world:
its arm follows each move's profile on the emulated clock, the RTDE stream reports it, and the tracker measures its
true TP in real time, stamped on the same clock plus a latency (tests/ur_emulator, tests/tracker_devices.py).

RTDE at 125 packages and the tracker at 125 lines per emulated second, the session at time scale 4 (500 of each
per wall second: a Python emulator on a shared 2-core machine loses more packages above that, which the recorder
records as gaps), the motion check at time scale 2. bench/ur_continuous.py runs a full session at real speed with
the e-Series 500 Hz stream.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.stats import chi2

pytest.importorskip("rtde_control", reason="ur_rtde is not installed (pip install 'dh-calib[ur]')")

from config.robots import load_robot
from drivers.ascii_profile import TRACKERS_DIR
from drivers.base import JointStreamBatch, TrackerStreamBatch
from drivers.registry import open_tracker
from identify.kinematics import points_from_joints
from tests.ur_emulator import EmulatorProcess, connected_robot

SCALE, RATE = 4.0, 125.0  # emulated s per wall s; RTDE packages per emulated s
PERIOD = 0.008  # emulated s between the tracker's streamed lines
NOISE = 5e-5  # m per axis: the stream-csv profile's stated sigma, which the simulated device keeps
LATENCY = 0.02  # s: each reading leaves the tracker this long after it was taken, stamped when it leaves
FALSE_ALARM = 1e-4  # chance that a noise-derived check below fails on a correct system
HOME = np.array(load_robot("ur5e").home, dtype=float)


def stream_profile(folder: Path) -> Path:
    """The bundled stream-csv profile at PERIOD (the device streams at the rate its profile states)."""
    doc = yaml.safe_load((TRACKERS_DIR / "stream-csv.yaml").read_text())
    doc["period"] = doc["simulation"]["period"] = PERIOD
    path = folder / "stream-csv.yaml"  # a profile file is named after its profile
    path.write_text(yaml.safe_dump(doc))
    return path


def joints_at(joints: JointStreamBatch, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The joint stream linearly interpolated at robot times ``t``, and which of them lie inside the stream and
    not inside one of its recorded gaps."""
    q = np.column_stack([np.interp(t, joints.t, joints.q[:, i]) for i in range(joints.q.shape[1])])
    ok = (t >= joints.t[0]) & (t <= joints.t[-1])
    for a, b in joints.gaps:
        ok &= ~((t > a) & (t < b))
    return q, ok


def test_the_emulated_tracker_measures_the_true_point_of_the_arm_in_motion(tmp_path: Path) -> None:
    """During a move the streamed positions are the rig's true TP at the joint stream's positions interpolated at
    the tracker's time minus its latency, to within the tracker noise; the arm really moved meanwhile."""
    profile = stream_profile(tmp_path)
    with EmulatorProcess(time_scale=2.0, native_rate=True, rate=RATE) as emu:  # 250 packages per wall s
        url = emu.serve_tracker(str(profile), NOISE, 1, latency=LATENCY)
        truth = emu.truth()
        robot = connected_robot(emu, options=f"rtde_frequency={RATE:g}")
        tracker = open_tracker(f"serial:{url}?protocol={profile}")
        tracker.connect(2.0)
        joints: list[JointStreamBatch] = []
        tracks: list[TrackerStreamBatch] = []
        try:
            robot.start_joint_stream(2.0)
            tracker.start_stream(1.0 / PERIOD, 2.0)
            robot.start_move(HOME + np.array([0.6, 0, 0, 0, 0, -0.6]), [0.8] * 6, [1.5] * 6, 10.0)
            deadline = time.monotonic() + 10.0
            while not robot.motion_done():
                assert time.monotonic() < deadline, "the move did not end"
                time.sleep(0.02)
                joints.append(robot.read_joint_stream())
                tracks.append(tracker.read_stream())
            time.sleep(0.1)
            joints.append(robot.stop_joint_stream(2.0))
            tracks.append(tracker.stop_stream(2.0))
        finally:
            robot.close()
            tracker.close()
    joint = JointStreamBatch(np.concatenate([b.t for b in joints]), np.concatenate([b.q for b in joints]),
                             tuple(g for b in joints for g in b.gaps))
    t = np.concatenate([b.t for b in tracks])
    points = np.concatenate([b.points for b in tracks])
    assert not any(b.gaps for b in tracks)  # nothing lost on the tracker's side
    q, ok = joints_at(joint, t - LATENCY)
    # lines whose robot time lies in a recorded gap of the joint stream (RTDE packages the loaded emulator sent
    # late, overwritten before the recorder polled) are left out, as the identification leaves them out
    assert ok.sum() >= 30
    predicted = points_from_joints(truth, q[ok])
    travel = np.linalg.norm(predicted - predicted[0], axis=1).max()
    assert travel > 0.3  # m: the TP moved a lot, so a tracker that did not follow it would miss by far more
    # per axis, the error must be tracker noise: chi-square over 3 N values, plus what linear interpolation
    # between 8 ms packages can miss at 1.5 rad/s² (a·h²/8 per joint, 2 joints, a lever under 1.2 m)
    error = points[ok] - predicted
    dof = error.size
    interpolation = 2 * 1.5 * (1.0 / RATE) ** 2 / 8 * 1.2
    limit = NOISE * np.sqrt(chi2.ppf(1 - FALSE_ALARM, dof) / dof) + interpolation
    rms = float(np.sqrt(np.mean(error**2)))
    assert rms < limit, f"{rms * 1e3:.4f} mm per axis vs {limit * 1e3:.4f} mm"
    # and the timestamps are the reading's time plus the latency: 2 ms either way misses by far more
    for shift in (-0.002, 0.002):
        q_off, _ = joints_at(joint, t - LATENCY + shift)
        off = points[ok] - points_from_joints(truth, q_off[ok])
        assert np.sqrt(np.mean(off**2)) > 2 * limit

