"""Clock synchronisation of streamed rows, fitted jointly with the kinematics.

In continuous motion the tracker and the robot sample on their own clocks. A streamed row's joint values
were interpolated from the robot's joint stream at robot time ``t + clock_offset`` (``t``: the row's tracker
time, s); the true mapping differs from that by a small correction

    shift(t) = tau_0 + tau_1 · (t − t_ref)        (s; tau_1: the relative clock drift, dimensionless)

and the row's joint values are the trajectory at ``t + shift(t)``. The trajectory of a sweep is the
piecewise-parabolic curve through its own streamed rows (time, joint values; each interval's parabola through
its two rows and the nearest row beyond: a chord would miss the ramps of a move streamed at 10 reports/s by
more than the tracker noise); it is cut wherever the rows leave a gap (a lost target, dropped joint packets:
more than ``GAP_FACTOR`` median sample intervals), and a shifted time beyond a segment's end is extrapolated
on its last interval's parabola, never across a gap.

One offset serves every sweep while the clocks keep one relation. A resume after a tracker or controller
restart, or a timestamp jump, breaks it between sweeps: :meth:`Retiming.per_sweep` gives each streamed sweep
its own offset (the drift stays common); the pipeline switches to it when a score test says the sweeps'
offsets differ.

:class:`Retiming` carries that model through the fit: :class:`identify.estimator.poe.LineProblem` adds ``tau`` to
its parameters (after the lines, tracked points and joint errors), so the offset comes with its
uncertainty from the same covariance as the kinematics.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

GAP_FACTOR = 5.0  # a step in time over this many median intervals cuts a sweep's trajectory
DRIFT_SPAN = 10.0  # s: streamed rows spanning longer than this also fit the clock drift


@dataclass(frozen=True)
class Segment:
    """One uninterrupted piece of a sweep's trajectory: ``t`` (k,) increasing tracker times (s), ``q`` (k, n)
    joint values at them."""

    t: Array
    q: Array


@dataclass(frozen=True)
class Retiming:
    """The clock correction of the streamed rows of a fit. Per row (m,): ``t`` tracker time (s, NaN for
    rows not streamed) and ``segment`` (index into ``segments``, -1 for rows not streamed); per segment its
    ``sweep`` id and ``offset_of`` (which offset applies to it). ``tau``: the ``offsets`` offsets (s), then
    the drift when fitted; ``t_ref`` (s) the time the offsets refer to; ``free``: fitted (else held at
    ``tau``)."""

    t: Array
    segment: NDArray[np.int64]
    segments: tuple[Segment, ...]
    t_ref: float
    tau: Array
    sweep: NDArray[np.int64]
    offset_of: NDArray[np.int64]
    offsets: int = 1
    free: bool = True
    own_drift: Array | None = None  # per offset: the time (s) its own drift refers to; None: one common drift

    @property
    def size(self) -> int:
        """Number of fitted parameters (0 when held)."""
        return len(self.tau) if self.free else 0

    @property
    def rows(self) -> NDArray[np.bool_]:
        return self.segment >= 0

    @property
    def drift(self) -> bool:
        """Whether the drift is part of ``tau`` (after the offsets)."""
        return len(self.tau) > self.offsets

    def per_sweep(self) -> Retiming:
        """The same correction with one offset per streamed sweep (each starting at its current offset), the
        drift, if fitted, common."""
        ids, first, offset_of = np.unique(self.sweep, return_index=True, return_inverse=True)
        tau = np.concatenate([self.tau[: self.offsets][self.offset_of[first]], self.tau[self.offsets:]])
        return replace(self, tau=tau, offset_of=offset_of.astype(np.int64), offsets=len(ids))

    def local(self) -> Retiming:
        """One offset and one drift per streamed sweep, each drift about the middle of its sweep's time span,
        starting where this correction is: the freedom of a latency that wanders slowly between and within the
        sweeps. Within one sweep of joint j at constant speed v, a drift d of the latency moves the readings by
        v·d·(t − t_k), a reading scale error d on joint j: the joint-error selection competes with it
        (:mod:`identify.estimator.extend`)."""
        if self.own_drift is not None:
            return self
        per = self.per_sweep()
        k = per.offsets
        refs = np.empty(k)
        for o in range(k):
            times = np.concatenate([seg.t for seg, of in zip(self.segments, per.offset_of, strict=True) if of == o])
            refs[o] = 0.5 * float(times.min() + times.max())
        drift = float(self.tau[self.offsets]) if self.drift else 0.0
        offsets = per.tau[:k] + drift * (refs - self.t_ref)  # the same shift at every row
        return replace(per, tau=np.concatenate([offsets, np.full(k, drift)]), own_drift=refs)

    def offset_index(self) -> NDArray[np.int64]:
        """Per row (m,): the index of the offset that applies to it, -1 for rows not streamed."""
        return np.where(self.rows, self.offset_of[np.maximum(self.segment, 0)], -1)

    def subset(self, rows: NDArray[np.bool_] | NDArray[np.int64]) -> Retiming:
        return replace(self, t=self.t[rows], segment=self.segment[rows])

    def held(self, tau: Array | None = None) -> Retiming:
        """The same correction, not fitted (at ``tau``, default the current one)."""
        return replace(self, tau=self.tau if tau is None else np.asarray(tau, dtype=float), free=False)

    def shift(self, tau: Array | None = None) -> Array:
        """Time correction (s) of every streamed row, (r,) in row order of ``rows``."""
        tau = self.tau if tau is None else tau
        t = self.t[self.rows]
        which = self.offset_of[self.segment[self.rows]]
        out = np.asarray(tau[: self.offsets], dtype=float)[which]
        if len(tau) > self.offsets:
            if self.own_drift is None:
                out = out + tau[self.offsets] * (t - self.t_ref)
            else:
                out = out + np.asarray(tau[self.offsets:], dtype=float)[which] * (t - self.own_drift[which])
        return out

    def joints(self, q: Array, tau: Array | None = None) -> Array:
        """``q`` (m, n) with the streamed rows' joint values taken at their corrected times."""
        if not np.any(self.rows):
            return q
        out = q.copy()
        values, _ = self._at(self.shift(tau))
        out[self.rows] = values
        return out

    def derivatives(self, tau: Array | None = None) -> Array:
        """d(joint values)/d(tau) of the streamed rows, (r, n, K): the trajectory's speed (rad/s or m/s)
        times d(shift)/d(tau)."""
        _, speed = self._at(self.shift(tau))
        basis = np.zeros((len(speed), len(self.tau)))
        which = self.offset_of[self.segment[self.rows]]
        basis[np.arange(len(speed)), which] = 1.0
        if self.drift and self.own_drift is None:
            basis[:, self.offsets] = self.t[self.rows] - self.t_ref
        elif self.drift:
            basis[np.arange(len(speed)), self.offsets + which] = self.t[self.rows] - self.own_drift[which]
        return speed[:, :, None] * basis[:, None, :]

    def _at(self, shift: Array) -> tuple[Array, Array]:
        """Joint values and speeds of the streamed rows at their times plus ``shift``."""
        seg_of = self.segment[self.rows]
        times = self.t[self.rows] + shift
        n = self.segments[0].q.shape[1]
        values = np.empty((len(times), n))
        speed = np.empty((len(times), n))
        for s in np.unique(seg_of):
            here = seg_of == s
            values[here], speed[here] = _interpolate(self.segments[s], times[here])
        return values, speed


