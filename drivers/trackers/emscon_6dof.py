"""The 6-DoF probe results of the Leica emScon TPI (T-Mac class), decoded: pure and byte-level, as
drivers/trackers/emscon_protocol.py (which dispatches ``type`` 4 and 5 here and re-exports these names).

6-DoF probes (T-Mac class): ``ES_MM_6DStationary`` answers one ``ES_DT_StationaryProbeMeasResult`` (``type`` 4,
:class:`ProbeResult`), ``ES_MM_6DContinuousTime`` streams ``ES_DT_ContinuousProbeMeasResult`` packets (``type`` 5,
:class:`ProbeMultiResult`): header, ``status``, ``lNumberOfResults``, ``measMode``, ``bIsTryMode``, probe id, field
number, tip status, tip adapter id and interface, the environment, then per point ``status``, trigger status,
``lRotationStatus``, ``lTime1``, ``lTime2`` and 24 doubles (the tip's position, its deviations, total and
covariances; the quaternion; rotation angles with their deviations, total and covariances).
What the header verifies and what is inferred (ES_C_API_Def.h of beckjac/emscon_ros, TPI 3.6): the packet types, the
field order, types and sizes of both probe results and the bit meaning of ``lRotationStatus`` (``Status6D`` bit 0:
valid, ``Error6D`` bit 1, ``Frozen6DValues`` bit 5; the bit order is the LSB-first allocation of the compilers the
header was written for) are verified; the quaternion's convention is not in the header: it is read as
(q0 scalar, q1, q2, q3) of the rotation taking probe-frame vectors to the tracker frame, the reading of the emScon
sample client in emscon_ros's first commits (it prints the columns of that matrix as the probe's axes): inferred,
as is ``lTime1`` s + ``lTime2`` µs. The rotation angles' deviations are taken as the orientation's per-axis
deviation (a small-angle reading of Euler-angle deviations: inferred).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from drivers.errors import BadReading

_HEADER = 8  # bytes of the packet header (lPacketSize, type) before what these layouts read
#: lRotationStatus bits (struct RotationStatus): Status6D (the rotation is valid), Error6D, Frozen6DValues
ROTATION_VALID, ROTATION_ERROR, ROTATION_FROZEN = 1, 2, 32
#: ProbeStationaryResultT after the header: status, measMode, bIsTryMode, triggerStatus, lRotationStatus, probe id,
#: field number, tipStatus, tip adapter id and interface, then 41 doubles (positions 0-16: the tip's position, its
#: deviations, total, covariances and a-priori ones; 17-20: the quaternion; 21-23: rotation angles; 24-37 their
#: deviations and covariances; 38-40: the environment): 376 bytes in all
_PROBE_STATIONARY = struct.Struct("<IIiIiiiIii41d")
#: ProbeContinuousResultT after the header: status, lNumberOfResults, measMode, bIsTryMode, probe id, field number,
#: tipStatus, tip adapter id and interface, environment (3 doubles); then the points (:func:`_probe_point_dtype`)
_PROBE_MULTI = struct.Struct("<IiIiiiIii3d")


@dataclass(frozen=True)
class ProbeResult:
    """A 6-DoF stationary probe result (``ES_DT_StationaryProbeMeasResult``, T-Mac class probes): the measuring
    tip's ``position`` (3,) and its standard deviations ``position_std`` (3,) in the units and coordinate system set,
    the probe's orientation as ``quaternion`` (q0, q1, q2, q3) and as ``angles`` (rotation angles X, Y, Z) with
    their standard deviations ``angles_std``, the ``rotation_status`` bits, probe and tip ids, the environment."""

    status: int
    mode: int
    try_mode: bool
    trigger: int
    rotation_status: int
    probe_id: int
    tip_status: int
    tip_adapter_id: int
    position: tuple[float, float, float]
    position_std: tuple[float, float, float]
    quaternion: tuple[float, float, float, float]
    angles: tuple[float, float, float]
    angles_std: tuple[float, float, float]
    temperature: float
    pressure: float
    humidity: float


@dataclass(frozen=True, eq=False)
class ProbeMultiResult:
    """A continuous 6-DoF result (``ES_DT_ContinuousProbeMeasResult``): the packet's ``status``, ``mode``,
    ``try_mode``, ``probe_id``, ``tip_status``, the environment, and per point (k rows) ``point_status``
    (:data:`POINT_STATUS`), ``rotation_status`` (bits :data:`ROTATION_VALID`...), ``time1``, ``time2`` (raw
    ``lTime1``, ``lTime2``), ``values`` (k, 3) the tip's position and ``std`` (k, 3) its deviations (units set),
    ``quaternion`` (k, 4) (q0, q1, q2, q3), ``angles_std`` (k, 3) the rotation angles' deviations. Its point fields
    are named as :class:`MultiResult`'s, so a stream reads both alike."""

    status: int
    mode: int
    try_mode: bool
    probe_id: int
    tip_status: int
    temperature: float
    pressure: float
    humidity: float
    point_status: np.ndarray
    rotation_status: np.ndarray
    time1: np.ndarray
    time2: np.ndarray
    values: np.ndarray
    std: np.ndarray
    quaternion: np.ndarray
    angles_std: np.ndarray


