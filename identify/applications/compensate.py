"""Compensation: joint values that bring the real arm (its identified model) to given targets, and the program
filter that turns them into poses for a controller that only knows its nominal (or factory) model.

Pure numpy. The inverse kinematics is a damped Newton (Levenberg-Marquardt) iteration run on every target at
once with the analytic Jacobian of :meth:`identify.applications.calibrated.CalibratedModel.axes`: a point target fixes
the TP's position (3 equations), a pose target also the tool's orientation (6). With more joints than equations
each step is the least-norm one, so the solution stays on the seed's branch, near the seed. Joints stay within
their limits (a joint pushed past one is held there and the others solve the rest).

Per target, ``status`` is one of :data:`STATUSES`: ``ok`` (reached), ``singular`` (the Jacobian's smallest
singular value at the solution is below ``singular_tol``: a tiny target change needs a large motion; reached, or
missed by less than :data:`SINGULAR_REACH`: see its residual), ``limit`` (not reached, with a joint at its limit
that would have to go beyond it) or ``unreachable`` (not reached: outside the workspace or on no branch near the
seed). Frames: the model's frame
(tracker, or frame 0 for a model whose ``base`` is the identity). Units: m, rad.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from identify.applications.calibrated import CalibratedModel

Array = NDArray[np.float64]

STATUSES = ("ok", "singular", "limit", "unreachable")
POSITION_TOL = 1e-12  # m: Newton stops here (rounding level for metre-sized arms)
ROTATION_TOL = 1e-12  # rad
OK_POSITION = 1e-9  # m: a target counts as reached within this (and the orientation within OK_ROTATION)
OK_ROTATION = 1e-9  # rad
SINGULAR_TOL = 1e-3  # m/rad or rad/rad: smallest singular value of the scaled Jacobian below which a target is singular
SINGULAR_REACH = 1e-3  # m: a target missed by less than this at a singularity is "singular", not "unreachable"
ROTATION_LENGTH = 0.1  # m per rad: weight of orientation errors against position errors (a 100 mm tool)
MAX_ITERATIONS = 100


@dataclass(frozen=True)
class Solution:
    """Inverse kinematics of k targets: ``q`` (k, n); ``status`` (k,) from :data:`STATUSES`; remaining
    ``position_error`` (k,) m and ``rotation_error`` (k,) rad (NaN for point targets); ``sigma_min`` (k,) the
    Jacobian's smallest singular value at ``q``; ``seed_change`` (k,) largest |q - seed| (rad or m)."""

    q: Array
    status: NDArray[np.str_]
    position_error: Array
    rotation_error: Array
    sigma_min: Array
    seed_change: Array

    @property
    def reached(self) -> NDArray[np.bool_]:
        """Targets reached within :data:`OK_POSITION` and :data:`OK_ROTATION` (``ok``, or ``singular`` ones that
        converged all the same)."""
        rot_ok = np.isnan(self.rotation_error) | (self.rotation_error <= OK_ROTATION)
        return (self.position_error <= OK_POSITION) & rot_ok


def pose_matrices(position: Array, rotvec: Array | None = None) -> Array:
    """4x4 poses (k, 4, 4) from positions (k, 3), m, and rotation vectors (k, 3), rad (UR axis-angle)."""
    position = np.atleast_2d(np.asarray(position, dtype=float))
    out = np.tile(np.eye(4), (len(position), 1, 1))
    out[:, :3, 3] = position
    if rotvec is not None:
        out[:, :3, :3] = Rotation.from_rotvec(np.atleast_2d(np.asarray(rotvec, dtype=float))).as_matrix()
    return out


def rotvecs(poses: Array) -> Array:
    """Rotation vectors (k, 3), rad, of the rotations of ``poses`` (k, 4, 4) or (k, 3, 3)."""
    return Rotation.from_matrix(np.asarray(poses)[:, :3, :3]).as_rotvec()


def _evaluate(model: CalibratedModel, q: Array, points: Array, rotations: Array | None, tool: Array,
              tool_rotation: Array) -> tuple[Array, Array, Array, Array]:
    """Weighted residuals (k, m), Jacobian (k, m, n) with respect to the readings, position errors (k,) m,
    rotation errors (k,) rad."""
    z, o, flange = model.axes(q)
    coupling = model.reading_jacobian()
    p = flange[:, :3, :3] @ tool + flange[:, :3, 3]
    rev = np.array([t == "R" for t in model.model.joint_types])
    lever = p[:, None, :] - o
    jp = np.where(rev[None, :, None], np.cross(z, lever), z)  # (k, n, 3)
    r_pos = p - points
    if rotations is None:
        return r_pos, np.swapaxes(jp, 1, 2) @ coupling, np.linalg.norm(r_pos, axis=1), np.full(len(q), np.nan)
    jr = np.where(rev[None, :, None], z, 0.0)
    rot = flange[:, :3, :3] @ tool_rotation
    r_rot = Rotation.from_matrix(rot @ np.swapaxes(rotations, 1, 2)).as_rotvec()  # world-frame orientation error
    res = np.hstack([r_pos, ROTATION_LENGTH * r_rot])
    jac = np.concatenate([np.swapaxes(jp, 1, 2), ROTATION_LENGTH * np.swapaxes(jr, 1, 2)], axis=1) @ coupling
    return res, jac, np.linalg.norm(r_pos, axis=1), np.linalg.norm(r_rot, axis=1)


