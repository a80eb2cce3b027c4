"""A calibrated robot as compensation, verification and comparison use it: one forward model with its uncertainty.

Every forward prediction of those tools goes through :class:`CalibratedModel` (built from a result document or
an :class:`~identify.pipeline.Identification`), so non-geometric terms beyond DH (the result's ``extensions``:
joint-reading corrections ``q_true = q + Δq(q)``) have one place to apply: :meth:`CalibratedModel.true_joints`.
This version applies none and refuses a result that carries any, rather than ignore them.

Frames: the tracker (cell) frame unless a name says ``base`` (DH frame 0 of the model). Units: m, rad.
Predictions use the DH table where it is the identified model, and the axis lines where the DH table keeps a
parallel-axis convention that costs measurable accuracy (verdict check ``dh_table`` not passed), as
:meth:`identify.pipeline.Identification.predict` does.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from identify.geometry import rotation_about_axis
from identify.kinematics import DHModel, frames_from_joints
from identify.poe import AxisLines, LineProblem, points_from_lines
from identify.refine import full_jacobian, parameter_names

Array = NDArray[np.float64]


class ResultError(ValueError):
    """A result document that cannot be used here; the message is one line."""


@dataclass(frozen=True)
class CalibratedModel:
    """A forward model with the covariance of its parameters.

    ``model``: DH table, ``base`` (tracker <- frame 0) and default ``tool`` (TP in frame n). ``free`` (9 + 4n,)
    marks the parameters of :func:`identify.refine.parameter_names` that ``covariance`` (m, rad squared) is over
    (None: a model known exactly, e.g. a nominal one). ``lines`` / ``lines_covariance``: the axis lines that
    predict instead of the DH table when it is not exact. ``model_error``: m per axis, what the DH model cannot
    hold; ``noise``: the tracker's, m per axis. ``tools``: TP id -> tool (m, frame n). ``name``: what it is.
    """

    model: DHModel
    free: NDArray[np.bool_] | None = None
    covariance: Array | None = None
    lines: AxisLines | None = None
    lines_covariance: Array | None = None
    model_error: float = 0.0
    noise: float = 0.0
    tools: dict[int, Array] | None = None
    name: str = "model"

    # --- construction ---------------------------------------------------------------------------------------

    @classmethod
    def from_document(cls, doc: dict[str, Any], name: str = "identified") -> CalibratedModel:
        """The model of a result document (identify --out); ResultError (one line) if it cannot be used."""
        from identify.result_io import model_from_dict

        if not isinstance(doc, dict):
            raise ResultError("not a result document (expected a YAML mapping with joints, base, tool)")
        extensions = doc.get("extensions")
        if extensions:
            names = ", ".join(map(str, extensions)) if isinstance(extensions, dict | list) else str(extensions)
            raise ResultError(f"the result carries non-geometric extensions ({names}) that this version does not "
                              "apply yet (identify/calibrated.py: CalibratedModel.true_joints)")
        try:
            model = model_from_dict(doc)
        except ValueError as exc:
            raise ResultError(str(exc)) from None
        cov = doc.get("covariance")
        if not isinstance(cov, dict) or "matrix" not in cov:
            raise ResultError("the result has no parameter covariance ('covariance:'; written by dh-calib before "
                              "compensation existed): identify the data again")
        names = parameter_names(model.n_joints)
        try:
            free = np.isin(names, cov["parameters"])
            matrix = np.array(cov["matrix"], dtype=float).reshape(int(free.sum()), int(free.sum()))
            lines = None
            if cov.get("lines") is not None:
                al = doc["axis_lines"]
                lines = AxisLines(model.joint_types, np.array(al["points"], dtype=float),
                                  np.array(al["directions"], dtype=float), np.array(al["home"], dtype=float),
                                  np.array(al["tp_home"], dtype=float))
            lines_cov = None if lines is None else np.array(cov["lines"], dtype=float).reshape(
                lines.n_parameters, lines.n_parameters)
            noise = doc.get("noise") or {}
            tools = {int(k): np.array(v, dtype=float).reshape(3) for k, v in (doc.get("tools") or {}).items()}
        except (KeyError, TypeError, ValueError) as exc:
            raise ResultError(f"malformed covariance or axis lines in the result ({exc})") from None
        if len(cov["parameters"]) != free.sum() or not np.all(np.isfinite(matrix)):
            raise ResultError("the result's covariance names unknown parameters or holds non-numbers")
        return cls(model, free, matrix, lines, lines_cov, float(noise.get("model_error_per_axis") or 0.0),
                   float(noise.get("tracker_per_axis") or 0.0), tools or None, name)

    @classmethod
    def from_identification(cls, ident: Any, name: str = "identified") -> CalibratedModel:
        """The model of an :class:`~identify.pipeline.Identification` (what its result document would give)."""
        exact = ident.exact_dh
        return cls(ident.model, ident.refinement.free.copy(), ident.refinement.covariance,
                   None if exact else ident.lines, None if exact else ident.lines_covariance,
                   float(ident.adequacy.model_error), float(ident.adequacy.noise), None, name)

    @classmethod
    def exact(cls, model: DHModel, name: str = "nominal") -> CalibratedModel:
        """A model taken as exact (no covariance), e.g. the nominal one a controller uses."""
        return cls(model, name=name)

    def with_base(self, base: Array) -> CalibratedModel:
        """The same robot seen in another frame: ``base`` (4x4) replaces tracker <- frame 0 (axis lines moved
        along). Covariances are kept (the base's own uncertainty then no longer means anything)."""
        base = np.asarray(base, dtype=float)
        lines = self.lines
        if lines is not None:
            move = base @ np.linalg.inv(self.model.base)
            rot, shift = move[:3, :3], move[:3, 3]
            lines = AxisLines(lines.joint_types, lines.points @ rot.T + shift, lines.directions @ rot.T, lines.home,
                              rot @ lines.tp_home + shift)
        return replace(self, model=replace(self.model, base=base), lines=lines)

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
        """Joint values the geometry sees for readings ``q`` (k, n): the one place where joint-reading
        corrections (``extensions``) apply. None are supported yet, so ``q`` itself (as float (k, n))."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        if q.shape[1] != self.n_joints:
            raise ValueError(f"joint values must have {self.n_joints} columns; got shape {q.shape}")
        return q

    def axes(self, q: Array) -> tuple[Array, Array, Array]:
        """At readings ``q`` (k, n): joint axis directions (k, n, 3), points on them (k, n, 3) and the flange
        frame (k, 4, 4), tracker frame. The TP is ``flange · [tool, 1]``."""
        qt = self.true_joints(q)
        if self.lines is None:
            frames = frames_from_joints(self.model, qt)
            return frames[:, :-1, :3, 2], frames[:, :-1, :3, 3], frames[:, -1]
        return self._line_axes(qt)

    def flanges(self, q: Array) -> Array:
        """Flange frames (k, 4, 4): tracker <- frame n at readings ``q`` (k, n)."""
        return self.axes(q)[2]

    def points(self, q: Array, tool: Array | None = None) -> Array:
        """Predicted TP (k, 3), tracker frame, at readings ``q`` (k, n); ``tool`` (3,) replaces the TP."""
        if self.lines is not None and tool is None:
            return points_from_lines(self.lines, self.true_joints(q))
        flange = self.flanges(q)
        t = self.model.tool if tool is None else np.asarray(tool, dtype=float)
        return flange[:, :3, :3] @ t + flange[:, :3, 3]

    def _line_axes(self, q: Array) -> tuple[Array, Array, Array]:
        """:meth:`axes` from the axis lines: each joint's screw motion at home, composed from the base."""
        lines = self.lines
        assert lines is not None
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

    def point_covariances(self, q: Array, tool: Array | None = None, frame: str = "tracker") -> Array:
        """Covariance (k, 3, 3) of the predicted TP (or of ``tool``, taken as exact) at ``q``, m², from the
        parameters' uncertainty; zeros for an exact model. ``frame="base"``: the point in frame 0, from the DH
        parameters alone (the base's uncertainty does not move a point in the robot's own frame)."""
        k = len(np.atleast_2d(q))
        if self.covariance is None or self.free is None:
            return np.zeros((k, 3, 3))
        if self.lines is not None and self.lines_covariance is not None and tool is None and frame == "tracker":
            qt = self.true_joints(q)
            problem = LineProblem(self.lines, qt, np.zeros((k, 3)), np.ones(k))
            g = problem.jacobian_blocks(np.zeros(self.lines.n_parameters), q=qt)
            return g @ self.lines_covariance @ np.swapaxes(g, 1, 2)
        model = self.model if tool is None else replace(self.model, tool=np.asarray(tool, dtype=float))
        if frame == "base":
            model = replace(model, base=np.eye(4))
        _, jac = full_jacobian(model, self.true_joints(q))
        cov = self.covariance
        if tool is not None or frame == "base":  # drop the tool (exact) and, in frame 0, the base
            keep = np.ones(len(self.free), dtype=bool)
            keep[6:9] = tool is None
            if frame == "base":
                keep[:6] = False
            sel = keep[self.free]
            cov = cov[np.ix_(sel, sel)]
            g = jac[:, :, self.free & keep]
        else:
            g = jac[:, :, self.free]
        return g @ cov @ np.swapaxes(g, 1, 2)

    def expected_errors(self, q: Array, tool: Array | None = None, frame: str = "tracker") -> Array:
        """Expected 3D error (k,) of the prediction at each of ``q``, m: the RMS the parameters' uncertainty and
        the model error give, ``sqrt(trace(cov) + 3 model_error²)``."""
        cov = self.point_covariances(q, tool, frame)
        return np.sqrt(np.trace(cov, axis1=1, axis2=2) + 3 * self.model_error**2)

    def expected_rms(self, q: Array) -> float:
        """RMS over ``q`` of :meth:`expected_errors`, m."""
        return float(np.sqrt(np.mean(self.expected_errors(q) ** 2)))


def load_result(path: str, name: str | None = None) -> tuple[CalibratedModel, dict[str, Any]]:
    """The model of the result YAML at ``path`` and the document; ResultError (one line) when unusable."""
    from pathlib import Path

    import yaml

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


def nominal_name(doc: dict[str, Any]) -> str | None:
    """The nominal model a result was identified against (``nominal.name``), or None."""
    nominal = doc.get("nominal") if isinstance(doc, dict) else None
    return nominal.get("name") if isinstance(nominal, dict) else None
