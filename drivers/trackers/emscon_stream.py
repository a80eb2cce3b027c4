"""Continuous measurement by time for the emScon client (implements :class:`drivers.base.StreamingTracker` for
:class:`drivers.trackers.emscon.EmsconTracker`, which inherits this mixin).

The exchange (drivers/trackers/emscon_protocol.py): ``SetMeasurementMode(ContinuousTime)``,
``SetContinuousTimeModeParams`` (the time separation, 1 / the rate asked, in whole milliseconds, at least 1; no end,
no region) read back with ``GetContinuousTimeModeParams``, then ``StartMeasurement``: the server answers, then sends
continuous result packets of the points measured since the last one until ``StopMeasurement``. A reader thread owns
the link while the stream runs (``measure`` is refused); ``stop_stream`` has it send ``StopMeasurement`` and read
up to its answer, so the last points are kept. The next stationary measurement sets the stationary mode again.
With a 6-DoF probe (``probe=6dof``) the mode is continuous 6-DoF measurement by time
(``ES_DT_ContinuousProbeMeasResult`` packets): the stream carries the tip's positions with each point's stated
deviation as ``sigma`` and the probe frame's orientation, as a stationary reading does
(drivers/trackers/emscon_probe.py): ``rotvec`` from the point's quaternion (rad, tracker frame <- probe frame),
``sigma_r`` the RMS of its rotation angles' deviations (rad; NaN when none is stated). Points whose rotation status
is not valid, or whose quaternion is not of unit length, are left out (as flagged points).

Timestamps: each point carries the tracker's time of the point (``lTime1`` s + ``lTime2`` µs of the tracker's own
clock, read as the public ROS driver ``beckjac/emscon_ros`` reads them); the stream's ``t`` is that time, so the
session's timing model (identify/estimator/sync.py) fits the offset and drift between the tracker's clock and the
controller's, as for a serial tracker with device times. No host receive time enters. The reading is checked on
every packet: microseconds outside [0, 10^6), or points of one packet not one time separation apart (median step
off by more than :data:`STEP_TOLERANCE`), stop the stream with :class:`StampError` (a ConnectionFailed: the sweep
stops) in one line (use --mode step) instead of mis-timing it.

Faults, as gaps ``(t_before, t_after)`` in tracker seconds between the good points around them, the stream going on:

- a point whose status is not "all OK" (speed warning or exceeded, prism error: "to be treated with care") is left
  out; a step between points over :data:`GAP_FACTOR` time separations (points the server did not send) is a gap;
- the beam breaks (status change "not ready", or an ``ES_DT_Error`` packet saying the beam does not reach the
  reflector, which ends the server's measurement): the reader sends ``StartMeasurement`` again every
  :data:`RELOCK_PERIOD` s until the server answers all OK (the beam is back on the reflector);
- the link drops, the bytes fall out of step (garbage), or the server stays silent for the answer timeout while
  measuring: the reader opens a new link, sets it up as at connect, and starts the continuous measurement again
  (``retries`` attempts in a row; then the stream fails with ConnectionFailed, which ends the sweep resumable).

``stream_counts`` counts points, flagged points, gaps, beam losses, relock attempts and reconnects of the stream.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from drivers.base import TrackerStreamBatch
from drivers.errors import BadReading, ConnectionFailed, DeviceTimeout, DriverError
from drivers.stream_buffer import BufferedStreaming
from drivers.trace import one_line
from drivers.trackers import emscon_protocol as es
from drivers.trackers.emscon_options import continuous_separation
from drivers.trackers.emscon_probe import UNIT

GAP_FACTOR = 1.5  # a step above this many time separations between kept points is a gap
STEP_TOLERANCE = 0.5  # a packet's median step between points off the separation by more than this: misread stamps
RELOCK_PERIOD = 0.2  # s between StartMeasurement attempts while the beam does not reach the reflector
POLL = 0.05  # s the reader waits for a packet before it checks whether it must stop

log = logging.getLogger("drivers.trackers.emscon")


class StampError(ConnectionFailed):
    """The tracker's point times cannot be read as seconds and microseconds one time separation apart: the stream is
    unusable, as a lost link is (the sweep stops, the run ends resumable; a new session with --mode step works)."""


class ContinuousMeasurement(BufferedStreaming):
    """The streaming half of EmsconTracker (module doc). ``separation_ms``: the time separation in force (ms)."""

    where: str
    retries: int
    reply_timeout: float
    events: list[tuple[float, str]]
    recorded_environment: tuple[float, float, float]
    measurement_mode: int
    probe: bool
    _sock: Any
    _trace: Any
    _connected_once: bool
    _call: Any
    _ask: Any
    _send: Any
    _packet: Any
    _open: Any
    _drop: Any
    _other: Any
    _status_error: Any

    def _init_stream(self) -> None:
        self._init_buffer()
        self.separation_ms = getattr(self, "separation_ms", 0)
        self.stream_counts = {"points": 0, "flagged": 0, "gaps": 0, "beam_lost": 0, "relocks": 0, "reconnects": 0}

    def start_stream(self, rate: float, timeout: float) -> float:
        """Start a continuous measurement of one point every 1 / ``rate`` s (rounded to whole ms, at least 1);
        returns the rate the server took (Hz). A broken beam at the start is a stream that begins once the beam
        is back (module doc); ConnectionFailed or an EmsconStatus (one line) when the server refuses the mode."""
        if not (rate > 0 and timeout > 0):
            raise ValueError(f"rate and timeout must be > 0, got {rate!r} Hz and {timeout!r} s")
        if not self._connected_once:
            raise ConnectionFailed(f"emScon tracker {self.where} is not connected (call connect())")
        self.stop_stream(timeout)
        self._init_stream()
        self._environment_seen = self.recorded_environment
        deadline = time.monotonic() + timeout
        if self._sock is None:
            self._open(deadline)
        lost = self._begin(continuous_separation(rate), deadline)
        self._reader = threading.Thread(target=self._read_loop, args=(lost,), daemon=True,
                                        name=f"emscon-stream-{self.where}")
        self._reader.start()
        return 1000.0 / self.separation_ms

    def stop_stream(self, timeout: float) -> TrackerStreamBatch:
        """Stop the measurement (the reader sends StopMeasurement and reads up to its answer); returns the points
        since the last read."""
        return self._stop_reader(max(timeout, self.reply_timeout + POLL))

    # --- set-up -------------------------------------------------------------------------------------------

    def _begin(self, separation_ms: int, deadline: float) -> bool:
        """Continuous mode, its time separation (read back), StartMeasurement; True when the beam does not reach
        the reflector yet (the measurement did not start)."""
        mode = es.MM_6D_CONTINUOUS_TIME if self.probe else es.MM_CONTINUOUS_TIME
        self._call(es.set_measurement_mode(mode), es.C_SET_MEAS_MODE, deadline)
        self.measurement_mode = mode
        self._call(es.set_continuous_time_params(separation_ms), es.C_SET_CONTINUOUS_TIME, deadline)
        taken = es.continuous_time_params(self._ask(es.C_GET_CONTINUOUS_TIME, deadline))[0]
        if taken != separation_ms:
            log.warning("%s measures every %d ms, not the %d ms asked for", self.where, taken, separation_ms)
        if taken < 1:
            raise ConnectionFailed(f"the emScon server {self.where} reports a time separation of {taken} ms")
        self.separation_ms = taken
        try:
            self._call(es.command(es.C_START_MEASUREMENT), es.C_START_MEASUREMENT, deadline)
        except DriverError as exc:
            if getattr(exc, "status", None) in es.BEAM_STATUSES | es.NOT_READY_STATUSES:
                self._trace.event(f"continuous measurement waits for the beam: {exc}")
                return True
            raise
        return False

    # --- the reader thread --------------------------------------------------------------------------------

    def _read_loop(self, lost: bool) -> None:
        self._last_t: float | None = None
        self._broken = lost  # points missing since the last kept one
        self._lost = lost  # the measurement stopped on a broken beam: restart it
        next_relock = 0.0
        heard = time.monotonic()
        failures = 0  # links that failed in a row
        while True:
            if self._halt.is_set():
                self._finish()
                return
            try:
                if self._sock is None:
                    self._reconnect()
                    heard = time.monotonic()
                    failures = 0
                    continue
                if self._lost and time.monotonic() >= next_relock:
                    self.stream_counts["relocks"] += 1
                    self._send(es.command(es.C_START_MEASUREMENT))
                    next_relock = time.monotonic() + RELOCK_PERIOD
                try:
                    packet = self._packet(time.monotonic() + POLL, "a continuous result")
                except DeviceTimeout:
                    if time.monotonic() - heard > self.reply_timeout:
                        raise DeviceTimeout(f"{self.where}: silent for {self.reply_timeout:g} s during a continuous "
                                            "measurement") from None
                    continue
                heard = time.monotonic()
                self._take(packet)
            except StampError as exc:  # a new link would read the same stamps
                self._fail(exc)
                return
            except (ConnectionFailed, BadReading, DeviceTimeout) as exc:
                failures += 1
                self._drop()
                self._broken = True
                self.stream_counts["reconnects"] += 1
                self._trace.event(f"stream: {exc}; a new link")
                log.warning("%s", exc)
                if failures > self.retries:
                    self._fail(ConnectionFailed(f"{exc} (continuous measurement, after {failures} attempt"
                                                f"{'s' if failures > 1 else ''})"))
                    return
            except DriverError as exc:  # a status the stream cannot go on with
                self._fail(exc)
                return

    def _reconnect(self) -> None:
        deadline = time.monotonic() + self.reply_timeout
        self._open(deadline)
        self._lost = self._begin(self.separation_ms, deadline)

    def _take(self, packet: es.Packet) -> None:
        if isinstance(packet, es.MultiResult | es.ProbeMultiResult):
            self._points(packet)
        elif isinstance(packet, es.Reply) and packet.command == es.C_START_MEASUREMENT:
            if packet.status == 0:
                self._lost = False
                self._trace.event("stream: measuring again")
            elif packet.status not in es.BEAM_STATUSES | es.NOT_READY_STATUSES:
                raise self._status_error(es.C_START_MEASUREMENT, packet.status)
        elif isinstance(packet, es.ErrorPacket) and packet.command in (es.C_START_MEASUREMENT, 0):
            if packet.status not in es.BEAM_STATUSES | es.NOT_READY_STATUSES:
                raise self._status_error(es.C_START_MEASUREMENT, packet.status)
            if not self._lost:
                self.stream_counts["beam_lost"] += 1
            self._lost = self._broken = True
            self._trace.event(f"stream: {self._status_error(es.C_START_MEASUREMENT, packet.status)}")
        else:
            if isinstance(packet, es.StatusChange) and packet.code == es.SSC_NOT_READY:
                self._broken = True
            self._other(packet)

    def _points(self, packet: es.MultiResult | es.ProbeMultiResult) -> None:
        """Keep the good points of a continuous result (3D or 6-DoF: the tip's), with gaps where points are missing
        or flagged (a 6-DoF point also when its rotation status is not valid)."""
        micro = packet.time2
        if len(micro) and (micro.min() < 0 or micro.max() >= 1_000_000):
            raise StampError(f"{self.where}: a continuous result's point time has lTime2 = "
                             f"{int(micro[(micro < 0) | (micro >= 1_000_000)][0])}, not microseconds: the tracker's "
                             "time stamps cannot be read (use --mode step)")
        t = packet.time1 + micro * 1e-6
        separation = self.separation_ms / 1000.0
        steps = np.diff(t)
        if len(steps) >= 2 and not abs(np.median(steps) - separation) <= STEP_TOLERANCE * separation:
            raise StampError(f"{self.where}: the points of a continuous result are {np.median(steps) * 1e3:.4g} ms "
                             f"apart by their time stamps, not the {self.separation_ms} ms asked: the tracker's "
                             "time stamps cannot be read (use --mode step)")
        values = packet.values
        good = (packet.point_status == 0) & np.all(np.isfinite(values) & (np.abs(values) < 1e4), axis=1)
        turns = None
        if isinstance(packet, es.ProbeMultiResult):
            good &= es.rotation_ok(packet.rotation_status) & _unit(packet.quaternion)
            turns = _orientations(packet, good)
        sigma = (np.sqrt(np.mean(packet.std**2, axis=1)) if packet.std is not None
                 else np.full(len(t), math.nan))
        rows, gaps = [], []
        last, broken = self._last_t, self._broken
        for i in range(len(t)):
            if not good[i]:
                broken = True
                continue
            if last is not None and (broken or not 0 < t[i] - last <= GAP_FACTOR * separation):
                gaps.append((last, float(t[i])))
            rows.append((float(t[i]), *values[i].tolist(), float(sigma[i]))
                        + (() if turns is None else tuple(turns[i].tolist())))
            last, broken = float(t[i]), False
        self._last_t, self._broken = last, broken
        flagged = int((~good).sum())
        with self._stream_lock:
            self._rows.extend(rows)
            self._gaps.extend(gaps)
            self.stream_counts["points"] += len(rows)
            self.stream_counts["flagged"] += flagged
            self.stream_counts["gaps"] += len(gaps)
        if flagged:
            self._trace.event(f"stream: {flagged} point(s) flagged ("
                              + ", ".join(sorted({es.POINT_STATUS.get(int(s), str(int(s))) if s else
                                                  "6-DoF rotation not valid" for s in packet.point_status[~good]}))
                              + ")")
        used = (packet.temperature, packet.pressure, packet.humidity)
        if used != self._environment_seen:  # the server's weather station moved on: said once per change
            self._environment_seen = used
            text = "environment now {:g} degC, {:g} mbar, {:g} %RH".format(*used)
            self.events.append((time.time(), text))
            self._trace.event(f"stream: {text}")

    def _finish(self) -> None:
        """StopMeasurement and the points up to its answer (a failure here loses nothing already read)."""
        if self._sock is None:
            return
        deadline = time.monotonic() + self.reply_timeout
        try:
            self._send(es.command(es.C_STOP_MEASUREMENT))
            while True:
                packet = self._packet(deadline, "StopMeasurement")
                if isinstance(packet, es.Reply) and packet.command == es.C_STOP_MEASUREMENT:
                    return
                if isinstance(packet, es.MultiResult | es.ProbeMultiResult):
                    self._points(packet)
                elif not isinstance(packet, es.Reply | es.ErrorPacket):
                    self._other(packet)
        except (DriverError, OSError) as exc:
            self._drop()  # the next use opens a new link, set up as at connect
            self._trace.event(f"StopMeasurement: {one_line(exc)}")

    def _fail(self, exc: Exception) -> None:
        with self._stream_lock:
            self._failure = exc
        self._trace.event(f"stream stopped: {exc}")
        self._finish()



def _unit(quaternion: np.ndarray) -> np.ndarray:
    """Per point (k,): its quaternion (k, 4) is of unit length (within emscon_probe.UNIT): a rotation."""
    return np.abs(np.linalg.norm(quaternion, axis=1) - 1.0) <= UNIT


def _orientations(packet: es.ProbeMultiResult, good: np.ndarray) -> np.ndarray:
    """Per point (k, 4): the probe frame's rotation vector (rad, tracker frame <- probe frame, from the quaternion
    read as q0 scalar first: drivers/trackers/emscon_6dof.py) and ``sigma_r`` (rad, the RMS of the rotation angles'
    stated deviations; NaN when none is stated); NaN rows where ``good`` is False."""
    out = np.full((len(good), 4), math.nan)
    if np.any(good):
        q = packet.quaternion[good]
        out[good, :3] = Rotation.from_quat(np.column_stack([q[:, 1:], q[:, 0]])).as_rotvec()
        spread = packet.angles_std[good]
        stated = np.all(np.isfinite(spread), axis=1) & (np.max(spread, axis=1) > 0)
        out[np.flatnonzero(good)[stated], 3] = np.sqrt(np.mean(spread[stated] ** 2, axis=1))
    return out
