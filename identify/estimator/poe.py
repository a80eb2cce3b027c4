"""Maximum-likelihood fit of the joint axes as lines (product of exponentials at the home pose).

Model, tracker frame, metres: ``p(q) = T_1(q_1 - h_1) ∘ … ∘ T_n(q_n - h_n) (p_home)`` where ``T_i`` turns
about joint i's axis line (revolute) or slides along its direction (prismatic), both as they are at the
home pose ``h``. Lines have no singular configuration (parallel or intersecting axes are ordinary), so
this fit is well conditioned where DH is not; its lines are then turned into DH frames.
Parameters: per revolute joint, 2 tilts of the direction and 2 shifts of the point; per prismatic, 2
tilts; then the TP at home (3). That is exactly what position-only data determine (4R + 2P + 3).

Several tracked points (reflectors) share the lines; each has its own position at home (``tps``). A tracked point
whose rows measured the target frame's orientation too (6-DoF probes, camera targets) also has that frame's rotation
at home (``orientations``): it turns with the chain's rotation, ``R(q) = L(q) · R_home`` with ``L(q)`` the product
of the joints' rotations about their lines; an orientation row's residual is ``log(R(q) · R_measuredᵀ)`` (rad,
:mod:`identify.estimator.orientation`), weighted by 1/sigma_r as a position row's is by 1/sigma, so both are in
units of their own standard uncertainty. Joint
errors beyond the lines (:mod:`kinematics.joint_errors`) enter as ``q + R · c``: per-row regressors ``R``
(m, T), each acting on one joint, with coefficients ``c`` fitted with the lines.

A row whose moved joint was not read (a sweep jogged by hand, or positions-only data) carries that
joint's value as a nuisance parameter. It is eliminated in closed form (variable projection): for given
lines the best angle (or stroke) of each such row is computed exactly, and the Jacobian is projected
onto the complement of the row's nuisance direction (Kaufman), which also gives the exact Schur
complement for the covariance.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from identify.estimator.geometry import cross, perpendicular_basis, rotation_about_axis, turned
from identify.estimator.linalg import project_out
from identify.estimator.orientation import (
    inverse_left_jacobians,
    left_jacobians,
    matrices_from_rotvecs,
    mean_rotation,
    rotation_residuals,
)
from identify.estimator.sync import Retiming
from kinematics.dh import DHModel, frames_from_joints, points_from_joints

Array = NDArray[np.float64]


@dataclass(frozen=True)
class AxisLines:
    """Joint axes at the home pose: ``points`` (n, 3) on each line, unit ``directions`` (n, 3), the
    ``home`` readings (n,) and the TP there, ``tp_home`` (3,); with several tracked points the others'
    positions at home, ``extra_tps`` (k - 1, 3); ``orientations`` (k, 3, 3): each tracked point's target frame at
    home in the tracker frame, NaN for points whose orientation was not measured (None: none was). Prismatic points
    are meaningless."""

    joint_types: str
    points: Array
    directions: Array
    home: Array
    tp_home: Array
    extra_tps: Array = field(default_factory=lambda: np.zeros((0, 3)))
    orientations: Array | None = None

    @property
    def tps(self) -> Array:
        """Every tracked point at home (k, 3), the first being ``tp_home``."""
        return np.vstack([self.tp_home, self.extra_tps])

    @property
    def n_line_parameters(self) -> int:
        """4 per revolute joint, 2 per prismatic."""
        return sum(4 if t == "R" else 2 for t in self.joint_types)

    @property
    def n_parameters(self) -> int:
        """Size of the minimal parameter vector: the lines', then 3 per tracked point."""
        return self.n_line_parameters + 3 * len(self.tps)


