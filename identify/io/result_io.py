"""The result document (README.md, File contracts: ``joints``, ``base``, ``tool``) plus its evidence, as plain
data, and the result YAML read back (:func:`load_result`).

Units follow the contract: metres and radians. The dict is ready for ``yaml.safe_dump`` or ``json``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from common import __version__
from identify.applications.calibrated import CalibratedModel, ResultError
from identify.applications.domain import domain_to_dict
from identify.estimator.dh_vector import parameter_names
from identify.estimator.extensions import EQUATIONS, UNITS
from identify.estimator.poe import AxisLines
from identify.results.pipeline import Identification
from identify.results.written import WrittenModel
from kinematics.dh import DH_NAMES, DHModel, model_to_dict

CONVENTION = (
    "standard DH (the forward model of README.md). Frame 0: z0 on joint 1's axis, theta1 and d1 conventional, the "
    "base absorbs the rest. Frame n: the last link's theta, d, a, alpha conventional, the tool carries the TP. "
    "Consecutive axes parallel within parallel_tol: the common normal passes where d takes its conventional "
    "value. Prismatic axes meet the next axis (a = 0). Conventional values: the nominal model's, or zero."
)


def _floats(values: Any) -> Any:
    return np.asarray(values, dtype=float).tolist()


def result_to_dict(ident: Identification, nominal: DHModel | None = None, nominal_name: str | None = None,
                   source: str | None = None, nominal_model: dict[str, Any] | None = None) -> dict[str, Any]:
    """Everything the identification knows, contract keys first. ``nominal_model``: the robot model's document
    when it is not bundled (config/robots.py ``model_document``), recorded as ``nominal.model`` so that the result
    reads where the model's file is not."""
    ref = ident.refinement
    n = ident.model.n_joints
    std = ident.std
    doc = model_section(ident.plain, ident.tp_ids)
    doc["use"] = ident.use
    doc["verdict"] = ident.verdict.as_dict()
    if ident.coupling is not None and not ident.coupling.is_identity:
        doc["coupling"] = {**ident.coupling.as_dict(), "note": "the joint values of this model are DH values; "
                           "the controller's readings give them by this equation"}
    doc["extensions"] = extensions_to_dict(ident)
    if ident.clock is not None:
        c = ident.clock
        doc["clock"] = {"offset_s": c.offset, "offset_std_s": c.offset_std, "drift": c.drift, "drift_std": c.drift_std,
                        "t_ref_s": c.t_ref, "streamed_rows": c.rows,
                        "note": "streamed rows: robot time = tracker time + offset_s + drift * (tracker time - "
                                "t_ref_s), fitted with the kinematics"}
        if c.sweeps:
            doc["clock"]["per_sweep"] = [{"sweep": s, "offset_s": o, "offset_std_s": e} for s, o, e in c.sweeps]
            doc["clock"]["note"] += ("; the sweeps' offsets differed (a clock restart or jump): each streamed sweep "
                                     "has its own (per_sweep), offset_s is their weighted mean")
    doc["axis_lines"] = {
        "note": "the plain model as joint axes at the home readings (tracker frame, m): exact even where "
                "the DH table keeps a parallel-axis convention (see verdict check dh_table)",
        **lines_to_dict(ident.lines),
    }
    a = ident.adequacy
    doc["noise"] = {
        "tracker_per_axis": a.noise,
        "declared_per_axis": a.declared,
        "residual_per_axis": a.residual,
        "difference_per_axis": a.difference,
        "model_error_per_axis": a.model_error,
        "covariance_inflation": a.inflation,
    }
    doc["uncertainty"] = {
        "note": "standard uncertainty (1 sigma); 0 for fixed parameters",
        "joints": [dict(zip(DH_NAMES, map(float, std[9 + 4 * i: 13 + 4 * i]), strict=True)) for i in range(n)],
        "base_rotation": _floats(std[0:3]),
        "base_translation": _floats(std[3:6]),
        "tool": _floats(std[6:9]),
        **({} if ident.plain.frame_std is None else {
            "tool_frame_rotation": _floats(ident.plain.frame_std),
            "tool_frame_note": "tool_frame_rotation: standard uncertainty (rad) of tool_frame's rotation, a small "
                               "turn about the last DH frame's x, y, z axes (tool_frame -> exp(w) tool_frame); its "
                               "origin's is tool's"}),
    }
    doc["fixed"] = [{"parameter": f.name, "value": f.value, "reason": f.reason}
                    | ({"sigma": f.sigma} if f.sigma else {}) for f in ident.fixed]
    doc["convention"] = {
        "values_from": f"nominal model {nominal_name}" if nominal_name else ident.convention,
        "parallel_links": ident.parallel,
        "description": CONVENTION,
    }
    doc["residuals"] = {
        "rms": ident.rms,
        "noise_per_axis": ref.noise,
        "model_error_per_axis": a.model_error,
        "samples": int(ref.inliers.size),
        "rejected_rows": ident.rejected_rows,
        **({} if ident.orientation is None else {"orientation": {
            "note": "rows that measured the target frame's orientation (full-pose devices): RMS of the kept ones' "
                    "rotation residuals (rad, 3D), each weighed by its sigma_r beside the positions' sigma",
            "samples": ident.orientation[0], "rejected": ident.orientation[1], "rms_rad": ident.orientation[2]}}),
        "per_sweep": [
            {"sweep": s.sweep, "joint": s.joint, "samples": s.samples, "rejected": s.rejected, "rms": s.rms}
            for s in ident.sweeps
        ],
    }
    doc["condition_number"] = ref.condition
    doc["validation"] = None if not ident.validations else {
        "note": "held-out (check) rows predicted by each model from the numbers written in this file (plain: the "
                "top-level DH table and tools; extended: extensions.model with extensions.terms); m",
        "use": ident.use,
        **{name: v.as_dict() for name, v in ident.validations.items()},
    }
    doc["domain"] = domain_to_dict(ident.domain)
    geo = ident.geometric
    doc["geometric_step"] = None if geo is None else {
        "home": _floats(geo.home),
        "axes": [
            {"joint": ax.joint, "type": ax.kind, "point": _floats(ax.point), "direction": _floats(ax.direction),
             "radius": None if np.isnan(ax.radius) else ax.radius, "rms": ax.rms, "travel": ax.travel,
             "samples": ax.samples, "sweep": ax.sweep}
            for ax in geo.axes
        ],
        "model": model_to_dict(geo.model),
    }
    doc["fit_start"] = ident.start
    doc["covariance"] = covariance_to_dict(ident.plain)
    if nominal is not None:
        delta = ident.model.dh_table() - nominal.dh_table()
        delta[:, 0] = np.angle(np.exp(1j * delta[:, 0]))
        doc["nominal"] = {"name": nominal_name, "delta": [dict(zip(DH_NAMES, map(float, row), strict=True))
                                                         for row in delta]}
        if nominal_model is not None:
            doc["nominal"]["model"] = nominal_model
    doc["warnings"] = list(ident.warnings) + list(ref.notes)
    doc["software"] = {"name": "dh-calib", "version": __version__}
    if source:
        doc["source"] = source
        doc["source_path"] = str(Path(source).resolve())  # what the file is, wherever the result is read from
    return finite(doc)


