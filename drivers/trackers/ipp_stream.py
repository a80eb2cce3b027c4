"""Streaming for the I++ DME client: ``OnMoveReportE`` event reports of the current position (implements
:class:`drivers.base.StreamingTracker` for :class:`drivers.trackers.ipp.IppTracker`, which inherits this mixin).

What could be verified (the I++ DME 1.4 specification text itself was not available here; these points come
from independent client/server implementations and their tests, which cite VDMA 8722 section 6.7.1, table 68):
``OnMoveReportE`` is sent with an EVENT tag (``E`` + four digits; a plain tag is refused, error 0502 in one
server), e.g. ``E0001 OnMoveReportE(Time(0.004), X(), Y(), Z())``; it starts a "daemon" that reports the
position as ``E0001 # X(..), Y(..), Z(..)`` lines until ``StopDaemon(E0001)`` (or ``StopAllDaemons()``);
only one such daemon runs at a time (a second one: error 0515); its arguments also take ``Dis(d)`` (a distance
criterion). Not verified, so not relied on: how ``Time`` and ``Dis`` combine, and whether a server reports
while the machine stands still. This client sends only ``Time`` (the interval, s = 1 / the rate asked for).

Timestamps: a report carries no device time (I++ has none in general), so each reading is stamped with the HOST's
receive time (``time.time()``, the same for the lines of one TCP segment). The host clock is then the tracker
clock of the stream, and the latency of the server and the network is a time offset that the synchronisation
fit absorbs (its jitter is noise in time). Gaps (host seconds): a report whose step from the previous one exceeds
1.5 × the interval plus :data:`JITTER`, and any error line of the daemon's tag or an unsolicited one (``E0000 !``,
e.g. target not visible) between two reports.

While a stream runs a reader thread owns the socket and ``measure`` is refused; ``stop_stream`` stops the reader,
then sends ``StopDaemon``. A server without the command (error 0501 or similar) makes ``start_stream`` raise
IppError with the server's message.
"""

from __future__ import annotations

import contextlib
import math
import re
import threading
import time
from typing import Any

from drivers.base import TrackerStreamBatch
from drivers.errors import ConnectionFailed, DeviceTimeout
from drivers.stream_buffer import BufferedStreaming
from drivers.trace import one_line
from drivers.trackers.ipp_protocol import IppError, _error_fields

GAP_FACTOR = 1.5  # a step above this many intervals (plus JITTER) between reports is a gap
JITTER = 0.02  # s: host receive times of reports jitter by the network and the scheduler
_AXIS = re.compile(r"\b(?P<axis>[XYZ])\(\s*(?P<value>[-+0-9.eE]+)\s*\)")


