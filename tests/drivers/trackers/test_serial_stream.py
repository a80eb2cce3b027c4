"""ASCII trackers streaming with the device's timestamps (drivers/trackers/serial_stream.py): the real serial driver
on a real pseudo-terminal with the simulated ``stream-csv`` device (tests/tracker_devices.py) at 500 Hz on its own
clock."""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.base import StreamingTracker, TrackerStreamBatch
from drivers.registry import open_tracker
from drivers.sim.rig import SimulatedRig
from tests.tracker_devices import AsciiDevice

PERIOD = 0.002  # s, the stream-csv device's period
OFFSET = 1000.0  # s, the device clock runs this far ahead of the host's


@pytest.fixture
def device():
    with AsciiDevice("stream-csv", SimulatedRig("ur5e"), clock_offset=OFFSET) as dev:
        yield dev


def connected(device: AsciiDevice):
    tracker = open_tracker(f"serial:{device.port}?protocol=stream-csv")
    tracker.connect(2.0)
    return tracker


def collect(tracker, seconds: float, during=None) -> TrackerStreamBatch:
    """Read the stream for ``seconds`` (``during()`` once, after a quarter of them) into one batch."""
    batches, end, done = [], time.monotonic() + seconds, during is None
    while time.monotonic() < end:
        time.sleep(0.02)
        batches.append(tracker.read_stream())
        if not done and time.monotonic() > end - 0.75 * seconds:
            during()
            done = True
    batches.append(tracker.stop_stream(1.0))
    return TrackerStreamBatch(np.concatenate([b.t for b in batches]), np.concatenate([b.points for b in batches]),
                              np.concatenate([b.tp for b in batches]), np.concatenate([b.sigma for b in batches]),
                              tuple(g for b in batches for g in b.gaps))


def test_stream_at_the_device_rate_with_device_timestamps(device: AsciiDevice) -> None:
    tracker = connected(device)
    try:
        assert isinstance(tracker, StreamingTracker)
        assert tracker.start_stream(1000.0, 2.0) == pytest.approx(1.0 / PERIOD)  # the device keeps its own rate
        host = time.time()
        batch = collect(tracker, 0.6)
        tracker.start_stream(500.0, 2.0)  # streaming again: measure() is refused while the reader owns the port
        with pytest.raises(RuntimeError, match="stop_stream"):
            tracker.measure(1, 1.0)
    finally:
        tracker.close()
    t = batch.t
    assert batch.gaps == ()  # nothing lost on a clean line
    assert np.all(np.diff(t) > 0)
    # the device's clock, not the host's: OFFSET ahead, within the stream's span
    assert host + OFFSET - 0.1 < t[0] < host + OFFSET + 0.1
    # the device's rate: a line every PERIOD (the simulated device's own pacing jitters by a few ms)
    span = t[-1] - t[0]
    assert 0.45 < span < 0.7
    assert abs(np.median(np.diff(t)) - PERIOD) < 0.3 * PERIOD
    assert len(t) > 0.8 * span / PERIOD
    true = device.rig.true_point()
    assert np.abs(batch.points - true).max() < 6 * device.noise and np.all(batch.tp == 1)
    np.testing.assert_allclose(batch.sigma, 5e-5)  # the profile's stated sigma


def test_a_half_second_target_loss_is_one_gap(device: AsciiDevice) -> None:
    tracker = connected(device)
    lost: list[tuple[float, float]] = []
    try:
        tracker.start_stream(500.0, 2.0)
        batch = collect(tracker, 1.2, lambda: lost.append(device.lose_target(0.5)))
        counts = tracker.stream_counts
    finally:
        tracker.close()
    assert len(batch.gaps) == 1
    (start, end), (lost_from, lost_to) = batch.gaps[0], lost[0]
    assert start < lost_from + PERIOD and end > lost_to - PERIOD  # the gap covers the loss...
    assert 0.5 - 2 * PERIOD < end - start < 0.5 + 0.05  # ...and not much more (device pacing jitter)
    assert not np.any((batch.t > start) & (batch.t < end))  # no reading inside it
    assert start in batch.t and end in batch.t
    assert counts["lost_lines"] > 0.8 * 0.5 / PERIOD


def test_lines_missing_on_the_wire_are_a_gap_by_sequence_number(device: AsciiDevice) -> None:
    tracker = connected(device)
    try:
        tracker.start_stream(500.0, 2.0)
        batch = collect(tracker, 0.4, lambda: device.skip_lines(3))
    finally:
        tracker.close()
    assert len(batch.gaps) == 1
    start, end = batch.gaps[0]
    assert 2 * PERIOD < end - start < 4 * PERIOD + 0.02  # four periods, give or take the device's pacing


def test_device_latency_shows_in_its_timestamps() -> None:
    with AsciiDevice("stream-csv", SimulatedRig("ur5e"), latency=0.05) as device:
        tracker = connected(device)
        try:
            tracker.start_stream(500.0, 2.0)
            time.sleep(0.2)
            received = time.time()
            batch = tracker.stop_stream(1.0)
        finally:
            tracker.close()
    assert received - batch.t[-1] > 0.05  # the last reading was taken at least the latency before it arrived


def test_a_profile_without_device_time_cannot_stream() -> None:
    with AsciiDevice("polled-xyz") as device:
        tracker = open_tracker(f"serial:{device.port}?protocol=polled-xyz")
        tracker.connect(2.0)
        try:
            with pytest.raises(ValueError, match="time field t") as info:
                tracker.start_stream(100.0, 1.0)
            assert "\n" not in str(info.value)
            assert len(tracker.measure(1, 2.0)) == 1  # still a polled tracker
        finally:
            tracker.close()