def extensions_to_dict(ident: Identification) -> dict[str, Any]:
    """The ``extensions`` section: joint errors selected (value, uncertainty, equation) and every decision."""
    terms = [{"name": name, "value": value, "std": std, "unit": UNITS[name.rsplit("_", 1)[0]]}
             for name, value, std in ident.extensions]
    families = sorted({d.candidate.family for d in ident.decisions if d.selected})
    out: dict[str, Any] = {
        "note": "joint errors beyond the DH table: the extended model is extensions.model with the joint standing "
                "at q + dq(q) (q: DH joint value, rad or m); the top-level model is the plain one, fitted without "
                "them",
        "home": _floats(ident.used.terms.home),
        "terms": terms,
        "equations": {f: EQUATIONS[f] for f in families},
        "selection": [
            {"term": d.candidate.family, "joint": d.candidate.joint + 1, "statistic": d.score,
             "likelihood_ratio": d.ratio, "limit": d.limit, "cv_ratio": d.cv, "selected": d.selected,
             "reason": d.reason}
            for d in ident.decisions
        ],
    }
    ext = ident.extended
    if ext is not None:
        out["model"] = model_section(ext, ident.tp_ids)
        out["axis_lines"] = lines_to_dict(ext.lines)
        out["covariance"] = covariance_to_dict(ext)
    return out


