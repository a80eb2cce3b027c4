"""Device protocols (small, structural: any class with these methods is a device) and reading types.

Units: joint positions rad (revolute) / m (prismatic); speeds rad/s or m/s; TP positions metres in
the tracker's own frame; timestamps seconds since the epoch (of the device's clock).
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


class RobotState(enum.Enum):
    READY = "ready"
    MOVING = "moving"
    PROTECTIVE_STOP = "protective stop"
    EMERGENCY_STOP = "emergency stop"
    DISCONNECTED = "disconnected"
    FAULT = "fault"


@dataclass(frozen=True)
class DeviceIdentity:
    """What a device says it is, recorded in the session header."""

    kind: str  # "robot" or "tracker"
    model: str
    serial: str = ""
    firmware: str = ""
    details: dict[str, str] = field(default_factory=dict)

    def as_dict(self) -> dict[str, object]:
        return {"kind": self.kind, "model": self.model, "serial": self.serial, "firmware": self.firmware,
                "details": dict(self.details)}


@dataclass(frozen=True, eq=False)
class Correction:
    """How a camera reading moves with the parameters θ of its board's shape and its lens's residual calibration
    (``names``, drivers/camera/board_and_lens.py), so that a later, better estimate can correct it again.

    The reading was corrected with the tracker's estimate of the time: its move is ``response @ θ`` (6,): the TP's
    position (m, camera frame), then a turn (rad, camera frame), to be subtracted. ``response`` (6, p) is the
    reading's frames' mean move per unit of each parameter, ``applied`` (6,) the mean of the moves their estimates
    made, ``estimate`` (p,) and ``covariance`` (p, p) the tracker's estimate after the reading, ``bias`` (m) and
    ``bias_r`` (rad) the per-axis part of its ``sigma`` and ``sigma_r`` that the estimate's uncertainty then made."""

    names: tuple[str, ...]
    response: Array
    applied: Array
    estimate: Array
    covariance: Array
    bias: float
    bias_r: float

    @classmethod
    def mean(cls, corrections: Sequence[Correction]) -> Correction:
        """Of several readings (or frames) averaged into one: the mean response and applied move, the last
        estimate (the most frames behind it), the biases' RMS."""
        last = corrections[-1]
        return cls(last.names, np.mean([c.response for c in corrections], axis=0),
                   np.mean([c.applied for c in corrections], axis=0), last.estimate, last.covariance,
                   float(np.sqrt(np.mean([c.bias**2 for c in corrections]))),
                   float(np.sqrt(np.mean([c.bias_r**2 for c in corrections]))))

    def shares(self, covariance: Array) -> tuple[float, float]:
        """Per-axis RMS (m, rad) of the error an estimate of ``covariance`` (p, p) leaves this reading's position and
        orientation."""
        position = self.response[:3] @ covariance @ self.response[:3].T
        turn = self.response[3:] @ covariance @ self.response[3:].T
        return float(np.sqrt(np.trace(position) / 3)), float(np.sqrt(np.trace(turn) / 3))

    def as_dict(self) -> dict[str, object]:
        """JSON-ready (lists of floats)."""
        return {"names": list(self.names), "response": np.asarray(self.response).tolist(),
                "applied": np.asarray(self.applied).tolist(), "estimate": np.asarray(self.estimate).tolist(),
                "covariance": np.asarray(self.covariance).tolist(), "bias": float(self.bias),
                "bias_r": float(self.bias_r)}

    @classmethod
    def from_dict(cls, d: dict) -> Correction:
        """The inverse of :meth:`as_dict`; ValueError when a shape does not fit the names."""
        names = tuple(str(n) for n in d["names"])
        p = len(names)
        out = cls(names, np.array(d["response"], dtype=float).reshape(6, p), np.array(d["applied"], dtype=float),
                  np.array(d["estimate"], dtype=float), np.array(d["covariance"], dtype=float).reshape(p, p),
                  float(d["bias"]), float(d["bias_r"]))
        if out.applied.shape != (6,) or out.estimate.shape != (p,):
            raise ValueError(f"a correction of {p} parameters needs 6 applied moves and {p} estimates")
        return out


@dataclass(frozen=True)
class TrackerReading:
    """One TP measurement: ``position`` (3,) m in the tracker frame, ``timestamp`` s, the device's
    per-axis standard uncertainty ``sigma`` (m) when it reports one, its ``status`` word, and ``tp``: the id
    (1..N) of the tracked point it sees (several reflectors or markers on the flange; 1 when there is one).
    Full-pose devices (6-DoF probes, camera targets) also give the target frame's orientation in the tracker frame,
    ``rotvec`` (3,) a rotation vector (rad; ``position`` is then the frame's origin), with its per-axis standard
    uncertainty ``sigma_r`` (rad) when they report one. ``shared`` (m) and ``shared_r`` (rad): the parts of
    ``sigma`` and ``sigma_r`` (per axis, in quadrature) that every reading of the same still view shares (a
    camera's detection bias for that view), which averaging readings does not reduce; None: readings independent.
    ``correction``: how a camera reading corrected for its board's shape and its lens moves with their estimate
    (:class:`Correction`; None for every other reading)."""

    position: Array
    timestamp: float
    sigma: float | None = None
    status: str = "ok"
    tp: int = 1
    rotvec: Array | None = None
    sigma_r: float | None = None
    shared: float | None = None
    shared_r: float | None = None
    correction: Correction | None = None


