"""``serial:rfc2217://host:port``: the serial driver through a real RFC 2217 server (pyserial's PortManager)
bridging a loopback TCP port to a simulated device on a pseudo-terminal, with faults on the way."""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("serial")

from drivers.errors import ConnectionFailed, DeviceTimeout
from drivers.registry import open_tracker
from drivers.sim.rig import SimulatedRig
from drivers.trackers.serial_tracker import SerialTracker
from tests.rfc2217_bridge import Rfc2217Bridge
from tests.tracker_devices import AsciiDevice, free_port

# pyserial 3.5's RFC 2217 client calls Thread.setDaemon()/setName()
pytestmark = pytest.mark.filterwarnings("ignore:set(Daemon|Name)\\(\\) is deprecated:DeprecationWarning")

TOL = 2e-4  # m: device noise 2e-5 and the profile's 0.1 µm resolution


@pytest.fixture
def rig() -> SimulatedRig:
    return SimulatedRig("ur5e", seed=6)


def _open(url: str, **options: str) -> SerialTracker:
    query = "&".join(f"{k}={v}" for k, v in {"protocol": "polled-xyz", "timeout": "0.3", **options}.items())
    tracker = open_tracker(f"serial:{url}?{query}")
    tracker.connect(3.0)
    return tracker


def test_readings_and_port_settings_go_through_the_rfc2217_server(rig: SimulatedRig) -> None:
    with AsciiDevice("polled-xyz", rig) as device, Rfc2217Bridge(device.port) as bridge:
        tracker = _open(bridge.url, baud="19200")
        readings = tracker.measure(3, 2.0)
        ident = tracker.identity()
        baud = bridge.serial.baudrate
        tracker.close()
    assert baud == 19200  # set by the client over RFC 2217 on the device's real port
    assert (ident.model, ident.serial) == ("XYZ-1", "SN1042") and ident.details["port"] == bridge.url
    assert all(np.allclose(r.position, rig.true_point(), atol=TOL) for r in readings)
    assert device.commands.count("MEAS?") == 3


def test_a_silent_line_times_out_in_one_line_then_recovers(rig: SimulatedRig) -> None:
    with AsciiDevice("polled-xyz", rig) as device, Rfc2217Bridge(device.port) as bridge:
        tracker = _open(bridge.url, retries="1")
        bridge.mute.set()  # the device answers, nothing reaches the client
        started = time.monotonic()
        with pytest.raises(DeviceTimeout) as info:
            tracker.measure(1, 2.0)
        assert time.monotonic() - started < 2.0
        assert "2 attempts" in str(info.value) and "\n" not in str(info.value)
        bridge.mute.clear()
        assert np.allclose(tracker.measure(1, 2.0)[0].position, rig.true_point(), atol=TOL)
        tracker.close()


def test_a_restarted_rfc2217_server_is_connection_failed_and_a_new_connect_works(rig: SimulatedRig) -> None:
    with AsciiDevice("polled-xyz", rig) as device, Rfc2217Bridge(device.port) as bridge:
        tracker = _open(bridge.url)
        tracker.measure(1, 2.0)
        bridge.kick()
        time.sleep(0.1)
        with pytest.raises(ConnectionFailed) as info:
            tracker.measure(1, 2.0)
        assert bridge.url in str(info.value) and "\n" not in str(info.value)
        tracker.connect(3.0)
        assert np.allclose(tracker.measure(1, 2.0)[0].position, rig.true_point(), atol=TOL)
        tracker.close()
    assert bridge.connections == 2


def test_nobody_listening_is_one_line() -> None:
    port = free_port()
    tracker = open_tracker(f"serial:rfc2217://127.0.0.1:{port}?protocol=polled-xyz")
    with pytest.raises(ConnectionFailed) as info:
        tracker.connect(1.0)
    assert f"rfc2217://127.0.0.1:{port}" in str(info.value) and "\n" not in str(info.value)


def test_a_server_that_does_not_speak_rfc2217_fails_within_the_connect_timeout(rig: SimulatedRig) -> None:
    with AsciiDevice("polled-xyz", rig, transport="tcp") as device:  # a plain TCP device: no Telnet options
        url = device.port.replace("socket://", "rfc2217://")
        tracker = open_tracker(f"serial:{url}?protocol=polled-xyz")
        started = time.monotonic()
        with pytest.raises(ConnectionFailed) as info:
            tracker.connect(0.5)
        assert time.monotonic() - started < 2.0
        assert "RFC2217" in str(info.value) and "\n" not in str(info.value)
