"""The simulated rig's streams (continuous motion): the robot's joint stream, a non-blocking move, the tracker's stream.

Clocks. The rig's clock (a ``VirtualClock`` in mock mode) is the physical time τ and the robot controller's clock:
joint samples are stamped with the τ they were taken at. The tracker has a clock of its own: a position taken at
physical time τ is stamped ``τ + latency + clock_offset + drift·(τ - epoch) + N(0, jitter)`` (s; ``epoch`` the
rig's creation) and delivered ``latency`` s after τ. So a tracker sample stamped ``t`` was taken at robot time
``t - latency - clock_offset`` when drift and jitter are zero: the clock offset a session should find is
``-(latency + clock_offset)``.

Streams (spec options, drivers/spec.py): ``mock:MODEL?rate=500&drop=P`` (joint samples every 1/rate s of the
robot clock; each packet lost with probability P, the lost stretch reported as a gap between the kept samples
around it); ``mock?rate=250&latency=0.02&clock_offset=0.1&drift=1e-3&stamp_jitter=1e-4&lost=0.5@2`` (tracker samples
every 1/rate s of physical time, each reflector with the rig's noise; ``lost=D@S``: the target is out of sight
for D s from S s into every stream, reported as a gap); in 6-DoF mode (``orientation=SIGMA_R``) each sample also
carries its target frame's orientation, turned by the orientation noise as a polled reading's (drivers/sim/tracker.py).
Reads return every sample delivered between the last
read and ``clock.now()``; nothing blocks.

A streamed move (:meth:`JointStreaming.start_move`) follows the synchronised trapezoidal profile of a blocking
move (drivers/motion.py) while the clock runs; ``motion_done`` ends it. Faults as for blocking moves, counted per
move: ``protective_stop``/``emergency_stop`` stop it halfway (``motion_done`` raises once the clock gets there),
``slow`` never lets it finish, ``disconnect`` raises at once. A move still running when its ``timeout`` (s from
``start_move``) has passed is stopped there and ``motion_done`` raises DeviceTimeout, as for a blocking move.
The kinematics are the rig's (``true_points``), never computed here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

from drivers.base import Array, JointStreamBatch, RobotState, TrackerStreamBatch
from drivers.errors import ConnectionFailed, DeviceTimeout, EmergencyStop, ProtectiveStop
from drivers.sim.stream_model import TIME_EPS, StreamedMove

if TYPE_CHECKING:
    from drivers.sim.rig import SimulatedRig


class JointStreaming:
    """The simulated robot's :class:`drivers.base.StreamingRobot` methods (mixed into ``SimulatedRobot``)."""

    rig: SimulatedRig

    def start_joint_stream(self, timeout: float) -> float:
        """Start recording at the rig's joint rate (Hz, returned); the first sample is the next tick."""
        self._require_link()  # type: ignore[attr-defined]
        rate = self.rig.stream.joint_rate
        self._joint_next = math.ceil(self.rig.clock.now() * rate - 1e-6) / rate
        self._joint_last_kept: float | None = None
        self._joint_streaming = True
        return rate

    def read_joint_stream(self) -> JointStreamBatch:
        """Joint samples (controller clock = the rig's) since the last read; lost packets become gaps."""
        n = self.rig.model.n_joints
        if not getattr(self, "_joint_streaming", False):
            return JointStreamBatch(np.zeros(0), np.zeros((0, n)))
        self._require_link()  # type: ignore[attr-defined]
        rig, rate = self.rig, self.rig.stream.joint_rate
        count = max(0, math.floor((rig.clock.now() - self._joint_next) * rate + 1e-6) + 1)
        t = self._joint_next + np.arange(count) / rate
        self._joint_next += count / rate
        kept = rig._stream_rng.random(count) >= rig.stream.drop if rig.stream.drop > 0 else np.ones(count, bool)
        t = t[kept]
        gaps = []
        previous = self._joint_last_kept
        for value in t:
            if previous is not None and value - previous > 1.5 / rate:
                gaps.append((float(previous), float(value)))
            previous = float(value)
        self._joint_last_kept = previous
        q = rig.actual_joints(t) if len(t) else np.zeros((0, n))
        return JointStreamBatch(t, q.reshape(len(t), n), tuple(gaps))

    def stop_joint_stream(self, timeout: float) -> JointStreamBatch:
        """Stop recording; what was recorded since the last read."""
        batch = self.read_joint_stream()
        self._joint_streaming = False
        return batch

    def start_move(self, q: Sequence[float], speed: Sequence[float], acceleration: Sequence[float],
                   timeout: float) -> None:
        """Begin a move to the readings ``q`` (checks and faults as ``move_joints``) and return at once."""
        rig = self.rig
        self._require_link()  # type: ignore[attr-defined]
        if rig._latched is not None:
            error = ProtectiveStop if rig._latched is RobotState.PROTECTIVE_STOP else EmergencyStop
            raise error(f"the simulated robot is in {rig._latched.value}: clear it (rig.clear_faults()), then resume")
        target, v, a = self._checked(q, speed, acceleration, timeout)  # type: ignore[attr-defined]
        number = rig.moves = rig.moves + 1
        fault = rig._take("robot", number)
        if fault == "disconnect":
            rig.robot_connected = False
            raise ConnectionFailed(f"lost the connection to the simulated robot at move {number}")
        move = StreamedMove(rig.rest_joints, target, v, a, rig.clock.now())
        if fault == "slow":
            move.t_stop, move.duration = move.t0, math.inf  # stuck: never arrives
        elif fault in ("protective_stop", "emergency_stop"):
            move.t_stop = move.t0 + move.duration / 2
        self._fault, self._number, self._deadline = fault, number, move.t0 + float(timeout)
        rig._path, rig._moving, rig._stop_requested = move, True, False

    def motion_done(self) -> bool:
        """True once the streamed move has ended (reached, or cut short by ``stop()``); ProtectiveStop /
        EmergencyStop when the clock passes a scheduled stop; ConnectionFailed without a link."""
        rig = self.rig
        self._require_link()  # type: ignore[attr-defined]
        move = rig._path
        if move is None or not rig._moving:
            return True
        now = rig.clock.now()
        if rig._stop_requested and move.t_stop > now:
            move.t_stop = now
        late = now >= self._deadline and move.t_end > self._deadline  # still moving when its time was up
        if late:
            move.t_stop = self._deadline
        elif move.duration == math.inf and not rig._stop_requested:
            return False
        if now < move.t_end - TIME_EPS:
            return False
        reached = move.joints(np.array([move.t_end]))[0]
        rig._moving, move.finished = False, True
        rig._rest = reached + rig._robot_rng.normal(0.0, rig.repeatability, len(reached))
        rig._ring_amp = rig.ring * rig._robot_rng.uniform(0.5, 1.0, len(reached)) * \
            rig._robot_rng.choice([-1.0, 1.0], len(reached))
        rig._ring_start, rig._ring_decays = move.t_end, True
        if self._fault in ("protective_stop", "emergency_stop"):
            rig._latched = RobotState.PROTECTIVE_STOP if self._fault == "protective_stop" else \
                RobotState.EMERGENCY_STOP
            error = ProtectiveStop if self._fault == "protective_stop" else EmergencyStop
            raise error(f"simulated {rig._latched.value} during move {self._number}: clear it (rig.clear_faults()), "
                        "then resume")
        rig._stop_requested = False  # stopped by stop(): the move has ended too
        if late:
            raise DeviceTimeout(f"move {self._number} needs {move.duration:.3f} s, more than its timeout of "
                                f"{self._deadline - move.t0:g} s; the robot was stopped")
        return True


