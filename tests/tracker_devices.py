"""Simulated measuring devices for tests: an ASCII device (any profile of ``config/trackers/``) on a real
pseudo-terminal or a loopback TCP socket, and an I++ DME server on loopback. Both answer from a simulated
rig's true TP (``rig.true_point()``) plus Gaussian noise.

ASCII device: the profile's ``simulation`` block says how it formats replies (``reply``, ``payload`` for a
checksum, ``identity``, ``banner``, ``lost``/``lost_status``, ``init_reply``, ``needs_init``, ``period`` of a
streaming device). Faults, each for the next ``count`` replies (``device.inject(name, count)``):

- ``target_lost``: the profile's target-lost reply; ``garbage``: a line of random bytes instead of the reply;
- ``noise``: non-printable noise bytes before the reply (the reply must still parse);
- ``partial``: the reply arrives in two pieces 20 ms apart (must still parse); ``truncated``: half a line;
- ``bad_checksum``: a wrong checksum; ``out_of_range``: coordinates of 1e6 m;
- ``reset``: the device prints its banner, forgets its initialisation (answers not_ready until
  initialised again) and drops the request; ``silence``: no answer.

``echo=True`` echoes every command line back first. ``mixed_endings=True`` ends each line with a random one
of CRLF, LF and CR. A profile with ``points: N`` answers each trigger with N lines (reflector k at
``rig.true_points()[k-1]``, written in one piece); ids in ``device.hidden`` answer the ``lost`` reply (out of
sight); a fault spoils the first line (``target_lost``: every line).
"""

from __future__ import annotations

import contextlib
import os
import random
import re
import select
import socket
import threading
import time
import tty
from typing import Any

import numpy as np

from drivers.ascii_profile import Profile, checksum_of, load_profile
from drivers.sim import SimulatedRig

ASCII_FAULTS = ("target_lost", "garbage", "noise", "partial", "truncated", "bad_checksum", "out_of_range", "reset",
                "silence")


class _Served:
    """A thread serving a byte stream on file descriptor ``fd`` until ``stop()``."""

    fd: int

    def __init__(self) -> None:
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.received = bytearray()

    def _start(self) -> None:
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _serve(self) -> None:
        raise NotImplementedError

    def _accept_each(self, server: socket.socket, serve: Any) -> None:
        """Accept loopback connections on ``server`` until stopped, ``serve(conn)`` each, then close it."""
        server.settimeout(0.05)
        while not self._stop.is_set():
            try:
                conn, _ = server.accept()
            except TimeoutError:
                continue
            with conn:
                serve(conn)
        server.close()


