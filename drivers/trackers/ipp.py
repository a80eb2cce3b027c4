"""I++ DME client (the open CMM interface, VDMA 8722) over TCP: reads the current point of a CMM or tracker.

URL form (``--tracker``)::

    ipp://HOST[:PORT][?timeout=S&retries=N&average=N&averaging=auto|client|PROPERTY&tools=A,B,C&trace=FILE]

``PORT`` defaults to 1294. ``timeout``: s to wait for one command's completion (default 2); ``retries``: extra
attempts per reading after an error reply, a timeout or a dropped connection (default 2); ``average``: raw
points averaged into each reading (default 1); ``averaging``: who averages (below); ``tools``: several tracked
points (below); ``trace``: a file logging every byte both ways. Other options are rejected with one line.

Protocol (I++ DME 1.4.3, section 6): tagged commands and their ``&``, ``#``, ``%`` and ``!`` replies, events and
error lines, as drivers/trackers/ipp_protocol.py describes and speaks them. The session: ``StartSession()`` and
``GetDMEVersion()`` (the identity) at connect, ``Get(X(), Y(), Z())`` per raw point (millimetres, the server's
current coordinate system), ``EndSession()`` at close.

Errors by severity (F1, section 8.1): 0 info and 1 warning "do not interfere with pending commands": the
client records them (:attr:`IppTracker.warnings`, the log, the byte trace, and the ``status`` of the reading
they came with, so a session file keeps them) and waits for the command's data and ``%`` as usual. 2 (the
client can repair it), 3 (user interaction needed) and 9 (fatal server error) abort the command: the client
sends ``ClearAllErrors()`` (the standard requires it from severity 2 on) and raises :class:`IppError`; the
reading is retried ``retries`` times.

Averaging. I++ DME has no averaged-measurement command: ``Get`` reads the current position once, and the
only quality figure of the standard, ``Q()``, exists only in ``OnPtMeasReport``/``OnScanReport`` of a
probing or scanning move, which a tracker watching a robot does not make. What the standard does provide is
its property mechanism (section 6.3.1.8-13), through which a server exposes technology- or vendor-specific
settings (vendor names carry a company prefix, section 9.1): ``EnumAllProp(Tool())`` lists every property
of the active tool with its type, ``GetProp(P())`` reads one and ``SetProp(P(v))`` sets one (an out-of-range
value gives warning 0504). So, at session start, with ``averaging=auto`` the client sends
``EnumAllProp(Tool())`` and looks for a ``"Number"`` property whose last name is one of
:data:`AVERAGE_NAMES` (e.g. ``Tool.XX.Average``); ``averaging=PROPERTY`` names the property instead
(checked with ``GetProp``), ``averaging=client`` skips the search. When the server has one, the client sets
it to ``average`` with ``SetProp``, reads back the count in force with ``GetProp`` (the server may clamp it),
and each reading is one ``Get`` of the server's average (no ``sigma``: the standard has no field for a point's
uncertainty). Otherwise (no such property, or ``EnumAllProp`` refused) the client averages: ``average`` raw
``Get`` points per reading, outliers rejected (:func:`drivers.averaging.robust_mean`), their spread as the
reading's ``sigma`` (per-axis standard uncertainty of the mean, m).

Several tracked points (``tools=A,B,C``): a server that follows several targets (reflectors on the flange)
exposes each as a tool; the names are the server's, and their order gives the points' ids (``tp`` 1, 2, 3...).
Each reading is, per tool, ``SetTool("A")`` (the standard's command that makes a tool active without a tool
change) then the point as above (averaging found and set up per tool at connect). A tool whose reading still
fails after its retries (e.g. a target out of sight) has no reading; only when every tool fails does the reading
fail.

Streaming (``start_stream``/``read_stream``/``stop_stream``): ``OnMoveReportE`` event reports, stamped with the
host's receive time (drivers/trackers/ipp_stream.py).
"""

from __future__ import annotations

import contextlib
import logging
import re
import socket
import time
from dataclasses import replace
from pathlib import Path
from typing import IO, Any

import numpy as np

from drivers.averaging import robust_mean
from drivers.base import DeviceIdentity, TrackerReading, check_measure_request
from drivers.errors import BadReading, ConnectionFailed, DeviceTimeout, MeasurementError, SpecError
from drivers.spec import TrackerSpec
from drivers.trace import ByteTrace, one_line
from drivers.trackers.ipp_protocol import IppError, IppNotice, IppProtocol
from drivers.trackers.ipp_stream import EventStreaming

