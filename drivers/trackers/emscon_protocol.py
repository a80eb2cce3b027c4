"""The Leica emScon TPI packet format (binary, over TCP): encoders and decoders, pure and byte-level.

Written from the public interface definitions of the emScon TPI (``ES_C_API_Def.h``, TPI 3.6); nothing here does
any I/O (the client: drivers/trackers/emscon.py). Every packet is little-endian with 4-byte packing and starts
with an 8-byte header, ``lPacketSize`` (int32, the whole packet's length in bytes) and ``type``
(:data:`ES_DT`, uint32):

- a command (``type`` 0) from the client: header, ``command`` (uint32), then the command's parameters;
- its answer (``type`` 0): header, ``command``, ``status`` (uint32, :data:`STATUS`; 0 all OK), then the answer's
  data (:data:`REPLY_BODY`: their sizes are fixed, which is how a damaged stream is recognised);
- a stationary result (``type`` 2, :class:`SingleResult`): header, ``status``, ``measMode``, ``bIsTryMode``, then
  17 doubles: the three values, their standard deviations and the total, pointing errors, a-priori standard
  deviations and total, temperature, pressure, humidity (in the units set with ``SetUnits``);
- a continuous result (``type`` 3, :class:`MultiResult`; ``type`` 10 with each point's a-priori deviations):
  header, ``status``, ``lNumberOfResults``, ``measMode``, ``bIsTryMode``, temperature, pressure, humidity (doubles),
  then that many points, each ``status`` (:data:`POINT_STATUS`), ``lTime1``, ``lTime2`` (int32: the tracker's time
  of the point, read as whole seconds and microseconds; below) and its three values (doubles; ``type`` 10 adds 7);
- an error (``type`` 1): header, ``command``, ``status``; a status change (``type`` 8): header, a code
  (:data:`STATUS_CHANGE`), sent by the server unprompted.

Continuous measurement by time (``ES_MM_ContinuousTime``): ``SetContinuousTimeModeParams`` (``lTimeSeparation``
ms between points, ``lNumberOfPoints`` 0 for no end, ``bUseRegion``, ``regionType``), then ``StartMeasurement``:
its answer, then continuous result packets (the server gathers the points of a few hundred milliseconds into each)
until ``StopMeasurement``. The header does not say what ``lTime1`` and ``lTime2`` hold; this client reads them as
seconds and microseconds of the tracker's clock, as the public ROS driver ``beckjac/emscon_ros`` does, and checks the
reading on every packet (drivers/trackers/emscon_stream.py): microseconds within [0, 10^6) and points one time
separation apart, else the stream is refused in one line rather than mis-timed.

6-DoF probe results (T-Mac class: ``type`` 4 and 5) are decoded by drivers/trackers/emscon_6dof.py, which says what
the header verifies of them and what is inferred.

Text fields (reflector names, the software version) are 32 UTF-16LE code units, zero-padded.
"""

from __future__ import annotations

import struct
from dataclasses import astuple, dataclass

import numpy as np

from drivers.errors import BadReading
from drivers.trackers.emscon_6dof import _PROBE_MULTI as _PROBE_MULTI  # the 6-DoF packets, re-exported
from drivers.trackers.emscon_6dof import _PROBE_STATIONARY as _PROBE_STATIONARY
from drivers.trackers.emscon_6dof import ROTATION_ERROR as ROTATION_ERROR
from drivers.trackers.emscon_6dof import ROTATION_FROZEN as ROTATION_FROZEN
from drivers.trackers.emscon_6dof import ROTATION_VALID as ROTATION_VALID
from drivers.trackers.emscon_6dof import ProbeMultiResult as ProbeMultiResult
from drivers.trackers.emscon_6dof import ProbeResult as ProbeResult
from drivers.trackers.emscon_6dof import _probe_point_dtype as _probe_point_dtype
from drivers.trackers.emscon_6dof import probe_continuous_result, probe_stationary_result
from drivers.trackers.emscon_6dof import rotation_ok as rotation_ok

HEADER = struct.Struct("<iI")  # lPacketSize, type
MAX_PACKET = 1 << 18  # bytes: above the longest packet this client reads (a continuous result of 2,800 points)

