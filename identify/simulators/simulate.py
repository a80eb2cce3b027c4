"""Simulated measurements from the forward model alone: the basis of tests and benchmarks.

A true robot (kinematics/truth.py, shared with mock mode's simulated rig) is a nominal DH model with seeded
perturbations, placed at a random pose in the tracker frame with a TP off every axis. Sweeps move one joint at a
time about a home pose; free poses move all joints. The tracker sees the true TP plus isotropic Gaussian noise
(metres) and optional gross outliers; a full-pose device (6-DoF probe, camera target) also sees the target frame's
orientation with isotropic noise (rad, a small random turn in the tracker frame). Every random draw comes from the
``numpy.random.Generator`` passed in.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from identify.estimator.geometry import perpendicular_basis, rotation_about_axis, unit
from identify.estimator.measurements import Measurements
from identify.estimator.orientation import matrices_from_rotvecs, rotvecs_from_matrices
from identify.estimator.poe import AxisLines, points_from_lines
from kinematics.dh import DHModel, flange_frames, frames_from_joints, points_from_joints
from kinematics.truth import random_base, random_truth

Array = NDArray[np.float64]


def sweep_readings(
    joint_types: str,
    home: Array,
    limits: Array,
    steps: int = 36,
    arc: float | None = None,
    stroke: float = 0.2,
) -> tuple[Array, NDArray[np.int64], NDArray[np.int64]]:
    """Joint readings for one sweep per joint, last joint first (as in the paper).

    Revolute joints cover a full turn about home in ``steps`` increments, or ``home ± arc`` radians;
    prismatic joints ``home ± stroke/2`` metres; both clipped to ``limits`` (n, 2).
    Returns (q (m, n), sweep ids (m,), moved joint 1-based (m,)).
    """
    n = len(joint_types)
    blocks, sweeps, joints = [], [], []
    for number, j in enumerate(reversed(range(n)), start=1):
        lo, hi = limits[j]
        if joint_types[j] == "R" and arc is None:
            values = home[j] + 2 * np.pi * (np.arange(steps) - steps // 2) / steps
            if values.min() < lo or values.max() > hi:
                values = np.linspace(max(lo, home[j] - np.pi), min(hi, home[j] + np.pi), steps)
        else:
            half = arc if joint_types[j] == "R" else stroke / 2
            values = np.linspace(max(lo, home[j] - half), min(hi, home[j] + half), steps)
        q = np.tile(home, (steps, 1))
        q[:, j] = values
        blocks.append(q)
        sweeps.append(np.full(steps, number))
        joints.append(np.full(steps, j + 1))
    return np.vstack(blocks), np.concatenate(sweeps), np.concatenate(joints)


def random_poses(limits: Array, count: int, rng: np.random.Generator, margin: float = 0.1) -> Array:
    """``count`` poses drawn uniformly inside ``limits`` (n, 2), shrunk by ``margin`` of each range."""
    lo, hi = limits[:, 0], limits[:, 1]
    span = hi - lo
    return rng.uniform(lo + margin * span, hi - margin * span, size=(count, len(lo)))


def observe(
    truth: DHModel,
    q: Array,
    rng: np.random.Generator,
    noise: float,
    outliers: int = 0,
    outlier_size: float = 5e-3,
) -> tuple[Array, NDArray[np.int64]]:
    """TP positions seen by a tracker with isotropic noise ``noise`` (m per axis) and ``outliers``
    gross errors of ``outlier_size`` m in random directions. Returns (points (m, 3), outlier rows)."""
    points = points_from_joints(truth, q) + rng.normal(0.0, noise, size=(len(q), 3))
    bad = rng.choice(len(q), size=outliers, replace=False) if outliers else np.zeros(0, dtype=np.int64)
    points[bad] += unit(rng.normal(size=(len(bad), 3))) * outlier_size
    return points, np.sort(bad)


def observe_frames(truth: DHModel, tool_rotation: Array, q: Array, rng: np.random.Generator, noise_r: float
                   ) -> Array:
    """Target-frame orientations (m, 3) as rotation vectors (rad, tracker frame) seen by a full-pose device with
    isotropic noise ``noise_r`` (rad per axis): the true frame is ``truth``'s last DH frame times ``tool_rotation``
    (3, 3, the target frame in the last DH frame), turned by ``exp(noise)``."""
    rotation, _ = flange_frames(truth, q)
    noisy = matrices_from_rotvecs(rng.normal(0.0, noise_r, size=(len(q), 3))) @ rotation @ tool_rotation
    return rotvecs_from_matrices(noisy)


def with_orientations(meas: Measurements, truth: DHModel, tool_rotation: Array, rng: np.random.Generator,
                      noise: float, noise_r: float) -> Measurements:
    """``meas`` (simulated from ``truth`` with ``noise`` m per axis) as a full-pose device's: every row with the
    target frame's orientation (:func:`observe_frames`, ``noise_r`` rad per axis) and both sigmas declared."""
    q = np.where(np.isnan(meas.q), 0.0, meas.q)
    rotvec = observe_frames(truth, tool_rotation, q, rng, noise_r)
    return replace(meas, rotvec=rotvec, sigma_r=np.full(len(meas), noise_r), sigma=np.full(len(meas), noise))