DEFAULT_PORT = 1294
OPTIONS = ("timeout", "retries", "average", "averaging", "tools", "trace")
FORM = "ipp://HOST[:PORT][?timeout=S&retries=N&average=N&averaging=auto|client|PROPERTY&tools=A,B&trace=FILE]"
#: Last names (case-insensitive) of a tool property that sets how many points the server averages.
AVERAGE_NAMES = ("average", "averages", "averaging", "averagecount", "avgcount", "numaverages")
MAX_AVERAGE = 100_000
GET_POINT = "Get(X(), Y(), Z())"
_AXIS = re.compile(r"\b(?P<axis>[XYZ])\(\s*(?P<value>[-+0-9.eE]+)\s*\)")
_PROPERTY = re.compile(r'^"(?P<name>[A-Za-z][A-Za-z0-9.]*)"\s*,\s*"(?P<type>[A-Za-z]+)"$')
_PATH = re.compile(r"^[A-Za-z][A-Za-z0-9]*(\.[A-Za-z][A-Za-z0-9]*)*$")
_TOOL = re.compile(r"^[A-Za-z0-9_.+-]+$")

log = logging.getLogger("drivers.trackers.ipp")


class IppTracker(EventStreaming, IppProtocol):
    """An I++ DME server as a tracker (implements :class:`drivers.base.Tracker` and, with a server that has
    ``OnMoveReportE``, :class:`drivers.base.StreamingTracker`).

    ``average``: raw points per reading; ``averaging``: "auto", "client" or a property path (module doc).
    After :meth:`connect`, ``server_average`` is the server's averaging property (None: the client averages)
    and ``server_count`` the count the server reported in force; ``warnings`` collects every
    :class:`IppNotice`; ``events`` the raw event lines (``E`` tags). ``tools``: the server's tools of several
    tracked points, in id order (empty: the active tool, one point); each tool's averaging is in ``per_tool``.
    """

    def __init__(self, host: str, port: int = DEFAULT_PORT, *, timeout: float = 2.0, retries: int = 2,
                 average: int = 1, averaging: str = "auto", tools: tuple[str, ...] = (),
                 trace_io: str | Path | IO[str] | None = None) -> None:
        if int(average) != average or not 1 <= average <= MAX_AVERAGE:
            raise ValueError(f"average must be an integer in 1..{MAX_AVERAGE}, got {average!r}")
        if averaging not in ("auto", "client") and not _PATH.match(averaging):
            raise ValueError(f"averaging must be auto, client or a property path such as Tool.XX.Average, "
                             f"got {averaging!r}")
        if any(not _TOOL.match(t) for t in tools) or len(set(tools)) != len(tools):
            raise ValueError(f"tools must be distinct names of letters, digits and _.+-, got {list(tools)}")
        self.host, self.port, self.tools = host, port, tuple(tools)
        self.per_tool: dict[str, tuple[str | None, int]] = {}
        self.reply_timeout, self.retries = float(timeout), int(retries)
        self.average, self.averaging = int(average), averaging
        self._trace = ByteTrace(trace_io)
        self._sock: socket.socket | None = None
        self._buffer = b""
        self._tag = 0
        self.version = ""
        self.server_average: str | None = None
        self.server_count = 1
        self.events: list[str] = []
        self.warnings: list[IppNotice] = []
        self.reconnects = 0
        self._stopped_tags: set[str] = set()  # event tags of ended OnMoveReportE daemons
        self._init_stream()

    @property
    def points(self) -> int:
        """How many tracked points each reading reports (one per tool of ``tools``, else one)."""
        return max(len(self.tools), 1)

    @property
    def where(self) -> str:
        return f"ipp://{self.host}:{self.port}"

    def connect(self, timeout: float) -> None:
        """Open the connection and the session (StartSession, GetDMEVersion), then find who averages."""
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
        for tool in self.tools:  # each tool's averaging, found with that tool active
            try:
                self._set_tool(tool, deadline)
            except IppError as exc:
                raise ConnectionFailed(f"the I++ server {self.where} has no tool {tool!r} (tools=): {exc}") from exc
            self._find_averaging(deadline)
            self.per_tool[tool] = (self.server_average, self.server_count)
        if not self.tools:
            self._find_averaging(deadline)

    def close(self) -> None:
        self.stop_stream(min(self.reply_timeout, 1.0))
        if self._sock is not None:
            with contextlib.suppress(Exception):  # closing a dead link must not raise
                self.command("EndSession()", time.monotonic() + min(self.reply_timeout, 1.0))
        self._drop()
        self._trace.close()

    def identity(self) -> DeviceIdentity:
        if self.server_average is not None:
            averaging = f"server: {self.server_average} = {self.server_count}"
        else:
            averaging = f"client: {self.average} point(s) per reading"
        details = {"address": self.where, "protocol": "I++ DME", "averaging": averaging}
        if self.tools:
            details["tools"] = ",".join(self.tools)
        return DeviceIdentity("tracker", "I++ DME server", firmware=self.version, details=details)

    def measure(self, count: int, timeout: float) -> list[TrackerReading]:
        """``count`` readings of the current point (m), each averaged as set up at connect; errors of
        severity >= 2 are cleared and retried ``retries`` times, a dropped connection re-opened once per
        reading; warnings go into the reading's ``status``; ``timeout`` bounds the call."""
        check_measure_request(count, timeout)
        if self._sock is None:
            raise ConnectionFailed(f"I++ tracker {self.where} is not connected (call connect())")
        self._refuse_while_streaming(f"I++ tracker {self.where}")
        deadline = time.monotonic() + timeout
        if not self.tools:
            return [self._one_reading(deadline) for _ in range(int(count))]
        return [reading for _ in range(int(count)) for reading in self._each_tool(deadline)]

    # --- readings -----------------------------------------------------------------------------------------

    def _each_tool(self, deadline: float) -> list[TrackerReading]:
        """One reading of every tool (``tp`` its place in ``tools``); a tool that fails has none; the last error
        when all fail."""
        out, last = [], None
        for tp, tool in enumerate(self.tools, start=1):
            try:
                out.append(replace(self._one_reading(deadline, tool), tp=tp))
            except MeasurementError as exc:
                last = exc
                self._trace.event(f"tool {tool} (point {tp}) has no reading: {exc}")
        if not out:
            assert last is not None
            raise last
        return out

    def _one_reading(self, deadline: float, tool: str | None = None) -> TrackerReading:
        last: Exception | None = None
        reconnected = False
        attempts = 0
        noticed = len(self.warnings)
        for _attempt in range(self.retries + 1):
            attempts += 1
            try:
                if self._sock is None:
                    self.connect(max(deadline - time.monotonic(), 0.1))
                if tool is not None:
                    self._set_tool(tool, deadline)
                reading = self._averaged_point(deadline)
                news = [str(n) for n in self.warnings[noticed:]]
                return reading if not news else TrackerReading(reading.position, reading.timestamp, reading.sigma,
                                                               "; ".join([reading.status, *news]))
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
        message = f"{last} (after {attempts} attempt{'s' if attempts > 1 else ''})"
        if isinstance(last, IppError):
            raise IppError(message, last.severity, last.code, last.text) from last
        raise type(last)(message) from last

    def _set_tool(self, tool: str, deadline: float) -> None:
        """Make ``tool`` the active one (``SetTool``) and take up its averaging (found at connect)."""
        self.command(f'SetTool("{tool}")', min(deadline, time.monotonic() + self.reply_timeout))
        if tool in self.per_tool:
            self.server_average, self.server_count = self.per_tool[tool]

    def _averaged_point(self, deadline: float) -> TrackerReading:
        """One reading: the server's (averaged) point, or the robust mean of ``average`` raw points."""
        samples = 1 if self.server_average is not None else self.average
        points, stamps = [], []
        for _ in range(samples):
            data = self.command(GET_POINT, min(deadline, time.monotonic() + self.reply_timeout))
            stamps.append(time.time())
            points.append(self._point(data))
        if samples == 1:
            return TrackerReading(points[0], stamps[0])
        mean, sigma, used = robust_mean(np.array(points))
        status = "ok" if used.all() else f"ok, {int((~used).sum())} of {samples} points rejected"
        if not used.all():
            self._trace.event(f"averaged reading: {status}")
        return TrackerReading(mean, float(np.mean(stamps)), sigma, status)

    def _point(self, data: list[str]) -> np.ndarray:
        values: dict[str, float] = {}
        for line in data:
            for m in _AXIS.finditer(line):
                with contextlib.suppress(ValueError):
                    values[m.group("axis")] = float(m.group("value"))
        if set(values) != {"X", "Y", "Z"} or not all(np.isfinite(list(values.values()))):
            raise BadReading(f"{self.where}: unusable reply to {GET_POINT}: {' | '.join(data)!r}")
        return np.array([values["X"], values["Y"], values["Z"]]) * 1e-3

    # --- averaging capability -----------------------------------------------------------------------------

    def _find_averaging(self, deadline: float) -> None:
        """Find the server's averaging property (``averaging``) and set it to ``average`` (module doc)."""
        self.server_average, self.server_count = None, 1
        if self.averaging == "client":
            return
        if self.averaging == "auto":
            self.server_average = self._averaging_property(deadline)
            if self.server_average is None:
                self._trace.event(f"no averaging property: the client averages {self.average} point(s)")
                return
        else:
            try:
                self._get_number(self.averaging, deadline)
            except (IppError, BadReading, DeviceTimeout) as exc:
                raise ConnectionFailed(f"the I++ server {self.where} has no averaging property {self.averaging} "
                                       f"(averaging=): {exc}") from exc
            self.server_average = self.averaging
        try:
            self.command(f"SetProp({self.server_average}({self.average}))", deadline)
            self.server_count = round(self._get_number(self.server_average, deadline))
        except (IppError, BadReading) as exc:
            raise ConnectionFailed(f"the I++ server {self.where} did not take {self.server_average}"
                                   f"({self.average}): {exc}") from exc
        if self.server_count != self.average:
            log.warning("%s averages %d point(s) per reading, not the %d asked for", self.where, self.server_count,
                        self.average)
            self._trace.event(f"server averages {self.server_count}, not {self.average}")

    def _averaging_property(self, deadline: float) -> str | None:
        """The first numeric tool property named like :data:`AVERAGE_NAMES` (None if none or refused)."""
        try:
            data = self.command("EnumAllProp(Tool())", min(deadline, time.monotonic() + self.reply_timeout))
        except (IppError, DeviceTimeout) as exc:
            self._trace.event(f"EnumAllProp(Tool()) refused: {exc}")
            return None
        for line in data:
            match = _PROPERTY.match(line)
            if match and match.group("type") == "Number":
                name = match.group("name")
                if name.rpartition(".")[2].lower() in AVERAGE_NAMES:
                    return f"Tool.{name}"
        return None

    def _get_number(self, path: str, deadline: float) -> float:
        """The numeric value of property ``path`` by ``GetProp(path())``."""
        data = self.command(f"GetProp({path}())", deadline)
        match = re.search(rf"{re.escape(path)}\(\s*([-+0-9.eE]+)\s*\)", " ".join(data))
        if match is None:
            raise BadReading(f"{self.where}: GetProp({path}()) answered {' | '.join(data)!r}, not a number")
        return float(match.group(1))



