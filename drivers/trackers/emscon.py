"""Leica emScon client (the TPI of AT4xx / AT9xx laser trackers) over TCP: stationary measurements of one reflector.

Spec form (``--tracker``)::

    emscon:HOST[:PORT][?timeout=S&init_timeout=S&retries=N&meas_time=S&reflector=NAME|ID&initialize=auto|always
                        &probe=none|6dof&temperature=C&pressure=MBAR&humidity=PERCENT&trace=FILE]

``PORT`` defaults to 700 (the emScon server's). ``timeout``: s to wait for one answer (default 3; a measurement
waits ``meas_time`` longer); ``init_timeout``: s an ``Initialize`` may take (default 120); ``retries``: extra
attempts per reading after a dropped connection, a damaged packet or a silent server (default 2); ``meas_time``: the
stationary measurement's duration, s (default 1, set with ``SetStationaryModeParams``); ``reflector``: the
reflector to measure, by its name in the server's list or its id (default: the one selected on the tracker);
``initialize``: ``auto`` initialises the tracker only when ``GetSystemStatus`` says it is not, ``always`` at every
connect; ``temperature`` (°C), ``pressure`` (mbar), ``humidity`` (%RH): environment parameters to set (without
them the server's own, e.g. its weather station's, are read and recorded); ``trace``: a file logging every byte.
The site file's ``tracker.settings`` give the same keys; the spec's options win.

Mock mode: ``emscon:sim[?noise=M&seed=N&fault=NAME[@N][xK],...&...]`` with ``--robot mock:MODEL`` runs this client
against the simulated emScon server of drivers/trackers/emscon_sim.py on loopback, which measures the mock robot's
rig (``noise`` m per axis, default 5e-5; ``angle_noise`` rad per axis of a 6-DoF probe's orientation, default 2e-5;
``seed`` of the noise, default the robot's; ``fault``: the server's
faults from measurement N on); every other option is the real tracker's.

What the client does at connect (drivers/trackers/emscon_protocol.py speaks the packets): ``GetSystemStatus``
(server version, tracker serial number, initialised or not), ``Initialize`` when needed, then everything a reading
depends on is set explicitly and read back: units (metre, radian, °C, mbar, %RH), the coordinate system type (right-
handed rectangular), the system settings (no transformation, no station orientation: readings are in the
tracker's own frame; unsolicited status messages on; no try mode), the environment parameters, the reflector, the
measurement mode (stationary) and its time. The identity (the session header) records all of them.

A reading is one ``StartMeasurement`` answered by a stationary result (X, Y, Z m, their standard deviations; the
timestamp is the host's receive time). Each result carries the environment it was corrected with: when that differs
from the one recorded at connect (the server's weather station moved on), the reading's ``status`` says it
(``ok, environment 20.6 degC, 1012.9 mbar, 48 %RH``), so the session keeps it with the reading.

Faults: a status saying the beam does not reach the reflector (broken beam,
reflector lost: :data:`~drivers.trackers.emscon_protocol.BEAM_STATUSES`) raises TargetLost; one saying the tracker
cannot measure yet (warming up, not initialised, unstable) raises :class:`TrackerNotReady`; both are measurement
errors the orchestrator retries. A dropped connection, a damaged byte stream (BadReading) or a server that stays
silent (DeviceTimeout) closes the link; the reading is then retried on a new connection (set up again as at
connect) up to ``retries`` times, so the step is not lost. Unsolicited status changes are kept in ``events``.

Continuous sweeps (``--mode continuous``): the tracker streams by continuous measurement by time, each point stamped
with the tracker's own time (drivers/trackers/emscon_stream.py: the exchange, the stamps, its faults as gaps).

6-DoF probes (T-Mac class), ``probe=6dof``: every reading is one stationary 6-DoF measurement, a full pose
(drivers/trackers/emscon_probe.py): ``position`` the probe's tip, ``rotvec`` the probe frame's orientation in the
tracker frame, ``sigma`` and ``sigma_r`` the server's deviations; sessions record both (their orientation rows), and
identification uses them. Continuous sweeps measure by continuous 6-DoF measurement by time; their stream carries
the tip's positions and the probe frame's orientations, each point with its deviations (sessions record both in their
streamed rows; drivers/trackers/emscon_stream.py).
:meth:`~drivers.trackers.emscon_probe.ProbeMeasurement.measure_pose` gives one measurement as a 4x4 pose.
"""