def simulate(
    truth: DHModel,
    home: Array,
    limits: Array,
    rng: np.random.Generator,
    noise: float = 5e-5,
    steps: int = 36,
    arc: float | None = None,
    free_poses: int = 0,
    check_poses: int = 0,
    outliers: int = 0,
) -> tuple[Measurements, NDArray[np.int64]]:
    """A full data set: sweeps of every joint, ``free_poses`` fitted free poses and ``check_poses``
    held-out (role ``check``) free poses. Outliers are put among the sweep samples only.

    Returns the measurements and the row indices of the outliers.
    """
    q, sweep, joint = sweep_readings(truth.joint_types, home, limits, steps, arc)
    points, bad = observe(truth, q, rng, noise, outliers)
    extra = free_poses + check_poses
    if extra:
        q_free = random_poses(limits, extra, rng)
        p_free, _ = observe(truth, q_free, rng, noise)
        q = np.vstack([q, q_free])
        points = np.vstack([points, p_free])
        next_id = int(sweep.max()) + 1
        sweep = np.concatenate([sweep, np.arange(next_id, next_id + extra)])
        joint = np.concatenate([joint, np.zeros(extra, dtype=np.int64)])
    check = np.zeros(len(q), dtype=bool)
    if check_poses:
        check[-check_poses:] = True
    meas = Measurements(truth.joint_types, q, points, sweep, joint, check=check, has_role=check_poses > 0)
    return meas, bad


# ------------------------------------------------------------------ realistic cells (issue 11 scenarios)
#
# A truth here is a set of axis lines at the home pose (identify.estimator.poe.AxisLines, tracker frame, metres), so it
# can carry errors a DH perturbation cannot express (a nominally parallel axis tilted in any direction). Readings are
# what the controller reports; the TP's true position comes from the *true* angles (readings through an optional
# ReadingError). Every random draw comes from the ``numpy.random.Generator`` passed in.

WRIST_STEP = float(np.radians(144.0))  # rad: sparse wrist sweeps, 6 samples over -360°..+360°


def lines_from_model(model: DHModel, q: Array) -> AxisLines:
    """The joint axes of ``model`` as lines at readings ``q`` (n,): joint i turns about z of DH frame i-1
    through its origin (tracker frame, metres); the TP there is ``tp_home``."""
    frames = frames_from_joints(model, q[None, :])[0]
    tp = points_from_joints(model, q[None, :])[0]
    return AxisLines(model.joint_types, frames[:-1, :3, 3].copy(), frames[:-1, :3, 2].copy(), np.array(q, float), tp)


def transform_lines(lines: AxisLines, transform: Array) -> AxisLines:
    """``lines`` moved rigidly by the 4x4 ``transform`` (new frame <- old frame)."""
    rot, shift = transform[:3, :3], transform[:3, 3]
    return replace(lines, points=lines.points @ rot.T + shift, directions=lines.directions @ rot.T,
                   tp_home=rot @ lines.tp_home + shift)