def open_tracker(spec: TrackerSpec | str, rig: Any = None, site: Any = None, *,
                 trace_io: str | Path | IO[str] | None = None) -> IppTracker:
    """An unconnected :class:`IppTracker` for ``ipp://HOST[:PORT]?...``; ``rig`` is not used (a real device),
    ``site.tracker_settings`` gives option defaults, ``trace_io`` overrides the ``trace`` option."""
    spec = spec if isinstance(spec, TrackerSpec) else TrackerSpec.parse(spec)
    if spec.backend != "ipp":
        raise SpecError(f"drivers.trackers.ipp opens ipp://HOST[:PORT] trackers, got {str(spec)!r}; expected {FORM}")
    raw: dict[str, Any] = {k: v for k, v in dict(getattr(site, "tracker_settings", None) or {}).items()
                           if v is not None}
    raw.update(spec.options)
    for key in raw:
        if key not in OPTIONS:
            raise SpecError(f"tracker spec {str(spec)!r}: unknown option {key!r} (known: {', '.join(OPTIONS)}); "
                            f"expected {FORM}")
    values: dict[str, Any] = {"timeout": 2.0, "retries": 2, "average": 1}
    for key, kind, low in (("timeout", float, 0.0), ("retries", int, 0), ("average", int, 1)):
        if key in raw:
            try:
                values[key] = kind(raw[key])
            except (TypeError, ValueError):
                values[key] = None
            if values[key] is None or values[key] < low or (key == "timeout" and values[key] == 0) \
                    or (key == "average" and values[key] > MAX_AVERAGE):
                need = {"timeout": "a number > 0", "retries": "an integer >= 0",
                        "average": f"an integer in 1..{MAX_AVERAGE}"}[key]
                raise SpecError(f"tracker spec {str(spec)!r}: option {key}={raw[key]} must be {need}; "
                                f"expected {FORM}")
    tools = tuple(t for t in str(raw.get("tools", "")).split(",") if t)
    if "tools" in raw and (not tools or any(not _TOOL.match(t) for t in tools) or len(set(tools)) != len(tools)):
        raise SpecError(f"tracker spec {str(spec)!r}: option tools={raw['tools']} must be distinct tool names "
                        f"separated by commas (letters, digits, _.+-); expected {FORM}")
    averaging = str(raw.get("averaging", "auto"))
    if averaging not in ("auto", "client") and not _PATH.match(averaging):
        raise SpecError(f"tracker spec {str(spec)!r}: option averaging={averaging} must be auto, client or a "
                        f"property path such as Tool.XX.Average; expected {FORM}")
    host, port = spec.address
    return IppTracker(host, port or DEFAULT_PORT, timeout=values["timeout"], retries=values["retries"],
                      average=values["average"], averaging=averaging, tools=tools,
                      trace_io=trace_io if trace_io is not None else raw.get("trace"))
