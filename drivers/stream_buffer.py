"""The buffer a tracker's stream reader thread fills, shared by the streaming trackers (serial, I++).

The reader thread appends rows ``(t, x, y, z, sigma)`` (device time s, metres in the tracker frame, sigma m or NaN), or
from a full-pose device ``(t, x, y, z, sigma, rx, ry, rz, sigma_r)`` (the target frame's rotation vector in the tracker
frame, rad, and its per-axis sigma, rad), and gaps ``(start, end)`` under ``_stream_lock``, or stores the exception that
ended it in ``_failure``; ``read_stream`` hands them over as a :class:`TrackerStreamBatch`.
"""

from __future__ import annotations

import math
import threading

import numpy as np

from drivers.base import TrackerStreamBatch

Row = tuple[float, ...]  # (t, x, y, z, sigma) or (t, x, y, z, sigma, rx, ry, rz, sigma_r)
POSE_ROW = 9  # the length of a full-pose row


class BufferedStreaming:
    """Reader-thread state and the reads of a streaming tracker (mixed into the device's streaming half)."""

    def _init_buffer(self) -> None:
        self._reader: threading.Thread | None = None
        self._halt = threading.Event()
        self._stream_lock = threading.Lock()
        self._rows: list[Row] = []
        self._gaps: list[tuple[float, float]] = []
        self._failure: Exception | None = None

    @property
    def streaming(self) -> bool:
        return self._reader is not None

    def _refuse_while_streaming(self, device: str) -> None:
        """RuntimeError when the stream runs: a polled measurement would compete with the reader thread."""
        if self.streaming:
            raise RuntimeError(f"{device} is streaming: call stop_stream() before measure()")

    def read_stream(self) -> TrackerStreamBatch:
        """Every sample since the last read; the reader's failure (ConnectionFailed...) if it stopped on one,
        keeping what it had read for the next call."""
        with self._stream_lock:
            rows, gaps, failure = self._rows, self._gaps, self._failure
            self._rows, self._gaps, self._failure = [], [], None
        if failure is not None:
            self._rows, self._gaps = rows, gaps
            raise failure
        return batch(rows, gaps)

    def _stop_reader(self, timeout: float) -> TrackerStreamBatch:
        """Stop the reader thread (waiting at most ``timeout`` s) and return the samples it left unread."""
        reader, self._reader = getattr(self, "_reader", None), None
        if reader is not None:
            self._halt.set()
            reader.join(max(timeout, 0.1))
        with self._stream_lock:
            rows, gaps = self._rows, self._gaps
            self._rows, self._gaps = [], []
        return batch(rows, gaps)


def batch(rows: list[Row], gaps: list[tuple[float, float]]) -> TrackerStreamBatch:
    """The stream batch of ``rows`` (module doc: with an orientation when any row has one, NaN for those without)
    and ``gaps`` (one tracked point, id 1)."""
    posed = any(len(r) == POSE_ROW for r in rows)
    width = POSE_ROW if posed else 5
    data = np.array([tuple(r) + (math.nan,) * (width - len(r)) for r in rows], dtype=float).reshape(len(rows), width)
    return TrackerStreamBatch(data[:, 0].copy(), data[:, 1:4].copy(), np.ones(len(rows), dtype=np.int64),
                              data[:, 4].copy(), tuple(gaps), data[:, 5:8].copy() if posed else None,
                              data[:, 8].copy() if posed else None)
