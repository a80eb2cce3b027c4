"""The verification report (``acquire verify``): one self-contained HTML file with the headline (the verdict, AP and
RP before and after compensation against what the result predicted), the per-pose table, a figure, and the run's
record. Built from the ``.verify.yaml`` summary and the session; lengths in mm on the page.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import numpy as np
from matplotlib.figure import Figure

from common import __version__
from identify.applications.iso9283 import FROM_FRAMES
from identify.report.headline import headline_html
from identify.report.html import _CSS, _acquisition_section, _e, _figure_html, _table, _when
from identify.report.verify_rows import iso_rows, orientation_rows, pose_cells

if TYPE_CHECKING:
    from session.store import SessionFile

MM = 1e3
MODES = ("before", "after")


def figure_accuracy(summary: dict[str, Any]) -> Figure:
    """AP (mm, log scale: before and after differ by orders of magnitude) and RP (mm, linear from zero) per pose,
    before and after, with the result's predictions; one legend below the plots, off the bars."""
    runs = summary.get("runs") or {}
    fig = Figure(figsize=(10, 4.2), layout="constrained")
    ax1, ax2 = fig.subplots(1, 2)
    x = np.arange(1, 6)
    for offset, mode, color in ((-0.2, "before", "C3"), (0.2, "after", "C2")):
        poses = {int(p["pose"][1:]): p for p in (runs.get(mode) or {}).get("poses", [])}
        ap = [poses[k]["ap"] * MM if k in poses else np.nan for k in x]
        rp = [poses[k]["rp"] * MM if k in poses else np.nan for k in x]
        ax1.bar(x + offset, ap, width=0.38, color=color, label=f"AP {mode}")
        ax2.bar(x + offset, rp, width=0.38, color=color, label=f"RP {mode}")
    predicted = summary.get("predicted") or {}
    if predicted.get("before"):
        ax1.plot(x - 0.2, np.array(predicted["before"]) * MM, "k_", ms=16, mew=2, label="predicted before")
    if summary.get("expected"):
        ax1.plot(x + 0.2, np.array(summary["expected"]) * MM, "kx", ms=8, label="uncertainty after (1 sigma, 3D)")
    ax1.set_yscale("log")
    ax2.set_ylim(bottom=0.0)
    for ax, title in ((ax1, "pose accuracy AP (log scale)"), (ax2, "pose repeatability RP")):
        ax.set_xticks(x, [f"P{k}" for k in x])
        ax.set_xlabel("pose")
        ax.set_ylabel("[mm]")
        ax.set_title(title)
    handles = {}
    for ax in (ax1, ax2):
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(label, handle)
    fig.legend(handles.values(), handles.keys(), loc="outside lower center", ncol=len(handles), fontsize=8)
    return fig


def _pose_rows(summary: dict[str, Any]) -> list[list[str]]:
    runs = summary.get("runs") or {}
    targets = np.array(summary["targets"]) * MM
    by_mode = {m: {int(p["pose"][1:]): p for p in (runs.get(m) or {}).get("poses", [])} for m in MODES}
    predicted = summary.get("predicted") or {}
    rows = []
    for k in range(1, 6):
        b, a = by_mode["before"].get(k), by_mode["after"].get(k)

        def cell(mode: str, p: dict[str, Any] | None, key: str, k: int = k) -> str:
            if p is None:
                return "-"
            if "figures" in (runs.get(mode) or {}):  # every figure with its uncertainty
                return pose_cells(runs[mode], key, k)
            return f"{p[key] * MM:.4f}" + (f" ± {p['ap_std'] * MM:.4f}" if key == "ap" else "")

        rows.append([f"P{k}", ", ".join(f"{v:.1f}" for v in targets[k - 1]),
                     f"{predicted['before'][k - 1] * MM:.4f}" if predicted.get("before") else "-",
                     cell("before", b, "ap"), f"0 ± {summary['expected'][k - 1] * MM:.4f}",
                     cell("after", a, "ap"), cell("before", b, "rp"), cell("after", a, "rp"), str(a["n"] if a else 0)])
    return rows


