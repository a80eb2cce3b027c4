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
from identify.sensors.flange import flange_document, turned_round
from identify.sensors.metadata import UNKNOWN
from identify.sensors.scale import ScaleResult, effect_rms, scale_result
from kinematics.dh import DHModel

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


def documented(doc: dict[str, Any], rows: SensorRows, scale: ScaleResult) -> dict[str, Any]:
    """The result document with the sensor's sections: ``scale`` (unless the device's own) and, for a flange camera,
    ``sensor: flange`` with ``sensor_frame``, ``target`` and ``view_point``."""
    if rows.scale_sigma is not None:
        doc = {**doc, "scale": scale.as_dict(effect_rms(rows.meas.points, scale.sigma))}
    if rows.view_point is not None:
        doc = flange_document(doc, rows.view_point)
    return doc
