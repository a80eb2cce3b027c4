"""The identification report: one self-contained HTML file (figures embedded as base64 PNG, opens offline).

Pure: :func:`report_html` builds the text from an :class:`~identify.results.pipeline.Identification` in memory and the
measurements it was made from; :func:`write_report` writes it. Figures are drawn with matplotlib's object
API (``matplotlib.figure.Figure``, no pyplot state, no GUI backend). Lengths are shown in mm, angles in deg.

Sections: DH table ± standard uncertainty with deltas against the nominal model (and a reference such as the
controller's factory calibration, when given); per joint the measured points with the fitted circle or line,
the swept arc and the residuals; a 3D view of the identified axes and DH frames with the points; held-out
validation errors; residuals per sweep; and, given an acquisition session, its record (devices, plan,
duration, how runs ended, missing and rejected samples, drift over time, events).
"""

from __future__ import annotations

import base64
import html
import io
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.image import imsave
from matplotlib.ticker import MaxNLocator
from numpy.typing import NDArray

from common import __version__
from identify.applications.domain import outside
from identify.estimator.extensions import UNITS
from identify.estimator.measurements import Measurements
from identify.report.figures import figure_frames, figure_joint
from identify.report.figures import focus_on_inliers as _focus_on_inliers
from identify.report.full_pose import full_pose_section
from identify.report.headline import accuracy_summary, headline_html
from identify.report.terminal import format_clock
from identify.results.pipeline import Identification
from kinematics.dh import DH_NAMES, DHModel

if TYPE_CHECKING:
    from session.store import SessionFile

Array = NDArray[np.float64]