def _step(jac: Array, res: Array, lam: Array) -> Array:
    """Damped Gauss-Newton steps (k, n): least squares with more equations than joints, least norm with fewer."""
    _, m, n = jac.shape
    jt = np.swapaxes(jac, 1, 2)
    if m >= n:
        a = jt @ jac
        scale = np.maximum(np.trace(a, axis1=1, axis2=2) / n, 1e-30)
        a = a + (lam * scale)[:, None, None] * np.eye(n)
        return -np.linalg.solve(a, (jt @ res[:, :, None]))[:, :, 0]
    a = jac @ jt
    scale = np.maximum(np.trace(a, axis1=1, axis2=2) / m, 1e-30)
    a = a + (lam * scale)[:, None, None] * np.eye(m)
    return -(jt @ np.linalg.solve(a, res[:, :, None]))[:, :, 0]


def solve_ik(model: CalibratedModel, points: Array, seeds: Array, limits: Array | None = None,
             rotations: Array | None = None, tool: Array | None = None, tool_rotation: Array | None = None,
             singular_tol: float = SINGULAR_TOL, max_iterations: int = MAX_ITERATIONS) -> Solution:
    """Joint values (from ``seeds`` (k, n)) at which ``model`` puts ``tool`` (3,) in the flange frame (default
    the model's TP) at ``points`` (k, 3) and, with ``rotations`` (k, 3, 3), the flange rotation times
    ``tool_rotation`` (3, 3) at those rotations; model frame. ``limits`` (n, 2) rad / m, or None."""
    points = np.atleast_2d(np.asarray(points, dtype=float))
    seeds = np.atleast_2d(np.asarray(seeds, dtype=float))
    k, n = seeds.shape
    if points.shape != (k, 3):
        raise ValueError(f"{k} seeds but targets of shape {points.shape}")
    tool = model.tool() if tool is None else np.asarray(tool, dtype=float)
    tool_rotation = np.eye(3) if tool_rotation is None else np.asarray(tool_rotation, dtype=float)
    lo, hi = (np.full(n, -np.inf), np.full(n, np.inf)) if limits is None else np.asarray(limits, dtype=float).T
    q = np.clip(seeds, lo, hi)
    res, jac, pos, rot = _evaluate(model, q, points, rotations, tool, tool_rotation)
    cost = np.sum(res**2, axis=1)
    lam = np.full(k, 1e-6)
    for _ in range(max_iterations):
        done = (pos <= POSITION_TOL) & ((rot <= ROTATION_TOL) | np.isnan(rot))
        idx = np.flatnonzero(~done & (lam < 1e12))
        if not len(idx):
            break
        ja, ra = jac[idx], res[idx]
        step = _step(ja, ra, lam[idx])
        trial = q[idx] + step
        pinned = (trial < lo) | (trial > hi)  # joints that would leave their range: held, the others solve
        if pinned.any():
            rows = np.flatnonzero(pinned.any(axis=1))
            held = ja[rows] * ~pinned[rows][:, None, :]
            trial[rows] = q[idx[rows]] + _step(held, ra[rows], lam[idx[rows]]) * ~pinned[rows]
            trial = np.clip(trial, lo, hi)
        r2, j2, p2, o2 = _evaluate(model, trial, points[idx], None if rotations is None else rotations[idx], tool,
                                   tool_rotation)
        c2 = np.sum(r2**2, axis=1)
        better = c2 < cost[idx]
        good = idx[better]
        q[good], res[good], jac[good], pos[good], rot[good], cost[good] = (trial[better], r2[better], j2[better],
                                                                          p2[better], o2[better], c2[better])
        lam[good] = np.maximum(lam[good] * 0.1, 1e-12)
        lam[idx[~better]] *= 10.0
    sigma = np.linalg.svd(jac, compute_uv=False).min(axis=1)
    reached = (pos <= OK_POSITION) & ((rot <= OK_ROTATION) | np.isnan(rot))
    descent = -np.einsum("kmn,km->kn", jac, res)  # where each joint would go to reduce the miss
    pushed = np.any(((q <= lo + 1e-12) & (descent < 0)) | ((q >= hi - 1e-12) & (descent > 0)), axis=1)
    near = np.linalg.norm(res, axis=1) < SINGULAR_REACH
    status = np.where(reached, np.where(sigma < singular_tol, "singular", "ok"),
                      np.where(pushed, "limit", np.where(near & (sigma < singular_tol), "singular", "unreachable")))
    return Solution(q, status.astype(str), pos, rot, sigma, np.max(np.abs(q - seeds), axis=1))


def why_not(status: str, reached: bool) -> str:
    """One line on a target's ``status``: why it was not reached, or what to watch for a reached singular one."""
    if reached:
        return "near a singularity: a small target change needs a large joint motion" if status == "singular" else ""
    return {"limit": "a joint would have to go beyond its limit",
            "singular": "missed at a singularity (the arm's reach is folded here)"}.get(
        status, "outside the calibrated arm's workspace or on no branch near the seed")


