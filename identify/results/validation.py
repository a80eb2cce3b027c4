"""Validation of a written model on the held-out (``check``) rows: what a reader of the result would predict.

Every figure here is computed from the numbers the result writes (the DH table and tools, the joint-error
terms, ``tool_frame``), not from the fit's internal parameterisation, so the figure a result states is the figure
of the model a user takes away. Pooled and per tracked point; with full-pose data, the held-out orientations too
(:class:`TurnValidation`). Frames: tracker; units: m, rad.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from identify.estimator.orientation import rotation_residuals
from identify.results.predict import Predictor

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Validation:
    """Errors at held-out poses: measured vs predicted TP, 3D, metres.

    ``bound`` is the RMS error of the model's own predictions the fit's covariance implies; ``expected`` adds the
    tracker noise and model error of the held-out measurements (what ``rms`` should be near). ``per_tp``: tracked
    point id -> (samples, rms, max)."""

    samples: int
    rms: float
    max: float
    bound: float
    expected: float
    per_tp: dict[int, tuple[int, float, float]] = field(default_factory=dict)
    orientation: TurnValidation | None = None

    def as_dict(self) -> dict[str, object]:
        out: dict[str, object] = {"samples": self.samples, "rms": self.rms, "max": self.max, "bound": self.bound,
                                  "expected_rms": self.expected}
        if len(self.per_tp) > 1:
            out["per_tp"] = {tp: {"samples": k, "rms": r, "max": m} for tp, (k, r, m) in self.per_tp.items()}
        if self.orientation is not None:
            out["orientation"] = self.orientation.as_dict()
        return out


@dataclass(frozen=True)
class TurnValidation:
    """The held-out rows' measured target-frame orientations against the written model's (full-pose data): 3D
    RMS and max of the rotation residuals ``log(R_predicted R_measuredᵀ)``, rad; ``bound`` the RMS the model's
    uncertainty implies there, ``expected`` that with the measurements' sigma_r (what ``rms`` should be near)."""

    samples: int
    rms: float
    max: float
    bound: float
    expected: float

    def as_dict(self) -> dict[str, object]:
        return {"samples": self.samples, "rms_rad": self.rms, "max_rad": self.max, "bound_rad": self.bound,
                "expected_rms_rad": self.expected}


def validate_turns(predicted: Array, measured: Array, sigma_r: Array, jacobian: Array | None,
                   covariance: Array | None) -> TurnValidation:
    """Held-out orientations: ``predicted`` and ``measured`` rotations (k, 3, 3), tracker frame, their per-axis
    ``sigma_r`` (k,) rad; ``jacobian`` (k, 3, p) of the predicted rotation (a turn, tracker frame) by the parameters
    whose ``covariance`` (p, p) the fit states (None: the bound is left out)."""
    err = np.linalg.norm(rotation_residuals(predicted, measured), axis=1)
    bound = 0.0 if jacobian is None or covariance is None else float(np.sqrt(np.mean(np.einsum(
        "kip,pq,kiq->k", jacobian, covariance, jacobian))))
    return TurnValidation(len(err), float(np.sqrt(np.mean(err**2))), float(err.max()), bound,
                          float(np.sqrt(bound**2 + 3 * np.mean(np.square(sigma_r)))))


def validate(q: Array, points: Array, tp: NDArray[np.int64], sigma: Array | None,
             predict: Callable[[Array, NDArray[np.int64]], Array], predictor: Predictor, noise: float,
             model_error: float) -> Validation:
    """Held-out rows: DH joint values ``q`` (k, n), measured ``points`` (k, 3), tracked point ids ``tp`` (k,),
    per-row ``sigma`` (m) or None. ``predict(q, tp)`` is the written model's prediction; ``predictor`` (without
    coupling) gives the parameters' uncertainty there; ``noise`` and ``model_error`` (m per axis) the rest of the
    expectation."""
    err = np.linalg.norm(points - predict(q, tp), axis=1)
    cov = predictor.covariances(q, tp)
    bound = float(np.sqrt(np.mean(np.trace(cov, axis1=1, axis2=2))))
    noise2 = noise**2 if sigma is None else float(np.mean(sigma**2))
    per_tp = {int(i): (int(np.sum(tp == i)), float(np.sqrt(np.mean(err[tp == i] ** 2))), float(err[tp == i].max()))
              for i in np.unique(tp)}
    return Validation(len(q), float(np.sqrt(np.mean(err**2))), float(err.max()), bound,
                      float(np.sqrt(bound**2 + 3 * noise2 + 3 * model_error**2)), per_tp)