def rotation_ok(rotation_status: int | np.ndarray) -> bool | np.ndarray:
    """A 6-DoF result's orientation can be used: valid, no error, not frozen (``lRotationStatus`` bits)."""
    bits = np.asarray(rotation_status, dtype=np.int64)
    good = ((bits & ROTATION_VALID) != 0) & ((bits & (ROTATION_ERROR | ROTATION_FROZEN)) == 0)
    return bool(good) if good.ndim == 0 else good


def _probe_point_dtype() -> np.dtype:
    """One point of a continuous 6-DoF result (``ProbeMeasValueT``, 212 bytes)."""
    return np.dtype({"names": ["status", "trigger", "rotation", "time1", "time2", "position", "std", "total",
                               "covariance", "quaternion", "angles", "angles_std", "angles_total", "angles_covariance"],
                     "formats": ["<u4", "<u4", "<i4", "<i4", "<i4", ("<f8", 3), ("<f8", 3), "<f8", ("<f8", 3),
                                 ("<f8", 4), ("<f8", 3), ("<f8", 3), "<f8", ("<f8", 3)]})


def probe_stationary_result(body: bytes) -> ProbeResult:
    """An ``ES_DT_StationaryProbeMeasResult``'s body (after the header); BadReading when its size is not its
    layout's."""
    if len(body) != _PROBE_STATIONARY.size:
        raise BadReading(f"a 6-DoF probe result of {_HEADER + len(body)} bytes ({_HEADER + _PROBE_STATIONARY.size} "
                         "expected)")
    v = _PROBE_STATIONARY.unpack(body)
    d = v[10:]
    return ProbeResult(v[0], v[1], bool(v[2]), v[3], v[4], v[5], v[7], v[8], (d[0], d[1], d[2]), (d[3], d[4], d[5]),
                       (d[17], d[18], d[19], d[20]), (d[21], d[22], d[23]), (d[24], d[25], d[26]), d[38], d[39],
                       d[40])


def probe_continuous_result(body: bytes) -> ProbeMultiResult:
    """An ``ES_DT_ContinuousProbeMeasResult``'s body (after the header); BadReading when its size does not hold the
    number of points it gives."""
    point = _probe_point_dtype()
    if len(body) < _PROBE_MULTI.size:
        raise BadReading(f"a continuous 6-DoF result of {_HEADER + len(body)} bytes is too short")
    status, count, mode, try_mode, probe_id, _field, tip, _adapter, _interface, *env = _PROBE_MULTI.unpack_from(body)
    if count < 0 or len(body) != _PROBE_MULTI.size + count * point.itemsize:
        raise BadReading(f"a continuous 6-DoF result of {_HEADER + len(body)} bytes says it holds {count} points "
                         f"({_HEADER + _PROBE_MULTI.size + max(count, 0) * point.itemsize} bytes expected)")
    rows = np.frombuffer(body, point, count, _PROBE_MULTI.size)
    return ProbeMultiResult(status, mode, bool(try_mode), probe_id, tip, env[0], env[1], env[2],
                            rows["status"].astype(np.int64), rows["rotation"].astype(np.int64),
                            rows["time1"].astype(np.int64), rows["time2"].astype(np.int64),
                            rows["position"].astype(float), rows["std"].astype(float),
                            rows["quaternion"].astype(float), rows["angles_std"].astype(float))
