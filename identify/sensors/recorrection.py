"""A camera session's readings corrected again with the session's final estimate of its board's shape and its lens.

A camera that estimates its board's shape and its lens's residual calibration from every frame so far
(``aruco:...&flatness=``, ``lens_sigma=``, ``focal_sigma=``, ``centre_sigma=``) corrects each reading with the estimate
of the moment: the first readings with an estimate of a few views, whose error every later reading no longer has.
The session keeps, for each step, how its average moves with the parameters (drivers/base.py ``Correction``). Here
every row is corrected again with the session's most informed estimate (:func:`final_estimate`), and the part of its
sigma that came from the estimate's uncertainty is replaced by that of the final estimate. The correction is linear
in the change of the estimate, as the tracker's own is (a flat pose's response holds to 2 µm for a 1 mm bow:
tests/drivers/camera/test_imperfections.py).

The final estimate's own error is one draw shared by every reading. A row's sigma carries its share (what a reader of
the rows alone can use: conservative, as if each row's were its own), and the rows' ``lens`` says how each moves with
it, so that a flange camera's fit carries it as one shared error instead (identify/sensors/lens_share.py).
Units: metres, radians.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from identify.estimator.measurements import LensShare, Measurements


class Correction(Protocol):
    """How a reading moves with the parameters (the session's record of drivers/base.py ``Correction``, which this
    pure module does not import): ``response`` (6, p) per unit of each of ``names`` (position m, then turn rad),
    ``applied`` (6,) the move made, ``estimate`` (p,) and ``covariance`` (p, p) the estimate after the reading,
    ``bias``/``bias_r`` (m, rad) the per-axis share of its sigma from that estimate's uncertainty."""

    names: tuple[str, ...]
    response: np.ndarray
    applied: np.ndarray
    estimate: np.ndarray
    covariance: np.ndarray
    bias: float
    bias_r: float

    def shares(self, covariance: np.ndarray) -> tuple[float, float]:
        """Per-axis RMS (m, rad) of the error an estimate of ``covariance`` leaves the reading."""
        ...


def final_estimate(corrections: Sequence[Correction]) -> Correction:
    """The correction whose estimate has the smallest total variance: within a run the last one (the most frames
    behind it); a resumed run starts its estimate afresh, so the run that saw the most views wins."""
    return min(corrections, key=lambda c: float(np.trace(c.covariance)))


def recorrected(meas: Measurements, corrections: Sequence[Correction | None]) -> Measurements:
    """``meas`` with each row that has a correction (``corrections`` parallel to its rows, None for a row without
    one) moved to the final estimate: position minus the response times the estimate's change (m, the device's
    frame), orientation turned back by its turn (rad), sigma and sigma_r with the final estimate's share in place
    of the one it had; ``lens`` says how the rows move with the final estimate's error (:func:`unfolded` takes its
    share out of the sigmas where the fit carries it as what it is). ``meas`` unchanged when no row has one or their
    parameters differ (never in one session)."""
    if len(corrections) != len(meas):
        raise ValueError(f"{len(corrections)} corrections for {len(meas)} rows")
    known = [c for c in corrections if c is not None]
    if not known or len({c.names for c in known}) != 1:
        return meas
    final = final_estimate(known)
    p = len(final.names)
    response = np.array([np.zeros((6, p)) if c is None else c.response for c in corrections])
    moves = np.array([np.zeros(6) if c is None else c.response @ final.estimate - c.applied for c in corrections])
    old = np.array([(0.0, 0.0) if c is None else (c.bias, c.bias_r) for c in corrections])
    new = np.array([(0.0, 0.0) if c is None else c.shares(final.covariance) for c in corrections])

    def restated(sigma: np.ndarray | None, k: int) -> np.ndarray | None:
        return None if sigma is None else np.sqrt(np.maximum(sigma**2 - old[:, k] ** 2, 0.0) + new[:, k] ** 2)

    out = moved(meas, moves)
    return replace(out, sigma=restated(meas.sigma, 0), sigma_r=restated(meas.sigma_r, 1),
                   lens=LensShare(response, final.covariance, new[:, 0], new[:, 1], final.names, final.estimate))


def moved(meas: Measurements, moves: np.ndarray) -> Measurements:
    """``meas`` with each row's position less ``moves[:, :3]`` (m) and its orientation turned back by
    ``moves[:, 3:]`` (rad, the device's frame: ``exp(-turn) R``)."""
    rotvec = meas.rotvec
    if rotvec is not None:
        rotvec = np.array(rotvec, dtype=float)
        turned = np.all(np.isfinite(rotvec), axis=1)
        rotvec[turned] = (Rotation.from_rotvec(-moves[turned, 3:]) * Rotation.from_rotvec(rotvec[turned])).as_rotvec()
    return replace(meas, points=np.asarray(meas.points, dtype=float) - moves[:, :3], rotvec=rotvec)


def unfolded(meas: Measurements) -> Measurements:
    """``meas`` with the final estimate's share taken out of its sigmas (for a fit that carries the shared error
    itself: identify/sensors/lens_share.py); unchanged without one."""
    lens = meas.lens
    if lens is None:
        return meas

    def without(sigma: np.ndarray | None, share: np.ndarray) -> np.ndarray | None:
        return None if sigma is None else np.sqrt(np.maximum(sigma**2 - share**2, 0.0))

    return replace(meas, sigma=without(meas.sigma, lens.share), sigma_r=without(meas.sigma_r, lens.share_r))