def tilt_lines(lines: AxisLines, rng: np.random.Generator, tilt: float = 1e-3, shift: float = 5e-4) -> AxisLines:
    """Every axis direction turned about a random axis perpendicular to it (rotation vector with two
    N(0, ``tilt``) components, rad) and every revolute line's point moved perpendicular to its axis by two
    N(0, ``shift``) components (m). The TP at home is kept."""
    points, directions = lines.points.copy(), lines.directions.copy()
    for i, t in enumerate(lines.joint_types):
        e1, e2 = perpendicular_basis(directions[i])
        g = rng.normal(size=2)
        turn = g[0] * e1 + g[1] * e2
        directions[i] = rotation_about_axis(unit(turn), tilt * np.linalg.norm(turn)) @ directions[i]
        h = rng.normal(size=2)
        if t == "R":
            points[i] = points[i] + shift * (h[0] * e1 + h[1] * e2)
    return replace(lines, points=points, directions=directions)


def line_distances(lines: AxisLines, point: Array) -> Array:
    """Distance (m) of ``point`` (3,) from each revolute axis line; inf for prismatic joints."""
    rel = point - lines.points
    along = np.sum(rel * lines.directions, axis=1)
    dist = np.linalg.norm(rel - along[:, None] * lines.directions, axis=1)
    return np.where(np.array([t == "R" for t in lines.joint_types]), dist, np.inf)


def place_tp(
    lines: AxisLines,
    flange: Array,
    rng: np.random.Generator,
    min_radius: float = 0.03,
    tool_reach: float = 0.12,
    last_radius: float | None = None,
) -> AxisLines:
    """``lines`` with a random TP at home near the ``flange`` point (3,), at least ``min_radius`` m off every
    revolute axis; with ``last_radius`` (m) the TP is exactly that far off the last axis (which must then be
    revolute) and only the other axes keep ``min_radius``."""
    n = len(lines.joint_types)
    others = np.arange(n) < n - 1 if last_radius is not None else np.ones(n, bool)
    for _ in range(1000):
        if last_radius is None:
            tp = flange + rng.uniform(-tool_reach, tool_reach, 3)
        else:
            d = lines.directions[-1]
            foot = lines.points[-1] + ((flange - lines.points[-1]) @ d) * d
            e1, e2 = perpendicular_basis(d)
            phi = rng.uniform(0, 2 * np.pi)
            tp = foot + rng.uniform(0, tool_reach) * d + last_radius * (np.cos(phi) * e1 + np.sin(phi) * e2)
        if np.all(line_distances(lines, tp)[others] >= min_radius):
            return replace(lines, tp_home=tp)
    raise RuntimeError("could not place a TP off every axis; widen tool_reach")


def tilted_truth(
    nominal: DHModel,
    home: Array,
    rng: np.random.Generator,
    tilt: float = 1e-3,
    shift: float = 5e-4,
    min_radius: float = 0.03,
    tool_reach: float = 0.12,
    last_radius: float | None = None,
) -> AxisLines:
    """A true robot whose axes are the ``nominal`` model's at ``home`` (base at the identity), each tilted in
    a random direction and shifted (:func:`tilt_lines`), with a random TP (:func:`place_tp`), then placed
    by a random tracker <- base transform (:func:`random_base`). Predict with ``points_from_lines``."""
    lines = tilt_lines(lines_from_model(replace(nominal, base=np.eye(4), tool=np.zeros(3)), home), rng, tilt, shift)
    flange = frames_from_joints(replace(nominal, base=np.eye(4)), home[None, :])[0, -1, :3, 3]
    lines = place_tp(lines, flange, rng, min_radius, tool_reach, last_radius)
    return transform_lines(lines, random_base(rng))


def dh_truth(
    nominal: DHModel, home: Array, rng: np.random.Generator, last_radius: float | None = None
) -> AxisLines:
    """:func:`random_truth` (DH values perturbed: nominally parallel axes tilt only about their common normal)
    as lines at ``home``; with ``last_radius`` (m) the TP is re-placed that far off the last axis."""
    model = random_truth(nominal, home, rng)
    lines = lines_from_model(model, home)
    if last_radius is not None:
        flange = frames_from_joints(model, home[None, :])[0, -1, :3, 3]
        lines = place_tp(lines, flange, rng, last_radius=last_radius)
    return lines


