"""Layout faults of a matplotlib figure, measured on its own renderer (``Text.get_window_extent``, display pixels): an
axes without a title (its own or the figure's) or without labelled axes, two texts whose boxes overlap, a legend
over plotted data. What a reader of the report's PNGs would meet, found without looking at them."""

from __future__ import annotations

from itertools import combinations

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import Collection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle
from matplotlib.text import Text

OVERLAP_PX = 1.0  # boxes overlapping by less than this (in both directions) only touch


def _texts(fig: Figure) -> list[tuple[str, Text]]:
    """Every visible, non-empty text of ``fig`` with the name of what it belongs to."""
    out: list[tuple[str, Text]] = []
    for k, ax in enumerate(fig.axes):
        name = f"axes {k}"
        axes = [ax.xaxis, ax.yaxis, *([ax.zaxis] if hasattr(ax, "zaxis") else [])]
        axis_texts = [ax.title, ax._left_title, ax._right_title, *ax.texts, *(a.label for a in axes)]
        for a in axes:  # the tick labels drawn (those within the view), not every tick's
            axis_texts += [tick.label1 for tick in a._update_ticks()] + [tick.label2 for tick in a._update_ticks()]
        legend = ax.get_legend()
        if legend is not None:
            axis_texts += legend.get_texts()
        out += [(name, t) for t in axis_texts]
    for legend in fig.legends:
        out += [("figure legend", t) for t in legend.get_texts()]
    if fig._suptitle is not None:
        out.append(("figure", fig._suptitle))
    out += [("figure", t) for t in fig.texts]
    return [(n, t) for n, t in out if t.get_visible() and t.get_text().strip()]


def figure_problems(fig: Figure) -> list[str]:
    """What is wrong with ``fig``'s layout (empty when nothing): see the module docstring."""
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    problems = []
    suptitle = fig._suptitle.get_text() if fig._suptitle is not None else ""
    for k, ax in enumerate(fig.axes):
        if not ax.get_visible() or not ax.axison:
            continue
        if not (ax.get_title() or ax.get_title("left") or suptitle):
            problems.append(f"axes {k}: no title")
        names = ("x", "y", "z") if hasattr(ax, "zaxis") else ("x", "y")
        for axis in names:
            if not getattr(ax, f"get_{axis}label")().strip():
                problems.append(f"axes {k}: no {axis} label")
        if not hasattr(ax, "zaxis"):  # a y label longer than its axes is tall runs into what lies above or below
            label, frame = ax.yaxis.label.get_window_extent(renderer), ax.get_window_extent(renderer)
            if ax.get_ylabel() and label.height > frame.height + OVERLAP_PX:
                problems.append(f"axes {k}: the y label {ax.get_ylabel()!r} is longer than the axes are tall")
    texts = _texts(fig)
    boxes = [(n, t, t.get_window_extent(renderer)) for n, t in texts]
    for (n1, t1, b1), (n2, t2, b2) in combinations(boxes, 2):
        w = min(b1.x1, b2.x1) - max(b1.x0, b2.x0)
        h = min(b1.y1, b2.y1) - max(b1.y0, b2.y0)
        if w > OVERLAP_PX and h > OVERLAP_PX:
            problems.append(f"text overlap: {n1} {t1.get_text()!r} / {n2} {t2.get_text()!r}")
    for k, ax in enumerate(fig.axes):
        legend = ax.get_legend()
        if legend is None or hasattr(ax, "zaxis"):
            continue
        box = legend.get_window_extent(renderer)
        covered = sum(_inside(_data_points(ax, artist), box) for artist in [*ax.lines, *ax.patches, *ax.collections])
        if covered:
            problems.append(f"axes {k}: the legend covers {covered} plotted point(s)")
    return problems


def _data_points(ax, artist) -> np.ndarray:
    """Display coordinates (m, 2) of what ``artist`` draws: a line's vertices, a bar's top centre, a collection's
    offsets. Spans across the whole axes (axhspan, axhline) are not data points."""
    if isinstance(artist, Line2D):
        xy = np.column_stack(artist.get_data()).astype(float)
        if len(xy) == 2 and artist.get_transform() != ax.transData:
            return np.zeros((0, 2))
        return artist.get_transform().transform(xy)
    if isinstance(artist, Rectangle):
        if artist.get_transform() != ax.transData:
            return np.zeros((0, 2))
        x, y, w, h = artist.get_x(), artist.get_y(), artist.get_width(), artist.get_height()
        return ax.transData.transform([[x + w / 2, y + h]])
    if isinstance(artist, Collection):
        offsets = np.asarray(artist.get_offsets(), dtype=float)
        return artist.get_offset_transform().transform(offsets) if len(offsets) else np.zeros((0, 2))
    return np.zeros((0, 2))


def _inside(points: np.ndarray, box) -> int:
    points = points[np.all(np.isfinite(points), axis=1)] if len(points) else points
    return int(np.sum((points[:, 0] > box.x0) & (points[:, 0] < box.x1) & (points[:, 1] > box.y0)
                      & (points[:, 1] < box.y1))) if len(points) else 0
