"""The device's length scale: what fixes it, how uncertain it is, and whether the arm's nominal lengths agree.

A camera measures lengths in units of its board: a board printed 0.3 % large makes every measured position 0.3 %
short, and the data are then those of an arm 0.3 % smaller, which the fit cannot tell from the truth (every
residual is the same). So the scale needs a reference, and the measurement CSV says which (``# scale_sigma:``):

- no line: the device's own scale (a laser tracker or a CMM, calibrated to a few ppm): nothing is added;
- a number: the relative standard uncertainty of a measured reference (a camera's board squares measured with a
  caliper, ``square_sigma / square``); it is added to every stated accuracy (a prediction at ``p`` in the device
  frame errs by ``p · u``), and the nominal's lengths are checked against it;
- ``unknown`` (the default of ``# sensor: flange``): nothing fixed it. With a nominal model the fitted link
  lengths are compared with the nominal's: the ratio's uncertainty comes from the arm's own length tolerance
  (:data:`NOMINAL_LENGTH_SIGMA` per link) and the fit's; a ratio farther from 1 than :data:`SIGNIFICANCE` of that is
  reported as a failed ``scale`` check (a wrong scale is reported, never absorbed into the link lengths); a ratio
  within it leaves the scale uncertain by the ratio's offset and uncertainty, which the stated accuracy includes.

Pure: arrays and the identification in, numbers and a verdict check out. Units: metres; ratios are 1-based.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from identify.estimator.dh_vector import dh_index
from identify.results.pipeline import Identification
from identify.results.verdict import Check
from identify.sensors.metadata import UNKNOWN
from kinematics.dh import DHModel

Array = NDArray[np.float64]

NOMINAL_LENGTH_SIGMA = 5e-4  # m: an arm's link length against its datasheet, one standard deviation
MIN_LENGTH = 0.01  # m: nominal lengths shorter than this say nothing about the scale
SIGNIFICANCE = 3.0  # standard deviations of the ratio beyond which the scale is reported wrong


@dataclass(frozen=True)
class NominalRatio:
    """Fitted link lengths over the nominal's: ``ratio`` (1) with its standard uncertainty ``sigma`` over the
    ``lengths`` named (e.g. ``a2``)."""

    ratio: float
    sigma: float
    lengths: tuple[str, ...]


def nominal_ratio(ident: Identification, nominal: DHModel) -> NominalRatio | None:
    """The weighted least-squares ratio of the fitted DH lengths (``a``, ``d`` the data determine) to the nominal's,
    each weighed by ``NOMINAL_LENGTH_SIGMA`` and its own fitted uncertainty; None when no nominal length of at least
    :data:`MIN_LENGTH` was fitted."""
    free, std, model = ident.refinement.free, ident.std, ident.model
    fitted, reference, variance, names = [], [], [], []
    for j in range(1, model.n_joints + 1):
        for name in ("a", "d"):
            index = dh_index(j, name)
            value = float(getattr(nominal, name)[j - 1])
            if free[index] and abs(value) >= MIN_LENGTH and not (name == "d" and nominal.joint_types[j - 1] == "P"):
                fitted.append(float(getattr(model, name)[j - 1]))
                reference.append(value)
                variance.append(NOMINAL_LENGTH_SIGMA**2 + float(std[index]) ** 2)
                names.append(f"{name}{j}")
    if not names:
        return None
    f, r, w = np.array(fitted), np.array(reference), 1.0 / np.array(variance)
    information = float(np.sum(w * r * r))
    return NominalRatio(float(np.sum(w * f * r) / information), 1.0 / math.sqrt(information), tuple(names))


@dataclass(frozen=True)
class ScaleResult:
    """What is known about the length scale: ``reference`` (``device``, ``measured``, ``nominal`` or ``none``), the
    relative standard uncertainty ``sigma`` the stated accuracies carry (0 for the device's own), the ``nominal``
    comparison (None without a nominal) and the verdict ``check`` (None for the device's own scale)."""

    reference: str
    sigma: float
    nominal: NominalRatio | None
    check: Check | None

    def as_dict(self, effect_rms: float | None = None) -> dict[str, Any]:
        out: dict[str, Any] = {"reference": self.reference, "relative_sigma": _finite(self.sigma)}
        if self.nominal is not None:
            out["ratio_to_nominal"] = self.nominal.ratio
            out["ratio_sigma"] = self.nominal.sigma
            out["lengths"] = list(self.nominal.lengths)
        if effect_rms is not None:
            out["effect_rms"] = _finite(effect_rms)
        out["note"] = ("relative_sigma: the device's length scale, 1 sigma (null: unknown); a prediction at p "
                       "(device frame) errs by |p| times it, which no held-out row can show (they share the scale); "
                       "effect_rms: that error, RMS over the fit poses, m")
        return out


def scale_result(ident: Identification, nominal: DHModel | None, scale_sigma: float | None) -> ScaleResult:
    """The scale of ``ident``'s data from its ``scale_sigma`` (None: the device's own; a number: a measured
    reference's relative uncertainty; :data:`UNKNOWN`: none), checked against the ``nominal``'s lengths."""
    if scale_sigma is None:
        return ScaleResult("device", 0.0, None, None)
    ratio = None if nominal is None else nominal_ratio(ident, nominal)
    measured = math.isfinite(scale_sigma)
    if ratio is None:
        if measured:
            return ScaleResult("measured", scale_sigma, None, Check(
                "scale", "pass", None, None, f"length scale from the measured reference, ±{100 * scale_sigma:.3g} % "
                "(1 sigma; no nominal lengths to check it against)"))
        return ScaleResult("none", UNKNOWN, None, Check(
            "scale", "warn", None, None, "nothing fixes the length scale (a board's print is off by 0.1-0.5 %): "
            "every length and position carries that error; measure the board (square_sigma=) or give the nominal "
            "model (--robot)"))
    offset = ratio.ratio - 1.0
    names = ", ".join(ratio.lengths)
    if measured:
        limit = SIGNIFICANCE * math.hypot(ratio.sigma, scale_sigma)
        if abs(offset) > limit:
            return ScaleResult("measured", scale_sigma, ratio, Check(
                "scale", "fail", abs(offset), limit,
                f"the fitted lengths ({names}) are {_percent(offset)} off the nominal's, beyond the measured "
                f"reference's ±{100 * scale_sigma:.3g} % and the arm's tolerance (limit {100 * limit:.3g} %): the "
                "board's measurement or the robot model is wrong"))
        return ScaleResult("measured", scale_sigma, ratio, Check(
            "scale", "pass", abs(offset), limit,
            f"length scale from the measured reference (±{100 * scale_sigma:.3g} %); the nominal's lengths agree "
            f"({_percent(offset)}, limit {100 * limit:.3g} %)"))
    limit = SIGNIFICANCE * ratio.sigma
    sigma = math.hypot(offset, ratio.sigma)
    if abs(offset) > limit:
        return ScaleResult("nominal", sigma, ratio, Check(
            "scale", "fail", abs(offset), limit,
            f"no scale reference, and the fitted lengths ({names}) are {_percent(offset)} off the nominal's (limit "
            f"{100 * limit:.3g} %): a board printed at the wrong scale? every length and position of this result is "
            "off by as much; measure the board's squares with a caliper and give them (square=, square_sigma=)"))
    return ScaleResult("nominal", sigma, ratio, Check(
        "scale", "warn", abs(offset), limit,
        f"no scale reference: the nominal's lengths ({names}) agree ({_percent(offset)}, limit {100 * limit:.3g} %) "
        f"and fix the scale to ±{100 * sigma:.3g} %, included in the stated accuracy; a measured board "
        "(square_sigma=) does better"))


def effect_rms(predicted: Array, sigma: float) -> float:
    """RMS (m) over ``predicted`` positions (k, 3), device frame, of the error a scale uncertain by ``sigma``
    (relative) gives them: ``|p| · sigma``; inf for an unknown scale."""
    if math.isinf(sigma):
        return math.inf
    return float(sigma * np.sqrt(np.mean(np.sum(np.asarray(predicted, dtype=float) ** 2, axis=1))))


def _finite(value: float) -> float | None:
    """``value``, None when it is not finite (an unknown scale: YAML and JSON have no infinity)."""
    return float(value) if math.isfinite(value) else None


def _percent(offset: float) -> str:
    return f"{100 * offset:+.3f} %"
