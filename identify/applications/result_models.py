"""The models a result document holds, as :class:`identify.applications.holds.Model` for checking them on new data
(pure).

``plain``: the top-level DH table (``joints``, ``base``, ``tool``/``tools``, ``coupling``), what any reader of the
file uses. ``extended``: the model with the joint errors of ``extensions`` (:meth:`CalibratedModel.from_document`),
present when the result selected any. Each carries the 3D RMS error its result states for it
(``validation.plain`` / ``validation.extended``; older results: ``validation.expected_rms``, the identification's
own model), with the tracker noise of the new data put in place of the calibration's; where the result states
none, it is computed from the result's covariance and model error at the new poses. Units: m, rad.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from identify.applications.calibrated import CalibratedModel, ResultError
from identify.applications.holds import Model
from kinematics.dh import DHModel, frames_from_joints, model_from_dict
from kinematics.joint_errors import Coupling

Array = NDArray[np.float64]


@dataclass(frozen=True)
class ResultModels:
    """``models`` to check, the name of the one the result recommends (``use``), and per model where its
    expected RMS came from (``sources``: name -> "stated" or "computed")."""

    models: list[Model]
    use: str
    sources: dict[str, str]
    tp_ids: list[int]


def result_models(doc: dict[str, Any], q: Array, tp: NDArray[np.int64], noise: float | None = None) -> ResultModels:
    """The models of result ``doc``, with expected errors for readings ``q`` (m, n) of tracked points ``tp`` (m,)
    at the new data's tracker ``noise`` (m per axis; default the result's). ResultError (one line) when the
    document cannot serve."""
    if not isinstance(doc, dict):
        raise ResultError("not a result document (expected a YAML mapping with joints, base, tool)")
    try:
        table = model_from_dict(doc)
        tools = {int(k): np.array(v, dtype=float).reshape(3) for k, v in (doc.get("tools") or {}).items()}
        coupling = None
        if doc.get("coupling"):
            c = doc["coupling"]
            coupling = Coupling(np.array(c["matrix"], dtype=float),
                                np.array(c.get("offset") or np.zeros(table.n_joints), dtype=float))
    except (KeyError, TypeError, ValueError) as exc:
        raise ResultError(f"malformed DH table, tools or coupling in the result ({exc})") from None
    tools = tools or {1: np.asarray(table.tool, dtype=float)}
    if q.shape[1] != table.n_joints:
        raise ResultError(f"the result has {table.n_joints} joints, the data {q.shape[1]}")
    unknown = sorted({int(t) for t in tp} - set(tools))
    if unknown:
        raise ResultError(f"the data see tracked point(s) {unknown}; the result knows {sorted(tools)}")
    noise_doc = doc.get("noise") or {}
    old = float(noise_doc.get("tracker_per_axis") or 0.0)
    new = old if noise is None else noise
    model_error = float(noise_doc.get("model_error_per_axis") or 0.0)
    validation = doc.get("validation") or {}
    has_terms = bool((doc.get("extensions") or {}).get("terms"))
    stated = {name: (validation.get(name) or {}).get("expected_rms") for name in ("plain", "extended")
              if isinstance(validation.get(name), dict)}
    if not stated and validation.get("expected_rms") is not None:  # before two models: the identification's own
        stated = {"extended" if has_terms else "plain": validation["expected_rms"]}
    calibrated = _calibrated(doc)
    plain = _Plain(table, tools, coupling)
    models, sources = [], {}
    for name in ("plain", "extended"):
        if name == "extended" and not has_terms:
            continue
        if name == "extended" and calibrated is None:
            raise ResultError("the result's joint errors cannot be used without its covariance and axis lines")
        if stated.get(name) is not None:
            expected = float(np.sqrt(max(float(stated[name]) ** 2 - 3 * old**2 + 3 * new**2, 3 * new**2)))
            sources[name] = "stated"
        else:
            expected = _computed(name, calibrated, plain, q, tp, new, model_error)
            sources[name] = "computed"
        if name == "plain":
            models.append(Model(name, plain.points, expected, plain.flange_rotations))
        else:
            assert calibrated is not None
            models.append(Model(name, _extended_points(calibrated), expected, _extended_flanges(calibrated)))
    names = [m.name for m in models]
    use = doc.get("use") if doc.get("use") in names else names[-1]
    return ResultModels(models, str(use), sources, sorted(tools))


@dataclass(frozen=True)
class _Plain:
    """The DH table with its tools and coupling: readings -> DH joint values -> flange -> tracked point."""

    table: DHModel
    tools: dict[int, Array]
    coupling: Coupling | None

    def flanges(self, q: Array) -> Array:
        q_dh = q if self.coupling is None else self.coupling.dh_from_readings(q)
        return frames_from_joints(self.table, q_dh)[:, -1]

    def flange_rotations(self, q: Array) -> Array:
        return self.flanges(q)[:, :3, :3]

    def points(self, q: Array, tp: NDArray[np.int64]) -> Array:
        flange = self.flanges(q)
        tools = np.array([self.tools[int(t)] for t in tp]).reshape(-1, 3)
        return np.einsum("kij,kj->ki", flange[:, :3, :3], tools) + flange[:, :3, 3]


def _calibrated(doc: dict[str, Any]) -> CalibratedModel | None:
    """The result's model with covariance and predictor, or None when it has none (an old or foreign file)."""
    try:
        return CalibratedModel.from_document(doc)
    except ResultError:
        return None


def _extended_points(model: CalibratedModel):
    def points(q: Array, tp: NDArray[np.int64]) -> Array:
        assert model.predictor is not None
        return model.predictor.points(q, tp)

    return points


def _extended_flanges(model: CalibratedModel):
    def rotations(q: Array) -> Array:
        return model.flanges(q)[:, :3, :3]

    return rotations


def _computed(name: str, calibrated: CalibratedModel | None, plain: _Plain, q: Array, tp: NDArray[np.int64],
              noise: float, model_error: float) -> float:
    """RMS 3D error expected at readings ``q``: the parameters' uncertainty (where the result has a covariance),
    its model error and the tracker noise."""
    spread = 0.0
    if calibrated is not None:
        traces = []
        for i in sorted({int(t) for t in tp}):
            rows = tp == i
            if name == "plain":
                dh_only = replace(calibrated, predictor=None, tools=plain.tools)
                q_dh = q[rows] if plain.coupling is None else plain.coupling.dh_from_readings(q[rows])
                cov = dh_only.point_covariances(q_dh, tp=i)
            else:
                assert calibrated.predictor is not None
                cov = calibrated.predictor.covariances(q[rows], np.full(int(rows.sum()), i))
            traces.append(np.trace(cov, axis1=1, axis2=2))
        spread = float(np.mean(np.concatenate(traces)))
    return float(np.sqrt(spread + 3 * model_error**2 + 3 * noise**2))
