"""The identification report's per-joint and 3D figures (matplotlib object API, no pyplot state).

Per joint: what is informative at metre scale is the deviation of each measured point from the model's path, not
the path itself: the residual split into radial (away from the axis), axial (along it) and tangential (along the
arc) parts, against the joint's angle, with the tracker's noise band; for a prismatic joint, along and across its
line. The 3D view is drawn in the robot's base frame (DH frame 0: the arm stands upright whatever the tracker's
placement), with the arm as a polyline through its frames at home, the joint axes, the measured points and, with
a cell, the mounting surface and the plan's swept envelope; a top view beside it. Lengths in mm, angles in deg.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator
from numpy.typing import NDArray

from identify.estimator.measurements import Measurements
from identify.results.pipeline import Identification
from kinematics.dh import frames_from_joints, points_from_joints

Array = NDArray[np.float64]

MM = 1e3
DEG = np.degrees(1.0)


NORM_95 = 2.7955  # sqrt of chi-square(3 dof)'s 0.95 quantile: the 95 % level of |r| / sigma for isotropic noise


def plane_basis(axis: Array) -> tuple[Array, Array]:
    """Two unit vectors completing ``axis`` to an orthonormal basis."""
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def focus_on_inliers(ax: Any, inlier_values: Array, outlier_values: Array) -> None:
    """Scale the y axis to the inliers when rejected samples would squash them; say how many are off scale."""
    if len(inlier_values) == 0 or len(outlier_values) == 0:
        return
    lo, hi = float(np.min(inlier_values)), float(np.max(inlier_values))
    pad = 0.3 * max(hi - lo, 1e-6)
    lo, hi = min(lo - pad, 0.0), hi + pad
    off = int(np.sum((outlier_values < lo) | (outlier_values > hi)))
    if off:
        ax.set_ylim(lo, hi)
        ax.text(0.01, 0.97, f"{off} rejected sample(s) off scale", transform=ax.transAxes, fontsize=7,
                va="top", color="C3")


def deviations(ident: Identification, fit: Measurements, joint: int) -> tuple[Array, Array, list[str]]:
    """For the sweep rows of ``joint`` (1-based): the joint values (deg or mm) and the residuals (measured minus
    model, mm) split along the directions named in the list: radial, axial, tangential for a revolute joint;
    along, across (the distance off the line) for a prismatic one."""
    model, ref = ident.model, ident.refinement
    j = joint - 1
    rows = fit.joint == joint
    q, res = ref.q[: len(rows)][rows], ref.residuals[: len(rows)][rows]  # (orientation rows follow the positions)
    frames = frames_from_joints(model, q)
    z, o = frames[:, j, :3, 2], frames[:, j, :3, 3]
    if model.joint_types[j] == "R":
        lever = points_from_joints(model, q) - o
        radial = lever - np.sum(lever * z, axis=1, keepdims=True) * z
        radial /= np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-12)
        tangential = np.cross(z, radial)
        parts = np.column_stack([np.sum(res * radial, axis=1), np.sum(res * z, axis=1),
                                 np.sum(res * tangential, axis=1)])
        return q[:, j] * DEG, parts * MM, ["radial", "axial", "tangential"]
    along = np.sum(res * z, axis=1)
    across = np.linalg.norm(res - along[:, None] * z, axis=1)
    return q[:, j] * MM, np.column_stack([along, across]) * MM, ["along the axis", "off the line"]


def figure_joint(ident: Identification, fit: Measurements, joint: int) -> Figure:
    """Joint ``joint`` (1-based): the deviation of its sweep's points from the model's path along the arc (radial
    and axial; along and across for a prismatic joint), and the rest of the residual (tangential and |r|)."""
    x, parts, names = deviations(ident, fit, joint)
    inl = ident.refinement.inliers[fit.joint == joint]
    noise = ident.refinement.noise * MM
    revolute = ident.model.joint_types[joint - 1] == "R"
    fig = Figure(figsize=(10, 4.0), layout="constrained")
    ax1, ax2 = fig.subplots(1, 2, sharex=True)
    for ax in (ax1, ax2):
        ax.axhspan(-2 * noise, 2 * noise, color="#ddd", alpha=0.6, lw=0, label="±2 sigma tracker noise (per axis)")
        ax.axhline(0, color="#999", lw=0.8)
    # |r| is a 3D norm: with noise alone it lies below NORM_95 sigma 95 % of the time, not below the ±2 sigma band
    ax2.axhline(NORM_95 * noise, color="k", ls=":", lw=1, label="|r|: 95 % below with noise alone")
    for k, name in enumerate(names[:2]):
        ax1.plot(x[inl], parts[inl, k], ".-" if revolute else ".", ms=4, lw=0.6, color=f"C{k}", label=name)
        if np.any(~inl):
            ax1.plot(x[~inl], parts[~inl, k], "x", color="C3", ms=7)
    focus_on_inliers(ax1, parts[inl, :2].ravel(), parts[~inl, :2].ravel())
    rest = parts[:, 2] if revolute else np.zeros(len(x))
    norm = np.linalg.norm(parts, axis=1) if revolute else np.hypot(parts[:, 0], parts[:, 1])
    if revolute:
        ax2.plot(x[inl], rest[inl], ".", ms=4, color="C2", label="tangential")
    ax2.plot(x[inl], norm[inl], "k_", ms=6, label="|r|")
    if np.any(~inl):
        ax2.plot(x[~inl], norm[~inl], "x", color="C3", ms=8, label="rejected")
    focus_on_inliers(ax2, np.concatenate([rest[inl], norm[inl]]), norm[~inl])
    unit = "deg" if revolute else "mm"
    travel = (x.max() - x.min()) if len(x) else 0.0
    ax1.set_title(f"joint {joint}: deviation from the model's {'circle' if revolute else 'line'} "
                  f"({travel:.0f} {unit} swept)", fontsize=10)
    ax1.set_xlabel(f"q{joint} [{unit}]")
    ax1.set_ylabel("[mm]")
    ax2.set_title("along the arc and in total" if revolute else "in total", fontsize=10)
    ax2.set_xlabel(f"q{joint} [{unit}]")
    ax2.set_ylabel("[mm]")
    for ax in (ax1, ax2):  # below the plot: a legend inside would cover points
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=3, frameon=False)
    return fig


def figure_frames(ident: Identification, fit: Measurements, cell: dict[str, Any] | None = None) -> Figure:
    """The identified arm at home in its base frame (DH frame 0, mm): a 3D view and a top view of the chain of
    frame origins to the TP, the joint axes (dashed), the frames' z axes and the measured points (grey).

    ``cell`` (optional, frame 0, m): ``normal`` (3,) and ``offset`` of the mounting surface and ``envelope``
    (k, 3), points the arm's bodies pass through during the plan."""
    model, home = ident.model, ident.lines.home
    inv = np.linalg.inv(model.base)
    frames = inv @ frames_from_joints(model, home)[0]
    tp = (inv[:3, :3] @ points_from_joints(model, home)[0] + inv[:3, 3]) * MM
    pts = (fit.points @ inv[:3, :3].T + inv[:3, 3]) * MM
    origins = frames[:, :3, 3] * MM
    span = float(np.ptp(np.vstack([pts, origins, tp]), axis=0).max()) or 100.0
    fig = Figure(figsize=(11, 5.2), layout="constrained")
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    top = fig.add_subplot(1, 2, 2)
    ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=2, color="#999", alpha=0.35, label="measured TP")
    top.plot(pts[:, 0], pts[:, 1], ".", ms=2, color="#999", alpha=0.5)
    if cell is not None:
        _draw_cell(ax, cell)
    chain = np.vstack([origins, tp])
    for a in (ax, top):
        args = (chain[:, 0], chain[:, 1], chain[:, 2]) if a is ax else (chain[:, 0], chain[:, 1])
        a.plot(*args, "-o", color="k", lw=2.5, ms=4, label="arm at home (frame origins)")
    size = 0.12 * span
    for i, frame in enumerate(frames[:-1]):
        o, z = frame[:3, 3] * MM, frame[:3, 2]
        color = "C1" if model.joint_types[i] == "R" else "C4"
        line = np.array([o - z * size, o + z * size])
        ax.plot(line[:, 0], line[:, 1], line[:, 2], "--", color=color, lw=1.5)
        top.plot(line[:, 0], line[:, 1], "--", color=color, lw=1.2)
        ax.text(*(o + z * size), f"J{i + 1}", fontsize=9, color=color)
    for joints, where in _top_labels(frames[:-1, :3, 3] * MM, 0.04 * span):  # one label where origins coincide
        top.annotate(", ".join(f"J{i + 1}" for i in joints), where, fontsize=8, color="k", xytext=(3, 3),
                     textcoords="offset points")
    ax.scatter(*tp, color="C3", s=40, label="TP at home", depthshade=False)
    top.plot(*tp[:2], "o", color="C3")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_zlabel("z [mm]")
    ax.set_aspect("equal")
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):  # few ticks: at the cube's corners they would run into each other
        axis.set_major_locator(MaxNLocator(4))
    ax.tick_params(labelsize=7)
    ax.view_init(elev=22, azim=-60)
    ax.set_title("3D, robot base frame", fontsize=10)
    fig.legend(*ax.get_legend_handles_labels(), fontsize=7, loc="outside lower left", ncol=3,
               frameon=False)  # below the plots, off the data
    top.set_aspect("equal", adjustable="datalim")
    top.set_xlabel("x [mm]")
    top.set_ylabel("y [mm]")
    top.set_title("top view (joint axes dashed: revolute orange, prismatic purple)", fontsize=10)
    top.grid(True, lw=0.3)
    return fig