def line_parameter_count(joint_types: str) -> int:
    """Size of the minimal lines parameter vector of :func:`moved_lines`: 4 per R, 2 per P, 3 for the TP."""
    return sum(4 if t == "R" else 2 for t in joint_types) + 3


def moved_lines(lines: AxisLines, x: Array) -> AxisLines:
    """``lines`` changed by the increments ``x``: per joint 2 tilts (rad) of the direction along the
    ``perpendicular_basis`` of the original direction, per revolute joint 2 shifts (m) of the point in that
    basis, then the TP at home (3, m). A parameterisation without singularities, minimal for position data."""
    points, directions, k = lines.points.copy(), lines.directions.copy(), 0
    for i, t in enumerate(lines.joint_types):
        e1, e2 = perpendicular_basis(lines.directions[i])
        directions[i] = unit(lines.directions[i] + x[k] * e1 + x[k + 1] * e2)
        if t == "R":
            points[i] = lines.points[i] + x[k + 2] * e1 + x[k + 3] * e2
        k += 4 if t == "R" else 2
    return replace(lines, points=points, directions=directions, tp_home=lines.tp_home + x[k:k + 3])


def perturbed_lines(lines: AxisLines, q: Array, rms: float, rng: np.random.Generator) -> AxisLines:
    """``lines`` with every axis tilted and shifted and the TP moved by a small random amount
    (:func:`moved_lines`), scaled so that the predictions at readings ``q`` (m, n) move by ``rms`` m (RMS 3D,
    to first order: exact to ~1e-4 relative at the micrometre sizes used). For model error between sweeps."""
    x = rng.normal(size=line_parameter_count(lines.joint_types)) * 1e-5
    exact = points_from_lines(lines, q)
    move = points_from_lines(moved_lines(lines, x), q) - exact
    return moved_lines(lines, x * rms / np.sqrt(np.mean(np.sum(move**2, axis=1))))


@dataclass(frozen=True)
class ReadingError:
    """Non-geometric joint error: the true angle of revolute joint i is
    ``r·(1 + scale_i) + amplitude_i·sin(r + phase_i)`` for a controller reading ``r`` (rad); prismatic
    joints get the scale only (m). Arrays (n,)."""

    scale: Array
    amplitude: Array
    phase: Array

    def true_from_reading(self, joint_types: str, readings: Array) -> Array:
        """True joint values (m, n) for controller ``readings`` (m, n); NaN stays NaN."""
        rev = np.array([t == "R" for t in joint_types])
        cyclic = np.where(rev, self.amplitude * np.sin(readings + self.phase), 0.0)
        return readings * (1 + self.scale) + cyclic


def reading_error(
    joint_types: str, rng: np.random.Generator, scale: float = 1e-4, amplitude: float = float(np.radians(0.01))
) -> ReadingError:
    """Every joint's reading scaled by ``1 + scale`` and every revolute joint off by a once-per-turn
    ``amplitude`` (rad) at a random phase."""
    n = len(joint_types)
    return ReadingError(np.full(n, scale), np.full(n, amplitude), rng.uniform(0, 2 * np.pi, n))


@dataclass(frozen=True)
class Scenario:
    """A simulated data set with what a benchmark needs to score its identification.

    ``meas``: the data (readings as the controller reports them, NaN where missing; ``check`` rows held out).
    ``truth``: true axis lines at the true home angles (tracker frame, m). ``home``: controller readings at
    home (n,). ``true_q``: true joint values of every row (m, n), never NaN. ``unknown``: rows whose moved
    joint's reading is missing. ``outliers``: 0-based rows carrying gross errors. ``noise``: tracker noise, m
    per axis. ``errors``: reading error or None. ``sweep_rms``: model error (m) each row's sweep saw (0 if
    none). ``relative``: readings given to a predictor are relative to home (no reading exists anywhere).
    """

    meas: Measurements
    truth: AxisLines
    home: Array
    true_q: Array
    unknown: NDArray[np.bool_]
    outliers: NDArray[np.int64]
    noise: float
    errors: ReadingError | None = None
    sweep_rms: Array | None = None
    relative: bool = False

    def true_values(self, readings: Array) -> Array:
        """True joint values (k, n) for controller readings (k, n) (absolute, not relative to home)."""
        return readings if self.errors is None else self.errors.true_from_reading(self.truth.joint_types, readings)

    def truth_points(self, readings: Array) -> Array:
        """Where the TP truly is (k, 3), tracker frame, m, when the controller reports ``readings`` (k, n)."""
        return points_from_lines(self.truth, self.true_values(readings))

    def predictor_readings(self, readings: Array) -> Array:
        """``readings`` as an identification of ``meas`` expects them (relative to home for positions-only)."""
        return readings - self.home if self.relative else readings


