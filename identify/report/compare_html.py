"""The trend page of ``identify compare --html``: one self-contained HTML file with the verdict, the pairs' tests,
the TP displacement of every calibration from the first, and the trend of every parameter that changed
significantly (value minus the first calibration's, ± 2 standard uncertainties). Lengths mm, angles deg.
"""

from __future__ import annotations

import math
import time

import numpy as np
from matplotlib.figure import Figure

from common import __version__
from identify.applications.calibrated import CalibratedModel
from identify.applications.compare import Comparison, dh_label, displacement
from identify.estimator.dh_vector import parameter_names
from identify.report.html import _CSS, _e, _figure_html, _table, _when
from identify.simulators.simulate import random_poses


def _value_std(model: CalibratedModel, index: int) -> tuple[float, float]:
    value = float(model.model.dh_table().ravel()[index - 9])
    if model.free is None or model.covariance is None or not model.free[index]:
        return value, 0.0
    pos = int(np.sum(model.free[:index]))
    return value, float(math.sqrt(max(model.covariance[pos, pos], 0.0)))


def figure_trend(names: list[str], models: list[CalibratedModel], labels: list[str]) -> Figure:
    """Per parameter ``names``: each calibration's value minus the first's, with ± 2 standard uncertainties."""
    index = {n: k for k, n in enumerate(parameter_names(models[0].n_joints))}
    cols = min(3, len(names))
    rows = math.ceil(len(names) / cols)
    fig = Figure(figsize=(3.6 * cols, 2.8 * rows), layout="constrained")
    axes = np.atleast_1d(fig.subplots(rows, cols)).ravel()
    x = np.arange(len(models))
    for ax, name in zip(axes, names, strict=False):
        angular = name.rstrip("0123456789") in ("theta", "alpha")
        scale, unit = (math.degrees(1.0), "deg") if angular else (1e3, "mm")
        values = np.array([_value_std(m, index[name]) for m in models])
        delta = values[:, 0] - values[0, 0]
        if angular:
            delta = np.angle(np.exp(1j * delta))
        ax.errorbar(x, delta * scale, yerr=2 * values[:, 1] * scale, fmt="o-", capsize=3)
        ax.axhline(0, color="#999", lw=0.8)
        ax.set_title(dh_label(name), fontsize=9)
        ax.set_ylabel(f"change [{unit}]")
        ax.set_xticks(x, labels, rotation=30, fontsize=7)
        ax.set_xlabel("calibration", fontsize=8)
    for ax in axes[len(names):]:
        ax.set_visible(False)
    return fig


def figure_displacement(models: list[CalibratedModel], labels: list[str], q: np.ndarray) -> Figure:
    """RMS and maximum TP displacement of every calibration from the first (mm), with the RMS the uncertainties
    alone would give."""
    stats = [displacement(models[0], m, q) for m in models]
    rms = np.array([np.sqrt(np.mean(np.sum(d**2, axis=1))) for d, _ in stats]) * 1e3
    worst = np.array([np.max(np.linalg.norm(d, axis=1)) for d, _ in stats]) * 1e3
    expected = np.array([e for _, e in stats]) * 1e3
    expected[0] = 0.0
    fig = Figure(figsize=(8, 3.2), layout="constrained")
    ax = fig.add_subplot()
    x = np.arange(len(models))
    ax.plot(x, rms, "o-", label="RMS")
    ax.plot(x, worst, "s--", label="max")
    ax.fill_between(x, 0, expected, color="#ccc", alpha=0.6, label="RMS from the uncertainties alone")
    ax.set_xticks(x, labels, rotation=20, fontsize=8)
    ax.set_xlabel("calibration")
    ax.set_ylabel("[mm]")  # the title says what: a long label would run past the axes
    ax.set_title("predicted TP displacement from the first calibration over random poses (robot base frame)",
                 fontsize=10)
    ax.legend(fontsize=7)
    return fig


def compare_html(result: Comparison, models: list[CalibratedModel], times: list[float | None]) -> str:
    """The trend page as one HTML document."""
    labels = list(result.labels)
    title = f"Change over time: {len(models)} calibrations of one robot"
    status = "fail" if result.significant else "pass"
    single = len(result.pairs) == 1  # two calibrations: the pair's verdict is the verdict, said once
    body = [f"<h1>{_e(title)}</h1>",
            f"<p>dh-calib {_e(__version__)}, generated {_e(_when(time.time()))}; family-wise false-alarm rate "
            f"{result.alpha:g} (a chi-square test of all DH parameters per pair, then each parameter with Holm's "
            "correction).</p>",
            f'<section id="headline" class="verdict-{status}"><h2>'
            f"{'SIGNIFICANT CHANGE' if result.significant else 'No significant change'}</h2>"
            f"<p>{_e(result.pairs[0].verdict if single else result.verdict)}</p></section>"]
    rows = [[_e(lab), _e(_when(t)) if t else "", _e(m.model.joint_types)] for lab, t, m in
            zip(labels, times, models, strict=True)]
    body.append('<section id="inputs"><h2>Calibrations</h2>' + _table(["input", "time", "joints"], rows, left=2)
                + "</section>")
    pair_rows = [[_e(f"{p.a} -> {p.b}"), f"{p.statistic:.1f} / {p.dof}", f"{p.p_value:.3g}",
                  "yes" if p.significant else "no", f"{p.displacement_rms * 1e3:.4f}",
                  f"{p.displacement_max * 1e3:.4f}", f"{p.expected_rms * 1e3:.4f}"] for p in result.pairs]
    body.append('<section id="pairs"><h2>Pairs</h2>'
                + _table(["pair", "chi-square / dof", "p", "significant", "TP RMS [mm]", "TP max [mm]",
                          "RMS from uncertainty [mm]"], pair_rows)
                + "".join(("" if single else f"<p>{_e(p.verdict)}</p>")  # one pair: the headline says it
                          + "".join(f"<p>note: {_e(e)}</p>" for e in p.excluded) for p in result.pairs)
                + "</section>")
    n = models[0].n_joints
    home = np.zeros(n)
    half = np.array([math.pi if t == "R" else 0.1 for t in models[0].model.joint_types])
    q = random_poses(np.column_stack([home - half, home + half]), 300, np.random.default_rng(0))
    body.append('<section id="displacement"><h2>TP displacement</h2>'
                + _figure_html(figure_displacement(models, labels, q), "TP displacement of each calibration from "
                               "the first") + "</section>")
    changed = sorted({c.name for p in result.pairs for c in p.changed})
    body.append('<section id="trend"><h2>Parameters that changed</h2>')
    if changed:
        body.append(_figure_html(figure_trend(changed, models, labels), "Change from the first calibration, "
                                 "± 2 standard uncertainties"))
        index = {nm: k for k, nm in enumerate(parameter_names(n))}
        trows = []
        for name in changed:
            angular = name.rstrip("0123456789") in ("theta", "alpha")
            scale, unit = (math.degrees(1.0), "deg") if angular else (1e3, "mm")
            cells = [f"{v * scale:.4f} ± {s * scale:.4f}" for v, s in (_value_std(m, index[name]) for m in models)]
            trows.append([_e(f"{dh_label(name)} [{unit}]"), *cells])
        body.append(_table(["parameter", *map(_e, labels)], trows))
    else:
        body.append("<p>None: every parameter stayed within what the calibrations' uncertainties allow.</p>")
    body.append("</section>")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{_e(title)}</title><style>{_CSS}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")