def lines_from_model(model: DHModel, home: Array) -> AxisLines:
    """The axis lines of a DH ``model`` at joint readings ``home`` (n,), tracker frame."""
    home = np.asarray(home, dtype=float)
    frames = frames_from_joints(model, home[None, :])[0]
    tp = points_from_joints(model, home[None, :])[0]
    return AxisLines(model.joint_types, frames[:-1, :3, 3].copy(), frames[:-1, :3, 2].copy(), home.copy(), tp)


def points_from_lines(lines: AxisLines, q: Array, tp_index: NDArray[np.int64] | None = None) -> Array:
    """Predicted TP (m, 3) at joint readings ``q`` (m, n); ``tp_index`` (m,): which tracked point (0-based
    row of ``lines.tps``; default the first)."""
    return _apply(lines, q, range(len(lines.joint_types)), _home_points(lines, len(q), tp_index))


def chain_rotations(lines: AxisLines, q: Array) -> Array:
    """The chain's rotation ``L(q)`` (m, 3, 3): the product of the revolute joints' turns from home to readings ``q``
    (m, n); a frame at home with rotation R is at ``L(q) R`` (prismatic joints only translate)."""
    out = np.tile(np.eye(3), (len(q), 1, 1))
    for i, t in enumerate(lines.joint_types):
        if t == "R":
            out = out @ rotation_about_axis(lines.directions[i], q[:, i] - lines.home[i])
    return out


def target_rotations(lines: AxisLines, q: Array, tp_index: NDArray[np.int64] | None = None) -> Array:
    """Predicted target-frame rotations (m, 3, 3), tracker frame, at readings ``q`` (m, n); NaN for a tracked point
    without an orientation. ``tp_index`` as in :func:`points_from_lines`."""
    if lines.orientations is None:
        return np.full((len(q), 3, 3), np.nan)
    home = lines.orientations[np.zeros(len(q), dtype=np.int64) if tp_index is None else tp_index]
    return chain_rotations(lines, q) @ home


def home_orientations(lines: AxisLines, q: Array, rotations: Array, tp_index: NDArray[np.int64]) -> Array:
    """Each tracked point's target frame at home (k, 3, 3) that best fits the measured ``rotations`` (m, 3, 3; NaN
    rows: positions only) at readings ``q`` (m, n): the chordal mean of ``L(q)ᵀ R`` over its rows; ``lines``'
    own orientation (or NaN) for a point without measured rotations."""
    count = len(lines.tps)
    out = np.full((count, 3, 3), np.nan) if lines.orientations is None else lines.orientations.copy()
    given = np.all(np.isfinite(rotations), axis=(1, 2))
    for p in range(count):
        rows = given & (tp_index == p)
        if np.any(rows):
            out[p] = mean_rotation(np.swapaxes(chain_rotations(lines, q[rows]), 1, 2) @ rotations[rows])
    return out


def _home_points(lines: AxisLines, m: int, tp_index: NDArray[np.int64] | None) -> Array:
    return np.tile(lines.tp_home, (m, 1)) if tp_index is None else lines.tps[tp_index]


def _apply(lines: AxisLines, q: Array, joints: range, x: Array) -> Array:
    """Points ``x`` (m, 3) moved by the given joints (applied from the last in ``joints`` to the first)."""
    for i in reversed(joints):
        delta = q[:, i] - lines.home[i]
        if lines.joint_types[i] == "R":
            x = turned(x, lines.points[i], lines.directions[i], delta)
        else:
            x = x + delta[:, None] * lines.directions[i]
    return x