def sweeps_from_values(home: Array, values: list[Array]) -> tuple[Array, NDArray[np.int64], NDArray[np.int64]]:
    """Sweeps moving joint j alone through ``values[j]`` (others at ``home``), last joint first.
    Returns (q (m, n), sweep ids (m,), moved joint 1-based (m,))."""
    blocks, sweeps, joints = [], [], []
    for number, j in enumerate(reversed(range(len(home))), start=1):
        q = np.tile(home, (len(values[j]), 1))
        q[:, j] = values[j]
        blocks.append(q)
        sweeps.append(np.full(len(q), number))
        joints.append(np.full(len(q), j + 1))
    return np.vstack(blocks), np.concatenate(sweeps), np.concatenate(joints)


def wrist_joints(joint_types: str, limits: Array) -> list[int]:
    """0-based revolute joints among the last three whose limits allow -360°..+360° (sparse wrist sweeps)."""
    n = len(joint_types)
    full = 2 * np.pi - 1e-9
    return [j for j in range(max(0, n - 3), n)
            if joint_types[j] == "R" and limits[j, 0] <= -full and full <= limits[j, 1]]


def scenario_sweeps(
    joint_types: str, home: Array, limits: Array, steps: int = 36, arc: float | None = None, wrist: bool = False
) -> tuple[Array, NDArray[np.int64], NDArray[np.int64]]:
    """Sweep readings as :func:`sweep_readings`; with ``wrist`` the joints of :func:`wrist_joints` instead
    take 6 samples from -360° to +360° in 144° steps (absolute readings)."""
    q, _, joint = sweep_readings(joint_types, home, limits, steps, arc)
    values = [q[joint == j + 1, j] for j in range(len(home))]
    if wrist:
        for j in wrist_joints(joint_types, limits):
            values[j] = -2 * np.pi + WRIST_STEP * np.arange(6)
    return sweeps_from_values(home, values)


def gross_outliers(
    m: int, rng: np.random.Generator, fraction: float = 0.05, size: tuple[float, float] = (5e-3, 20e-3),
    rows: NDArray[np.int64] | None = None,
) -> tuple[NDArray[np.int64], Array]:
    """``round(fraction · len(rows))`` distinct rows among ``rows`` (default all ``m``), each displaced by a
    length uniform in ``size`` (m) in a uniformly random direction. Returns (sorted rows, offsets (m, 3))."""
    pool = np.arange(m) if rows is None else np.asarray(rows)
    count = round(fraction * len(pool))
    bad = np.sort(rng.choice(pool, size=count, replace=False))
    offsets = np.zeros((m, 3))
    offsets[bad] = unit(rng.normal(size=(count, 3))) * rng.uniform(size[0], size[1], (count, 1))
    return bad, offsets


