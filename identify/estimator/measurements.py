"""Measurements: joint readings and tracked-point positions, grouped in sweeps (pure data, no I/O).

Rows follow the measurement CSV (README, "File contracts"): ``sweep`` id, the 1-based ``joint`` moved in
that sweep (0 for free poses), joint readings ``q`` (rad for R, m for P; NaN where a moved joint's
reading was not logged), the TP ``points`` in the tracker frame (metres) and the id ``tp`` of the tracked
point each row sees (several reflectors at one pose: one row each). With a ``coupling`` the readings are
the controller's; :func:`in_dh_joints` turns them into DH joint values. Full-pose devices (6-DoF probes, camera
targets) also give the measured target frame's orientation (``rotvec``, rad) with its own uncertainty (``sigma_r``).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from common.errors import InputError
from kinematics.dh import check_joint_types
from kinematics.joint_errors import Coupling

Array = NDArray[np.float64]

MIN_SWEEP_SAMPLES = 3
FEW_SWEEP_SAMPLES = 8


@dataclass(frozen=True)
class LensShare:
    """The error a camera's rows share through its final estimate of its board's shape and its lens (p parameters,
    identify/sensors/recorrection.py): ``response`` (m, 6, p) each row's move per unit of each (its position m, then a
    turn rad, the device's frame), ``covariance`` (p, p) the estimate's, and ``share``, ``share_r`` (m,) the per-axis
    RMS it makes of each row's position (m) and orientation (rad), which the rows' ``sigma``, ``sigma_r`` include;
    ``names`` the parameters and ``estimate`` (p,) their values (drivers/camera/board_and_lens.py: m, relative, px).
    """

    response: Array
    covariance: Array
    share: Array
    share_r: Array
    names: tuple[str, ...] = ()
    estimate: Array | None = None

    def subset(self, mask: NDArray[np.bool_]) -> LensShare:
        return replace(self, response=self.response[mask], share=self.share[mask], share_r=self.share_r[mask])

    def as_dict(self) -> dict[str, list[float]]:
        """Each estimated parameter (a prior above 0: variance above 0) as [value, standard deviation] (empty without
        ``names``)."""
        if not self.names:
            return {}
        sd = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        value = np.zeros(len(sd)) if self.estimate is None else self.estimate
        return {name: [float(v), float(s)] for name, v, s in zip(self.names, value, sd, strict=True) if s > 0}


@dataclass(frozen=True)
class Measurements:
    """One data set. Shapes: q (m, n), points (m, 3), sweep/joint (m,), sigma (m,) or None.

    ``check`` (m,) marks rows held out for validation (never fitted); ``row`` (m,) is the source line
    number of each sample, for messages; ``tp`` (m,) the tracked point's id (1 when there is one);
    ``coupling``: how the readings give DH joint values (None: they are DH joint values).

    Continuous motion: ``t`` (m,) the sample's time, s on the tracker's clock (NaN or None when unknown);
    ``streamed`` (m,) marks rows recorded while the robot moved, whose ``q`` were interpolated from the
    robot's joint stream at robot time ``t + clock_offset`` (s); the fit refines that timing.

    Full pose: ``rotvec`` (m, 3) the measured target frame's orientation in the tracker frame as a rotation vector
    (axis times angle, rad; NaN rows: that row measured a position only) and ``sigma_r`` (m,) its standard
    uncertainty per axis (rad, NaN where no orientation); ``points`` is then the frame's origin. None: no row has one.

    ``sensor``: ``fixed`` (the device stands in the cell, the target rides on the robot) or ``flange`` (the device,
    an eye-in-hand camera, rides on the flange and the rows are the fixed target's pose in its frame; identify turns
    them round first: identify/sensors/flange.py). ``scale_sigma``: the relative standard uncertainty of the device's
    length scale when a reference fixed it (a camera's board measured with a caliper), None when nothing did.
    ``lens``: a camera's rows corrected with its final estimate of its board's shape and its lens, how each moves with
    that estimate's error, one draw shared by every row (:class:`LensShare`; None for every other device).
    """

    joint_types: str
    q: Array
    points: Array
    sweep: NDArray[np.int64]
    joint: NDArray[np.int64]
    sigma: Array | None = None
    check: NDArray[np.bool_] | None = None
    row: NDArray[np.int64] | None = None
    has_role: bool = False
    tp: NDArray[np.int64] | None = None
    coupling: Coupling | None = None
    t: Array | None = None
    streamed: NDArray[np.bool_] | None = None
    clock_offset: float = 0.0
    rotvec: Array | None = None
    sigma_r: Array | None = None
    sensor: str = "fixed"
    scale_sigma: float | None = None
    lens: LensShare | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "joint_types", check_joint_types(self.joint_types))
        m = len(self.points)
        if self.check is None:
            object.__setattr__(self, "check", np.zeros(m, dtype=bool))
        if self.row is None:
            object.__setattr__(self, "row", np.arange(1, m + 1))
        if self.tp is None:
            object.__setattr__(self, "tp", np.ones(m, dtype=np.int64))
        if self.streamed is None:
            object.__setattr__(self, "streamed", np.zeros(m, dtype=bool))
        if np.any(self.streamed) and (self.t is None or np.any(np.isnan(self.t[self.streamed]))):
            raise InputError("streamed rows need their time t (s): the fit interpolates the joints in time")

    @property
    def oriented(self) -> NDArray[np.bool_]:
        """Rows (m,) that measured an orientation as well as a position."""
        if self.rotvec is None:
            return np.zeros(len(self), dtype=bool)
        return np.all(np.isfinite(self.rotvec), axis=1)

    @property
    def has_streams(self) -> bool:
        """True when some rows were recorded in continuous motion."""
        return bool(np.any(self.streamed))

    @property
    def tp_ids(self) -> list[int]:
        """The tracked points' ids, ascending."""
        return [int(t) for t in np.unique(self.tp)]

    @property
    def n_joints(self) -> int:
        return len(self.joint_types)

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, mask: NDArray[np.bool_]) -> Measurements:
        """The rows where ``mask`` is true."""
        sigma = None if self.sigma is None else self.sigma[mask]
        return replace(
            self,
            q=self.q[mask],
            points=self.points[mask],
            sweep=self.sweep[mask],
            joint=self.joint[mask],
            sigma=sigma,
            check=self.check[mask],
            row=self.row[mask],
            tp=self.tp[mask],
            t=None if self.t is None else self.t[mask],
            streamed=self.streamed[mask],
            rotvec=None if self.rotvec is None else self.rotvec[mask],
            sigma_r=None if self.sigma_r is None else self.sigma_r[mask],
            lens=None if self.lens is None else self.lens.subset(mask),
        )

    def sweeps_of(self, joint: int) -> list[int]:
        """Sweep ids that move ``joint`` (1-based), in order of first appearance."""
        ids = self.sweep[self.joint == joint]
        _, first = np.unique(ids, return_index=True)
        return [int(ids[i]) for i in sorted(first)]