from __future__ import annotations

import contextlib
import logging
import math
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

import numpy as np

from drivers.base import DeviceIdentity, TrackerReading, check_measure_request
from drivers.errors import BadReading, ConnectionFailed, DeviceTimeout, MeasurementError, TargetLost
from drivers.spec import TrackerSpec
from drivers.trace import ByteTrace, one_line
from drivers.trackers import emscon_protocol as es
from drivers.trackers.emscon_options import DEFAULT_PORT, parse_settings
from drivers.trackers.emscon_probe import InvalidPose, ProbeMeasurement
from drivers.trackers.emscon_stream import ContinuousMeasurement
from drivers.trackers.socket_reads import receive

#: changes of the environment a result was corrected with (degC, mbar, %RH) that a reading's status reports
ENVIRONMENT_STEP = (0.05, 0.1, 0.5)

__all__ = ["DEFAULT_PORT", "BeamLost", "EmsconStatus", "EmsconTracker", "TrackerNotReady", "open_tracker"]

log = logging.getLogger("drivers.trackers.emscon")


class EmsconStatus(MeasurementError):
    """The server answered a command with a status other than all OK: ``command`` and ``status`` as sent."""

    def __init__(self, message: str, command: int = 0, status: int = 0) -> None:
        super().__init__(message)
        self.command, self.status = command, status


class TrackerNotReady(EmsconStatus):
    """The tracker cannot measure yet (warming up, not initialised, not stable); retry later."""


class BeamLost(EmsconStatus, TargetLost):
    """The beam does not reach the reflector (broken beam, reflector lost); re-lock it on the reflector."""


