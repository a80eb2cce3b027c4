"""The sensor's part of an identification, around the estimator: rows turned round before it, the scale and the
camera's frames after it (identify/sensors/flange.py, identify/sensors/scale.py). Used by ``identify`` and the API."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from identify.estimator.measurements import Measurements
from identify.results.pipeline import Identification
from identify.results.verdict import with_session_check
from identify.sensors.flange import flange_document, frame_point_covariances, turned_round
from identify.sensors.metadata import UNKNOWN
from identify.sensors.scale import ScaleResult, effect_rms, scale_result
from kinematics.dh import DHModel, frames_from_joints

Array = NDArray[np.float64]


@dataclass(frozen=True)
class SensorRows:
    """Rows ready for the estimator (``meas``), the flange camera's ``view_point`` (camera frame, m; None for a
    fixed device) and the ``scale_sigma`` of the data (None: the device's own scale)."""

    meas: Measurements
    view_point: Array | None
    scale_sigma: float | None


def for_estimator(meas: Measurements) -> SensorRows:
    """``meas`` as the estimator takes it: a flange camera's rows turned round (its scale unknown unless the data
    say otherwise); a fixed device's as they are."""
    if meas.sensor != "flange":
        return SensorRows(meas, None, meas.scale_sigma)
    turned, view_point = turned_round(meas)
    scale = UNKNOWN if meas.scale_sigma is None else meas.scale_sigma
    return SensorRows(replace(turned, scale_sigma=scale), view_point, scale)


def checked(ident: Identification, rows: SensorRows, nominal: DHModel | None) -> tuple[Identification, ScaleResult]:
    """``ident`` with the ``scale`` check in its verdict (when the data's scale is not the device's own)."""
    scale = scale_result(ident, nominal, rows.scale_sigma)
    if scale.check is not None:
        ident = replace(ident, verdict=with_session_check(ident.verdict, scale.check))
    return ident, scale


def documented(doc: dict[str, Any], rows: SensorRows, scale: ScaleResult, ident: Identification | None = None
               ) -> dict[str, Any]:
    """The result document with the sensor's sections: ``scale`` (unless the device's own) and, for a flange camera,
    ``sensor: flange`` with ``sensor_frame``, ``target``, ``view_point`` and (given ``ident``)
    ``flange_accuracy_rms``: :func:`flange_accuracy` over the fit poses (m; null with an unknown scale)."""
    if rows.scale_sigma is not None:
        doc = {**doc, "scale": scale.as_dict(effect_rms(rows.meas.points, scale.sigma))}
    if rows.view_point is not None:
        doc = flange_document(doc, rows.view_point)
        if ident is not None:
            q = np.unique(ident.refinement.q, axis=0)
            value = flange_accuracy(ident, np.array(doc["tool_frame"]), q, scale)
            doc["flange_accuracy_rms"] = value if np.isfinite(value) else None
    return doc


def flange_accuracy(ident: Identification, tool_frame: Array, q: Array, scale: ScaleResult) -> float:
    """RMS over DH joint values ``q`` (m, n) of the 3D standard uncertainty (m) of the flange's position (the last DH
    frame's origin, through the fitted camera frame ``tool_frame``: last DH frame <- view-point frame) predicted by
    the plain model: the fit's covariance, its model error and the scale's ``|p| sigma`` (inf: unknown scale)."""
    offset = np.linalg.inv(np.asarray(tool_frame, dtype=float))[:3, 3]  # the flange's origin in the view frame
    cov = frame_point_covariances(ident.plain, q, offset)
    flange = frames_from_joints(ident.model, np.atleast_2d(q))[:, -1, :3, 3]
    fit = float(np.mean(np.trace(cov, axis1=1, axis2=2))) + 3 * ident.plain.adequacy.model_error**2
    return float(np.sqrt(fit + effect_rms(flange, scale.sigma) ** 2))