def validate(meas: Measurements, with_nominal: bool = False) -> list[str]:
    """Check that ``meas`` can be identified; raise InputError on the first fatal problem.

    Missing readings (NaN) are allowed for a sweep's moved joint (jogged by hand) or for a whole sweep row
    (positions only: the other joints stand at home). ``with_nominal``: a nominal model will start the fit,
    so joints without a sweep are allowed when there are free poses.
    Returns warnings (one line each) for problems that do not stop the identification.
    """
    n = meas.n_joints
    if meas.q.shape != (len(meas), n):
        raise InputError(f"joint readings have {meas.q.shape[1]} columns but the joint types say {n} joints")
    if not np.all(np.isfinite(meas.points)):
        bad = int(meas.row[~np.all(np.isfinite(meas.points), axis=1)][0])
        raise InputError(f"line {bad}: x, y, z must be finite numbers")
    if np.any(np.isinf(meas.q)):
        bad = int(meas.row[np.any(np.isinf(meas.q), axis=1)][0])
        raise InputError(f"line {bad}: joint readings must be finite")
    if meas.sigma is not None and not np.all(np.isfinite(meas.sigma) & (meas.sigma > 0)):
        bad = int(meas.row[~(np.isfinite(meas.sigma) & (meas.sigma > 0))][0])
        raise InputError(f"line {bad}: sigma must be a positive number (metres)")
    _validate_orientation(meas)
    if np.any((meas.joint < 0) | (meas.joint > n)):
        bad = int(meas.row[(meas.joint < 0) | (meas.joint > n)][0])
        raise InputError(f"line {bad}: joint must be 0 (free pose) or 1..{n}")
    for rows in _rows_by_sweep(meas):
        joints = np.unique(meas.joint[rows])
        if len(joints) > 1:
            raise InputError(f"sweep {meas.sweep[rows[0]]} mixes joints {joints.tolist()}; one sweep moves one joint")
    missing_q = np.isnan(meas.q)
    moved = np.zeros_like(missing_q)
    swept = meas.joint > 0
    moved[np.flatnonzero(swept), meas.joint[swept] - 1] = True
    positions_only = swept & np.all(missing_q, axis=1)  # nothing read: the other joints stand at home
    if np.any(missing_q & ~moved & ~positions_only[:, None]):
        bad = int(meas.row[np.any(missing_q & ~moved & ~positions_only[:, None], axis=1)][0])
        raise InputError(f"line {bad}: in a sweep, leave either the moved joint's reading or every reading empty; "
                         "a free pose needs every reading")
    warnings: list[str] = []
    fit = ~meas.check
    for j in range(1, n + 1):
        sweeps = [s for s in meas.sweeps_of(j) if np.any(fit & (meas.sweep == s))]
        if not sweeps:
            if with_nominal and np.any(fit & (meas.joint == 0)):
                continue  # free poses and a nominal model determine the joint without a sweep
            hint = "; or give a nominal model (--robot) to calibrate from free poses" if not with_nominal else ""
            raise InputError(f"joint {j} is never swept: every joint needs a sweep where it alone moves{hint}")
        for s in sweeps:
            count = int(np.sum(fit & (meas.sweep == s)))
            if count < MIN_SWEEP_SAMPLES:
                raise InputError(f"sweep {s} (joint {j}) has {count} samples; at least {MIN_SWEEP_SAMPLES} needed")
            if count < FEW_SWEEP_SAMPLES:
                warnings.append(f"sweep {s} (joint {j}) has only {count} samples; {FEW_SWEEP_SAMPLES}+ recommended")
    return warnings


