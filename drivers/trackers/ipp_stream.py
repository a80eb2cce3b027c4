"""Streaming for the I++ DME client: ``OnMoveReportE`` event reports of the current position (implements
:class:`drivers.base.StreamingTracker` for :class:`drivers.trackers.ipp.IppTracker`, which inherits this mixin).

The exchange: ``E0001 OnMoveReportE(Time(s), X(), Y(), Z())`` (an EVENT tag, ``E`` + four digits) starts a daemon
that reports the position as ``E0001 # X(..), Y(..), Z(..)`` (mm) until ``StopDaemon(E0001)``. This client sends
only ``Time`` (the interval, s = 1 / the rate asked for), never ``Dis``.

What is confirmed, and where from. The I++ DME specification text itself (VDMA 8722 / I++ DME 1.4) was not
available; these points were checked against the NIST I++ DME test suite (its command checker, its error table
and its simulated server), and against independent client/server implementations that cite section 6.7.1:

- confirmed: ``OnMoveReportE`` takes an event tag; the checker refuses ``Time`` below 0.1 s with "Bad property",
  error 0510 (severity 3), so a server that keeps to the standard reports at most 10 times per second; a second
  daemon is refused (0515 "Daemon already exists", severity 2), ``StopDaemon`` of a tag that has none too (0513
  "Daemon does not exist"); an error of severity >= 2 leaves the server refusing everything (0514 "Use
  ClearAllErrors to continue") until ``ClearAllErrors()``.
- confirmed for the test suite's server only: reports come from its motion (trajectory) loop, so a machine at
  rest sends none; a report is due when ``Time`` s (or ``Dis`` mm) have passed since the last one.
- not confirmed: whether a given tracker's server refuses ``Time`` below 0.1 (several are faster, a vendor
  matter) or reports at rest; whether the refusal comes before or after the ``&``.

So the client does not rely on either: :meth:`EventStreaming.start_stream` does not wait for a report (a stream
is started with the arm still, before each sweep); it asks the rate wanted (``Time(1/rate)``) and, when the
server refuses it with error 0510, clears the error, asks the standard's ``Time(0.1)`` (10 reports/s), says so in
one line (the log and :attr:`EventStreaming.rate_note`) and keeps that interval for the connection. A refusal is
recognised whether it comes before the ``&`` or after it (the first time, the client waits up to
:data:`REFUSAL_WAIT` s after the ``&`` for one). A refused daemon never ran: no ``StopDaemon`` is sent for it.

Timestamps: a report carries no device time (I++ has none in general), so each reading is stamped with the HOST's
receive time: the kernel's, where it gives one (Linux; drivers/receive_time.py), else the reader's ``time.time()``;
the same for the lines read together. The host clock is then the tracker
clock of the stream, and the latency of the server and the network is a time offset that the synchronisation
fit absorbs (its jitter is noise in time). Gaps (host seconds): a report whose step from the previous one exceeds
1.5 × the interval plus :data:`JITTER`, and any error line of the daemon's tag or an unsolicited one (``E0000 !``,
e.g. target not visible) between two reports. The time before the first report and after the last one (the arm
at rest) is no gap.

While a stream runs a reader thread owns the socket and ``measure`` is refused; ``stop_stream`` stops the reader,
then sends ``StopDaemon``.
"""

from __future__ import annotations

import contextlib
import logging
import math
import re
import threading
import time
from typing import Any

from drivers.base import TrackerStreamBatch
from drivers.errors import ConnectionFailed
from drivers.receive_time import enable_receive_times, receive
from drivers.stream_buffer import BufferedStreaming
from drivers.trace import one_line
from drivers.trackers.ipp_protocol import IppError, error_fields

GAP_FACTOR = 1.5  # a step above this many intervals (plus JITTER) between reports is a gap
JITTER = 0.02  # s: host receive times of reports jitter by the network and the scheduler
STANDARD_INTERVAL = 0.1  # s: the least OnMoveReportE Time the standard allows (at most 10 reports/s)
RATE_REFUSED = "0510"  # the error ("Bad property") of a Time below what the server allows
REFUSAL_WAIT = 0.25  # s: how long a first start waits after the & for a refusal (none comes at a good rate)
_AXIS = re.compile(r"\b(?P<axis>[XYZ])\(\s*(?P<value>[-+0-9.eE]+)\s*\)")

log = logging.getLogger("drivers.trackers.ipp")


