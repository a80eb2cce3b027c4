"""A simulated I++ DME server on loopback (see tests/tracker_devices.py): answers from a simulated rig's true TP."""

from __future__ import annotations

import contextlib
import re
import socket
import threading
import time
from typing import Any

import numpy as np

from drivers.sim.rig import SimulatedRig
from tests._served import _Served

STILL = 1e-6  # m: a standard server reports when the point moved more than this since the last tick
IPP_FAULTS = ("error", "fatal", "warning", "info", "event_warning", "outlier", "silence", "drop", "no_ack")
IPP_TOOL_PROPERTIES = ("PtMeasPar.Speed", "PtMeasPar.Accel", "PtMeasPar.Approach", "PtMeasPar.Search",
                       "PtMeasPar.Retract", "GoToPar.Speed", "GoToPar.Accel")


class IppServer(_Served):
    """A minimal I++ DME server on loopback (``host``, ``port``) that answers from the rig's TP (mm, noise
    ``noise`` m per axis): StartSession, EndSession, GetDMEVersion, ClearAllErrors, GetErrStatusE,
    Get(X(),Y(),Z()), EnumAllProp(Tool()), GetProp/SetProp of tool properties; anything else is error 0501.

    ``averaging``: the name (below ``Tool.``) of a vendor property that sets how many points each Get
    averages (1..``max_average``; more is clamped with warning 0504), or None for a server without one;
    ``enum_props=False``: a server that refuses EnumAllProp (error 0501). Errors of severity >= 2 put the
    server in its error state (every command but ClearAllErrors/GetErrStatusE answers 0514) until
    ClearAllErrors(); each error is followed by ``%`` as in the standard's examples.

    Faults (``inject``), each on the next Get: ``error`` (0511, severity 2), ``fatal`` (0503, severity 9),
    ``warning`` (1009 re-classified as severity 1, the point follows), ``info`` (0000, severity 0, the
    point follows), ``event_warning`` (an unsolicited E0000 warning, then the point), ``outlier`` (the point
    5 mm off), ``silence`` (no answer), ``drop`` (the server resets: connection closed, session ended),
    ``no_ack`` (data without the ``&``).

    ``tools``: names of the targets it follows (reflector k of the rig, ``rig.true_points()[k]``, is tool k);
    ``SetTool("NAME")`` makes one active (an unknown name: error 0510, severity 3) and Get answers its point;
    a tool in ``hidden`` answers Get with error 0511 (severity 2, "Target not visible").

    ``move_reports``: the server supports ``OnMoveReportE(Time(s), X(), Y(), Z())`` sent with an event tag
    ``Ennnn`` (a plain tag: error 0502; a second daemon: error 0515): after ``Ennnn &`` a daemon thread sends
    ``Ennnn # X(..), Y(..), Z(..)`` (mm) every ``s`` s; while the active tool is hidden it sends ``Ennnn !
    Error(2, 0511, OnMoveReportE, "Target not visible")`` instead, once per report. ``StopDaemon(Ennnn)`` or
    ``StopAllDaemons()`` ends it (``Ennnn %``). ``reports`` counts the reports sent, ``sent`` holds the host
    time each one's point was taken.

    ``standard=True``: the daemon as the I++ DME standard has it (drivers/trackers/ipp_stream.py says what is
    confirmed): a ``Time`` below 0.1 s is refused after the ``&`` with error 0510 (severity 3, "Bad property"),
    so at most 10 reports per second, and a report is sent only when the point moved more than :data:`STILL`
    since the last tick (the machine in motion: none at rest).
    """

    def __init__(self, rig: SimulatedRig | None = None, *, noise: float = 2e-5, seed: int = 0,
                 events: bool = False, averaging: str | None = None, max_average: int = 64,
                 enum_props: bool = True, tools: tuple[str, ...] = (), move_reports: bool = False,
                 standard: bool = False) -> None:
        super().__init__()
        self.rig = rig if rig is not None else SimulatedRig("ur5e", seed=seed)
        self.noise, self.events = noise, events
        self.averaging, self.max_average, self.enum_props = averaging, max_average, enum_props
        self.rng = np.random.default_rng(seed)
        self._server = socket.create_server(("127.0.0.1", 0))
        self.host, self.port = "127.0.0.1", self._server.getsockname()[1]
        self.faults: list[str] = []
        self.in_error = False
        self.session = False
        self.tools, self.active, self.hidden = tuple(tools), (tools[0] if tools else None), set[str]()
        self.properties: dict[str, float] = dict.fromkeys(IPP_TOOL_PROPERTIES, 10.0)
        if averaging is not None:
            self.properties[averaging] = 1.0
        self.commands: list[str] = []
        self.gets = 0  # Get(X(),Y(),Z()) commands answered with a point
        self.move_reports, self.reports, self.standard = move_reports, 0, standard
        self.sent: list[float] = []  # host time (time.time()) at which each report's point was taken
        self._daemon: tuple[str, threading.Event] | None = None  # (event tag, stop flag) of OnMoveReportE
        self._send_lock = threading.Lock()  # the daemon thread and the command handler share the socket
        self._start()

    def inject(self, fault: str, count: int = 1) -> None:
        if fault not in IPP_FAULTS:
            raise ValueError(f"unknown fault {fault!r} (known: {', '.join(IPP_FAULTS)})")
        self.faults.extend([fault] * count)

    def _serve(self) -> None:
        self._accept_each(self._server, self._serve_connection)

    def _serve_connection(self, conn: socket.socket) -> None:
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.settimeout(0.05)
        buffer = b""
        while not self._stop.is_set():
            try:
                data = conn.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                break
            if not data:
                break
            buffer += data
            *lines, buffer = buffer.split(b"\r\n")
            if any(not self._handle(conn, raw.decode("ascii", "replace")) for raw in lines if raw):
                break
        self._stop_daemon()  # a daemon ends with its connection

    def _handle(self, conn: socket.socket, line: str) -> bool:
        """Answer one command; False to drop the connection."""
        self.commands.append(line)
        tag, _, command = line.partition(" ")
        command = command.strip()
        name = command.partition("(")[0]
        fault = self.faults.pop(0) if self.faults and name == "Get" else None
        if fault == "drop":
            self.session = False  # the server restarted: the client must start a new session
            return False
        if fault == "silence":
            return True

        def send(text: str) -> None:
            with self._send_lock:
                conn.sendall(f"{tag} {text}\r\n".encode())

        def error(severity: int, code: str, text: str) -> bool:
            send(f'! Error({severity}, {code}, {name}, "{text}")')
            send("%")
            self.in_error = self.in_error or severity >= 2
            return True

        if fault != "no_ack":
            send("&")
        if self.events:
            conn.sendall(b"E0000 # GoTo(X(0), Y(0), Z(0))\r\n")
        if name not in ("StartSession", "EndSession", "ClearAllErrors", "GetErrStatusE"):
            if not self.session:
                return error(3, "0008", "Protocol error")
            if self.in_error:
                return error(2, "0514", "Use ClearAllErrors to continue")
        if command == "StartSession()":
            self.session = True
        elif command == "EndSession()":
            self.session = False
        elif command == "GetDMEVersion()":
            send('# DMEVersion("1.4.2")')
        elif command == "ClearAllErrors()":
            self.in_error = False
        elif command == "GetErrStatusE()":
            send(f"# ErrStatus({1 if self.in_error else 0})")
        elif command.replace(" ", "") == "Get(X(),Y(),Z())":
            if self.active in self.hidden:
                return error(2, "0511", "Target not visible")
            return self._get(conn, send, error, fault)
        elif name == "OnMoveReportE" and self.move_reports:
            return self._start_daemon(conn, tag, command, send, error)
        elif name in ("StopDaemon", "StopAllDaemons") and self.move_reports:
            daemon = self._daemon
            wanted = command[len("StopDaemon("):-1].strip() if name == "StopDaemon" else None
            if daemon is None or (wanted is not None and wanted != daemon[0]):
                return error(2, "0513", "No such daemon")
            self._stop_daemon()
        elif name == "SetTool" and self.tools:
            wanted = command[len("SetTool("):-1].strip().strip('"')
            if wanted not in self.tools:
                return error(3, "0510", "Bad tool")
            self.active = wanted
        elif command == "EnumAllProp(Tool())" and self.enum_props:
            for prop in self.properties:
                send(f'# "{prop}", "Number"')
        elif name in ("GetProp", "SetProp"):
            return self._property(name, command, send, error)
        else:
            return error(3, "0501", "Unsupported command")
        send("%")
        return True

    def _start_daemon(self, conn: socket.socket, tag: str, command: str, send: Any, error: Any) -> bool:
        if not tag.startswith("E"):
            return error(3, "0502", "OnMoveReportE needs an event tag")
        if self._daemon is not None:
            return error(2, "0515", "A daemon is already running")
        match = re.search(r"Time\(\s*([-+0-9.eE]+)\s*\)", command)
        interval = float(match.group(1)) if match else 0.0
        if not interval > 0:
            return error(3, "0509", "Bad argument")
        if self.standard and interval < 0.1:
            return error(3, "0510", "Bad property")
        stop = threading.Event()
        self._daemon = (tag, stop)
        threading.Thread(target=self._report_loop, args=(conn, tag, interval, stop, send), daemon=True).start()
        return True

    def _report_loop(self, conn: socket.socket, tag: str, interval: float, stop: threading.Event, send: Any) -> None:
        next_time = time.monotonic()
        last: np.ndarray | None = None  # the true point at the previous tick (standard: report only if it moved)
        while not stop.is_set() and not self._stop.is_set():
            next_time += interval
            stop.wait(max(0.0, next_time - time.monotonic()))
            if stop.is_set():
                break
            try:
                if self.active in self.hidden:
                    send('! Error(2, 0511, OnMoveReportE, "Target not visible")')
                    continue
                true = self.rig.true_points()[self.tools.index(self.active)] if self.tools else self.rig.true_point()
                moved = last is not None and float(np.abs(np.asarray(true) - last).max()) > STILL
                last = np.asarray(true, dtype=float)
                if self.standard and not moved:
                    continue
                x, y, z = (np.asarray(true) + self.rng.normal(0.0, self.noise, 3)) * 1000.0
                self.sent.append(time.time())
                send(f"# X({x:.6f}), Y({y:.6f}), Z({z:.6f})")
                self.reports += 1
            except OSError:
                return
        with contextlib.suppress(OSError):
            send("%")

    def _stop_daemon(self) -> None:
        daemon, self._daemon = self._daemon, None
        if daemon is not None:
            daemon[1].set()

    def _get(self, conn: socket.socket, send: Any, error: Any, fault: str | None) -> bool:
        if fault == "error":
            return error(2, "0511", "Error processing method")
        if fault == "fatal":
            return error(9, "0503", "Controller communications failure")
        if fault == "warning":
            send('! Error(1, 1009, Get, "Air pressure out of range")')
        elif fault == "info":
            send('! Error(0, 0000, Get, "Buffer full")')
        elif fault == "event_warning":
            conn.sendall(b'E0000 ! Error(1, 8001, Thermometer, "Air temperature changed by 1.2 K")\r\n')
        n = int(self.properties.get(self.averaging, 1)) if self.averaging else 1
        true = self.rig.true_points()[self.tools.index(self.active)] if self.tools else self.rig.true_point()
        point = np.asarray(true) + self.rng.normal(0.0, self.noise, (n, 3)).mean(axis=0)
        if fault == "outlier":
            point = point + 5e-3
        x, y, z = point * 1000.0
        self.gets += 1
        send(f"# X({x:.6f}), Y({y:.6f}), Z({z:.6f})")
        send("%")
        return True

    def _property(self, name: str, command: str, send: Any, error: Any) -> bool:
        """GetProp(Tool.P(), ...) answers ``Tool.P(v)``; SetProp(Tool.P(v)) sets it (the averaging count is
        clamped to 1..max_average with warning 0504)."""
        args = re.findall(r"Tool\.([A-Za-z][A-Za-z0-9.]*)\(\s*([-+0-9.eE]*)\s*\)", command)
        if not args or any(prop not in self.properties for prop, _ in args):
            return error(3, "0510", "Bad property")
        if name == "GetProp":
            send("# " + ", ".join(f"Tool.{prop}({self.properties[prop]:g})" for prop, _ in args))
        else:
            for prop, value in args:
                wanted = float(value or "nan")
                if prop == self.averaging:
                    if not 1 <= wanted <= self.max_average:
                        send('! Error(1, 0504, SetProp, "Argument out of range")')
                    wanted = float(min(max(round(wanted), 1), self.max_average))
                self.properties[prop] = wanted
        send("%")
        return True


def free_port() -> int:
    """A loopback TCP port nobody listens on (bound, then released)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def open_ipp(server: IppServer, **options: str) -> Any:
    """The I++ tracker driver connected to ``server`` (options as in the spec; reply timeout 0.5 s by default)."""
    from drivers.registry import open_tracker

    query = "&".join(f"{k}={v}" for k, v in {"timeout": "0.5", **options}.items())
    tracker = open_tracker(f"ipp://{server.host}:{server.port}?{query}")
    tracker.connect(2.0)
    return tracker
