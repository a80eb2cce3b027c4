"""Streaming for the ArUco camera tracker: every frame at the camera's frame rate, detected in a worker thread
(implements :class:`drivers.base.StreamingTracker` for :class:`drivers.camera.tracker.ArucoTracker`, which inherits this
mixin).

The frame source (drivers/camera/sources.py: a live camera; drivers/camera/renderer.py: the rendered camera) hands
each frame, numbered and stamped with its capture time, to a bounded queue; a worker thread takes them in order
and measures each one with the polled path's own code (``ArucoTracker._pose``: detection, corner refinement,
pose, the ``max_rms`` check; the TP covariance from :class:`drivers.camera.pose.CornerNoise`, pooled over the
stream's frames so far). A frame becomes a row ``(t, x, y, z, sigma, rx, ry, rz, sigma_r)``: t the frame's stamp
(s, the source's clock; its ``stamps`` is in the tracker's identity), the TP in metres in the camera frame, sigma the
per-axis standard uncertainty of that one frame (m, ``sqrt(trace(C) / 3)``), the target frame's orientation (rotation
vector, rad, camera frame) and its per-axis sigma (rad, with the view's error as a polled reading states it).

Gaps ``(start, end)`` (stamps, s) are recorded from the last good frame before to the first good one after:

- a frame where the target is not seen or fails a check (TargetLost, BadReading, DuplicateMarker);
- frames the source lost: its frame number jumps, or the stamps step by more than :data:`GAP_FACTOR` frame
  periods (the camera dropped them before we saw them), or go backwards;
- frames still queued when ``stop_stream`` runs out of time (never measured).

A bad stretch at the very start (no good frame before it) runs from its first frame's stamp, and one at the very
end to its last frame's stamp, so every frame taken is a row or inside a gap. ``read_stream`` first lets the source
capture (the simulated camera renders the frames due by now there; a live camera raises DeviceTimeout after
``timeout`` s without a frame), then hands over what the worker has measured. ``stop_stream`` captures the last
frames due, closes the queue, waits up to its timeout for the worker to measure what is queued and always joins
it. ``measure`` is refused while a stream runs.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any

import cv2
import numpy as np

from drivers.base import TrackerStreamBatch
from drivers.camera.pose import VIEW_BIAS_PX, VIEW_TURN_BIAS_PX, CornerNoise
from drivers.camera.sources import Frame, FrameQueue
from drivers.errors import ConnectionFailed, MeasurementError, TargetLost
from drivers.stream_buffer import BufferedStreaming

GAP_FACTOR = 1.5  # a step of the stamps above this many frame periods means frames were lost
WAIT = 0.05  # s: the worker looks at its stop flag this often while the queue is empty


class FrameStreaming(BufferedStreaming):
    """The streaming half of ArucoTracker (see the module docstring)."""

    source: Any
    settings: Any
    _pose: Any

    def _init_stream(self) -> None:
        self._init_buffer()
        self._frames: FrameQueue | None = None
        self._period = math.nan
        self._noise = CornerNoise()
        self.stream_counts = {"frames": 0, "rows": 0, "not_seen": 0, "rejected": 0, "missing": 0, "unmeasured": 0,
                              "gaps": 0}
        self.detect_seconds = 0.0  # worker time spent measuring frames (detection, refinement, pose)

    def start_stream(self, rate: float, timeout: float) -> float:
        """Start the frames and the detection worker; returns the camera's frame rate (Hz). ``rate`` is what the
        caller would like: a camera runs at its own."""
        if not (rate > 0 and timeout > 0):
            raise ValueError(f"rate and timeout must be > 0, got {rate!r} Hz and {timeout!r} s")
        if not callable(getattr(self.source, "start_frames", None)):
            raise ValueError(f"{self.source.description} cannot stream (a replay has no live frame timing): use a "
                             "live camera or aruco:sim")
        self.stop_stream(timeout)
        self._init_stream()
        queue, frame_rate = self.source.start_frames(timeout)
        if not (math.isfinite(frame_rate) and frame_rate > 0):
            self.source.stop_frames()
            raise ConnectionFailed(f"{self.source.description} reports no usable frame rate ({frame_rate!r})")
        self._frames, self._period = queue, 1.0 / frame_rate
        self._reader = threading.Thread(target=self._detect_loop, args=(queue,), daemon=True,
                                        name=f"aruco-stream-{self.source.description}")
        self._reader.start()
        return float(frame_rate)

    def read_stream(self) -> TrackerStreamBatch:
        """Every frame measured since the last read (module docstring); the source's failure (ConnectionFailed,
        DeviceTimeout) or the worker's."""
        if self._frames is not None:
            self.source.capture(self.settings.timeout)
        return super().read_stream()

    def stop_stream(self, timeout: float) -> TrackerStreamBatch:
        """Stop the frames, let the worker measure what is queued (up to ``timeout`` s), join it; returns the rows
        since the last read. A failure of the last capture is raised after that (the rows stay for the next call)."""
        reader, queue = self._reader, self._frames
        if reader is None or queue is None:
            return self._stop_reader(timeout)
        self._frames = None
        try:
            self.source.capture(self.settings.timeout)
        finally:
            self.source.stop_frames()
            queue.close()
            reader.join(max(timeout, 0.1))  # the worker measures what is queued, then ends
            self._halt.set()  # out of time: it ends after the frame in hand (the rest becomes a gap)
            reader.join(max(timeout, 0.1))
            self._reader = None
        return self._stop_reader(timeout)

    # --- the worker thread -------------------------------------------------------------------------------

    def _detect_loop(self, queue: FrameQueue) -> None:
        state = _Sequence()
        try:
            while not self._halt.is_set():
                frame = queue.get(WAIT)
                if frame is None:
                    if queue.finished:
                        break
                    continue
                self._measure_frame(frame, state)
        except Exception as exc:  # a bug, not a frame's fault: read_stream raises it
            with self._stream_lock:
                self._failure = ConnectionFailed(f"the detection of {self.source.description}'s frames stopped: "
                                                 f"{type(exc).__name__}: {exc}")
        for frame in queue.drain():  # out of time (or failed): queued frames were never measured
            self.stream_counts["unmeasured"] += 1
            state.bad(frame.stamp)
        if state.first_bad is not None:
            self._add_gap(state.last_good if state.last_good is not None else state.first_bad, state.last_bad)

    def _measure_frame(self, frame: Frame, state: _Sequence) -> None:
        self.stream_counts["frames"] += 1
        if state.last_seq is not None:
            skipped = frame.seq - state.last_seq - 1
            late = frame.stamp - state.last_stamp > GAP_FACTOR * self._period
            if skipped != 0 or late or frame.stamp <= state.last_stamp:
                self.stream_counts["missing"] += max(skipped, 0) or max(round((frame.stamp - state.last_stamp)
                                                                              / self._period) - 1, 0)
                state.bad(state.last_stamp)  # the stretch from the frame before belongs to a gap
        state.last_seq, state.last_stamp = frame.seq, frame.stamp
        started = time.perf_counter()
        try:
            pose = self._pose(frame.image)
        except MeasurementError as exc:
            self.stream_counts["not_seen" if isinstance(exc, TargetLost) else "rejected"] += 1
            state.bad(frame.stamp)
            return
        finally:
            self.detect_seconds += time.perf_counter() - started
        tp = self.settings.tp
        self._noise.add(pose)
        sigma = math.sqrt(max(float(np.trace(self._noise.covariance(pose, tp))), 0.0) / 3)
        if VIEW_BIAS_PX > 0:  # the view's own error, as a polled reading states it
            sigma = math.hypot(sigma, pose.view_bias(tp, VIEW_BIAS_PX)[0])
        # the board's orientation (camera frame <- board frame) and its per-axis sigma (rad), as a polled reading's
        rotvec = cv2.Rodrigues(pose.rotation)[0].ravel()
        sigma_r = math.sqrt(max(float(np.trace(self._noise.orientation_covariance(pose))), 0.0) / 3)
        if VIEW_TURN_BIAS_PX > 0:
            sigma_r = math.hypot(sigma_r, pose.view_bias(tp, VIEW_BIAS_PX, VIEW_TURN_BIAS_PX)[1])
        if state.first_bad is not None:
            self._add_gap(state.last_good if state.last_good is not None else state.first_bad, frame.stamp)
        state.good(frame.stamp)
        with self._stream_lock:
            self._rows.append((frame.stamp, *map(float, pose.point(tp)), sigma, *map(float, rotvec), sigma_r))
            self.stream_counts["rows"] += 1

    def _add_gap(self, start: float, end: float) -> None:
        with self._stream_lock:
            self._gaps.append((float(start), float(end)))
            self.stream_counts["gaps"] += 1


class _Sequence:
    """Where the worker is in the frame sequence: the last frame's number and stamp, the last good frame's stamp,
    and the first and last stamp of the bad stretch since it (None when there is none)."""

    def __init__(self) -> None:
        self.last_seq: int | None = None
        self.last_stamp = math.nan
        self.last_good: float | None = None
        self.first_bad: float | None = None
        self.last_bad = math.nan

    def bad(self, stamp: float) -> None:
        if self.first_bad is None:
            self.first_bad = stamp
        self.last_bad = stamp

    def good(self, stamp: float) -> None:
        self.last_good, self.first_bad = stamp, None


def _empty() -> TrackerStreamBatch:
    return TrackerStreamBatch(np.zeros(0), np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros(0))