@dataclass(frozen=True)
class Compensation:
    """Joint values that reach the targets with the identified model (``solution``), the nominal model's own
    solution they were seeded with (``nominal``, None without a nominal model) and the expected 3D error of
    each reached point from the identified model's uncertainty and model error (``expected`` (k,), m)."""

    solution: Solution
    nominal: Solution | None
    expected: Array


def compensate(identified: CalibratedModel, points: Array, seeds: Array, limits: Array | None = None,
               rotations: Array | None = None, tool: Array | None = None, tool_rotation: Array | None = None,
               nominal: CalibratedModel | None = None, frame: str = "tracker") -> Compensation:
    """Solve the targets (``points`` (k, 3), optional ``rotations`` (k, 3, 3)) with ``identified``, each seeded by
    ``nominal``'s solution from ``seeds`` where it has one (else by the seed). ``seeds`` and the solution are the
    controller's readings (the DH values through the result's coupling for the nominal model; ``limits`` bound
    the DH values). Targets are in ``identified``'s frame
    (and in ``nominal``'s: give both models the same base). ``frame`` names the frame the expected errors are
    quoted in: ``tracker`` (the TP as the tracker sees it) or ``base`` (the robot's frame 0: the base's own
    uncertainty left out). ``tool`` (3,) in the flange frame, taken as exact; default the identified TP."""
    start = np.atleast_2d(np.asarray(seeds, dtype=float))
    nominal_solution = None
    if nominal is not None:  # the nominal model works in DH joint values, the identified one in readings
        nominal_tool = identified.tool() if tool is None else tool
        nominal_solution = solve_ik(nominal, points, identified.dh_values(start), limits, rotations, nominal_tool,
                                    tool_rotation)
        start = np.where(nominal_solution.reached[:, None], identified.readings(nominal_solution.q), start)
    coupled = not np.array_equal(identified.reading_jacobian(), np.eye(identified.n_joints))
    solution = solve_ik(identified, points, start, None if coupled else limits, rotations, tool, tool_rotation)
    if coupled and limits is not None:  # the limits bound DH joint values: a box in readings they are not
        dh = identified.dh_values(solution.q)
        beyond = np.any((dh < np.asarray(limits)[:, 0]) | (dh > np.asarray(limits)[:, 1]), axis=1)
        solution = Solution(solution.q, np.where(beyond, "limit", solution.status).astype(str),
                            solution.position_error, solution.rotation_error, solution.sigma_min, solution.seed_change)
    expected = identified.expected_errors(solution.q, tool, frame)
    expected[~solution.reached] = np.nan
    # the seed change is counted from the caller's seeds, not from the nominal solution
    solution = Solution(solution.q, solution.status, solution.position_error, solution.rotation_error,
                        solution.sigma_min, np.max(np.abs(solution.q - np.atleast_2d(seeds)), axis=1))
    return Compensation(solution, nominal_solution, expected)


def controller_poses(nominal_in_base: CalibratedModel, q: Array, tcp: Array, tcp_rotation: Array | None = None
                     ) -> Array:
    """The poses (k, 4, 4), robot base frame, a controller whose model is ``nominal_in_base`` (base = identity)
    reports for joint values ``q`` with the tool centre point ``tcp`` (3,) m and ``tcp_rotation`` (3, 3) in its
    flange frame: the Cartesian targets that make it move to ``q`` (the program filter)."""
    flange = nominal_in_base.flanges(q)
    rot = np.eye(3) if tcp_rotation is None else np.asarray(tcp_rotation, dtype=float)
    out = np.tile(np.eye(4), (len(flange), 1, 1))
    out[:, :3, :3] = flange[:, :3, :3] @ rot
    out[:, :3, 3] = flange[:, :3, :3] @ np.asarray(tcp, dtype=float) + flange[:, :3, 3]
    return out


def ur_pose(pose: Array) -> str:
    """A 4x4 pose (m) as UR's ``p[x, y, z, rx, ry, rz]`` (metres, axis-angle rad), 12 significant digits."""
    values = [*np.asarray(pose)[:3, 3], *rotvecs(np.asarray(pose)[None])[0]]
    return "p[" + ", ".join(f"{v:.12g}" for v in values) + "]"


def parse_ur_pose(text: str) -> Array:
    """The 4x4 pose of ``p[x, y, z, rx, ry, rz]``; ValueError (one line) for anything else."""
    body = text.strip()
    if not (body.startswith("p[") and body.endswith("]")):
        raise ValueError(f"not a UR pose p[x, y, z, rx, ry, rz]: {text!r}")
    try:
        values = [float(v) for v in body[2:-1].split(",")]
    except ValueError:
        raise ValueError(f"not a UR pose p[x, y, z, rx, ry, rz]: {text!r}") from None
    if len(values) != 6 or not all(np.isfinite(values)):
        raise ValueError(f"a UR pose has six finite numbers: {text!r}")
    return pose_matrices(np.array(values[:3]), np.array(values[3:]))[0]
