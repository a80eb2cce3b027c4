"""Continuous motion for the UR driver: the joint stream and moves that return at once (implements
:class:`drivers.base.StreamingRobot` for :class:`drivers.ur.driver.URRobot`, which inherits this mixin).

- The joint stream is recorded in the worker process (drivers/ur/recorder.py) at the controller's native RTDE
  rate (option ``rtde_frequency``; default 500 Hz e-Series, 125 Hz CB3) with the controller's timestamps
  (``getTimestamp()``: s on the controller's clock, not the host's). Gaps (a dropped package, a stream that
  stood still) are recorded there as (start, end) controller times.
- ``read_joint_stream`` fetches what the worker holds in requests of at most :data:`BATCH` samples (no reply
  grows without bound); a call takes at most :data:`MAX_REQUESTS` of them and leaves the rest for the next.
- A lost link (LinkLost) while streaming: the driver starts a fresh worker as for any operation
  (``reconnects``), starts its recorder, and records a gap from the last sample it received to the first sample
  of the new recorder. What the dead worker held and had not handed over lies inside that gap.
- ``start_move`` sends the asynchronous moveJ (same checks as ``move_joints``) and returns; ``motion_done``
  reads one state snapshot and ur_rtde's async progress: False while the arm moves; True once it is at the
  target and still; raises ProtectiveStop / EmergencyStop / RobotFault from the controller's state, RobotFault
  when the move was stopped (``stop()``) or ended short of its target, DeviceTimeout (the arm is stopped) after
  the ``start_move`` timeout, ConnectionFailed when the link is lost for good. A move cut by a lost link is
  commanded again to the same target from the fresh worker. A KeyboardInterrupt (Ctrl-C) inside
  ``motion_done`` or ``read_joint_stream`` while a move runs stops the arm.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.base import Array, JointStreamBatch
from drivers.errors import DeviceTimeout, RobotFault

BATCH = 5000  # samples per stream_read request (10 s at 500 Hz; about 300 kB pickled)
MAX_REQUESTS = 20  # stream_read requests per read_joint_stream call
POSITION_TOLERANCE = 1e-3  # rad, as drivers/ur/driver.py: arrived when every joint is this close to its target
#: s a still arm short of its target with no async move running must last to count as a move that ended early
#: (the progress comes from the control interface's RTDE connection, the joints from the receive one: either
#: may be a package ahead of the other)
EARLY_END_HOLD = 0.25


@dataclass
class _Motion:
    """The move begun by start_move: target, per-joint speed and acceleration, host deadline, timeout, stop count,
    the worker that got the command, since when (host monotonic s) it has looked ended short of its target."""

    target: Array
    speed: Array
    acceleration: Array
    deadline: float
    timeout: float
    stops: int
    worker: Any
    short_since: float | None = None


class JointStreaming:
    """The streaming half of URRobot (see the module docstring). Needs URRobot's ``_linked``, ``_call``,
    ``_checked``, ``_checked_snapshot``, ``_command_move``, ``_raise_if_stopped``, ``stop``, ``_worker``,
    ``host``, ``still_speed``, ``rtde_frequency``."""

    _worker: Any
    host: str
    joint_types: str
    still_speed: float
    rtde_frequency: float
    _stops: int
    _linked: Any
    _call: Any
    _checked: Any
    _checked_snapshot: Any
    _command_move: Any
    _raise_if_stopped: Any
    stop: Any

    def _init_stream(self) -> None:
        self._streaming = False
        self._stream_worker: Any = None  # the worker whose recorder runs
        self._last_t: float | None = None  # controller time of the last sample handed to the caller
        self._restarted = False  # a fresh worker's recorder: a gap from _last_t to its first sample
        self._acc: tuple[list[float], list[list[float]], list[tuple[float, float]]] = ([], [], [])
        self._motion: _Motion | None = None
        self.stream_stats: dict[str, float] | None = None  # the last stopped recorder's counters

    # --- joint stream ---------------------------------------------------------------------------------------

    def start_joint_stream(self, timeout: float) -> float:
        """Start recording (a running recording is restarted); returns the native rate, Hz."""
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout!r}")
        self._streaming, self._last_t, self._restarted, self._acc = True, None, False, ([], [], [])
        self._stream_worker = None
        self._linked(self._ensure_recorder)
        return float(self.rtde_frequency)

    def _ensure_recorder(self) -> None:
        """Start the recorder in the current worker unless it runs there (a fresh worker: mark the gap)."""
        if self._streaming and self._stream_worker is not self._worker:
            self._call("stream_start", float(self.rtde_frequency))
            self._restarted = self._stream_worker is not None or self._last_t is not None
            self._stream_worker = self._worker

    def read_joint_stream(self) -> JointStreamBatch:
        """Every sample recorded since the last read (empty arrays when nothing new, or no stream runs)."""
        if self._streaming:
            try:
                self._linked(self._fetch)
            except KeyboardInterrupt:
                if self._motion is not None:
                    self._motion = None
                    self.stop()
                raise
        return self._hand_out()

    def stop_joint_stream(self, timeout: float) -> JointStreamBatch:
        """Stop recording; returns the samples since the last read. ``stream_stats`` then holds the recorder's
        counters (kept, gaps, torn, polls, longest_still, period)."""
        if not timeout > 0:
            raise ValueError(f"timeout must be > 0 s, got {timeout!r}")
        if self._streaming:
            try:
                self._linked(lambda: self._fetch(drain=True))
                self.stream_stats = self._linked(lambda: self._call("stream_stop"))
            finally:
                self._streaming, self._stream_worker = False, None
        return self._hand_out()

    def _fetch(self, drain: bool = False) -> None:
        """Take the worker's samples into the accumulator (kept across a lost link)."""
        self._ensure_recorder()
        ts, qs, gaps = self._acc
        for _ in range(MAX_REQUESTS * (50 if drain else 1)):
            t, q, g, left = self._call("stream_read", BATCH)
            if t and self._restarted:
                before = ts[-1] if ts else self._last_t
                if before is not None:
                    gaps.append((float(before), float(t[0])))
                self._restarted = False
            ts.extend(t)
            qs.extend(q)
            gaps.extend((float(a), float(b)) for a, b in g)
            if not left:
                break

    def _hand_out(self) -> JointStreamBatch:
        ts, qs, gaps = self._acc
        self._acc = ([], [], [])
        n = len(self.joint_types)
        t = np.asarray(ts, dtype=float)
        q = np.asarray(qs, dtype=float).reshape(len(ts), n)
        if len(t):
            self._last_t = float(t[-1])
        return JointStreamBatch(t, q, tuple(sorted(gaps)))

    # --- moves that return at once --------------------------------------------------------------------------

    def start_move(self, q: Sequence[float], speed: Sequence[float], acceleration: Sequence[float],
                   timeout: float) -> None:
        """Send an asynchronous moveJ to ``q`` and return; ``timeout`` (s) bounds the whole move (see
        ``motion_done``). Checks as in ``move_joints``."""
        stops = self._stops
        target, v, a = self._checked(q, speed, acceleration, timeout)
        motion = _Motion(target, v, a, time.monotonic() + timeout, timeout, stops, None)
        self._motion = motion
        try:
            self._linked(lambda: self._send_motion(motion))
        except KeyboardInterrupt:
            self.stop()
            raise
        except BaseException:
            self._motion = None
            raise

    def _send_motion(self, motion: _Motion) -> None:
        self._ensure_recorder()
        self._command_move(motion.target, motion.speed, motion.acceleration, motion.stops)
        motion.worker, motion.short_since = self._worker, None

    def motion_done(self) -> bool:
        """True once the move begun by ``start_move`` has ended at its target (True when none was begun); see
        the module docstring for what it raises."""
        motion = self._motion
        if motion is None:
            return True
        try:
            done = bool(self._linked(lambda: self._poll_motion(motion)))
        except KeyboardInterrupt:
            self._motion = None
            self.stop()
            raise
        except BaseException:
            self._motion = None
            raise
        if done:
            self._motion = None
        return done

    def _poll_motion(self, motion: _Motion) -> bool:
        if motion.worker is not self._worker:  # a fresh worker after a lost link: command the move again
            self._send_motion(motion)
        self._ensure_recorder()
        _, _, _, _, actual, qd, _ = self._checked_snapshot()
        self._raise_if_stopped(motion.stops)
        still = max(map(abs, qd)) < self.still_speed
        if np.max(np.abs(np.asarray(actual) - motion.target)) < POSITION_TOLERANCE and still:
            return True
        now = time.monotonic()
        if not (still and int(self._call("progress")) < 0):
            motion.short_since = None
        elif motion.short_since is None:
            motion.short_since = now
        elif now - motion.short_since > EARLY_END_HOLD:
            far = float(np.max(np.abs(np.asarray(actual) - motion.target)))
            raise RobotFault(f"the move of the UR robot at {self.host} ended {far:.4f} rad short of its target "
                             "(the controller finished it without a fault); check the teach pendant")
        if now >= motion.deadline:
            self.stop()
            raise DeviceTimeout(f"the UR robot at {self.host} did not reach its target within {motion.timeout:g} "
                                "s; it was stopped (stopJ)")
        return False
