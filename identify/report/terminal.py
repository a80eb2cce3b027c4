"""Human-readable summary of an identification for the terminal (millimetres and degrees)."""

from __future__ import annotations

import numpy as np

from common import fit_width
from identify.results.pipeline import ClockFit, Identification, SweepFit
from kinematics.dh import DHModel

_SCALE = {"theta": np.degrees(1.0), "d": 1e3, "a": 1e3, "alpha": np.degrees(1.0)}
_UNIT = {"theta": "deg", "d": "mm", "a": "mm", "alpha": "deg"}


def _cell(value: float, std: float, fixed: bool, name: str) -> str:
    scale = _SCALE[name]
    if fixed:
        return f"{value * scale:10.4f} fixed   "
    return f"{value * scale:10.4f} ± {std * scale:<7.4f}"


def format_report(ident: Identification, nominal: DHModel | None = None, nominal_name: str | None = None) -> str:
    """Multi-line text: DH table ± uncertainty (and deltas vs nominal), base, tool, fit and validation."""
    model, std, ref = ident.model, ident.std, ident.refinement
    fixed = {f.name for f in ident.fixed}
    names = ("theta", "d", "a", "alpha")
    lines = [ident.verdict.summary()]
    lines += [f"  {c.status:<4}  {c.name}: {c.message}" for c in ident.verdict.checks]
    lines += format_models(ident)
    lines.append(f"Plain DH model (the result's top-level table), joints {model.joint_types} (standard DH; "
                 "lengths mm, angles deg)" + (f"; Δ: identified - {nominal_name or 'nominal'}" if nominal is not None
                                              else ""))
    head = ["", *(f"{n} [{_UNIT[n]}]" for n in names)] + ([f"Δ{n}" for n in names] if nominal is not None else [])
    rows = []
    for i in range(model.n_joints):
        cells = [f"J{i + 1} {model.joint_types[i]}"]
        for k, name in enumerate(names):
            value = model.dh_table()[i, k]
            cells.append(_cell(value, std[9 + 4 * i + k], f"{name}{i + 1}" in fixed, name).strip())
        if nominal is not None:
            delta = model.dh_table()[i] - nominal.dh_table()[i]
            delta[0] = np.angle(np.exp(1j * delta[0]))
            cells += [f"{d * _SCALE[n]:+8.3f}" for d, n in zip(delta, names, strict=True)]
        rows.append(cells)
    lines += fit_width.table(head, rows)  # split into column blocks on a narrow terminal
    t = model.base[:3, 3] * 1e3
    lines.append(f"base origin in tracker frame [mm]: {t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}"
                 f"  (± {', '.join(f'{s * 1e3:.3f}' for s in std[3:6])})")
    tool = model.tool * 1e3
    lines.append(f"tool (TP in frame {model.n_joints}) [mm]: {tool[0]:.3f}, {tool[1]:.3f}, {tool[2]:.3f}"
                 f"  (± {', '.join(f'{s * 1e3:.3f}' for s in std[6:9])})")
    for tp_id, t in zip(ident.tp_ids[1:], ident.tools[1:], strict=True):
        lines.append(f"tool of tracked point {tp_id} (frame {model.n_joints}) [mm]: "
                     + ", ".join(f"{x * 1e3:.3f}" for x in t))
    if ident.coupling is not None and not ident.coupling.is_identity:
        coupled = "; ".join(f"q{g[0] + 1} from readings {', '.join(str(r + 1) for r in g[1:])}"
                            for g in ident.coupling.coupled_groups())
        lines.append(f"coupled readings (q_dh = C . readings + offset): {coupled}")
    lines += format_extensions(ident)
    if ident.clock is not None:
        lines.append(format_clock(ident.clock))
    if ident.parallel:
        lines.append(f"parallel axes (within tolerance) at links {ident.parallel}: their d is conventional")
    lines.append(f"fixed (undetermined by the data): {', '.join(f.name for f in ident.fixed) or 'none'}")
    a = ident.adequacy
    split = (f"tracker noise {ref.noise * 1e3:.4f} mm per axis, model error {a.model_error * 1e3:.4f} mm per axis"
             if a.declared is not None or a.difference is not None else
             "noise and model error not separable (no sweeps, no --noise)")
    lines.append(f"fit: {int(ref.inliers.sum())} samples, residual RMS {ident.rms * 1e3:.4f} mm (3D), {split}, "
                 f"condition number {ref.condition:.3g}")
    if ident.orientation is not None:
        count, rejected, rms = ident.orientation
        lines.append(f"orientations (full-pose readings): {count} fitted, {rejected} rejected as outliers, residual "
                     f"RMS {rms * 1e3:.4f} mrad (3D); positions {int(ref.inliers.sum()) - count + rejected} samples")
        held = ident.validations.get(ident.use)
        if held is not None and held.orientation is not None:
            t = held.orientation
            lines.append(f"held-out orientations: {t.samples}, RMS {t.rms * 1e3:.4f} mrad (3D), expected "
                         f"{t.expected * 1e3:.4f} mrad")
    worst = max(ident.sweeps, key=lambda s: s.rms if np.isfinite(s.rms) else -1.0)
    lines.append("per sweep RMS [mm]: " + ", ".join(
        f"{_sweep_name(s)} " + (f"{s.rms * 1e3:.4f}" if np.isfinite(s.rms) else "none kept") for s in ident.sweeps
    ) + (f"  (worst: {_sweep_name(worst)}, sweep id {worst.sweep})" if np.isfinite(worst.rms) else ""))
    if ident.rejected_rows:
        lines.append(f"rejected outliers (CSV lines): {ident.rejected_rows}")
    if ident.geometric is not None:
        lines.append(f"geometric step alone (the paper's method): residual RMS {ident.geometric_rms * 1e3:.4f} mm")
    if not ident.validations:
        lines.append("validation: no held-out poses (add free poses, or rows with role=check)")
    for name, v in ident.validations.items():
        lines.append(
            f"validation of the {name} model on {v.samples} held-out poses: RMS {v.rms * 1e3:.4f} mm, max "
            f"{v.max * 1e3:.4f} mm; expected RMS {v.expected * 1e3:.4f} mm (model bound {v.bound * 1e3:.4f} mm + "
            "tracker noise)"
        )
        if len(v.per_tp) > 1:
            lines.append("  per tracked point: " + ", ".join(f"{tp}: {rms * 1e3:.4f} mm ({k})"
                                                             for tp, (k, rms, _) in v.per_tp.items()))
    for warning in ident.warnings + ref.notes:
        lines.append(f"note: {warning}")
    return "\n".join(fit_width.wrap_lines(lines))  # every line within the terminal's width


