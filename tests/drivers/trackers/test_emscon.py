"""The emScon client (drivers/trackers/emscon.py) against the loopback emulator (tests/emscon_device.py), which answers
from a simulated rig's true TP with Gaussian noise NOISE per axis: set-up, readings against the truth, status faults
and a damaged, dropped or silent link."""

from __future__ import annotations

import re
import time
from types import SimpleNamespace

import numpy as np
import pytest

from drivers.base import Tracker
from drivers.errors import BadReading, ConnectionFailed, DeviceTimeout, MeasurementError, SpecError, TargetLost
from drivers.registry import open_tracker
from drivers.sim.rig import SimulatedRig
from drivers.trackers import emscon_protocol as es
from drivers.trackers.emscon import DEFAULT_PORT, BeamLost, TrackerNotReady
from tests.emscon_device import EmsconServer, open_emscon
from tests.ipp_device import free_port

NOISE = 2e-5  # m per axis, the emulator's noise
TOL = 5 * NOISE  # per axis: a reading further than this from the truth is wrong (5 sigma: 1 in 1.7 million)


@pytest.fixture
def rig() -> SimulatedRig:
    return SimulatedRig("ur5e", seed=2)


def _errors(server: EmsconServer, readings: list) -> np.ndarray:
    """Reading minus truth (m), reading by reading (the emulator records the truth of every result it sends)."""
    truths = np.array(server.truths[-len(readings):])
    return np.array([r.position for r in readings]) - truths


def test_set_up_is_explicit_and_recorded(rig: SimulatedRig) -> None:
    with EmsconServer(rig, noise=NOISE) as server:
        tracker = open_emscon(server, meas_time="0.004")
        ident = tracker.identity()
        state = (server.units, server.coordinates, server.settings, server.stationary, server.initialized)
        tracker.close()
    assert state == ((0, 0, 0, 0, 0), es.CS_RHR, (2, 0, 0, 1, 1, 0, 0, 1, 1), (4, 0), True)
    assert ident.kind == "tracker" and ident.firmware == "3.6.1234" and ident.serial == "392001"
    assert ident.details["reflector"] == "RRR 1.5in (id 1, RRR 1.5in, surface offset 0.01905 m)"
    assert ident.details["environment"] == "20 degC, 1013.25 mbar, 50 %RH (the server's)"
    assert ident.details["measurement"] == "stationary, 4 ms" and ident.details["initialized"] == "already"
    assert ident.details["units"] == "m, rad, degC, mbar, %RH" and "tracker frame" in ident.details["coordinate_system"]
    assert ident.details["address"] == f"emscon:127.0.0.1:{server.port}"


def test_readings_are_the_truth_within_the_noise(rig: SimulatedRig) -> None:
    with EmsconServer(rig, noise=NOISE, seed=5) as server:
        tracker = open_emscon(server)
        assert isinstance(tracker, Tracker)
        before = time.time()
        readings = tracker.measure(40, 5.0)
        err = _errors(server, readings)
        tracker.close()
    assert len(readings) == 40 and np.abs(err).max() < TOL
    rms = float(np.sqrt(np.mean(err**2)))
    assert 0.75 * NOISE < rms < 1.25 * NOISE, rms  # 120 components: the RMS is known to about 7 %
    assert all(r.sigma == pytest.approx(NOISE) and r.status == "ok" and r.tp == 1 for r in readings)
    stamps = [r.timestamp for r in readings]
    assert before <= stamps[0] and stamps == sorted(stamps) and stamps[-1] <= time.time()


def test_environment_and_reflector_from_the_site_file(rig: SimulatedRig) -> None:
    site = SimpleNamespace(tracker_settings={"temperature": 21.5, "pressure": 990, "humidity": 40,
                                             "reflector": "TBR 0.5in", "timeout": 0.5, "meas_time": 0.002})
    with EmsconServer(rig, noise=NOISE) as server:
        tracker = open_tracker(f"emscon:{server.host}:{server.port}", site=site)
        tracker.connect(3.0)
        readings = tracker.measure(2, 2.0)
        ident = tracker.identity()
        tracker.close()
        chosen, environment = server.reflector, server.environment
    assert chosen == 3 and environment == (21.5, 990.0, 40.0)
    assert ident.details["reflector"].startswith("TBR 0.5in (id 3") and ident.details["environment"].endswith("(set)")
    assert np.abs(_errors(server, readings)).max() < TOL


