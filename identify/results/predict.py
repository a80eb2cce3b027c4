"""Predictions of an identified model: controller readings in, tracked point (tracker frame, m) out.

The chain of the extended model (README, "Two models, one file"): readings -> DH joint values (coupling) ->
joint errors (:mod:`identify.estimator.extensions`) -> the axis lines (:mod:`identify.estimator.poe`), which are the
identified model exactly (the DH table equals them when its ``dh_table`` check passes). Uncertainty from the fit's
full covariance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from identify.estimator.extensions import TermSet
from identify.estimator.poe import AxisLines, JointTerms, LineProblem, points_from_lines
from kinematics.joint_errors import Coupling

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Predictor:
    """``lines`` with ``covariance`` over (lines, tracked points, joint-error coefficients), the joint-error
    ``terms`` and their ``coefs``, the readings' ``coupling`` (None: readings are DH values) and the
    tracked points' ids ``tp_ids`` (rows of ``lines.tps``)."""

    lines: AxisLines
    covariance: Array
    terms: TermSet
    coefs: Array
    coupling: Coupling | None
    tp_ids: tuple[int, ...]

    def joints(self, readings: Array) -> Array:
        """DH joint values with the joint errors applied (m, n), from readings (m, n)."""
        q = np.atleast_2d(np.asarray(readings, dtype=float))
        if self.coupling is not None:
            q = self.coupling.dh_from_readings(q)
        return self.terms.terms(q, self.coefs).corrected(q)

    def tp_index(self, tp: int | NDArray[np.int64] | None, m: int) -> NDArray[np.int64] | None:
        """0-based rows of ``lines.tps`` for tracked point id(s) ``tp`` (None: the first)."""
        if tp is None:
            return None
        ids = np.broadcast_to(np.asarray(tp, dtype=np.int64), (m,))
        index = np.searchsorted(self.tp_ids, ids)
        if np.any(index >= len(self.tp_ids)) or np.any(np.asarray(self.tp_ids)[np.minimum(index, len(self.tp_ids) - 1)]
                                                       != ids):
            raise ValueError(f"tracked point id(s) {sorted(set(ids.tolist()) - set(self.tp_ids))} not in the model "
                             f"(ids {list(self.tp_ids)})")
        return index

    def points(self, readings: Array, tp: int | NDArray[np.int64] | None = None) -> Array:
        """Predicted TP (m, 3), tracker frame, metres."""
        q = self.joints(readings)
        return points_from_lines(self.lines, q, self.tp_index(tp, len(q)))

    def covariances(self, readings: Array, tp: int | NDArray[np.int64] | None = None) -> Array:
        """Covariance (m, 3, 3) of the predicted TP from the parameters' uncertainty, m²."""
        g = self._jacobian(readings, tp)
        return g @ self.covariance @ np.swapaxes(g, 1, 2)

    def mean_variance(self, readings: Array, tp: int | NDArray[np.int64] | None = None) -> float:
        """Mean over the readings of the trace of :meth:`covariances` (m²), as trace(C GᵀG) / m with G the
        stacked Jacobian: one matrix product instead of m 3 × 3 products."""
        g = self._jacobian(readings, tp)
        flat = g.reshape(-1, g.shape[2])
        return float(np.sum(self.covariance * (flat.T @ flat))) / len(g)

    def _jacobian(self, readings: Array, tp: int | NDArray[np.int64] | None) -> Array:
        """Jacobian (m, 3, size) of the predicted TP at ``readings`` with respect to the parameters."""
        raw = np.atleast_2d(np.asarray(readings, dtype=float))
        dh = raw if self.coupling is None else self.coupling.dh_from_readings(raw)
        q = self.joints(raw)
        regressors = self.terms.regressors(dh)
        terms = JointTerms(regressors, self.terms.joints, self.coefs)
        problem = LineProblem(self.lines, q, np.zeros((len(q), 3)), np.ones(len(q)), terms=terms)
        return problem.jacobian_blocks(np.zeros(problem.size), q=q, tp_index=self.tp_index(tp, len(q)),
                                       regressors=regressors)
