"""A camera session's readings corrected again with the session's final estimate of its board's shape and its lens.

A camera that estimates its board's shape and its lens's residual calibration from every frame so far
(``aruco:...&flatness=``, ``lens_sigma=``, ``focal_sigma=``, ``centre_sigma=``) corrects each reading with the estimate
of the moment: the first readings with an estimate of a few views, whose error every later reading no longer has.
The session keeps, for each step, how its average moves with the parameters (drivers/base.py ``Correction``). Here
every row is corrected again with the session's most informed estimate (:func:`final_estimate`), and the part of its
sigma that came from the estimate's uncertainty is replaced by that of the final estimate. The correction is linear
in the change of the estimate (it changes by a few of its standard deviations: micrometres of a reading).

The final estimate's own error is one draw shared by every reading; a row's sigma carries it as if it were its own
(the fit has no shared-error term), which is why its share is kept beside the rows (:func:`shared_part`).
Units: metres, radians.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from identify.estimator.measurements import Measurements


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


def final_estimate(corrections: Sequence[Correction]) -> Correction:
    """The correction whose estimate has the smallest total variance: within a run the last one (the most frames
    behind it); a resumed run starts its estimate afresh, so the run that saw the most views wins."""
    return min(corrections, key=lambda c: float(np.trace(c.covariance)))


def recorrected(meas: Measurements, corrections: Sequence[Correction | None]) -> Measurements:
    """``meas`` with each row that has a correction (``corrections`` parallel to its rows, None for a row without
    one) moved to the final estimate: position minus the response times the estimate's change (m, the device's
    frame), orientation turned back by its turn (rad), sigma and sigma_r with the final estimate's share in place
    of the one it had. ``meas`` unchanged when no row has one or their parameters differ (never in one session)."""
    if len(corrections) != len(meas):
        raise ValueError(f"{len(corrections)} corrections for {len(meas)} rows")
    known = [c for c in corrections if c is not None]
    if not known or len({c.names for c in known}) != 1:
        return meas
    final = final_estimate(known)
    points = np.array(meas.points, dtype=float)
    rotvec = None if meas.rotvec is None else np.array(meas.rotvec, dtype=float)
    sigma = None if meas.sigma is None else np.array(meas.sigma, dtype=float)
    sigma_r = None if meas.sigma_r is None else np.array(meas.sigma_r, dtype=float)
    for k, c in enumerate(corrections):
        if c is None:
            continue
        move = c.response @ final.estimate - c.applied  # (6,): the TP (m), then the turn (rad)
        points[k] -= move[:3]
        bias, bias_r = shared_part(c, final.covariance)
        if rotvec is not None and np.all(np.isfinite(rotvec[k])):
            rotvec[k] = (Rotation.from_rotvec(-move[3:]) * Rotation.from_rotvec(rotvec[k])).as_rotvec()
        if sigma is not None:
            sigma[k] = np.sqrt(max(sigma[k] ** 2 - c.bias**2, 0.0) + bias**2)
        if sigma_r is not None and np.isfinite(sigma_r[k]):
            sigma_r[k] = np.sqrt(max(sigma_r[k] ** 2 - c.bias_r**2, 0.0) + bias_r**2)
    return replace(meas, points=points, rotvec=rotvec, sigma=sigma, sigma_r=sigma_r)


def shared_part(correction: Correction, covariance: np.ndarray) -> tuple[float, float]:
    """Per-axis RMS (m, rad) of the error the parameters' ``covariance`` leaves a reading of this ``correction``:
    its position, its orientation."""
    position = correction.response[:3] @ covariance @ correction.response[:3].T
    turn = correction.response[3:] @ covariance @ correction.response[3:].T
    return float(np.sqrt(np.trace(position) / 3)), float(np.sqrt(np.trace(turn) / 3))