def _validate_orientation(meas: Measurements) -> None:
    """InputError (one line) unless every row's orientation is whole (rx, ry, rz all given or all empty), has a
    positive ``sigma_r`` (rad), and the positions have their ``sigma`` (m): the two are weighed by their own."""
    if meas.rotvec is None:
        return
    given = np.isfinite(meas.rotvec)
    partial = np.any(given, axis=1) & ~np.all(given, axis=1)
    if np.any(partial) or np.any(np.isinf(meas.rotvec)):
        bad = int(meas.row[partial | np.any(np.isinf(meas.rotvec), axis=1)][0])
        raise InputError(f"line {bad}: give rx, ry, rz all three (finite, rad) or leave all three empty")
    oriented = meas.oriented
    if not np.any(oriented):
        return
    sigma_r = np.full(len(meas), np.nan) if meas.sigma_r is None else meas.sigma_r
    bad_sigma = oriented & ~(np.isfinite(sigma_r) & (sigma_r > 0))
    if np.any(bad_sigma):
        raise InputError(f"line {int(meas.row[bad_sigma][0])}: an orientation (rx, ry, rz) needs sigma_r, its "
                         "standard uncertainty per axis (a positive number of radians)")
    if meas.sigma is None:
        raise InputError("orientations (rx, ry, rz) need a sigma column too: positions (m) and orientations (rad) "
                         "are weighed by their own uncertainties, sigma and sigma_r")


def orientation_rows(meas: Measurements) -> tuple[Measurements, list[str]]:
    """The fit's rows: every row as a position row (``rotvec`` NaN), then each orientation as a row of its own
    (the same readings, ``rotvec`` set, ``sigma`` = its ``sigma_r``, rad), so that an orientation and its position
    are tested for outliers and weighed each on its own; and notes. A streamed orientation row keeps its position
    row's time ``t``: the fit's clock correction moves both (the joints' speed turns the frame as it moves the point).
    Orientations of rows with an unread joint are not used: the unread angle is estimated from the position alone
    (sharing it between a row's position and orientation is not implemented; see
    :class:`identify.estimator.poe.LineProblem`)."""
    oriented = meas.oriented
    if not np.any(oriented):
        return replace(meas, rotvec=None, sigma_r=None), []
    notes = []
    unusable = oriented & np.any(np.isnan(meas.q), axis=1)
    if np.any(unusable):
        notes.append(f"{int(unusable.sum())} orientation(s) of rows with an unread joint not used")
    extra = meas.subset(oriented & ~unusable)
    positions = replace(meas, rotvec=np.full((len(meas), 3), np.nan), sigma_r=None)
    extra = replace(extra, sigma=extra.sigma_r, sigma_r=None)
    joined = {name: np.concatenate([getattr(positions, name), getattr(extra, name)])
              for name in ("q", "points", "sweep", "joint", "sigma", "check", "row", "tp", "streamed", "rotvec")}
    t = None if meas.t is None else np.concatenate([meas.t, extra.t])
    return replace(meas, t=t, sigma_r=None, lens=None, **joined), notes


