"""Continuous measurement by time of the emScon client (drivers/trackers/emscon_stream.py) against the loopback
emulator (tests/emscon_device.py) on the wall clock: every point stamped with the tracker's own time, the truth within
the noise, and faults mid-stream (a broken beam, flagged points, a dropped, garbled or silent link) as gaps while the
stream goes on. Each test streams for a second or two."""

from __future__ import annotations

import time

import numpy as np
import pytest

from drivers.base import StreamingTracker
from drivers.clock import WallClock
from drivers.errors import ConnectionFailed
from drivers.sim.rig import SimulatedRig
from drivers.trackers import emscon_protocol as es
from drivers.trackers.emscon_stream import GAP_FACTOR
from tests.emscon_device import EmsconServer, open_emscon

NOISE = 2e-5  # m per axis, the emulator's noise
TOL = 5 * NOISE  # per axis: a point further than this from the truth is wrong (5 sigma, ~1 in 1.7 million)
STAMP = 1e-6  # s: lTime2 carries whole microseconds


@pytest.fixture
def rig() -> SimulatedRig:
    return SimulatedRig("ur5e", seed=2, clock=WallClock())


def _collect(tracker, seconds: float) -> list:
    batches, end = [], time.monotonic() + seconds
    while time.monotonic() < end:
        time.sleep(0.05)
        batches.append(tracker.read_stream())
    return batches


def _join(batches: list) -> tuple[np.ndarray, np.ndarray, list]:
    t = np.concatenate([b.t for b in batches])
    points = np.concatenate([b.points for b in batches])
    return t, points, [g for b in batches for g in b.gaps]


def test_points_are_the_truth_stamped_on_the_trackers_clock(rig: SimulatedRig) -> None:
    with EmsconServer(rig, noise=NOISE, seed=3, drift=2e-4) as server:
        tracker = open_emscon(server)
        assert isinstance(tracker, StreamingTracker)
        rate = tracker.start_stream(250.0, 2.0)
        with pytest.raises(RuntimeError, match="is streaming"):
            tracker.measure(1, 1.0)
        batches = _collect(tracker, 0.6)
        batches.append(tracker.stop_stream(2.0))
        sent = list(server.streamed)
        reading = tracker.measure(1, 2.0)[0]  # the stationary mode again
        modes = server.commands.count(es.C_SET_MEAS_MODE)  # at connect, for the stream, for the reading
        separation = server.continuous[0]
        tracker.close()
    t, points, gaps = _join(batches)
    tau = np.array([s[0] for s in sent])
    truth = np.array([s[1] for s in sent])
    assert rate == 250.0 and separation == 4 and modes == 3 and server.mode == es.MM_STATIONARY
    assert len(t) == len(sent) > 100 and not gaps  # every point the server sent, the last ones after the stop
    np.testing.assert_allclose(t, server.tracker_time(tau), rtol=0, atol=STAMP)  # the tracker's clock, drift included
    np.testing.assert_allclose(np.diff(t), 0.004 * (1 + 2e-4), rtol=0, atol=2 * STAMP)
    assert np.abs(points - truth).max() < TOL
    assert np.abs(np.std(points - truth, axis=0) - NOISE).max() < 0.25 * NOISE  # the noise, not a smoothed copy
    assert np.abs(reading.position - server.truths[-1]).max() < TOL