#: ES_DataType
DT_COMMAND, DT_ERROR, DT_SINGLE, DT_MULTI, DT_NIVEL, DT_REFLECTOR_POS, DT_STATUS_CHANGE = 0, 1, 2, 3, 6, 7, 8
DT_PROBE_STATIONARY, DT_PROBE_CONTINUOUS, DT_SINGLE2, DT_MULTI2 = 4, 5, 9, 10

#: ES_Command values the client and the emulator use
C_GET_SYSTEM_STATUS, C_GET_TRACKER_STATUS, C_SET_UNITS, C_GET_UNITS, C_INITIALIZE = 1, 2, 5, 6, 7
C_SET_ENVIRONMENT, C_GET_ENVIRONMENT = 20, 21
C_SET_MEAS_MODE, C_GET_MEAS_MODE, C_SET_COORD_SYS, C_GET_COORD_SYS = 24, 25, 26, 27
C_SET_STATIONARY, C_GET_STATIONARY, C_SET_CONTINUOUS_TIME, C_GET_CONTINUOUS_TIME = 28, 29, 30, 31
C_SET_REFLECTOR, C_GET_REFLECTOR, C_GET_REFLECTORS = 40, 41, 42
C_SET_SYSTEM_SETTINGS, C_GET_SYSTEM_SETTINGS = 47, 48
C_START_MEASUREMENT, C_STOP_MEASUREMENT = 49, 52
C_GET_SOFTWARE_VERSION = 142
COMMAND_NAMES = {
    C_GET_SYSTEM_STATUS: "GetSystemStatus", C_GET_TRACKER_STATUS: "GetTrackerStatus", C_SET_UNITS: "SetUnits",
    C_GET_UNITS: "GetUnits", C_INITIALIZE: "Initialize", C_SET_ENVIRONMENT: "SetEnvironmentParams",
    C_GET_ENVIRONMENT: "GetEnvironmentParams", C_SET_MEAS_MODE: "SetMeasurementMode",
    C_GET_MEAS_MODE: "GetMeasurementMode", C_SET_COORD_SYS: "SetCoordinateSystemType",
    C_GET_COORD_SYS: "GetCoordinateSystemType", C_SET_STATIONARY: "SetStationaryModeParams",
    C_GET_STATIONARY: "GetStationaryModeParams", C_SET_CONTINUOUS_TIME: "SetContinuousTimeModeParams",
    C_GET_CONTINUOUS_TIME: "GetContinuousTimeModeParams", C_SET_REFLECTOR: "SetReflector",
    C_GET_REFLECTOR: "GetReflector",
    C_GET_REFLECTORS: "GetReflectors", C_SET_SYSTEM_SETTINGS: "SetSystemSettings",
    C_GET_SYSTEM_SETTINGS: "GetSystemSettings", C_START_MEASUREMENT: "StartMeasurement",
    C_STOP_MEASUREMENT: "StopMeasurement", C_GET_SOFTWARE_VERSION: "GetSystemSoftwareVersion",
}

#: ES_LengthUnit meter, ES_AngleUnit radian, ES_TemperatureUnit Celsius, ES_PressureUnit mbar, ES_HumidityUnit %RH
UNITS_SI = (0, 0, 0, 0, 0)
CS_RHR = 0  # ES_CoordinateSystemType: right-handed rectangular (X, Y, Z)
MM_STATIONARY, MM_CONTINUOUS_TIME, MM_6D_STATIONARY, MM_6D_CONTINUOUS_TIME = 0, 1, 6, 7  # ES_MeasMode

#: ES_MeasurementStatus of each point of a continuous result (0 all OK; others "should be treated with care")
POINT_STATUS = {0: "all OK", 1: "speed warning", 2: "speed exceeded", 3: "prism error", 4: "trigger time violation"}
TPS_INITIALIZED = 5  # ES_TrackerProcessorStatus
TRACKER_READY = 2  # ES_TrackerStatus: 0 not ready, 1 busy, 2 ready
TARGET_TYPES = {0: "unknown", 1: "corner cube", 2: "cat's eye", 3: "glass prism", 4: "RFI prism", 5: "RRR 1.5in",
                6: "RRR 0.5in", 7: "BRR 1.5in", 8: "BRR 0.5in", 9: "TBR 0.5in"}