def validation_of(doc: dict[str, Any], model: str | None = None) -> dict[str, Any] | None:
    """The held-out figures (``samples``, ``rms``, ``max``, ``bound``, ``expected_rms``) of a result's ``model``
    (``plain`` or ``extended``; default: the one it recommends), or None (no check rows, or no such model).
    Results written before the two models read as their one."""
    v = doc.get("validation")
    if not isinstance(v, dict):
        return None
    if "rms" in v:  # one model only (older results)
        return v
    return v.get(model or v.get("use") or doc.get("use") or "plain")


def model_section(model: WrittenModel, tp_ids: tuple[int, ...]) -> dict[str, Any]:
    """``joints``, ``base``, ``tool`` and (several tracked points) ``tools`` of a written model; ``tool`` is the
    smallest id's, so a reader of the plain contract still gets a valid model. Where orientations were measured
    (full-pose targets), ``tool_frame``: the target frame in the last DH frame (row-major 4x4, its origin ``tool``),
    and with several tracked points ``tool_frames`` for every id that has one."""
    doc = model_to_dict(model.model)
    if len(tp_ids) > 1:
        doc["tools"] = {int(i): _floats(t) for i, t in zip(tp_ids, model.tools, strict=True)}
    frames = model.frames
    if frames is not None:
        poses = {int(i): _pose(r, t) for i, r, t in zip(tp_ids, frames, model.tools, strict=True)
                 if np.all(np.isfinite(r))}
        if int(tp_ids[0]) in poses:
            doc["tool_frame"] = poses[int(tp_ids[0])]
        if len(tp_ids) > 1:
            doc["tool_frames"] = poses
    return doc


def _pose(rotation: np.ndarray, origin: np.ndarray) -> list[list[float]]:
    """A row-major 4x4 homogeneous transform of ``rotation`` (3, 3) and ``origin`` (3,)."""
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rotation, origin
    return _floats(pose)


def lines_to_dict(lines: AxisLines) -> dict[str, Any]:
    """Axis lines at the home readings (tracker frame, m)."""
    return {
        "home": _floats(lines.home),
        "points": _floats(lines.points),
        "directions": _floats(lines.directions),
        "tp_home": _floats(lines.tp_home),
        **({"tps": _floats(lines.tps)} if len(lines.tps) > 1 else {}),
    }


def covariance_to_dict(model: WrittenModel) -> dict[str, Any]:
    """The parameters' covariance, for compensation, verification and comparison (identify/applications/calibrated.py):
    ``parameters`` (the free names of :func:`identify.estimator.dh_vector.parameter_names`; base rotation a rotation
    vector applied on the left of ``base``) and ``matrix`` (their covariance, m and rad squared: the DH table's), and
    ``predictor``: the covariance of what predicts (the axis lines' minimal parameters, the tracked points', then
    the joint-error coefficients: :class:`identify.results.predict.Predictor`)."""
    names = parameter_names(model.model.n_joints)
    free = np.flatnonzero(model.refinement.free)
    return {
        "note": "covariance of the free parameters (1 sigma squared; m, rad), noise and model error included",
        "parameters": [names[k] for k in free],
        "matrix": _floats(model.refinement.covariance),
        "predictor": _floats(model.predictor.covariance),
    }


def finite(value: Any) -> Any:
    """``value`` with every NaN or infinity replaced by None, so the document is valid JSON and YAML."""
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite(v) for v in value]
    if isinstance(value, float | np.floating):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def load_result(path: str, name: str | None = None) -> tuple[CalibratedModel, dict[str, Any]]:
    """The model of the result YAML at ``path`` and the document; ResultError (one line) when unusable."""
    p = Path(path)
    try:
        doc = yaml.safe_load(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ResultError(f"{path}: no such result file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ResultError(f"{path}: cannot be read ({exc})") from None
    except yaml.YAMLError as exc:
        raise ResultError(f"{path}: not YAML ({' '.join(str(exc).split())[:120]})") from None
    try:
        return CalibratedModel.from_document(doc, name or p.name), doc
    except ResultError as exc:
        raise ResultError(f"{path}: {exc}") from None
