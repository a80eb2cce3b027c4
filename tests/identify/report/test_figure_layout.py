"""Every figure of the reports (identification, verification, trend) has a title and labelled axes, no text over
another text, no legend over plotted data, and no y label running past its axes: measured on matplotlib's own
renderer (tests/_figure_layout.py). Before: the per-joint figures' legends covered points and their right-hand
plot had no y label, the top view's J1-J3 labels overlapped, the 3D view's tick labels ran into each other, the
trend figures had no x label and the displacement figure's y label ran past its axes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

pytest.importorskip("matplotlib")

from identify.applications.calibrated import CalibratedModel
from identify.report.compare_html import figure_displacement, figure_trend
from identify.report.figures import figure_frames, figure_joint
from identify.report.html import _fit_rows, figure_drift, figure_sweeps, figure_validation
from identify.report.verify_html import figure_accuracy
from identify.simulators.simulate import random_poses
from tests._figure_layout import figure_problems
from tests.identify.report.test_html import _identified


@pytest.fixture(scope="module")
def identified():
    robot, meas, ident = _identified("ur5e")
    return robot, meas.subset(_fit_rows(meas)), ident


@pytest.mark.slow
@pytest.mark.parametrize("joint", range(1, 7))
def test_each_joints_figure(identified, joint):
    _, fit, ident = identified
    fig = figure_joint(ident, fit, joint)
    assert figure_problems(fig) == []
    # |r| is a 3D norm: its reference is the 95 % level of the norm of isotropic noise (2.80 sigma), not the
    # per-axis ±2 sigma band it was drawn against before
    levels = [line.get_ydata()[0] for line in fig.axes[1].lines if line.get_label().startswith("|r|: 95 %")]
    assert levels == [pytest.approx(np.sqrt(chi2.ppf(0.95, 3)) * ident.refinement.noise * 1e3, rel=1e-4)]


def test_the_arm_figure_the_fit_figures_and_the_drift(identified):
    _, fit, ident = identified
    errors = np.abs(np.random.default_rng(1).normal(size=8)) * 1e-4
    for fig in (figure_frames(ident, fit), figure_sweeps(ident, fit), figure_validation(errors, 1e-4),
                figure_drift([(0.0, 0.0), (60.0, 1e-5), (120.0, 2e-5)])):
        assert figure_problems(fig) == []


def test_the_verification_figure():
    poses = {m: {"poses": [{"pose": f"P{k}", "ap": a * (1 + k / 10), "rp": 7e-5 + k * 5e-6} for k in range(1, 6)]}
             for m, a in (("before", 1.5e-3), ("after", 1e-5))}
    summary = {"runs": poses, "predicted": {"before": [1.5e-3] * 5}, "expected": [4e-6] * 5}
    assert figure_problems(figure_accuracy(summary)) == []


def test_the_trend_figures(identified):
    robot, _, ident = identified
    _, _, other = _identified("ur5e", seed=8)
    models = [CalibratedModel.from_identification(i) for i in (ident, other)]
    q = random_poses(robot.limits, 50, np.random.default_rng(0))
    assert figure_problems(figure_trend(["theta2", "a2", "d4", "alpha3"], models, ["jan", "feb"])) == []
    assert figure_problems(figure_displacement(models, ["jan", "feb"], q)) == []


def test_the_3d_z_label_stands_clear_of_the_top_view_and_counts_are_whole(identified):
    """Issue 39, item 12: the 3D view's z label ran into the top view's y label; the held-out histogram's count
    axis had ticks at 0.5, 1.5, ... and the per-pose bars' axis at 2.5, 7.5, ... (drawn, then measured)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    _, fit, ident = identified
    fig = figure_frames(ident, fit)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    z_label = fig.axes[0].zaxis.label.get_window_extent(renderer)
    y_label = fig.axes[1].yaxis.label.get_window_extent(renderer)
    assert z_label.x1 + 20 < y_label.x0, (z_label, y_label)
    for count in (8, 20, 40):
        fig = figure_validation(np.abs(np.random.default_rng(count).normal(size=count)) * 1e-4, 1e-4)
        FigureCanvasAgg(fig).draw()
        for axis in (fig.axes[0].yaxis, fig.axes[1].xaxis):
            assert all(float(t).is_integer() for t in axis.get_ticklocs()), axis.get_ticklocs()