#: ES_ResultStatus values this client names (others are shown by number)
STATUS = {
    0: "all OK", 1: "server busy", 2: "not implemented", 3: "wrong parameter", 23: "wrong current reflector",
    26: "no tracker processor found", 36: "unknown error", 38: "no tracker connected", 39: "tracker not initialized",
    41: "module timed out", 57: "meteo data out of range", 10004: "measurement status not ready",
    10005: "ADM start-up busy", 10009: "no stationary result", 10010: "sensor not levelled",
    10012: "sensor not warmed up", 10013: "sensor not stable", 10014: "system not ready for measurement",
    10015: "communication with sensor failed",
}
#: statuses that mean the beam does not reach the reflector (broken beam, reflector lost): TargetLost
BEAM_STATUSES = frozenset({10004, 10009})
#: statuses that mean the tracker cannot measure yet (warming up, not initialised, unstable): retry later
NOT_READY_STATUSES = frozenset({1, 39, 10005, 10010, 10012, 10013, 10014})

#: ES_SystemStatusChange codes this client names
STATUS_CHANGE = {
    0: "distance set", 1: "laser warmed up", 2: "environment parameters changed", 6: "units changed",
    7: "reflector changed", 8: "system settings changed", 12: "coordinate system type changed",
    17: "measurement mode changed", 18: "stationary mode parameters changed",
    19: "continuous time mode parameters changed", 25: "measurement status not ready",
    26: "measurement status busy", 27: "measurement status ready", 146: "laser not stabilized",
    851: "sensor disconnected", 997: "tracker processor connection closing", 998: "server closing",
    999: "server started",
}
SSC_NOT_READY, SSC_BUSY, SSC_READY = 25, 26, 27

_SINGLE = struct.Struct("<IIi17d")  # status, measMode, bIsTryMode, 17 doubles
_SINGLE2 = struct.Struct("<IIi23d")
_MULTI = struct.Struct("<IiIi3d")  # status, lNumberOfResults, measMode, bIsTryMode, environment
_CONTINUOUS_TIME = struct.Struct("<iiiI")  # lTimeSeparation (ms), lNumberOfPoints, bUseRegion, regionType
_VERSION = struct.Struct("<iii")
_UNITS = struct.Struct("<5I")
_ENVIRONMENT = struct.Struct("<3d")
_SETTINGS = struct.Struct("<I8i")
_REFLECTOR = struct.Struct("<iiId64s")
_SYSTEM_STATUS = struct.Struct("<4I3iIii")
#: command -> size in bytes of its answer's data (after command and status)
REPLY_BODY = {
    C_GET_SYSTEM_STATUS: _SYSTEM_STATUS.size, C_GET_TRACKER_STATUS: 4, C_GET_UNITS: _UNITS.size,
    C_GET_ENVIRONMENT: _ENVIRONMENT.size, C_GET_MEAS_MODE: 4, C_GET_COORD_SYS: 4, C_GET_STATIONARY: 8,
    C_GET_CONTINUOUS_TIME: _CONTINUOUS_TIME.size,
    C_GET_REFLECTOR: 4, C_GET_REFLECTORS: _REFLECTOR.size, C_GET_SYSTEM_SETTINGS: _SETTINGS.size,
    C_GET_SOFTWARE_VERSION: 64,
}


def status_text(status: int) -> str:
    """``status 10004 (measurement status not ready)``: an ES_ResultStatus for messages."""
    name = STATUS.get(status)
    return f"status {status}" + (f" ({name})" if name else "")


def command_name(command: int) -> str:
    return COMMAND_NAMES.get(command, f"command {command}")


# --- packets ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Reply:
    """The answer to a command: ``command``, ``status`` (0: all OK) and its data ``body`` (bytes)."""

    command: int
    status: int
    body: bytes = b""


@dataclass(frozen=True)
class ErrorPacket:
    """An ``ES_DT_Error`` packet: ``command`` failed with ``status``."""

    command: int
    status: int


