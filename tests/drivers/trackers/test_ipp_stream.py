"""I++ DME streaming (drivers/trackers/ipp_stream.py): OnMoveReportE event reports from the simulated I++ server
(tests/ipp_device.py) over real loopback TCP."""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.base import StreamingTracker
from drivers.clock import WallClock
from drivers.sim.rig import SimulatedRig
from drivers.sim.robot import SimulatedRobot
from drivers.trackers.ipp_protocol import IppError
from tests.ipp_device import IppServer, open_ipp

RATE = 100.0  # Hz asked for: a report every 10 ms


def test_move_reports_are_parsed_with_host_receive_times() -> None:
    rig = SimulatedRig("ur5e")
    with IppServer(rig, move_reports=True) as server:
        tracker = open_ipp(server)
        try:
            assert isinstance(tracker, StreamingTracker)
            before = time.time()
            assert tracker.start_stream(RATE, 2.0) == RATE
            time.sleep(0.5)
            batch = tracker.stop_stream(1.0)
            after = time.time()
            assert any(c.startswith("E0001 OnMoveReportE(Time(0.01), X(), Y(), Z())") for c in server.commands)
            assert any("StopDaemon(E0001)" in c for c in server.commands)
            reading = tracker.measure(1, 2.0)[0]  # the session goes on after the stream
        finally:
            tracker.close()
    t = batch.t
    assert before <= t[0] and t[-1] <= after  # the host's clock
    assert np.all(np.diff(t) >= 0)
    assert 0.6 * 0.5 * RATE < len(t) <= 0.5 * RATE + 5  # about one report per interval
    assert abs(np.median(np.diff(t)) - 1 / RATE) < 0.5 / RATE
    assert np.abs(batch.points - rig.true_point()).max() < 6 * server.noise  # mm on the wire, m here
    assert np.all(np.isnan(batch.sigma)) and np.all(batch.tp == 1)
    assert batch.gaps == ()
    assert np.abs(reading.position - rig.true_point()).max() < 6 * server.noise
    assert not [e for e in tracker.events if "#" in e]  # reports are not kept as events


def test_target_out_of_sight_during_a_stream_is_a_gap() -> None:
    rig = SimulatedRig("ur5e")
    with IppServer(rig, move_reports=True, tools=("A",)) as server:
        tracker = open_ipp(server)
        try:
            tracker.start_stream(RATE, 2.0)
            time.sleep(0.2)
            server.hidden.add("A")
            time.sleep(0.3)
            server.hidden.clear()
            time.sleep(0.2)
            batch = tracker.stop_stream(1.0)
            counts = tracker.stream_counts
        finally:
            tracker.close()
    assert len(batch.gaps) == 1
    start, end = batch.gaps[0]
    assert 0.25 < end - start < 0.45
    assert counts["errors"] > 10
    assert not np.any((batch.t > start) & (batch.t < end))


def test_a_server_without_move_reports_refuses_with_one_line() -> None:
    with IppServer(SimulatedRig("ur5e")) as server:
        tracker = open_ipp(server)
        try:
            with pytest.raises(IppError, match="OnMoveReportE") as info:
                tracker.start_stream(RATE, 1.0)
            assert "\n" not in str(info.value)
            assert not tracker.streaming
            assert len(tracker.measure(1, 2.0)) == 1
        finally:
            tracker.close()


def test_a_standard_server_refuses_the_fast_rate_and_the_client_streams_at_ten_reports_per_second() -> None:
    """Time(0.004) is refused with error 0510 after the &: the client clears it, asks Time(0.1), says so in one
    line, sends no StopDaemon for the refused daemon, and asks Time(0.1) directly from then on."""
    with IppServer(SimulatedRig("ur5e"), move_reports=True, standard=True) as server:
        tracker = open_ipp(server)
        try:
            t0 = time.monotonic()
            assert tracker.start_stream(250.0, 2.0) == pytest.approx(10.0)
            took = time.monotonic() - t0
            tracker.stop_stream(1.0)
            assert tracker.start_stream(250.0, 2.0) == pytest.approx(10.0)
            tracker.stop_stream(1.0)
            in_error = server.in_error
            commands = [c.partition(" ")[2] for c in server.commands]
            note = tracker.rate_note
        finally:
            tracker.close()
    asked = [c for c in commands if c.startswith(("OnMoveReportE", "StopDaemon", "ClearAllErrors"))]
    assert asked == ["OnMoveReportE(Time(0.004), X(), Y(), Z())", "ClearAllErrors()",
                     "OnMoveReportE(Time(0.1), X(), Y(), Z())", "StopDaemon(E0002)",
                     "OnMoveReportE(Time(0.1), X(), Y(), Z())", "StopDaemon(E0003)"]
    assert not in_error
    assert took < 1.5  # no wait for a report: the arm is at rest and a standard server sends none
    assert "0510" in note and "10 reports/s" in note and "stream_rate: 10" in note and "\n" not in note


def test_a_standard_server_reports_only_while_the_arm_moves() -> None:
    """Started with the arm still, the stream has no report until the arm moves, then one per 0.1 s of motion,
    each the arm's true point at its receive time to within what 0.1 s of motion allows, and none after it."""
    rig = SimulatedRig("ur5e", clock=WallClock(), ring=0.0)
    robot = SimulatedRobot(rig)
    robot.connect(1.0)
    with IppServer(rig, move_reports=True, standard=True, noise=1e-6) as server:
        tracker = open_ipp(server)
        try:
            assert tracker.start_stream(10.0, 2.0) == pytest.approx(10.0)
            time.sleep(0.4)
            at_rest = tracker.read_stream()
            target = rig.rest_joints.copy()
            target[0] += 0.4
            t0 = time.time()
            robot.start_move(target, [0.4] * 6, [4.0] * 6, 5.0)
            while not robot.motion_done():
                time.sleep(0.01)
            t1 = time.time()
            time.sleep(0.5)
            batch = tracker.stop_stream(1.0)
        finally:
            tracker.close()
    assert len(at_rest.t) == 0 and server.reports == len(batch.t)
    moving = t1 - t0  # 1.1 s: 1.0 s at speed and the ramps
    assert moving * 10 - 3 <= len(batch.t) <= moving * 10 + 2
    assert t0 < batch.t[0] and batch.t[-1] < t1 + 0.15  # nothing at rest after the move
    assert batch.gaps == ()
    reach = 0.4 * 1.0  # m/s: the TP's speed bound (0.4 rad/s at < 1 m from the axis)
    truth = np.array([rig.true_point(t) for t in batch.t])
    assert np.abs(batch.points - truth).max() < reach * 0.05  # stamped on receipt, within a scheduler's delay


def test_a_refused_daemon_is_not_stopped_and_the_message_says_what_to_do() -> None:
    """A server without OnMoveReportE (error 0501 after the &): one line naming --mode step, no StopDaemon."""
    with IppServer(SimulatedRig("ur5e")) as server:
        tracker = open_ipp(server)
        try:
            with pytest.raises(IppError, match="use --mode step") as info:
                tracker.start_stream(RATE, 1.0)
            assert "\n" not in str(info.value)
        finally:
            tracker.close()
    assert not any("StopDaemon" in c for c in server.commands)
