"""I++ DME streaming (drivers/trackers/ipp_stream.py): OnMoveReportE event reports from the simulated I++ server
(tests/ipp_device.py) over real loopback TCP."""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.base import StreamingTracker
from drivers.sim.rig import SimulatedRig
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
