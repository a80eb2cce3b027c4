"""The verification run's analysis (pure): the ISO 9283 figures of a finished (or partial) ``acquire verify`` session,
with their uncertainties, and the verdict (the plan: :mod:`acquire.verification.verify`).

The tracker is registered first on the session's own registration steps (:func:`register`); every measured point
is then taken into the calibration's tracker frame and through the identified base into the robot's base frame.
Per mode (before / after) and pose:

- AP, RP (7.2.1, 7.2.2), AD, RD between P2 and P4 (7.3) and the drift of P1 within the run (7.6) from the visits
  approached from the first direction (+x), as the standard's one-directional test;
- vAP (7.2) from the barycentres of the visits from the three directions (sessions planned before the test had
  approach directions have one, and no vAP);
- orientation AP and RP (7.2.1, 7.2.2; a, b, c about the base's x, y, z) from full-pose readings when the calibration
  measured the target frame (the result's ``tool_frame``) and the tracker reads it (a 6-DoF probe, a camera's
  board): each visit's attained orientation is the measured frame taken into the base frame, the commanded one the
  flange orientation the test commands times ``tool_frame``. Otherwise from three or more tracked points on the tool
  that the result knows and the tracker saw: each visit's attained orientation is the rigid fit of the points the
  commanded pose (the target's position and the flange orientation the test commands) puts them at to the measured
  ones. Either way the deviation is R_attained R_commandedᵀ as rotations about the base's fixed x, y, z axes.

Uncertainty of every figure: Monte-Carlo (:func:`identify.applications.iso9283.monte_carlo`, 400 synthetic repeats of
the cycles, each visit redrawn with the spread of its pose's visits pooled with the run's other poses and the tracker's
stated noise: :func:`identify.applications.iso9283.spread_covariances`), combined
in quadrature with the registration's (linearised, :func:`registration_covariance`) for the figures it moves: AP
(its 3D variance at the pose over 3, along AP's direction) and orientation AP (its rotation's variance about each
base axis). RP, AD, RD, vAP and drift are differences within the run: a registration error cancels in them.

Units: m, rad, s. Frames: base (DH frame 0) unless said otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from acquire.verification.verify import AFTER_ALARM, DISTANCE_POSES, MODES, REGISTER
from identify.applications.holds import MIN_POSES, ModelCheck, check_models, tabulated
from identify.applications.iso9283 import (
    FROM_FRAMES,
    FROM_POINTS,
    Accuracy,
    Distance,
    Drift,
    accuracy,
    deviation_angles,
    directions_result,
    distance_result,
    drift,
    monte_carlo,
    orientation_result,
)

Array = NDArray[np.float64]
MIN_POINTS = 3  # tracked points on the tool that give an orientation
UNCERTAINTY = ("standard uncertainty: Monte-Carlo over the cycles (400 repeats from the visits' spread, pooled over "
               "the poses, and the tracker's noise), with the registration's for AP and orientation AP")
ISO_DRIFT_HOURS = 8


@dataclass(frozen=True)
class Outcome:
    """The measured figures per mode (``runs``; a mode with no complete pose is absent), the verdict
    (pass | warn | fail | incomplete) and the line that says why, with numbers; ``registration``: the check that
    registered the tracker (None for a session planned without registration poses); ``duration``: s from the first
    measurement to the last; ``orientation``: why orientation was not measured (None: it was);
    ``orientation_source``: what it was measured from (:data:`FROM_FRAMES` or :data:`FROM_POINTS`), else None."""

    runs: dict[str, Accuracy]
    status: str
    message: str
    missing: int
    registration: ModelCheck | None = None
    duration: float = 0.0
    orientation: str | None = None
    orientation_source: str | None = None

    @property
    def drift_note(self) -> str:
        """One line: the drift figures are within this run, not ISO 9283's 8-hour test."""
        return (f"drift (7.6) is measured within this run of {_hours(self.duration)} only; ISO 9283 measures it "
                f"over {ISO_DRIFT_HOURS} h of cycling, which this test does not")

    def as_dict(self, info: dict[str, Any]) -> dict[str, Any]:
        out = {"verdict": {"status": self.status, "message": self.message}}
        if self.registration is not None:
            r = self.registration
            out["registration"] = {"model": r.name, "poses": r.heldout.samples, "moved": r.registration.moved,
                                   "turned_deg": math.degrees(r.registration.turned), "heldout_rms": r.heldout.rms,
                                   "heldout_max": r.heldout.max, "expected_rms": r.expected, "ratio": r.ratio,
                                   "status": r.status, "reasons": r.reasons}
        return {**out, "runs": {m: a.as_dict() for m, a in self.runs.items()}, "missing_steps": self.missing,
                "predicted": info["predicted"], "expected": info["expected"], "targets": info["targets"],
                "result": info["result"], "result_sha256": info.get("result_sha256"), "cycles": info["cycles"],
                "edge": info["edge"], "centre": info["centre"],
                "before_model": info.get("before_model", "nominal model"), "duration_s": self.duration,
                "drift_note": self.drift_note, "uncertainty": UNCERTAINTY,
                "orientation": {"measured": self.orientation is None, "reason": self.orientation,
                                "source": self.orientation_source},
                "domain": info.get("domain")}


