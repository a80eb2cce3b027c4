"""The I++ DME client against a simulated I++ server on loopback that answers from the rig's true TP."""

from __future__ import annotations

import io

import numpy as np
import pytest

from drivers.base import Tracker
from drivers.errors import BadReading, ConnectionFailed, DeviceTimeout, SpecError
from drivers.registry import open_tracker
from drivers.sim.rig import SimulatedRig
from drivers.trackers.ipp import DEFAULT_PORT
from drivers.trackers.ipp import open_tracker as open_ipp
from tests.tracker_devices import IppServer, free_port
from tests.tracker_devices import open_ipp as _open

TOL = 2e-4


@pytest.fixture
def rig() -> SimulatedRig:
    return SimulatedRig("ur5e", seed=2)


def test_session_identity_and_points(rig: SimulatedRig) -> None:
    with IppServer(rig) as server:
        tracker = _open(server)
        assert server.session
        readings = tracker.measure(4, 3.0)
        ident = tracker.identity()
        tracker.close()
        assert not server.session
    assert ident.firmware == "1.4.2" and ident.kind == "tracker"
    for r in readings:
        assert np.allclose(r.position, rig.true_point(), atol=TOL)
    tags = [c.split(" ")[0] for c in server.commands]
    assert len(set(tags)) == len(tags) and all(len(t) == 5 and t.isdigit() for t in tags)
    assert server.commands[0].endswith("StartSession()") and server.commands[-1].endswith("EndSession()")


def test_error_reply_is_cleared_and_retried(rig: SimulatedRig) -> None:
    with IppServer(rig) as server:
        tracker = _open(server)
        server.inject("error")
        assert len(tracker.measure(2, 3.0)) == 2
        tracker.close()
    assert any(c.endswith("ClearAllErrors()") for c in server.commands)


def test_persistent_error_gives_one_line(rig: SimulatedRig) -> None:
    with IppServer(rig) as server:
        tracker = _open(server, retries="1")
        server.inject("error", 2)
        with pytest.raises(BadReading) as info:
            tracker.measure(1, 3.0)
        assert "0511" in str(info.value) and "severity 2" in str(info.value) and "\n" not in str(info.value)
        assert info.value.severity == 2 and info.value.code == "0511"
        assert len(tracker.measure(1, 2.0)) == 1
        tracker.close()


def test_silence_times_out_then_late_tags_are_ignored(rig: SimulatedRig) -> None:
    with IppServer(rig) as server:
        tracker = _open(server, timeout="0.2", retries="0")
        server.inject("silence")
        with pytest.raises(DeviceTimeout) as info:
            tracker.measure(1, 1.0)
        assert "no complete answer" in str(info.value) and "\n" not in str(info.value)
        assert np.allclose(tracker.measure(1, 1.0)[0].position, rig.true_point(), atol=TOL)
        tracker.close()


def test_dropped_connection_is_reopened_once(rig: SimulatedRig) -> None:
    with IppServer(rig) as server:
        tracker = _open(server)
        server.inject("drop")
        assert len(tracker.measure(2, 5.0)) == 2
        assert tracker.reconnects == 1
        tracker.close()


def test_events_and_missing_ack_are_tolerated(rig: SimulatedRig) -> None:
    with IppServer(rig, events=True) as server:
        tracker = _open(server)
        server.inject("no_ack")
        assert len(tracker.measure(2, 3.0)) == 2
        assert tracker.events
        tracker.close()


def test_trace_io_records_both_directions(rig: SimulatedRig) -> None:
    log = io.StringIO()
    with IppServer(rig) as server:
        tracker = open_ipp(f"ipp://{server.host}:{server.port}", trace_io=log)
        tracker.connect(2.0)
        tracker.measure(1, 2.0)
        tracker.close()
    text = log.getvalue()
    assert "> b'00001 StartSession()\\r\\n'" in text and "< b'00001 &\\r\\n" in text


def test_nobody_listening_is_connection_failed() -> None:
    port = free_port()
    tracker = open_tracker(f"ipp://127.0.0.1:{port}")
    with pytest.raises(ConnectionFailed) as info:
        tracker.connect(1.0)
    assert str(port) in str(info.value) and "\n" not in str(info.value)


def test_default_port_and_option_checks() -> None:
    assert isinstance(open_tracker("ipp://cmm.local"), Tracker)
    assert open_tracker("ipp://cmm.local").port == DEFAULT_PORT
    with pytest.raises(SpecError, match="unknown option 'speed'"):
        open_tracker("ipp://cmm.local?speed=3")
    with pytest.raises(SpecError, match="timeout=-1"):
        open_tracker("ipp://cmm.local?timeout=-1")
    for bad in ("average=0", "average=two", "averaging=Tool..X", "averaging=1x"):
        with pytest.raises(SpecError, match=bad.partition("=")[0]) as info:
            open_tracker(f"ipp://cmm.local?{bad}")
        assert "\n" not in str(info.value)