def solve_unknown(lines: AxisLines, q: Array, points: Array, unknown: NDArray[np.int64],
                  tp_index: NDArray[np.int64] | None = None) -> Array:
    """``q`` with each row's unknown joint (0-based index in ``unknown``, -1 for none) set to the value
    that brings the predicted TP closest to the measured ``points`` (closed form; rad or m)."""
    q = q.copy()
    for j in np.unique(unknown[unknown >= 0]):
        rows = np.flatnonzero(unknown == j)
        qr = q[rows]
        qr[:, j] = lines.home[j]
        n = len(lines.joint_types)
        tip = _apply(lines, qr, range(j + 1, n), _home_points(lines, len(rows), None if tp_index is None
                                                               else tp_index[rows]))
        # the joints before j move rigidly: undo them on the measurement (A^-1 y = R_Aᵀ (y - A(0)))
        origin = _apply(lines, qr, range(j), np.zeros((len(rows), 3)))
        cols = [_apply(lines, qr, range(j), np.tile(e, (len(rows), 1))) - origin for e in np.eye(3)]
        rot_a = np.stack(cols, axis=2)
        target = np.einsum("kji,kj->ki", rot_a, points[rows] - origin)
        u = lines.directions[j]
        if lines.joint_types[j] == "R":
            v1 = tip - lines.points[j]
            v2 = target - lines.points[j]
            v1 -= np.outer(v1 @ u, u)
            v2 -= np.outer(v2 @ u, u)
            delta = np.arctan2(cross(v1, v2) @ u, np.einsum("ki,ki->k", v1, v2))
        else:
            delta = (target - tip) @ u
        q[rows, j] = lines.home[j] + delta
    return q


@dataclass(frozen=True)
class JointTerms:
    """Joint errors in the fit: ``regressors`` (m, T) per row, each column acting on joint ``joints[t]``
    (0-based), with coefficients ``coefs`` (T,): the joints stand at ``q + Σ_t regressors[:, t] · coefs[t]``."""

    regressors: Array
    joints: NDArray[np.int64]
    coefs: Array

    @classmethod
    def none(cls, m: int) -> JointTerms:
        return cls(np.zeros((m, 0)), np.zeros(0, dtype=np.int64), np.zeros(0))

    def __len__(self) -> int:
        return len(self.joints)

    def corrected(self, q: Array, coefs: Array | None = None) -> Array:
        """``q`` (m, n) plus the joint errors (unread values, NaN, stay NaN)."""
        if not len(self):
            return q
        coefs = self.coefs if coefs is None else coefs
        out = q.copy()
        for t, j in enumerate(self.joints):
            out[:, j] += self.regressors[:, t] * coefs[t]
        return out

    def subset(self, rows: NDArray[np.bool_] | NDArray[np.int64]) -> JointTerms:
        return JointTerms(self.regressors[rows], self.joints, self.coefs)