def _hours(seconds: float) -> str:
    """A duration as people say it: 45 s, 12 min, 1 h 05 min."""
    if seconds < 60:
        return f"{seconds:.0f} s"
    minutes = round(seconds / 60.0)
    return f"{minutes} min" if minutes < 60 else f"{minutes // 60} h {minutes % 60:02d} min"


def register(info: dict[str, Any], records: list[Any]) -> ModelCheck | str:
    """Register the tracker on the session's registration steps (``identify check``'s fit of the recommended
    model's predictions stored in ``info["register"]``); the check, or why it cannot be made (one line)."""
    reg = info["register"]
    rows = [r for r in records if r.status == "ok" and info["steps"][r.plan_index][0] == REGISTER]
    if len(rows) < MIN_POSES:
        return f"{len(rows)} of {len(reg['q'])} registration poses measured: at least {MIN_POSES} are needed"
    pose = np.array([info["steps"][r.plan_index][2] - 1 for r in rows])
    predicted = np.array(reg["predicted"], dtype=float)[pose]
    model = tabulated(reg["model"], predicted, float(reg["expected"]))
    points = np.array([r.position for r in rows], dtype=float)
    q = np.array(reg["q"], dtype=float)[pose]
    return check_models(points, q, np.ones(len(rows), dtype=np.int64), [model]).chosen


@dataclass
class _Visits:
    """One mode's measurements: positions per (pose, direction), their cycles and sigmas; orientation deviations
    (rad) per pose (first direction); the tracker's noise on them."""

    positions: dict[tuple[int, int], list[Array]]
    cycles: dict[tuple[int, int], list[int]]
    sigmas: dict[tuple[int, int], list[float]]
    angles: dict[int, list[Array]]
    angle_noise: list[float]


def _orientation_setup(info: dict[str, Any]) -> tuple[dict[int, Array] | None, str | None]:
    """The tools (tp -> flange frame vector, m; empty when only the target frame can give it) when orientation can
    be measured, else None and why."""
    tools = {int(k): np.array(v, dtype=float) for k, v in (info.get("tools") or {}).items()}
    if info.get("rotation") is None:
        return None, "the arm has fewer than six joints: the test commands no orientation"
    if len(tools) < MIN_POINTS and info.get("tool_frame") is None:
        return None, (f"the result knows {_points(max(len(tools), 1))} on the tool and no target frame; orientation "
                      f"needs a full-pose target (6-DoF probe, camera board) or {MIN_POINTS} or more points "
                      "(calibrate with one of them)")
    return tools, None


def _points(n: int) -> str:
    return f"{n} tracked point{'s' if n != 1 else ''}"


