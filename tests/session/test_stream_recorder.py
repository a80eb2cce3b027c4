"""A stream attempt's last position (``StreamRecorder.last_point``): the arm at rest at the range end is the last
streamed sample of the smallest tracked-point id, read from the session file, and nothing when the tracker
streamed no position."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drivers.base import JointStreamBatch, TrackerStreamBatch
from session.plan import Plan, Step
from session.store import SessionFile
from session.streams import StreamRecorder
from tests._session_writer import CONFIG, HOME, JOINT_TYPES, ROBOT, TRACKER


def _plan() -> Plan:
    start = (HOME[0] - 0.5, *HOME[1:])
    end = (HOME[0] + 0.5, *HOME[1:])
    steps = (Step(0, "home", 0, 0, HOME, "check"), Step(1, "stream", 1, 1, end, start=start, speed=0.5,
                                                             acceleration=1.0))
    return Plan("test-arm", JOINT_TYPES, HOME, steps, samples_per_step=1, settle_time=0.0)


def _tracker(t: list[float], points: list[list[float]], tp: list[int], sigma: list[float]) -> TrackerStreamBatch:
    return TrackerStreamBatch(np.array(t), np.array(points), np.array(tp, dtype=np.int64), np.array(sigma))


def test_the_last_position_is_the_latest_sample_of_the_smallest_tracked_point(tmp_path: Path) -> None:
    with SessionFile.create(tmp_path / "s.session", _plan(), CONFIG, ROBOT, TRACKER) as session:
        session.begin_run()
        recorder = StreamRecorder(session, 1, 10.0)
        assert recorder.last_point() is None  # nothing streamed yet
        joints = JointStreamBatch(np.array([0.0, 0.1]), np.zeros((2, 3)))
        recorder.commit([joints], [_tracker([0.0, 0.0], [[1, 2, 3], [4, 5, 6]], [1, 2], [np.nan, np.nan])], 11.0)
        # later samples, tracked point 2 listed first; the second batch's last time holds both points
        recorder.commit([], [_tracker([0.5, 0.5, 0.4], [[7, 8, 9], [0.1, 0.2, 0.3], [9, 9, 9]], [2, 1, 1],
                                      [2e-5, 1e-5, 3e-5])], 12.0)
        position, sigma = recorder.last_point()
        assert position == (0.1, 0.2, 0.3) and sigma == 1e-5
        other = StreamRecorder(session, 1, 20.0)  # a new attempt reads only its own samples
        other.commit([], [_tracker([1.0], [[4.0, 4.0, 4.0]], [3], [np.nan])], 21.0)
        assert other.last_point() == ((4.0, 4.0, 4.0), None)