class EmsconTracker(ContinuousMeasurement, ProbeMeasurement):
    """An emScon server as a tracker (implements :class:`drivers.base.Tracker` and ``StreamingTracker``). After
    :meth:`connect`: ``version`` (server), ``serial`` (tracker), ``environment`` (°C, mbar, %RH in force),
    ``reflector`` (id, name, target type, surface offset m), ``meas_time_ms`` (the stationary measurement time in
    force); ``events`` holds every unsolicited status change (time, text); ``reconnects`` counts links re-opened by
    :meth:`measure` (a stream's: ``stream_counts``). ``probe``: readings are a 6-DoF probe's full poses."""

    def __init__(self, host: str, port: int = DEFAULT_PORT, *, timeout: float = 3.0, init_timeout: float = 120.0,
                 retries: int = 2, meas_time: float = 1.0, reflector: str | None = None, initialize: str = "auto",
                 probe: bool = False, environment: tuple[float, float, float] | None = None,
                 trace_io: str | Path | IO[str] | None = None, simulator: Callable[[], Any] | None = None) -> None:
        if initialize not in ("auto", "always"):
            raise ValueError(f"initialize must be auto or always, got {initialize!r}")
        self.host, self.port = host, port
        self.reply_timeout, self.init_timeout, self.retries = float(timeout), float(init_timeout), int(retries)
        self.meas_time_ms = round(meas_time * 1000)
        self.wanted_reflector, self.initialize, self.wanted_environment = reflector, initialize, environment
        self.probe = bool(probe)
        self._trace = ByteTrace(trace_io)
        self._sock: socket.socket | None = None
        self._buffer = b""
        self._connected_once = False
        self.version = ""
        self.serial = ""
        self.environment: tuple[float, float, float] = (math.nan, math.nan, math.nan)
        self.recorded_environment = self.environment
        self.reflector: tuple[int, str, str, float] = (0, "", "", 0.0)
        self.initialized_by_us = False
        self.events: list[tuple[float, str]] = []
        self.meas_status = ""  # the last measurement status change: ready, busy, not ready
        self.reconnects = 0
        self._simulator, self.server = simulator, None  # emscon:sim: starts the simulated server at connect
        self.measurement_mode = es.MM_STATIONARY  # the mode set on the server (stationary, continuous, 6-DoF)
        self._init_stream()

    @property
    def where(self) -> str:
        return f"emscon:{self.host}:{self.port}"

    # --- Tracker ----------------------------------------------------------------------------------------------

    def connect(self, timeout: float) -> None:
        """Open the link and set the tracker up (module doc); ConnectionFailed in one line when it cannot be."""
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout!r}")
        if self._simulator is not None and self.server is None:
            self.server = self._simulator()
            self.port = self.server.port
        self._trace.open()
        self._open(time.monotonic() + timeout)
        self._connected_once = True

    def close(self) -> None:
        self.stop_stream(self.reply_timeout)
        self._drop()
        self._connected_once = False  # a closed tracker measures again only after connect()
        self._trace.close()
        server, self.server = self.server, None
        if server is not None:
            server.stop()

    def identity(self) -> DeviceIdentity:
        rid, name, kind, offset = self.reflector
        t, p, h = self.recorded_environment
        details = {"address": self.where, "protocol": "emScon TPI", "units": "m, rad, degC, mbar, %RH",
                   "coordinate_system": "right-handed rectangular, tracker frame (no transformation, no station "
                                        "orientation)",
                   "reflector": f"{name} (id {rid}, {kind}, surface offset {offset:g} m)",
                   "environment": f"{t:g} degC, {p:g} mbar, {h:g} %RH"
                                  + (" (set)" if self.wanted_environment else " (the server's)"),
                   "measurement": (f"6-DoF probe (tip position and orientation), stationary, {self.meas_time_ms} ms"
                                   if self.probe else f"stationary, {self.meas_time_ms} ms"),
                   "initialized": "by this client" if self.initialized_by_us else "already"}
        model = "Leica emScon tracker"
        if self.server is not None:
            model += " (simulated: emscon:sim)"
            details["noise"] = f"{self.server.noise:g}"
            if self.probe:
                details["angle_noise"] = f"{self.server.angle_noise:g}"
        return DeviceIdentity("tracker", model, serial=self.serial, firmware=self.version, details=details)

    def measure(self, count: int, timeout: float) -> list[TrackerReading]:
        """``count`` stationary readings of the reflector (m, tracker frame; ``sigma`` the RMS of the server's
        three standard deviations, m per axis; ``timestamp`` the host's receive time), or with ``probe`` of the
        6-DoF probe (full poses: module doc); ``timeout`` bounds the call.
        Raises BeamLost (a TargetLost), TrackerNotReady, BadReading, DeviceTimeout, ConnectionFailed (module doc)."""
        check_measure_request(count, timeout)
        if not self._connected_once:
            raise ConnectionFailed(f"emScon tracker {self.where} is not connected (call connect())")
        self._refuse_while_streaming(f"emScon tracker {self.where}")
        deadline = time.monotonic() + timeout
        return [self._one_reading(deadline) for _ in range(int(count))]

    # --- readings -----------------------------------------------------------------------------------------

    def _one_reading(self, deadline: float) -> TrackerReading:
        last: Exception | None = None
        attempts = 0
        for _ in range(self.retries + 1):
            attempts += 1
            try:
                if self._sock is None:
                    self.reconnects += 1
                    self._trace.event("reconnecting")
                    self._open(deadline)
                if self.probe:
                    return self._probe_reading(deadline)
                if self.measurement_mode != es.MM_STATIONARY:  # after a continuous or 6-DoF one on this link
                    self._call(es.set_measurement_mode(es.MM_STATIONARY), es.C_SET_MEAS_MODE, deadline)
                    self.measurement_mode = es.MM_STATIONARY
                return self._stationary(deadline)
            except (EmsconStatus, InvalidPose):
                raise  # the tracker's own state: nothing a new link repairs
            except (ConnectionFailed, BadReading, DeviceTimeout) as exc:
                last = exc
                self._drop()  # out of step, silent or gone: the next attempt starts on a fresh link
                self._trace.event(f"retry after: {exc}")
                log.warning("%s", exc)
            if time.monotonic() >= deadline:
                break
        assert last is not None
        raise type(last)(f"{last} (after {attempts} attempt{'s' if attempts > 1 else ''})") from last

    def _stationary(self, deadline: float) -> TrackerReading:
        self._call(es.command(es.C_START_MEASUREMENT), es.C_START_MEASUREMENT, deadline)
        wait = min(deadline, time.monotonic() + self.meas_time_ms / 1000 + self.reply_timeout)
        while True:
            packet = self._packet(wait, "StartMeasurement's result")
            if isinstance(packet, es.SingleResult):
                break
            if isinstance(packet, es.ErrorPacket) and packet.command in (es.C_START_MEASUREMENT, 0):
                raise self._status_error(es.C_START_MEASUREMENT, packet.status)
            self._other(packet)
        stamp = time.time()
        if packet.status != 0:
            raise self._status_error(es.C_START_MEASUREMENT, packet.status)
        values = np.array(packet.values, dtype=float)
        if not np.all(np.isfinite(values)) or np.abs(values).max() > 1e4:
            raise BadReading(f"{self.where}: a measurement result of {values.tolist()} m is not a position")
        std = np.array(packet.std, dtype=float)
        sigma = float(np.sqrt(np.mean(std**2))) if np.all(np.isfinite(std)) and std.max() > 0 else None
        status = self._environment_status((packet.temperature, packet.pressure, packet.humidity),
                                          "ok" if not packet.try_mode else "ok, try mode")
        return TrackerReading(values, stamp, sigma, status)

    def _environment_status(self, used: tuple[float, float, float], status: str) -> str:
        """A reading's ``status`` with the environment its result was corrected with (``used``: degC, mbar, %RH)
        when that is not the one recorded at connect (module doc)."""
        if any(abs(a - b) > tol for a, b, tol in zip(used, self.environment, ENVIRONMENT_STEP, strict=True)):
            self.environment = used  # the server's weather station moved on: the readings say so from here on
            self._trace.event(f"environment now {used}")
        if used != self.recorded_environment:
            status += ", environment {:g} degC, {:g} mbar, {:g} %RH".format(*used)
        return status

    # --- set-up -------------------------------------------------------------------------------------------

    def _open(self, deadline: float) -> None:
        self._drop()
        self._trace.event(f"connect {self.where}")
        try:
            self._sock = socket.create_connection((self.host, self.port),
                                                  timeout=max(deadline - time.monotonic(), 0.05))
            self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError as exc:
            raise ConnectionFailed(f"cannot connect to the emScon server {self.where}: {one_line(exc)} (is the "
                                   "server running and reachable?)") from exc
        self._buffer = b""
        try:
            self._set_up(deadline)
        except EmsconStatus as exc:
            self._drop()
            raise ConnectionFailed(f"the emScon server {self.where} refused the set-up: {exc}") from exc

    def _set_up(self, deadline: float) -> None:
        status = es.system_status(self._ask(es.C_GET_SYSTEM_STATUS, deadline))
        self.version = ".".join(str(v) for v in status.version)
        self.serial = str(status.serial)
        if self.initialize == "always" or status.processor != es.TPS_INITIALIZED:
            self._trace.event("initializing the tracker")
            self._call(es.command(es.C_INITIALIZE), es.C_INITIALIZE,
                       max(deadline, time.monotonic() + self.init_timeout))
            self.initialized_by_us = True
        self._call(es.set_units(*es.UNITS_SI), es.C_SET_UNITS, deadline)
        units = es.units(self._ask(es.C_GET_UNITS, deadline))
        self._call(es.set_coordinate_system(es.CS_RHR), es.C_SET_COORD_SYS, deadline)
        coordinates = es.one_int(self._ask(es.C_GET_COORD_SYS, deadline))
        if units != es.UNITS_SI or coordinates != es.CS_RHR:
            raise ConnectionFailed(f"the emScon server {self.where} kept units {units} and coordinate system "
                                   f"{coordinates} after being set to {es.UNITS_SI} and {es.CS_RHR}")
        settings = list(es.system_settings(self._ask(es.C_GET_SYSTEM_SETTINGS, deadline)))
        wanted = [settings[0], 0, 0, settings[3], 1, settings[5], 0, settings[7], settings[8]]
        if settings != wanted:
            self._call(es.set_system_settings(tuple(wanted)), es.C_SET_SYSTEM_SETTINGS, deadline)
        if self.wanted_environment is not None:
            self._call(es.set_environment(*self.wanted_environment), es.C_SET_ENVIRONMENT, deadline)
        self.environment = es.environment(self._ask(es.C_GET_ENVIRONMENT, deadline))
        if not self._connected_once:  # what the session header records (identity); later changes: readings' status
            self.recorded_environment = self.environment
        self._choose_reflector(deadline)
        self._call(es.set_measurement_mode(es.MM_STATIONARY), es.C_SET_MEAS_MODE, deadline)
        self.measurement_mode = es.MM_STATIONARY
        self._call(es.set_stationary_params(self.meas_time_ms), es.C_SET_STATIONARY, deadline)
        time_ms, _ = es.stationary_params(self._ask(es.C_GET_STATIONARY, deadline))
        if time_ms != self.meas_time_ms:
            log.warning("%s measures for %d ms, not the %d ms asked for", self.where, time_ms, self.meas_time_ms)
            self.meas_time_ms = time_ms
        self._trace.event(f"set up: environment {self.environment}, reflector {self.reflector}")

    def _choose_reflector(self, deadline: float) -> None:
        """Select ``wanted_reflector`` (name or id) if given, then record the one in force."""
        entries = [es.reflector_entry(r.body) for r in self._call(es.command(es.C_GET_REFLECTORS), es.C_GET_REFLECTORS,
                                                                    deadline, many=True)]
        wanted = self.wanted_reflector
        if wanted is not None:
            match = [e for e in entries if e.name == wanted or str(e.id) == wanted]
            if not match:
                known = ", ".join(f"{e.name} ({e.id})" for e in entries) or "none"
                raise ConnectionFailed(f"the emScon server {self.where} has no reflector {wanted!r} (reflector=); "
                                       f"known: {known}")
            self._call(es.set_reflector(match[0].id), es.C_SET_REFLECTOR, deadline)
        current = es.one_int(self._ask(es.C_GET_REFLECTOR, deadline))
        entry = next((e for e in entries if e.id == current), None)
        if entry is None:
            raise ConnectionFailed(f"the emScon server {self.where} measures with reflector id {current}, which is "
                                   "not in its own reflector list")
        self.reflector = (entry.id, entry.name, es.TARGET_TYPES.get(entry.target_type, str(entry.target_type)),
                          entry.surface_offset)

    # --- packets ------------------------------------------------------------------------------------------

    def _ask(self, code: int, deadline: float) -> bytes:
        """The data of a parameterless Get command's answer."""
        return self._call(es.command(code), code, deadline)[0].body

    def _call(self, packet: bytes, code: int, deadline: float, many: bool = False) -> list[es.Reply]:
        """Send ``packet`` (command ``code``) and return its answer (``many``: every answer, as GetReflectors
        sends one per reflector, each with the total). EmsconStatus subclasses for a status other than OK."""
        self._send(packet)
        wait = min(deadline, time.monotonic() + self.reply_timeout) if code != es.C_INITIALIZE else deadline
        answers: list[es.Reply] = []
        while True:
            got = self._packet(wait, es.command_name(code))
            if isinstance(got, es.Reply) and got.command == code:
                if got.status != 0:
                    raise self._status_error(code, got.status)
                answers.append(got)
                total = es.reflector_entry(got.body).total if many else 1
                if len(answers) >= total:
                    return answers
            elif isinstance(got, es.ErrorPacket) and got.command in (code, 0):
                raise self._status_error(code, got.status)
            else:
                self._other(got)

    def _other(self, packet: es.Packet) -> None:
        """A packet nobody waits for: status changes are recorded, late answers skipped."""
        if isinstance(packet, es.StatusChange):
            text = str(packet)
            self.events.append((time.time(), text))
            if packet.code in (es.SSC_NOT_READY, es.SSC_BUSY, es.SSC_READY):
                self.meas_status = text
            self._trace.event(f"status change: {text}")
            log.info("%s: %s", self.where, text)
        else:
            self._trace.event(f"skipped {packet}")

    def _status_error(self, code: int, status: int) -> EmsconStatus:
        what = f"{self.where}: {es.command_name(code)} failed: {es.status_text(status)}"
        not_ready = es.STATUS_CHANGE[es.SSC_NOT_READY]
        seen = f" (the server said: {not_ready})" if self.meas_status == not_ready else ""
        if status in es.BEAM_STATUSES:
            return BeamLost(f"{what}: the beam does not reach the reflector (broken beam or reflector lost; "
                            f"re-lock it){seen}", code, status)
        if status in es.NOT_READY_STATUSES:
            return TrackerNotReady(f"{what}: the tracker is not ready to measure (warming up, not initialised or "
                                   f"not stable){seen}", code, status)
        return EmsconStatus(what, code, status)

    def _send(self, data: bytes) -> None:
        if self._sock is None:
            raise ConnectionFailed(f"emScon tracker {self.where} is not connected")
        self._trace.data(">", data)
        try:
            self._sock.sendall(data)
        except OSError as exc:
            self._drop()
            raise ConnectionFailed(f"lost the connection to {self.where}: {one_line(exc)}") from exc

    def _packet(self, deadline: float, what: str) -> es.Packet:
        """The next whole packet, decoded; DeviceTimeout at ``deadline``, BadReading for a damaged stream."""
        while True:
            sock = self._sock
            if sock is None:
                raise ConnectionFailed(f"emScon tracker {self.where} is not connected")
            try:
                packets, rest = es.frame(self._buffer)
            except BadReading as exc:
                raise BadReading(f"{self.where}: {exc}") from None
            if packets:
                self._buffer = b"".join(packets[1:]) + rest
                try:
                    return es.decode(packets[0])
                except BadReading as exc:
                    raise BadReading(f"{self.where}: {exc}") from None
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceTimeout(f"{self.where}: no answer to {what} within the timeout ({self.reply_timeout:g} s "
                                    "per answer)")
            chunk = receive(sock, remaining, self.where, "the emScon server", self._drop)
            if chunk is None:
                continue
            self._trace.data("<", chunk)
            self._buffer += chunk

    def _drop(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.close()
            self._trace.event("disconnected")


def open_tracker(spec: TrackerSpec | str, rig: Any = None, site: Any = None, *,
                 trace_io: str | Path | IO[str] | None = None) -> EmsconTracker:
    """An unconnected :class:`EmsconTracker` for ``emscon:HOST[:PORT]?...`` (options: drivers/trackers/
    emscon_options.py); ``rig`` is only for ``emscon:sim`` (the mock robot's), ``site.tracker_settings`` gives
    option defaults, ``trace_io`` overrides the ``trace`` option. SpecError in one line for a bad option."""
    spec = spec if isinstance(spec, TrackerSpec) else TrackerSpec.parse(spec)
    settings = parse_settings(spec, site)
    simulator = settings.simulator(spec, rig) if settings.simulated else None
    return EmsconTracker(settings.host, settings.port, timeout=settings.timeout, init_timeout=settings.init_timeout,
                         retries=settings.retries, meas_time=settings.meas_time, reflector=settings.reflector,
                         initialize=settings.initialize, probe=settings.probe, environment=settings.environment,
                         trace_io=trace_io if trace_io is not None else settings.trace, simulator=simulator)