@dataclass(frozen=True)
class StatusChange:
    """An unsolicited ``ES_DT_SystemStatusChange``: ``code`` (:data:`STATUS_CHANGE`)."""

    code: int

    def __str__(self) -> str:
        return STATUS_CHANGE.get(self.code, f"status change {self.code}")


@dataclass(frozen=True)
class SingleResult:
    """A stationary measurement (``ES_DT_SingleMeasResult``, or ``...2`` without pointing errors): ``values``
    (3,) in the units and coordinate system set, ``std`` (3,) their standard deviations, ``std_total``,
    ``temperature``, ``pressure``, ``humidity`` the environment it was corrected with; ``status`` 0 all OK."""

    status: int
    mode: int
    try_mode: bool
    values: tuple[float, float, float]
    std: tuple[float, float, float]
    std_total: float
    temperature: float
    pressure: float
    humidity: float


@dataclass(frozen=True)
class MultiResult:
    """A continuous result (``ES_DT_MultiMeasResult``, or ``...2`` with each point's a-priori deviations): the
    packet's ``status`` (0 all OK), ``mode``, ``try_mode``, the environment it was corrected with, and per point
    ``point_status`` (k,) (:data:`POINT_STATUS`), ``time1``, ``time2`` (k,) the raw ``lTime1``, ``lTime2``,
    ``values`` (k, 3) in the units set and, for ``...2``, ``std`` (k, 3) the a-priori standard deviations (else
    None)."""

    status: int
    mode: int
    try_mode: bool
    temperature: float
    pressure: float
    humidity: float
    point_status: np.ndarray
    time1: np.ndarray
    time2: np.ndarray
    values: np.ndarray
    std: np.ndarray | None = None

    def __eq__(self, other: object) -> bool:  # arrays compare element by element
        if not isinstance(other, MultiResult):
            return NotImplemented
        return all(np.array_equal(a, b) if isinstance(a, np.ndarray) or isinstance(b, np.ndarray) else a == b
                   for a, b in zip(astuple(self), astuple(other), strict=True))

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True)
class OtherPacket:
    """A packet this client does not use (nivel or reflector position results): its ``type`` and bytes."""

    type: int
    data: bytes


Packet = (Reply | ErrorPacket | StatusChange | SingleResult | MultiResult | ProbeResult | ProbeMultiResult
          | OtherPacket)


def frame(buffer: bytes) -> tuple[list[bytes], bytes]:
    """Split a received byte stream into whole packets and the rest (an incomplete packet). BadReading when a
    header's size cannot be a packet's (below 12 or above :data:`MAX_PACKET` bytes): the stream is out of step."""
    packets = []
    while len(buffer) >= HEADER.size:
        size, kind = HEADER.unpack_from(buffer)
        if not 12 <= size <= MAX_PACKET:
            raise BadReading(f"a packet header gives {size} bytes (type {kind}): not an emScon packet, the stream "
                             f"is out of step (first bytes {buffer[:16].hex(' ')})")
        if len(buffer) < size:
            break
        packets.append(bytes(buffer[:size]))
        buffer = buffer[size:]
    return packets, bytes(buffer)


