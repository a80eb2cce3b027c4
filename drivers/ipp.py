"""I++ DME client (the open CMM interface, VDMA 8722) over TCP: reads the current point of a CMM or tracker.

URL form (``--tracker``)::

    ipp://HOST[:PORT][?timeout=S&retries=N&trace=FILE]

``PORT`` defaults to 1294. ``timeout``: s to wait for one command's completion (default 2); ``retries``: extra
attempts per reading after an error reply, a timeout or a dropped connection (default 2); ``trace``: a file
logging every byte both ways. Other options are rejected with one line.

Protocol: the client sends ``TAG Command(args)\\r\\n`` with a five-digit tag (00001..99999, wrapping); the
server answers lines ``TAG &`` (acknowledged), ``TAG # data`` (zero or more), then ``TAG %`` (complete), or
``TAG ! Error(severity, code, "method", "text")``. Lines with an ``E`` tag are events and are only logged;
lines of another tag (late replies of an abandoned command) are skipped. After an error the client sends
``ClearAllErrors()``. The session: ``StartSession()`` at connect, ``GetDMEVersion()`` for the identity,
``Get(X(), Y(), Z())`` per reading (millimetres, the server's current coordinate system), ``EndSession()`` at
close.
"""

from __future__ import annotations

import contextlib
import re
import socket
import time
from pathlib import Path
from typing import IO, Any

import numpy as np

from drivers.base import DeviceIdentity, TrackerReading
from drivers.errors import BadReading, ConnectionFailed, DeviceTimeout, MeasurementError, SpecError
from drivers.spec import TrackerSpec
from drivers.trace import ByteTrace, one_line

DEFAULT_PORT = 1294
OPTIONS = ("timeout", "retries", "trace")
FORM = "ipp://HOST[:PORT][?timeout=S&retries=N&trace=FILE]"
_REPLY = re.compile(r"^(?P<tag>E?\d{4,5})\s+(?P<kind>[&#%!])\s*(?P<body>.*)$")
_ERROR = re.compile(r'^Error\(\s*(?P<severity>\d+)\s*,\s*(?P<code>\d+)\s*,\s*"(?P<method>[^"]*)"\s*,\s*'
                    r'"(?P<text>[^"]*)"\s*\)')
_AXIS = re.compile(r"\b(?P<axis>[XYZ])\(\s*(?P<value>[-+0-9.eE]+)\s*\)")
MAX_LINE = 4096


class IppError(BadReading):
    """The server answered ``!`` Error(...): ``severity``, ``code``, ``method`` and ``text`` as sent."""

    def __init__(self, message: str, severity: int = 0, code: str = "", text: str = "") -> None:
        super().__init__(message)
        self.severity, self.code, self.text = severity, code, text


