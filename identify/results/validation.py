"""Validation of a written model on the held-out (``check``) rows: what a reader of the result would predict.

Every figure here is computed from the numbers the result writes (the DH table and tools, the joint-error
terms), not from the fit's internal parameterisation, so the figure a result states is the figure of the model
a user takes away. Pooled and per tracked point. Frames: tracker; units: m.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

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

    def as_dict(self) -> dict[str, object]:
        out: dict[str, object] = {"samples": self.samples, "rms": self.rms, "max": self.max, "bound": self.bound,
                                  "expected_rms": self.expected}
        if len(self.per_tp) > 1:
            out["per_tp"] = {tp: {"samples": k, "rms": r, "max": m} for tp, (k, r, m) in self.per_tp.items()}
        return out


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