@runtime_checkable
class Robot(Protocol):
    """A robot arm the orchestrator can sequence. Every blocking call takes a timeout (s)."""

    joint_types: str

    def connect(self, timeout: float) -> None: ...

    def close(self) -> None: ...

    def identity(self) -> DeviceIdentity: ...

    def state(self) -> RobotState: ...

    def read_joints(self) -> Array:
        """Actual joint positions (n,), rad / m (encoder values, not the commanded ones)."""
        ...

    def move_joints(self, q: Sequence[float], speed: Sequence[float], acceleration: Sequence[float],
                    timeout: float) -> None:
        """Move to ``q`` and return when the motion is done; raises RobotFault, DeviceTimeout,
        ConnectionFailed. ``speed``/``acceleration`` per joint, rad/s (m/s) and rad/s² (m/s²)."""
        ...

    def wait_until_still(self, settle_time: float, timeout: float) -> None:
        """Return once the joints have been still for ``settle_time`` s; DeviceTimeout after ``timeout``."""
        ...

    def stop(self) -> None:
        """Stop any motion now (decelerating within the robot's limits). Never raises."""
        ...


def check_measure_request(count: int, timeout: float) -> None:
    """The arguments of :meth:`Tracker.measure`: ValueError unless ``count`` is an integer >= 1, ``timeout`` > 0 s."""
    if int(count) != count or count < 1 or not timeout > 0:
        raise ValueError(f"count must be an integer >= 1 and timeout > 0 s, got {count!r} and {timeout!r}")


@runtime_checkable
class Tracker(Protocol):
    """A device that measures the TP's position."""

    def connect(self, timeout: float) -> None: ...

    def close(self) -> None: ...

    def identity(self) -> DeviceIdentity: ...

    def measure(self, count: int, timeout: float) -> list[TrackerReading]:
        """``count`` consecutive readings of the TP; raises MeasurementError subclasses, DeviceTimeout,
        ConnectionFailed. A tracker that sees several points returns ``count`` readings of each point in sight
        (each with its ``tp``); a point out of sight has none, and only when no point is in sight does it raise
        TargetLost. A tracker that can see several points says how many in an attribute ``points`` (optional:
        one when absent)."""
        ...


# --- continuous motion: streams ------------------------------------------------------------------------------


@dataclass(frozen=True)
class JointStreamBatch:
    """Joint samples the robot controller recorded: ``t`` (k,) s on the controller's own clock (its
    timestamp, not the host's), ``q`` (k, n) actual joint positions (rad / m), ``gaps``: (start, end) pairs
    of controller times between which samples were lost (a dropped packet, a restarted link), so that
    nothing is interpolated across them."""

    t: Array
    q: Array
    gaps: tuple[tuple[float, float], ...] = ()


@dataclass(frozen=True)
class TrackerStreamBatch:
    """Tracker samples: ``t`` (k,) s on the tracker's own clock, ``points`` (k, 3) m in the tracker frame,
    ``tp`` (k,) tracked-point ids, ``sigma`` (k,) m per axis (NaN when the device reports none), ``gaps``:
    (start, end) tracker times between which the target was lost or samples were dropped. A full-pose device (6-DoF
    probe, camera target) also gives each sample's target-frame orientation: ``rotvec`` (k, 3) a rotation vector in
    the tracker frame (rad; NaN rows: a position only) and ``sigma_r`` (k,) its standard uncertainty per axis (rad,
    NaN when none); None: positions only."""

    t: Array
    points: Array
    tp: NDArray[np.int64]
    sigma: Array
    gaps: tuple[tuple[float, float], ...] = ()
    rotvec: Array | None = None
    sigma_r: Array | None = None


@runtime_checkable
class StreamingRobot(Protocol):
    """A robot that records its joint positions at the controller's native rate while it moves (continuous
    acquisition). Recording runs in the background (the UR driver's worker process); reads never block."""

    def start_joint_stream(self, timeout: float) -> float:
        """Start recording now; returns the native rate, Hz."""
        ...

    def read_joint_stream(self) -> JointStreamBatch:
        """Everything recorded since the last read (empty arrays when nothing new)."""
        ...

    def stop_joint_stream(self, timeout: float) -> JointStreamBatch:
        """Stop recording; returns what was recorded since the last read."""
        ...

    def start_move(self, q: Sequence[float], speed: Sequence[float], acceleration: Sequence[float],
                   timeout: float) -> None:
        """Begin a move to ``q`` and return at once (the move's checks as in ``move_joints``)."""
        ...

    def motion_done(self) -> bool:
        """True once the move begun by ``start_move`` has ended; raises RobotFault (protective stop...),
        ConnectionFailed."""
        ...


@runtime_checkable
class StreamingTracker(Protocol):
    """A tracker that streams timestamped positions at its own rate."""

    def start_stream(self, rate: float, timeout: float) -> float:
        """Start streaming at about ``rate`` Hz; returns the rate the device runs at."""
        ...

    def read_stream(self) -> TrackerStreamBatch:
        """Every sample since the last read (empty arrays when nothing new); never blocks."""
        ...

    def stop_stream(self, timeout: float) -> TrackerStreamBatch:
        """Stop streaming; returns the samples since the last read."""
        ...