class IppTracker:
    """An I++ DME server as a tracker (implements :class:`drivers.base.Tracker`)."""

    def __init__(self, host: str, port: int = DEFAULT_PORT, *, timeout: float = 2.0, retries: int = 2,
                 trace_io: str | Path | IO[str] | None = None) -> None:
        self.host, self.port = host, port
        self.reply_timeout, self.retries = float(timeout), int(retries)
        self._trace = ByteTrace(trace_io)
        self._sock: socket.socket | None = None
        self._buffer = b""
        self._tag = 0
        self.version = ""
        self.events: list[str] = []
        self.reconnects = 0

    @property
    def where(self) -> str:
        return f"ipp://{self.host}:{self.port}"

    def connect(self, timeout: float) -> None:
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout!r}")
        self._drop()
        self._trace.open()
        self._trace.event(f"connect {self.where}")
        try:
            self._sock = socket.create_connection((self.host, self.port), timeout=timeout)
            self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError as exc:
            raise ConnectionFailed(f"cannot connect to the I++ server {self.where}: {one_line(exc)} (is the "
                                   "server running and reachable?)") from exc
        self._buffer = b""
        deadline = time.monotonic() + timeout
        try:
            self.command("StartSession()", deadline)
            data = self.command("GetDMEVersion()", deadline)
        except IppError as exc:
            raise ConnectionFailed(f"the I++ server {self.where} refused the session: {exc}") from exc
        match = re.search(r'DMEVersion\(\s*"?([^")]*)"?\s*\)', " ".join(data))
        self.version = match.group(1) if match else ""

    def close(self) -> None:
        if self._sock is not None:
            with contextlib.suppress(Exception):  # closing a dead link must not raise
                self.command("EndSession()", time.monotonic() + min(self.reply_timeout, 1.0))
        self._drop()
        self._trace.close()

    def identity(self) -> DeviceIdentity:
        return DeviceIdentity("tracker", "I++ DME server", firmware=self.version,
                              details={"address": self.where, "protocol": "I++ DME"})

    def measure(self, count: int, timeout: float) -> list[TrackerReading]:
        """``count`` readings of the current point (m) with ``Get(X(), Y(), Z())``; errors are cleared and
        retried ``retries`` times, a dropped connection re-opened once per reading; ``timeout`` bounds the call."""
        if int(count) != count or count < 1 or not timeout > 0:
            raise ValueError(f"count must be an integer >= 1 and timeout > 0 s, got {count!r} and {timeout!r}")
        if self._sock is None:
            raise ConnectionFailed(f"I++ tracker {self.where} is not connected (call connect())")
        deadline = time.monotonic() + timeout
        return [self._one_reading(deadline) for _ in range(int(count))]

    def _one_reading(self, deadline: float) -> TrackerReading:
        last: Exception | None = None
        reconnected = False
        attempts = 0
        for _attempt in range(self.retries + 1):
            attempts += 1
            try:
                if self._sock is None:
                    self.connect(max(deadline - time.monotonic(), 0.1))
                stop = min(deadline, time.monotonic() + self.reply_timeout)
                data = self.command("Get(X(), Y(), Z())", stop)
                stamp = time.time()
                return TrackerReading(self._point(data), stamp)
            except ConnectionFailed as exc:
                if reconnected:
                    raise
                last, reconnected = exc, True
                self.reconnects += 1
                self._drop()
            except (MeasurementError, DeviceTimeout) as exc:
                last = exc
            self._trace.event(f"retry after: {last}")
            if time.monotonic() >= deadline:
                break
        assert last is not None
        if isinstance(last, ConnectionFailed):
            raise last
        raise type(last)(f"{last} (after {attempts} attempt{'s' if attempts > 1 else ''})") from last

    def _point(self, data: list[str]) -> np.ndarray:
        values: dict[str, float] = {}
        for line in data:
            for m in _AXIS.finditer(line):
                with contextlib.suppress(ValueError):
                    values[m.group("axis")] = float(m.group("value"))
        if set(values) != {"X", "Y", "Z"} or not all(np.isfinite(list(values.values()))):
            raise BadReading(f"{self.where}: unusable reply to Get(X(), Y(), Z()): {' | '.join(data)!r}")
        return np.array([values["X"], values["Y"], values["Z"]]) * 1e-3

    # --- protocol -----------------------------------------------------------------------------------------

    def command(self, text: str, deadline: float) -> list[str]:
        """Send ``text`` with a fresh tag and return its ``#`` data lines once ``%`` arrives. Raises IppError
        (after sending ClearAllErrors()), DeviceTimeout, ConnectionFailed."""
        tag = self._send(text)
        data: list[str] = []
        while True:
            kind, body = self._reply(tag, deadline, text)
            if kind == "#":
                data.append(body)
            elif kind == "%":
                return data
            elif kind == "!":
                match = _ERROR.match(body)
                severity = int(match.group("severity")) if match else 9
                code, message = (match.group("code"), match.group("text")) if match else ("?", body)
                if text != "ClearAllErrors()":
                    with contextlib.suppress(IppError, DeviceTimeout):
                        self.command("ClearAllErrors()", deadline)
                raise IppError(f"{self.where}: {text} failed: error {code} (severity {severity}): {message}",
                               severity, code, message)

    def _send(self, text: str) -> str:
        if self._sock is None:
            raise ConnectionFailed(f"I++ tracker {self.where} is not connected")
        self._tag = self._tag % 99999 + 1
        tag = f"{self._tag:05d}"
        data = f"{tag} {text}\r\n".encode("ascii")
        self._trace.data(">", data)
        try:
            self._sock.sendall(data)
        except OSError as exc:
            self._drop()
            raise ConnectionFailed(f"lost the connection to {self.where}: {one_line(exc)}") from exc
        return tag

    def _reply(self, tag: str, deadline: float, what: str) -> tuple[str, str]:
        """The next (kind, body) of ``tag``; events and other tags are skipped."""
        while True:
            line = self._line(deadline, what)
            match = _REPLY.match(line)
            if match is None:
                self._trace.event(f"skipped malformed line {line!r}")
                continue
            if match.group("tag").startswith("E"):
                self.events.append(line)
                continue
            if match.group("tag") != tag:
                self._trace.event(f"skipped reply of another tag: {line!r}")
                continue
            return match.group("kind"), match.group("body").strip()

    def _line(self, deadline: float, what: str) -> str:
        sock = self._sock
        while True:
            if sock is None:
                raise ConnectionFailed(f"I++ tracker {self.where} is not connected")
            head, sep, rest = self._buffer.partition(b"\n")
            if sep:
                self._buffer = rest
                text = head.decode("ascii", "replace").strip()
                if text:
                    return text
                continue
            if len(self._buffer) > MAX_LINE:
                self._buffer = b""
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeout(f"{self.where}: no complete answer to {what} within the timeout")
            try:
                sock.settimeout(remaining)
                chunk = sock.recv(65536)
            except TimeoutError:
                continue
            except OSError as exc:
                self._drop()
                raise ConnectionFailed(f"lost the connection to {self.where}: {one_line(exc)}") from exc
            if not chunk:
                self._drop()
                raise ConnectionFailed(f"the I++ server {self.where} closed the connection")
            self._trace.data("<", chunk)
            self._buffer += chunk

    def _drop(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()
            self._trace.event("disconnected")



def open_tracker(spec: TrackerSpec | str, rig: Any = None, site: Any = None, *,
                 trace_io: str | Path | IO[str] | None = None) -> IppTracker:
    """An unconnected :class:`IppTracker` for ``ipp://HOST[:PORT]?...``; ``rig`` is not used (a real device),
    ``site.tracker_settings`` gives option defaults, ``trace_io`` overrides the ``trace`` option."""
    spec = spec if isinstance(spec, TrackerSpec) else TrackerSpec.parse(spec)
    if spec.backend != "ipp":
        raise SpecError(f"drivers.ipp opens ipp://HOST[:PORT] trackers, got {str(spec)!r}; expected {FORM}")
    raw: dict[str, Any] = {k: v for k, v in dict(getattr(site, "tracker_settings", None) or {}).items()
                           if v is not None}
    raw.update(spec.options)
    for key in raw:
        if key not in OPTIONS:
            raise SpecError(f"tracker spec {str(spec)!r}: unknown option {key!r} (known: {', '.join(OPTIONS)}); "
                            f"expected {FORM}")
    values: dict[str, Any] = {"timeout": 2.0, "retries": 2}
    for key, kind in (("timeout", float), ("retries", int)):
        if key in raw:
            try:
                values[key] = kind(raw[key])
            except (TypeError, ValueError):
                values[key] = -1
            if values[key] < 0 or (key == "timeout" and values[key] == 0):
                raise SpecError(f"tracker spec {str(spec)!r}: option {key}={raw[key]} must be a number "
                                f"{'> 0' if key == 'timeout' else '>= 0'}; expected {FORM}")
    host, port = spec.address
    return IppTracker(host, port or DEFAULT_PORT, timeout=values["timeout"], retries=values["retries"],
                      trace_io=trace_io if trace_io is not None else raw.get("trace"))
