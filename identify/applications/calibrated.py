"""A calibrated robot as compensation, verification and comparison use it: one forward model with its uncertainty.

Every forward prediction of those tools goes through :class:`CalibratedModel`, built from a result document or an
:class:`~identify.results.pipeline.Identification`. Where the result has one, it predicts with the identification's own
:class:`~identify.results.predict.Predictor` (controller readings -> DH joint values through the coupling -> joint
errors, the result's ``extensions`` -> the axis lines, which are the identified model exactly), so compensation and
verification see everything the identification found; :meth:`CalibratedModel.true_joints` is that chain's first
half and :meth:`CalibratedModel.axes` the frames along it (for the inverse kinematics' Jacobian and tool poses).

Frames: the tracker (cell) frame unless a name says ``base`` (DH frame 0 of the model). Units: m, rad.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray

from common.errors import InputError
from identify.estimator.dh_vector import full_jacobian, parameter_names
from identify.estimator.geometry import rotation_about_axis
from identify.estimator.poe import AxisLines
from identify.results.predict import Predictor
from kinematics.dh import DHModel, frames_from_joints, model_from_dict

Array = NDArray[np.float64]


class ResultError(ValueError):
    """A result document that cannot be used here; the message is one line."""


@dataclass(frozen=True)
class CalibratedModel:
    """A forward model with the covariance of its parameters.

    ``model``: DH table, ``base`` (tracker <- frame 0) and default ``tool`` (TP in frame n). ``free`` (9 + 4n,)
    marks the parameters of :func:`identify.estimator.dh_vector.parameter_names` that ``covariance`` (m, rad squared) is
    over (None: a model known exactly, e.g. a nominal one). ``predictor``: what predicts where the result has it (None:
    the DH table alone). ``model_error``: m per axis, what the model cannot hold; ``noise``: the tracker's, m per
    axis. ``tools``: TP id -> tool (m, frame n). ``name``: what it is. ``held`` (9 + 4n,): sigmas (m, rad) of fixed
    values that are the nominal's (frame n placed as the catalogue places the flange), which a tool given on the
    flange carries; None for none.
    """

    model: DHModel
    free: NDArray[np.bool_] | None = None
    covariance: Array | None = None
    predictor: Predictor | None = None
    model_error: float = 0.0
    noise: float = 0.0
    tools: dict[int, Array] | None = None
    name: str = "model"
    held: Array | None = None

    # --- construction ---------------------------------------------------------------------------------------

    @classmethod
    def from_document(cls, doc: dict[str, Any], name: str = "identified") -> CalibratedModel:
        """The model a result document (identify --out) recommends (``use``: its extended model, DH with joint
        errors, when it has one; else the top-level plain model); ResultError (one line) if it cannot be used."""
        if not isinstance(doc, dict):
            raise ResultError("not a result document (expected a YAML mapping with joints, base, tool)")
        section = used_section(doc)
        try:
            model = model_from_dict(section)
        except ValueError as exc:
            raise ResultError(str(exc)) from None
        cov = section.get("covariance")
        if not isinstance(cov, dict) or "matrix" not in cov or cov.get("predictor") is None:
            raise ResultError("the result has no parameter covariance ('covariance:' with its predictor; written by "
                              "dh-calib before compensation existed): identify the data again")
        names = parameter_names(model.n_joints)
        try:
            free = np.isin(names, cov["parameters"])
            matrix = np.array(cov["matrix"], dtype=float).reshape(int(free.sum()), int(free.sum()))
            tools = {int(k): np.array(v, dtype=float).reshape(3) for k, v in (section.get("tools") or {}).items()}
            predictor = predictor_from_document(doc, model, sorted(tools) or [1])
            noise = doc.get("noise") or {}
        except (KeyError, TypeError, ValueError) as exc:
            raise ResultError(f"malformed covariance, axis lines or extensions in the result ({exc})") from None
        if len(cov["parameters"]) != free.sum() or not np.all(np.isfinite(matrix)):
            raise ResultError("the result's covariance names unknown parameters or holds non-numbers")
        return cls(model, free, matrix, predictor, float(noise.get("model_error_per_axis") or 0.0),
                   float(noise.get("tracker_per_axis") or 0.0), tools or None, name,
                   _held_sigmas(names, doc.get("fixed") or []))

    @classmethod
    def from_identification(cls, ident: Any, name: str = "identified") -> CalibratedModel:
        """The model of an :class:`~identify.results.pipeline.Identification` (what its result document would give)."""
        used = ident.used
        tools = {int(i): np.asarray(t, dtype=float) for i, t in zip(ident.tp_ids, used.tools, strict=True)}
        names = parameter_names(used.model.n_joints)
        fixed = [{"parameter": f.name, "sigma": f.sigma} for f in used.fixed]
        return cls(used.model, used.refinement.free.copy(), used.refinement.covariance, ident.predictor,
                   float(ident.adequacy.model_error), float(ident.adequacy.noise),
                   tools if len(tools) > 1 else None, name, _held_sigmas(names, fixed))

    @classmethod
    def exact(cls, model: DHModel, name: str = "nominal") -> CalibratedModel:
        """A model taken as exact (no covariance, no predictor), e.g. the nominal one a controller uses."""
        return cls(model, name=name)

    def with_base(self, base: Array) -> CalibratedModel:
        """The same robot seen in another frame: ``base`` (4x4) replaces tracker <- frame 0 (axis lines moved
        along). Covariances are kept (the base's own uncertainty then no longer means anything)."""
        base = np.asarray(base, dtype=float)
        predictor = self.predictor
        if predictor is not None:
            move = base @ np.linalg.inv(self.model.base)
            rot, shift = move[:3, :3], move[:3, 3]
            lines = predictor.lines
            moved = AxisLines(lines.joint_types, lines.points @ rot.T + shift, lines.directions @ rot.T, lines.home,
                              rot @ lines.tp_home + shift, lines.extra_tps @ rot.T + shift)
            predictor = replace(predictor, lines=moved)
        return replace(self, model=replace(self.model, base=base), predictor=predictor)

    # --- forward model --------------------------------------------------------------------------------------

    @property
    def n_joints(self) -> int:
        return self.model.n_joints

    @property
    def base(self) -> Array:
        """Tracker <- frame 0 (4x4)."""
        return self.model.base

    def tool(self, tp: int | None = None) -> Array:
        """The TP ``tp`` (default: the result's ``tool``) in frame n, m."""
        if tp is None or not self.tools:
            return self.model.tool
        if tp not in self.tools:
            raise ResultError(f"the result has no tracked point {tp} (it has {sorted(self.tools)})")
        return self.tools[tp]

    def true_joints(self, q: Array) -> Array:
        """The DH joint values the geometry sees (k, n) for controller readings ``q`` (k, n): through the coupling
        and the joint errors of the result where it has them."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        if q.shape[1] != self.n_joints:
            raise ValueError(f"joint values must have {self.n_joints} columns; got shape {q.shape}")
        return q if self.predictor is None else self.predictor.joints(q)

    def dh_values(self, q: Array) -> Array:
        """DH joint values (k, n) of readings ``q`` (k, n) through the coupling alone (what a nominal DH model
        takes); the readings themselves without a coupling."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        coupling = None if self.predictor is None else self.predictor.coupling
        return q if coupling is None else coupling.dh_from_readings(q)

    def readings(self, q_dh: Array) -> Array:
        """Readings (k, n) that give DH joint values ``q_dh`` (k, n) through the coupling (inverse of
        :meth:`dh_values`)."""
        q_dh = np.atleast_2d(np.asarray(q_dh, dtype=float))
        coupling = None if self.predictor is None else self.predictor.coupling
        return q_dh if coupling is None else coupling.readings_from_dh(q_dh)

    def reading_jacobian(self) -> Array:
        """d(DH joint values)/d(readings) (n, n): the coupling matrix (the joint errors' own slope, of order 1e-4,
        is left out: the inverse kinematics converges all the same)."""
        coupling = None if self.predictor is None else self.predictor.coupling
        return np.eye(self.n_joints) if coupling is None else coupling.matrix

    def axes(self, q: Array) -> tuple[Array, Array, Array]:
        """At readings ``q`` (k, n): joint axis directions (k, n, 3), points on them (k, n, 3) and the flange
        frame (k, 4, 4), tracker frame. The TP is ``flange · [tool, 1]``."""
        qt = self.true_joints(q)
        if self.predictor is None:
            frames = frames_from_joints(self.model, qt)
            return frames[:, :-1, :3, 2], frames[:, :-1, :3, 3], frames[:, -1]
        return self._line_axes(qt)

    def flanges(self, q: Array) -> Array:
        """Flange frames (k, 4, 4): tracker <- frame n at readings ``q`` (k, n)."""
        return self.axes(q)[2]

    def points(self, q: Array, tool: Array | None = None, tp: int | None = None) -> Array:
        """Predicted TP (k, 3), tracker frame, at readings ``q`` (k, n): tracked point ``tp`` (default the first),
        or the point ``tool`` (3,) of the flange frame."""
        if self.predictor is not None and tool is None:
            return self.predictor.points(np.atleast_2d(np.asarray(q, dtype=float)), tp)
        flange = self.flanges(q)
        t = self.tool(tp) if tool is None else np.asarray(tool, dtype=float)
        return flange[:, :3, :3] @ t + flange[:, :3, 3]

    def _line_axes(self, q: Array) -> tuple[Array, Array, Array]:
        """:meth:`axes` from the axis lines at DH joint values ``q``: each joint's screw motion at home, composed
        from the base; the flange is the DH table's at home, moved onto the lines' first tracked point."""
        assert self.predictor is not None
        lines = self.predictor.lines
        k, n = len(q), self.n_joints
        directions, points = np.empty((k, n, 3)), np.empty((k, n, 3))
        rot, shift = np.broadcast_to(np.eye(3), (k, 3, 3)).copy(), np.zeros((k, 3))
        for i in range(n):
            directions[:, i] = rot @ lines.directions[i]
            points[:, i] = rot @ lines.points[i] + shift
            delta = q[:, i] - lines.home[i]
            if lines.joint_types[i] == "R":
                r = rotation_about_axis(lines.directions[i], delta)
                t = lines.points[i] - r @ lines.points[i]
            else:
                r = np.broadcast_to(np.eye(3), (k, 3, 3))
                t = delta[:, None] * lines.directions[i]
            shift = np.einsum("kij,kj->ki", rot, t) + shift
            rot = rot @ r
        home = frames_from_joints(self.model, lines.home)[0, -1].copy()
        home[:3, 3] = lines.tp_home - home[:3, :3] @ self.model.tool  # the DH flange, moved onto the lines' TP
        flange = np.empty((k, 4, 4))
        flange[:, :3, :3] = rot @ home[:3, :3]
        flange[:, :3, 3] = np.einsum("kij,j->ki", rot, home[:3, 3]) + shift
        flange[:, 3] = (0.0, 0.0, 0.0, 1.0)
        return directions, points, flange

    # --- uncertainty ----------------------------------------------------------------------------------------

    def point_covariances(self, q: Array, tool: Array | None = None, frame: str = "tracker",
                          tp: int | None = None) -> Array:
        """Covariance (k, 3, 3) of the predicted TP ``tp`` (or of ``tool``, taken as exact) at readings ``q``,
        m², from the parameters' uncertainty; zeros for an exact model. ``frame="base"``: the point in frame 0,
        from the DH parameters alone (the base's uncertainty does not move a point in the robot's own frame)."""
        k = len(np.atleast_2d(q))
        if self.covariance is None or self.free is None:
            return np.zeros((k, 3, 3))
        if self.predictor is not None and tool is None and frame == "tracker":
            return self.predictor.covariances(np.atleast_2d(np.asarray(q, dtype=float)), tp)
        t = self.tool(tp) if tool is None else np.asarray(tool, dtype=float)
        model = replace(self.model, tool=t)
        if frame == "base":
            model = replace(model, base=np.eye(4))
        _, jac = full_jacobian(model, self.true_joints(q))
        keep = np.ones(len(self.free), dtype=bool)
        keep[6:9] = tool is None  # a given tool is exact
        if frame == "base":
            keep[:6] = False
        sel = keep[self.free]
        g = jac[:, :, self.free & keep]
        out = g @ self.covariance[np.ix_(sel, sel)] @ np.swapaxes(g, 1, 2)
        if tool is not None and self.held is not None:  # a tool on the flange: where the nominal put the flange
            h = jac * self.held
            out += h @ np.swapaxes(h, 1, 2)
        return out

    def expected_errors(self, q: Array, tool: Array | None = None, frame: str = "tracker") -> Array:
        """Expected 3D error (k,) of the prediction at each of ``q``, m: the RMS the parameters' uncertainty and
        the model error give, ``sqrt(trace(cov) + 3 model_error²)``."""
        cov = self.point_covariances(q, tool, frame)
        return np.sqrt(np.trace(cov, axis1=1, axis2=2) + 3 * self.model_error**2)

    def expected_rms(self, q: Array) -> float:
        """RMS over ``q`` of :meth:`expected_errors`, m."""
        return float(np.sqrt(np.mean(self.expected_errors(q) ** 2)))


def _held_sigmas(names: list[str], fixed: list[Any]) -> Array | None:
    """The full vector's sigmas (m, rad) of the ``fixed`` entries (result document) that carry one; None for none."""
    out = np.zeros(len(names))
    for entry in fixed:
        if isinstance(entry, dict) and entry.get("sigma") and entry.get("parameter") in names:
            out[names.index(entry["parameter"])] = float(entry["sigma"])
    return out if np.any(out) else None


def predictor_from_document(doc: dict[str, Any], model: DHModel, tp_ids: list[int]) -> Predictor:
    """The identification's predictor rebuilt from its result document: axis lines, coupling, joint-error terms
    (``extensions``; compliance needs the nominal robot's link masses) and ``covariance.predictor``."""
    from identify.estimator.extensions import Candidate, TermSet
    from kinematics.joint_errors import Coupling, gravity_torques

    section = used_section(doc)
    al = section["axis_lines"]
    tps = np.array(al.get("tps") or [al["tp_home"]], dtype=float).reshape(-1, 3)
    lines = AxisLines(model.joint_types, np.array(al["points"], dtype=float), np.array(al["directions"], dtype=float),
                      np.array(al["home"], dtype=float), np.array(al["tp_home"], dtype=float), tps[1:])
    coupling = None
    if doc.get("coupling"):
        coupling = Coupling(np.array(doc["coupling"]["matrix"], dtype=float),
                            np.array(doc["coupling"].get("offset") or np.zeros(model.n_joints), dtype=float))
    ext = doc.get("extensions") or {}
    terms = (ext.get("terms") or []) if doc.get("use") != "plain" else []  # a plain model recommended: no terms
    candidates: list[Candidate] = []
    for term in terms:
        family, joint = term["name"].rsplit("_", 1)
        family = "eccentricity" if family.startswith("ecc_") else family
        candidate = Candidate(family, int(joint) - 1)
        if candidate not in candidates:
            candidates.append(candidate)
    torques = None
    if any(c.family == "compliance" for c in candidates):
        from config.robots import ConfigError, load_robot

        name = nominal_name(doc)
        try:
            robot = load_robot(name) if name else None
        except ConfigError:
            robot = None
        if robot is None or robot.links is None:
            raise ResultError(f"the result's compliance terms need the link masses of its robot ({name or 'none'})")
        torques = partial(gravity_torques, robot.nominal, robot.links)
    home = np.array(ext.get("home") if ext.get("home") is not None else lines.home, dtype=float)
    term_set = TermSet(tuple(candidates), home, torques)
    by_name = {t["name"]: float(t["value"]) for t in terms}
    coefs = np.array([by_name[n] for n in term_set.names], dtype=float)
    size = lines.n_parameters + len(coefs)
    covariance = np.array(section["covariance"]["predictor"], dtype=float).reshape(size, size)
    return Predictor(lines, covariance, term_set, coefs, coupling, tuple(tp_ids))


def used_section(doc: dict[str, Any]) -> dict[str, Any]:
    """The part of a result document that holds the model it recommends: ``extensions.model`` (with the
    extended model's axis lines and covariance) when ``use`` is ``extended``, else the document itself (the
    top-level plain model; results written before ``use`` existed keep their joint errors beside it)."""
    ext = doc.get("extensions") if isinstance(doc.get("extensions"), dict) else {}
    if doc.get("use") != "extended":
        return doc
    if not isinstance(ext.get("model"), dict) or "axis_lines" not in ext or "covariance" not in ext:
        raise ResultError("the result recommends its extended model but extensions.model, axis_lines or covariance "
                          "is missing")
    return {**ext["model"], "axis_lines": ext["axis_lines"], "covariance": ext["covariance"]}


def nominal_name(doc: dict[str, Any]) -> str | None:
    """The nominal model a result was identified against (``nominal.name``), or None."""
    nominal = doc.get("nominal") if isinstance(doc, dict) else None
    return nominal.get("name") if isinstance(nominal, dict) else None


def robot_model(name: str | None, recorded: Any = None, where: str | None = None):
    """The robot model named ``name`` (bundled name or YAML path), None for None; a bad name or file is an
    :class:`~common.errors.InputError` (one line). ``recorded``: the model document a session or a result
    ``where`` records (:func:`recorded_model`): it is the model when ``name`` is its name (the file it was read
    from may be gone)."""
    if name is None:
        return None
    if not name.strip():
        raise InputError("--robot is empty: name a bundled model (e.g. ur5e) or a robot YAML file")
    from config.robots import ConfigError, load_robot, robot_from_document

    try:
        if isinstance(recorded, dict) and str(recorded.get("name", "")).strip().lower() == name.strip().lower():
            return robot_from_document(recorded, f"{where or 'the input'}: its recorded robot model")
        return load_robot(name)
    except ConfigError as exc:
        hint = (f"; {where} names a robot model it does not record: give its YAML file with --robot FILE"
                if where is not None else "")
        raise InputError(f"{exc}{hint}") from None


def recorded_model(doc: Any) -> dict[str, Any] | None:
    """The robot model document (config/robots.py ``model_document``) a result (``nominal.model``) or a session
    header (``config.robot_model``) records, None when it records none (a bundled model, or an older file)."""
    if not isinstance(doc, dict):
        return None
    for section, key in (("nominal", "model"), ("config", "robot_model")):
        value = (doc.get(section) or {}).get(key) if isinstance(doc.get(section), dict) else None
        if isinstance(value, dict):
            return value
    return None
