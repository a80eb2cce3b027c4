"""Trackers that see several points: the ``multi-xyz`` ASCII profile over a real pseudo-terminal and I++ DME
``tools=`` against the simulated server, both answering from the simulated rig's reflectors; a session recorded
through the serial one with points going out of sight."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from acquire.running.orchestrator import Orchestrator, Progress
from acquire.running.session import Session
from config.robots import ConfigError
from drivers.errors import BadReading, ConnectionFailed, SpecError, TargetLost
from drivers.registry import open_tracker
from drivers.sim.rig import SimulatedRig
from drivers.sim.robot import SimulatedRobot
from drivers.trackers.ascii_profile import PointLost, load_profile, parse_line, profile_from_dict
from session.plan import Plan, Step
from tests.tracker_devices import AsciiDevice, IppServer, open_ipp

NOISE = 2e-5


@pytest.fixture(scope="module")
def rig() -> SimulatedRig:
    return SimulatedRig("ur5e", seed=2, points=3)


def _check(readings, rig: SimulatedRig, ids: list[int], count: int) -> None:
    assert [r.tp for r in readings] == ids * count
    err = np.array([r.position - rig.true_points()[r.tp - 1] for r in readings])
    assert np.abs(err).max() < 6 * NOISE


def test_multi_xyz_profile_reports_each_point(rig: SimulatedRig) -> None:
    with AsciiDevice("multi-xyz", rig, noise=NOISE) as device:
        tracker = open_tracker(f"serial:{device.port}?protocol=multi-xyz&timeout=0.5")
        tracker.connect(2.0)
        try:
            assert tracker.points == 3 and tracker.identity().model == "MXYZ-3"
            _check(tracker.measure(3, 5.0), rig, [1, 2, 3], 3)
            device.hidden = {2}  # out of sight: the others are still read
            _check(tracker.measure(2, 5.0), rig, [1, 3], 2)
            for fault in ("garbage", "partial", "noise", "bad_checksum", "truncated"):  # the frame is read again
                device.inject(fault)
                _check(tracker.measure(1, 5.0), rig, [1, 3], 1)
            device.hidden = {1, 2, 3}
            with pytest.raises(TargetLost, match="every one of the 3 tracked points is out of sight"):
                tracker.measure(1, 5.0)
        finally:
            tracker.close()


def test_multi_point_profiles_are_checked() -> None:
    profile = load_profile("multi-xyz")
    assert parse_line(profile, "T2 OK 1.0 2.0 3.0").tp == 2
    with pytest.raises(PointLost) as lost:
        parse_line(profile, "T3 LOST")
    assert lost.value.tp == 3
    with pytest.raises(BadReading, match="bad tracked point id"):
        parse_line(profile, "T0 OK 1 2 3")
    base = {"schema": 1, "name": "x", "mode": "polled", "trigger": "M", "units": "mm", "points": 2,
            "response": {"fields": ["x", "y", "z"]}}
    with pytest.raises(ConfigError, match="a tp field"):
        profile_from_dict(base)
    with pytest.raises(ConfigError, match="1 in mode streaming"):
        profile_from_dict({**base, "mode": "streaming", "trigger": None, "response": {"fields": ["tp", "x", "y", "z"]}})
    with pytest.raises(ConfigError, match="an integer >= 1"):
        profile_from_dict({**base, "points": 0})


def test_a_session_records_the_points_in_sight(rig: SimulatedRig, tmp_path: Path) -> None:
    home = tuple(float(v) for v in rig.model.home)
    steps = tuple(Step(k, "free", 1 + k, 0, tuple(v + 0.05 * k * (j % 2) for j, v in enumerate(home)))
                  for k in range(6))
    plan = Plan("ur5e", "RRRRRR", home, steps, samples_per_step=2, settle_time=0.1,
                speed=tuple(rig.model.default_speed), acceleration=tuple(rig.model.default_acceleration))
    arm = SimulatedRobot(rig)
    arm.connect(1.0)
    with AsciiDevice("multi-xyz", rig, noise=NOISE) as device:
        tracker = open_tracker(f"serial:{device.port}?protocol=multi-xyz&timeout=0.5")
        tracker.connect(2.0)

        def hide(progress: Progress) -> None:  # point 3 out of sight from the third step on
            device.hidden = {3} if progress.done >= 2 else set()

        try:
            with Session.create(tmp_path / "s.session", plan, {}, arm.identity(), tracker.identity()) as session:
                assert Orchestrator(arm, tracker, session, rig.clock, on_progress=hide).run().outcome == "complete"
                records = session.steps()
                meas = session.to_measurements()
        finally:
            tracker.close()
    assert [[p.tp for p in s.points] for s in records] == [[1, 2, 3]] * 2 + [[1, 2]] * 4
    assert len(meas) == 2 * 3 + 4 * 2 and meas.tp.tolist()[:5] == [1, 2, 3, 1, 2]


def test_ipp_tools_are_the_points(rig: SimulatedRig) -> None:
    with IppServer(rig, noise=NOISE, tools=("SMR1", "SMR2", "SMR3"), averaging="XX.Average") as server:
        tracker = open_ipp(server, tools="SMR1,SMR2,SMR3", average="2")
        try:
            assert tracker.points == 3 and tracker.identity().details["tools"] == "SMR1,SMR2,SMR3"
            assert tracker.per_tool["SMR2"] == ("Tool.XX.Average", 2)
            _check(tracker.measure(2, 5.0), rig, [1, 2, 3], 2)
            assert sum(c.endswith('SetTool("SMR2")') for c in server.commands) == 3  # at connect, then per reading
            server.hidden = {"SMR1"}
            _check(tracker.measure(1, 5.0), rig, [2, 3], 1)
            server.hidden = {"SMR1", "SMR2", "SMR3"}
            with pytest.raises(BadReading, match="Target not visible"):
                tracker.measure(1, 5.0)
        finally:
            tracker.close()
        with pytest.raises(ConnectionFailed, match="has no tool 'SMR9'"):
            open_ipp(server, tools="SMR1,SMR9")
    with pytest.raises(SpecError, match="option tools=A,A must be distinct tool names"):
        open_tracker("ipp://127.0.0.1?tools=A,A")
