"""Streaming with the device's own timestamps for ASCII trackers (implements :class:`drivers.base.StreamingTracker`
for :class:`drivers.trackers.serial_tracker.SerialTracker`, which inherits this mixin).

Needs a profile in ``mode: streaming`` whose lines carry the device's time of the reading (field ``t``, s on the
device's clock; e.g. the bundled ``stream-csv``), and optionally a sequence number (field ``seq``). While a
stream runs, a reader thread owns the port: it splits the bytes into lines, parses each
(drivers/trackers/ascii_profile.py) and appends the readings to a buffer that ``read_stream`` empties; ``measure`` is
refused until ``stop_stream``.

Gaps ``(t_before, t_after)``, device seconds between the last good reading before and the first good one after:

- the device reported the target lost (its target-lost reply or status) on one or more lines;
- lines are missing: the sequence number stepped by more than one (with ``seq``), or, without it, the device time
  stepped by more than 1.5 × the period (the profile's ``period``, else the one measured at ``start_stream``);
  an unparseable line, a checksum mismatch or a reset banner is a missing line too; the device time going
  backwards (its clock was reset) is a gap as well.

The device streams at its own rate: ``rate`` in ``start_stream`` is not sent (the profiles have no rate command)
and the rate returned is the device's (1 / ``period``, or measured from the first readings' device times).
A reset banner during a stream makes the reader initialise the device again (and start its stream).
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any

import numpy as np

from drivers.base import TrackerStreamBatch
from drivers.errors import BadReading, ConnectionFailed, DeviceTimeout, MeasurementError, TargetLost
from drivers.stream_buffer import BufferedStreaming
from drivers.trace import one_line
from drivers.trackers.ascii_profile import DeviceReset, parse_line

GAP_FACTOR = 1.5  # a device-time step above this many periods is a gap (without sequence numbers)
RATE_SAMPLES = 10  # readings whose device times give the rate when the profile states no period
MAX_BUFFER = 2_000_000  # readings held unread before the oldest are dropped (as a gap)


class LineStreaming(BufferedStreaming):
    """The streaming half of SerialTracker (see the module docstring)."""

    url: str
    profile: Any
    _port: Any
    _splitter: Any
    _last_sent: str
    _trace: Any
    _initialise: Any
    _flush: Any

    def _init_stream(self) -> None:
        self._init_buffer()
        self._period: float | None = None
        self.stream_counts = {"readings": 0, "lost_lines": 0, "bad_lines": 0, "gaps": 0, "resets": 0}

    def start_stream(self, rate: float, timeout: float) -> float:
        """Start the reader; returns the device's rate (Hz) once its first reading is in (DeviceTimeout if none
        comes within ``timeout`` s). ``rate`` is what the caller would like; the device keeps its own."""
        if not (rate > 0 and timeout > 0):
            raise ValueError(f"rate and timeout must be > 0, got {rate!r} Hz and {timeout!r} s")
        profile = self.profile
        if profile.mode != "streaming" or not profile.has_field("t"):
            raise ValueError(f"profile {profile.name!r} cannot stream with device timestamps: it needs mode "
                             "streaming and a time field t in its replies (see config/trackers/stream-csv.yaml)")
        if self._port is None:
            raise ConnectionFailed(f"serial tracker {self.url} is not connected (call connect())")
        self.stop_stream(timeout)
        self._init_stream()
        self._period = profile.period
        self._flush(recover=False)
        self._splitter.resync()  # the first bytes may be the tail of a line
        self._reader = threading.Thread(target=self._read_loop, daemon=True, name=f"serial-stream-{self.url}")
        self._reader.start()
        deadline = time.monotonic() + timeout
        need = 1 if self._period else RATE_SAMPLES
        while True:
            with self._stream_lock:
                rows, failure = list(self._rows), self._failure
            if failure is not None:
                self.stop_stream(timeout)
                raise failure
            if len(rows) >= need:
                break
            if time.monotonic() > deadline:
                self.stop_stream(timeout)
                raise DeviceTimeout(f"{self.url}: no streamed reading with a device time within {timeout:g} s")
            time.sleep(0.005)
        if self._period is None:
            steps = np.diff([r[0] for r in rows])
            self._period = float(np.median(steps)) if len(steps) and np.median(steps) > 0 else None
            if self._period is None:
                self.stop_stream(timeout)
                raise BadReading(f"{self.url}: the device times of the first readings do not advance")
        return 1.0 / self._period

    def stop_stream(self, timeout: float) -> TrackerStreamBatch:
        """Stop the reader (the device keeps streaming: ``measure`` reads its lines); returns the readings since
        the last read."""
        return self._stop_reader(timeout)

    # --- the reader thread ------------------------------------------------------------------------------

    def _read_loop(self) -> None:
        last_t: float | None = None
        last_seq: int | None = None
        broken = False  # lines lost (target lost, bad or missing) since the last good reading
        while not self._halt.is_set():
            try:
                port = self._port
                data = port.read(max(1, min(port.in_waiting, 4096)))
            except Exception as exc:
                with self._stream_lock:
                    self._failure = ConnectionFailed(f"lost the link to {self.url}: {one_line(exc)}")
                return
            if not data:
                continue
            self._trace.data("<", data)
            for line in self._splitter.feed(data):
                if line == self._last_sent:
                    continue
                try:
                    parsed = parse_line(self.profile, line)
                except DeviceReset:
                    self.stream_counts["resets"] += 1
                    broken = True
                    self._restart_device()
                    continue
                except TargetLost:
                    self.stream_counts["lost_lines"] += 1
                    broken = True
                    continue
                except MeasurementError:
                    self.stream_counts["bad_lines"] += 1
                    broken = True
                    continue
                if parsed.t is None:
                    self.stream_counts["bad_lines"] += 1
                    broken = True
                    continue
                t, seq = parsed.t, parsed.seq
                if last_t is not None:
                    if seq is not None and last_seq is not None:
                        missing = seq - last_seq != 1
                    else:
                        missing = bool(self._period) and t - last_t > GAP_FACTOR * (self._period or math.inf)
                    if broken or missing or t <= last_t:
                        self._add_gap(last_t, t)
                broken, last_t, last_seq = False, t, seq
                sigma = math.nan if parsed.sigma is None else parsed.sigma
                with self._stream_lock:
                    self._rows.append((t, *parsed.position, sigma))
                    self.stream_counts["readings"] += 1
                    if len(self._rows) > MAX_BUFFER:
                        dropped = self._rows[: len(self._rows) - MAX_BUFFER]
                        del self._rows[: len(dropped)]
                        self._gaps.append((dropped[0][0], self._rows[0][0]))

    def _add_gap(self, start: float, end: float) -> None:
        with self._stream_lock:
            self._gaps.append((start, end))
            self.stream_counts["gaps"] += 1

    def _restart_device(self) -> None:
        """After a reset banner: initialise the device again (its stream restarts); a failure ends the reader."""
        try:
            self._initialise(time.monotonic() + 2.0)
            self._splitter.resync()
        except (MeasurementError, DeviceTimeout, ConnectionFailed) as exc:
            with self._stream_lock:
                self._failure = ConnectionFailed(f"{self.url}: the device reset during a stream and did not start "
                                                 f"again: {exc}")
            self._halt.set()

