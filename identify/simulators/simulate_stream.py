"""Simulated continuous-motion data, for tests and benchmarks of the clock fit (pure math, seeded).

Each sweep is one trapezoidal move of one joint through its range (constant speed between the ramps). The
robot's controller samples the joints on its clock (``robot_rate`` Hz, the reference: physical time); the
tracker samples the tracked point on its own clock, whose stamps relate to robot time by

    robot time = tracker stamp + offset + drift · (tracker stamp − t_ref)

plus a timestamp ``jitter`` (s, RMS). A streamed row's joint values are the joint stream interpolated at
``tracker stamp + recorded_offset`` (what the acquisition's coarse estimate gives), so ``recorded_offset −
offset`` is the timing error the fit must remove. Tracker frame, metres, radians, seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from identify.estimator.measurements import Measurements
from identify.simulators.simulate import observe_frames
from kinematics.dh import DHModel, points_from_joints

Array = NDArray[np.float64]


def trapezoid(start: float, end: float, speed: float, acceleration: float, t: Array) -> Array:
    """Position at times ``t`` (s from the move's start) of a rest-to-rest move ``start`` → ``end`` with
    peak ``speed`` and ``acceleration`` (a triangle when the range is too short to reach the speed)."""
    distance = abs(end - start)
    direction = np.sign(end - start)
    ramp = min(speed / acceleration, np.sqrt(distance / acceleration))
    peak = acceleration * ramp
    cruise = (distance - acceleration * ramp**2) / peak if peak > 0 else 0.0
    total = 2 * ramp + cruise
    t = np.clip(t, 0.0, total)
    s = np.where(t < ramp, 0.5 * acceleration * t**2,
                 np.where(t < ramp + cruise, 0.5 * acceleration * ramp**2 + peak * (t - ramp),
                          distance - 0.5 * acceleration * (total - t) ** 2))
    return start + direction * s


def move_duration(start: float, end: float, speed: float, acceleration: float) -> float:
    """Duration (s) of :func:`trapezoid`'s move."""
    distance = abs(end - start)
    ramp = min(speed / acceleration, np.sqrt(distance / acceleration))
    peak = acceleration * ramp
    return 2 * ramp + ((distance - acceleration * ramp**2) / peak if peak > 0 else 0.0)


@dataclass(frozen=True)
class StreamSettings:
    """Rates (Hz), motion (rad/s, rad/s²), clocks (s; drift dimensionless) and noise (m per axis)."""

    robot_rate: float = 500.0
    tracker_rate: float = 250.0
    speed: float = 0.25
    acceleration: float = 1.0
    offset: float = -0.02  # robot time − tracker stamp: a tracker 20 ms late on the same clock
    drift: float = 0.0
    recorded_offset: float = -0.02
    jitter: float = 0.0
    noise: float = 2e-5
    pause: float = 2.0  # s between sweeps (the stop-and-go moves in between)


def streamed_sweeps(truth: DHModel, home: Array, ranges: list[tuple[int, float, float]], settings: StreamSettings,
                    rng: np.random.Generator, first_sweep: int = 1, frame: Array | None = None,
                    noise_r: float = 0.0) -> Measurements:
    """Streamed rows of sweeps ``ranges`` = [(joint 1-based, from, to), ...] of ``truth`` about ``home``
    (n,) joint values, in that order, one sweep id each from ``first_sweep``. With a target ``frame`` (3, 3, its
    rotation in the last DH frame) every row is a full-pose device's: the frame's orientation at the sample's true
    time, turned by ``noise_r`` rad per axis (drawn after the positions' noise), with both sigmas declared."""
    s = settings
    n = len(home)
    rows_q, rows_p, rows_t, sweep, joint, true_q = [], [], [], [], [], []
    clock = 0.0  # robot time at the next sweep's start
    t_ref = 0.0
    for k, (j, lo, hi) in enumerate(ranges):
        duration = move_duration(lo, hi, s.speed, s.acceleration)
        robot_t = clock + np.arange(0.0, duration + 0.5, 1.0 / s.robot_rate)  # from the start to 0.5 s after
        q_stream = np.tile(home, (len(robot_t), 1))
        q_stream[:, j - 1] = trapezoid(lo, hi, s.speed, s.acceleration, robot_t - clock)
        # tracker samples: physical (robot) times on the tracker's grid
        stamps = (clock - s.offset) + np.arange(0.1, duration + 0.4, 1.0 / s.tracker_rate)
        physical = stamps + s.offset + s.drift * (stamps - t_ref)
        q_true = np.tile(home, (len(physical), 1))
        q_true[:, j - 1] = trapezoid(lo, hi, s.speed, s.acceleration, physical - clock)
        points = points_from_joints(truth, q_true) + rng.normal(0.0, s.noise, (len(physical), 3))
        stamped = stamps + rng.normal(0.0, s.jitter, len(stamps)) if s.jitter else stamps
        at = stamped + s.recorded_offset
        q_rows = np.column_stack([np.interp(at, robot_t, q_stream[:, i]) for i in range(n)])
        rows_q.append(q_rows)
        rows_p.append(points)
        true_q.append(q_true)
        rows_t.append(stamped)
        sweep.append(np.full(len(at), first_sweep + k))
        joint.append(np.full(len(at), j))
        clock += duration + 0.5 + s.pause
    m = sum(len(t) for t in rows_t)
    posed = {}
    if frame is not None:
        posed = {"rotvec": observe_frames(truth, frame, np.vstack(true_q), rng, noise_r),
                 "sigma_r": np.full(m, noise_r), "sigma": np.full(m, s.noise)}
    return Measurements(truth.joint_types, np.vstack(rows_q), np.vstack(rows_p), np.concatenate(sweep),
                        np.concatenate(joint), t=np.concatenate(rows_t), streamed=np.ones(m, dtype=bool),
                        clock_offset=s.recorded_offset, **posed)


def joined(*parts: Measurements) -> Measurements:
    """The rows of ``parts`` in one data set (rows without a time get NaN)."""
    first = parts[0]

    def times(p: Measurements) -> Array:
        return np.full(len(p), np.nan) if p.t is None else p.t

    return Measurements(
        first.joint_types, np.vstack([p.q for p in parts]), np.vstack([p.points for p in parts]),
        np.concatenate([p.sweep for p in parts]), np.concatenate([p.joint for p in parts]),
        check=np.concatenate([p.check for p in parts]), tp=np.concatenate([p.tp for p in parts]),
        t=np.concatenate([times(p) for p in parts]), streamed=np.concatenate([p.streamed for p in parts]),
        clock_offset=next((p.clock_offset for p in parts if p.has_streams), 0.0))
