"""The emulated controller's network side: the dashboard server, the script / primary ports and the RTDE
server (see tests/ur_emulator/__init__.py). A mixin of :class:`tests.ur_emulator.controller.UREmulator`, whose
state (modes, registers, motion, log, lock) it reads and writes."""

from __future__ import annotations

import contextlib
import socket
import struct
import threading
import time
from typing import Any

from tests.ur_emulator.protocol import (
    _DOUBLES,
    _FORMATS,
    _UINT8,
    _UINT32,
    _V6,
    _ZERO,
    DASHBOARD_MODEL,
    ROBOT_MODE_POWER_OFF,
    ROBOT_MODE_RUNNING,
    SAFETY_NORMAL,
    SAFETY_PROTECTIVE_STOP,
    SAFETY_ROBOT_EMERGENCY_STOP,
    VARIABLES,
    I,
    O,
    P,
    S,
    U,
    V,
    _packet,
    _recv_exact,
    _take_program,
    v,
)


class ControllerServers:
    """Serving methods of the emulator (every attribute used here is set by UREmulator.__init__; it calls
    UREmulator's ``_spawn``, ``_state`` and ``_stop_program``)."""

    _running: bool
    _lock: Any
    _connections: set[socket.socket]
    _inputs: dict[str, Any]
    _frozen: dict[str, Any] | None
    log: Any
    version: tuple[int, int, int, int]
    model: str
    serial: str
    remote_control: bool
    kinematics: bool
    rate: float
    native_rate: bool
    late_packages: int
    robot_mode: int
    safety_mode: int
    rig: Any
    _program_running: bool
    _program_starts_at: float

    # --- servers --------------------------------------------------------------------------------------------

    def _accept_loop(self, server: socket.socket, handler: Any) -> None:
        while self._running:
            try:
                conn, _ = server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._connections.add(conn)
            self._spawn(self._guard, handler, conn)

    def _guard(self, handler: Any, conn: socket.socket) -> None:
        try:
            handler(conn)
        except (OSError, ConnectionError, struct.error):
            pass
        finally:
            self._connections.discard(conn)
            with contextlib.suppress(OSError):
                conn.close()

    def _serve_dashboard(self, conn: socket.socket) -> None:
        conn.sendall(b"Connected: Universal Robots Dashboard Server\n")
        buffer = b""
        while self._running:
            data = conn.recv(4096)
            if not data:
                return
            buffer += data
            while b"\n" in buffer:
                line, buffer = buffer.split(b"\n", 1)
                command = line.decode(errors="replace").strip()
                self.log.dashboard.append(command)
                reply = self._dashboard(command)
                conn.sendall((reply + "\n").encode())
                if command == "quit":
                    return

    def _dashboard(self, command: str) -> str:
        major, minor, bugfix, build = self.version
        c = command.lower()
        if c == "polyscopeversion":
            return f"URSoftware {major}.{minor}.{bugfix}.{build} (Jan 01 2024)"
        if c == "is in remote control":
            return "true" if self.remote_control else "false"
        if c == "get robot model":
            return DASHBOARD_MODEL.get(self.model.lower(), self.model.upper())
        if c == "get serial number":
            return self.serial
        if c == "robotmode":
            names = {ROBOT_MODE_RUNNING: "RUNNING", ROBOT_MODE_POWER_OFF: "POWER_OFF"}
            return f"Robotmode: {names.get(self.robot_mode, 'IDLE')}"
        if c == "safetystatus" or c == "safetymode":
            names = {SAFETY_NORMAL: "NORMAL", SAFETY_PROTECTIVE_STOP: "PROTECTIVE_STOP",
                     SAFETY_ROBOT_EMERGENCY_STOP: "ROBOT_EMERGENCY_STOP"}
            return f"{command.capitalize()}: {names[self.safety_mode]}"
        if c == "unlock protective stop":
            if self.safety_mode == SAFETY_PROTECTIVE_STOP:
                self.clear_stop()
            return "Protective stop releasing"
        if c == "stop":
            with self._lock:
                self.rig._stop_requested = True
                self._stop_program()
            return "Stopped"
        if c == "programstate":
            return "PLAYING <unnamed>" if self._program_running else "STOPPED <unnamed>"
        if c == "running":
            return f"Program running: {'true' if self._program_running else 'false'}"
        if c in ("close popup", "close safety popup"):
            return "closing popup" if c == "close popup" else "closing safety popup"
        if c == "quit":
            return "Disconnected"
        return f"could not understand: '{command}'"

    def _serve_script(self, conn: socket.socket) -> None:
        if conn.getsockname()[1] in (30001, 30002):
            conn.sendall(self._primary_greeting())
        buffer = ""
        while self._running:
            data = conn.recv(65536)
            if not data:
                return
            buffer += data.decode(errors="replace")
            while True:
                program, buffer = _take_program(buffer)
                if program is None:
                    break
                self._run_program(program)

    def _primary_greeting(self) -> bytes:
        """What the primary / secondary interface sends first: a version message, then a robot state message
        with the kinematics info (the controller's factory-calibrated DH values: here the rig's true robot)."""
        major, minor, bugfix, build = self.version
        name = b"URControl"
        version = (struct.pack(">QbB", 0, -1, 3) + bytes([len(name)]) + name
                   + struct.pack(">BBii", major, minor, bugfix, build) + b"01-01-2024, 00:00:00")
        truth = self.rig.truth
        body = (struct.pack(">6I", *[0x1234 + i for i in range(6)])
                + b"".join(struct.pack(">6d", *getattr(truth, key)) for key in ("theta", "a", "d", "alpha"))
                + struct.pack(">I", 1))
        kinematics = struct.pack(">iB", len(body) + 5, 5) + body
        greeting = struct.pack(">iB", len(version) + 5, 20) + version
        if self.kinematics:
            return greeting + struct.pack(">iB", len(kinematics) + 5, 16) + kinematics
        # a controller without the kinematics info: robot state messages with only a robot mode sub-package
        robot_mode = struct.pack(">iB", 5 + 8, 0) + bytes(8)
        return greeting + (struct.pack(">iB", len(robot_mode) + 5, 16) + robot_mode) * 3

    def _run_program(self, program: str) -> None:
        self.log.scripts.append(program)
        with self._lock:
            self._stop_program()  # a new program replaces the running one
            if "def rtde_control" in program or "rtde_cmd" in program:
                self._program_starts_at = time.monotonic() + 0.05

    def _serve_rtde(self, conn: socket.socket) -> None:
        outputs: list[tuple[str, str]] = []
        recipes: dict[int, list[tuple[str, str]]] = {}
        frequency = self.rate
        streamer: threading.Thread | None = None
        streaming = threading.Event()
        send_lock = threading.Lock()

        def send(kind: int, payload: bytes = b"") -> None:
            with send_lock:
                conn.sendall(_packet(kind, payload))

        def stream() -> None:
            period = 1.0 / min(frequency, self.rate)
            if self.native_rate:  # one package per period of emulated time, stamped with its tick
                return stream_native(period)
            next_time = time.monotonic()
            while self._running and streaming.is_set():
                with self._lock:
                    state = self._frozen or self._state()
                if not send_state(state):
                    return
                next_time += period
                time.sleep(max(0.0, next_time - time.monotonic()))

        def stream_native(period: float) -> None:
            clock = self.rig.clock
            tick = int(clock.now() / period) + 1
            while self._running and streaming.is_set():
                clock.sleep(tick * period - clock.now())
                with self._lock:
                    state = self._frozen or self._state(tick * period)
                    dropped = self._dropped_at(tick * period)
                    if clock.now() - tick * period > period / 2:  # sent late: it may reach the client in a burst
                        self.late_packages += 1
                tick += 1
                if not dropped and not send_state(state):
                    return

        def send_state(state: dict[str, Any]) -> bool:
            payload = bytearray(b"\x01")
            for name, kind in outputs:
                value = state.get(name, _ZERO.get(kind, 0))
                fmt = ">" + _FORMATS[kind]
                payload += struct.pack(fmt, *value) if isinstance(value, tuple) else struct.pack(fmt, value)
            try:
                send(U, bytes(payload))
            except OSError:
                return False
            return True

        while self._running:
            size, kind = struct.unpack(">HB", _recv_exact(conn, 3))
            payload = _recv_exact(conn, size - 3)
            if kind == V:
                send(V, b"\x01")
            elif kind == v:
                send(v, struct.pack(">IIII", *self.version))
            elif kind == O:
                (frequency,) = struct.unpack(">d", payload[:8])
                names = [n for n in payload[8:].decode().strip("\x00").split(",") if n]
                types = [VARIABLES.get(n, "NOT_FOUND") for n in names]
                self.log.unknown_variables += [n for n, t in zip(names, types, strict=True) if t == "NOT_FOUND"]
                outputs = list(zip(names, types, strict=True))
                send(O, b"\x01" + ",".join(types).encode())
            elif kind == I:
                names = [n for n in payload.decode().strip("\x00").split(",") if n]
                types = [VARIABLES.get(n, "NOT_FOUND") if n.startswith("input") or n in _UINT8 or n in _DOUBLES
                         or n in _V6 or n in _UINT32 else "NOT_FOUND" for n in names]
                recipe_id = len(recipes) + 1
                recipes[recipe_id] = list(zip(names, types, strict=True))
                send(I, bytes([recipe_id]) + ",".join(types).encode())
            elif kind == S:
                streaming.set()
                send(S, b"\x01")
                if streamer is None or not streamer.is_alive():
                    streamer = threading.Thread(target=stream, daemon=True)
                    streamer.start()
            elif kind == P:
                streaming.clear()
                send(P, b"\x01")
            elif kind == U:
                recipe = recipes.get(payload[0])
                if recipe is None:
                    continue
                offset, values = 1, {}
                for name, kind_ in recipe:
                    fmt = ">" + _FORMATS.get(kind_, "i")
                    item = struct.unpack_from(fmt, payload, offset)
                    offset += struct.calcsize(fmt)
                    values[name] = item[0] if len(item) == 1 else item
                with self._lock:
                    self._inputs.update(values)
        streaming.clear()
