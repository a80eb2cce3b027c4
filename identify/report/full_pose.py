"""The report's full-pose section (6-DoF probes, camera targets): the orientation rows' residuals against their
stated ``sigma_r``, per sweep and as a figure, and which of the wrist's parameters the data determine, with their
uncertainties beside what the same poses would give from positions alone.

The orientation rows of a fit follow its position rows (:func:`identify.estimator.measurements.orientation_rows`):
one per fitted sample that measured the target frame, in the fit rows' order; their residuals are rotation vectors
``log(R_predicted R_measuredᵀ)`` (rad, tracker frame). The positions-only comparison is the Cramér-Rao bound
(:func:`identify.estimator.bounds.full_pose_jacobian`) at the same poses and noise, over the same free parameters.
Units on the page: mrad, mm, deg.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from numpy.typing import NDArray

from identify.estimator.bounds import RCOND, full_pose_jacobian
from identify.estimator.dh_vector import dh_index
from identify.estimator.measurements import Measurements
from identify.results.pipeline import Identification
from kinematics.dh import DH_NAMES

Array = NDArray[np.float64]
MRAD = 1e3
WRIST = 3  # the last three joints are the wrist
_SCALE = {"theta": 180.0 / np.pi, "d": 1e3, "a": 1e3, "alpha": 180.0 / np.pi}
_UNIT = {"theta": "deg", "d": "mm", "a": "mm", "alpha": "deg"}
LOADING = 1e-3  # a parameter whose share of an undetermined direction exceeds this is not determined


def turning_rows(fit: Measurements) -> NDArray[np.bool_]:
    """The fitted rows whose orientation the fit used (measured, every joint read), in fit order."""
    return fit.oriented & np.all(np.isfinite(fit.q), axis=1)


def full_pose_section(ident: Identification, fit: Measurements, escape: Callable[[Any], str],
                      table: Callable[..., str], figure_html: Callable[[Figure, str], str]) -> str:
    """The section's HTML ('' without orientation rows): ``ident`` with its orientation rows (not the positions
    view), ``fit`` its fitted rows; the page's own ``escape``, ``table`` and ``figure_html`` (identify.report.html)
    build it."""
    if ident.orientation is None:
        return ""
    turning = turning_rows(fit)
    count = int(ident.orientation[0])
    ref = ident.refinement
    if count != int(turning.sum()) or count > len(ref.residuals):
        return ""  # measurements of another shape: report_html refuses them elsewhere
    residuals, kept = ref.residuals[-count:], ref.inliers[-count:]
    sigma_r = fit.sigma_r[turning]
    sweeps, joints = fit.sweep[turning], fit.joint[turning]
    rows = []
    for s in np.unique(sweeps):
        here = sweeps == s
        good = here & kept
        rms = float(np.sqrt(np.mean(np.sum(residuals[good] ** 2, axis=1)))) if good.any() else float("nan")
        chi = float(np.mean(np.sum((residuals[good] / sigma_r[good, None]) ** 2, axis=1)) / 3) if good.any() else \
            float("nan")
        joint = int(joints[here][0])
        rows.append([str(int(s)), "free" if joint == 0 else str(joint), str(int(here.sum())),
                     str(int(np.sum(here & ~kept))), f"{rms * MRAD:.4f}", f"{np.median(sigma_r[here]) * MRAD:.4f}",
                     f"{chi:.2f}"])
    chi_all = float(np.mean(np.sum((residuals[kept] / sigma_r[kept, None]) ** 2, axis=1)) / 3)
    parts = ['<section id="full-pose"><h2>Orientations and the wrist</h2>',
             f"<p>{count} orientations of the target frame fitted beside the positions, "
             f"{int(np.sum(~kept))} rejected as outliers. Each residual is the rotation vector of "
             "R_predicted · R_measuredᵀ (tracker frame), weighed by its sigma_r; reduced chi-square of the kept "
             f"ones against their sigma_r: {chi_all:.2f} (1 when the stated sigma_r is honest; the fit's share of "
             "the residuals makes it a little less).</p>",
             table(["sweep", "joint", "orientations", "rejected", "RMS [mrad, 3D]", "sigma_r [mrad]",
                     "reduced chi²"], rows),
             figure_html(figure_orientations(residuals, kept, sweeps, joints, sigma_r),
                          "Orientation residual of every fitted sample, per sweep")]
    held = ident.validations.get(ident.use)
    turns = None if held is None else held.orientation
    if turns is not None:
        parts.append(f"<p>Held out: {turns.samples} orientations predicted from the written numbers (DH table and "
                     f"tool_frame), RMS {turns.rms * MRAD:.4f} mrad (3D), max {turns.max * MRAD:.4f} mrad; expected "
                     f"{turns.expected * MRAD:.4f} mrad (the model's uncertainty there, {turns.bound * MRAD:.4f} "
                     "mrad, and the readings' sigma_r).</p>")
    stated = None if fit.sigma is None else fit.sigma[np.isfinite(fit.sigma)]
    sigma = float(np.median(stated)) if stated is not None and len(stated) else ref.noise
    parts.append(_wrist_html(ident, ref.q[-count:][kept], sigma, float(np.median(sigma_r[kept])), escape, table))
    return "".join(parts) + "</section>"


def figure_orientations(residuals: Array, kept: NDArray[np.bool_], sweeps: Array, joints: Array,
                        sigma_r: Array) -> Figure:
    """Orientation residual norms (mrad) per sweep (x: rejected), with the RMS a stated sigma_r predicts
    (sqrt(3) sigma_r, dashed)."""
    norms = np.linalg.norm(residuals, axis=1) * MRAD
    fig = Figure(figsize=(10, 3.2))
    ax = fig.add_subplot()
    labels = []
    for k, s in enumerate(np.unique(sweeps)):
        here = sweeps == s
        x = k + np.linspace(-0.25, 0.25, int(here.sum()))
        ax.plot(x[kept[here]], norms[here][kept[here]], ".", color="C0", ms=3)
        ax.plot(x[~kept[here]], norms[here][~kept[here]], "x", color="C3", ms=6)
        ax.plot([k - 0.35, k + 0.35], [np.sqrt(3) * np.median(sigma_r[here]) * MRAD] * 2, "--", color="k", lw=1)
        joint = int(joints[here][0])
        labels.append("free" if joint == 0 else f"{int(s)}\nJ{joint}")
    ax.set_xticks(range(len(labels)), labels)
    ax.set_xlabel("sweep (joint moved)")
    ax.set_ylabel("|orientation residual| [mrad]")
    ax.set_title("orientation residuals (dots; x rejected), dashed = sqrt(3) sigma_r")
    return fig


def wrist_bounds(ident: Identification, q: Array, sigma: float, sigma_r: float) -> tuple[Array, Array]:
    """Cramér-Rao standard deviations (9 + 4n,) of the plain model's free parameters at readings ``q`` (m, n; the
    oriented samples, DH values) with position noise ``sigma`` (m): with orientations (``sigma_r``, rad) and from
    positions alone; NaN where a parameter is held, inf where the data leave it undetermined."""
    ref = ident.refinement
    free = np.asarray(ref.free, dtype=bool)
    out = []
    for turn in (sigma_r, None):
        jac = full_pose_jacobian(ident.model, q, sigma, turn)
        keep = np.concatenate([free, [turn is not None] * 3])
        j = jac[:, keep]
        scale = np.maximum(np.linalg.norm(j, axis=0), 1e-300)
        _, s, vt = np.linalg.svd(j / scale, full_matrices=False)
        good = s > RCOND * s[0]
        cov = (vt[good].T / s[good] ** 2) @ vt[good] / np.outer(scale, scale)
        std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        loose = np.linalg.norm(vt[~good], axis=0) > LOADING if np.any(~good) else np.zeros(len(std), bool)
        std[loose] = np.inf
        full = np.full(len(free), np.nan)
        full[free] = std[: int(free.sum())]
        out.append(full)
    return out[0], out[1]


def _wrist_html(ident: Identification, q: Array, sigma: float, sigma_r: float, escape: Callable[[Any], str],
                table: Callable[..., str]) -> str:
    """The wrist's parameters: value ± the fit's standard uncertainty, or held and why; the bound with these
    orientations and from the same poses' positions alone."""
    n = ident.model.n_joints
    with_turns, positions = wrist_bounds(ident, q, sigma, sigma_r)
    fixed = {f.name: f.reason for f in ident.fixed}
    dh = ident.model.dh_table()
    rows = []
    for joint in range(max(1, n - WRIST + 1), n + 1):
        for k, name in enumerate(DH_NAMES):
            label, i, scale = f"{name}{joint}", dh_index(joint, name), _SCALE[name]
            value = f"{dh[joint - 1, k] * scale:.4f}"
            if label in fixed:
                rows.append([label, f"{value} (held)", "-", "-", escape(fixed[label])])
                continue
            pos = "not determined" if np.isinf(positions[i]) else f"{positions[i] * scale:.4f}"
            rows.append([label, f"{value} ± {ident.std[i] * scale:.4f}", f"{with_turns[i] * scale:.4f}", pos,
                         "determined"])
    return ("<p>The wrist (joints " + f"{max(1, n - WRIST + 1)}-{n}): each parameter's value ± the fit's standard "
            "uncertainty (deg, mm), or held and why; the Cramér-Rao bound at these poses with the orientations "
            "and, for comparison, from the same poses' positions alone (\"not determined\": positions leave it "
            "to a convention the geometry allows).</p>"
            + table(["parameter", "value", "bound, 6-DoF", "bound, positions only", "status"], rows))
