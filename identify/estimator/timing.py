"""Timing of streamed samples (continuous motion): joints interpolated in time, and the clock offset between a
tracker's clock and the robot's estimated from the data (pure functions on numpy arrays; no devices, no files).

Clocks: the robot's joint stream is stamped by the controller (robot time, s); the tracker's samples by the
tracker (tracker time, s). A tracker sample stamped ``t`` was taken at robot time ``t + offset``;
:func:`coarse_clock_offset` estimates ``offset`` by cross-correlating speed profiles: the TP's speed
``|dp/dt|`` (m/s, from the tracker samples) against the joints' speed ``|dq/dt|`` (rad/s or m/s, from the joint
stream) over each sweep, both on a common grid. In a one-joint sweep at constant speed the TP speed is the
joint speed times a constant radius, so the two profiles (a trapezoid: ramp up, cruise, ramp down) differ
only in scale and in the time shift sought; the correlation of their z-scores peaks at it. The estimate is a
start for the identification's joint fit of offset and drift (identify/estimator/sync.py), not the final timing.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

SPEED_WINDOW = 0.02  # s: speeds are differences of positions this far apart (centred)
GRID_STEP = 1e-3  # s: the common grid of the speed profiles, and the lag resolution before refinement
MAX_LAG = 0.5  # s: the offset is searched this far either side of the streams' start difference


@dataclass(frozen=True)
class SweepStreams:
    """One sweep's streams: tracker times ``t_tracker`` (k,) s and TP positions ``points`` (k, 3) m (one tracked
    point), robot times ``t_joint`` (j,) s and joint readings ``q_joint`` (j, n)."""

    t_tracker: Array
    points: Array
    t_joint: Array
    q_joint: Array


@dataclass(frozen=True)
class ClockOffset:
    """The estimated offset (s: robot time = tracker time + offset), the peak of the correlation summed over
    the sweeps; ``per_sweep`` each sweep's own peak (s; NaN where a sweep had too little overlap);
    ``correlation`` the peak value of the summed, normalised correlation (1: identical shapes)."""

    offset: float
    per_sweep: tuple[float, ...]
    correlation: float


def interpolate_joints(t_joint: Array, q_joint: Array, t: Array, gaps: Sequence[tuple[float, float]] = (),
                       max_spacing: float | None = None) -> tuple[Array, NDArray[np.bool_]]:
    """Joint readings at robot times ``t`` (m,) by linear interpolation of the stream (``t_joint`` (j,) s,
    increasing; ``q_joint`` (j, n)): returns q (m, n) and ``ok`` (m,): False outside the recorded stream, within
    one sample period (the median spacing) of a recorded gap (``gaps``: (start, end) robot times), or between
    two samples more than ``max_spacing`` s apart (default 1.5 sample periods: an unrecorded gap). Rows that are
    not ok hold the nearest interpolation but must not be used."""
    tj = np.asarray(t_joint, dtype=float)
    qj = np.asarray(q_joint, dtype=float).reshape(len(tj), -1)
    t = np.asarray(t, dtype=float)
    if len(tj) < 2:
        return np.full((len(t), qj.shape[1]), np.nan), np.zeros(len(t), dtype=bool)
    if np.any(np.diff(tj) <= 0):
        raise ValueError("joint stream times must increase")
    period = float(np.median(np.diff(tj)))
    limit = 1.5 * period if max_spacing is None else float(max_spacing)
    ok = (t >= tj[0]) & (t <= tj[-1])
    i = np.clip(np.searchsorted(tj, t, side="right") - 1, 0, len(tj) - 2)
    ok &= (tj[i + 1] - tj[i]) <= limit + 1e-12
    for start, end in gaps:
        ok &= ~((t >= start - period) & (t <= end + period))
    q = np.column_stack([np.interp(t, tj, qj[:, k]) for k in range(qj.shape[1])])
    return q, ok


def _speed(times: Array, values: Array, grid: Array, window: float) -> Array:
    """|d values / dt| (on ``grid``) from centred differences ``window`` s apart of the linear interpolation."""
    values = values.reshape(len(times), -1)
    ahead = np.column_stack([np.interp(grid + window / 2, times, values[:, k]) for k in range(values.shape[1])])
    behind = np.column_stack([np.interp(grid - window / 2, times, values[:, k]) for k in range(values.shape[1])])
    return np.linalg.norm(ahead - behind, axis=1) / window


def _zscore(x: Array) -> Array:
    spread = float(np.std(x))
    return (x - np.mean(x)) / spread if spread > 0 else np.zeros_like(x)


def _correlation(sweep: SweepStreams, start: float, lags: NDArray[np.int64], step: float,
                 window: float) -> Array | None:
    """Normalised correlation (len(lags),) of the sweep's TP speed and joint speed, the joint profile read at
    tracker time + ``start`` + lag·``step``; None when the streams overlap too little."""
    tt, tj = np.asarray(sweep.t_tracker, dtype=float), np.asarray(sweep.t_joint, dtype=float)
    if len(tt) < 4 or len(tj) < 4:
        return None
    span = int(np.max(np.abs(lags)))
    lo = max(tt[0], tj[0] - start) + window
    hi = min(tt[-1], tj[-1] - start) - window
    count = int((hi - lo) / step) - 2 * span
    if count < 20:
        return None
    grid = lo + step * (span + np.arange(count))  # tracker times where every lag stays inside both streams
    tp = _zscore(_speed(tt, np.asarray(sweep.points, dtype=float), grid, window))
    wide = lo + step * np.arange(count + 2 * span)
    joint = _speed(tj, np.asarray(sweep.q_joint, dtype=float), wide + start, window)
    out = np.empty(len(lags))
    for k, lag in enumerate(lags):
        out[k] = float(np.mean(tp * _zscore(joint[span + lag: span + lag + count])))
    return out


def _peak(values: Array) -> tuple[float, float]:
    """(index of the maximum refined by a parabola through it and its neighbours, the maximum)."""
    k = int(np.argmax(values))
    if 0 < k < len(values) - 1:
        a, b, c = values[k - 1], values[k], values[k + 1]
        curvature = a - 2 * b + c
        if curvature < 0:
            shift = 0.5 * (a - c) / curvature
            return k + shift, float(b - 0.25 * (a - c) * shift)
    return float(k), float(values[k])


def coarse_clock_offset(sweeps: Sequence[SweepStreams], max_lag: float = MAX_LAG, step: float = GRID_STEP,
                        window: float = SPEED_WINDOW) -> ClockOffset:
    """The offset (s, robot time = tracker time + offset) that best aligns the TP speed with the joint speed
    over all ``sweeps`` (their correlations summed), searched within ``max_lag`` s of the median difference of
    the streams' first samples (both streams start together, so that difference is right to within the start
    skew and the latency); ``step`` the grid and lag resolution (s, refined by a parabola), ``window`` the
    differencing span of the speeds (s). ValueError when no sweep has enough overlapping samples."""
    starts = [float(s.t_joint[0] - s.t_tracker[0]) for s in sweeps if len(s.t_joint) and len(s.t_tracker)]
    if not starts:
        raise ValueError("no sweep has samples of both streams")
    start = float(np.median(starts))
    span = round(max_lag / step)
    lags = np.arange(-span, span + 1)
    curves = [_correlation(s, start, lags, step, window) for s in sweeps]
    used = [c for c in curves if c is not None]
    if not used:
        raise ValueError("the streams of no sweep overlap long enough to estimate the clock offset")
    index, value = _peak(np.sum(used, axis=0) / len(used))
    per_sweep = tuple(float(start + step * (lags[0] + _peak(c)[0])) if c is not None else float("nan")
                      for c in curves)
    return ClockOffset(float(start + step * (lags[0] + index)), per_sweep, value)
