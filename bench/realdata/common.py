"""What every converter and the real-data bench share: the measurement CSV they write, and an independent forward
model to score written models with.

The forward model here is written from the README's equations (File contracts) and nothing else (it imports nothing from
``identify`` or ``kinematics``), so a model the product writes is scored by code that did not make it:
``T(q) = base · A_1(q_1) ··· A_n(q_n)``, ``A_i = Rz(theta_i + q_i) · Tz(d_i) · Tx(a_i) · Rx(alpha_i)`` (revolute;
``Tz(d_i + q_i)`` prismatic), point ``p = T(q) · [tool, 1]``; metres and radians; ``q`` are DH joint values
(readings after the coupling).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


class DataError(ValueError):
    """A data folder that does not hold what its converter expects (one line, names the file)."""


@dataclass
class Converted:
    """One set in the CSV contract: ``q`` readings (rad), ``points`` (m, tracker frame), one entry per row."""

    joints: str
    q: Array
    points: Array
    sweep: NDArray[np.int64]
    joint: NDArray[np.int64]
    check: NDArray[np.bool_]
    tp: NDArray[np.int64]
    sigma: Array | None = None
    coupling: Array | None = None
    metadata: dict[str, str] = field(default_factory=dict)

    def csv_text(self) -> str:
        """The measurement CSV (README.md, File contracts): metres, radians, ``role`` and ``tp`` columns."""
        out = io.StringIO()
        out.write(f"# joints: {self.joints}\n# units: m, rad\n")
        if self.coupling is not None:
            out.write(f"# coupling: {self.coupling.tolist()}\n")
        for key, value in self.metadata.items():
            out.write(f"# {key}: {value}\n")
        n = len(self.joints)
        header = ["sweep", "joint", *(f"q{j}" for j in range(1, n + 1)), "x", "y", "z", "role", "tp"]
        if self.sigma is not None:
            header.append("sigma")
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(header)
        for k in range(len(self.q)):
            row = [str(int(self.sweep[k])), str(int(self.joint[k]))]
            row += [repr(float(v)) for v in self.q[k]] + [repr(float(v)) for v in self.points[k]]
            row += ["check" if self.check[k] else "fit", str(int(self.tp[k]))]
            if self.sigma is not None:
                row.append(repr(float(self.sigma[k])))
            writer.writerow(row)
        return out.getvalue()

    def write(self, path: Path) -> Path:
        path.write_text(self.csv_text(), encoding="utf-8")
        return path

    def dh_values(self) -> Array:
        """DH joint values of every row (coupling applied), rad or m."""
        return self.q if self.coupling is None else self.q @ self.coupling.T


def free_poses(joints: str, q: Array, points: Array, source: str, hold_every: int = 4,
               sigma: Array | None = None) -> Converted:
    """Free poses (``joint`` 0, one sweep id each) of one tracked point, every ``hold_every``-th (0-based index
    hold_every - 1, 2 hold_every - 1, ...) held out; ``source`` goes into the CSV's metadata."""
    m = len(q)
    check = np.arange(m) % hold_every == hold_every - 1
    return Converted(joints, q, points, np.arange(1, m + 1), np.zeros(m, dtype=np.int64), check,
                     np.ones(m, dtype=np.int64), sigma=sigma, metadata={"source": source})


def no_sessions(folder: Path) -> dict[str, Converted]:
    return {}


@dataclass(frozen=True)
class Source:
    """One public set as the bench runs it: ``DATA/<folder>/`` holds its files.

    ``convert`` gives the fit session with the set's fixed held-out rows (``role`` check); ``sessions`` the later
    sessions of the same arm (all rows check; scored after a rigid re-registration of the tracker); ``nominal``
    the robot YAML the product starts from (None: the set's sweeps identify the arm from scratch); ``regions`` the
    DH joints (1-based) whose upper half of the fit session is held out in a region split; ``published`` the
    figures the source states, by split slug (the bench prints them beside its own rows); ``retool``: the tracked
    point was re-mounted between sessions, so a later session re-fits the tools with the tracker's pose."""

    name: str
    folder: str
    convert: Callable[[Path], Converted]
    sessions: Callable[[Path], dict[str, Converted]] = no_sessions
    nominal: Path | None = None
    regions: tuple[int, ...] = ()
    published: dict[str, str] = field(default_factory=dict)
    retool: bool = False


def require(path: Path) -> Path:
    if not path.is_file():
        raise DataError(f"{path}: missing (see bench/realdata/README.md for what the folder must hold)")
    return path


def dh_points(table: Array, types: str, base: Array, tool: Array, q: Array) -> Array:
    """Points (m, tracker frame) of the tracked point ``tool`` (m, last DH frame) at DH values ``q`` (m x n).
    ``table`` rows are ``theta, d, a, alpha`` (rad, m); ``base`` is 4x4 (tracker <- DH frame 0)."""
    q = np.atleast_2d(q)
    m = len(q)
    frames = np.broadcast_to(base, (m, 4, 4)).copy()
    for i, (theta, d, a, alpha) in enumerate(table):
        angle = theta + (q[:, i] if types[i] == "R" else 0.0)
        length = d + (q[:, i] if types[i] == "P" else 0.0)
        c, s, ca, sa = np.cos(angle), np.sin(angle), np.cos(alpha), np.sin(alpha)
        link = np.zeros((m, 4, 4))
        link[:, 0, 0], link[:, 0, 1], link[:, 0, 2], link[:, 0, 3] = c, -s * ca, s * sa, a * c
        link[:, 1, 0], link[:, 1, 1], link[:, 1, 2], link[:, 1, 3] = s, c * ca, -c * sa, a * s
        link[:, 2, 1], link[:, 2, 2], link[:, 2, 3] = sa, ca, length
        link[:, 3, 3] = 1.0
        frames = frames @ link
    return frames[:, :3, :3] @ np.asarray(tool, dtype=float) + frames[:, :3, 3]


def rigid_fit(source: Array, target: Array) -> tuple[Array, Array]:
    """Rotation R and translation t minimising ``|R · source + t - target|`` (Kabsch, no scale), m x 3 each."""
    cs, ct = source.mean(axis=0), target.mean(axis=0)
    u, _, vt = np.linalg.svd((source - cs).T @ (target - ct))
    flip = np.diag([1.0, 1.0, np.sign(np.linalg.det(vt.T @ u.T))])
    rotation = vt.T @ flip @ u.T
    return rotation, ct - rotation @ cs


def rms(errors: Array) -> float:
    """RMS of the 3D error lengths (m)."""
    return float(np.sqrt(np.mean(np.sum(np.square(errors), axis=1)))) if len(errors) else float("nan")
