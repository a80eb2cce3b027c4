"""A session's measurements: the rows of a session file (session/) as the measurement CSV's rows, read at
identify's edge.

Stop-and-go steps (:func:`measurements_from`): one row per ok step and tracked point seen, q = the ACTUAL joint
readings, the averaged TP, the plan's sweep id, joint and role; home re-measurements become held-out free poses.
A camera's steps corrected for its board's shape and its lens are corrected again with the session's final estimate
(identify/sensors/recorrection.py).
A step whose readings carried no device sigma (an I++ server, a profile without one) has, in the session, the spread
of its own few readings as its sigma: 5 readings give 12 degrees of freedom, a figure off by 20 % either way, and a
fit that weighs rows by such figures as if known leans on the steps that happened to scatter little and finds a
chi-square inflated by ν/(ν−2) (1.2 for 12), so its model check warns on a model that is right (and a step of fewer
than 3 kept readings has none, which left the whole session without a sigma column). Those rows take the pooled
spread instead (:func:`pooled_spread`): the per-reading noise pooled over every such step of the session, over the
square root of the step's kept readings.
Streams (continuous motion, :func:`with_streams`): every complete, current attempt whose stream step is recorded
ok becomes rows: one per tracker sample (each tracked point), ``t`` its tracker time, ``q`` the joint stream
interpolated (linearly) at robot time ``t + clock_offset``, a full-pose device's orientation (``rotvec``,
``sigma_r``) where the sample has one; ``clock_offset`` is the coarse estimate of
:func:`identify.estimator.timing.coarse_clock_offset` over all the session's sweeps. Rows whose robot time lies outside
the recorded joint stream or within one sample of a joint-stream gap are dropped (counted).

Units: metres (positions, sigma), radians / metres (joint readings), seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from common import __version__
from common.errors import InputError
from common.outputs import OutputError, same_file, write_output
from identify.estimator.measurements import Measurements
from identify.estimator.timing import SweepStreams, coarse_clock_offset, interpolate_joints
from identify.io.csvio import CsvContent, format_measurements
from identify.sensors.metadata import UNKNOWN
from identify.sensors.recorrection import recorrected
from kinematics.joint_errors import Coupling
from session.records import FrameRecord, PointRecord
from session.rows import points_seen
from session.schema import SessionError
from session.store import SessionFile
from session.stream_data import StreamData


def open_session(path: Path) -> SessionFile:
    """An acquisition session, open for reading; InputError if it is not one."""
    try:
        return SessionFile.open(path)
    except SessionError as exc:
        raise InputError(str(exc)) from None


def read_session(path: Path) -> tuple[CsvContent, dict[str, Any]]:
    """The measurements of an acquisition session, and its header (with the plan's robot as ``robot_model``)."""
    with open_session(path) as session:
        if "verification" in (session.header.get("config") or {}):
            raise InputError(f"{path} is a verification session (acquire verify), not measurements to identify "
                             "from; its results are in the .verify.yaml and report beside it")
        try:
            header = {**session.header, "robot_model": session.plan.robot, "missing_steps": missing_steps(session)}
            return CsvContent(session_measurements(session), {"session": str(path)}, []), header
        except SessionError as exc:  # a record that does not read back; the file's own messages name it already
            text = str(exc)
            raise InputError(text if text.startswith(str(session.path)) else f"{path}: {text}") from None


def missing_steps(session: SessionFile) -> tuple[int, int, dict[str, int]]:
    """(steps recorded missing, steps in the plan, how many missing for each reason) of ``session``."""
    missing = [s for s in session.steps() if s.status == "missing"]
    reasons: dict[str, int] = {}
    for s in missing:
        reasons[s.reason] = reasons.get(s.reason, 0) + 1
    return len(missing), len(session.plan.steps), reasons


def session_measurements(session: SessionFile) -> Measurements:
    """The ok steps of ``session`` as measurement-CSV rows, in plan order: q = ACTUAL joint readings, points =
    averaged TP, one row per tracked point seen (``tp``: its id), ``coupling`` as the header records it; then, for
    a continuous session, the streamed rows (:func:`with_streams`).

    Sweeps and free poses keep the plan's sweep id, joint and role. Home re-measurements become free poses
    (joint 0) with role "check": held out, they validate the model at home and never bias the fit. Missing
    steps are skipped. ``sigma`` is given only when every exported row has one.
    """
    steps = _step_measurements(session)
    if not session.plan.continuous:
        return steps
    return with_streams(session.streams(), steps)[0]


def stream_summary(session: SessionFile) -> StreamSummary | None:
    """What :func:`with_streams` makes of ``session``'s streams (None without any)."""
    return with_streams(session.streams(), _step_measurements(session))[1]


def export_csv(session: SessionFile, path: str | Path, force: bool = False) -> int:
    """Write :func:`session_measurements` as the measurement CSV (with session, robot and tracker metadata lines);
    returns the number of rows. The file appears whole or not at all; an existing file is replaced only with
    ``force``, the session itself never (OutputError)."""
    path = Path(path)
    if same_file(path, session.path):
        raise OutputError(f"--csv {path} is the session {session.path}; an input is never overwritten")
    meas = session_measurements(session)
    if meas.coupling is not None and np.any(meas.coupling.offset):  # the CSV's coupling has no offset
        shift = np.linalg.solve(meas.coupling.matrix, meas.coupling.offset)
        meas = replace(meas, q=meas.q + shift, coupling=Coupling(meas.coupling.matrix, np.zeros(len(shift))))
    header = session.header
    metadata = {"session": str(session.path), "robot": _identity_line(header.get("robot", {})),
                "tracker": _identity_line(header.get("tracker", {})),
                "software": str(header.get("software", "")), "exported by": f"dh-calib {__version__}"}
    write_output(path, format_measurements(meas, metadata), force)
    return len(meas)


def _step_measurements(session: SessionFile) -> Measurements:
    rows, points = session.measured_rows()
    meas = measurements_from(rows, points, session.plan.joint_types, session.coupling, session.measured_frames())
    meas = replace(meas, **sensor_of(session.header))
    corrections = {(i, tp): c for i, mine in session.measured_corrections().items() for tp, c in mine}
    if corrections:  # a camera's readings corrected again with its final shape-and-lens estimate
        meas = recorrected(meas, [corrections.get((r["plan_index"], tp)) for r in rows
                                  for tp, _, _ in points_seen(r, points)])
    spread = session.spread_sigmas()
    if not spread:
        return meas
    kept = {(r["plan_index"], p.tp): p.samples for r in rows for p in points.get(r["plan_index"], [])}
    kept.update({(r["plan_index"], 1): r["samples"] for r in rows if r["plan_index"] not in points})
    seen = [((r["plan_index"], tp), sigma) for r in rows for tp, _, sigma in points_seen(r, points)]  # rows' order
    sigma = pooled_spread(np.array([np.nan if s is None else s for _, s in seen], dtype=float),
                          np.array([kept.get(k, 0) for k, _ in seen], dtype=float),
                          np.array([k in spread for k, _ in seen], dtype=bool))
    return replace(meas, sigma=None if np.any(np.isnan(sigma)) else sigma)


def sensor_of(header: dict[str, Any]) -> dict[str, Any]:
    """The device's ``sensor`` and ``scale_sigma`` as the session's tracker identity records them (a camera's
    ``mount`` and ``scale_sigma`` details: drivers/camera/tracker.py): a camera's scale, on the flange or in the
    cell, is its printed target's, unknown unless the target was measured; another device's is its own."""
    details = (header.get("tracker") or {}).get("details") or {}
    sensor = "flange" if details.get("mount") == "flange" else "fixed"
    given = str(details.get("scale_sigma") or "")
    scale = float(given) if given else (UNKNOWN if "mount" in details else None)
    return {"sensor": sensor, "scale_sigma": scale}


def pooled_spread(sigma: np.ndarray, samples: np.ndarray, estimated: np.ndarray) -> np.ndarray:
    """Rows' ``sigma`` (m per axis, of their average; NaN: none) with those ``estimated`` from their own readings'
    spread replaced by the pooled per-reading noise over sqrt(``samples`` kept) (module doc): each row of at least 2
    readings contributes its per-reading variance ``samples · sigma²`` weighed by its 3 (samples − 1) degrees of
    freedom; a row of fewer (no spread of its own, no sigma) takes the pooled figure too. Unchanged when no row
    contributes."""
    pool = estimated & (samples >= 2) & np.isfinite(sigma)
    if not pool.any():
        return sigma
    dof = 3.0 * (samples[pool] - 1.0)
    per_reading = float(np.sum(dof * samples[pool] * sigma[pool] ** 2) / np.sum(dof))
    take = estimated & (samples >= 1)
    out = sigma.copy()
    out[take] = np.sqrt(per_reading / samples[take])
    return out


def measurements_from(rows: list[dict[str, Any]], points: dict[int, list[PointRecord]], joint_types: str,
                      coupling: Coupling | None, frames: dict[int, list[FrameRecord]] | None = None) -> Measurements:
    """The measurement-CSV rows of ok step ``rows`` (plan order): one row per tracked point seen, q = the actual
    readings, ``coupling`` as recorded. Home re-measurements become held-out free poses (joint 0, role check);
    ``sigma`` only when every row has one; ``tp`` the point's id; with a full-pose device the target frame's averaged
    orientation (``frames``: plan index -> per point) as ``rotvec``/``sigma_r`` (NaN for a row without one)."""
    entries = [(r, *seen) for r in rows for seen in points_seen(r, points)]
    n, m = len(joint_types), len(entries)
    q = np.array([r["q_act"] for r, *_ in entries], dtype=float).reshape(m, n)
    xyz = np.array([p for _, _, p, _ in entries], dtype=float).reshape(m, 3)
    home = np.array([r["kind"] == "home" for r, *_ in entries], dtype=bool)
    joint = np.where(home, 0, np.array([r["joint"] for r, *_ in entries], dtype=np.int64)).astype(np.int64)
    sweep = np.array([r["sweep"] for r, *_ in entries], dtype=np.int64)
    check = home | np.array([r["role"] == "check" for r, *_ in entries], dtype=bool)
    sigmas = [s for *_, s in entries]
    sigma = np.array(sigmas, dtype=float) if entries and None not in sigmas else None
    tp = np.array([t for _, t, _, _ in entries], dtype=np.int64)
    rotvec = sigma_r = None
    if frames:
        turned = {(i, f.tp): f for i, seen in frames.items() for f in seen}
        found = [turned.get((r["plan_index"], t)) for r, t, _, _ in entries]
        rotvec = np.array([f.rotvec if f else (np.nan,) * 3 for f in found], dtype=float).reshape(m, 3)
        sigma_r = np.array([np.nan if f is None or f.sigma_r is None else f.sigma_r for f in found], dtype=float)
    return Measurements(joint_types, q, xyz, sweep, joint, sigma, check, has_role=True, tp=tp, coupling=coupling,
                        rotvec=rotvec, sigma_r=sigma_r)


@dataclass(frozen=True)
class StreamSummary:
    """What the export did with the streams: the clock offset (s, robot = tracker + offset) and each sweep's own
    estimate, tracker rows kept and dropped (outside the joint stream or at a joint-stream gap), gaps seen."""

    clock_offset: float
    per_sweep: tuple[float, ...]
    kept: int
    dropped: int
    gaps: int

    def line(self) -> str:
        spread = np.array(self.per_sweep, dtype=float)
        spread = spread[np.isfinite(spread)]
        span = f" (sweeps {1e3 * spread.min():.2f} .. {1e3 * spread.max():.2f} ms)" if spread.size > 1 else ""
        return (f"streams: {self.kept} streamed rows, {self.dropped} dropped (outside the joint stream or at one of "
                f"{self.gaps} gaps); coarse clock offset {1e3 * self.clock_offset:.2f} ms{span}")


def with_streams(streams: list[StreamData], steps: Measurements) -> tuple[Measurements, StreamSummary | None]:
    """``steps`` (the stop-and-go rows) followed by the streamed rows of the session's current ``streams``
    (:meth:`session.store.SessionFile.streams`; module docstring), with the session's coarse clock offset; the
    summary is None when there is no stream to read."""
    streams = [s for s in streams if len(s.t) and len(s.t_joint) >= 2]
    if not streams:
        return steps, None
    first = [s.tp == s.tp.min() for s in streams]
    estimate = coarse_clock_offset([SweepStreams(s.t[k], s.points[k], s.t_joint, s.q_joint)
                                    for s, k in zip(streams, first, strict=True)])
    offset = estimate.offset
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("q", "points", "sweep", "joint", "sigma", "tp", "t",
                                                          "rotvec", "sigma_r")}
    dropped = 0
    for s in streams:
        q, ok = interpolate_joints(s.t_joint, s.q_joint, s.t + offset, s.joint_gaps)
        dropped += int((~ok).sum())
        parts["q"].append(q[ok])
        parts["points"].append(s.points[ok])
        parts["sweep"].append(np.full(int(ok.sum()), s.sweep, dtype=np.int64))
        parts["joint"].append(np.full(int(ok.sum()), s.joint, dtype=np.int64))
        parts["sigma"].append(s.sigma[ok])
        parts["tp"].append(s.tp[ok])
        parts["t"].append(s.t[ok])
        parts["rotvec"].append(np.full((int(ok.sum()), 3), np.nan) if s.rotvec is None else s.rotvec[ok])
        parts["sigma_r"].append(np.full(int(ok.sum()), np.nan) if s.sigma_r is None else s.sigma_r[ok])
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    m0, m1 = len(steps), len(cat["t"])
    sigma = None
    if steps.sigma is not None or m0 == 0:
        joined = np.concatenate([steps.sigma if steps.sigma is not None else np.zeros(0), cat["sigma"]])
        sigma = None if np.any(np.isnan(joined)) else joined
    t_steps = steps.t if steps.t is not None else np.full(m0, np.nan)
    meas = replace(steps, q=np.vstack([steps.q, cat["q"]]), points=np.vstack([steps.points, cat["points"]]),
                   sweep=np.concatenate([steps.sweep, cat["sweep"]]), joint=np.concatenate([steps.joint, cat["joint"]]),
                   sigma=sigma, check=np.concatenate([steps.check, np.zeros(m1, dtype=bool)]),
                   row=np.arange(1, m0 + m1 + 1), tp=np.concatenate([steps.tp, cat["tp"]]),
                   t=np.concatenate([t_steps, cat["t"]]),
                   streamed=np.concatenate([np.zeros(m0, bool), np.ones(m1, bool)]),
                   clock_offset=offset, **_orientations(steps, cat["rotvec"], cat["sigma_r"]))
    gaps = sum(len(s.joint_gaps) + len(s.tracker_gaps) for s in streams)
    return meas, StreamSummary(offset, estimate.per_sweep, m1, dropped, gaps)


def _orientations(steps: Measurements, rotvec: np.ndarray, sigma_r: np.ndarray) -> dict[str, np.ndarray | None]:
    """``rotvec`` and ``sigma_r`` of the stop-and-go ``steps`` followed by the streamed rows' (NaN: a position only);
    None for both when no row has an orientation (positions-only data stay exactly as they were)."""
    if steps.rotvec is None and not np.any(np.isfinite(rotvec)):
        return {"rotvec": None, "sigma_r": None}
    m0 = len(steps)
    given = steps.rotvec if steps.rotvec is not None else np.full((m0, 3), np.nan)
    given_r = steps.sigma_r if steps.sigma_r is not None else np.full(m0, np.nan)
    return {"rotvec": np.vstack([given, rotvec]), "sigma_r": np.concatenate([given_r, sigma_r])}


def _identity_line(identity: dict[str, Any]) -> str:
    parts = [str(identity.get("model", ""))]
    if identity.get("serial"):
        parts.append(f"serial {identity['serial']}")
    if identity.get("firmware"):
        parts.append(f"firmware {identity['firmware']}")
    return " ".join(" ".join(parts).split())