class AsciiDevice(_Served):
    """An ASCII tracker speaking ``profile`` (name or Profile) on a pty (``transport="pty"``, then ``port``
    is the slave's path) or on loopback TCP (``transport="tcp"``, then ``port`` is ``socket://127.0.0.1:N``)."""

    def __init__(self, profile: str | Profile, rig: SimulatedRig | None = None, *, noise: float = 2e-5,
                 seed: int = 0, transport: str = "pty", mixed_endings: bool = False, latency: float = 0.0,
                 echo: bool = False) -> None:
        super().__init__()
        self.profile = profile if isinstance(profile, Profile) else load_profile(profile)
        self.sim = self.profile.simulation
        self.rig = rig if rig is not None else SimulatedRig("ur5e", seed=seed)
        self.noise, self.latency, self.mixed, self.echo = noise, latency, mixed_endings, echo
        self.rng = np.random.default_rng(seed)
        self._random = random.Random(seed)
        self.faults: list[str] = []
        self.hidden: set[int] = set()  # tracked point ids out of sight (profiles with several points)
        self.initialised = not self.sim.get("needs_init", False)
        self.streaming = not self.sim.get("needs_start", False)
        self.replies = 0
        self.commands: list[str] = []
        self.busy: list[float] = []  # s the device spent answering each trigger (its own response time)
        self._inbuf = b""
        self._lock = threading.Lock()
        self.transport = transport
        if transport == "pty":
            self.fd, self._slave = os.openpty()
            tty.setraw(self._slave)
            self.port = os.ttyname(self._slave)
            self._start()
        else:
            self._server = socket.create_server(("127.0.0.1", 0))
            self.port = f"socket://127.0.0.1:{self._server.getsockname()[1]}"
            self._start()

    def inject(self, fault: str, count: int = 1) -> None:
        if fault not in ASCII_FAULTS:
            raise ValueError(f"unknown fault {fault!r} (known: {', '.join(ASCII_FAULTS)})")
        with self._lock:
            self.faults.extend([fault] * count)

    def reset(self) -> None:
        """Reboot now (unprompted): banner, initialisation lost, streaming stopped."""
        self._write_line(self.sim.get("banner", "RESET"))
        self.initialised = not self.sim.get("needs_init", False)
        self.streaming = not self.sim.get("needs_start", False)

    # --- serving ------------------------------------------------------------------------------------------

    def _serve(self) -> None:
        if self.transport == "tcp":
            self._accept_each(self._server, self._serve_connection)
        else:
            try:
                self._loop()
            finally:
                os.close(self.fd)
                os.close(self._slave)

    def _serve_connection(self, conn: socket.socket) -> None:
        self.fd = conn.fileno()
        self._loop()

    def _loop(self) -> None:
        period = float(self.sim.get("period", 0.0)) if self.profile.mode == "streaming" else 0.0
        next_emit = time.monotonic()
        while not self._stop.is_set():
            wait = 0.01 if not (period and self.streaming) else max(0.0, min(0.01, next_emit - time.monotonic()))
            ready, _, _ = select.select([self.fd], [], [], wait)
            if ready:
                try:
                    data = os.read(self.fd, 4096)
                except OSError:
                    data = b""
                if not data:
                    if self.transport == "tcp":
                        return
                    time.sleep(0.01)  # pty: the other side is closed for now
                    continue
                self.received += data
                self._inbuf += data
                *lines, self._inbuf = re.split(rb"\r\n|\r|\n", self._inbuf)
                for raw in lines:
                    if raw.strip():
                        self._command(raw.decode("ascii", "replace").strip())
            if period and self.streaming and time.monotonic() >= next_emit:
                self._reply()
                next_emit = max(next_emit + period, time.monotonic() - period)

    def _command(self, text: str) -> None:
        self.commands.append(text)
        if self.echo:
            self._write_line(text)
        p = self.profile
        if p.identify is not None and text == p.identify[0]:
            self._write_line(self.sim.get("identity", "SIM"))
        elif any(text == c.send for c in p.init):
            self.initialised = True
            expects = [c for c in p.init if c.send == text and c.expect is not None]
            if expects:
                self._write_line(self.sim.get("init_reply", "OK"))
        elif p.start is not None and text == p.start:
            self.streaming = True
        elif p.stop is not None and text == p.stop:
            self.streaming = False
        elif p.trigger is not None and text == p.trigger:
            started = time.perf_counter()
            if self.latency:
                time.sleep(self.latency)
            self._reply()
            self.busy.append(time.perf_counter() - started)

    def _next_fault(self) -> str | None:
        with self._lock:
            return self.faults.pop(0) if self.faults else None

    def _reply(self) -> None:
        if not self.initialised:
            self._write_line(self.sim.get("not_ready", "E07 NOT READY"))
            return
        self.replies += 1
        fault = self._next_fault()
        if fault == "silence":
            return
        if fault == "reset":
            self.reset()
            return
        if fault == "garbage":
            junk = bytes(self._random.randrange(256) for _ in range(24)).replace(b"\r", b"").replace(b"\n", b"")
            self._write(junk + b"\r\n")
            return
        line = self._format(lost=fault == "target_lost", far=fault == "out_of_range")
        if fault == "bad_checksum":
            line = line[:-1] + ("0" if line[-1] != "0" else "1")
        if fault == "truncated":
            line = line[: len(line) // 2]
        eol = self._eol()
        for tp in range(2, self.profile.points + 1):  # the other points' lines follow in the same write
            line += eol.decode() + self._format(lost=fault == "target_lost" or tp in self.hidden, tp=tp)
        if fault == "noise":
            self._write(b"\x00\x13\xfe\x7f" + line.encode() + b"\x01" + eol)
        elif fault == "partial":
            half = len(line) // 2
            self._write(line[:half].encode())
            time.sleep(0.02)
            self._write(line[half:].encode() + eol)
        else:
            self._write(line.encode() + eol)

    def _format(self, lost: bool = False, far: bool = False, tp: int = 1) -> str:
        sim = self.sim
        lost = lost or (self.profile.points > 1 and tp in self.hidden)
        if lost and "lost" in sim:
            return str(sim["lost"]).format(tp=tp)
        true = self.rig.true_points()[tp - 1] if self.profile.points > 1 else self.rig.true_point()
        point = np.asarray(true, dtype=float) + self.rng.normal(0.0, self.noise, 3)
        if far:
            point = np.full(3, 1e6)
        x, y, z = point / self.profile.scale
        status = sim.get("lost_status", "TL") if lost else sim.get("ok", "OK")
        values = {"x": x, "y": y, "z": z, "status": status, "tp": tp}
        if "payload" in sim:
            payload = str(sim["payload"]).format(**values)
            algorithm = self.profile.checksum or "xor"
            return str(sim["reply"]).format(payload=payload, checksum=checksum_of(payload, algorithm))
        return str(sim["reply"]).format(**values)

    def _eol(self) -> bytes:
        if self.mixed:
            return self._random.choice([b"\r\n", b"\n", b"\r"])
        return self.profile.line_ending.encode()

    def _write_line(self, text: str) -> None:
        self._write(text.encode() + self._eol())

    def _write(self, data: bytes) -> None:
        with contextlib.suppress(OSError):
            os.write(self.fd, data)


# --- I++ DME ----------------------------------------------------------------------------------------------

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
    """

    def __init__(self, rig: SimulatedRig | None = None, *, noise: float = 2e-5, seed: int = 0,
                 events: bool = False, averaging: str | None = None, max_average: int = 64,
                 enum_props: bool = True, tools: tuple[str, ...] = ()) -> None:
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