def _top_labels(origins: Array, near: float) -> list[tuple[list[int], Array]]:
    """The frame origins (k, 3), mm, grouped where they lie within ``near`` mm of each other in the top view (x, y):
    (joint indices, position of the group's first origin)."""
    groups: list[tuple[list[int], Array]] = []
    for i, o in enumerate(origins):
        for joints, where in groups:
            if np.hypot(*(o[:2] - where)) < near:
                joints.append(i)
                break
        else:
            groups.append(([i], o[:2]))
    return groups


def _draw_cell(ax: Any, cell: dict[str, Any]) -> None:
    """The plan's swept envelope (points) and the mounting surface (a square patch under it), frame 0, mm."""
    envelope = np.asarray(cell["envelope"], dtype=float).reshape(-1, 3)
    normal = np.asarray(cell["normal"], dtype=float)
    if len(envelope):
        env = envelope * MM
        ax.scatter(env[:, 0], env[:, 1], env[:, 2], s=2, color="C0", alpha=0.2, label="swept by the plan")
    u, v = plane_basis(normal)
    centre = normal * float(cell["offset"])
    extent = float(np.max(np.abs((envelope - centre) @ np.column_stack([u, v])), initial=0.5)) * 1.1
    grid = np.linspace(-extent, extent, 2)
    gu, gv = np.meshgrid(grid, grid)
    corners = (centre + gu[..., None] * u + gv[..., None] * v) * MM
    ax.plot_surface(corners[..., 0], corners[..., 1], corners[..., 2], color="C2", alpha=0.15)
