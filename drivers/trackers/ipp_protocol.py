"""The I++ DME wire protocol (VDMA 8722, section 6) as the client speaks it: tagged commands, their replies, error
lines by severity, and the line framing of the TCP stream (the tracker itself: drivers/trackers/ipp.py).

The client sends ``TAG Command(args)\\r\\n`` with a five-digit tag (00001..99999, wrapping); the server answers
``TAG &`` (acknowledged), ``TAG # data`` (zero or more), then ``TAG %`` (complete), and ``TAG ! Error(F1, F2, F3,
Text)`` when something went wrong. Lines with an ``E`` tag are events and are only recorded; lines of another tag (late
replies of an abandoned command) are skipped. Errors of severity 0 (info) and 1 (warning) are recorded and the
command goes on; from severity 2 on the client sends ``ClearAllErrors()`` and raises :class:`IppError`.
"""

from __future__ import annotations

import contextlib
import logging
import re
import socket
import time
from dataclasses import dataclass

from drivers.errors import BadReading, ConnectionFailed, DeviceTimeout
from drivers.trace import ByteTrace, one_line
from drivers.trackers.socket_reads import receive

SEVERITY = {0: "info", 1: "warning", 2: "error", 3: "error (user action needed)", 9: "fatal server error"}
_REPLY = re.compile(r"^(?P<tag>E?\d{4,5})\s+(?P<kind>[&#%!])\s*(?P<body>.*)$")
_ERROR = re.compile(r"^Error\(\s*(?P<severity>\d+)\s*,\s*(?P<code>\d+)\s*,\s*(?P<method>\"[^\"]*\"|[^,\"]*?)\s*,"
                    r"\s*(?P<text>.*?)\s*\)\s*$")
MAX_LINE = 65536  # the standard's longest line (section 6.2)

log = logging.getLogger("drivers.trackers.ipp")  # the I++ client's log (drivers/trackers/ipp.py logs there too)


class IppError(BadReading):
    """The server answered ``!`` Error(...) of severity >= 2: ``severity``, ``code``, ``text`` as sent."""

    def __init__(self, message: str, severity: int = 0, code: str = "", text: str = "") -> None:
        super().__init__(message)
        self.severity, self.code, self.text = severity, code, text


@dataclass(frozen=True)
class IppNotice:
    """An I++ error line that did not stop anything: severity 0 (info) or 1 (warning) of a command, or any
    unsolicited one (``E`` tag). ``command`` is the command it came with ("" if unsolicited)."""

    timestamp: float
    severity: int
    code: str
    method: str
    text: str
    command: str

    def __str__(self) -> str:
        kind = SEVERITY.get(self.severity, f"severity {self.severity}")
        where = f" ({self.command})" if self.command else " (unsolicited)"
        return f"{kind} {self.code}{where}: {self.text}"


def error_fields(body: str) -> tuple[int, str, str, str]:
    """(severity, code, method, text) of an ``Error(F1, F2, F3, Text)`` body; severity 9 if it does not parse."""
    match = _ERROR.match(body)
    if match is None:
        return 9, "?", "", body
    unquote = "\"“”' "
    return (int(match.group("severity")), match.group("code"), match.group("method").strip(unquote),
            match.group("text").strip(unquote))


class IppProtocol:
    """The client side of the protocol, a base of :class:`drivers.trackers.ipp.IppTracker`, which holds the link:
    ``_sock`` (the connected socket or None), ``_buffer`` (bytes received, not yet a line), ``_tag`` (the last
    tag sent), ``_trace`` (the byte trace), ``warnings`` (every :class:`IppNotice`), ``events`` (event lines),
    ``_stopped_tags`` (event tags of ended daemons) and ``where`` (its address, for messages)."""

    _sock: socket.socket | None
    _buffer: bytes
    _tag: int
    _trace: ByteTrace
    warnings: list[IppNotice]
    events: list[str]
    _stopped_tags: set[str]
    where: str

    def command(self, text: str, deadline: float, tag: str | None = None, until: str = "%") -> list[str]:
        """Send ``text`` with a fresh tag (or the event tag ``tag``) and return its ``#`` data lines once ``%``
        (or ``until``, e.g. ``&``) arrives. Errors of severity 0/1 are recorded in ``warnings`` and the command
        goes on; from severity 2 on the client sends ClearAllErrors() and raises IppError. Also raises
        DeviceTimeout, ConnectionFailed."""
        tag = self._send(text, tag)
        data: list[str] = []
        while True:
            kind, body = self._reply(tag, deadline, text)
            if kind == until:
                return data
            if kind == "#":
                data.append(body)
            elif kind == "!":
                severity, code, method, message = error_fields(body)
                if severity < 2:
                    self._notice(IppNotice(time.time(), severity, code, method, message, text))
                    continue
                if text != "ClearAllErrors()":
                    with contextlib.suppress(IppError, DeviceTimeout):
                        self.command("ClearAllErrors()", deadline)
                raise IppError(f"{self.where}: {text} failed: error {code} (severity {severity}, "
                               f"{SEVERITY.get(severity, 'error')}): {message}", severity, code, message)

    def _notice(self, notice: IppNotice) -> None:
        self.warnings.append(notice)
        self._trace.event(f"I++ {notice}")
        log.log(logging.WARNING if notice.severity < 2 else logging.ERROR, "%s: %s",
                self.where, notice)

    def _send(self, text: str, tag: str | None = None) -> str:
        if self._sock is None:
            raise ConnectionFailed(f"I++ tracker {self.where} is not connected")
        if tag is None:
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
        """The next (kind, body) of ``tag``; events (recorded) and other tags are skipped."""
        while True:
            line = self._line(deadline, what)
            match = _REPLY.match(line)
            if match is None:
                self._trace.event(f"skipped malformed line {line!r}")
                continue
            if match.group("tag") == tag:  # an event-tagged command (OnMoveReportE): its own replies
                return match.group("kind"), match.group("body").strip()
            if match.group("tag") in self._stopped_tags:  # a late report of a stopped daemon
                continue
            if match.group("tag").startswith("E"):
                self.events.append(line)
                if match.group("kind") == "!":
                    self._notice(IppNotice(time.time(), *error_fields(match.group("body").strip()), ""))
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
            chunk = receive(sock, remaining, self.where, "the I++ server", self._drop)
            if chunk is None:
                continue
            self._trace.data("<", chunk)
            self._buffer += chunk

    def _drop(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()
            self._trace.event("disconnected")
