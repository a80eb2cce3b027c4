"""6-DoF probe measurements (T-Mac class) of the emScon client: one stationary probe result as a pose (implements
``measure_pose`` for :class:`drivers.trackers.emscon.EmsconTracker`, which inherits this mixin). Sessions do not use
it yet: full-pose measurements in a session are another part of the product.

The exchange: ``SetMeasurementMode(6DStationary)``, ``StartMeasurement``, its answer, then one
``ES_DT_StationaryProbeMeasResult`` (drivers/trackers/emscon_protocol.py): the measuring tip's position and the
probe's orientation, as a quaternion and as rotation angles. The pose is built from the quaternion, read as
(q0 scalar, q1, q2, q3) of the rotation taking probe-frame vectors to the tracker frame; the header does not define
the convention, so a real T-Mac's first poses should be checked against a known motion before they are trusted. A
result whose rotation status says it is not valid (bit 0 clear, or bit 1: error) or whose quaternion is not of unit
length is a BadReading.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from drivers.errors import BadReading, ConnectionFailed
from drivers.trackers import emscon_protocol as es

UNIT = 1e-6  # a quaternion whose length is further than this from 1 is not a rotation


@dataclass(frozen=True)
class ProbePose:
    """One 6-DoF probe measurement: ``matrix`` 4x4, tracker frame <- probe frame (the translation is the tip, m),
    ``position_std`` (3,) m and ``angles_std`` (3,) rad as the server states them, ``timestamp`` the host's receive
    time (s), ``probe_id`` the server's probe id."""

    matrix: np.ndarray
    position_std: np.ndarray
    angles_std: np.ndarray
    timestamp: float
    probe_id: int


def pose_of(result: es.ProbeResult, where: str, timestamp: float) -> ProbePose:
    """The pose of a probe result (module doc); BadReading in one line when it is not a valid one."""
    if result.status != 0 or not result.rotation_status & 1 or result.rotation_status & 2:
        raise BadReading(f"{where}: a 6-DoF result with status {result.status} and rotation status "
                         f"{result.rotation_status:#x} is not a valid pose")
    q = np.array(result.quaternion, dtype=float)
    if not np.all(np.isfinite(q)) or abs(np.linalg.norm(q) - 1.0) > UNIT:
        raise BadReading(f"{where}: a 6-DoF result's quaternion {q.tolist()} is not of unit length")
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
    matrix[:3, 3] = result.position
    return ProbePose(matrix, np.array(result.position_std), np.array(result.angles_std), timestamp, result.probe_id)


class ProbeMeasurement:
    """The 6-DoF half of EmsconTracker (module doc)."""

    where: str
    reply_timeout: float
    measurement_mode: int
    meas_time_ms: int
    _connected_once: bool
    _sock: Any
    _call: Any
    _packet: Any
    _open: Any
    _other: Any
    _status_error: Any
    _refuse_while_streaming: Any

    def measure_pose(self, timeout: float) -> ProbePose:
        """One stationary 6-DoF measurement of the probe (module doc) within ``timeout`` s; BeamLost,
        TrackerNotReady, BadReading, DeviceTimeout or ConnectionFailed in one line, as :meth:`measure`."""
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout!r}")
        if not self._connected_once:
            raise ConnectionFailed(f"emScon tracker {self.where} is not connected (call connect())")
        self._refuse_while_streaming(f"emScon tracker {self.where}")
        deadline = time.monotonic() + timeout
        if self._sock is None:
            self._open(deadline)
        if self.measurement_mode != es.MM_6D_STATIONARY:
            self._call(es.set_measurement_mode(es.MM_6D_STATIONARY), es.C_SET_MEAS_MODE, deadline)
            self.measurement_mode = es.MM_6D_STATIONARY
        self._call(es.command(es.C_START_MEASUREMENT), es.C_START_MEASUREMENT, deadline)
        wait = min(deadline, time.monotonic() + self.meas_time_ms / 1000 + self.reply_timeout)
        while True:
            packet = self._packet(wait, "StartMeasurement's 6-DoF result")
            if isinstance(packet, es.ProbeResult):
                return pose_of(packet, self.where, time.time())
            if isinstance(packet, es.ErrorPacket) and packet.command in (es.C_START_MEASUREMENT, 0):
                raise self._status_error(es.C_START_MEASUREMENT, packet.status)
            self._other(packet)
