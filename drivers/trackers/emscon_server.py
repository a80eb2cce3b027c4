"""What an emScon server sends (the emulator in :mod:`drivers.trackers.emscon_sim` and the protocol's tests): answer,
error, status-change and result packets, and the bodies of the answers a client reads with
:mod:`drivers.trackers.emscon_protocol` (little-endian, the header's sizes and types as there); and the emulator's
connection (:class:`Link`) and continuous measurement (:class:`Stream`) it sends them on.
"""

from __future__ import annotations

import contextlib
import re
import socket
import struct
import threading
from typing import Any

import numpy as np

from drivers.trackers.emscon_protocol import (  # the layouts a client reads, written here
    _ENVIRONMENT,
    _MULTI,
    _PROBE_MULTI,
    _PROBE_STATIONARY,
    _REFLECTOR,
    _SETTINGS,
    _SINGLE,
    _SYSTEM_STATUS,
    _UNITS,
    DT_COMMAND,
    DT_ERROR,
    DT_MULTI,
    DT_MULTI2,
    DT_PROBE_CONTINUOUS,
    DT_PROBE_STATIONARY,
    DT_SINGLE,
    DT_STATUS_CHANGE,
    HEADER,
    MM_6D_CONTINUOUS_TIME,
    MM_6D_STATIONARY,
    MM_CONTINUOUS_TIME,
    MM_STATIONARY,
    SystemStatus,
    _point_dtype,
    _probe_point_dtype,
)

STREAM_FAULTS = ("stream_lost", "stream_prism", "stream_garbage", "stream_drop", "stream_silence", "stream_error")
EMSCON_FAULTS = ("beam_broken", "lost_during", "warming_up", "not_ready", "garbage", "silence", "drop", "split",
                 "pose_invalid", *STREAM_FAULTS)
_FAULT = re.compile(r"([a-z_]+)(?:@([0-9]+))?(?:x([0-9]+))?\Z")


def reply(code: int, status: int = 0, body: bytes = b"") -> bytes:
    """The answer packet to command ``code``."""
    return HEADER.pack(HEADER.size + 8 + len(body), DT_COMMAND) + struct.pack("<II", code, status) + body


def error_packet(code: int, status: int) -> bytes:
    return HEADER.pack(16, DT_ERROR) + struct.pack("<II", code, status)


def status_change(code: int) -> bytes:
    return HEADER.pack(12, DT_STATUS_CHANGE) + struct.pack("<I", code)


def single_result(values: tuple[float, float, float], std: tuple[float, float, float], environment_: tuple[float,
                  float, float], status: int = 0, mode: int = MM_STATIONARY) -> bytes:
    """An ``ES_DT_SingleMeasResult`` (pointing errors and a-priori deviations zero; totals from ``std``)."""
    total = float(sum(s * s for s in std) ** 0.5)
    doubles = (*values, *std, total, 0.0, 0.0, 0.0, *std, total, *environment_)
    return HEADER.pack(HEADER.size + _SINGLE.size, DT_SINGLE) + _SINGLE.pack(status, mode, 0, *doubles)


def multi_result(point_status: Any, time1: Any, time2: Any, values: Any, environment_: tuple[float, float, float],
                 std: Any = None, status: int = 0, mode: int = MM_CONTINUOUS_TIME) -> bytes:
    """A continuous result of k points (``ES_DT_MultiMeasResult``; with ``std`` (k, 3), ``...2``, whose totals
    are computed and covariances zero): per point its status, ``lTime1``, ``lTime2`` and values (k, 3)."""
    kind = DT_MULTI if std is None else DT_MULTI2
    values = np.asarray(values, dtype=float).reshape(-1, 3)
    rows = np.zeros(len(values), _point_dtype(kind))
    rows["status"], rows["time1"], rows["time2"], rows["values"] = point_status, time1, time2, values
    if std is not None:
        rows["std"] = std
        rows["total"] = np.sqrt(np.sum(np.square(std), axis=1))
    head = _MULTI.pack(status, len(rows), mode, 0, *environment_)
    return HEADER.pack(HEADER.size + len(head) + rows.nbytes, kind) + head + rows.tobytes()


def probe_stationary_result(position: tuple[float, float, float], position_std: tuple[float, float, float],
                            quaternion: tuple[float, float, float, float], angles: tuple[float, float, float],
                            angles_std: tuple[float, float, float], environment_: tuple[float, float, float],
                            probe_id: int = 1, status: int = 0, rotation_status: int = 1) -> bytes:
    """An ``ES_DT_StationaryProbeMeasResult`` (totals from the deviations, covariances and a-priori values zero,
    trigger not pressed, tip OK, tip adapter 1; ``rotation_status`` 1: valid)."""
    total = float(sum(x * x for x in position_std) ** 0.5)
    angle_total = float(sum(x * x for x in angles_std) ** 0.5)
    doubles = (*position, *position_std, total, 0.0, 0.0, 0.0, *position_std, total, 0.0, 0.0, 0.0, *quaternion,
               *angles, *angles_std, angle_total, 0.0, 0.0, 0.0, *angles_std, angle_total, 0.0, 0.0, 0.0,
               *environment_)
    body = _PROBE_STATIONARY.pack(status, MM_6D_STATIONARY, 0, 0, rotation_status, probe_id, 0, 0, 1, 0, *doubles)
    return HEADER.pack(HEADER.size + len(body), DT_PROBE_STATIONARY) + body