def test_an_unknown_reflector_is_refused_in_one_line(rig: SimulatedRig) -> None:
    with EmsconServer(rig) as server:
        tracker = open_tracker(f"emscon:{server.host}:{server.port}?reflector=9")
        with pytest.raises(ConnectionFailed) as info:
            tracker.connect(2.0)
        tracker.close()
    message = str(info.value)
    assert "no reflector '9'" in message and "RRR 1.5in (1), RRR 0.5in (2), TBR 0.5in (3)" in message
    assert "\n" not in message


@pytest.mark.parametrize(("initialized", "option", "inits"), [(False, "auto", 1), (True, "auto", 0),
                                                               (True, "always", 1)])
def test_the_tracker_is_initialised_when_it_needs_it_or_when_asked(rig: SimulatedRig, initialized: bool, option: str,
                                                                   inits: int) -> None:
    with EmsconServer(rig, initialized=initialized) as server:
        tracker = open_emscon(server, initialize=option)
        ident = tracker.identity()
        tracker.close()
        assert server.initialized and server.commands.count(es.C_INITIALIZE) == inits
    assert ident.details["initialized"] == ("by this client" if inits else "already")


def test_a_closed_tracker_does_not_reconnect_by_itself_and_the_trace_logs_bytes(rig: SimulatedRig, tmp_path) -> None:
    trace = tmp_path / "bytes.log"
    with EmsconServer(rig) as server:
        tracker = open_emscon(server, trace=str(trace))
        tracker.measure(1, 2.0)
        tracker.close()
        with pytest.raises(ConnectionFailed, match="not connected"):
            tracker.measure(1, 2.0)
        assert server.connections == 1
    text = trace.read_text()
    assert f"# connect emscon:127.0.0.1:{server.port}" in text
    assert "> b'\\x0c\\x00\\x00\\x00\\x00\\x00\\x00\\x00\\x01\\x00\\x00\\x00'" in text  # GetSystemStatus
    assert text.count(" < b'") >= 14 and "disconnected" in text


def test_a_broken_beam_is_target_lost_then_measured_again(rig: SimulatedRig) -> None:
    with EmsconServer(rig, noise=NOISE) as server:
        tracker = open_emscon(server)
        server.inject("beam_broken")
        with pytest.raises(TargetLost) as info:
            tracker.measure(1, 2.0)
        assert isinstance(info.value, BeamLost) and info.value.status == 10004
        message = str(info.value)
        assert "10004" in message and "broken beam or reflector lost" in message and "\n" not in message
        assert "measurement status not ready" in message  # the server's status change, heard before the answer
        readings = tracker.measure(1, 2.0)  # the beam is back: the server says ready, then measures
        events = [text for _, text in tracker.events]
        reconnects = tracker.reconnects
        tracker.close()
    assert np.abs(_errors(server, readings)).max() < TOL
    assert events[-2:] == ["measurement status not ready", "measurement status ready"] and reconnects == 0


@pytest.mark.parametrize(("fault", "kind", "status"), [("lost_during", BeamLost, 10009),
                                                        ("warming_up", TrackerNotReady, 10012),
                                                        ("not_ready", TrackerNotReady, 10014)])
def test_status_faults_are_one_line_measurement_errors(rig: SimulatedRig, fault: str, kind: type,
                                                       status: int) -> None:
    with EmsconServer(rig) as server:
        tracker = open_emscon(server)
        server.inject(fault)
        with pytest.raises(kind) as info:
            tracker.measure(1, 2.0)
        assert len(tracker.measure(1, 2.0)) == 1  # the next measurement works on the same link
        assert tracker.reconnects == 0
        tracker.close()
    assert isinstance(info.value, MeasurementError) and info.value.status == status
    assert str(status) in str(info.value) and "\n" not in str(info.value)
    assert isinstance(info.value, TargetLost) == (kind is BeamLost)


