"""Locating a flange camera's mount and its board before the views are planned (pure: arrays in, arrays out).

A real camera's pose on the flange (``mount``: flange <- camera, 4x4) and the board's place (``board``: base <-
board, 4x4) are not known before the run: the operator gives the mount roughly (:class:`RoughMount`, e.g. from the
bracket's drawing, with a tolerance) and jogs the arm where the camera sees the whole board (the *start* pose). The
locate phase then measures the board from the start pose and from small turns of the wrist joints about it
(:func:`locate_poses`), and :func:`solve_mount` solves ``F_i X C_i = B`` for the mount X and the board B from the
nominal flange poses F_i (base <- flange) and the board's measured poses C_i (camera <- board): Park and Martin's
closed form (the rotation from the turns' axes, then the translation by least squares), refined by least squares
over every view with the camera's stated sigmas. Its uncertainties are scaled by the residuals (a moving board or
a loose camera shows there), and the nominal kinematics' own error (:data:`KINEMATIC` for the mount,
:data:`BOARD_KINEMATIC` for the board: it hardly shows in the residuals of small turns) is added in quadrature,
so a poor locate says so; :func:`refusal` says when it is too poor to plan from.
Frames: metres, radians; OpenCV's camera frame (z along the line of sight).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from acquire.planning.plan import HOME_SWEEP, _per_joint
from config.robots import RobotModel
from config.site import SiteConfig
from session.plan import Plan, Step

Array = NDArray[np.float64]

WRIST_TURN = math.radians(8.0)  # rad: each locate move turns one wrist joint this far from the start pose ...
LAST_TURN = math.radians(15.0)  # ... the last joint (about the flange's axis, the view turns about the board) further
MIN_VIEWS = 4  # views of the board the solve needs (the start and three turns about different axes)
MAX_POSITION = 0.02  # m: 3 sigma of the mount's or the board's position beyond this: too poor to plan the views
MAX_ANGLE = math.radians(2.0)  # rad: ... of their orientation
KINEMATIC = (1e-3, 2e-3)  # m, rad per axis: the nominal kinematics' error carried into the located mount (the
BOARD_KINEMATIC = (3e-3, 5e-3)  # wrist's links) and into the board's place (the whole arm's absolute error there)
DEFAULT_MOUNT = (0.0, 0.0, 0.05, 0.0, 0.0, 0.0)  # the camera 50 mm out along the flange's axis, looking along it
DEFAULT_TOLERANCE = (0.10, math.pi)  # m, rad: ... known to 100 mm and in no particular turn


@dataclass(frozen=True)
class RoughMount:
    """The mount as the operator gives it: ``mount`` flange <- camera (4x4) known to ``position`` m and ``angle``
    rad (a tolerance: the most it may be off, e.g. a bracket's drawing to 5 mm and 5°); ``given`` False for the
    default (:data:`DEFAULT_MOUNT` and :data:`DEFAULT_TOLERANCE`)."""

    mount: Array
    position: float
    angle: float
    given: bool


def rough_mount(values: str | None, tolerance: str | None) -> RoughMount:
    """The :class:`RoughMount` of ``--camera-mount X,Y,Z,RX,RY,RZ`` (m; a rotation vector in degrees) and
    ``--camera-mount-tolerance MM,DEG``; ValueError (one line) for a bad value. None: the default."""
    numbers = DEFAULT_MOUNT if values is None else _numbers(values, 6, "--camera-mount X,Y,Z,RX,RY,RZ (m, deg)")
    if values is None:
        position, angle = DEFAULT_TOLERANCE
    else:
        position, angle = 0.02, math.radians(10.0)
    if tolerance is not None:
        mm, deg = _numbers(tolerance, 2, "--camera-mount-tolerance MM,DEG")
        if mm <= 0 or not 0 < deg <= 180:
            raise ValueError(f"--camera-mount-tolerance {tolerance}: MM > 0 and 0 < DEG <= 180")
        position, angle = mm * 1e-3, math.radians(deg)
    if values is not None and math.hypot(*numbers[:3]) > 0.5:
        raise ValueError(f"--camera-mount {values}: the camera {math.hypot(*numbers[:3]):.2f} m from the flange "
                         "(metres expected, at most 0.5)")
    mount = np.eye(4)
    mount[:3, :3] = Rotation.from_rotvec(np.radians(numbers[3:])).as_matrix()
    mount[:3, 3] = numbers[:3]
    return RoughMount(mount, position, angle, values is not None)


def _numbers(text: str, count: int, form: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.replace(" ", ",").split(",") if v)
    except ValueError:
        values = ()
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{form}: got {text!r}")
    return values


def locate_poses(start: Array, limits: Array, joint_types: str) -> Array:
    """The locate views (k, n), DH joint values: the start pose, then each wrist joint (the last three revolute ones)
    turned by ±:data:`WRIST_TURN` (the last ±:data:`LAST_TURN`) alone, then two turns of two joints at once; a turn
    that would leave the limits goes the other way (and is dropped if that leaves them too)."""
    start = np.asarray(start, dtype=float)
    lo, hi = np.asarray(limits, dtype=float).T
    wrist = [j for j in range(len(start)) if joint_types[j] == "R"][-3:]
    turns: list[dict[int, float]] = []
    for j in wrist:
        angle = LAST_TURN if j == wrist[-1] else WRIST_TURN
        turns += [{j: angle}, {j: -angle}]
    if len(wrist) >= 2:
        turns += [{wrist[0]: WRIST_TURN, wrist[1]: WRIST_TURN}, {wrist[-2]: -WRIST_TURN, wrist[-1]: LAST_TURN}]
    out = [start]
    for turn in turns:
        q = start.copy()
        for j, angle in turn.items():
            q[j] = start[j] + angle if lo[j] <= start[j] + angle <= hi[j] else start[j] - angle
        if np.all(q >= lo) and np.all(q <= hi) and not any(np.allclose(q, p) for p in out):
            out.append(q)
    return np.array(out)


def locate_plan(robot: RobotModel, site: SiteConfig, start: Array) -> Plan:
    """The locate views about ``start`` (DH values) as a plan (the start's reading first, one reading each)."""
    poses = locate_poses(start, robot.limits, robot.joint_types)
    steps = tuple(Step(i, "home" if i == 0 else "free", HOME_SWEEP if i == 0 else i, 0,
                       tuple(float(v) for v in q)) for i, q in enumerate(poses))
    return Plan(robot.name, robot.joint_types, tuple(float(v) for v in start), steps, 1, site.settle_time,
                tuple(float(v) for v in _per_joint(robot, site, "speed")),
                tuple(float(v) for v in _per_joint(robot, site, "acceleration")),
                ("locate: the start pose, then small turns of the wrist joints about it",))


@dataclass(frozen=True)
class Located:
    """What the locate phase found: ``mount`` flange <- camera and ``board`` base <- board (4x4), their standard
    uncertainties (the largest axis's: ``mount_position`` m, ``mount_angle`` rad, ``board_position``,
    ``board_angle``), the residuals' RMS (``rms_position`` m, ``rms_angle`` rad) over ``views`` views of
    ``tried``, and ``distance`` m: the board's centre from the camera at the start pose."""

    mount: Array
    board: Array
    mount_position: float
    mount_angle: float
    board_position: float
    board_angle: float
    rms_position: float
    rms_angle: float
    views: int
    tried: int
    distance: float

    def pointing(self) -> float:
        """rad: the standard error of the camera's line of sight at the board's distance from the located mount (the
        board's own place errs with the nominal kinematics the views are solved with, so it does not add)."""
        return math.hypot(self.mount_angle, self.mount_position / self.distance)

    def lines(self) -> list[str]:
        """What the operator reads: how well the mount and the board are known, from how many views."""
        mount = self.mount[:3, 3]
        turn = np.degrees(Rotation.from_matrix(self.mount[:3, :3]).as_rotvec())
        return [f"locate: the board seen in {self.views} of {self.tried} views; residuals {self.rms_position * 1e3:.2f}"
                f" mm, {math.degrees(self.rms_angle):.3f}° RMS (the nominal kinematics' errors and the camera's)",
                f"  camera mount (flange frame): [{mount[0]:.4f}, {mount[1]:.4f}, {mount[2]:.4f}] m, turned "
                f"[{turn[0]:.2f}, {turn[1]:.2f}, {turn[2]:.2f}]°, known to {self.mount_position * 1e3:.2f} mm, "
                f"{math.degrees(self.mount_angle):.3f}° (1 sigma, with the nominal kinematics' "
                f"{KINEMATIC[0] * 1e3:g} mm, {KINEMATIC[1] * 1e3:g} mrad)",
                f"  board: {self.distance:.3f} m from the camera at the start pose, placed to "
                f"{self.board_position * 1e3:.2f} mm, {math.degrees(self.board_angle):.3f}° (1 sigma, with the "
                f"nominal kinematics' {BOARD_KINEMATIC[0] * 1e3:g} mm, {BOARD_KINEMATIC[1] * 1e3:g} mrad)"]

    def as_dict(self) -> dict[str, object]:
        """The session's record of the locate (plain lists; m, rad)."""
        return {"mount": self.mount.tolist(), "board": self.board.tolist(), "mount_sigma_m": self.mount_position,
                "mount_sigma_rad": self.mount_angle, "board_sigma_m": self.board_position,
                "board_sigma_rad": self.board_angle, "rms_m": self.rms_position, "rms_rad": self.rms_angle,
                "views": self.views, "tried": self.tried, "distance_m": self.distance}


def _inverse(t: Array) -> Array:
    out = np.eye(4)
    out[:3, :3] = t[:3, :3].T
    out[:3, 3] = -t[:3, :3].T @ t[:3, 3]
    return out


def park_martin(flanges: Array, views: Array) -> Array:
    """The mount X (flange <- camera) from ``flanges`` (k, 4, 4; base <- flange) and ``views`` (k, 4, 4; camera <-
    board) of a fixed board, in closed form (Park and Martin): for each pair the flange's relative motion A and the
    camera's B satisfy ``A X = X B``; the rotation aligns B's rotation axes with A's, the translation solves
    ``(R_A - I) t = R_X t_B - t_A`` by least squares. ValueError without two turns about different axes."""
    alphas, betas, a_list, b_list = [], [], [], []
    for i in range(len(flanges)):
        for j in range(i + 1, len(flanges)):
            a = _inverse(flanges[j]) @ flanges[i]
            b = views[j] @ _inverse(views[i])
            alpha = Rotation.from_matrix(a[:3, :3]).as_rotvec()
            if np.linalg.norm(alpha) < math.radians(1.0):
                continue
            alphas.append(alpha)
            betas.append(Rotation.from_matrix(b[:3, :3]).as_rotvec())
            a_list.append(a)
            b_list.append(b)
    if len(alphas) < 2 or np.linalg.matrix_rank(np.array(alphas), tol=math.radians(0.5)) < 2:
        raise ValueError("the views turn the camera about fewer than two axes")
    rotation = Rotation.align_vectors(np.array(alphas), np.array(betas))[0].as_matrix()
    lhs = np.vstack([a[:3, :3] - np.eye(3) for a in a_list])
    rhs = np.concatenate([rotation @ b[:3, 3] - a[:3, 3] for a, b in zip(a_list, b_list, strict=True)])
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    return out


def solve_mount(flanges: Array, views: Array, sigma: Array, sigma_r: Array, tried: int,
                kinematic: tuple[float, float] = KINEMATIC,
                board_kinematic: tuple[float, float] = BOARD_KINEMATIC) -> Located:
    """The mount and the board (:class:`Located`) from the views of the board: ``flanges`` (k, 4, 4) base <-
    flange by the nominal model at the joints read, ``views`` (k, 4, 4) camera <- board measured, ``sigma`` (k,) m
    and ``sigma_r`` (k,) rad their stated uncertainties. The closed form (:func:`park_martin`) refined by least
    squares (positions over ``sigma``, turns over ``sigma_r``); the covariance scaled up by the reduced
    chi-square when it exceeds 1, ``kinematic`` (the mount's) and ``board_kinematic`` (the board's; m, rad per
    axis) added in quadrature. ValueError with fewer
    than :data:`MIN_VIEWS` views or too few axes."""
    flanges, views = np.asarray(flanges, dtype=float), np.asarray(views, dtype=float)
    if len(views) < MIN_VIEWS:
        raise ValueError(f"the board was seen in {len(views)} of {tried} views (at least {MIN_VIEWS} needed)")
    x0 = park_martin(flanges, views)
    b0 = flanges[0] @ x0 @ views[0]
    sigma, sigma_r = np.asarray(sigma, dtype=float), np.asarray(sigma_r, dtype=float)

    def transforms(p: Array) -> tuple[Array, Array]:
        x, b = x0.copy(), b0.copy()
        x[:3, :3] = Rotation.from_rotvec(p[:3]).as_matrix() @ x0[:3, :3]
        x[:3, 3] += p[3:6]
        b[:3, :3] = Rotation.from_rotvec(p[6:9]).as_matrix() @ b0[:3, :3]
        b[:3, 3] += p[9:12]
        return x, b

    def residuals(p: Array) -> Array:
        x, b = transforms(p)
        predicted = np.einsum("kij,jl->kil", np.linalg.inv(flanges @ x), b)
        position = (predicted[:, :3, 3] - views[:, :3, 3]) / sigma[:, None]
        turn = Rotation.from_matrix(predicted[:, :3, :3] @ np.swapaxes(views[:, :3, :3], 1, 2)).as_rotvec()
        return np.concatenate([position.ravel(), (turn / sigma_r[:, None]).ravel()])

    fit = least_squares(residuals, np.zeros(12), x_scale="jac")
    mount, board = transforms(fit.x)
    dof = max(len(fit.fun) - 12, 1)
    scale = max(1.0, float(fit.fun @ fit.fun) / dof)
    cov = np.linalg.pinv(fit.jac.T @ fit.jac) * scale

    def largest(block: slice) -> float:
        extra = (kinematic if block.start < 6 else board_kinematic)[0 if block.start in (3, 9) else 1]
        return math.sqrt(max(float(np.max(np.linalg.eigvalsh(cov[block, block]))), 0.0) + extra**2)

    k = len(views)
    raw = fit.fun.reshape(2, k, 3)
    rms_position = math.sqrt(float(np.mean((raw[0] * sigma[:, None]) ** 2)) * 3)
    rms_angle = math.sqrt(float(np.mean((raw[1] * sigma_r[:, None]) ** 2)) * 3)
    return Located(mount, board, largest(slice(3, 6)), largest(slice(0, 3)), largest(slice(9, 12)),
                   largest(slice(6, 9)), rms_position, rms_angle, k, tried, float(np.linalg.norm(views[0, :3, 3])))


def refusal(located: Located, rough: RoughMount) -> str:
    """Why the located mount and board are too poor to plan the views from (one line), or ""."""
    if 3 * max(located.mount_position, located.board_position) > MAX_POSITION or \
            3 * max(located.mount_angle, located.board_angle) > MAX_ANGLE:
        return (f"the locate phase knows the camera's mount to {located.mount_position * 1e3:.1f} mm, "
                f"{math.degrees(located.mount_angle):.2f}° and the board to {located.board_position * 1e3:.1f} mm, "
                f"{math.degrees(located.board_angle):.2f}° (1 sigma, from {located.views} views; 3 sigma must be "
                f"within {MAX_POSITION * 1e3:g} mm and {math.degrees(MAX_ANGLE):g}°): check that the board is fixed "
                "and flat and the camera firmly mounted, or jog the arm nearer the board and run again")
    off = float(np.linalg.norm(located.mount[:3, 3] - rough.mount[:3, 3]))
    turn = float(np.linalg.norm(Rotation.from_matrix(located.mount[:3, :3] @ rough.mount[:3, :3].T).as_rotvec()))
    if off > rough.position + 3 * located.mount_position or turn > rough.angle + 3 * located.mount_angle:
        return (f"the located camera mount is {off * 1e3:.0f} mm and {math.degrees(turn):.1f}° from --camera-mount "
                f"(tolerance {rough.position * 1e3:.0f} mm, {math.degrees(rough.angle):.0f}°): check the option "
                "(flange <- camera, OpenCV's camera frame) or the bracket")
    return ""
