"""identify/estimator/timing.py: joints interpolated in time, and the coarse clock offset from speed profiles; plus the
simulated rig's streams (drivers/sim/stream.py), whose configured latency the offset must recover."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.motion import profile_fraction
from drivers.sim.rig import SimulatedRig
from drivers.sim.robot import open_robot
from drivers.sim.tracker import open_tracker
from identify.estimator.timing import SweepStreams, coarse_clock_offset, interpolate_joints


def _trapezoid(t: np.ndarray, t0: float, duration: float = 3.5, distance: float = 1.5) -> np.ndarray:
    return np.array([distance * profile_fraction(x - t0, duration, 0.5, 1.0, distance) if x > t0 else 0.0
                     for x in t])


def _synthetic(offset: float, noise: float, rng: np.random.Generator, t0: float = 1000.0) -> SweepStreams:
    """A one-joint sweep: the TP on a circle of radius 0.4 m; tracker stamps = robot time - offset."""
    tj = t0 + np.arange(0, 6.0, 0.002)
    qj = np.column_stack([np.zeros_like(tj), _trapezoid(tj, t0 + 0.5)])
    robot_time = t0 + 0.01 + np.arange(0, 5.9, 0.004)
    angle = _trapezoid(robot_time, t0 + 0.5)
    points = 0.4 * np.column_stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)])
    points += rng.normal(0.0, noise, points.shape)
    return SweepStreams(robot_time - offset, points, tj, qj)


@pytest.mark.parametrize("offset", [-0.02, -0.3, 0.047])
def test_coarse_offset_recovers_a_known_shift(offset: float) -> None:
    rng = np.random.default_rng(1)
    sweeps = [_synthetic(offset, 5e-5, rng, t0) for t0 in (1000.0, 1020.0)]
    found = coarse_clock_offset(sweeps)
    # noise-free timing, 0.05 mm noise: the lag grid is 1 ms and refined: well under a millisecond
    assert found.offset == pytest.approx(offset, abs=5e-4)
    assert all(v == pytest.approx(offset, abs=1e-3) for v in found.per_sweep)
    assert found.correlation > 0.8


def test_coarse_offset_needs_overlapping_streams() -> None:
    rng = np.random.default_rng(2)
    sweep = _synthetic(0.0, 5e-5, rng)
    far = SweepStreams(sweep.t_tracker[:3], sweep.points[:3], sweep.t_joint, sweep.q_joint)
    with pytest.raises(ValueError, match="overlap"):
        coarse_clock_offset([far])
    with pytest.raises(ValueError, match="no sweep"):
        coarse_clock_offset([])


def test_interpolation_is_linear_and_refuses_gaps_and_the_outside() -> None:
    tj = np.arange(0.0, 1.0, 0.01)
    qj = np.column_stack([2 * tj, -tj])
    keep = (tj < 0.5) | (tj > 0.55)  # samples 0.50 .. 0.55 lost, recorded as a gap
    t = np.array([-0.01, 0.005, 0.2337, 0.485, 0.525, 0.57, 0.575, 0.985, 0.995])
    q, ok = interpolate_joints(tj[keep], qj[keep], t, gaps=[(0.49, 0.56)])
    assert ok.tolist() == [False, True, True, False, False, False, True, True, False]
    assert np.allclose(q[ok], np.column_stack([2 * t[ok], -t[ok]]))
    # the same gap unrecorded: only the stretch without samples is refused (spacing above 1.5 periods)
    _, ok = interpolate_joints(tj[keep], qj[keep], t)
    assert ok.tolist() == [False, True, True, True, False, True, True, True, False]
    with pytest.raises(ValueError, match="increase"):
        interpolate_joints(tj[::-1], qj, t)


def _stream_sweeps(tracker: str, joints: tuple[int, ...] = (6, 4), robot: str = "mock:ur5e") -> list[SweepStreams]:
    """Sweeps of ±1.5 rad on the simulated rig with both streams read every 50 ms of its virtual clock."""
    rig = SimulatedRig.from_spec(robot, tracker)
    arm, sensor = open_robot(robot, rig=rig), open_tracker(tracker, rig=rig)
    arm.connect(1.0)
    sensor.connect(1.0)
    speed, acc = [0.5] * 6, [1.0] * 6
    out = []
    for j in joints:
        home = np.array(rig.model.home)
        a, b = home.copy(), home.copy()
        a[j - 1] -= 1.5
        b[j - 1] += 1.5
        arm.move_joints(a, speed, acc, 100.0)
        arm.start_joint_stream(1.0)
        sensor.start_stream(250.0, 1.0)
        arm.start_move(b, speed, acc, 100.0)
        joint, track = [], []
        while not arm.motion_done():
            rig.clock.sleep(0.05)
            joint.append(arm.read_joint_stream())
            track.append(sensor.read_stream())
        rig.clock.sleep(0.2)
        joint.append(arm.stop_joint_stream(1.0))
        track.append(sensor.stop_stream(1.0))
        first = np.concatenate([x.tp for x in track]) == 1
        out.append(SweepStreams(np.concatenate([x.t for x in track])[first],
                                np.concatenate([x.points for x in track])[first],
                                np.concatenate([x.t for x in joint]), np.concatenate([x.q for x in joint])))
        arm.move_joints(home, speed, acc, 100.0)
    return out


@pytest.mark.parametrize("latency", [0.005, 0.02, 0.05])
def test_rig_latency_is_recovered_by_the_coarse_offset(latency: float) -> None:
    sweeps = _stream_sweeps(f"mock?latency={latency}&clock_offset=0.25")
    found = coarse_clock_offset(sweeps)
    # 250 Hz, 0.05 mm noise: within a few ms (the identification refines it)
    assert found.offset == pytest.approx(-(latency + 0.25), abs=3e-3)


def test_rig_streams_rates_drift_gaps() -> None:
    sweeps = _stream_sweeps("mock?latency=0.01&drift=0.001&lost=0.5@1&points=2", joints=(6,),
                            robot="mock:ur5e?drop=0.01&points=2")
    s = sweeps[0]
    assert np.median(np.diff(s.t_joint)) == pytest.approx(0.002, rel=1e-4)
    # drift 0.1 %: the tracker clock ticks 1.001 s per robot second
    assert np.median(np.diff(s.t_tracker)) == pytest.approx(0.004 * 1.001, rel=1e-4)
    # the target lost for 0.5 s: one stretch with no samples
    assert np.max(np.diff(s.t_tracker)) == pytest.approx(0.5, abs=0.01)
    # 1 % of the joint packets lost: a few spacings of 2+ periods
    assert 5 < int(np.sum(np.diff(s.t_joint) > 0.003)) < 60