def _interpolate(segment: Segment, times: Array) -> tuple[Array, Array]:
    """Values and slopes of ``segment`` at ``times``: the parabola through the interval's two rows and the row
    beyond its nearer end (exact where the joint accelerates uniformly, as on a move's ramps, where a chord errs
    by acceleration × shift × (interval − shift) / 2: 0.4 mrad at 1 rad/s², 8 ms in 100 ms); times beyond the
    segment's ends on the end interval's parabola; a segment of two rows is a line."""
    t, q = segment.t, segment.q
    k = np.clip(np.searchsorted(t, times, side="right") - 1, 0, len(t) - 2)
    slope = (q[k + 1] - q[k]) / (t[k + 1] - t[k])[:, None]
    linear = q[k] + slope * (times - t[k])[:, None]
    if len(t) < 3:
        return linear, slope
    mid = 0.5 * (t[k] + t[k + 1])
    third = np.where(times < mid, k - 1, k + 2)
    third = np.where(third < 0, k + 2, np.where(third > len(t) - 1, k - 1, third))
    t3 = t[third]
    # second divided difference of (t_k, t_k+1, t_3): half the parabola's second derivative
    curvature = ((q[third] - q[k]) / (t3 - t[k])[:, None] - slope) / (t3 - t[k + 1])[:, None]
    dt0, dt1 = (times - t[k])[:, None], (times - t[k + 1])[:, None]
    return linear + curvature * dt0 * dt1, slope + curvature * (dt0 + dt1)


def retiming(t: Array, streamed: NDArray[np.bool_], sweep: NDArray[np.int64], q: Array) -> Retiming | None:
    """The clock correction model of a fit's rows (tracker times ``t`` (m,), ``streamed`` flags, ``sweep``
    ids, joint values ``q`` (m, n) as interpolated at recording), or None without streamed rows. The offset
    refers to the middle of the streamed rows' time span; the drift is fitted when they span over
    ``DRIFT_SPAN`` s."""
    usable = streamed & np.all(np.isfinite(q), axis=1) & np.isfinite(t)
    if not np.any(usable):
        return None
    segment = np.full(len(t), -1, dtype=np.int64)
    segments: list[Segment] = []
    sweep_of: list[int] = []
    for s in np.unique(sweep[usable]):
        rows = np.flatnonzero(usable & (sweep == s))
        times, first = np.unique(t[rows], return_index=True)  # several tracked points share a time
        if len(times) < 2:
            continue
        values = q[rows[first]]
        steps = np.diff(times)
        cuts = np.flatnonzero(steps > GAP_FACTOR * np.median(steps)) + 1
        bounds = [0, *cuts.tolist(), len(times)]
        for a, b in itertools.pairwise(bounds):
            if b - a < 2:
                continue
            inside = (t[rows] >= times[a]) & (t[rows] <= times[b - 1])
            segment[rows[inside]] = len(segments)
            segments.append(Segment(times[a:b], values[a:b]))
            sweep_of.append(int(s))
    if not segments:
        return None
    span = t[segment >= 0]
    t_ref = 0.5 * float(span.min() + span.max())
    k = 2 if float(span.max() - span.min()) > DRIFT_SPAN else 1
    return Retiming(np.where(segment >= 0, t, np.nan), segment, tuple(segments), t_ref, np.zeros(k),
                    np.array(sweep_of, dtype=np.int64), np.zeros(len(segments), dtype=np.int64))
