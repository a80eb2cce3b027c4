"""The serial tracker driver over real byte streams: pyserial on a pseudo-terminal (and loopback TCP)."""

from __future__ import annotations

import io
import time
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

pytest.importorskip("serial")

from drivers.base import Tracker
from drivers.errors import BadReading, ConnectionFailed, DeviceTimeout, SpecError, TargetLost
from drivers.registry import open_tracker
from drivers.sim.rig import SimulatedRig
from drivers.trackers.serial_tracker import SerialTracker
from drivers.trackers.serial_tracker import open_tracker as open_serial
from tests.tracker_devices import AsciiDevice

PROFILES = ("polled-xyz", "stream-csv", "tracker-checksum")
TOL = 5e-4  # m: noise 2e-5 plus the formats' resolution


@pytest.fixture
def rig() -> SimulatedRig:
    return SimulatedRig("ur5e", seed=4)


def _open(device: AsciiDevice, **options: str) -> SerialTracker:
    query = "&".join(f"{k}={v}" for k, v in {"protocol": device.profile.name, "timeout": "0.3", **options}.items())
    tracker = open_tracker(f"serial:{device.port}?{query}")
    tracker.connect(2.0)
    return tracker


@pytest.mark.parametrize("name", PROFILES)
def test_each_profile_measures_the_true_point(name: str, rig: SimulatedRig) -> None:
    with AsciiDevice(name, rig) as device:
        tracker = _open(device)
        try:
            readings = tracker.measure(5, timeout=3.0)
        finally:
            tracker.close()
    assert len(readings) == 5
    for r in readings:
        assert np.allclose(r.position, rig.true_point(), atol=TOL)
        assert r.status == "ok" and r.sigma is not None


def test_opened_tracker_is_a_tracker() -> None:
    assert isinstance(open_tracker("serial:/dev/ttyS0"), Tracker)


def test_identity_from_the_identify_command(rig: SimulatedRig) -> None:
    with AsciiDevice("tracker-checksum", rig) as device:
        tracker = _open(device)
        ident = tracker.identity()
        tracker.close()
    assert (ident.model, ident.serial, ident.firmware) == ("LT-500", "T5001", "4.2")
    assert ident.details["profile"] == "tracker-checksum"


@pytest.mark.parametrize("fault", ["noise", "partial"])
def test_noise_bytes_and_partial_lines_still_parse(fault: str, rig: SimulatedRig) -> None:
    with AsciiDevice("tracker-checksum", rig) as device:
        tracker = _open(device, retries="0")
        device.inject(fault, 3)
        readings = tracker.measure(3, 3.0)
        tracker.close()
    assert all(np.allclose(r.position, rig.true_point(), atol=TOL) for r in readings)


@pytest.mark.parametrize("fault", ["garbage", "truncated", "bad_checksum", "out_of_range", "silence", "reset"])
def test_transient_faults_are_retried(fault: str, rig: SimulatedRig) -> None:
    with AsciiDevice("tracker-checksum", rig) as device:
        tracker = _open(device)
        device.inject(fault, 1)
        readings = tracker.measure(2, 5.0)
        tracker.close()
    assert len(readings) == 2
    if fault == "reset":
        assert tracker.resets == 1


@pytest.mark.parametrize(("fault", "error", "words"), [
    ("bad_checksum", BadReading, "checksum"), ("garbage", BadReading, ""), ("truncated", BadReading, ""),
    ("out_of_range", BadReading, "range"), ("target_lost", TargetLost, ""), ("silence", DeviceTimeout, "no answer"),
    ("reset", BadReading, "kept resetting"),
])
def test_persistent_faults_give_one_clear_error(fault: str, error: type, words: str, rig: SimulatedRig) -> None:
    with AsciiDevice("tracker-checksum", rig) as device:
        tracker = _open(device, retries="2")
        device.inject(fault, 3)
        with pytest.raises(error) as info:
            tracker.measure(1, 5.0)
        message = str(info.value)
        assert "\n" not in message and words in message
        assert "3 attempts" in message or fault == "reset"
        assert len(tracker.measure(1, 2.0)) == 1  # the device recovered, so does the driver
        tracker.close()