def _collect(info: dict[str, Any], records: list[Any], to_base: Any, turn_to_base: Any,
             tools: dict[int, Array] | None) -> tuple[dict[str, _Visits], int, int]:
    """Every mode's visits in the base frame; the most tracked points seen at a visit; the visits whose orientation
    came from a full-pose reading (``turn_to_base``: tracker-frame rotation (3, 3) -> base frame)."""
    targets = np.array(info["targets"], dtype=float)
    rotation = None if info.get("rotation") is None else np.array(info["rotation"], dtype=float)
    tool = np.array(info.get("tool") or [0.0, 0.0, 0.0], dtype=float)
    frame = None if info.get("tool_frame") is None else np.array(info["tool_frame"], dtype=float)
    visits = {m: _Visits({}, {}, {}, {}, []) for m in MODES}
    most = full = 0
    for record in records:
        label = info["steps"][record.plan_index]
        if record.status != "ok" or label[0] not in MODES:
            continue
        mode, cycle, pose = label[0], int(label[1]), int(label[2])
        key = (pose, int(label[3]) if len(label) > 3 else 1)
        v = visits[mode]
        v.positions.setdefault(key, []).append(to_base(np.array(record.position, dtype=float)))
        v.cycles.setdefault(key, []).append(cycle)
        if record.sigma is not None:
            v.sigmas.setdefault(key, []).append(record.sigma)
        seen = record.positions()
        most = max(most, len(seen))
        if key[1] != 1 or tools is None or rotation is None:
            continue
        reading = _frame_reading(record, frame)
        if reading is not None:  # the target frame measured: its own orientation, no rigid fit needed
            attained = turn_to_base(Rotation.from_rotvec(reading.rotvec).as_matrix())
            v.angles.setdefault(pose, []).append(Rotation.from_matrix(attained @ (rotation @ frame).T).as_euler("xyz"))
            if reading.sigma_r is not None:
                v.angle_noise.append(reading.sigma_r)
            full += 1
            continue
        common = sorted(set(seen) & set(tools))
        if len(common) < MIN_POINTS:
            continue
        flange = targets[pose - 1] - rotation @ tool
        commanded = np.array([flange + rotation @ tools[t] for t in common])
        measured = np.array([to_base(np.array(seen[t][0], dtype=float)) for t in common])
        v.angles.setdefault(pose, []).append(deviation_angles(commanded, measured))
        sig = [s for t in common if (s := seen[t][1]) is not None]
        if sig:  # the best-determined axis of the fit: noise over the root of the plate's largest moment
            r = commanded - commanded.mean(axis=0)
            moment = np.sum(r**2) * np.eye(3) - r.T @ r
            v.angle_noise.append(float(np.mean(sig)) / math.sqrt(float(np.linalg.eigvalsh(moment)[-1])))
    return visits, most, full


def _frame_reading(record: Any, frame: Array | None) -> Any:
    """The record's averaged orientation of the tracked point whose position it gives (the first seen: the one the
    result's ``tool`` and ``tool_frame`` describe), or None (no full-pose reading, or no ``frame`` to compare)."""
    if frame is None or not record.frames:
        return None
    first = record.points[0].tp if record.points else 1
    return next((f for f in record.frames if f.tp == first), None)


def _run(mode: str, targets: Array, positions: dict[Any, Array], v: _Visits, angles: dict[Any, Array]) -> Accuracy:
    """The run's figures from ``positions`` per (pose, direction) and orientation ``angles`` per pose (the
    measured ones, or a Monte-Carlo repeat of them); cycles and sigmas from ``v``."""
    first = {p: x for (p, h), x in positions.items() if h == 1}
    sigma = {p: np.array(v.sigmas[(p, 1)]) for p in first if len(v.sigmas.get((p, 1), [])) == len(first[p])}
    acc = accuracy(mode, targets, first, sigma)
    if not acc.poses:
        return acc
    by_cycle = {p: dict(zip(v.cycles[(p, 1)], first[p], strict=True)) for p in DISTANCE_POSES if p in first}
    directions = tuple(directions_result(p, [positions[(p, h)] for h in sorted(h for q, h in positions if q == p)])
                       for p in sorted(first) if sum(q == p for q, _ in positions) >= 2)
    orientation = tuple(orientation_result(p, a) for p, a in sorted(angles.items()) if len(a) >= 2)
    return replace(acc, distance=_distance(targets, by_cycle), drift=_drift(targets, first, sigma),
                   directions=directions, orientation=orientation)


def _figures(mode: str, targets: Array, v: _Visits, positions: dict[Any, Array], angles: dict[Any, Array]
             ) -> Accuracy:
    """The run's figures with the Monte-Carlo uncertainty of each (without the registration's share)."""
    run = _run(mode, targets, positions, v, angles)
    if not run.poses:
        return run
    sets = {**{("x", k): x for k, x in positions.items()}, **{("abc", p): a for p, a in angles.items()}}
    noise = {("x", k): float(np.mean(v.sigmas[k])) for k in positions if v.sigmas.get(k)}
    noise |= {("abc", p): float(np.mean(v.angle_noise)) for p in angles if v.angle_noise}

    def figures(s: dict[Any, Array]) -> dict[str, float]:
        return _run(mode, targets, {k[1]: x for k, x in s.items() if k[0] == "x"}, v,
                    {k[1]: a for k, a in s.items() if k[0] == "abc"}).figures()

    groups = {k: k[0] for k in sets}  # the positions of all poses pooled, the orientations of all poses pooled
    return replace(run, uncertainty=monte_carlo(figures, sets, noise, seed=MODES.index(mode), groups=groups))


