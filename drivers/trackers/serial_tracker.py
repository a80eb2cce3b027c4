"""Line-oriented ASCII trackers over any pyserial transport, driven by a profile
(``drivers/trackers/ascii_profile.py``).

URL form (``--tracker``)::

    serial:PORT?protocol=NAME[&baud=N][&parity=N|E|O|M|S][&bytesize=5..8][&stopbits=1|1.5|2]
               [&eol=crlf|lf|cr][&timeout=S][&retries=N][&trace=FILE]

``PORT`` is anything ``serial.serial_for_url`` opens: ``/dev/ttyUSB0``, ``COM3``, ``socket://host:port``,
``rfc2217://host:port``, ``loop://``. ``protocol``: a bundled profile name (``config/trackers/``) or a YAML
path (default ``polled-xyz``); ``baud``/``parity``/``bytesize``/``stopbits`` override the profile's serial
settings; ``eol`` the line ending of commands; ``timeout`` s to wait for one reply (default 1); ``retries``
extra attempts per reading after a bad line, a timeout or a reset (default 2); ``trace`` a file that logs
every byte in both directions (``<time> > b'...'`` sent, ``<time> < b'...'`` received). Any other option is
rejected with one line. ``site.tracker_settings`` (same names) gives defaults below the spec's options.
With ``rfc2217://`` the port settings travel to the remote port over RFC 2217; the negotiation waits at most
the connect timeout (unless the URL gives pyserial's own ``?timeout=``), and writes have no timeout of their
own (pyserial's RFC 2217 client has none).

Several tracked points: a profile with ``points: N`` answers each trigger with N lines, one per point in id
order (``tp`` 1..N, checked against the reply's ``tp`` field: a line out of step, e.g. left over from an
abandoned trigger, is a bad reading and the trigger is retried); a line with the profile's target-lost reply
is a point out of sight (it has no reading); only when every point is out of sight is the reading TargetLost
(and retried).

Streaming with the device's timestamps (``start_stream``/``read_stream``/``stop_stream``, profiles with a time
field ``t`` such as ``stream-csv``): drivers/trackers/serial_stream.py.

Faults: a missing or busy port raises ConnectionFailed; a lost link ConnectionFailed; no reply within the
reply timeout (after ``retries`` re-sent triggers) DeviceTimeout; bad lines are retried, then BadReading;
target lost TargetLost; the device's reset banner makes the driver initialise it again and carry on.
"""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import IO, Any

import numpy as np

from common.errors import install_hint
from config.robots import ConfigError
from drivers.base import DeviceIdentity, TrackerReading, check_measure_request
from drivers.errors import (
    BackendUnavailable,
    BadReading,
    ConnectionFailed,
    DeviceTimeout,
    MeasurementError,
    SpecError,
    TargetLost,
)
from drivers.spec import TrackerSpec
from drivers.trace import ByteTrace, one_line
from drivers.trackers.ascii_profile import DeviceReset, LineSplitter, ParsedLine, Profile, load_profile, parse_line
from drivers.trackers.serial_stream import LineStreaming

OPTIONS = ("protocol", "baud", "parity", "bytesize", "stopbits", "eol", "timeout", "retries", "trace")
EOLS = {"crlf": "\r\n", "lf": "\n", "cr": "\r"}
FORM = "serial:PORT?protocol=NAME&baud=N&parity=N|E|O&eol=crlf|lf|cr&timeout=S&retries=N&trace=FILE"
READ_CHUNK = 4096