def make_scenario(
    truth: AxisLines,
    home: Array,
    limits: Array,
    rng: np.random.Generator,
    noise: float = 5e-5,
    steps: int = 36,
    arc: float | None = None,
    wrist: bool = False,
    free_poses: int = 0,
    free_only: int = 0,
    check_poses: int = 0,
    holdout_in_sweep: int = 0,
    missing_in_sweep: int = 0,
    outlier_fraction: float = 0.0,
    readings: str = "all",
    jogged_joint: int | None = None,
    model_error: tuple[float, float] | None = None,
    errors: ReadingError | None = None,
) -> Scenario:
    """One data set of a true cell ``truth`` (lines at the true home angles) whose controller reads ``home``.

    Sweeps (:func:`scenario_sweeps`) unless ``free_only`` > 0 (then only that many free poses, joint 0);
    ``free_poses`` extra fitted free poses and ``check_poses`` held-out free poses; ``holdout_in_sweep`` rows
    of the last joint's sweep (its 2nd, 3rd, ...) held out; ``missing_in_sweep`` rows of that sweep (from its
    2nd) never measured. ``outlier_fraction`` of the fitted sweep rows
    (free rows for ``free_only``) get gross errors of 5-20 mm. ``readings``: ``"all"``; ``"none"`` (every
    reading of every sweep row NaN: positions only, the predictor works relative to home); ``"jogged"``
    (only joint ``jogged_joint``'s sweep, 1-based, default the middle joint). ``model_error`` (lo, hi) m: each
    sweep sees the truth moved by an RMS amount uniform in that range (:func:`perturbed_lines`). ``errors``:
    controller readings differ from the true angles. Noise: isotropic Gaussian, ``noise`` m per axis.
    The rows of a sweep are in the order of motion (readings increasing), which is all that gives a
    positions-only sweep its sense of rotation.
    """
    types, n = truth.joint_types, len(home)
    if free_only:
        q = random_poses(limits, free_only, rng)
        sweep, joint = np.arange(1, free_only + 1), np.zeros(free_only, dtype=np.int64)
    else:
        q, sweep, joint = scenario_sweeps(types, home, limits, steps, arc, wrist)
        if missing_in_sweep:  # the tracker lost the target: consecutive steps of the last joint's sweep absent
            gone = np.flatnonzero(joint == n)[1:1 + missing_in_sweep]
            keep = ~np.isin(np.arange(len(q)), gone)
            q, sweep, joint = q[keep], sweep[keep], joint[keep]
    n_main = len(q)
    extra = free_poses + check_poses
    if extra:
        q = np.vstack([q, random_poses(limits, extra, rng)])
        sweep = np.concatenate([sweep, np.arange(sweep.max() + 1, sweep.max() + 1 + extra)])
        joint = np.concatenate([joint, np.zeros(extra, dtype=np.int64)])
    check = np.zeros(len(q), dtype=bool)
    if check_poses:
        check[-check_poses:] = True
    if holdout_in_sweep and not free_only:
        last = np.flatnonzero(joint == n)
        check[last[1:1 + holdout_in_sweep]] = True
    true_q = q if errors is None else errors.true_from_reading(types, q)
    true_home = home if errors is None else errors.true_from_reading(types, home[None, :])[0]
    truth = replace(truth, home=true_home)
    points = points_from_lines(truth, true_q)
    sweep_rms = np.zeros(len(q))
    if model_error is not None:
        for s in np.unique(sweep[:n_main]):
            rows = np.flatnonzero(sweep == s)
            size = rng.uniform(*model_error)
            points[rows] = points_from_lines(perturbed_lines(truth, true_q[rows], size, rng), true_q[rows])
            sweep_rms[rows] = size
    points = points + rng.normal(0.0, noise, size=points.shape)
    pool = np.flatnonzero(~check[:n_main])
    bad, offsets = gross_outliers(len(q), rng, outlier_fraction, rows=pool) if outlier_fraction else (
        np.zeros(0, dtype=np.int64), np.zeros_like(points))
    points = points + offsets
    unknown = np.zeros(len(q), dtype=bool)
    if readings == "none":
        unknown = joint > 0
    elif readings == "jogged":
        unknown = joint == (jogged_joint or (n + 1) // 2)
    elif readings != "all":
        raise ValueError(f"readings must be all, none or jogged; got {readings!r}")
    q_seen = q.copy()
    q_seen[np.flatnonzero(unknown), joint[unknown] - 1] = np.nan
    if readings == "none":
        q_seen[joint > 0] = np.nan  # positions only: no reading of any joint in any sweep row
    meas = Measurements(types, q_seen, points, sweep, joint, check=check, has_role=bool(check.any()))
    return Scenario(meas, truth, home, true_q, unknown, bad, noise, errors, sweep_rms, relative=readings == "none")