def prepared_joints(meas: Measurements, home: Array) -> tuple[Array, NDArray[np.int64]]:
    """Readings ready for the forward model, and the joint each row did not read.

    Joints held still in a positions-only sweep row take their ``home`` readings (n,); the moved joint of
    a row without its reading stays NaN and is named in ``unknown`` (0-based, -1 where every reading is
    known): the fit estimates it as a nuisance parameter.
    """
    q = meas.q.copy()
    unknown = np.full(len(q), -1, dtype=np.int64)
    swept = meas.joint > 0
    missing = np.isnan(q)
    held = missing & swept[:, None]
    held[np.flatnonzero(swept), meas.joint[swept] - 1] = False
    q = np.where(held, home[None, :], q)
    moved_missing = swept & missing[np.arange(len(q)), np.maximum(meas.joint - 1, 0)]
    unknown[moved_missing] = meas.joint[moved_missing] - 1
    return q, unknown


def looks_like_millimetres(points: Array) -> bool:
    """True when positions look like millimetres (robot-sized data spans tens of metres otherwise)."""
    return bool(np.max(np.abs(points)) > 20.0)


def _rows_by_sweep(meas: Measurements) -> list[NDArray[np.int64]]:
    order = np.argsort(meas.sweep, kind="stable")
    ids = meas.sweep[order]
    cuts = np.flatnonzero(np.diff(ids)) + 1
    return np.split(order, cuts)


MOVED_FRACTION = 0.1  # a joint moves in a sweep when its values span over this share of the widest span
STILL = 1e-4  # rad or m: a sweep whose joints all span less than this has not moved (repeated readings)


def in_dh_joints(meas: Measurements) -> tuple[Measurements, list[str]]:
    """``meas`` with DH joint values in ``q`` (its coupling applied, then dropped), and notes.

    A sweep must move one DH joint: the joints whose values span more than ``MOVED_FRACTION`` of the sweep's
    widest span. A sweep labelled with another joint than the one it moves is relabelled; one that moves
    several joints is an error without a coupling (it names the readings that move together), and is used
    as free poses with one (readings moved on the controller one at a time move several DH joints).
    """
    notes: list[str] = []
    coupling = meas.coupling
    q = meas.q if coupling is None else coupling.dh_from_readings(meas.q)
    if coupling is not None:
        bad = np.isnan(q) & ~np.isnan(meas.q)
        if np.any(bad):
            row = int(meas.row[np.any(bad, axis=1)][0])
            raise InputError(f"line {row}: an empty reading that the coupling mixes into other joints; with a "
                             "coupling, give every reading the coupling combines")
    joint = meas.joint.copy()
    for rows in _rows_by_sweep(meas):
        label = int(joint[rows[0]])
        if not 0 < label <= meas.n_joints or len(rows) < 2 or np.all(np.isnan(q[rows, label - 1])):
            continue  # free poses, or positions only / a moved joint never read: nothing to check
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns of unread joints
            span = np.nan_to_num(np.nanmax(q[rows], axis=0) - np.nanmin(q[rows], axis=0))
        if span.max() < STILL:
            continue
        moved = np.flatnonzero(span > MOVED_FRACTION * span.max())
        sweep = int(meas.sweep[rows[0]])
        if len(moved) == 1:
            if moved[0] + 1 != label:
                notes.append(f"sweep {sweep} is labelled joint {label} but moves joint {moved[0] + 1}: relabelled")
                joint[rows] = moved[0] + 1
            continue
        names = " and ".join(str(j + 1) for j in moved)
        if coupling is None:
            raise InputError(f"sweep {sweep} (joint {label}): the readings of joints {names} move together; if the "
                             "controller couples them (e.g. FANUC J2/J3), declare the coupling (--coupling FILE, "
                             "'coupling:' in the robot model or '# coupling:' in the CSV)")
        notes.append(f"sweep {sweep} moves DH joints {names} together (coupling): used as free poses")
        joint[rows] = 0
    return replace(meas, q=q, joint=joint, coupling=None), notes