def decode(packet: bytes) -> Packet:
    """One whole packet (from :func:`frame`) -> its dataclass; BadReading when its size does not fit its type
    (a command's answer of a known command must have exactly its data: :data:`REPLY_BODY`)."""
    size, kind = HEADER.unpack_from(packet)
    body = packet[HEADER.size:]
    if size != len(packet):
        raise BadReading(f"packet of {len(packet)} bytes says it has {size}")
    if kind == DT_COMMAND:
        if len(body) < 8:
            raise BadReading(f"a command answer of {size} bytes is too short (at least 16)")
        command, status = struct.unpack_from("<II", body)
        data = body[8:]
        expected = REPLY_BODY.get(command, 0) if status == 0 else None
        if command in COMMAND_NAMES and expected is not None and len(data) != expected:
            raise BadReading(f"the answer to {command_name(command)} has {len(data)} data bytes, not {expected}")
        return Reply(command, status, data)
    if kind == DT_ERROR:
        if len(body) != 8:
            raise BadReading(f"an error packet of {size} bytes (16 expected)")
        return ErrorPacket(*struct.unpack("<II", body))
    if kind == DT_STATUS_CHANGE:
        if len(body) != 4:
            raise BadReading(f"a status change packet of {size} bytes (12 expected)")
        return StatusChange(struct.unpack("<I", body)[0])
    if kind in (DT_SINGLE, DT_SINGLE2):
        layout = _SINGLE if kind == DT_SINGLE else _SINGLE2
        if len(body) != layout.size:
            raise BadReading(f"a measurement result of {size} bytes ({HEADER.size + layout.size} expected)")
        status, mode, try_mode, *d = layout.unpack(body)
        std_total = d[6]
        return SingleResult(status, mode, bool(try_mode), (d[0], d[1], d[2]), (d[3], d[4], d[5]), std_total,
                            d[-3], d[-2], d[-1])
    if kind in (DT_MULTI, DT_MULTI2):
        return _multi_result(kind, body)
    if kind == DT_PROBE_STATIONARY:
        return probe_stationary_result(body)
    if kind == DT_PROBE_CONTINUOUS:
        return probe_continuous_result(body)
    if kind in (DT_NIVEL, DT_REFLECTOR_POS):
        return OtherPacket(kind, packet)
    raise BadReading(f"a packet of unknown type {kind} ({size} bytes)")


def _point_dtype(kind: int) -> np.dtype:
    """One point of a continuous result (``MeasValueT``, or ``MeasValue2T`` for ``ES_DT_MultiMeasResult2``)."""
    names = ["status", "time1", "time2", "values"] + (["std", "total", "covariance"] if kind == DT_MULTI2 else [])
    formats = ["<u4", "<i4", "<i4", ("<f8", 3)] + ([("<f8", 3), "<f8", ("<f8", 3)] if kind == DT_MULTI2 else [])
    return np.dtype({"names": names, "formats": formats})


def _multi_result(kind: int, body: bytes) -> MultiResult:
    point = _point_dtype(kind).itemsize  # 36 or 92 bytes
    if len(body) < _MULTI.size:
        raise BadReading(f"a continuous result of {HEADER.size + len(body)} bytes is too short")
    status, count, mode, try_mode, temperature, pressure, humidity = _MULTI.unpack_from(body)
    if count < 0 or len(body) != _MULTI.size + count * point:
        raise BadReading(f"a continuous result of {HEADER.size + len(body)} bytes says it holds {count} points "
                         f"({HEADER.size + _MULTI.size + max(count, 0) * point} bytes expected)")
    rows = np.frombuffer(body, _point_dtype(kind), count, _MULTI.size)
    std = rows["std"].astype(float) if kind == DT_MULTI2 else None
    return MultiResult(status, mode, bool(try_mode), temperature, pressure, humidity, rows["status"].astype(np.int64),
                       rows["time1"].astype(np.int64), rows["time2"].astype(np.int64), rows["values"].astype(float),
                       std)


# --- what the client sends ----------------------------------------------------------------------------------


def command(code: int, payload: bytes = b"") -> bytes:
    """A command packet: header, ``code``, ``payload`` (the command's parameters, already packed)."""
    return HEADER.pack(HEADER.size + 4 + len(payload), DT_COMMAND) + struct.pack("<I", code) + payload


def set_units(length: int = 0, angle: int = 0, temperature: int = 0, pressure: int = 0, humidity: int = 0) -> bytes:
    """SetUnits (default: metre, radian, degree Celsius, mbar, %RH: :data:`UNITS_SI`)."""
    return command(C_SET_UNITS, _UNITS.pack(length, angle, temperature, pressure, humidity))


def set_coordinate_system(kind: int = CS_RHR) -> bytes:
    return command(C_SET_COORD_SYS, struct.pack("<I", kind))


def set_measurement_mode(mode: int = MM_STATIONARY) -> bytes:
    return command(C_SET_MEAS_MODE, struct.pack("<I", mode))


