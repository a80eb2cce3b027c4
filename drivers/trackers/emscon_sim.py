"""The simulated Leica emScon server: the TPI's binary packets on loopback TCP, answered from a simulated rig's true TP.

It serves ``--tracker emscon:sim`` (mock mode: drivers/trackers/emscon.py starts one per tracker, on the mock
robot's rig) and the tests (tests/emscon_device.py; tests/drivers/trackers/test_emscon_cesapi.py checks it against the
independent CESAPI client). It speaks the subset a calibration needs: GetSystemStatus, Initialize, Set/GetUnits,
Set/GetCoordinateSystemType (right-handed rectangular only; others: status 2, not implemented),
Set/GetSystemSettings, Set/GetEnvironmentParams, GetReflectors / Set/GetReflector, Set/GetMeasurementMode
(stationary, continuous by time, 6-DoF stationary), Set/GetStationaryModeParams, Set/GetContinuousTimeModeParams,
StartMeasurement (stationary: the answer, then one ``ES_DT_SingleMeasResult`` after the measurement time on the
rig's clock; continuous: the answer, then ``ES_DT_MultiMeasResult`` packets; 6-DoF stationary: one
``ES_DT_StationaryProbeMeasResult``; 6-DoF continuous by time: ``ES_DT_ContinuousProbeMeasResult`` packets as the
continuous ones), StopMeasurement, GetTrackerStatus,
GetSystemSoftwareVersion; any other command is answered with status 2 (not implemented).

6-DoF probe (T-Mac class): the probe's frame is the rig's first target frame (``rig.true_frames``: a fixed frame
on the flange, the mock's 6-DoF target; the flange's own axes on a rig without one) with its origin, the measuring
tip, at the TP; the tip has the positions' noise, the orientation is turned by a random rotation of ``angle_noise``
rad per axis (stated as each rotation angle's deviation); the quaternion (q0 scalar first) takes probe-frame vectors
to the tracker frame (drivers/trackers/emscon_6dof.py: the reading this client infers).

Continuous by time: the points are the rig's true TP at times ``lTimeSeparation`` ms apart on the rig's clock (the
first at the StartMeasurement), each with the noise; every :data:`PACKET_PERIOD` s of that clock the points due so
far leave in one packet (about 10 packets per second, as the TPI's TCP data packet rate allows: 3 to 10), and
StopMeasurement sends the last ones before its answer. A point's ``lTime1``, ``lTime2`` are whole seconds and
microseconds of the tracker's own clock: ``(1 + drift)·(τ − boot)`` at the point's rig time τ, where the tracker
booted :data:`UPTIME` s before the server started (``drift`` of the constructor, default 0); the stamp is when the
point was taken.

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
pieces 10 ms apart: must still parse), ``pose_invalid`` (a 6-DoF result whose rotation status says error: too few
LEDs seen).

Faults during a continuous measurement (``inject`` or ``fault=NAME[@N][xK]``, ``@N`` counting the continuous result
packets over the server's life): ``stream_lost`` (the beam breaks: status change "not ready", an ``ES_DT_Error``
packet for StartMeasurement with status 10004, the measurement ends; the next K StartMeasurement commands are
answered 10004 as a ``beam_broken``), ``stream_prism`` (the next K packets' points have status 3, prism error),
``stream_garbage`` (40 bytes that are no packet instead of the packet's), ``stream_drop`` (the server closes the
connection), ``stream_silence`` (the link goes silent: no packet and no answer until the client closes it),
``stream_error`` (an ``ES_DT_Error`` packet for StartMeasurement with status 36, unknown error: the measurement ends,
and nothing says the beam is the cause). On the
mock's virtual clock the client's waits (a relock every 0.2 s, the silence timeout, a reconnect) are wall time, during
which the virtual clock runs on: such a fault costs a larger part of a sweep there than on a real tracker.
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from drivers.trackers import emscon_protocol as es
from drivers.trackers import emscon_server as served
from drivers.trackers.emscon_server import EMSCON_FAULTS, STREAM_FAULTS
from drivers.trackers.socket_reads import accept_each

PACKET_PERIOD = 0.1  # s of the rig's clock between continuous result packets
UPTIME = 5000.25  # s the tracker's clock had run when the server started (its stamps' origin is its boot)
SHIFT = (0.5, -0.2, 0.1)  # m: the transformation the server applies until the client switches it off
#: (id, target type, surface offset m, name) of the reflectors the server knows
REFLECTORS = ((1, 5, 0.01905, "RRR 1.5in"), (2, 6, 0.00635, "RRR 0.5in"), (3, 9, 0.00635, "TBR 0.5in"))
LENGTH_SCALE = {0: 1.0, 1: 1e3, 2: 1e6, 3: 1 / 0.3048, 4: 1 / 0.9144, 5: 1 / 0.0254}  # per metre, ES_LengthUnit
VERSION = (3, 6, 1234)
SERIAL = 392001




class EmsconSimServer:
    """The emulator (module doc) on ``host``, ``port``; readings are the rig's true TP (``rig.true_point()``, m in
    the tracker frame; ``rig`` is a :class:`drivers.sim.rig.SimulatedRig`) plus Gaussian noise ``noise`` (m per axis),
    reported with ``noise`` as each axis's standard deviation; the measurement time passes on ``rig.clock``.
    ``initialized=False``: the tracker needs an Initialize (which takes ``init_time`` s); ``drift``: the tracker
    clock's relative drift (continuous stamps, module doc); ``angle_noise``: rad per axis of a 6-DoF probe's
    orientation. ``stop()`` ends it."""

    def __init__(self, rig: Any, *, noise: float = 2e-5, seed: int = 0, initialized: bool = True,
                 init_time: float = 0.05, faults: tuple[tuple[str, int, int], ...] = (), drift: float = 0.0,
                 angle_noise: float = 2e-5) -> None:
        self.rig = rig
        self.noise, self.init_time, self.drift, self.angle_noise = noise, init_time, drift, angle_noise
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
        self.continuous = (100, 0, 0, 0)  # lTimeSeparation ms, lNumberOfPoints, bUseRegion, regionType
        self.boot = rig.clock.now() - UPTIME  # rig time at which the tracker's clock read 0
        self.faults: list[str] = []
        self.stream_faults: list[str] = []
        self.broken = False  # the beam is broken (a beam_broken fault was answered, no measurement since)
        self.commands: list[int] = []
        self.connections = 0
        self.measurements = 0  # results sent
        self.truths: list[np.ndarray] = []  # the true point (m, tracker frame) of every result sent
        self.started = 0  # StartMeasurement commands so far
        self.packets = 0  # continuous result packets so far (sent or replaced by a fault)
        self.probe_truths: list[np.ndarray] = []  # the true pose (4x4, tracker <- probe) of every 6-DoF result sent
        self.streamed: list[tuple[float, np.ndarray]] = []  # (rig time, true point m) of every streamed point sent
        self._schedule = list(faults)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._link: served.Link | None = None
        self.received = bytearray()
        self._thread = threading.Thread(target=accept_each, args=(self._server, self._serve_connection, self._stop),
                                        daemon=True, name="emscon-sim")
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
        """``fault`` on the next ``count`` StartMeasurement commands, or for a ``stream_`` fault the next
        continuous result packets (module doc)."""
        if fault not in EMSCON_FAULTS:
            raise ValueError(f"unknown fault {fault!r} (known: {', '.join(EMSCON_FAULTS)})")
        with self._lock:
            (self.stream_faults if fault in STREAM_FAULTS else self.faults).extend([fault] * count)

    def tracker_time(self, tau: float | np.ndarray) -> float | np.ndarray:
        """The tracker clock's reading (s) at rig time ``tau`` (s)."""
        return (1.0 + self.drift) * (np.asarray(tau) - self.boot)

    # --- serving --------------------------------------------------------------------------------------------

    def _serve_connection(self, conn: socket.socket) -> None:
        self.connections += 1
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.settimeout(0.05)
        link = self._link = served.Link(conn)
        buffer = b""
        try:
            while not self._stop.is_set() and not link.closed:
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
                    if not self._answer(link, code, packet[12:]):
                        return
        finally:
            self._end_stream(link, flush=False)

    def _answer(self, link: served.Link, code: int, payload: bytes) -> bool:
        """Answer one command; False to close the connection."""
        self.commands.append(code)
        send = link.send

        def ok(body: bytes = b"", change: int | None = None) -> bool:
            send(served.reply(code, 0, body))
            if change is not None and self.settings[4]:
                send(served.status_change(change))
            return True

        def refuse(status: int) -> bool:
            send(served.reply(code, status))
            return True

        if code == es.C_START_MEASUREMENT:
            return self._measure(link)
        if code == es.C_STOP_MEASUREMENT:
            self._end_stream(link, flush=True)
            return ok()
        if link.measuring:
            return refuse(1)  # server busy: the continuous measurement runs
        if code == es.C_GET_SYSTEM_STATUS:
            status = es.SystemStatus(0, es.TPS_INITIALIZED if self.initialized else 3, 3, 2, VERSION,
                                     self.settings[0], 0, SERIAL)
            return ok(served.system_status_body(status))
        if code == es.C_INITIALIZE:
            time.sleep(self.init_time)
            self.initialized = True
            return ok()
        if code == es.C_SET_UNITS:
            self.units = struct.unpack("<5I", payload)
            return ok(change=6)
        if code == es.C_GET_UNITS:
            return ok(served.units_body(self.units))
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
            return ok(served.settings_body(self.settings))
        if code == es.C_SET_ENVIRONMENT:
            values = struct.unpack("<3d", payload)
            if not (-20 <= values[0] <= 60 and 500 <= values[1] <= 1200 and 0 <= values[2] <= 100):
                return refuse(57)
            self.environment = values
            return ok(change=2)
        if code == es.C_GET_ENVIRONMENT:
            return ok(served.environment_body(self.environment))
        if code == es.C_GET_REFLECTORS:
            for rid, kind, offset, name in REFLECTORS:
                send(served.reply(code, 0, served.reflector_body(len(REFLECTORS), rid, kind, offset, name)))
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
            if mode not in (es.MM_STATIONARY, es.MM_CONTINUOUS_TIME, es.MM_6D_STATIONARY, es.MM_6D_CONTINUOUS_TIME):
                return refuse(2)
            self.mode = mode
            return ok(change=17)
        if code == es.C_GET_MEAS_MODE:
            return ok(struct.pack("<I", self.mode))
        if code == es.C_SET_STATIONARY:
            self.stationary = struct.unpack("<ii", payload)
            return ok(change=18)
        if code == es.C_GET_STATIONARY:
            return ok(struct.pack("<ii", *self.stationary))
        if code == es.C_SET_CONTINUOUS_TIME:
            separation, points, use_region, region = struct.unpack("<iiiI", payload)
            if separation < 1 or points < 0 or use_region:  # regions are not emulated
                return refuse(4 if separation < 1 else 5 if points < 0 else 6)
            self.continuous = (separation, points, use_region, region)
            return ok(change=19)
        if code == es.C_GET_CONTINUOUS_TIME:
            return ok(struct.pack("<iiiI", *self.continuous))
        if code == es.C_GET_TRACKER_STATUS:
            return ok(struct.pack("<I", es.TRACKER_READY if self.initialized and not self.broken else 0))
        if code == es.C_GET_SOFTWARE_VERSION:
            return ok(served.text_field("emScon emulator {}.{}.{}".format(*VERSION)))
        return refuse(2)

    def _measure(self, link: served.Link) -> bool:
        with self._lock:
            self.started += 1
            for name, at, count in self._schedule:
                if at == self.started and name not in STREAM_FAULTS:
                    self.faults.extend([name] * count)
            fault = self.faults.pop(0) if self.faults else None
        unsolicited = bool(self.settings[4])
        code = es.C_START_MEASUREMENT
        send = link.send
        if link.measuring:
            send(served.reply(code, 1))  # server busy: one measurement at a time
            return True
        self._end_stream(link, flush=False)  # one that ended by itself (beam lost, count reached)
        if fault == "drop":
            return False
        if fault == "silence":
            return True
        if fault == "beam_broken":
            if unsolicited and not self.broken:
                send(served.status_change(es.SSC_NOT_READY))
            self.broken = True
            send(served.reply(code, 10004))
            return True
        if fault in ("warming_up", "not_ready"):
            send(served.reply(code, 10012 if fault == "warming_up" else 10014))
            return True
        if not self.initialized:
            send(served.reply(code, 39))
            return True
        if self.broken:
            self.broken = False
            if unsolicited:
                send(served.status_change(es.SSC_READY))
        send(served.reply(code, 0))
        if self.mode in (es.MM_CONTINUOUS_TIME, es.MM_6D_CONTINUOUS_TIME):
            link.stream = served.Stream(self.rig.clock.now(), self.continuous[0] / 1000, self.continuous[1],
                                  self.mode == es.MM_6D_CONTINUOUS_TIME)
            link.thread = threading.Thread(target=self._stream_loop, args=(link,), daemon=True,
                                           name="emscon-sim-stream")
            link.thread.start()
            return True
        if fault == "lost_during":
            send(served.error_packet(code, 10009))
            return True
        if self.mode == es.MM_6D_STATIONARY:
            return self._probe(link, fault == "pose_invalid")
        if fault == "garbage":
            send(b"\xff\xff\xff\x7f" + bytes(self.rng.integers(0, 256, 36, dtype=np.uint8)))
            return True
        self.rig.clock.sleep(self.stationary[0] / 1000)  # the stationary measurement's duration
        true = np.asarray(self.rig.true_point(), dtype=float)
        values, std = self._reported(true[None, :])
        packet = served.single_result(tuple(values[0]), tuple(std), self.environment)  # type: ignore[arg-type]
        self.measurements += 1  # counted before it leaves: a client may read the truth as soon as it has the result
        self.truths.append(true)
        if fault == "split":
            for piece in (packet[:5], packet[5:60], packet[60:]):
                send(piece)
                time.sleep(0.01)
        else:
            send(packet)
        return True

    def _probe(self, link: served.Link, invalid: bool = False) -> bool:
        """A 6-DoF stationary result (module doc); ``invalid``: its rotation status says error (bits 0, 1, 2:
        valid, error, not enough LEDs)."""
        self.rig.clock.sleep(self.stationary[0] / 1000)
        pose = self.probe_pose()
        values, std = self._reported(pose[None, :3, 3])
        quaternion = self._turned(pose[None, :3, :3])[0]
        self.measurements += 1  # counted before it leaves, as a stationary result
        self.probe_truths.append(pose)
        angles = tuple(float(a) for a in Rotation.from_quat(np.roll(quaternion, -1)).as_euler("xyz"))
        link.send(served.probe_stationary_result(tuple(values[0]), std, tuple(quaternion), angles,  # type: ignore[arg-type]
                                                 (self.angle_noise,) * 3, self.environment,
                                                 rotation_status=0b111 if invalid else 1))
        return True

    def probe_pose(self, tau: float | None = None) -> np.ndarray:
        """The probe's true pose at rig time ``tau`` (default now): 4x4, tracker frame <- probe frame, m (module
        doc)."""
        pose = np.eye(4)
        frames = getattr(self.rig, "true_frames", None)
        pose[:3, :3] = frames(tau)[0] if frames is not None else np.asarray(self.rig.flange_pose(tau))[:3, :3]
        pose[:3, 3] = self.rig.true_point(tau)
        return pose

    def _turned(self, rotations: np.ndarray) -> np.ndarray:
        """True orientations (k, 3, 3) -> the quaternions (k, 4), q0 scalar first, the probe reports: each turned
        by a random rotation of ``angle_noise`` rad per axis."""
        turn = Rotation.from_rotvec(self.rng.normal(0.0, self.angle_noise, (len(rotations), 3)))
        x, y, z, w = (turn * Rotation.from_matrix(rotations)).as_quat().T
        return np.column_stack([w, x, y, z])

    def _reported(self, true: np.ndarray) -> tuple[np.ndarray, tuple[float, float, float]]:
        """True points (k, 3) m -> what the server reports (k, 3) in its units and settings, and each axis's
        standard deviation in those units."""
        point = true + self.rng.normal(0.0, self.noise, true.shape)
        if self.settings[1]:
            point = point + np.array(SHIFT)
        scale = LENGTH_SCALE[self.units[0]]
        return point * scale, (self.noise * scale,) * 3

    # --- continuous measurement ---------------------------------------------------------------------------

    def _stream_loop(self, link: served.Link) -> None:
        """One packet per PACKET_PERIOD s of the rig's clock (several at once when the clock jumped, as a
        virtual clock does), until the measurement ends."""
        stream = link.stream
        assert stream is not None
        while not (self._stop.is_set() or link.closed or stream.ended.is_set()):
            while self.rig.clock.now() >= stream.last_packet + PACKET_PERIOD and not stream.ended.is_set():
                self._send_points(link, stream, stream.last_packet + PACKET_PERIOD)
                stream.ended_itself = stream.ended.is_set()
            stream.ended.wait(0.002)

    def _send_points(self, link: served.Link, stream: served.Stream, until: float) -> None:
        """One packet of the points due by rig time ``until``, or the packet's fault."""
        stream.last_packet = until
        due = int(np.floor((until - stream.start) / stream.separation + 1e-9)) + 1
        if stream.limit:
            due = min(due, stream.limit)
        k = np.arange(stream.sent, due)
        if not len(k):
            return
        with self._lock:
            self.packets += 1
            for name, at, count in self._schedule:
                if at == self.packets and name in STREAM_FAULTS:
                    self.stream_faults.extend([name] * count)
            fault = self.stream_faults.pop(0) if self.stream_faults else None
            if fault == "stream_lost":  # it and the same ones queued after it: the restarts refused
                refused = 1
                while self.stream_faults and self.stream_faults[0] == "stream_lost":
                    refused += self.stream_faults.pop(0) == "stream_lost"
                self.faults[:0] = ["beam_broken"] * refused
        stream.sent = due
        if stream.limit and due >= stream.limit:
            stream.ended.set()  # lNumberOfPoints taken: the measurement ends after this packet
        if fault == "stream_lost":
            if self.settings[4]:
                link.send(served.status_change(es.SSC_NOT_READY))
            self.broken = True
            link.send(served.error_packet(es.C_START_MEASUREMENT, 10004))
            stream.ended.set()
            return
        if fault == "stream_error":
            link.send(served.error_packet(es.C_START_MEASUREMENT, 36))
            stream.ended.set()
            return
        if fault == "stream_drop":
            link.close()
            return
        if fault == "stream_silence":
            link.muted = True
            return
        if fault == "stream_garbage":
            link.send(b"\xff\xff\xff\x7f" + bytes(self.rng.integers(0, 256, 36, dtype=np.uint8)))
            return
        tau = stream.start + k * stream.separation
        stamp = np.asarray(self.tracker_time(tau))
        seconds = np.floor(stamp)
        micro = np.minimum(np.round((stamp - seconds) * 1e6), 999_999)
        status = np.full(len(k), 3 if fault == "stream_prism" else 0)
        if stream.six_dof:
            poses = np.array([self.probe_pose(float(t)) for t in tau])
            true = poses[:, :3, 3]
            values, std = self._reported(true)
            packet = served.probe_continuous_result(status, seconds, micro, values, std,
                                                    self._turned(poses[:, :3, :3]), self.angle_noise,
                                                    self.environment)
        else:
            true = np.array([self.rig.true_point(float(t)) for t in tau], dtype=float)
            values, _ = self._reported(true)  # the standard statistic mode: no deviations per point
            packet = served.multi_result(status, seconds, micro, values, self.environment)
        if link.send(packet):
            self.streamed.extend(zip(tau.tolist(), true, strict=True))

    def _end_stream(self, link: served.Link, flush: bool) -> None:
        """Stop the continuous measurement of ``link`` (``flush``: its due points sent first, as StopMeasurement
        does)."""
        stream, thread = link.stream, link.thread
        if stream is None:
            return
        stream.ended.set()
        if thread is not None:
            thread.join(2.0)
        if flush and not link.closed and not link.muted and not stream.ended_itself:
            self._send_points(link, stream, self.rig.clock.now())
        link.stream, link.thread = None, None