def _settings(spec: TrackerSpec, site: Any) -> dict[str, Any]:
    """Typed options (site defaults, then the spec's); SpecError with one line."""
    raw: dict[str, Any] = {}
    site_settings = getattr(site, "tracker_settings", None) or {}
    raw.update({k: v for k, v in dict(site_settings).items() if v is not None})
    raw.update(spec.options)

    def fail(why: str) -> SpecError:
        return SpecError(f"tracker spec {str(spec)!r}: {why}; expected {FORM}")

    for key in raw:
        if key not in OPTIONS:
            raise fail(f"unknown option {key!r} (known: {', '.join(OPTIONS)})")
    out: dict[str, Any] = {"protocol": str(raw.get("protocol", "polled-xyz")), "timeout": 1.0, "retries": 2,
                           "trace": raw.get("trace")}
    for key, kind in (("baud", int), ("bytesize", int), ("stopbits", float), ("timeout", float),
                      ("retries", int)):
        if key in raw:
            try:
                value = kind(raw[key])
            except (TypeError, ValueError):
                raise fail(f"option {key}={raw[key]} must be a number") from None
            if value < 0 or (key != "retries" and value == 0):
                raise fail(f"option {key}={raw[key]} out of range")
            out[key] = value
    if "bytesize" in out and out["bytesize"] not in (5, 6, 7, 8):
        raise fail(f"option bytesize={out['bytesize']} must be 5, 6, 7 or 8")
    if "stopbits" in out and out["stopbits"] not in (1, 1.5, 2):
        raise fail(f"option stopbits={raw['stopbits']} must be 1, 1.5 or 2")
    if "parity" in raw:
        if str(raw["parity"]).upper() not in ("N", "E", "O", "M", "S"):
            raise fail(f"option parity={raw['parity']} must be N, E, O, M or S")
        out["parity"] = str(raw["parity"]).upper()
    if "eol" in raw:
        if raw["eol"] not in EOLS:
            raise fail(f"option eol={raw['eol']} must be crlf, lf or cr")
        out["eol"] = EOLS[raw["eol"]]
    return out


