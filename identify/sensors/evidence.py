"""The sensor's part of an identification, around the estimator: rows turned round before it, the scale and the
camera's frames after it (identify/sensors/flange.py, identify/sensors/scale.py). Used by ``identify`` and the API."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.stats import gamma

from identify.applications.domain import outside
from identify.estimator.measurements import Measurements
from identify.results.pipeline import Identification
from identify.results.verdict import Verdict, holdout, with_session_check
from identify.sensors.flange import flange_document, frame_point_jacobian, turned_round
from identify.sensors.lens_share import held_out_share, shared_lines
from identify.sensors.metadata import UNKNOWN
from identify.sensors.recorrection import unfolded
from identify.sensors.scale import ScaleResult, effect_rms, scale_result
from identify.simulators.simulate import random_poses
from kinematics.dh import DHModel, frames_from_joints

Array = NDArray[np.float64]


@dataclass(frozen=True)
class SensorRows:
    """Rows ready for the estimator (``meas``), the flange camera's ``view_point`` (camera frame, m; None for a
    fixed device), the ``scale_sigma`` of the data (None: the device's own scale) and, for a flange camera, its rows
    as the camera gave them (``device``, the estimator's before turning round)."""

    meas: Measurements
    view_point: Array | None
    scale_sigma: float | None
    device: Measurements | None = None


def for_estimator(meas: Measurements) -> SensorRows:
    """``meas`` as the estimator takes it: a flange camera's rows turned round (its scale unknown unless the data
    say otherwise), without its final lens estimate's share in their sigmas (the flange's statement carries that
    error as one draw shared by every row: identify/sensors/lens_share.py); a fixed device's as they are."""
    if meas.sensor != "flange":
        return SensorRows(meas, None, meas.scale_sigma)
    device = unfolded(meas)
    turned, view_point = turned_round(device)
    scale = UNKNOWN if meas.scale_sigma is None else meas.scale_sigma
    return SensorRows(replace(turned, scale_sigma=scale), view_point, scale, device)


def checked(ident: Identification, rows: SensorRows, nominal: DHModel | None) -> tuple[Identification, ScaleResult]:
    """``ident`` with the ``scale`` check in its verdict (when the data's scale is not the device's own) and, for a
    flange camera's rows that share its final lens estimate's error, that error's part in the held-out check."""
    scale = scale_result(ident, nominal, rows.scale_sigma)
    if scale.check is not None:
        ident = replace(ident, verdict=with_session_check(ident.verdict, scale.check))
    return _lens_held_out(ident, rows), scale


def _lens_held_out(ident: Identification, rows: SensorRows) -> Identification:
    """``ident`` with the held-out expectation of its plain model grown by what the camera's shared lens error leaves
    the held-out rows (identify/sensors/lens_share.py ``held_out_share``; the rows' sigmas no longer hold it) and its
    holdout check made again on it; as it is without that error, held-out rows, or when joint errors were fitted
    (their check compares the models: not redone here)."""
    validation = ident.validations.get("plain")
    if rows.device is None or rows.device.lens is None or validation is None or set(ident.models) != {"plain"}:
        return ident
    lines = shared_lines(ident, rows.device, rows.view_point)
    extra = held_out_share(ident, rows.device, rows.view_point, lines)
    if extra <= 0:
        return ident
    grown = replace(validation, expected=math.sqrt(validation.expected**2 + extra))
    check = holdout(grown.samples, grown.rms, grown.expected, "plain")
    kept = tuple(check if c.name == "holdout" else c for c in ident.verdict.checks)
    return replace(ident, validations={**ident.validations, "plain": grown}, verdict=Verdict(kept))


CAMERA_NOTE = ("the camera's final estimate of its board's shape (bow_x, bow_y, twist: m) and its calibration's errors "
               "(dk1, dk2; dfocal: relative; dcx, dcy: px) as [value, standard deviation]; every reading was corrected "
               "with it. A focal or principal-point error many deviations from 0 says: calibrate the camera again")
WORKSPACE_POSES = 300  #: random poses within the joint limits where a flange camera's result states the flange
LIKELY = (0.05, 0.95)  #: the probabilities bounding the range a single calibration's realised RMS is stated in


@dataclass(frozen=True)
class FlangeAccuracy:
    """The flange's predicted 3D position error (m) over a set of poses: ``rms`` the expected RMS (the fit's
    covariance, a camera's final lens estimate's error, its model error and the scale's ``|p| sigma``; inf with an
    unknown scale) and ``low``, ``high`` the
    range (:data:`LIKELY`) the realised RMS of one calibration lies in. The parameters' error is one draw shared by
    every pose, so the RMS over many poses is a weighted chi-square over the few directions that reach the flange
    and scatters from calibration to calibration (Satterthwaite's gamma with its mean and variance)."""

    rms: float
    low: float
    high: float

    def as_dict(self) -> dict[str, Any]:
        finite = np.isfinite(self.rms)
        return {"accuracy_rms": float(self.rms) if finite else None,
                "likely_rms": [float(self.low), float(self.high)] if finite else None}


def documented(doc: dict[str, Any], rows: SensorRows, scale: ScaleResult, ident: Identification | None = None,
               limits: Array | None = None) -> dict[str, Any]:
    """The result document with the sensor's sections: ``scale`` (unless the device's own), ``camera_estimate`` (a
    camera that estimated its board's shape and its lens: :data:`CAMERA_NOTE`) and, for a flange camera,
    ``sensor: flange`` with ``sensor_frame``, ``target``, ``view_point`` and (given ``ident``)
    ``flange_accuracy_rms``: :func:`flange_accuracy` over the fit poses (m; null with an unknown scale), and ``flange``:
    that and its likely range at the fit poses and, given the robot's joint ``limits`` (n, 2; rad or m), at
    :data:`WORKSPACE_POSES` random poses within them, with how many lie outside the fitted joint ranges."""
    if rows.scale_sigma is not None:
        doc = {**doc, "scale": scale.as_dict(effect_rms(rows.meas.points, scale.sigma))}
    lens = (rows.device if rows.device is not None else rows.meas).lens
    if lens is not None:
        doc = {**doc, "camera_estimate": {**lens.as_dict(), "note": CAMERA_NOTE}}
    if rows.view_point is not None:
        doc = flange_document(doc, rows.view_point)
        if ident is not None:
            tool_frame = np.array(doc["tool_frame"])
            q = np.unique(ident.refinement.q, axis=0)
            lens_lines = shared_lines(ident, rows.device, rows.view_point) if rows.device is not None else None
            if lens_lines is None and rows.device is not None and rows.device.lens is not None:
                share = 1e3 * float(np.sqrt(np.mean(rows.device.lens.share**2)))
                left_out = (f"the flange's stated accuracy leaves out the error of the camera's final lens estimate "
                            f"({share:.3g} mm a reading, per axis): a lower bound")
                doc["warnings"] = [*doc.get("warnings", []), left_out]
            fit = flange_accuracy(ident, tool_frame, q, scale, lens_lines)
            doc["flange_accuracy_rms"] = fit.as_dict()["accuracy_rms"]
            doc["flange"] = {"fit_poses": fit.as_dict()}
            if limits is not None:
                doc["flange"]["workspace"] = _workspace(ident, tool_frame, scale, limits, rows.meas, lens_lines)
    return doc


def _workspace(ident: Identification, tool_frame: Array, scale: ScaleResult, limits: Array,
               meas: Measurements, lens_lines: Array | None) -> dict[str, Any]:
    readings = random_poses(np.asarray(limits, dtype=float), WORKSPACE_POSES, np.random.default_rng(0))
    q = readings if meas.coupling is None else readings @ meas.coupling.matrix.T + meas.coupling.offset
    found = outside(ident.domain, q, meas.joint_types) if ident.domain is not None else None
    section = {**flange_accuracy(ident, tool_frame, q, scale, lens_lines).as_dict(), "poses": WORKSPACE_POSES,
               "poses_outside_domain": None if found is None else found.count}
    section["note"] = ("random poses within the robot's joint limits (the margin 10 % of each range); outside the "
                       "fitted joint ranges (domain) the figure is a lower bound: errors the model cannot hold are "
                       "not known there")
    return section


def flange_accuracy(ident: Identification, tool_frame: Array, q: Array, scale: ScaleResult,
                    lens_lines: Array | None = None) -> FlangeAccuracy:
    """The 3D standard uncertainty (m) of the flange's position (the last DH frame's origin, through the fitted
    camera frame ``tool_frame``: last DH frame <- view-point frame) predicted by the plain model over DH joint values
    ``q`` (m, n), with its likely range (:class:`FlangeAccuracy`); ``lens_lines`` (k, d): the lines' answer to the
    camera's final lens estimate's error (identify/sensors/lens_share.py), d more independent directions."""
    offset = np.linalg.inv(np.asarray(tool_frame, dtype=float))[:3, 3]  # the flange's origin in the view frame
    jac = frame_point_jacobian(ident.plain, q, offset)
    k = jac.shape[2]
    cov = ident.plain.covariance[:k, :k]
    values, vectors = np.linalg.eigh((cov + cov.T) / 2)
    directions = vectors * np.sqrt(np.clip(values, 0.0, None))
    if lens_lines is not None:
        directions = np.hstack([directions, lens_lines])
    spread = jac.reshape(-1, k) @ directions
    weights = np.linalg.eigvalsh(spread.T @ spread / len(q))  # mean square per independent direction, m²
    flange = frames_from_joints(ident.model, np.atleast_2d(q))[:, -1, :3, 3]
    shared = effect_rms(flange, scale.sigma)  # the scale: one more direction
    if not np.isfinite(shared):
        return FlangeAccuracy(math.inf, math.inf, math.inf)
    weights = np.append(np.clip(weights, 0.0, None), shared**2)
    fixed = 3 * ident.plain.adequacy.model_error**2  # per pose, independent: no scatter over many poses
    mean, variance = float(weights.sum()), 2 * float(np.sum(weights**2))
    if variance <= 0:
        value = math.sqrt(mean + fixed)
        return FlangeAccuracy(value, value, value)
    low, high = gamma.ppf(LIKELY, mean**2 / variance, scale=variance / mean)
    return FlangeAccuracy(math.sqrt(mean + fixed), math.sqrt(low + fixed), math.sqrt(high + fixed))


def camera_text(doc: dict[str, Any]) -> list[str]:
    """What a camera's result states about the camera's own estimate and, on the flange, about the flange, in lines
    for the operator (none for other devices)."""
    units = {"bow_x": (1e3, " mm"), "bow_y": (1e3, " mm"), "twist": (1e3, " mm"), "dk1": (1.0, ""), "dk2": (1.0, ""),
             "dfocal": (100.0, " %"), "dcx": (1.0, " px"), "dcy": (1.0, " px")}
    estimate = {k: v for k, v in (doc.get("camera_estimate") or {}).items() if k in units}
    lines = []
    if estimate:
        parts = [f"{name} {value * units[name][0]:.3g} ± {sd * units[name][0]:.2g}{units[name][1]}"
                 for name, (value, sd) in estimate.items()]
        lines.append(f"camera: its board's shape and calibration errors as estimated ({', '.join(parts)}); every "
                     "reading corrected with them")
    section = doc.get("flange") or {}
    for key, where in (("fit_poses", "at the fit poses"), ("workspace", "over the workspace")):
        part = section.get(key)
        if not part:
            continue
        if part.get("accuracy_rms") is None:
            lines.append(f"flange camera: the flange's position {where}: not stated (the board's scale is unknown)")
            continue
        low, high = (1e3 * v for v in part["likely_rms"])
        text = (f"flange camera: the flange's position {where} stated to {part['accuracy_rms'] * 1e3:.3f} mm RMS "
                f"(one calibration's: {low:.3f}-{high:.3f} mm, 90 %)")
        if key == "workspace":
            outside_count = part.get("poses_outside_domain")
            text += (f", at {part['poses']} random poses within the joint limits"
                     + ("" if not outside_count else
                        f"; {outside_count} of them outside the fitted joint ranges, where it is a lower bound"))
        lines.append(text)
    return lines