class EventStreaming(BufferedStreaming):
    """The streaming half of IppTracker (see the module docstring)."""

    where: str
    _sock: Any
    _buffer: bytes
    _trace: Any
    command: Any
    _notice: Any
    _stopped_tags: set[str]

    def _init_stream(self) -> None:
        self._init_buffer()
        self._daemon_tag: str | None = None
        self._event_tag = 0
        self._interval = 0.0
        self.stream_counts = {"reports": 0, "errors": 0, "gaps": 0}

    def start_stream(self, rate: float, timeout: float) -> float:
        """Start the OnMoveReportE daemon at ``rate`` Hz (interval 1 / rate s); returns ``rate`` once the first
        report is in (DeviceTimeout if none comes within ``timeout`` s; IppError if the server refuses)."""
        if not (rate > 0 and timeout > 0):
            raise ValueError(f"rate and timeout must be > 0, got {rate!r} Hz and {timeout!r} s")
        if self._sock is None:
            raise ConnectionFailed(f"I++ tracker {self.where} is not connected (call connect())")
        self.stop_stream(timeout)
        self._init_stream()
        self._event_tag = self._event_tag % 9999 + 1
        tag = f"E{self._event_tag:04d}"
        self._interval = 1.0 / rate
        deadline = time.monotonic() + timeout
        self._await_ack(tag, f"OnMoveReportE(Time({self._interval:.6g}), X(), Y(), Z())", deadline)
        self._daemon_tag = tag
        self._reader = threading.Thread(target=self._read_loop, args=(tag,), daemon=True, name="ipp-stream")
        self._reader.start()
        while True:
            with self._stream_lock:
                got, failure = len(self._rows), self._failure
            if failure is not None:
                self.stop_stream(timeout)
                with contextlib.suppress(Exception):  # the standard wants errors of severity >= 2 cleared
                    self.command("ClearAllErrors()", time.monotonic() + max(timeout, 0.1))
                raise failure
            if got:
                return float(rate)
            if time.monotonic() > deadline:
                self.stop_stream(timeout)
                raise DeviceTimeout(f"{self.where}: no OnMoveReportE report within {timeout:g} s")
            time.sleep(0.005)

    def _await_ack(self, tag: str, text: str, deadline: float) -> None:
        """Send ``text`` with event tag ``tag`` and wait for its ``&`` (an error raises as in ``command``)."""
        self.command(text, deadline, tag=tag, until="&")

    def stop_stream(self, timeout: float) -> TrackerStreamBatch:
        """Stop the reader, then the daemon (``StopDaemon``); returns the reports since the last read."""
        unread = self._stop_reader(timeout)
        tag, self._daemon_tag = getattr(self, "_daemon_tag", None), None
        if tag is not None:
            self._stopped_tags.add(tag)  # its late reports are skipped, not kept as events
        if tag is not None and self._sock is not None:
            try:
                self.command(f"StopDaemon({tag})", time.monotonic() + max(timeout, 0.1))
            except Exception as exc:  # the reports are in; a failed stop is logged, the next command tells
                self._trace.event(f"StopDaemon({tag}) failed: {one_line(exc)}")
        return unread

    def _read_loop(self, tag: str) -> None:
        last: float | None = None
        broken = False
        limit = GAP_FACTOR * self._interval + JITTER
        sock, received = self._sock, time.time()
        while not self._halt.is_set():
            head, sep, rest = self._buffer.partition(b"\n")
            if not sep:
                try:
                    sock.settimeout(0.05)
                    chunk = sock.recv(65536)
                except TimeoutError:
                    continue
                except OSError as exc:
                    chunk, failure = b"", exc
                else:
                    failure = None
                if not chunk:
                    with self._stream_lock:
                        self._failure = ConnectionFailed(f"lost the connection to {self.where} during a stream"
                                                         + (f": {one_line(failure)}" if failure else ""))
                    return
                self._trace.data("<", chunk)
                self._buffer += chunk
                received = time.time()
                continue
            self._buffer = rest
            line = head.decode("ascii", "replace").strip()
            if line.startswith(f"{tag} #"):
                values = {m.group("axis"): float(m.group("value")) for m in _AXIS.finditer(line)}
                if set(values) != {"X", "Y", "Z"} or not all(map(math.isfinite, values.values())):
                    broken = True
                    continue
                if last is not None and (broken or received - last > limit):
                    with self._stream_lock:
                        self._gaps.append((last, received))
                        self.stream_counts["gaps"] += 1
                with self._stream_lock:
                    self._rows.append((received, values["X"] * 1e-3, values["Y"] * 1e-3, values["Z"] * 1e-3,
                                       math.nan))
                    self.stream_counts["reports"] += 1
                last, broken = received, False
            elif line.startswith((f"{tag} !", "E0000 !")):
                if last is None and line.startswith(tag):  # refused before any report: no such daemon here
                    severity, code, _, text = _error_fields(line.partition("!")[2].strip())
                    with self._stream_lock:
                        self._failure = IppError(f"{self.where}: OnMoveReportE failed: error {code} (severity "
                                                 f"{severity}): {text}", severity, code, text)
                    return
                self.stream_counts["errors"] += 1
                broken = True
                self._trace.event(f"stream: {line}")
            elif line:
                self._trace.event(f"stream: skipped {line!r}")

