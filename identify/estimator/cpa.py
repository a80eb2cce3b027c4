"""The paper's geometric step (circle point analysis): joint axes from sweeps, then DH frames.

Per revolute sweep a circle is fitted to the TP positions; its normal through its centre is the
joint's axis, oriented so that increasing joint readings turn counter-clockwise about it. Per
prismatic sweep a line is fitted; its direction is the joint's axis (the line's position is free).
DH frames follow from consecutive axes at the home pose via their common normals, with the
conventions of :func:`dh_from_axes`. All positions are in the tracker frame, metres.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from common.errors import InputError
from identify.estimator.geometry import (
    Circle,
    angles_on_circle,
    circle_from_points,
    circle_residuals,
    common_normal,
    cross,
    line_from_points,
    perpendicular_basis,
    rotation_about_axis,
    unit,
)
from identify.estimator.measurements import Measurements
from kinematics.dh import DHModel, transform_from_dh

Array = NDArray[np.float64]

DEFAULT_PARALLEL_TOL = 0.01  # rad: consecutive axes closer than this are treated as parallel
class ReadingScaleError(InputError):
    """A sweep's TP turns by another angle than its joint readings say (readings in degrees, the wrong column):
    the data are wrong whatever model the fit starts from."""


MIN_ARC = np.radians(2.0)  # rad: shortest arc that can define an axis
OUTLIER_FACTOR = 6.0  # a circle residual beyond this many robust sigmas triggers a robust refit
MIN_CHORD = 5e-4  # m: a TP moving less than this in a sweep sits on the joint's axis


@dataclass(frozen=True)
class JointAxis:
    """A joint axis at the home pose, tracker frame.

    ``point`` lies on the axis (for a prismatic joint only the direction is meaningful); ``radius``
    is the TP's distance from a revolute axis (NaN for prismatic); ``rms`` the fit residual (m);
    ``travel`` the swept arc (rad) or stroke (m); ``samples`` the points used.
    """

    joint: int
    kind: str
    point: Array
    direction: Array
    radius: float
    rms: float
    travel: float
    samples: int
    sweep: int
    tp_home: Array | None


@dataclass(frozen=True)
class GeometricResult:
    """Outcome of the geometric step: per-joint axes, home pose (rad/m), TP at home, DH model."""

    axes: list[JointAxis]
    home: Array
    tp_home: Array
    model: DHModel
    noise: float


def home_from_measurements(meas: Measurements) -> Array:
    """Home reading of every joint: the median of its readings while other joints were swept.

    A joint that is never held still (a one-joint robot) takes the median of its own readings.
    """
    home = np.empty(meas.n_joints)
    for j in range(meas.n_joints):
        held = (meas.joint > 0) & (meas.joint != j + 1)
        values = meas.q[held, j] if np.any(held) else meas.q[:, j]
        values = values[np.isfinite(values)]
        home[j] = np.median(values) if len(values) else 0.0
    return home


def axis_from_sweep(
    points: Array, moved: Array, kind: str, joint: int, sweep: int, home: float, robust_scale: float | None = None
) -> JointAxis:
    """Fit one joint's axis to the TP positions (m, 3) of a sweep; ``moved`` = the joint's readings.

    ``moved`` may be all NaN (joint jogged by hand): the rows are then taken as increasing readings.
    Raises InputError for a TP on the axis, an arc too short, or readings in the wrong unit.
    """
    chord = float(np.max(np.linalg.norm(points - points.mean(axis=0), axis=1))) * 2.0
    if chord < MIN_CHORD:
        what = "the joint's axis" if kind == "R" else "a fixed point"
        raise InputError(
            f"joint {joint}: the TP moved only {chord * 1e3:.3f} mm in sweep {sweep}; it sits on {what}"
        )
    have_q = np.all(np.isfinite(moved))
    order = np.argsort(moved, kind="stable") if have_q else np.arange(len(points))
    if kind == "P":
        line = line_from_points(points)
        along = (points - line.point) @ line.direction
        reference = moved if have_q else np.arange(len(points), dtype=float)
        direction = line.direction if np.corrcoef(along, reference)[0, 1] >= 0 else -line.direction
        tp_home = None
        if have_q:
            tp_home = np.mean(points + np.outer(home - moved, direction), axis=0)
        return JointAxis(joint, kind, line.point, direction, np.nan, line.rms, float(np.ptp(along)),
                         len(points), sweep, tp_home)
    circle = circle_from_points(points, robust_scale)
    if circle.radius < 3.0 * circle.rms:
        raise InputError(f"joint {joint}: sweep {sweep} is not a circle (radius {circle.radius * 1e3:.3f} mm); "
                         "is the TP on the joint's axis?")
    angles = angles_on_circle(points[order], circle, moved[order] if have_q else None)
    span = float(np.ptp(angles))
    sagitta = circle.radius * (1.0 - np.cos(min(span, np.pi) / 2.0))
    # the arc's sagitta must stand out of the noise of its mean over the sweep's samples
    sagitta_noise = circle.rms / np.sqrt(len(points))
    if span < MIN_ARC or sagitta < 3.0 * sagitta_noise:
        raise InputError(
            f"joint {joint}: sweep {sweep} covers {np.degrees(span):.2f} deg, too short an arc to define an axis "
            f"(sagitta {sagitta * 1e3:.3f} mm vs its noise {sagitta_noise * 1e3:.3f} mm)"
        )
    reference = moved[order] if have_q else np.arange(len(points), dtype=float)
    slope = np.polyfit(reference, angles, 1)[0] if np.ptp(reference) > 0 else 1.0
    normal = circle.normal if slope >= 0 else -circle.normal
    tp_home = None
    if have_q:
        if not 0.5 < abs(slope) < 2.0:
            hint = " Are they in degrees? The CSV contract uses radians." if 40 < 1 / abs(slope) < 80 else ""
            raise ReadingScaleError(f"joint {joint}: the TP turns {abs(slope):.3g} rad per unit of joint reading in "
                             f"sweep {sweep}, expected 1.{hint}")
        turn = home - moved
        rel = points - circle.center
        rotated = np.einsum("kij,kj->ki", rotation_about_axis(normal, turn), rel)
        tp_home = circle.center + rotated.mean(axis=0)
    return JointAxis(joint, kind, circle.center, normal, circle.radius, circle.rms, span, len(points), sweep,
                     tp_home)


def _line_anchors(types: str, points: list[Array], dirs: list[Array], tp_home: Array, tol: float) -> list[Array]:
    """Place prismatic axes (free in position) so each meets the next axis where that axis's frame origin
    will be: a_i = 0 for the prismatic joint and d = 0 for the joint after it (tip first)."""
    n = len(types)
    points = [p.copy() for p in points]

    def anchor_on(k: int) -> Array:
        if k == n:
            return tp_home
        if types[k] == "P":
            return points[k]
        if k + 1 < n:
            cn = common_normal(points[k], dirs[k], points[k + 1], dirs[k + 1], tol)
            if not cn.parallel:
                return cn.foot_1
        return points[k] + ((tp_home - points[k]) @ dirs[k]) * dirs[k]

    for i in reversed(range(n)):
        if types[i] == "P":
            points[i] = anchor_on(i + 1)
    return points


SIGN_BY_ALPHA = 0.5  # |sin alpha| above which (axes 30 deg or more apart) alpha's sign fixes x_i; below it, a's


def _oriented_normal(x: Array, ref: DHModel | None, i: int, a: float, alpha: float) -> Array:
    """Pick the sign of x_i: match the reference model's sign of a_i (or alpha_i). Without one, a fixed rule that
    noise cannot flip on real arms, whose links are either clearly twisted or nearly parallel: alpha_i in
    [0, pi] for twisted links (|sin alpha_i| > SIGN_BY_ALPHA), a_i >= 0 for nearly parallel ones."""
    if ref is None:
        if abs(np.sin(alpha)) > SIGN_BY_ALPHA:
            return x if np.sin(alpha) >= 0 else -x
        return x if a >= -1e-12 else -x
    if abs(ref.a[i]) > 1e-6:
        return x if np.sign(a) == np.sign(ref.a[i]) or abs(a) < 1e-12 else -x
    if abs(np.sin(ref.alpha[i])) > 1e-6:
        return x if np.sign(np.sin(alpha)) == np.sign(np.sin(ref.alpha[i])) else -x
    return x


def dh_from_axes(
    types: str,
    points: list[Array],
    dirs: list[Array],
    home: Array,
    tp_home: Array,
    conventional: Array,
    parallel_tol: float = DEFAULT_PARALLEL_TOL,
    reference: DHModel | None = None,
    force_parallel: Collection[int] = (),
) -> DHModel:
    """DH model whose axes at the ``home`` pose are the given lines (tracker frame).

    Conventions (``conventional`` is an (n, 4) table theta, d, a, alpha: the nominal DH or zeros):
    frame 0 takes theta_1 and d_1 from it (the base absorbs the rest); the last frame n is placed by
    the last link's conventional theta, d, a, alpha (the tool carries the TP); for axes parallel within
    ``parallel_tol`` the common normal passes where d_i takes its conventional value; a prismatic axis
    meets the next axis (a_i = 0). Signs of x_i follow ``reference`` when given, else
    :func:`_oriented_normal`'s fixed rule.
    Links in ``force_parallel`` (1-based) are treated as parallel whatever their measured angle (their
    misalignment is within its uncertainty).
    """
    n = len(types)
    rev = np.array([t == "R" for t in types])
    dirs = [unit(u) for u in dirs]
    points = _line_anchors(types, points, dirs, tp_home, parallel_tol)
    origins: list[Array | None] = [None] * n
    xs: list[Array | None] = [None] * n
    feet0 = None
    for i in range(1, n):  # frame i from axes z_{i-1}, z_i
        prev_offset = conventional[i - 1, 1] + (0.0 if rev[i - 1] else home[i - 1])
        if i == 1:
            anchor = points[0] + ((points[1] - points[0]) @ dirs[0]) * dirs[0]
        else:
            anchor = origins[i - 1] + prev_offset * dirs[i - 1]
        # a prismatic axis was placed to meet the next one: their common normal is exact, never a convention
        tol = 1e-12 if types[i - 1] == "P" else (np.pi / 2 if i in force_parallel else parallel_tol)
        cn = common_normal(points[i - 1], dirs[i - 1], points[i], dirs[i], tol, anchor)
        gap = cn.foot_2 - cn.foot_1
        gap -= (gap @ dirs[i - 1]) * dirs[i - 1]
        normal = cross(dirs[i - 1], dirs[i])
        if not cn.parallel:  # skew or intersecting: x is the common normal's direction, exactly
            flip = np.linalg.norm(gap) > 1e-9 and gap @ normal < 0  # sign from a gap that is really there
            x = -unit(normal) if flip else unit(normal)
        elif np.linalg.norm(gap) > 1e-9:
            x = unit(gap)
        else:  # coincident axes: keep the previous x (or any normal)
            x = xs[i - 1] if i > 1 else perpendicular_basis(dirs[0])[0]
            x = unit(x - (x @ dirs[i]) * dirs[i])
        a = float((cn.foot_2 - cn.foot_1) @ x)
        alpha = float(np.arctan2(cross(dirs[i - 1], dirs[i]) @ x, dirs[i - 1] @ dirs[i]))
        x_signed = _oriented_normal(x, reference, i - 1, a, alpha)
        if i == 1:
            feet0 = cn.foot_1
        origins[i], xs[i] = cn.foot_2, x_signed
    # frame 0: theta_1 and d_1 conventional
    q1 = home[0]
    if n == 1:
        feet0 = points[0] + ((tp_home - points[0]) @ dirs[0]) * dirs[0]
        x1 = unit(cross(dirs[0], perpendicular_basis(dirs[0])[1]))
    else:
        x1 = xs[1]
    turn0 = conventional[0, 0] + (q1 if rev[0] else 0.0)
    shift0 = conventional[0, 1] + (0.0 if rev[0] else q1)
    xs[0] = rotation_about_axis(dirs[0], -turn0) @ x1
    origins[0] = feet0 - shift0 * dirs[0]
    frames = np.zeros((n + 1, 4, 4))
    for i in range(n):
        frames[i, :3, 0] = xs[i]
        frames[i, :3, 1] = cross(dirs[i], xs[i])
        frames[i, :3, 2] = dirs[i]
        frames[i, :3, 3] = origins[i]
        frames[i, 3, 3] = 1.0
    last = conventional[n - 1]
    frames[n] = frames[n - 1] @ transform_from_dh(
        last[0] + (home[-1] if rev[-1] else 0.0), last[1] + (0.0 if rev[-1] else home[-1]), last[2], last[3]
    )
    table = np.zeros((n, 4))
    for i in range(1, n + 1):
        prev, cur = frames[i - 1], frames[i]
        xp, zp, op = prev[:3, 0], prev[:3, 2], prev[:3, 3]
        xc, zc, oc = cur[:3, 0], cur[:3, 2], cur[:3, 3]
        theta = np.arctan2(cross(xp, xc) @ zp, xp @ xc)
        d = (oc - op) @ zp
        if rev[i - 1]:
            theta -= home[i - 1]
        else:
            d -= home[i - 1]
        table[i - 1] = [np.angle(np.exp(1j * theta)), d, (oc - op) @ xc, np.arctan2(cross(zp, zc) @ xc, zp @ zc)]
    table[n - 1] = conventional[n - 1]
    tool = frames[n, :3, :3].T @ (tp_home - frames[n, :3, 3])
    return DHModel(types, table[:, 0], table[:, 1], table[:, 2], table[:, 3], frames[0], tool)


def common_point(axes: list[JointAxis], meas: Measurements) -> Array:
    """The point closest to every revolute sweep's circle and every prismatic sweep's line (tracker frame, m):
    the TP at home, which all sweeps of one home pose pass through. Seeded by the measured sample nearest
    to all of them, refined by least squares."""

    def distances(p: Array) -> Array:
        out = []
        for ax in axes:
            rel = p - ax.point
            if ax.kind == "R":
                h = rel @ ax.direction
                out.append(np.hypot(h, np.linalg.norm(rel - h * ax.direction) - ax.radius))
            else:
                out.append(np.linalg.norm(rel - (rel @ ax.direction) * ax.direction))
        return np.array(out)

    seeds = meas.points[meas.joint > 0]
    best = min(seeds, key=lambda p: float(np.sum(distances(p) ** 2)))
    return least_squares(distances, best, method="lm" if len(axes) >= 3 else "trf", xtol=1e-12, ftol=1e-12).x


def geometric_step(
    meas: Measurements,
    conventional: Array | None = None,
    parallel_tol: float = DEFAULT_PARALLEL_TOL,
    reference: DHModel | None = None,
    force_parallel: Collection[int] = (),
) -> GeometricResult:
    """The paper's method on the fit rows of ``meas``: one axis per joint, then DH frames.

    For a joint swept more than once, the sweep with the most samples is used.
    """
    fit = meas.subset(~meas.check)
    n = fit.n_joints
    home = home_from_measurements(fit)
    conventional = np.zeros((n, 4)) if conventional is None else np.asarray(conventional, dtype=float)
    axes: list[JointAxis] = []
    for j in range(1, n + 1):
        sweeps = fit.sweeps_of(j)
        best = max(sweeps, key=lambda s: int(np.sum(fit.sweep == s)))
        rows = fit.sweep == best
        pts = fit.points[rows]
        axis = axis_from_sweep(pts, fit.q[rows, j - 1], fit.joint_types[j - 1], j, best, home[j - 1])
        if axis.kind == "R":
            # a gross outlier pulls a least-squares circle: refit with a robust loss when one shows
            circle = Circle(axis.point, axis.direction, axis.radius, axis.rms)
            dist = circle_residuals(pts, circle)
            scale = max(1.4826 * float(np.median(dist)), 1e-9)
            if dist.max() > OUTLIER_FACTOR * scale:
                axis = axis_from_sweep(pts, fit.q[rows, j - 1], "R", j, best, home[j - 1], robust_scale=scale)
        axes.append(axis)
    estimates = [ax.tp_home for ax in axes if ax.tp_home is not None]
    if estimates:
        weights = np.array([ax.samples for ax in axes if ax.tp_home is not None], dtype=float)
        tp_home = np.average(np.array(estimates), axis=0, weights=weights)
    else:  # positions only (the paper's setting): every sweep passes through the TP at home
        tp_home = common_point(axes, fit)
    model = dh_from_axes(
        fit.joint_types,
        [ax.point for ax in axes],
        [ax.direction for ax in axes],
        home,
        tp_home,
        conventional,
        parallel_tol,
        reference,
        force_parallel,
    )
    noise = float(np.sqrt(np.mean([ax.rms**2 for ax in axes])) / np.sqrt(3.0))
    return GeometricResult(axes, home, tp_home, model, noise)