def _iso_extras(summary: dict[str, Any]) -> str:
    """Distance accuracy and repeatability (P2-P4), the drift of P1 within the run, vAP per pose and orientation,
    before and after, each ± its uncertainty; what was not measured and why."""
    runs = summary.get("runs") or {}
    rows = iso_rows(runs)
    out = ""
    if rows:
        out += ("<p>Beyond AP and RP (ISO 9283): distance accuracy AD = D̄ - D_c and repeatability RD = 3 S_D "
                "between P2 and P4 in each cycle (7.3); the drift of P1's AP and RP between the first and the last "
                "third of its visits (7.6, within this run); vAP, the largest distance between the barycentres of a "
                "pose's visits from the three approach directions (7.2).</p>"
                + _table(["figure [mm]", "before", "after"], rows))
    turns = orientation_rows(runs, per_pose=True)
    reason = (summary.get("orientation") or {}).get("reason")
    if turns:
        attained = ("the measured target frame (6-DoF readings) taken into the base frame, the commanded one the "
                    "commanded flange orientation times the result's tool_frame"
                    if (summary.get("orientation") or {}).get("source") == FROM_FRAMES else
                    "the rigid fit of the points the commanded pose puts the result's tracked points at to the "
                    "measured ones")
        out += ("<p>Orientation accuracy AP and repeatability RP (7.2.1, 7.2.2): a, b, c are the rotations about the "
                "base's x, y and z axes that take the commanded orientation to the attained one; each visit's "
                f"attained orientation is {attained}. AP = the mean of a (b, c), RP = 3 S.</p>"
                + _table(["figure [mrad]", "before", "after"], turns))
    elif reason:
        out += f"<p>Orientation was not measured: {_e(reason)}.</p>"
    for key in ("drift_note", "uncertainty"):
        if summary.get(key):
            out += f"<p>{'± ' if key == 'uncertainty' else ''}{_e(summary[key])}.</p>"
    return out


def verification_html(summary: dict[str, Any], header: dict[str, Any], source: str,
                      session: SessionFile | None = None) -> str:
    """The report as one HTML document: ``summary`` as written to ``.verify.yaml``, the session ``header``."""
    info = (header.get("config") or {}).get("verification") or {}
    robot = (header.get("robot") or {}).get("model", "robot")
    title = f"Verification report: {robot}"
    verdict = summary["verdict"]
    checks = [("verification", verdict["status"], verdict["message"])]
    body = [f"<h1>{_e(title)}</h1>",
            f"<p>dh-calib {_e(__version__)}, generated {_e(_when(time.time()))}; session <code>{_e(source)}</code>; "
            f"calibration <code>{_e(summary.get('result'))}</code> (its verdict: {_e(info.get('result_verdict'))})."
            "</p>",
            headline_html(verdict["status"], checks, None, summary, what="verification")]
    reg = summary.get("registration")
    if reg:
        body.append('<section id="registration"><h2>Tracker registration</h2>'
                    f"<p>Before judging anything the tracker frame is fitted again (rigid, 6 degrees of freedom) on "
                    f"{reg['poses']} poses of its own, none of them a test pose, with the result's {_e(reg['model'])} "
                    f"model: the tracker moved {reg['moved'] * MM:.2f} mm and turned {reg['turned_deg']:.3f}° since "
                    f"the calibration (its origin's displacement and rotation). Residuals held out (5 folds): "
                    f"{reg['heldout_rms'] * MM:.4f} mm RMS, at most {reg['heldout_max'] * MM:.4f} mm; the result "
                    f"predicts {reg['expected_rms'] * MM:.4f} mm ({reg['ratio']:.2f}x: {_e(reg['status'])}"
                    f"{'; ' + _e('; '.join(reg['reasons'])) if reg['reasons'] else ''}).</p></section>")
    body.append('<section id="poses"><h2>Per pose</h2>'
                f"<p>ISO 9283-style: five poses on the diagonal plane of a cube of edge {summary['edge'] * MM:.0f} mm "
                f"centred at {', '.join(f'{v * MM:.1f}' for v in summary['centre'])} mm (robot base frame), each "
                f"visited {summary['cycles']} times in the order P1, P5, P4, P3, P2; first commanded with the "
                f"{_e(summary.get('before_model', 'nominal model'))} (before: what the controller runs today), then "
                "with the identified one (after). AP: distance of the barycentre of the "
                "attained positions from the commanded one; RP: l̄ + 3 S_l; each ± its standard uncertainty. AP, "
                "RP, AD, RD and drift use the visits from the first approach direction (+x), as the standard's "
                "one-directional test. Missing steps: "
                f"{summary.get('missing_steps', 0)}.</p>"
                + _table(["pose", "target x, y, z [mm]", "predicted AP before [mm]", "AP before [mm]",
                          "predicted AP after [mm]", "AP after [mm]", "RP before [mm]", "RP after [mm]", "visits"],
                         _pose_rows(summary))
                + _iso_extras(summary)
                + _figure_html(figure_accuracy(summary), "AP and RP per pose, before and after compensation")
                + "".join(f"<p>note: {_e(n)}</p>" for n in info.get("notes", []))
                + (f"<p>domain: {_e(summary['domain']['text'])}</p>" if summary.get("domain") else "")
                + "</section>")
    if session is not None:
        text, fig = _acquisition_section(session)
        body.append('<section id="acquisition"><h2>Run record</h2>' + text
                    + ("" if fig is None else _figure_html(fig, "Home re-measurements over time")) + "</section>")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{_e(title)}</title><style>{_CSS}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")