MM = 1e3
DEG = np.degrees(1.0)
_SCALE = {"theta": DEG, "d": MM, "a": MM, "alpha": DEG}
_UNIT = {"theta": "deg", "d": "mm", "a": "mm", "alpha": "deg"}
DPI = 96

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1100px;
color:#222;padding:0 1em}h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.8em}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em}td,th{border:1px solid #ddd;padding:.25em .6em;
text-align:right;white-space:nowrap}th{background:#f4f4f4;white-space:normal}td.l,th.l{text-align:left;white-space:normal}
.fixed{color:#888}figure{margin:1em 0}img{max-width:100%;height:auto}figcaption{font-size:.9em;color:#555}
.warn{color:#a40}code{background:#f4f4f4}.scroll{overflow-x:auto}.verdict-pass h2{color:#063}
.verdict-warn h2{color:#a40}.verdict-fail h2{color:#b00}.sides{display:flex;flex-wrap:wrap;gap:1.5em}
#headline{border:2px solid #ccc;border-radius:6px;padding:0 1em .6em;margin:1em 0}#headline.verdict-pass{
border-color:#063}#headline.verdict-warn{border-color:#a40}#headline.verdict-fail{border-color:#b00}
"""


# ------------------------------------------------------------------------------------------- figures


def png_data_uri(fig: Figure) -> str:
    """``data:image/png;base64,...`` of ``fig`` at :data:`DPI`, drawn once: the figure's layout engine (constrained
    layout, given here to a figure that has none) keeps every label inside the canvas as it draws, and the canvas
    is encoded as drawn. (``savefig`` draws twice with a layout engine or ``bbox_inches="tight"``: a pass to lay out
    or measure, then the real one, which cost the report a third more CPU time: docs/benchmarks.md, section 25.)"""
    if fig.get_layout_engine() is None:
        fig.set_layout_engine("constrained")
    fig.set_dpi(DPI)
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    buf = io.BytesIO()
    imsave(buf, canvas.buffer_rgba(), format="png", dpi=DPI)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def positions_view(ident: Identification, m: int) -> Identification:
    """``ident`` with its plain model's refinement record cut to the ``m`` position rows (orientation rows of
    full-pose data follow them and are summed up in ``ident.orientation``), for the figures in metres."""
    ref = ident.refinement
    if ident.orientation is None or len(ref.residuals) - ident.orientation[0] != m:
        return ident  # (the caller refuses measurements of another size)
    cut = replace(ref, residuals=ref.residuals[:m], inliers=ref.inliers[:m], q=ref.q[:m], points=ref.points[:m])
    return replace(ident, models={**ident.models, "plain": replace(ident.plain, refinement=cut)})


def orientation_line(orientation: tuple[int, int, float]) -> str:
    """One line on the orientation rows: how many, rejected, and their RMS residual (mrad, 3D)."""
    count, rejected, rms = orientation
    return (f"orientations (full-pose readings): {count} fitted, {rejected} rejected as outliers, residual RMS "
            f"{rms * 1e3:.4f} mrad (3D), each weighed by its sigma_r beside the positions' sigma")


def _fit_rows(meas: Measurements) -> NDArray[np.bool_]:
    """Rows of ``meas`` the pipeline fitted (not held out, every joint reading finite), in its order."""
    return ~meas.check & np.all(np.isfinite(meas.q), axis=1)


def figure_validation(errors: Array, expected: float | None) -> Figure:
    """Held-out errors (mm): histogram and per pose."""
    fig = Figure(figsize=(10, 3.5), layout="constrained")
    ax1, ax2 = fig.subplots(1, 2)
    e = errors * MM
    ax1.hist(e, bins=max(5, min(30, len(e) // 2)), color="C0")
    ax1.set_xlabel("3D error [mm]")
    ax1.set_ylabel("poses")
    ax1.set_title("held-out errors")
    ax2.bar(np.arange(1, len(e) + 1), e, color="C0")
    ax2.axhline(float(np.sqrt(np.mean(e**2))), color="k", lw=1, label="RMS")
    if expected is not None:
        ax2.axhline(expected * MM, color="C1", ls="--", lw=1, label="expected RMS")
    ax2.set_xlabel("held-out pose")
    ax2.set_ylabel("3D error [mm]")
    ax1.yaxis.set_major_locator(MaxNLocator(integer=True))  # counts and pose numbers are whole: no 0.5 or 2.5 ticks
    ax2.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax2.set_xlim(0.4, len(e) + 0.6)
    ax2.set_title("per pose")
    ax2.legend(fontsize=7)
    return fig


def figure_sweeps(ident: Identification, fit: Measurements) -> Figure:
    """Residual norms (mm) of every fitted sample, per sweep, with each sweep's RMS."""
    ref = ident.refinement
    norms = np.linalg.norm(ref.residuals, axis=1) * MM
    fig = Figure(figsize=(10, 3.5), layout="constrained")
    ax = fig.add_subplot()
    labels = []
    for k, s in enumerate(ident.sweeps):
        rows = (fit.joint == 0) if s.joint == 0 else (fit.sweep == s.sweep) & (fit.joint > 0)
        x = np.full(int(rows.sum()), k) + np.linspace(-0.25, 0.25, int(rows.sum()))
        good = ref.inliers[rows]
        ax.plot(x[good], norms[rows][good], ".", color="C0", ms=3)
        ax.plot(x[~good], norms[rows][~good], "x", color="C3", ms=6)
        ax.plot([k - 0.35, k + 0.35], [s.rms * MM] * 2, "-", color="k", lw=2)
        labels.append("free" if s.joint == 0 else f"{s.sweep}\nJ{s.joint}")
    _focus_on_inliers(ax, norms[ref.inliers], norms[~ref.inliers])
    ax.set_xticks(range(len(labels)), labels)
    ax.set_xlabel("sweep (joint moved)")
    ax.set_ylabel("|residual| [mm]")
    ax.set_title("residuals per sweep (dots; x rejected), bar = RMS of inliers")
    return fig


def figure_drift(drift: list[tuple[float, float]]) -> Figure:
    """Home re-measurement displacement (mm) against time since the first (min)."""
    t = np.array([d[0] for d in drift])
    fig = Figure(figsize=(8, 3), layout="constrained")
    ax = fig.add_subplot()
    ax.plot((t - t[0]) / 60.0, np.array([d[1] for d in drift]) * MM, "o-", color="C0")
    ax.set_xlabel("time since the first home check [min]")
    ax.set_ylabel("home TP displacement [mm]")
    ax.set_title("drift checks")
    return fig


# ------------------------------------------------------------------------------------------- HTML parts


def _e(value: Any) -> str:
    return html.escape(str(value))


def _table(head: list[str], rows: list[list[str]], left: int = 1) -> str:
    """HTML table; cells are already escaped HTML; the first ``left`` columns are left aligned."""
    cls = [' class="l"' if k < left else "" for k in range(len(head))]
    out = ["<table><tr>" + "".join(f"<th{c}>{h}</th>" for c, h in zip(cls, head, strict=True)) + "</tr>"]
    out += ["<tr>" + "".join(f"<td{c}>{v}</td>" for c, v in zip(cls, row, strict=True)) + "</tr>" for row in rows]
    return '<div class="scroll">' + "\n".join(out) + "</table></div>"


def _wrap(delta: Array) -> Array:
    delta = delta.copy()
    delta[:, 0] = np.angle(np.exp(1j * delta[:, 0]))
    return delta


def _value_with_unit(name: str, value: float) -> str:
    """A parameter value in the report's units: ``d3`` 0.1 -> ``100 mm``; base and tool names in SI."""
    key = name.rstrip("0123456789")
    if key in _SCALE:
        return f"{value * _SCALE[key]:.4f} {_UNIT[key]}"
    return f"{value:.6g}"


def _dh_section(ident: Identification, references: list[tuple[str, DHModel]]) -> str:
    """The DH table (value ± standard uncertainty), then one narrow table of differences per reference, side by
    side where the page is wide enough: every column fits the page."""
    model, std = ident.model, ident.std
    fixed = {f.name for f in ident.fixed}
    head = ["joint", "type", *(f"{n} [{_UNIT[n]}]" for n in DH_NAMES)]
    rows = []
    for i in range(model.n_joints):
        row = [str(i + 1), model.joint_types[i]]
        for k, name in enumerate(DH_NAMES):
            value = model.dh_table()[i, k] * _SCALE[name]
            if f"{name}{i + 1}" in fixed:
                row.append(f'<span class="fixed">{value:.4f} (fixed)</span>')
            else:
                row.append(f"{value:.4f} ± {std[9 + 4 * i + k] * _SCALE[name]:.4f}")
        rows.append(row)
    deltas = []
    for label, ref in references:
        delta = _wrap(model.dh_table() - ref.dh_table())
        drows = []
        for i in range(model.n_joints):
            cells = []
            for k, n in enumerate(DH_NAMES):
                sigma = std[9 + 4 * i + k]
                big = f"{n}{i + 1}" not in fixed and sigma > 0 and abs(delta[i, k]) > 3 * sigma
                text = f"{delta[i, k] * _SCALE[n]:+.4f}"
                cells.append(f"<b>{text}</b>" if big else text)
            drows.append([str(i + 1), *cells])
        deltas.append(f'<div class="side"><p>Δ identified vs {_e(label)}</p>'
                      + _table(["joint", *(f"Δ{n} [{_UNIT[n]}]" for n in DH_NAMES)], drows) + "</div>")
    t, tool = model.base[:3, 3] * MM, model.tool * MM
    parts = [_table(head, rows, left=2)]
    if deltas:
        parts.append('<div class="sides">' + "".join(deltas) + "</div><p>Bold: more than three standard "
                     "uncertainties from the reference.</p>")
    parts.append(f"<p>Base origin in the tracker frame: {', '.join(f'{v:.3f}' for v in t)} mm "
                 f"(± {', '.join(f'{s * MM:.3f}' for s in std[3:6])}); "
                 f"tool (TP in frame {model.n_joints}): {', '.join(f'{v:.3f}' for v in tool)} mm "
                 f"(± {', '.join(f'{s * MM:.3f}' for s in std[6:9])}).</p>")
    if ident.fixed:
        parts.append(_table(["fixed parameter", "value", "reason"],
                            [[_e(f.name), _e(_value_with_unit(f.name, f.value)), _e(f.reason)] for f in ident.fixed],
                            left=3))
    if ident.parallel:
        parts.append(f"<p>Parallel axes (within tolerance) at links {_e(ident.parallel)}: their d is "
                     "conventional.</p>")
    ref = ident.refinement
    paper = ("" if ident.geometric is None else
             f"; the geometric step alone (the paper's method) gives {ident.geometric_rms * MM:.4f} mm")
    parts.append(f"<p>Fit: {int(ref.inliers.sum())} samples, residual RMS {ident.rms * MM:.4f} mm (3D), tracker "
                 f"noise {ref.noise * MM:.4f} mm per axis, model error {ident.adequacy.model_error * MM:.4f} mm per "
                 f"axis, condition number {ref.condition:.3g}{paper}.</p>")
    return "".join(parts)


def _beyond_dh_section(ident: Identification, fit: Measurements) -> str:
    """Tracked points, coupled readings and joint errors beyond the DH table (issue 14), with the decisions."""
    parts = ['<section id="beyond-dh"><h2>Tracked points, coupling and joint errors</h2>']
    rows = []
    for tp_id, tool in zip(ident.tp_ids, ident.tools, strict=True):
        count = int(np.sum(fit.tp == tp_id))
        rows.append([str(tp_id), ", ".join(f"{x * MM:.3f}" for x in tool), str(count)])
    parts.append("<p>Each tracked point's position in the last DH frame (mm); the first is the contract's "
                 "<code>tool</code>.</p>" + _table(["tp", "tool [mm]", "fitted rows"], rows))
    coupling = ident.coupling
    if coupling is not None and not coupling.is_identity:
        parts.append("<p>Readings are coupled: <code>q_dh = C · readings + offset</code>, C = "
                     f"<code>{_e(coupling.matrix.tolist())}</code>, offset = <code>{_e(coupling.offset.tolist())}"
                     "</code>. Joint values in this report are DH values.</p>")
    if ident.clock is not None:
        parts.append(f"<p>{_e(format_clock(ident.clock))} (fitted with the kinematics; the result YAML's "
                     "<code>clock</code>).</p>")
    if ident.extensions:
        terms = [[_e(name), f"{value:.4g}", f"{std:.2g}", _e(UNITS[name.rsplit('_', 1)[0]])]
                 for name, value, std in ident.extensions]
        parts.append("<p>Joint errors selected (the joint stands at q + Δq(q); equations in the result YAML's "
                     "<code>extensions</code>; URDF and UR calibration exports cannot carry them):</p>"
                     + _table(["term", "value", "± std", "unit"], terms))
    if ident.decisions:
        decisions = [[_e(d.candidate.family), str(d.candidate.joint + 1),
                      "-" if not np.isfinite(d.score) else f"{d.score:.1f}", f"{d.limit:.1f}",
                      "yes" if d.selected else "no", _e(d.reason)] for d in ident.decisions]
        parts.append("<p>Every candidate, with its score statistic (chi-square when absent) and the limit it had "
                     "to pass (information criterion and 5 % family-wise):</p>"
                     + _table(["term", "joint", "statistic", "limit", "selected", "why"], decisions, left=6))
    else:
        parts.append("<p>No joint errors were tested (switched off, or a misfit too large for corrections).</p>")
    return "".join(parts) + "</section>"


def _domain_section(ident: Identification, check: Measurements) -> str:
    """The joint ranges the recommended model was fitted on (its domain), and where the held-out poses ``check``
    (every joint read) lie."""
    if ident.domain is None:
        return ""
    types = ident.model.joint_types
    rows = [[str(j + 1), *(("-", "-", "-") if not np.all(np.isfinite(r)) else
                           (_amount(r[0], k), _amount(r[1], k), _amount(r[1] - r[0], k)))]
            for j, (r, k) in enumerate(zip(ident.domain, types, strict=True))]
    text = ("<p>The joint values of the fitted rows span these ranges: the result's domain, recorded in its YAML. "
            "The accuracies it states hold inside them; outside, it extrapolates, and every command that applies "
            "it (<code>identify check</code>, <code>compensate</code>, <code>acquire verify</code>, "
            "<code>compare</code>) says how many of its poses lie outside and by how much.</p>")
    if len(check):
        q = check.q if ident.coupling is None else ident.coupling.dh_from_readings(check.q)
        text += f"<p>Held-out poses: {_e(outside(ident.domain, q, types).text())}.</p>"
    return ('<section id="domain"><h2>Where the result holds</h2>' + text
            + _table(["joint", "from", "to", "span"], rows) + "</section>")


def _amount(value: float, kind: str) -> str:
    """A joint value as read: degrees for a revolute joint, mm for a prismatic one."""
    return f"{np.degrees(value):.1f}°" if kind == "R" else f"{value * MM:.1f} mm"


def _acquisition_section(session: SessionFile) -> tuple[str, Figure | None]:
    header = session.header
    devices = []
    for key in ("robot", "tracker"):
        d = header.get(key) or {}
        details = ", ".join(f"{k}: {v}" for k, v in (d.get("details") or {}).items()
                            if k != "factory_calibration")  # shown against the DH table
        devices.append([_e(key), _e(d.get("model", "")), _e(d.get("serial", "")), _e(d.get("firmware", "")),
                        _e(details)])
    parts = [_table(["device", "model", "serial", "firmware", "details"], devices, left=5)]
    plan = session.plan
    kinds = Counter(step.kind for step in plan.steps)
    parts.append(f"<p>Plan: robot {_e(plan.robot)}, joints {_e(plan.joint_types)}, {len(plan.steps)} steps "
                 f"({', '.join(f'{v} {_e(k)}' for k, v in sorted(kinds.items()))}), {plan.samples_per_step} "
                 f"readings per step, settle {plan.settle_time:g} s. Session created "
                 f"{_e(_when(header.get('created')))} by dh-calib {_e(header.get('software', '?'))}.</p>")
    for note in plan.notes:
        parts.append(f"<p>plan note: {_e(note)}</p>")
    runs = session.runs()
    run_rows, total = [], 0.0
    for r in runs:
        duration = None if r.ended is None else r.ended - r.started
        total += duration or 0.0
        run_rows.append([str(r.id), _e(_when(r.started)), _e(_when(r.ended)),
                         "" if duration is None else f"{duration / 60:.1f} min", _e(r.outcome), _e(r.reason)])
    parts.append(_table(["run", "started", "ended", "duration", "outcome", "reason"], run_rows, left=6))
    steps = session.steps()
    missing = [s for s in steps if s.status == "missing"]
    readings = sum(len(s.readings) for s in steps)
    rejected = sum(s.rejected for s in steps)
    span = (max(st.t_end for st in steps) - min(st.t_start for st in steps)) if steps else 0.0
    parts.append(f"<p>Total run time {total / 60:.1f} min; first to last step {span / 60:.1f} min. {len(steps)} "
                 f"of {len(plan.steps)} plan steps recorded, {len(missing)} missing; {readings} tracker readings, "
                 f"{rejected} rejected as outliers.</p>")
    if missing:
        reasons = Counter(s.reason for s in missing)
        parts.append(_table(["missing steps: reason", "count"], [[_e(k), str(v)] for k, v in reasons.items()]))
    events = session.events()
    if events:
        parts.append(_table(["time", "run", "event", "message"],
                            [[_e(_when(t)), _e(run), _e(kind), _e(msg)] for t, run, kind, msg in events], left=4))
    drift = session.drift()
    fig = None
    if len(drift) >= 2:
        fig = figure_drift(drift)
        parts.append(f"<p>Drift: largest home displacement {max(d for _, d in drift) * MM:.4f} mm over "
                     f"{len(drift)} home checks.</p>")
    return "".join(parts), fig


def _when(t: float | None) -> str:
    return "" if t is None else time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(float(t)))


def _figure_html(fig: Figure, caption: str) -> str:
    uri = png_data_uri(fig)
    return f'<figure><img src="{uri}" alt="{_e(caption)}"><figcaption>{_e(caption)}</figcaption></figure>'


def report_html(
    ident: Identification,
    meas: Measurements,
    nominal: DHModel | None = None,
    nominal_name: str | None = None,
    session: SessionFile | None = None,
    reference: tuple[str, DHModel] | None = None,
    title: str | None = None,
    source: str | None = None,
    reference_note: str | None = None,
    cell: dict[str, Any] | None = None,
    verification: dict[str, Any] | None = None,
) -> str:
    """The report as one HTML document (str). It opens with the headline: the verdict, the accuracy before
    (nominal) and after (identified) at the held-out poses, and ``verification`` (the ``.verify.yaml`` of an
    ``acquire verify`` run of this result) when given.

    ``meas``: the measurements given to :func:`identify.results.pipeline.identify` (after the hold-out split), so
    fitted and held-out rows can be told apart. ``nominal``: deltas against it. ``reference``: (label, model)
    for another comparison, e.g. the controller's factory calibration; ``reference_note``: shown with the DH
    table, e.g. why there is no factory calibration. ``session``: adds the acquisition record. ``cell``: the
    mounting surface and the plan's swept envelope for the 3D view (see :func:`figure_frames`).
    """
    fit = meas.subset(_fit_rows(meas))
    full = ident
    ident = positions_view(ident, len(fit))
    if len(fit) != len(ident.refinement.residuals):
        raise ValueError(f"meas has {len(fit)} fitted rows, the identification {len(ident.refinement.residuals)}: "
                         "pass the measurements it was made from")
    references = ([(nominal_name or "nominal", nominal)] if nominal is not None else []) + (
        [reference] if reference is not None else [])
    title = title or (f"DH identification report: {nominal_name} ({ident.model.joint_types})" if nominal_name
                      else f"DH identification report: {ident.model.joint_types}")
    body = [f"<h1>{_e(title)}</h1>",
            f"<p>dh-calib {_e(__version__)}, generated {_e(_when(time.time()))}"
            + (f"; source <code>{_e(source)}</code>" if source else "") + ".</p>"]
    verdict = ident.verdict
    body.append(headline_html(verdict.status, [(c.name, c.status, c.message) for c in verdict.checks],
                              accuracy_summary(ident, meas, nominal, nominal_name), verification))
    body.append(f'<section id="verdict" class="verdict-{verdict.status}"><h2>Checks</h2>'
                + _table(["check", "status", "what it found"],
                         [[_e(c.name), _e(c.status), _e(c.message)] for c in verdict.checks], left=3)
                + "</section>")
    notes = list(ident.warnings) + list(ident.refinement.notes)
    if notes:
        body.append('<section id="notes"><h2>Notes</h2><ul>'  # what the fit did; what to worry about: the checks
                    + "".join(f"<li>{_e(w)}</li>" for w in notes) + "</ul></section>")
    body.append('<section id="dh-table"><h2>DH parameters</h2><p>Standard DH (lengths mm, angles deg, ± one '
                "standard uncertainty).</p>" + _dh_section(ident, references)
                + (f'<p class="warn">{_e(reference_note)}</p>' if reference_note else "") + "</section>")
    body.append(_beyond_dh_section(ident, fit))
    body.append('<section id="joints"><h2>Per joint</h2>')
    for axis in [] if ident.geometric is None else ident.geometric.axes:
        a = axis
        travel = f"{np.degrees(a.travel):.1f}°" if a.kind == "R" else f"{a.travel * MM:.1f} mm"
        radius = "" if np.isnan(a.radius) else f", radius {a.radius * MM:.2f} mm"
        caption = (f"Joint {a.joint}: sweep {a.sweep}, {a.samples} samples, travel {travel}{radius}, "
                   f"geometric-step fit RMS {a.rms * MM:.4f} mm")
        body.append(_figure_html(figure_joint(ident, fit, a.joint), caption))
    body.append("</section>")
    body.append('<section id="frames-3d"><h2>Axes and frames</h2>'
                + _figure_html(figure_frames(ident, fit, cell), "The identified arm at the home pose in its base frame "
                               "(DH frame 0), with the joint axes and the measured points" + (
                                   "; the mounting surface (green) and the space the plan swept the arm through "
                                   "(blue dots)" if cell is not None else "")) + "</section>")
    body.append('<section id="validation"><h2>Held-out validation</h2>')
    v = ident.validation
    check = meas.subset(meas.check & np.all(np.isfinite(meas.q), axis=1))  # held out, every joint read
    if v is None:
        body.append("<p>No held-out poses (add free poses, or rows with role=check).</p>")
    else:
        errors = np.linalg.norm(check.points - ident.predict(check.q), axis=1)
        body.append(f"<p>{v.samples} held-out poses: RMS {v.rms * MM:.4f} mm, max {v.max * MM:.4f} mm; expected "
                    f"RMS {v.expected * MM:.4f} mm (model bound {v.bound * MM:.4f} mm + tracker noise).</p>")
        body.append(_figure_html(figure_validation(errors, v.expected), "Errors at held-out poses"))
    body.append("</section>")
    body.append(_domain_section(ident, check))
    rows = [[str(s.sweep), "free" if s.joint == 0 else str(s.joint), str(s.samples), str(s.rejected),
             f"{s.rms * MM:.4f}"] for s in ident.sweeps]
    body.append('<section id="sweeps"><h2>Residuals per sweep</h2>'
                + _table(["sweep", "joint", "samples", "rejected", "RMS [mm]"], rows)
                + ("" if ident.orientation is None else f"<p>{_e(orientation_line(ident.orientation))}</p>")
                + _figure_html(figure_sweeps(ident, fit), "Residual norm of every fitted sample, per sweep")
                + "</section>" + full_pose_section(full, fit, _e, _table, _figure_html))
    if session is not None:
        text, fig = _acquisition_section(session)
        body.append('<section id="acquisition"><h2>Acquisition record</h2>' + text
                    + ("" if fig is None else _figure_html(fig, "Home re-measurements over time")) + "</section>")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{_e(title)}</title><style>{_CSS}</style></head><body>\n"
            + "\n".join(body) + "\n</body></html>\n")


def write_report(path: str | Path, text: str) -> None:
    """Write ``text`` (from :func:`report_html`) to ``path``, UTF-8."""
    Path(path).write_text(text, encoding="utf-8")