def set_stationary_params(meas_time_ms: int, use_adm: bool = False) -> bytes:
    """SetStationaryModeParams: the measurement's duration (ms) and whether the ADM alone measures."""
    return command(C_SET_STATIONARY, struct.pack("<ii", int(meas_time_ms), int(use_adm)))


def set_continuous_time_params(separation_ms: int, points: int = 0, use_region: bool = False,
                               region: int = 0) -> bytes:
    """SetContinuousTimeModeParams: ``separation_ms`` between points, ``points`` to take (0: until stopped),
    whether a region (``region``: 0 sphere, 1 box) limits where points are taken."""
    return command(C_SET_CONTINUOUS_TIME, _CONTINUOUS_TIME.pack(int(separation_ms), int(points), int(use_region),
                                                               int(region)))


def set_environment(temperature: float, pressure: float, humidity: float) -> bytes:
    """SetEnvironmentParams in the units set (°C, mbar, %RH with :data:`UNITS_SI`)."""
    return command(C_SET_ENVIRONMENT, _ENVIRONMENT.pack(temperature, pressure, humidity))


def set_reflector(reflector_id: int) -> bytes:
    return command(C_SET_REFLECTOR, struct.pack("<i", reflector_id))


def set_system_settings(settings: tuple[int, ...]) -> bytes:
    """SetSystemSettings from the nine fields of :func:`system_settings`."""
    return command(C_SET_SYSTEM_SETTINGS, _SETTINGS.pack(*settings))


# --- answers' data --------------------------------------------------------------------------------------------


def _text(raw: bytes) -> str:
    return raw.decode("utf-16-le", "replace").split("\x00", 1)[0].strip()


def units(body: bytes) -> tuple[int, int, int, int, int]:
    """GetUnits: (length, angle, temperature, pressure, humidity) unit codes."""
    return _UNITS.unpack(body)  # type: ignore[return-value]


def one_int(body: bytes) -> int:
    """The single 32-bit value of GetCoordinateSystemType, GetMeasurementMode, GetReflector, GetTrackerStatus."""
    return int(struct.unpack("<i", body)[0])


def continuous_time_params(body: bytes) -> tuple[int, int, bool, int]:
    """GetContinuousTimeModeParams: (time separation ms, number of points, use region, region type)."""
    separation, points, use_region, region = _CONTINUOUS_TIME.unpack(body)
    return int(separation), int(points), bool(use_region), int(region)


def environment(body: bytes) -> tuple[float, float, float]:
    """GetEnvironmentParams: (temperature, pressure, humidity) in the units set."""
    return _ENVIRONMENT.unpack(body)  # type: ignore[return-value]


def stationary_params(body: bytes) -> tuple[int, bool]:
    """GetStationaryModeParams: (measurement time ms, ADM only)."""
    time_ms, adm = struct.unpack("<ii", body)
    return int(time_ms), bool(adm)


def system_settings(body: bytes) -> tuple[int, ...]:
    """GetSystemSettings: weather monitor status, apply transformation, apply station orientation, keep last
    position, send unsolicited messages, send reflector position data, try mode, has nivel, has video camera."""
    return _SETTINGS.unpack(body)


@dataclass(frozen=True)
class ReflectorEntry:
    """One answer of GetReflectors (one per reflector the server knows)."""

    total: int
    id: int
    target_type: int
    surface_offset: float
    name: str


def reflector_entry(body: bytes) -> ReflectorEntry:
    total, rid, kind, offset, name = _REFLECTOR.unpack(body)
    return ReflectorEntry(total, rid, kind, offset, _text(name))


@dataclass(frozen=True)
class SystemStatus:
    """GetSystemStatus: last result status, tracker processor, laser and ADM status, server version, weather
    monitor status, flags, tracker serial number."""

    last_status: int
    processor: int
    laser: int
    adm: int
    version: tuple[int, int, int]
    weather_monitor: int
    flags: int
    serial: int


def system_status(body: bytes) -> SystemStatus:
    v = _SYSTEM_STATUS.unpack(body)
    return SystemStatus(v[0], v[1], v[2], v[3], (v[4], v[5], v[6]), v[7], v[8], v[9])


def software_version(body: bytes) -> str:
    return _text(body)