def test_target_lost_error_reply_of_polled_device(rig: SimulatedRig) -> None:
    with AsciiDevice("polled-xyz", rig) as device:
        tracker = _open(device, retries="0")
        device.inject("target_lost")
        with pytest.raises(TargetLost):
            tracker.measure(1, 2.0)
        tracker.close()


def test_reset_mid_session_reinitialises_the_device(rig: SimulatedRig) -> None:
    with AsciiDevice("polled-xyz", rig) as device:
        tracker = _open(device)
        tracker.measure(2, 2.0)
        device.inject("reset")
        readings = tracker.measure(3, 5.0)
        tracker.close()
    assert len(readings) == 3 and tracker.resets == 1
    assert device.commands.count("UNITS MM") == 2


def test_streaming_device_reset_and_mixed_line_endings(rig: SimulatedRig) -> None:
    with AsciiDevice("stream-csv", rig, mixed_endings=True) as device:
        tracker = _open(device)
        assert len(tracker.measure(20, 3.0)) == 20
        device.reset()  # unprompted: banner, stream stops until STREAM ON
        readings = tracker.measure(10, 5.0)
        tracker.close()
    assert len(readings) == 10  # the banner may be flushed away: a timeout then restarts the stream
    assert device.commands.count("STREAM ON") == 2


def test_trace_io_logs_every_byte_both_ways(rig: SimulatedRig, tmp_path) -> None:
    trace = tmp_path / "io.log"
    with AsciiDevice("polled-xyz", rig) as device:
        tracker = _open(device, trace=str(trace))
        tracker.measure(2, 2.0)
        tracker.close()
        received = bytes(device.received)
    text = trace.read_text()
    assert "> b'MEAS?\\r\\n'" in text and "< b'" in text and "# open" in text
    sent = b"".join(eval(line.split(" ", 2)[2]) for line in text.splitlines() if line.split(" ")[1] == ">")
    assert sent == received


def test_trace_io_argument_takes_a_file_object(rig: SimulatedRig) -> None:
    log = io.StringIO()
    with AsciiDevice("polled-xyz", rig) as device:
        tracker = open_serial(f"serial:{device.port}?protocol=polled-xyz", trace_io=log)
        tracker.connect(2.0)
        tracker.measure(1, 2.0)
        tracker.close()
    assert "MEAS?" in log.getvalue()


def test_socket_url_works_like_a_port(rig: SimulatedRig) -> None:
    with AsciiDevice("polled-xyz", rig, transport="tcp") as device:
        tracker = _open(device)
        reading = tracker.measure(1, 2.0)[0]
        tracker.close()
    assert np.allclose(reading.position, rig.true_point(), atol=TOL)


def test_loop_url_opens() -> None:
    tracker = open_tracker("serial:loop://?protocol=stream-csv&timeout=0.1&retries=0")
    tracker.connect(1.0)
    with pytest.raises((BadReading, DeviceTimeout)):
        tracker.measure(1, 0.5)
    tracker.close()


def test_missing_port_is_one_line_connection_failed() -> None:
    tracker = open_tracker("serial:/dev/does-not-exist-42?protocol=polled-xyz")
    with pytest.raises(ConnectionFailed) as info:
        tracker.connect(1.0)
    assert "\n" not in str(info.value) and "/dev/does-not-exist-42" in str(info.value)


def test_busy_port_is_connection_failed(rig: SimulatedRig) -> None:
    with AsciiDevice("polled-xyz", rig) as device:
        first = _open(device)
        second = open_tracker(f"serial:{device.port}?protocol=polled-xyz")
        with pytest.raises(ConnectionFailed) as info:
            second.connect(1.0)
        first.close()
    assert device.port in str(info.value) and "no other program" in str(info.value) and "\n" not in str(info.value)


def test_silent_device_at_connect_times_out(rig: SimulatedRig) -> None:
    with AsciiDevice("polled-xyz", rig) as device:
        device.stop()  # nobody answers
        tracker = open_tracker(f"serial:{device.port}?protocol=polled-xyz")
        with pytest.raises((DeviceTimeout, ConnectionFailed)):
            tracker.connect(0.3)
        tracker.close()