def test_faults_mid_stream_are_gaps_and_the_stream_goes_on(rig: SimulatedRig) -> None:
    """A broken beam (twice refused on restart: a relock every 0.2 s), a silent link (0.5 s), flagged points, a
    dropped link and garbage: each one gap around exactly the points lost, every other point kept, the stream
    running to the end."""
    faults = ("stream_lost", "stream_silence", "stream_prism", "stream_drop", "stream_garbage")
    with EmsconServer(rig, noise=NOISE, seed=4) as server:
        tracker = open_emscon(server, timeout="0.5")
        tracker.start_stream(250.0, 2.0)
        batches = _collect(tracker, 0.3)
        for fault in faults:
            server.inject(fault, 2 if fault == "stream_lost" else 1)
            batches += _collect(tracker, 0.9 if fault in ("stream_lost", "stream_silence") else 0.4)
        batches.append(tracker.stop_stream(2.0))
        sent = np.array([server.tracker_time(s[0]) for s in server.streamed])
        counts, connections = dict(tracker.stream_counts), server.connections
        tracker.close()
    t, _, gaps = _join(batches)
    assert counts["beam_lost"] == 1 and counts["relocks"] == 3  # refused twice, then measuring again
    assert counts["reconnects"] == 3 and connections == 4  # the silence, the drop, the garbage
    assert counts["flagged"] > 0 and counts["gaps"] == len(gaps) == len(faults)
    kept = set(np.round(t, 6))
    assert kept <= set(np.round(sent, 6))  # only points the server sent
    missing = [s for s in sent if round(s, 6) not in kept]  # flagged, or sent on a link the client then dropped
    assert len(missing) >= counts["flagged"] and all(any(a < s < b for a, b in gaps) for s in missing)
    steps = np.diff(t)
    jumps = [(a, b) for a, b, d in zip(t[:-1], t[1:], steps, strict=True) if d > GAP_FACTOR * 0.004]
    assert [tuple(g) for g in gaps] == jumps  # a gap exactly where points are missing, nowhere else


def test_a_server_gone_for_good_fails_the_stream_in_one_line(rig: SimulatedRig) -> None:
    server = EmsconServer(rig, noise=NOISE)
    tracker = open_emscon(server, timeout="0.2", retries="1")
    tracker.start_stream(100.0, 2.0)
    time.sleep(0.2)
    server.stop()  # closes the link and listens no more
    deadline = time.monotonic() + 3.0
    with pytest.raises(ConnectionFailed) as failed:
        while time.monotonic() < deadline:
            tracker.read_stream()
            time.sleep(0.05)
    assert "continuous measurement, after 2 attempts" in str(failed.value) and "\n" not in str(failed.value)
    tracker.close()


def test_stamps_that_are_not_seconds_and_microseconds_stop_the_stream(rig: SimulatedRig) -> None:
    class MillisecondServer(EmsconServer):
        def tracker_time(self, tau):  # a server counting milliseconds in lTime1 and lTime2 together
            return super().tracker_time(tau) * 1000.0

    with MillisecondServer(rig, noise=NOISE) as server:
        tracker = open_emscon(server)
        tracker.start_stream(250.0, 2.0)
        with pytest.raises(ConnectionFailed, match="4000 ms apart by their time stamps, not the 4 ms asked") as failed:
            _collect(tracker, 0.5)
        assert "use --mode step" in str(failed.value)
        tracker.close()


def test_a_6dof_probe_result_decodes_to_the_true_pose(rig: SimulatedRig) -> None:
    """``measure_pose``: the emulator serves 6-DoF stationary results and the client turns them into poses (as
    readings with probe=6dof: tests/drivers/trackers/test_emscon_probe.py); the next stationary reading sets the
    stationary mode again."""
    from drivers.trackers.emscon_probe import ProbePose

    angle = 2e-5  # rad per axis
    with EmsconServer(rig, noise=NOISE, seed=6, angle_noise=angle) as server:
        tracker = open_emscon(server)
        poses = [tracker.measure_pose(2.0) for _ in range(20)]
        truths = list(server.probe_truths)
        reading = tracker.measure(1, 2.0)[0]
        tracker.close()
    assert all(isinstance(p, ProbePose) for p in poses) and server.mode == es.MM_STATIONARY
    position = np.array([p.matrix[:3, 3] - t[:3, 3] for p, t in zip(poses, truths, strict=True)])
    turn = np.array([np.arccos(np.clip((np.trace(p.matrix[:3, :3].T @ t[:3, :3]) - 1) / 2, -1, 1))
                     for p, t in zip(poses, truths, strict=True)])
    assert np.abs(position).max() < TOL and np.abs(position).max() > 0  # the tip, with its noise
    assert turn.max() < 5 * np.sqrt(3) * angle and turn.max() > 0  # the orientation, with its noise
    assert np.allclose([p.matrix[3] for p in poses], [0, 0, 0, 1]) and poses[0].position_std.tolist() == [NOISE] * 3
    assert np.abs(reading.position - server.truths[-1]).max() < TOL