_EXT_SCALE = {"scale": (1e6, "ppm"), "ecc_sin": (np.degrees(1.0) * 3600, "arcsec"),
              "ecc_cos": (np.degrees(1.0) * 3600, "arcsec"), "compliance": (np.degrees(1.0) * 3600, "arcsec/(N m)")}


def _sweep_name(sweep: SweepFit) -> str:
    """``J2`` for a sweep of joint 2, ``free`` for the free poses."""
    return "free" if sweep.joint == 0 else f"J{sweep.joint}"


def format_models(ident: Identification) -> list[str]:
    """Which model to use, and what each written model predicts at the held-out poses."""
    figure = {name: (f"held-out {v.rms * 1e3:.4f} mm" if (v := ident.validations.get(name)) else "not validated")
              for name in ident.models}
    if ident.use == "extended":
        ext = ident.models["extended"]
        return [f"use: the extended model (DH + {len(ext.coefs)} joint-error coefficients: extensions.model and "
                f"extensions.terms of the result), {figure['extended']}; the plain DH table below, "
                f"{figure['plain']}, is for tools that cannot apply joint errors"]
    return [f"use: the plain DH model (no joint errors selected), {figure['plain']}"]


def format_clock(clock: ClockFit) -> str:
    """One line: the fitted clock relation of the streamed rows."""
    drift = "" if clock.drift is None else f", drift {clock.drift * 1e6:+.1f} ± {clock.drift_std * 1e6:.1f} ppm"
    if clock.sweeps:
        each = ", ".join(f"{s}: {o * 1e3:+.3f} ± {e * 1e3:.3f}" for s, o, e in clock.sweeps)
        return (f"clock of {clock.rows} streamed rows, one offset per sweep (they differ): robot time = tracker "
                f"time + offset (ms; {each}){drift}")
    return (f"clock of {clock.rows} streamed rows: robot time = tracker time {clock.offset * 1e3:+.3f} "
            f"± {clock.offset_std * 1e3:.3f} ms{drift}")


def format_extensions(ident: Identification) -> list[str]:
    """Joint errors selected beyond DH (with uncertainty) and why the others were not, one line each."""
    if not ident.decisions:
        return []
    out = []
    for name, value, std in ident.extensions:
        family = name.rsplit("_", 1)[0]
        scale, unit = _EXT_SCALE[family]
        out.append(f"joint error {name}: {value * scale:+.3f} ± {std * scale:.3f} {unit}")
    rejected = [d for d in ident.decisions if not d.selected and d.ratio is not None]
    if not ident.extensions:
        out.append(f"joint errors: none selected ({len(ident.decisions)} candidates tested; statistics below "
                   "the information criterion)")
    for d in rejected:
        out.append(f"joint error {d.candidate.family} on joint {d.candidate.joint + 1} not selected: {d.reason}")
    return out


def format_reference(ident: Identification, label: str, reference: DHModel) -> str:
    """Lines of the identified DH table's deltas against ``reference`` (e.g. the controller's factory
    calibration): d, a in mm; theta, alpha in deg (theta wrapped to ±180)."""
    names = ("theta", "d", "a", "alpha")
    lines = [f"Δ identified vs {label} (d, a mm; theta, alpha deg):"]
    for i in range(ident.model.n_joints):
        delta = ident.model.dh_table()[i] - reference.dh_table()[i]
        delta[0] = np.angle(np.exp(1j * delta[0]))
        lines.append(f"{i + 1:>5}  " + " ".join(f"{name} {d * _SCALE[name]:+9.4f}"
                                            for d, name in zip(delta, names, strict=True)))
    return "\n".join(fit_width.wrap_lines(lines))