def probe_continuous_result(point_status: Any, time1: Any, time2: Any, positions: Any, position_std: Any,
                            quaternions: Any, angles_std: Any, environment_: tuple[float, float, float],
                            rotation_status: Any = 1, probe_id: int = 1, status: int = 0) -> bytes:
    """An ``ES_DT_ContinuousProbeMeasResult`` of k points: per point its status, ``lTime1``, ``lTime2``, the tip's
    position and deviations (k, 3), the quaternion (k, 4: q0 scalar first), the rotation angles' deviations (k, 3)
    and ``lRotationStatus`` (default 1: valid); totals computed, covariances, rotation angles and the trigger zero."""
    positions = np.asarray(positions, dtype=float).reshape(-1, 3)
    rows = np.zeros(len(positions), _probe_point_dtype())
    rows["status"], rows["rotation"], rows["time1"], rows["time2"] = point_status, rotation_status, time1, time2
    rows["position"], rows["std"], rows["quaternion"] = positions, position_std, quaternions
    rows["angles_std"] = angles_std
    rows["total"] = np.sqrt(np.sum(np.square(rows["std"]), axis=1))
    rows["angles_total"] = np.sqrt(np.sum(np.square(rows["angles_std"]), axis=1))
    head = _PROBE_MULTI.pack(status, len(rows), MM_6D_CONTINUOUS_TIME, 0, probe_id, 0, 0, 1, 0, *environment_)
    return HEADER.pack(HEADER.size + len(head) + rows.nbytes, DT_PROBE_CONTINUOUS) + head + rows.tobytes()


def text_field(text: str) -> bytes:
    """32 UTF-16LE code units, zero-padded (names and versions)."""
    raw = text.encode("utf-16-le")[:64]
    return raw + b"\x00" * (64 - len(raw))


def units_body(codes: tuple[int, ...]) -> bytes:
    return _UNITS.pack(*codes)


def environment_body(values: tuple[float, float, float]) -> bytes:
    return _ENVIRONMENT.pack(*values)


def settings_body(settings: tuple[int, ...]) -> bytes:
    return _SETTINGS.pack(*settings)


def reflector_body(total: int, rid: int, target_type: int, offset: float, name: str) -> bytes:
    return _REFLECTOR.pack(total, rid, target_type, offset, text_field(name))


def system_status_body(status: SystemStatus) -> bytes:
    return _SYSTEM_STATUS.pack(status.last_status, status.processor, status.laser, status.adm, *status.version,
                               status.weather_monitor, status.flags, status.serial)


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


class Stream:
    """A continuous measurement: points every ``separation`` s of the rig's clock from ``start``, ``limit`` of
    them (0: no end), 6-DoF ones (``six_dof``) or positions; ``sent`` so far, the last packet's rig time."""

    def __init__(self, start: float, separation: float, limit: int, six_dof: bool = False) -> None:
        self.start, self.separation, self.limit, self.six_dof = start, separation, limit, six_dof
        self.sent = 0
        self.last_packet = start
        self.ended = threading.Event()
        self.ended_itself = False  # the beam was lost or the count reached: nothing left to send


class Link:
    """One client connection: its socket, what is sent on it (the command handler and the stream share it), the
    continuous measurement running on it; ``muted``: a silent link sends nothing."""

    def __init__(self, conn: socket.socket) -> None:
        self.conn = conn
        self.closed = self.muted = False
        self.stream: Stream | None = None
        self.thread: threading.Thread | None = None
        self._lock = threading.Lock()

    @property
    def measuring(self) -> bool:
        """A continuous measurement runs on this link."""
        return self.stream is not None and not self.stream.ended.is_set()

    def send(self, data: bytes) -> bool:
        """Send ``data``; False when it did not leave (a closed or silent link)."""
        with self._lock:
            if self.closed or self.muted:
                return False
            try:
                self.conn.sendall(data)
            except OSError:
                self.closed = True
                return False
            return True

    def close(self) -> None:
        """The server hangs up (the serving loop sees it and ends)."""
        with self._lock:
            self.closed = True
            with contextlib.suppress(OSError):
                self.conn.shutdown(socket.SHUT_RDWR)