class LineProblem:
    """Weighted residuals and (projected) Jacobian of the lines model over its minimal parameters.

    ``unknown`` (m,): 0-based index of each row's unread joint, -1 where every reading is known;
    ``tp_index`` (m,): each row's tracked point (0-based row of ``start.tps``); ``terms``: joint errors
    fitted with the lines; ``timing``: the clock correction of streamed rows (:mod:`identify.estimator.sync`).
    ``rotations`` (m, 3, 3): the measured target-frame rotation of orientation rows (NaN rows: position rows); an
    orientation row's residual is its rotation's (rad, weighted by its ``weights`` entry, 1/sigma_r). A streamed
    orientation row moves with the clock correction as a position row does: a joint turning at speed dq_i/dt turns
    the frame by ``L_i u_i · dq_i/dt`` per second of shift (``L_i`` the joints before i, ``u_i`` its axis; a prismatic
    joint does not turn it), so its timing columns are those turns through ``J_l⁻¹`` of its residual. An orientation
    row has no unread joint: the right model would share the unread angle between a reading's position and orientation
    rows (one nuisance per reading, the orientation constraining the angle too); not implemented, so
    :func:`identify.estimator.measurements.orientation_rows` leaves such orientations out. Parameters are increments on
    ``start`` (and on ``terms.coefs``, ``timing.tau``), zero at the start: lines, then 3 per tracked point, then 3 per
    tracked point with orientation rows (a turn of its frame at home, a rotation vector in the tracker frame applied on
    the left), then one per joint-error coefficient, then the timing's (when free).
    """

    def __init__(self, start: AxisLines, q: Array, points: Array, weights: Array,
                 unknown: NDArray[np.int64] | None = None, tp_index: NDArray[np.int64] | None = None,
                 terms: JointTerms | None = None, timing: Retiming | None = None, rotations: Array | None = None):
        self.q, self.points, self.weights = q, points, weights
        self.unknown = np.full(len(q), -1) if unknown is None else np.asarray(unknown)
        self.has_unknown = bool(np.any(self.unknown >= 0))
        self.tp_index = None if tp_index is None or not np.any(tp_index) else np.asarray(tp_index)
        self.terms = JointTerms.none(len(q)) if terms is None else terms
        self.types = start.joint_types
        self.bases = [np.array(perpendicular_basis(d)) for d in start.directions]
        self.rotations = rotations
        self.oriented = (np.zeros(len(q), dtype=bool) if rotations is None
                         else np.all(np.isfinite(rotations), axis=(1, 2)))
        if np.any(self.oriented & (self.unknown >= 0)):
            raise ValueError("an orientation row cannot have an unread joint")
        tps = np.zeros(len(q), dtype=np.int64) if tp_index is None else np.asarray(tp_index)
        self.oriented_tps = [int(p) for p in np.unique(tps[self.oriented])]  # 0-based, with orientation parameters
        if self.oriented_tps and (start.orientations is None
                                  or not np.all(np.isfinite(start.orientations[self.oriented_tps]))):
            start = replace(start, orientations=home_orientations(start, q, rotations, tps))
        self.start = start
        self.n_lines = start.n_parameters + 3 * len(self.oriented_tps)
        self.timing = timing
        self.n_terms = self.n_lines + len(self.terms)  # index of the first timing parameter
        self.size = self.n_terms + (0 if timing is None else timing.size)

    def lines(self, x: Array) -> tuple[AxisLines, list[Array]]:
        pts, dirs, tangents, k = [], [], [], 0
        for i, t in enumerate(self.types):
            e = self.bases[i]
            v = self.start.directions[i] + x[k] * e[0] + x[k + 1] * e[1]
            length = np.linalg.norm(v)
            u = v / length
            tangents.append((e - np.outer(e @ u, u)) / length)  # d(direction)/d(tilt), (2, 3)
            dirs.append(u)
            if t == "R":
                pts.append(self.start.points[i] + x[k + 2] * e[0] + x[k + 3] * e[1])
                k += 4
            else:
                pts.append(self.start.points[i])
                k += 2
        tps = x[k:self.start.n_parameters].reshape(-1, 3) + self.start.tps
        orientations = self.start.orientations
        if self.oriented_tps:
            orientations = orientations.copy()
            turns = matrices_from_rotvecs(x[self.start.n_parameters:self.n_lines].reshape(-1, 3))
            orientations[self.oriented_tps] = turns @ orientations[self.oriented_tps]
        lines = AxisLines(self.types, np.array(pts), np.array(dirs), self.start.home, tps[0], tps[1:], orientations)
        return lines, tangents

    def coefs(self, x: Array) -> Array:
        """Joint-error coefficients at ``x``."""
        return self.terms.coefs + x[self.n_lines:self.n_terms]

    def tau(self, x: Array) -> Array | None:
        """The timing correction at ``x`` (None without streamed rows)."""
        if self.timing is None:
            return None
        return self.timing.tau + x[self.n_terms:] if self.timing.free else self.timing.tau

    def joints(self, lines: AxisLines, coefs: Array | None = None, tau: Array | None = None) -> Array:
        """Joint values at corrected times (streamed rows), with the joint errors applied and every unknown
        value at its best estimate."""
        q = self.q if self.timing is None else self.timing.joints(self.q, tau)
        q = self.terms.corrected(q, coefs)
        return solve_unknown(lines, q, self.points, self.unknown, self.tp_index) if self.has_unknown else q

    def residuals(self, x: Array) -> Array:
        lines, _ = self.lines(x)
        return self.residuals_at(lines, self.joints(lines, self.coefs(x), self.tau(x))).ravel()

    def residuals_at(self, lines: AxisLines, q: Array) -> Array:
        """Weighted residuals (m, 3) of every row, predicted minus measured, for ``lines`` at joint values ``q``."""
        res = points_from_lines(lines, q, self.tp_index) - self.points
        o = self.oriented
        if np.any(o):
            tps = None if self.tp_index is None else self.tp_index[o]
            res[o] = rotation_residuals(target_rotations(lines, q[o], tps), self.rotations[o])
        return res * self.weights[:, None]

    def jacobian_blocks(self, x: Array, q: Array | None = None, tp_index: NDArray[np.int64] | None = None,
                        regressors: Array | None = None) -> Array:
        """Jacobian of the (weighted) predictions at joint values ``q`` (default: the data's, with their
        tracked points and regressors), (m, 3, size), after the projection of the nuisance parameters."""
        lines, tangents = self.lines(x)
        data = q is None
        timed = data and self.timing is not None and self.timing.free
        if data:
            q, tp_index = self.joints(lines, self.coefs(x), self.tau(x)), self.tp_index
            regressors = self.terms.regressors
        elif regressors is None:
            regressors = np.zeros((len(q), len(self.terms)))
        m = len(q)
        streamed = self.timing.rows if timed else np.zeros(m, dtype=bool)
        if timed:
            dq = self.timing.derivatives(self.tau(x))  # (r, n, K), the streamed rows in order
            timing_moves = np.any(dq != 0.0, axis=(0, 2))
            dq_row = np.cumsum(streamed) - 1  # each streamed row's index in dq
        jac = np.zeros((m, 3, self.size))
        nuisance = np.zeros((m, 3))
        k = self.start.n_line_parameters
        oriented = self.oriented if data else np.zeros(m, dtype=bool)
        for chunk in _chunks(m):
            tps = None if tp_index is None else tp_index[chunk]
            lefts, outputs = self._line_columns(lines, tangents, q[chunk], tps, jac[chunk])
            turning = oriented[chunk]
            here = streamed[chunk]
            if timed:
                timing_columns = np.zeros((int(np.sum(here)), 3, self.size - self.n_terms))
                dq_here = dq[dq_row[chunk][here]]
            for i, t in enumerate(self.types):
                acting = np.flatnonzero(self.terms.joints == i)
                moves = timed and timing_moves[i]
                if (data and self.has_unknown) or len(acting) or moves:
                    if t == "R":  # dp/dq_i
                        column = np.einsum("kij,kj->ki", lefts[i],
                                           cross(lines.directions[i], outputs[i] - lines.points[i]))
                    else:
                        column = lefts[i] @ lines.directions[i]
                    if np.any(turning):  # an orientation row turns with a revolute joint, not with a prismatic one
                        column[turning] = lefts[i][turning] @ lines.directions[i] if t == "R" else 0.0
                    if data:
                        rows = self.unknown[chunk] == i
                        nuisance[chunk][rows] = column[rows]
                    for c in acting:
                        jac[chunk, :, self.n_lines + c] = column * regressors[chunk, c, None]
                    if moves:
                        timing_columns += column[here, :, None] * dq_here[:, i, None, :]
            if timed:
                jac[chunk][here, :, self.n_terms:] += timing_columns
            if tps is None:
                jac[chunk, :, k:k + 3] = lefts[-1]
            else:
                for p in range(len(lines.tps)):
                    rows = np.flatnonzero(tps == p) + chunk.start
                    jac[rows, :, k + 3 * p:k + 3 * p + 3] = lefts[-1][rows - chunk.start]
            if np.any(turning):
                self._orientation_columns(lines, tangents, q[chunk], tps, lefts, turning, jac[chunk], chunk.start, x)
        if data:
            if np.any(self.weights != 1.0):
                jac *= self.weights[:, None, None]
            if self.has_unknown:
                rows = np.flatnonzero(self.unknown >= 0)
                project_out(jac, rows, nuisance[rows] * self.weights[rows, None])
        return jac

    def jacobian(self, x: Array) -> Array:
        return self.jacobian_blocks(x).reshape(-1, self.size)

    def _orientation_columns(self, lines: AxisLines, tangents: list[Array], q: Array,
                             tp_index: NDArray[np.int64] | None, lefts: Array, turning: NDArray[np.bool_], jac: Array,
                             offset: int, x: Array) -> None:
        """In place, for the orientation rows ``turning`` of a chunk of rows at joint values ``q`` (its first row
        ``offset``; parameters ``x``): the columns of the lines, tracked points and home orientations in ``jac``
        (chunk, 3, size), unweighted, with ``lefts`` from :meth:`_line_columns`. A tilt du of revolute joint i's
        direction turns the frame by ``L_i J_l(δ u) δ du`` (``L_i`` the joints before i, δ its angle from home);
        shifts of a line, the tracked points' positions and prismatic joints do not turn it; the turn ω of the
        frame at home turns it by ``L(q) J_l(ω) dω``. Every column is then mapped through ``J_l⁻¹(r)`` of the row's
        residual r (exact for any r)."""
        rows = np.flatnonzero(turning)
        block = np.zeros((len(rows), 3, self.size))
        first = np.cumsum([0] + [4 if t == "R" else 2 for t in self.types])
        for i, t in enumerate(self.types):
            if t != "R":
                continue
            delta = q[rows, i] - lines.home[i]
            spin = left_jacobians(delta[:, None] * lines.directions[i]) * delta[:, None, None]
            block[:, :, first[i]:first[i] + 2] = lefts[i][rows] @ spin @ tangents[i].T
        tps = np.zeros(len(rows), dtype=np.int64) if tp_index is None else tp_index[rows]
        start = self.start.n_parameters
        turns = left_jacobians(x[start:self.n_lines].reshape(-1, 3))
        for slot, p in enumerate(self.oriented_tps):
            mine = tps == p
            block[mine, :, start + 3 * slot:start + 3 * slot + 3] = lefts[-1][rows[mine]] @ turns[slot]
        # the joint-value columns (terms, timing) of these rows were set in the loop: keep them
        block[:, :, self.n_lines:] = jac[rows, :, self.n_lines:]
        predicted = lefts[-1][rows] @ lines.orientations[tps]
        measured = self.rotations[rows + offset]
        jac[rows] = inverse_left_jacobians(rotation_residuals(predicted, measured)) @ block

    def _line_columns(self, lines: AxisLines, tangents: list[Array], q: Array, tp_index: NDArray[np.int64] | None,
                      jac: Array) -> tuple[Array, Array]:
        """In place, for rows at joint values ``q``: the lines' columns of ``jac`` (m, 3, size), unweighted; returns
        the rotations (n + 1, m, 3, 3) of T_1 … T_i, i = 0 … n, and the points (n, m, 3) after T_i … T_n."""
        n, m = len(self.types), len(q)
        inputs, rots, outputs = np.empty((n, m, 3)), np.empty((n, m, 3, 3)), np.empty((n, m, 3))
        lefts = np.empty((n + 1, m, 3, 3))
        x = _home_points(lines, m, tp_index)
        for i in reversed(range(n)):  # the chain of :func:`_apply`, with its rotations kept
            delta = q[:, i] - lines.home[i]
            inputs[i] = x
            if self.types[i] == "R":
                rots[i] = rotation_about_axis(lines.directions[i], delta)
                outputs[i] = lines.points[i] + np.einsum("kij,kj->ki", rots[i], x - lines.points[i])
            else:
                rots[i] = np.eye(3)
                outputs[i] = x + delta[:, None] * lines.directions[i]
            x = outputs[i]
        lefts[0] = np.eye(3)
        for i in range(n):
            np.matmul(lefts[i], rots[i], out=lefts[i + 1])
        first = np.cumsum([0] + [4 if t == "R" else 2 for t in self.types])  # each joint's first column
        revolute = [i for i, t in enumerate(self.types) if t == "R"]
        rev = slice(None) if len(revolute) == n else revolute  # (a view when every joint is revolute)
        if revolute:
            # moving joint i's line rigidly by (eps_w, eps_v) moves the TP by
            # L [(-[w]x + R [u]x) eps_w + (I - R) eps_v]   (L = rotation of the joints before i), for every
            # revolute joint at once; tilting the direction turns the line about its point c: eps_v = c x eps_w;
            # as matrices per row: L (R A - B), the columns of A and B (3 x 4) for the two tilts and two shifts
            r = len(revolute)
            eps = cross(lines.directions[revolute][:, None, :], np.array([tangents[i] for i in revolute]))  # (r, 2, 3)
            ce = cross(eps, lines.points[revolute][:, None, :])  # (r, 2, 3)
            a = np.empty((r, m, 3, 4))
            b = np.empty_like(a)
            for j in range(2):
                cross(inputs[rev], eps[:, None, j], out=a[..., j])
                a[..., j] += ce[:, None, j]
                cross(outputs[rev], eps[:, None, j], out=b[..., j])
                b[..., j] += ce[:, None, j]
            a[..., 2:] = b[..., 2:] = -np.array([self.bases[i] for i in revolute]).swapaxes(1, 2)[:, None]
            moved = np.matmul(rots[rev], a, out=a)
            moved -= b
            columns = jac[:, :, :4 * n].reshape(m, 3, n, 4).transpose(2, 0, 1, 3) if r == n else None
            if columns is not None and np.may_share_memory(columns, jac):  # all revolute: joint i's 4i … 4i + 3
                np.matmul(lefts[:-1], moved, out=columns)
            else:
                moved = np.matmul(lefts[:-1][rev], moved, out=b)  # (r, m, 3, 4)
                for index, i in enumerate(revolute):
                    jac[:, :, first[i]:first[i] + 4] = moved[index]
        for i, t in enumerate(self.types):
            if t == "P":
                jac[:, :, first[i]:first[i] + 2] = (lefts[i] @ tangents[i].T) * (q[:, i] - lines.home[i])[:, None, None]
        return lefts, outputs

