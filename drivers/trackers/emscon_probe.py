"""6-DoF probe measurements (T-Mac class) of the emScon client (a mixin of
:class:`drivers.trackers.emscon.EmsconTracker`): with ``probe=6dof`` every stationary reading is one 6-DoF
measurement delivered as a full pose (:meth:`ProbeMeasurement._probe_reading`: the tip's position and the probe
frame's orientation as a rotation vector, each with its deviation), and ``measure_pose`` gives one such
measurement as a 4x4 pose.

The exchange: ``SetMeasurementMode(6DStationary)``, ``StartMeasurement``, its answer, then one
``ES_DT_StationaryProbeMeasResult`` (drivers/trackers/emscon_6dof.py): the measuring tip's position and the
probe's orientation, as a quaternion and as rotation angles. The pose is built from the quaternion, read as
(q0 scalar, q1, q2, q3) of the rotation taking probe-frame vectors to the tracker frame: the header does not define
it (inferred; emscon_6dof.py says what is verified and what is not), so a real T-Mac's first poses should be
checked against a known motion (turn the flange about its own axis: the rotation vector's change must be that
axis, in the tracker frame) before they are trusted. A result whose status is not OK raises the tracker's status
error (BeamLost, TrackerNotReady...), as a stationary one does; one whose rotation status says it is not valid
(:func:`~drivers.trackers.emscon_6dof.rotation_ok`: bit 0 clear, error or frozen values) is an :class:`InvalidPose`,
one whose quaternion is not of unit length a BadReading (the orchestrator retries both).

A reading's ``sigma`` is the RMS of the tip's three deviations (m), its ``sigma_r`` the RMS of the rotation angles'
three deviations (rad: taken as the orientation's per-axis deviation, a small-angle reading of Euler-angle
deviations, inferred), both as the server states them.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from drivers.base import TrackerReading
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


class InvalidPose(BadReading):
    """The server's 6-DoF result says its pose is not valid (status not OK, rotation status not valid, in error or
    frozen: too few LEDs seen, the probe turned away, out of range): a measurement to retry, the link is fine."""


def rotation_of(quaternion: tuple[float, ...] | np.ndarray, where: str) -> Rotation:
    """The rotation (tracker frame <- probe frame) of an emScon quaternion (q0 scalar first: module doc);
    BadReading in one line when it is not of unit length."""
    q = np.array(quaternion, dtype=float)
    if not np.all(np.isfinite(q)) or abs(np.linalg.norm(q) - 1.0) > UNIT:
        raise BadReading(f"{where}: a 6-DoF result's quaternion {q.tolist()} is not of unit length")
    return Rotation.from_quat([q[1], q[2], q[3], q[0]])


def pose_of(result: es.ProbeResult, where: str, timestamp: float) -> ProbePose:
    """The pose of a probe result (module doc); BadReading in one line when it is not a valid one."""
    if result.status != 0 or not es.rotation_ok(result.rotation_status):
        raise InvalidPose(f"{where}: a 6-DoF result with status {result.status} and rotation status "
                          f"{result.rotation_status:#x} is not a valid pose (is the probe facing the tracker?)")
    matrix = np.eye(4)
    matrix[:3, :3] = rotation_of(result.quaternion, where).as_matrix()
    matrix[:3, 3] = result.position
    if not np.all(np.isfinite(matrix)) or np.abs(matrix[:3, 3]).max() > 1e4:
        raise BadReading(f"{where}: a 6-DoF result's tip at {list(result.position)} m is not a position")
    return ProbePose(matrix, np.array(result.position_std), np.array(result.angles_std), timestamp, result.probe_id)


def rms(values: tuple[float, ...] | np.ndarray) -> float | None:
    """The RMS of a result's stated deviations; None when they are not all finite or all zero (none stated)."""
    v = np.asarray(values, dtype=float)
    return float(np.sqrt(np.mean(v**2))) if np.all(np.isfinite(v)) and v.max() > 0 else None


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
    _environment_status: Any

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
        result, stamp = self._probe_result(deadline)
        return pose_of(result, self.where, stamp)

    def _probe_reading(self, deadline: float) -> TrackerReading:
        """One 6-DoF reading (module doc): ``position`` the tip (m, tracker frame), ``rotvec`` the probe frame's
        rotation (rad), ``sigma`` and ``sigma_r`` as stated, ``timestamp`` the host's receive time."""
        result, stamp = self._probe_result(deadline)
        if result.status != 0:  # the result's own status (a beam lost while measuring...): as a stationary one's
            raise self._status_error(es.C_START_MEASUREMENT, result.status)
        pose = pose_of(result, self.where, stamp)
        status = self._environment_status((result.temperature, result.pressure, result.humidity),
                                          "ok" if not result.try_mode else "ok, try mode")
        return TrackerReading(pose.matrix[:3, 3].copy(), stamp, rms(result.position_std), status,
                              rotvec=Rotation.from_matrix(pose.matrix[:3, :3]).as_rotvec(),
                              sigma_r=rms(result.angles_std))

    def _probe_result(self, deadline: float) -> tuple[es.ProbeResult, float]:
        """6-DoF stationary mode (set when another is in force), ``StartMeasurement`` and its result, with the
        host's receive time."""
        if self.measurement_mode != es.MM_6D_STATIONARY:
            self._call(es.set_measurement_mode(es.MM_6D_STATIONARY), es.C_SET_MEAS_MODE, deadline)
            self.measurement_mode = es.MM_6D_STATIONARY
        self._call(es.command(es.C_START_MEASUREMENT), es.C_START_MEASUREMENT, deadline)
        wait = min(deadline, time.monotonic() + self.meas_time_ms / 1000 + self.reply_timeout)
        while True:
            packet = self._packet(wait, "StartMeasurement's 6-DoF result")
            if isinstance(packet, es.ProbeResult):
                return packet, time.time()
            if isinstance(packet, es.ErrorPacket) and packet.command in (es.C_START_MEASUREMENT, 0):
                raise self._status_error(es.C_START_MEASUREMENT, packet.status)
            self._other(packet)