@pytest.mark.parametrize(("spec", "words"), [
    ("serial:/dev/ttyS0?protocl=polled-xyz", "unknown option 'protocl'"),
    ("serial:/dev/ttyS0?baud=fast", "baud=fast"),
    ("serial:/dev/ttyS0?parity=X", "parity=X"),
    ("serial:/dev/ttyS0?eol=crcr", "eol=crcr"),
    ("serial:/dev/ttyS0?protocol=nonesuch", "nonesuch"),
])
def test_bad_options_are_rejected_with_one_line(spec: str, words: str) -> None:
    with pytest.raises(SpecError) as info:
        open_tracker(spec)
    assert words in str(info.value) and "\n" not in str(info.value)


def test_site_settings_are_defaults_below_the_spec() -> None:
    site = SimpleNamespace(tracker_settings={"baud": 19200, "protocol": "stream-csv"})
    tracker = open_serial("serial:/dev/ttyS0?baud=57600", site=site)
    assert tracker.baud == 57600 and tracker.profile.name == "stream-csv"


def test_echoing_device_works(rig: SimulatedRig) -> None:
    with AsciiDevice("tracker-checksum", rig, echo=True) as device:
        tracker = _open(device)
        readings = tracker.measure(3, 3.0)
        assert tracker.identity().model == "LT-500"
        tracker.close()
    assert all(np.allclose(r.position, rig.true_point(), atol=TOL) for r in readings)


def test_unplugged_device_is_connection_failed(rig: SimulatedRig) -> None:
    with AsciiDevice("polled-xyz", rig) as device:
        tracker = _open(device)
        tracker.measure(1, 2.0)
        device.stop()  # closes the pty's device side: the link is gone
        with pytest.raises(ConnectionFailed) as info:
            tracker.measure(1, 2.0)
        assert "\n" not in str(info.value)
        tracker.close()


def test_wrong_profile_for_the_device_fails_at_connect(rig: SimulatedRig) -> None:
    with AsciiDevice("polled-xyz", rig) as device:
        tracker = open_tracker(f"serial:{device.port}?protocol=tracker-checksum")
        with pytest.raises((DeviceTimeout, ConnectionFailed)) as info:
            tracker.connect(0.5)
        assert "$ID" in str(info.value)
        tracker.close()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.binary(max_size=300), st.sampled_from(PROFILES))
def test_fuzz_driver_on_loop_never_hangs_or_crashes(data: bytes, name: str) -> None:
    tracker = open_tracker(f"serial:loop://?protocol={name}&timeout=0.02&retries=1")
    if name != "stream-csv":  # the polled profiles wait for replies at connect: skip that handshake
        tracker.profile = replace(tracker.profile, init=(), identify=None)
    tracker.connect(0.5)
    try:
        flush = tracker._flush

        def flush_then_receive(recover: bool = True) -> None:  # the "device" sends ``data`` after each flush
            flush(recover)
            tracker._port.write(data)  # loop:// reads back what is written

        tracker._flush = flush_then_receive
        started = time.monotonic()
        try:
            readings = tracker.measure(1, 0.3)
            assert np.all(np.isfinite(readings[0].position))
        except (BadReading, TargetLost, DeviceTimeout):
            pass
        assert time.monotonic() - started < 1.0
    finally:
        tracker.close()


def test_streaming_garbage_and_lost_target_are_skipped_or_reported(rig: SimulatedRig) -> None:
    with AsciiDevice("stream-csv", rig) as device:
        tracker = _open(device, retries="1")
        device.inject("garbage", 1)
        assert len(tracker.measure(5, 3.0)) == 5
        device.inject("target_lost", 50)
        with pytest.raises(TargetLost):
            tracker.measure(1, 3.0)
        tracker.close()


def test_polled_device_with_mixed_line_endings(rig: SimulatedRig) -> None:
    with AsciiDevice("tracker-checksum", rig, mixed_endings=True) as device:
        tracker = _open(device, retries="0")
        readings = tracker.measure(20, 5.0)
        tracker.close()
    assert all(np.allclose(r.position, rig.true_point(), atol=TOL) for r in readings)