class SerialTracker(LineStreaming):
    """A profile-driven ASCII tracker (implements :class:`drivers.base.Tracker`, and
    :class:`drivers.base.StreamingTracker` with a streaming profile that has a time field)."""

    def __init__(self, url: str, profile: Profile, *, baud: int | None = None, parity: str | None = None,
                 bytesize: int | None = None, stopbits: float | None = None, eol: str | None = None,
                 timeout: float = 1.0, retries: int = 2, trace_io: str | Path | IO[str] | None = None) -> None:
        self.url, self.profile = url, profile
        ser = profile.serial
        self.baud = int(baud or ser.get("baud", 9600))
        self.parity = parity or ser.get("parity", "N")
        self.bytesize = int(bytesize or ser.get("bytesize", 8))
        self.stopbits = stopbits or ser.get("stopbits", 1)
        self.eol = (eol or profile.line_ending).encode("ascii")
        self.reply_timeout, self.retries = float(timeout), int(retries)
        self._trace = ByteTrace(trace_io)
        self._port: Any = None
        self._splitter = LineSplitter()
        self._lines: list[str] = []
        self._identity: dict[str, str] = {}
        self._last_sent = ""
        self._discard_first = False
        self.resets = 0  # device resets seen (and recovered from)
        self._init_stream()

    @property
    def points(self) -> int:
        """How many tracked points each trigger reports (the profile's ``points``)."""
        return self.profile.points

    # --- link -----------------------------------------------------------------------------------------

    def connect(self, timeout: float) -> None:
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout!r}")
        try:
            import serial
        except ImportError as exc:
            raise BackendUnavailable(f"the serial tracker needs pyserial: {install_hint('serial')}") from exc
        self.close()
        self._trace.open()
        self._trace.event(f"open {self.url} profile={self.profile.name} baud={self.baud} parity={self.parity}")
        url, write_timeout = self.url, timeout
        if url.startswith("rfc2217://"):
            # pyserial's RFC 2217 client has no write timeout; its network timeout (negotiation, s) is a URL
            # option, bounded here by the connect timeout unless the URL sets it
            write_timeout = None
            url += "" if "?" in url else f"?timeout={timeout:g}"
        try:
            port = serial.serial_for_url(url, do_not_open=True, baudrate=self.baud, parity=self.parity,
                                         bytesize=self.bytesize, stopbits=self.stopbits, timeout=0.05,
                                         write_timeout=write_timeout)
            if self.url.startswith("/") or self.url.upper().startswith("COM"):
                port.exclusive = True
            port.open()
        except (serial.SerialException, OSError, ValueError, NotImplementedError) as exc:
            raise ConnectionFailed(f"cannot open serial port {self.url!r}: {one_line(exc)} (check that it exists, "
                                   "that no other program uses it, and your permissions)") from exc
        self._port = port
        self._initialise(time.monotonic() + timeout, identify=True)

    def close(self) -> None:
        self.stop_stream(1.0)
        port, self._port = self._port, None
        if port is not None:
            try:
                if self.profile.stop:
                    self._write(port, self.profile.stop)
                port.close()
            except Exception:  # closing a dead link must not raise
                pass
            self._trace.event("close")
        self._trace.close()

    def identity(self) -> DeviceIdentity:
        ident = self._identity
        details = {"profile": self.profile.name, "profile_file": self.profile.path, "port": self.url,
                   "units": self.profile.units}
        return DeviceIdentity("tracker", ident.get("model", f"ASCII tracker ({self.profile.name})"),
                              serial=ident.get("serial", ""), firmware=ident.get("firmware", ""), details=details)

    # --- measurements -----------------------------------------------------------------------------------

    def measure(self, count: int, timeout: float) -> list[TrackerReading]:
        """``count`` readings (m, tracker frame) of each tracked point in sight. Bad lines, timeouts and resets are
        retried ``retries`` times per reading; then BadReading / TargetLost / DeviceTimeout. ``timeout`` bounds
        the whole call."""
        check_measure_request(count, timeout)
        if self._port is None:
            raise ConnectionFailed(f"serial tracker {self.url} is not connected (call connect())")
        self._refuse_while_streaming(f"serial tracker {self.url}")
        deadline = time.monotonic() + timeout
        self._flush()
        return [reading for _ in range(int(count)) for reading in self._one_reading(deadline)]

    def _read_frame(self, deadline: float) -> list[TrackerReading]:
        """The lines answering one trigger: one reading, or with ``points`` > 1 one line per point in id order
        (those out of sight left out; TargetLost if all are)."""
        points, frame, lost = self.profile.points, [], None
        for k in range(1, points + 1):
            what = "a measurement" if points == 1 else f"point {k} of a measurement"
            line = self._read_reply(min(deadline, time.monotonic() + self.reply_timeout), what)
            stamp = time.time()
            try:
                parsed: ParsedLine = parse_line(self.profile, line)
            except TargetLost as exc:
                if points == 1:
                    raise
                if getattr(exc, "tp", k) != k:
                    raise BadReading(f"{self.url}: reply {line!r} is about point {getattr(exc, 'tp', k)} where point "
                                     f"{k} was due (one line per point, in id order)") from exc
                lost = exc
                continue
            if points > 1 and parsed.tp is not None and parsed.tp != k:
                raise BadReading(f"{self.url}: reply {line!r} is point {parsed.tp} where point {k} was due (one line "
                                 "per point, in id order)")
            frame.append(TrackerReading(np.array(parsed.position), stamp, sigma=parsed.sigma, status=parsed.status,
                                        tp=k))
        if not frame:
            raise TargetLost(f"{self.url}: every one of the {points} tracked points is out of sight ({lost})")
        return frame

    def _one_reading(self, deadline: float) -> list[TrackerReading]:
        last: Exception | None = None
        attempts = 0
        for attempt in range(self.retries + 1):
            attempts += 1
            if attempt:
                self._flush()  # a late reply to the previous trigger is not this reading
            if self.profile.trigger is not None:
                self._send(self.profile.trigger)
            try:
                return self._read_frame(deadline)
            except DeviceReset as exc:
                last = exc
                self._recover("device reset")
            except (MeasurementError, DeviceTimeout) as exc:
                last = exc
                self._trace.event(f"retry after: {exc}")
                if isinstance(exc, DeviceTimeout) and self.profile.mode == "streaming":
                    self._initialise(deadline)  # a silent reboot stops the stream: start it again
            if time.monotonic() >= deadline:
                break
        if isinstance(last, DeviceReset):
            raise BadReading(f"{self.url}: the device kept resetting ({last})")
        assert last is not None
        raise type(last)(f"{last} (after {attempts} attempt{'s' if attempts > 1 else ''})") from last

    # --- helpers ----------------------------------------------------------------------------------------

    def _initialise(self, deadline: float, identify: bool = False) -> None:
        """Send the profile's init commands (waiting for expected replies), identify the device (``identify``),
        then send ``start`` if streaming."""
        self._flush(recover=False)
        for command in self.profile.init:
            self._send(command.send)
            if command.expect is not None:
                self._await(command.expect, deadline, command.send)
        if identify and self.profile.identify is not None:
            text, pattern = self.profile.identify
            self._send(text)
            match = self._await(pattern, deadline, text)
            self._identity = {k: v for k, v in match.groupdict().items() if v is not None}
        if self.profile.start:
            self._send(self.profile.start)
        self._flush(recover=False)

    def _await(self, pattern: re.Pattern[str], deadline: float, command: str) -> re.Match[str]:
        """The first line matching ``pattern`` (others, e.g. stream data or a reset banner, are skipped); an
        error reply or no match by ``deadline`` raise ConnectionFailed (DeviceTimeout if nothing came)."""
        last = None
        while True:
            try:
                line = self._read_reply(deadline, f"the reply to {command!r}")
            except DeviceTimeout:
                if last is None:
                    raise
                raise ConnectionFailed(f"{self.url}: no reply to {command!r} matches profile {self.profile.name!r} "
                                       f"({pattern.pattern!r}; last line {last!r}): wrong protocol or device?") \
                    from None
            match = pattern.search(line)
            if match is not None:
                return match
            last = line
            if any(p.search(line) for p, _ in self.profile.errors):
                raise ConnectionFailed(f"{self.url}: the device answered {command!r} with the error {line!r}")

    def _recover(self, why: str) -> None:
        self.resets += 1
        self._trace.event(f"{why}: initialising again")
        self._initialise(time.monotonic() + max(self.reply_timeout, 1.0))

    def _flush(self, recover: bool = True) -> None:
        """Forget stale input; a stream's next fragment is the tail of a line and is dropped."""
        try:
            waiting = self._port.in_waiting
            stale = self._port.read(waiting) if waiting else b""
            # over RFC 2217 a purge is a round trip of >= 50 ms (pyserial polls for its acknowledgement every
            # 50 ms): the drain above is enough there
            if not self.url.startswith("rfc2217://"):
                self._port.reset_input_buffer()
        except Exception as exc:
            raise ConnectionFailed(f"lost the link to {self.url}: {one_line(exc)}") from exc
        self._trace.data("<", stale)
        lines = self._lines + (self._splitter.feed(stale) if stale else [])
        self._lines = []
        reset = self.profile.reset
        if recover and reset is not None and any(reset.search(line) for line in lines):
            return self._recover("device reset seen in stale input")
        self._splitter.clear()
        # a stream's next line may be the tail of one cut by the flush: drop it (unless it is a reset banner)
        self._discard_first = self.profile.mode == "streaming"

    def _send(self, command: str) -> None:
        try:
            self._write(self._port, command)
        except Exception as exc:
            raise ConnectionFailed(f"lost the link to {self.url} while sending {command!r}: {one_line(exc)}") \
                from exc

    def _write(self, port: Any, command: str) -> None:
        data = command.encode("ascii") + self.eol
        self._last_sent = command
        self._trace.data(">", data)
        port.write(data)
        port.flush()

    def _read_line(self, deadline: float, what: str) -> str:
        """The next complete line; DeviceTimeout at ``deadline``; ConnectionFailed if the link is lost."""
        while not self._lines:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeout(f"{self.url}: no answer ({what}) within the timeout")
            try:
                port = self._port
                data = port.read(max(1, min(port.in_waiting, READ_CHUNK)))
            except Exception as exc:
                raise ConnectionFailed(f"lost the link to {self.url}: {one_line(exc)}") from exc
            if data:
                self._trace.data("<", data)
                self._lines.extend(self._splitter.feed(data))
        line = self._lines.pop(0)
        if self._discard_first:
            self._discard_first = False
            reset = self.profile.reset
            if reset is None or not reset.search(line):
                return self._read_line(deadline, what)
        return line

    def _read_reply(self, deadline: float, what: str) -> str:
        """The next line that is not the echo of the last command sent (some devices echo)."""
        while True:
            line = self._read_line(deadline, what)
            if line != self._last_sent:
                return line



def open_tracker(spec: TrackerSpec | str, rig: Any = None, site: Any = None, *,
                 trace_io: str | Path | IO[str] | None = None) -> SerialTracker:
    """An unconnected :class:`SerialTracker` for ``serial:PORT?...``. ``rig`` is not used (a real device);
    ``site.tracker_settings`` gives option defaults; ``trace_io`` (path or text file) overrides ``trace``."""
    spec = spec if isinstance(spec, TrackerSpec) else TrackerSpec.parse(spec)
    if spec.backend != "serial":
        raise SpecError(f"drivers.trackers.serial_tracker opens serial:PORT trackers, got {str(spec)!r}; "
                        f"expected {FORM}")
    opts = _settings(spec, site)
    try:
        profile = load_profile(opts["protocol"])
    except ConfigError as exc:
        raise SpecError(f"tracker spec {str(spec)!r}: protocol: {exc}") from exc
    return SerialTracker(spec.target, profile, baud=opts.get("baud"), parity=opts.get("parity"),
                         bytesize=opts.get("bytesize"), stopbits=opts.get("stopbits"), eol=opts.get("eol"),
                         timeout=opts["timeout"], retries=opts["retries"],
                         trace_io=trace_io if trace_io is not None else opts["trace"])
