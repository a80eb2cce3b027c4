"""Read the models a result YAML gives a user and predict with them, by this package's own forward model.

Two models per file (README.md, File contracts): the plain one (top-level ``joints``, ``base``, ``tool``/``tools``,
``coupling``: standard DH, no joint errors) and, when ``extensions`` is present, the extended one: the DH part
``extensions.model`` with the joint errors
``extensions.terms`` applied as ``extensions.equations`` state: the joint stands at ``q + dq(q)``, with
``dq_i = scale_i (q_i - home_i) + ecc_sin_i (sin q_i - sin home_i) + ecc_cos_i (cos q_i - cos home_i)`` on
DH values ``q = C · readings + offset``. Compliance terms need the arm's gravity torques, which this scorer
does not compute: a model holding them is reported as not scored rather than scored without them. Files
written before ``extensions.model`` existed predict their joint errors from ``axis_lines``, which no DH reader
can use: their extended model is reported as not in the file.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.realdata.common import Array, dh_points

KNOWN_TERMS = ("scale", "ecc_sin", "ecc_cos")


@dataclass
class Model:
    """A written model: DH ``table`` rows ``theta, d, a, alpha`` (rad, m), ``base`` 4x4 (tracker <- frame 0),
    ``tools`` {tp: [x, y, z]} (m, last frame), the readings' coupling and joint-error ``terms`` {name: value}."""

    types: str
    table: Array
    base: Array
    tools: dict[int, Array]
    coupling: Array
    offset: Array
    terms: dict[str, float] = field(default_factory=dict)
    home: Array | None = None

    @property
    def scorable(self) -> bool:
        return all(name.rsplit("_", 1)[0] in KNOWN_TERMS for name in self.terms)

    def dh_values(self, readings: Array) -> Array:
        """DH joint values (rad, m) at ``readings`` (m x n), joint errors included."""
        q = readings @ self.coupling.T + self.offset
        if not self.terms:
            return q
        dq = np.zeros_like(q)
        home = np.zeros(q.shape[1]) if self.home is None else self.home
        for name, value in self.terms.items():
            kind, joint = name.rsplit("_", 1)
            j = int(joint) - 1
            if kind == "scale":
                dq[:, j] += value * (q[:, j] - home[j])
            elif kind == "ecc_sin":
                dq[:, j] += value * (np.sin(q[:, j]) - np.sin(home[j]))
            elif kind == "ecc_cos":
                dq[:, j] += value * (np.cos(q[:, j]) - np.cos(home[j]))
            else:
                raise ValueError(f"joint error {name!r} is not scored here (see the module docstring)")
        return q + dq

    def predict(self, readings: Array, tp: np.ndarray) -> Array:
        """Points (m, tracker frame) at ``readings`` of the tracked points ``tp`` (one id per row)."""
        q = self.dh_values(readings)
        out = np.empty((len(readings), 3))
        for point in np.unique(tp):
            rows = tp == point
            out[rows] = dh_points(self.table, self.types, self.base, self.tools[int(point)], q[rows])
        return out


def _dh(section: dict[str, Any]) -> tuple[str, Array, Array, dict[int, Array]]:
    joints = section["joints"]
    types = "".join(j["type"] for j in joints)
    table = np.array([[j["theta"], j["d"], j["a"], j["alpha"]] for j in joints], dtype=float)
    base = np.array(section["base"], dtype=float)
    tools = {int(k): np.array(v, dtype=float) for k, v in (section.get("tools") or {}).items()}
    tools = tools or {1: np.array(section["tool"], dtype=float)}
    return types, table, base, tools


def models(doc: dict[str, Any]) -> dict[str, Model]:
    """``{"plain": Model, "extended": Model}`` (extended only when the file has joint errors)."""
    types, table, base, tools = _dh(doc)
    n = len(types)
    coupling = doc.get("coupling") or {}
    matrix = np.array(coupling.get("matrix", np.eye(n)), dtype=float)
    offset = np.array(coupling.get("offset", np.zeros(n)), dtype=float)
    out = {"plain": Model(types, table, base, tools, matrix, offset)}
    ext = doc.get("extensions")
    if ext and ext.get("terms") and ext.get("model"):
        section = ext["model"]
        e_types, e_table, e_base, e_tools = _dh(section)
        terms = {t["name"]: float(t["value"]) for t in ext["terms"]}
        out["extended"] = Model(e_types, e_table, e_base, e_tools, matrix, offset, terms,
                                np.array(ext.get("home", np.zeros(n)), dtype=float))
    return out


def from_robot(doc: dict[str, Any], tracked: list[int]) -> Model:
    """The nominal of a robot YAML (``config/robots/*.yaml`` format: ``joints``, ``dh``, optional ``coupling``)
    as a model with an identity base and zero tools for the tracked points ``tracked``."""
    types = doc["joints"]
    n = len(types)
    table = np.array([[row["theta"], row["d"], row["a"], row["alpha"]] for row in doc["dh"]], dtype=float)
    coupling = doc.get("coupling") or {}
    return Model(types, table, np.eye(4), {tp: np.zeros(3) for tp in tracked},
                 np.array(coupling.get("matrix", np.eye(n)), dtype=float),
                 np.array(coupling.get("offset", np.zeros(n)), dtype=float))


def stated(doc: dict[str, Any]) -> dict[str, float]:
    """What the file says its models predict on the check rows (m): ``{model: expected RMS}``. Files with
    ``validation.plain``/``extended`` state one per model; older files one for the full predictor (extended
    when there are joint errors, else plain)."""
    v = doc.get("validation") or {}
    if "plain" in v or "extended" in v:
        return {k: float(v[k]["expected_rms"]) for k in ("plain", "extended")
                if isinstance(v.get(k), dict) and v[k].get("expected_rms") is not None}
    if v.get("expected_rms") is None:
        return {}
    return {("extended" if (doc.get("extensions") or {}).get("terms") else "plain"): float(v["expected_rms"])}
