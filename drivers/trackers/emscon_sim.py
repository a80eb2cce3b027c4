"""The simulated Leica emScon server: the TPI's binary packets on loopback TCP, answered from a simulated rig's true TP.

It serves ``--tracker emscon:sim`` (mock mode: drivers/trackers/emscon.py starts one per tracker, on the mock
robot's rig) and the tests (tests/emscon_device.py; tests/drivers/trackers/test_emscon_cesapi.py checks it against the
independent CESAPI client). It speaks the subset a calibration needs: GetSystemStatus, Initialize, Set/GetUnits,
Set/GetCoordinateSystemType (right-handed rectangular only; others: status 2, not implemented),
Set/GetSystemSettings, Set/GetEnvironmentParams, GetReflectors / Set/GetReflector, Set/GetMeasurementMode
(stationary only), Set/GetStationaryModeParams, StartMeasurement (answer, then one ``ES_DT_SingleMeasResult`` after
the measurement time on the rig's clock), GetTrackerStatus, GetSystemSoftwareVersion; any other command is answered
with status 2 (not implemented).

What it starts with, so that a client that assumes anything gets wrong numbers: millimetres, the system settings
applying a transformation (every point shifted by :data:`SHIFT`), no unsolicited messages, reflector id 1 of
:data:`REFLECTORS` selected, 20 degC / 1013.25 mbar / 50 %RH. Status changes (``ES_DT_SystemStatusChange``) are
sent after every accepted Set command and around faults, once the client has turned unsolicited messages on.

Faults (``inject(name, count)``: the next ``count`` StartMeasurement commands; ``faults=`` of the constructor, or
``emscon:sim?fault=NAME[@N][xK],...``: from measurement N, 1-based over the server's life): ``beam_broken`` (status
change "not ready", then the answer with status 10004; the next measurement that works sends "ready" first),
``lost_during`` (answer OK, then an ``ES_DT_Error`` packet: status 10009, no stationary result), ``warming_up``
(status 10012), ``not_ready`` (status 10014), ``garbage`` (answer OK, then 40 bytes that are no packet),
``silence`` (no answer), ``drop`` (the server closes the connection), ``split`` (the result arrives in three
pieces 10 ms apart: must still parse).
"""

from __future__ import annotations

import re
import socket
import struct
import threading
import time
from typing import Any

import numpy as np

from drivers.trackers import emscon_protocol as es

EMSCON_FAULTS = ("beam_broken", "lost_during", "warming_up", "not_ready", "garbage", "silence", "drop", "split")
SHIFT = (0.5, -0.2, 0.1)  # m: the transformation the server applies until the client switches it off
#: (id, target type, surface offset m, name) of the reflectors the server knows
REFLECTORS = ((1, 5, 0.01905, "RRR 1.5in"), (2, 6, 0.00635, "RRR 0.5in"), (3, 9, 0.00635, "TBR 0.5in"))
LENGTH_SCALE = {0: 1.0, 1: 1e3, 2: 1e6, 3: 1 / 0.3048, 4: 1 / 0.9144, 5: 1 / 0.0254}  # per metre, ES_LengthUnit
VERSION = (3, 6, 1234)
SERIAL = 392001


_FAULT = re.compile(r"([a-z_]+)(?:@([0-9]+))?(?:x([0-9]+))?\Z")


def parse_faults(text: str) -> tuple[tuple[str, int, int], ...]:
    """``NAME[@N][xK],...`` -> ((name, at, count), ...) (``at`` 1 without ``@N``); ValueError in one line."""
    out = []
    for item in text.split(","):
        match = _FAULT.match(item)
        if not match or match.group(1) not in EMSCON_FAULTS:
            raise ValueError(f"fault {item!r} must be NAME[@N][xCOUNT] with NAME one of {', '.join(EMSCON_FAULTS)}")
        at, count = int(match.group(2) or 1), int(match.group(3) or 1)
        if at < 1 or count < 1:
            raise ValueError(f"fault {item!r}: numbers start at 1")
        out.append((match.group(1), at, count))
    return tuple(out)