def analyse(info: dict[str, Any], records: list[Any]) -> Outcome:
    """Every figure per mode from the session's step ``records`` (ok ones, positions in the tracker frame) and its
    ``verification`` header ``info`` (module docstring); the verdict compares "after" with what the result
    predicts."""
    base = np.array(info["base"], dtype=float)
    inv_r, shift = base[:3, :3].T, base[:3, 3]
    check = register(info, records) if "register" in info else None
    missing = sum(1 for r in records if r.status != "ok")
    times = [t for r in records if r.status == "ok" for t in (r.t_start, r.t_end)]
    duration = max(times) - min(times) if times else 0.0
    if isinstance(check, str):
        return Outcome({}, "incomplete", f"{check}: resume the session", missing, None, duration)
    registration = None if check is None else check.registration

    def to_base(x: Array) -> Array:
        return inv_r @ ((x if registration is None else registration.to_calibration(x)) - shift)

    def turn_to_base(r: Array) -> Array:
        return inv_r @ (r if registration is None else registration.rotation.T @ r)

    tools, why = _orientation_setup(info)
    targets = np.array(info["targets"], dtype=float)
    visits, most, full = _collect(info, records, to_base, turn_to_base, tools)
    source = None
    if why is None and full:
        source = FROM_FRAMES
    elif why is None and most >= MIN_POINTS and len(tools or {}) >= MIN_POINTS:
        source = FROM_POINTS
    elif why is None:
        why = f"the tracker saw {_points(max(most, 1))} per visit; orientation needs {MIN_POINTS} or more"
        if info.get("tool_frame") is not None:
            why = (f"the tracker read no orientation of the target frame and saw {_points(max(most, 1))} per visit; "
                   f"orientation needs a full-pose reading or {MIN_POINTS} or more points")
    reg_var, reg_rot = np.zeros(5), np.zeros((3, 3))
    if check is not None:
        fitted = np.array(info["register"]["predicted"], dtype=float)
        centre, cov = registration_covariance(fitted, check.expected)
        reg_var = _carried(cov, targets @ base[:3, :3].T + shift - centre)
        reg_rot = base[:3, :3].T @ cov[:3, :3] @ base[:3, :3]  # about the base's axes
    runs = {}
    for mode in MODES:
        v = visits[mode]
        run = _figures(mode, targets, v, {k: np.array(x) for k, x in v.positions.items()},
                       {p: np.array(a) for p, a in v.angles.items()} if why is None else {})
        if run.poses:
            runs[mode] = replace(run, uncertainty=_with_registration(run.uncertainty, reg_var, reg_rot))
    status, message = _verdict(runs, info, reg_var)
    if check is not None and check.status == "fail":
        status, message = "fail", (
            f"registered on {check.heldout.samples} poses of its own, the result's {check.name} model still misses "
            f"by {check.heldout.rms * 1e3:.3f} mm RMS (held out), {check.ratio:.1f}x the {check.expected * 1e3:.3f} "
            "mm it predicts: another arm or another tool than the calibration's, or an error its model does not "
            "hold (play in the joints, a warm arm); do not use this model here")
    return Outcome(runs, status, message, missing, check, duration, why, source)


def _with_registration(u: dict[str, float], var: Array, rot: Array) -> dict[str, float]:
    """The Monte-Carlo uncertainties with the registration's added where it counts (module docstring)."""
    out = dict(u)
    for name in u:
        figure, _, pose = name.partition(" P")
        if figure == "ap":
            out[name] = math.sqrt(u[name] ** 2 + var[int(pose) - 1] / 3.0)
        elif figure in ("ap_a", "ap_b", "ap_c"):
            out[name] = math.sqrt(u[name] ** 2 + rot["abc".index(figure[-1]), "abc".index(figure[-1])])
    return out


