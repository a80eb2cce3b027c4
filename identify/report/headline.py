"""The first screen of the reports: can the result be trusted, and how accurate is the robot before and after.

:func:`accuracy_summary` computes, at the held-out poses of an identification, the TP error of the nominal model
(placed by least squares on the identified model: the best a cell registration can do with the catalogue model)
and of the identified model: predicted (from the identified model and its covariance) and measured (against the
held-out measurements, tracker noise included), each with its standard uncertainty. :func:`headline_html` shows
that, the verdict and, after a verification run (``acquire verify``), the measured AP and RP before and after.
Units: m inside, mm on the page.
"""

from __future__ import annotations

import html
import math
from typing import Any

import numpy as np

from identify.applications.calibrated import CalibratedModel
from identify.estimator.estimate import place_nominal
from identify.estimator.measurements import Measurements
from identify.results.pipeline import Identification
from kinematics.dh import DHModel, points_from_joints

MM = 1e3


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(np.atleast_2d(values) ** 2, axis=1))))


def rms_std(rms: float, count: int) -> float:
    """Standard uncertainty (m) of a 3D RMS error over ``count`` poses, from its own scatter (Gaussian errors:
    3·count squared components, relative standard deviation 1/sqrt(6·count))."""
    return rms / math.sqrt(6 * count) if count else float("nan")


def accuracy_summary(ident: Identification, meas: Measurements, nominal: DHModel | None,
                     nominal_name: str | None) -> dict[str, Any] | None:
    """Before (nominal) and after (identified) TP errors at the held-out poses of ``meas`` (None without any)."""
    check = meas.subset(meas.check & np.all(np.isfinite(meas.q), axis=1))
    if not len(check):
        return None
    model = CalibratedModel.from_identification(ident)
    k = len(check)
    predicted = model.points(check.q)
    after_pred = model.expected_rms(check.q)
    # measured: the figure of the written model the result recommends (identify.results.validation), not of the fit's
    # lines
    after_meas = ident.validation.rms if ident.validation is not None else _rms(check.points - predicted)
    noise = ident.adequacy.noise if check.sigma is None else float(np.sqrt(np.mean(check.sigma**2)))
    out: dict[str, Any] = {
        "poses": k, "noise_3d": math.sqrt(3) * noise,
        "after": {"label": f"identified, {ident.use} model", "predicted": after_pred, "measured": after_meas,
                  "measured_std": rms_std(after_meas, k), "expected_measured": ident.validation.expected
                  if ident.validation is not None else None},
    }
    if nominal is not None:
        ref = ident.refinement
        q_fit = ref.q[ref.inliers]  # DH joint values (the nominal model's); the identified model takes readings
        finite = np.all(np.isfinite(q_fit), axis=1)
        placed, _ = place_nominal(nominal, q_fit[finite], model.points(model.readings(q_fit[finite])))
        before = points_from_joints(placed, model.dh_values(check.q))
        out["before"] = {"label": f"nominal {nominal_name or ''}".strip(), "predicted": _rms(predicted - before),
                         "predicted_std": after_pred, "measured": _rms(check.points - before),
                         "measured_std": rms_std(_rms(check.points - before), k)}
    return out


def _e(value: Any) -> str:
    return html.escape(str(value))


def _mm(value: float | None, std: float | None = None, digits: int = 4) -> str:
    if value is None or not math.isfinite(value):
        return "-"
    text = f"{value * MM:.{digits}f}"
    if std is not None and math.isfinite(std):
        text += f" ± {std * MM:.{digits}f}"
    return text + " mm"


def headline_html(status: str, checks: list[tuple[str, str, str]], accuracy: dict[str, Any] | None,
                  verification: dict[str, Any] | None = None, what: str = "result") -> str:
    """The headline section: ``status`` (pass | warn | fail) with the messages of ``checks`` (name, status,
    message) that did not pass; the before/after table of ``accuracy`` (:func:`accuracy_summary`) and of
    ``verification`` (the summary of ``acquire verify``: ``.verify.yaml``)."""
    bad = [(n, s, m) for n, s, m in checks if s != "pass"]
    parts = [f'<section id="headline" class="verdict-{_e(status)}"><h2>Verdict: {_e(status.upper())}</h2>']
    if bad:
        parts.append("<ul>" + "".join(f"<li><b>{_e(n)}</b> ({_e(s)}): {_e(m)}</li>" for n, s, m in bad) + "</ul>")
    else:
        parts.append(f"<p>Every check of the {_e(what)} passed ({len(checks)} checks, below).</p>" if len(checks) > 1
                     else f"<p>The {_e(what)} passed.</p>")  # one check: its message is the headline's own
    rows: list[list[str]] = []
    if accuracy is not None:
        k = accuracy["poses"]
        before = accuracy.get("before") or {}
        after = accuracy["after"]
        rows.append([f"predicted TP error at the {k} held-out poses (3D RMS)",
                     _mm(before.get("predicted"), before.get("predicted_std")) if before else "no nominal model",
                     _mm(after["predicted"]) + " (covariance and model error)"])
        rows.append([f"measured at those poses (tracker noise {_mm(accuracy['noise_3d'], digits=3)} 3D included)",
                     _mm(before.get("measured"), before.get("measured_std")) if before else "-",
                     _mm(after["measured"], after["measured_std"])
                     + (f" (expected {_mm(after['expected_measured'])})" if after.get("expected_measured") else "")])
    if verification is not None:
        runs = verification.get("runs") or {}
        b, a = runs.get("before") or {}, runs.get("after") or {}
        predicted = verification.get("predicted") or {}
        rows.append([f"AP, pose accuracy (worst of 5 poses; {verification.get('cycles')} cycles)",
                     _mm(b.get("ap_max")) + (f" (predicted {_mm(max(predicted.get('before') or [float('nan')]))})"
                                              if predicted.get("before") else ""),
                     _mm(a.get("ap_max")) + (f" (predicted 0 ± {_mm(max(verification.get('expected') or [0.0]))})"
                                              if verification.get("expected") else "")])
        rows.append(["RP, pose repeatability (worst of 5 poses; tracker noise per visit included)",
                     _mm(b.get("rp_max")), _mm(a.get("rp_max"))])
        v = verification.get("verdict") or {}
        parts.append(f"<p><b>Verification ({_e(v.get('status', '?'))}):</b> {_e(v.get('message', ''))}</p>")
    if rows:
        label_before = ((accuracy or {}).get("before") or {}).get("label") or "nominal model"
        label_after = ((accuracy or {}).get("after") or {}).get("label") or "identified"
        head = ["", f"before ({_e(label_before)})", f"after ({_e(label_after)})"]
        body = "".join("<tr>" + "".join(f'<td class="l">{_e(c)}</td>' if i == 0 else f"<td>{_e(c)}</td>"
                                         for i, c in enumerate(r)) + "</tr>" for r in rows)
        parts.append('<div class="scroll"><table><tr>' + "".join(f"<th>{h}</th>" for h in head) + "</tr>" + body
                     + "</table></div>")
    parts.append("</section>")
    return "".join(parts)