class EmsconSimServer:
    """The emulator (module doc) on ``host``, ``port``; readings are the rig's true TP (``rig.true_point()``, m in
    the tracker frame; ``rig`` is a :class:`drivers.sim.rig.SimulatedRig`) plus Gaussian noise ``noise`` (m per axis),
    reported with ``noise`` as each axis's standard deviation; the measurement time passes on ``rig.clock``.
    ``initialized=False``: the tracker needs an Initialize (which takes ``init_time`` s). ``stop()`` ends it."""

    def __init__(self, rig: Any, *, noise: float = 2e-5, seed: int = 0, initialized: bool = True,
                 init_time: float = 0.05, faults: tuple[tuple[str, int, int], ...] = ()) -> None:
        self.rig = rig
        self.noise, self.init_time = noise, init_time
        self.rng = np.random.default_rng(seed)
        self._server = socket.create_server(("127.0.0.1", 0))
        self.host, self.port = "127.0.0.1", self._server.getsockname()[1]
        self.initialized = initialized
        self.units = (1, 1, 0, 0, 0)
        self.coordinates = es.CS_RHR
        self.settings = (2, 1, 1, 1, 0, 0, 0, 1, 1)
        self.environment = (20.0, 1013.25, 50.0)
        self.reflector = 1
        self.mode = es.MM_STATIONARY
        self.stationary = (1000, 0)
        self.faults: list[str] = []
        self.broken = False  # the beam is broken (a beam_broken fault was answered, no measurement since)
        self.commands: list[int] = []
        self.connections = 0
        self.measurements = 0  # results sent
        self.truths: list[np.ndarray] = []  # the true point (m, tracker frame) of every result sent
        self.started = 0  # StartMeasurement commands so far
        self._schedule = list(faults)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.received = bytearray()
        self._thread = threading.Thread(target=self._serve, daemon=True, name="emscon-sim")
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2.0)

    def __enter__(self) -> EmsconSimServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def change_environment(self, values: tuple[float, float, float]) -> None:
        """The weather station's new reading (degC, mbar, %RH): used from the next result on."""
        self.environment = tuple(float(v) for v in values)  # type: ignore[assignment]

    def inject(self, fault: str, count: int = 1) -> None:
        if fault not in EMSCON_FAULTS:
            raise ValueError(f"unknown fault {fault!r} (known: {', '.join(EMSCON_FAULTS)})")
        with self._lock:
            self.faults.extend([fault] * count)

    # --- serving --------------------------------------------------------------------------------------------

    def _serve(self) -> None:
        self._server.settimeout(0.05)
        while not self._stop.is_set():
            try:
                conn, _ = self._server.accept()
            except TimeoutError:
                continue
            with conn:
                self._serve_connection(conn)
        self._server.close()

    def _serve_connection(self, conn: socket.socket) -> None:
        self.connections += 1
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.settimeout(0.05)
        buffer = b""
        while not self._stop.is_set():
            try:
                data = conn.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                return
            if not data:
                return
            self.received += data
            buffer += data
            while len(buffer) >= 12:
                size, kind = struct.unpack_from("<iI", buffer)
                if size < 12 or size > 4096 or kind != es.DT_COMMAND:
                    return  # not a command stream: hang up, as a server would on a protocol violation
                if len(buffer) < size:
                    break
                packet, buffer = buffer[:size], buffer[size:]
                code = struct.unpack_from("<I", packet, 8)[0]
                if not self._answer(conn, code, packet[12:]):
                    return

    def _answer(self, conn: socket.socket, code: int, payload: bytes) -> bool:
        """Answer one command; False to close the connection."""
        self.commands.append(code)

        def send(data: bytes) -> None:
            conn.sendall(data)

        def ok(body: bytes = b"", change: int | None = None) -> bool:
            send(es.reply(code, 0, body))
            if change is not None and self.settings[4]:
                send(es.status_change(change))
            return True

        def refuse(status: int) -> bool:
            send(es.reply(code, status))
            return True

        if code == es.C_START_MEASUREMENT:
            return self._measure(conn)
        if code == es.C_GET_SYSTEM_STATUS:
            status = es.SystemStatus(0, es.TPS_INITIALIZED if self.initialized else 3, 3, 2, VERSION,
                                     self.settings[0], 0, SERIAL)
            return ok(es.system_status_body(status))
        if code == es.C_INITIALIZE:
            time.sleep(self.init_time)
            self.initialized = True
            return ok()
        if code == es.C_SET_UNITS:
            self.units = struct.unpack("<5I", payload)
            return ok(change=6)
        if code == es.C_GET_UNITS:
            return ok(es.units_body(self.units))
        if code == es.C_SET_COORD_SYS:
            kind = struct.unpack("<I", payload)[0]
            if kind != es.CS_RHR:
                return refuse(2)
            self.coordinates = kind
            return ok(change=12)
        if code == es.C_GET_COORD_SYS:
            return ok(struct.pack("<I", self.coordinates))
        if code == es.C_SET_SYSTEM_SETTINGS:
            self.settings = struct.unpack("<I8i", payload)
            return ok(change=8)
        if code == es.C_GET_SYSTEM_SETTINGS:
            return ok(es.settings_body(self.settings))
        if code == es.C_SET_ENVIRONMENT:
            values = struct.unpack("<3d", payload)
            if not (-20 <= values[0] <= 60 and 500 <= values[1] <= 1200 and 0 <= values[2] <= 100):
                return refuse(57)
            self.environment = values
            return ok(change=2)
        if code == es.C_GET_ENVIRONMENT:
            return ok(es.environment_body(self.environment))
        if code == es.C_GET_REFLECTORS:
            for rid, kind, offset, name in REFLECTORS:
                send(es.reply(code, 0, es.reflector_body(len(REFLECTORS), rid, kind, offset, name)))
            return True
        if code == es.C_SET_REFLECTOR:
            rid = struct.unpack("<i", payload)[0]
            if rid not in [r[0] for r in REFLECTORS]:
                return refuse(4)
            self.reflector = rid
            return ok(change=7)
        if code == es.C_GET_REFLECTOR:
            return ok(struct.pack("<i", self.reflector))
        if code == es.C_SET_MEAS_MODE:
            mode = struct.unpack("<I", payload)[0]
            if mode != es.MM_STATIONARY:
                return refuse(2)
            return ok(change=17)
        if code == es.C_GET_MEAS_MODE:
            return ok(struct.pack("<I", self.mode))
        if code == es.C_SET_STATIONARY:
            self.stationary = struct.unpack("<ii", payload)
            return ok(change=18)
        if code == es.C_GET_STATIONARY:
            return ok(struct.pack("<ii", *self.stationary))
        if code == es.C_GET_TRACKER_STATUS:
            return ok(struct.pack("<I", es.TRACKER_READY if self.initialized and not self.broken else 0))
        if code == es.C_GET_SOFTWARE_VERSION:
            return ok(es.text_field("emScon emulator {}.{}.{}".format(*VERSION)))
        return refuse(2)

    def _measure(self, conn: socket.socket) -> bool:
        with self._lock:
            self.started += 1
            for name, at, count in self._schedule:
                if at == self.started:
                    self.faults.extend([name] * count)
            fault = self.faults.pop(0) if self.faults else None
        unsolicited = bool(self.settings[4])
        code = es.C_START_MEASUREMENT
        if fault == "drop":
            return False
        if fault == "silence":
            return True
        if fault == "beam_broken":
            if unsolicited and not self.broken:
                conn.sendall(es.status_change(es.SSC_NOT_READY))
            self.broken = True
            conn.sendall(es.reply(code, 10004))
            return True
        if fault in ("warming_up", "not_ready"):
            conn.sendall(es.reply(code, 10012 if fault == "warming_up" else 10014))
            return True
        if not self.initialized:
            conn.sendall(es.reply(code, 39))
            return True
        if self.broken:
            self.broken = False
            if unsolicited:
                conn.sendall(es.status_change(es.SSC_READY))
        conn.sendall(es.reply(code, 0))
        if fault == "lost_during":
            conn.sendall(es.error_packet(code, 10009))
            return True
        if fault == "garbage":
            conn.sendall(b"\xff\xff\xff\x7f" + bytes(self.rng.integers(0, 256, 36, dtype=np.uint8)))
            return True
        self.rig.clock.sleep(self.stationary[0] / 1000)  # the stationary measurement's duration
        true = np.asarray(self.rig.true_point(), dtype=float)
        point = true + self.rng.normal(0.0, self.noise, 3)
        if self.settings[1]:
            point = point + np.array(SHIFT)
        scale = LENGTH_SCALE[self.units[0]]
        values = tuple(float(v) for v in point * scale)
        std = (self.noise * scale,) * 3
        packet = es.single_result(values, std, self.environment)  # type: ignore[arg-type]
        self.measurements += 1  # counted before it leaves: a client may read the truth as soon as it has the result
        self.truths.append(true)
        if fault == "split":
            for piece in (packet[:5], packet[5:60], packet[60:]):
                conn.sendall(piece)
                time.sleep(0.01)
        else:
            conn.sendall(packet)
        return True