class EventStreaming(BufferedStreaming):
    """The streaming half of IppTracker (see the module docstring). ``rate_note``: one line saying why the
    stream runs slower than asked ("" when it does not)."""

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
        self._event_tag = getattr(self, "_event_tag", 0)
        self._interval = 0.0
        self._least_interval = getattr(self, "_least_interval", 0.0)  # s: raised to the standard's after a 0510
        self._accepted = getattr(self, "_accepted", set())  # intervals the server took on this connection
        self.rate_note = getattr(self, "rate_note", "")
        self.stream_counts = {"reports": 0, "errors": 0, "gaps": 0}

    def start_stream(self, rate: float, timeout: float) -> float:
        """Start the OnMoveReportE daemon at ``rate`` Hz (interval 1 / rate s), or at the standard's 10 Hz when the
        server refuses the rate with error 0510; returns the rate asked of the server (Hz) without waiting for a
        report. IppError (one line, with what to change) when the server refuses the daemon."""
        if not (rate > 0 and timeout > 0):
            raise ValueError(f"rate and timeout must be > 0, got {rate!r} Hz and {timeout!r} s")
        if self._sock is None:
            raise ConnectionFailed(f"I++ tracker {self.where} is not connected (call connect())")
        self.stop_stream(timeout)
        interval = max(1.0 / rate, self._least_interval)
        try:
            self._start_daemon(interval, timeout)
        except IppError as exc:
            if exc.code != RATE_REFUSED:
                raise IppError(f"{exc} (the server cannot stream OnMoveReportE: use --mode step)", exc.severity,
                               exc.code, exc.text) from None
            if interval >= STANDARD_INTERVAL:
                raise IppError(f"{exc} (the server refuses {1 / interval:g} reports/s: set a lower rate in the site "
                               "file, plan: {stream_rate: N})", exc.severity, exc.code, exc.text) from None
            self._least_interval = STANDARD_INTERVAL
            self.rate_note = (f"{self.where} refused OnMoveReportE Time({interval:.6g}) (error {exc.code}: "
                              f"{exc.text}); streaming at the I++ standard's {1 / STANDARD_INTERVAL:g} reports/s "
                              f"instead of {rate:g} (set plan: {{stream_rate: {1 / STANDARD_INTERVAL:g}}})")
            log.warning("%s", self.rate_note)
            self._trace.event(self.rate_note)
            return self.start_stream(rate, timeout)
        return 1.0 / interval

    def _start_daemon(self, interval: float, timeout: float) -> None:
        """Send OnMoveReportE at ``interval`` s and start the reader; IppError when the server refuses it (before the
        ``&``, or after it within :data:`REFUSAL_WAIT` s the first time an interval is asked): the error is
        cleared and no StopDaemon is sent."""
        self._init_stream()
        self._event_tag = self._event_tag % 9999 + 1
        tag = f"E{self._event_tag:04d}"
        self._interval = interval
        deadline = time.monotonic() + timeout
        try:
            self.command(f"OnMoveReportE(Time({interval:.6g}), X(), Y(), Z())", deadline, tag=tag, until="&")
        except IppError:
            self._stopped_tags.add(tag)  # its "%" may still come
            raise
        self._reader = threading.Thread(target=self._read_loop, args=(tag,), daemon=True, name="ipp-stream")
        self._reader.start()
        if interval not in self._accepted:
            wait_until = time.monotonic() + min(REFUSAL_WAIT, timeout)
            while time.monotonic() < wait_until:
                with self._stream_lock:
                    got, failure = len(self._rows), self._failure
                if failure is not None:
                    self._stop_reader(timeout)
                    self._stopped_tags.add(tag)
                    with contextlib.suppress(Exception):  # the standard wants errors of severity >= 2 cleared
                        self.command("ClearAllErrors()", time.monotonic() + max(timeout, 0.1))
                    raise failure
                if got:
                    break
                time.sleep(0.005)
            self._accepted.add(interval)
        self._daemon_tag = tag

    def stop_stream(self, timeout: float) -> TrackerStreamBatch:
        """Stop the reader, then the daemon (``StopDaemon``, only for one the server took); returns the reports since
        the last read."""
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
        stamped = enable_receive_times(sock)
        while not self._halt.is_set():
            head, sep, rest = self._buffer.partition(b"\n")
            if not sep:
                try:
                    sock.settimeout(0.05)
                    chunk, arrived = receive(sock, 65536, stamped)
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
                received = arrived
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
                    severity, code, _, text = error_fields(line.partition("!")[2].strip())
                    with self._stream_lock:
                        self._failure = IppError(f"{self.where}: OnMoveReportE failed: error {code} (severity "
                                                 f"{severity}): {text}", severity, code, text)
                    return
                self.stream_counts["errors"] += 1
                broken = True
                self._trace.event(f"stream: {line}")
            elif line:
                self._trace.event(f"stream: skipped {line!r}")

