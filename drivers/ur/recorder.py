"""The joint-stream recorder that runs inside the ur_rtde worker process (drivers/ur/worker.py).

``RTDEReceiveInterface`` keeps only the latest RTDE package, so a thread of the worker polls it
``POLLS_PER_PERIOD`` times per package interval and keeps each package whose controller timestamp
(``getTimestamp()``, s on the controller's clock) advanced. Nothing is dropped silently: when the timestamp
steps by more than ``GAP_FACTOR`` × the nominal period (a dropped or late package, a package overwritten before
it was polled, a stream that stood still and resumed) the step is recorded as a gap ``(t_before, t_after)``
in controller seconds. A package whose timestamp changed while its joints were read (``getTimestamp`` before and
after ``getActualQ`` differ) is read again at the next poll; if that loses it, the step is a gap too.

The buffer holds at most ``max_samples`` samples; beyond that the oldest unread ones are dropped and the drop is a
gap as well. :meth:`Recorder.take` hands out at most ``limit`` samples per call (so no reply to the driver
grows without bound) together with the gaps that end at or before the last sample handed out.

The package interval polled for is the nominal period (1 / frequency), or the interval at which packages
actually arrive on the host clock when that is shorter (an emulated controller whose clock runs faster than
the wall clock: the nominal period is in controller seconds).

Standard library only (the worker imports nothing else).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from typing import Any

GAP_FACTOR = 1.5  # a timestamp step above this many nominal periods is a gap
POLLS_PER_PERIOD = 4  # polls of the receive interface per nominal period
MAX_SECONDS = 900.0  # s of samples the buffer holds before the oldest unread ones are dropped (as a gap)

#: What :meth:`Recorder.take` returns: (t list s, q list of 6-lists rad, gaps [(start, end) s], samples left).
Batch = tuple[list[float], list[list[float]], list[tuple[float, float]], int]


class Recorder:
    """Records ``receive`` (an ``RTDEReceiveInterface``) at ``frequency`` Hz in a daemon thread until :meth:`stop`.

    ``stats()`` gives counters for tests and benchmarks: samples kept, gaps, torn reads retried, polls, the
    longest time (host s) the timestamp stood still.
    """

    def __init__(self, receive: Any, frequency: float, max_samples: int | None = None) -> None:
        if not frequency > 0:
            raise ValueError(f"stream frequency must be > 0 Hz, got {frequency!r}")
        self.receive, self.period = receive, 1.0 / float(frequency)
        self.max_samples = int(max_samples or MAX_SECONDS * frequency)
        self._t: deque[float] = deque()
        self._q: deque[list[float]] = deque()
        self._gaps: list[tuple[float, float]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._last: float | None = None  # controller time of the last sample kept
        self._handed: float | None = None  # controller time of the last sample handed out
        self.kept = self.torn = self.polls = self.gap_count = 0
        self.longest_still = 0.0
        self._thread = threading.Thread(target=self._run, daemon=True, name="ur-joint-recorder")
        self._thread.start()

    def _run(self) -> None:
        receive, interval = self.receive, self.period  # host s between packages (nominal, or as they arrive)
        seen_at = time.monotonic()
        while not self._stop.is_set():
            self.polls += 1
            try:
                stamp = float(receive.getTimestamp())
                if stamp != self._last:
                    q = list(receive.getActualQ())
                    if float(receive.getTimestamp()) != stamp:
                        self.torn += 1  # a new package came in while q was read: read it at the next poll
                    else:
                        now = time.monotonic()
                        if self._last is not None and stamp > self._last:
                            packages = max(1, round((stamp - self._last) / self.period))
                            interval = min(self.period, 0.9 * interval + 0.1 * (now - seen_at) / packages)
                        self._keep(stamp, q)
                        seen_at = now
                else:
                    self.longest_still = max(self.longest_still, time.monotonic() - seen_at)
            except Exception:  # ur_rtde raises RuntimeError on a lost link; the driver sees that
                pass
            time.sleep(interval / POLLS_PER_PERIOD)

    def _keep(self, stamp: float, q: list[float]) -> None:
        with self._lock:
            last = self._last
            # a step over GAP_FACTOR periods, or backwards (the controller restarted its clock), is a gap
            if last is not None and (stamp < last or stamp - last > GAP_FACTOR * self.period):
                self._gaps.append((last, stamp))
                self.gap_count += 1
            self._last = stamp
            self._t.append(stamp)
            self._q.append(q)
            self.kept += 1
            if len(self._t) > self.max_samples:
                drop = len(self._t) - self.max_samples
                first = self._handed if self._handed is not None else self._t[0]
                for _ in range(drop):
                    self._t.popleft()
                    self._q.popleft()
                self._gaps.append((first, self._t[0]))
                self.gap_count += 1

    def take(self, limit: int) -> Batch:
        """At most ``limit`` samples in time order, the gaps ending at or before the last of them, and how many
        samples are left to take."""
        with self._lock:
            n = min(max(int(limit), 0), len(self._t))
            t = [self._t.popleft() for _ in range(n)]
            q = [self._q.popleft() for _ in range(n)]
            if t:
                self._handed = t[-1]
            edge = self._handed
            gaps = [g for g in self._gaps if edge is not None and g[1] <= edge]
            self._gaps = [g for g in self._gaps if not (edge is not None and g[1] <= edge)]
            return t, q, gaps, len(self._t)

    def stats(self) -> dict[str, float]:
        return {"kept": self.kept, "gaps": self.gap_count, "torn": self.torn, "polls": self.polls,
                "longest_still": self.longest_still, "period": self.period}

    def stop(self, timeout: float = 1.0) -> None:
        self._stop.set()
        self._thread.join(timeout)