class TrackerStreaming:
    """The simulated tracker's :class:`drivers.base.StreamingTracker` methods (mixed into ``SimulatedTracker``)."""

    rig: SimulatedRig

    def start_stream(self, rate: float, timeout: float) -> float:
        """Start streaming; the device runs at its own rate (the ``rate`` option, Hz, returned)."""
        rig = self.rig
        if not rig.tracker_connected:
            raise ConnectionFailed("the simulated tracker is not connected (call connect())")
        if not rate > 0 or not timeout > 0:
            raise ValueError(f"rate and timeout must be > 0, got {rate!r} Hz and {timeout!r} s")
        now = rig.clock.now()
        duration, start = rig.stream.lost
        self._tracker_next = now  # physical time of the next sample
        self._lost = (now + start, now + start + duration) if duration > 0 else None
        self._lost_reported = False
        self._tracker_streaming = True
        return rig.stream.tracker_rate

    def tracker_time(self, tau: Array) -> Array:
        """The tracker's timestamps (s, its clock) of positions taken at physical times ``tau``, without jitter."""
        rig, s = self.rig, self.rig.stream
        tau = np.asarray(tau, dtype=float)
        return tau + rig.latency + s.clock_offset + s.drift * (tau - rig.stream_epoch)

    def read_stream(self) -> TrackerStreamBatch:
        """Samples delivered since the last read: every reflector at each sample time, stamped on the tracker's
        clock; the stretch the target was lost (``lost``) as a gap once it is over."""
        rig = self.rig
        if not getattr(self, "_tracker_streaming", False):
            return _empty_tracker_batch()
        if not rig.tracker_connected:
            raise ConnectionFailed("the simulated tracker is not connected")
        rate = rig.stream.tracker_rate
        count = max(0, math.floor((rig.clock.now() - rig.latency - self._tracker_next) * rate + 1e-6) + 1)
        tau = self._tracker_next + np.arange(count) / rate
        self._tracker_next += count / rate
        gaps: tuple[tuple[float, float], ...] = ()
        if self._lost is not None:
            lo, hi = self._lost
            tau = tau[(tau < lo) | (tau > hi)]
            if not self._lost_reported and self._tracker_next > hi:
                gaps = ((float(self.tracker_time(lo)), float(self.tracker_time(hi))),)
                self._lost_reported = True
        if not len(tau):
            return _empty_tracker_batch(gaps)
        points = rig.true_points(tau)  # (k, points, 3)
        points = points + rig._tracker_rng.normal(0.0, rig.noise, points.shape)
        stamps = self.tracker_time(tau)
        if rig.stream.jitter > 0:
            stamps = stamps + rig._stream_rng.normal(0.0, rig.stream.jitter, len(stamps))
        k, p = points.shape[:2]
        rotvec = sigma_r = None
        if rig.orientation > 0:  # 6-DoF mode: each target frame turned by the orientation noise (own generator)
            frames = rig.true_frames(tau)  # (k, points, 3, 3)
            turns = Rotation.from_rotvec(rig._orientation_rng.normal(0.0, rig.orientation, (k * p, 3))).as_matrix()
            rotvec = Rotation.from_matrix(turns @ frames.reshape(k * p, 3, 3)).as_rotvec()
            sigma_r = np.full(k * p, rig.orientation)
        return TrackerStreamBatch(np.repeat(stamps, p), points.reshape(k * p, 3),
                                  np.tile(np.arange(1, p + 1, dtype=np.int64), k), np.full(k * p, rig.noise), gaps,
                                  rotvec, sigma_r)

    def stop_stream(self, timeout: float) -> TrackerStreamBatch:
        """Stop streaming; the samples since the last read."""
        batch = self.read_stream()
        self._tracker_streaming = False
        return batch


def robot_time_of_stamps(details: dict[str, str], t: Array) -> Array:
    """The robot-clock times (s) at which a simulated tracker took the positions it stamped ``t`` (s, its clock),
    without jitter: the inverse of :meth:`TrackerStreaming.tracker_time`, from the tracker identity's ``details``
    (a session header's ``tracker.details``: latency, clock_offset, drift, clock_epoch). ``result - t`` is what a
    session's clock fit should find as its offset (robot time = tracker time + offset)."""
    latency, offset, drift, epoch = (float(details[k]) for k in ("latency", "clock_offset", "drift", "clock_epoch"))
    return (np.asarray(t, dtype=float) - latency - offset + drift * epoch) / (1 + drift)


def _empty_tracker_batch(gaps: tuple[tuple[float, float], ...] = ()) -> TrackerStreamBatch:
    return TrackerStreamBatch(np.zeros(0), np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros(0), gaps)