def _distance(targets: Array, by_cycle: dict[int, dict[int, Array]]) -> Distance | None:
    """AD and RD between P2 and P4 (ISO 9283's pair for 7.3) over the cycles that measured both."""
    a, b = (by_cycle.get(p, {}) for p in DISTANCE_POSES)
    common = sorted(set(a) & set(b))
    if len(common) < 2:
        return None
    return distance_result(*DISTANCE_POSES, targets[DISTANCE_POSES[0] - 1], targets[DISTANCE_POSES[1] - 1],
                           np.array([a[c] for c in common]), np.array([b[c] for c in common]))


def _drift(targets: Array, attained: dict[int, Array], sigma: dict[int, Array]) -> Drift | None:
    """dAP and dRP of P1 over the run (first against last third of its visits), when it has 4 visits or more."""
    visits = attained.get(1, [])
    return drift(1, targets[0], np.array(visits), sigma.get(1)) if len(visits) >= 4 else None


def registration_covariance(fitted: Array, expected: float) -> tuple[Array, Array]:
    """The linearised covariance (6, 6) of a rigid registration on the points ``fitted`` (k, 3) when each misses by
    ``expected`` (3D RMS, m; isotropic): sigma² (Σ J_iᵀ J_i)⁻¹, J = [-[x]×, I] about the points' centroid (returned
    with it); the first three parameters are the small rotation (rad), the last three the shift (m)."""
    centre = fitted.mean(axis=0)  # any origin gives the same answer; the centroid keeps the system well scaled
    normal = sum(_jacobian(x - centre).T @ _jacobian(x - centre) for x in fitted)
    return centre, expected**2 / 3.0 * np.linalg.inv(normal)


def _jacobian(x: Array) -> Array:
    skew = np.array([[0.0, x[2], -x[1]], [-x[2], 0.0, x[0]], [x[1], -x[0], 0.0]])  # -[x]x
    return np.hstack([skew, np.eye(3)])


def _carried(cov: Array, at: Array) -> Array:
    return np.array([np.trace(_jacobian(x) @ cov @ _jacobian(x).T) for x in at])


def registration_variance(fitted: Array, at: Array, expected: float) -> Array:
    """Variance (m², 3D) a rigid registration on the points ``fitted`` (k, 3) adds to positions ``at`` (m, 3), both
    in one frame, when each fitted point misses by ``expected`` (3D RMS, m; isotropic): the linearised fit's
    covariance (:func:`registration_covariance`) carried to each position."""
    centre, cov = registration_covariance(fitted, expected)
    return _carried(cov, np.asarray(at, dtype=float) - centre)


def _verdict(runs: dict[str, Accuracy], info: dict[str, Any], registration: Array) -> tuple[str, str]:
    """pass: every pose's "after" AP within what the result's uncertainty, the measurement's spread and the
    registration (``registration``: its variance at each pose, m²) allow (chi-square, 3 degrees of freedom, 0.1 %
    false alarms); warn: beyond that but better than "before"; fail: not
    better; incomplete: a run or a pose missing."""
    if set(runs) != set(MODES) or any(len(a.poses) < 5 for a in runs.values()):
        return "incomplete", "not every pose of both runs has 2 or more measurements: resume the session"
    before, after = runs["before"], runs["after"]
    expected = np.array(info["expected"], dtype=float)
    scale = chi2.ppf(1 - AFTER_ALARM, 3) / 3  # a 3D error's square over its mean square, at the alarm rate
    limits = [math.sqrt(scale * (e**2 + 3 * p.ap_std**2 + r))
              for e, p, r in zip(expected, after.poses, registration, strict=True)]
    worst = max(range(5), key=lambda k: after.poses[k].ap / limits[k])
    summary = (f"AP before {before.ap * 1e3:.4f} mm, after {after.ap * 1e3:.4f} mm (worst pose); RP before "
               f"{before.rp * 1e3:.4f} mm, after {after.rp * 1e3:.4f} mm")
    p = after.poses[worst]
    if all(a.ap <= lim for a, lim in zip(after.poses, limits, strict=True)):
        return "pass", f"{summary}: every pose within what the result predicts (P{p.pose}: {p.ap * 1e3:.4f} mm " \
                       f"<= {limits[worst] * 1e3:.4f} mm)"
    if after.ap < before.ap:
        return "warn", f"{summary}: better than before, but P{p.pose} misses by {p.ap * 1e3:.4f} mm, more than the " \
                       f"{limits[worst] * 1e3:.4f} mm the result's uncertainty allows: the model holds less than it " \
                       "claims (recalibrate, or check the tool and the mounting)"
    return "fail", f"{summary}: compensation does not improve the arm: do not use this model"