ROWS_PER_CHUNK = 16384  # rows whose Jacobian blocks are formed at once (bounds the temporaries of large sessions)


def _chunks(m: int) -> list[slice]:
    """Row slices of at most :data:`ROWS_PER_CHUNK` covering ``m`` rows."""
    return [slice(a, min(a + ROWS_PER_CHUNK, m)) for a in range(0, max(m, 1), ROWS_PER_CHUNK)]


STOP_SIGMAS = 1e-3  # a least-squares fit stops when its step moves the parameters by less than this many σ


def converged_tolerance(residuals: int) -> float:
    """``ftol`` (also ``xtol``, ``gtol``) of a least-squares fit of ``residuals`` noise-level residuals: a step
    that lowers the cost (about ``residuals`` noise variances at the optimum) by less than its relative share
    (STOP_SIGMAS²/residuals) moves the parameters by less than STOP_SIGMAS standard deviations; at most 1e-10."""
    return min(1e-10, STOP_SIGMAS**2 / max(residuals, 1))


class LeastSquares(NamedTuple):
    """A least-squares fit: ``lines``, joint values ``q`` (m, n) with joint errors applied and unknown
    values solved, weighted ``residuals`` (m, 3) predicted minus measured, the joint ``terms`` fitted and the
    streamed rows' ``timing`` (None without)."""

    lines: AxisLines
    q: Array
    residuals: Array
    terms: JointTerms
    timing: Retiming | None = None
