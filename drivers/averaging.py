"""Client-side averaging of raw tracker samples into one reading, with outlier rejection.

Used by drivers whose device cannot average by itself (e.g. an I++ DME server without an averaging
property): the driver takes N raw samples of a still target and reports their robust mean.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation
from scipy.stats import f as f_dist

Array = NDArray[np.float64]

REJECT_SIGMAS = 5.0  # a sample farther than this many robust sigmas from the median is an outlier
CHI3_MEDIAN = 1.5382  # median of the 3D distance of isotropic unit-sigma noise (chi, 3 degrees of freedom)
SPREAD_SIGNIFICANCE = 0.01  # false-alarm rate of the test "frames scatter more than the model says"
SPREAD_FLOOR = 1e-7  # m: below this a spread is the reply's resolution (0.1 µm), not noise


def mean_orientation(rotvecs: Array) -> tuple[Array, float | None]:
    """The chordal mean (a rotation vector (3,), rad) of orientations ``rotvecs`` (n, 3) of a still target, and its
    per-axis standard uncertainty from their spread (rad: the RMS per-axis turn from the mean over sqrt(n), None for
    fewer than 3)."""
    rotations = Rotation.from_rotvec(np.asarray(rotvecs, dtype=float).reshape(-1, 3))
    mean = rotations.mean()
    if len(rotations) < 3:
        return mean.as_rotvec(), None
    turns = (rotations * mean.inv()).as_rotvec()
    per_axis = float(np.sqrt(np.sum(turns**2) / (3 * (len(turns) - 1))))
    return mean.as_rotvec(), max(per_axis, SPREAD_FLOOR) / np.sqrt(len(turns))


def robust_mean(points: Array, reject_sigmas: float = REJECT_SIGMAS) -> tuple[Array, float | None, NDArray[np.bool_]]:
    """Mean (3,) of ``points`` (n, 3), m, after rejecting outliers; its per-axis standard uncertainty, m;
    and the mask (n,) of the samples kept.

    The noise per axis is estimated robustly from the median 3D distance to the median point; samples
    farther than ``reject_sigmas`` of it are dropped (only with at least 3 samples). The uncertainty is the
    kept samples' RMS per-axis standard deviation divided by sqrt(kept), floored at the reply resolution
    (:data:`SPREAD_FLOOR`); None for fewer than 2 kept samples (one sample has no spread).
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(pts) == 0:
        raise ValueError("robust_mean needs at least one sample")
    used = np.ones(len(pts), dtype=bool)
    if len(pts) >= 3:
        median = np.median(pts, axis=0)
        dist = np.linalg.norm(pts - median, axis=1)
        noise = max(float(np.median(dist)) / CHI3_MEDIAN, SPREAD_FLOOR)
        used = dist <= reject_sigmas * noise
    kept = pts[used]
    if len(kept) < 2:
        return kept.mean(axis=0), None, used
    per_axis = float(np.sqrt(np.mean(np.var(kept, axis=0, ddof=1))))
    return kept.mean(axis=0), max(per_axis, SPREAD_FLOOR) / np.sqrt(len(kept)), used


def frame_sigma(model: float, pts: Array, dof: int) -> float:
    """One frame's per-axis standard uncertainty (m): the propagated ``model`` (``dof`` residual degrees of
    freedom behind it), unless the kept frames ``pts`` (n, 3) scatter significantly more than it (an
    F-test at SPREAD_SIGNIFICANCE: vibration, flicker, a target still moving), then their spread."""
    n = len(pts)
    if n < 2 or dof < 1 or model <= 0:
        return model
    spread2 = float(np.mean(np.var(pts, axis=0, ddof=1)))
    # one axis (depth) dominates the spread: n - 1 degrees of freedom, not 3 (n - 1)
    if spread2 > model**2 * f_dist.isf(SPREAD_SIGNIFICANCE, n - 1, dof):
        return math.sqrt(spread2)
    return model