@pytest.mark.parametrize("fault", ["garbage", "silence", "drop", "split"])
def test_a_damaged_dropped_or_silent_link_loses_no_reading(rig: SimulatedRig, fault: str) -> None:
    with EmsconServer(rig, noise=NOISE) as server:
        tracker = open_emscon(server)  # answer timeout 0.5 s
        server.inject(fault)
        started = time.monotonic()
        readings = tracker.measure(3, 5.0)
        took = time.monotonic() - started
        reconnects, connections = tracker.reconnects, server.connections
        tracker.close()
    assert len(readings) == 3 and np.abs(_errors(server, readings)).max() < TOL
    again = fault != "split"  # split packets are reassembled on the same link
    assert reconnects == int(again) and connections == 1 + int(again)
    assert took < (1.0 if fault == "silence" else 0.5)  # silence: one answer timeout (0.5 s), then a new link


def test_a_persistently_silent_tracker_times_out_in_one_line(rig: SimulatedRig) -> None:
    with EmsconServer(rig) as server:
        tracker = open_emscon(server, timeout="0.2", retries="1")
        server.inject("silence", 2)
        started = time.monotonic()
        with pytest.raises(DeviceTimeout) as info:
            tracker.measure(1, 5.0)
        took = time.monotonic() - started
        assert len(tracker.measure(1, 2.0)) == 1  # and it measures again once the server answers
        tracker.close()
    message = str(info.value)
    assert "no answer to" in message and "(after 2 attempts)" in message and "\n" not in message
    assert 0.4 <= took < 1.0


def test_persistent_garbage_is_a_bad_reading(rig: SimulatedRig) -> None:
    with EmsconServer(rig) as server:
        tracker = open_emscon(server, retries="1")
        server.inject("garbage", 2)
        with pytest.raises(BadReading) as info:
            tracker.measure(1, 5.0)
        tracker.close()
    assert "out of step" in str(info.value) and "(after 2 attempts)" in str(info.value)
    assert "\n" not in str(info.value)


def test_a_server_gone_for_good_is_connection_failed(rig: SimulatedRig) -> None:
    server = EmsconServer(rig)
    tracker = open_emscon(server)
    server.stop()  # stops listening; the open link is closed when the server thread ends
    with pytest.raises(ConnectionFailed) as info:
        tracker.measure(1, 3.0)
    tracker.close()
    assert f"{server.port}" in str(info.value) and "\n" not in str(info.value)


def test_nobody_listening_is_connection_failed() -> None:
    port = free_port()
    tracker = open_tracker(f"emscon:127.0.0.1:{port}")
    with pytest.raises(ConnectionFailed) as info:
        tracker.connect(1.0)
    assert str(port) in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(ConnectionFailed, match="not connected"):
        tracker.measure(1, 1.0)


def test_default_port_and_option_checks() -> None:
    assert open_tracker("emscon:at960.local").port == DEFAULT_PORT == 700
    assert open_tracker("emscon:[fe80::1]:7000").port == 7000
    for bad, words in (("speed=3", "unknown option 'speed'"), ("timeout=-1", "timeout=-1"),
                       ("retries=x", "retries=x"), ("meas_time=0", "meas_time=0"),
                       ("initialize=never", "auto or always"), ("temperature=20", "go together"),
                       ("temperature=20&pressure=100&humidity=50", "pressure=100 must be a number in [500, 1200]"),
                       ("noise=1e-5", "unknown option 'noise' (only for emscon:sim)")):
        with pytest.raises(SpecError, match=re.escape(words)) as info:
            open_tracker(f"emscon:host?{bad}")
        assert "\n" not in str(info.value)
    with pytest.raises(SpecError, match="use it with --robot mock:MODEL"):
        open_tracker("emscon:sim")


def test_a_changed_environment_is_kept_with_the_readings(rig: SimulatedRig) -> None:
    with EmsconServer(rig) as server:
        tracker = open_emscon(server)
        before = tracker.measure(1, 2.0)[0]
        server.change_environment((20.6, 1012.9, 48.0))  # the weather station moved on
        after = tracker.measure(2, 2.0)
        ident = tracker.identity()
        tracker.close()
    assert before.status == "ok"
    assert [r.status for r in after] == ["ok, environment 20.6 degC, 1012.9 mbar, 48 %RH"] * 2
    assert ident.details["environment"].startswith("20 degC, 1013.25 mbar, 50 %RH")  # the header: at connect
