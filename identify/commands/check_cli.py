"""``identify check RESULT DATA``: does a calibration still hold on new data?

Its options and help: identify/commands/sub_options.py (light, so that --help answers at once).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from common.errors import InputError
from common.outputs import check_outputs, write_output
from common.units import as_typed, mm, slip_hint
from identify.applications.calibrated import ResultError
from identify.applications.domain import result_outside
from identify.applications.holds import Check, check_models
from identify.applications.result_models import ResultModels, result_models
from identify.commands.sub_options import check_parser as build_parser
from identify.estimator.measurements import Measurements
from identify.io.csvio import read_measurements
from identify.io.result_io import finite
from identify.io.session_measurements import read_session
from session.schema import is_session_file

PROG = "identify check"


def load(args: argparse.Namespace) -> tuple[dict[str, Any], Measurements, list[str]]:
    """The result document, the new data's rows that can be predicted, and notes."""
    try:
        doc = yaml.safe_load(Path(args.result).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(f"{args.result}: no such result file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{args.result}: cannot be read ({type(exc).__name__})") from None
    except yaml.YAMLError:
        raise InputError(f"{args.result}: not YAML (a result file of identify --out?)") from None
    if not isinstance(doc, dict) or "joints" not in doc:
        raise InputError(f"{args.result}: not a result file of identify --out (no 'joints')")
    if is_session_file(Path(args.data)):
        meas = read_session(Path(args.data))[0].measurements
    else:
        meas = read_measurements(args.data, args.joints, args.units).measurements
    notes = []
    if meas.has_streams:
        notes.append(f"{int(meas.streamed.sum())} streamed rows: readings interpolated at the recorded clock offset "
                     "(not refined here)")
    read = np.all(np.isfinite(meas.q), axis=1)
    if not read.all():
        notes.append(f"{int((~read).sum())} rows without every joint reading left out (cannot be predicted)")
        meas = meas.subset(read)
    return doc, meas, notes


def run(args: argparse.Namespace) -> tuple[Check, ResultModels, Measurements, list[str]]:
    """Check per ``args``; InputError (one line) for bad input."""
    check_outputs([args.result, args.data], [("--out", args.out)], args.force)
    doc, meas, notes = load(args)
    try:
        if args.noise is not None:
            check_noise_stated(args.noise, as_typed(args, "noise"), meas.sigma)
            check_noise(args.noise, as_typed(args, "noise"), _check(doc, meas, None, args.refit_tool))
        models = result_models(doc, meas.q, meas.tp, args.noise)
        check = check_models(meas.points, meas.q, meas.tp, models.models, models.use, args.refit_tool)
    except (ResultError, ValueError) as exc:
        raise InputError(f"{args.result} on {args.data}: {exc}") from None
    found, line = result_outside(doc, meas.q)
    notes.append(line)
    if found is not None and found.count:
        notes.append("the check's figures pool the poses inside and outside the domain")
    return check, models, meas, notes


def _check(doc: dict[str, Any], meas: Measurements, noise: float | None, refit_tool: bool) -> Check:
    """The result's models checked on ``meas`` at tracker ``noise`` (m per axis; None: the result's)."""
    models = result_models(doc, meas.q, meas.tp, noise)
    return check_models(meas.points, meas.q, meas.tp, models.models, models.use, refit_tool)


UNIT_SLIP = 10.0  # a stated noise this many times the data's own scatter cannot be the tracker's: a unit slip


def check_noise(noise: float, typed: str | None, check: Check) -> None:
    """InputError (one line) when ``noise`` (m per axis, typed as ``typed``) is more than :data:`UNIT_SLIP` times
    the scatter the data show: the in-sample RMS per axis of ``check`` (made at the result's own noise), which
    holds the tracker's noise and every model error, so no real noise exceeds it tenfold (1000x: a bare number
    meant in mm)."""
    scatter = min(m.fitted_dof_rms for m in check.models) / math.sqrt(3.0)
    if noise > UNIT_SLIP * scatter:
        raise InputError(f"{slip_hint('--noise', typed, noise)} ({noise / scatter:.0f}x the scatter these data "
                         f"show, {mm(scatter)} per axis in-sample: no tracker is noisier than its own data)")


STATED_SLIP = 100.0  # a stated noise this many times the sigma the rows carry: a unit slip (an average of n readings
# states the reading's sigma / sqrt(n), so a true noise can be some ten times a row's sigma, a slip is 1000 times)


def check_noise_stated(noise: float, typed: str | None, sigma: Any) -> None:
    """InputError (one line) when ``noise`` (m per axis, typed as ``typed``) is more than :data:`STATED_SLIP` times
    the median per-axis sigma the data's rows carry (a session's, or a CSV ``sigma`` column; None: no check). It
    holds where :func:`check_noise` cannot: data of another arm or tool scatter far from the result, and that
    scatter hides a noise 1000x too large."""
    if sigma is None or not np.any(np.isfinite(sigma)):
        return
    stated = float(np.nanmedian(sigma))
    if stated > 0 and noise > STATED_SLIP * stated:
        raise InputError(f"{slip_hint('--noise', typed, noise)} ({noise / stated:.0f}x the sigma these data state, "
                         f"{mm(stated)} per axis (median of the rows))")


def as_dict(check: Check, models: ResultModels, meas: Measurements, notes: list[str]) -> dict[str, Any]:
    """The check as plain data (m, rad; rows 1-based as in the data file)."""
    def errors(e: Any) -> dict[str, Any]:
        return {"samples": e.samples, "rms": e.rms, "max": e.max}

    out: dict[str, Any] = {"status": check.status, "use": check.use, "folds": check.folds,
                           "refit_tool": check.refit_tool, "models": {}, "notes": notes}
    for m in check.models:
        reg = m.registration
        out["models"][m.name] = {
            "status": m.status, "reasons": m.reasons, "heldout": errors(m.heldout),
            "per_tp": {int(i): errors(e) for i, e in m.per_tp.items()},
            "fitted": errors(m.fitted), "fitted_dof_rms": m.fitted_dof_rms, "parameters": m.parameters,
            "expected_rms": m.expected, "expected_from": models.sources[m.name], "ratio": m.ratio,
            "limit": m.limit, "gross_rows": [int(r) for r in meas.row[m.gross]], "gross_cutoff": m.gross_cutoff,
            "tracker": {"rotation": reg.rotation.tolist(), "translation": reg.translation.tolist(),
                        "moved": reg.moved, "turned": reg.turned},
            **({"tool_change": {int(i): t.tolist() for i, t in reg.tools.items()}} if check.refit_tool else {}),
        }
    return finite(out)


def format_check(check: Check, models: ResultModels, meas: Measurements, notes: list[str]) -> str:
    """The verdict line, the tracker's move, one line per model, per tracked point, notes (<= 80 columns)."""
    c = check.chosen
    word = {"pass": "PASS: the calibration holds", "warn": "WARN: the calibration holds only roughly",
            "fail": "FAIL: the calibration does not hold"}[check.status]
    lines = [f"{word} ({c.name} model)",
             f"tracker: moved {c.registration.moved * 1e3:.1f} mm, turned "
             f"{math.degrees(c.registration.turned):.2f} deg since the calibration",
             "model     held-out rms   max  expected  ratio  in-sample  status",
             "              mm          mm     mm               mm"]
    for m in check.models:
        mark = "" if models.sources[m.name] == "stated" else "*"
        lines.append(f"{m.name:<9} {m.heldout.rms * 1e3:10.3f} {m.heldout.max * 1e3:8.3f} "
                     f"{m.expected * 1e3:7.3f}{mark:1} {m.ratio:6.2f} {m.fitted_dof_rms * 1e3:9.3f}  {m.status}")
    lines.append(f"held-out: each of {check.folds} blocks of poses predicted from a registration on the others")
    lines.append(f"in-sample: all kept rows, RMS dof-corrected for {c.parameters} registration parameters")
    if any(s != "stated" for s in models.sources.values()):
        lines.append("* expected computed from the result's covariance (it states none)")
    if len(models.tp_ids) > 1 or len(c.per_tp) > 1:
        for m in check.models:
            parts = [f"tp {i}: {e.rms * 1e3:.3f}" for i, e in m.per_tp.items() if e.samples]
            lines.append(f"{m.name} per tracked point, held-out rms mm: " + ", ".join(parts))
    for m in check.models:
        lines += [f"{m.name}: {r}" for r in m.reasons]
        if len(m.gross):
            rows = ", ".join(str(int(r)) for r in meas.row[m.gross][:8]) + (", ..." if len(m.gross) > 8 else "")
            lines.append(f"{m.name}: {len(m.gross)} rows left out as gross errors (> "
                         f"{m.gross_cutoff * 1e3:.2f} mm), at data lines {rows}")
    if check.refit_tool:
        for i, t in c.registration.tools.items():
            lines.append(f"tool refitted: tp {i} moved {np.linalg.norm(t) * 1e3:.3f} mm on the flange")
        lines.append("(a changed tool, or a change the last link shows as one, is not seen)")
    lines += [f"note: {n}" for n in notes]
    return "\n".join(_wrap(line) for line in lines)


def _wrap(line: str, width: int = 80) -> str:
    """``line`` broken at spaces into lines of at most ``width`` columns (continuations indented)."""
    return "\n".join(textwrap.wrap(line, width, subsequent_indent="  ", break_on_hyphens=False)) or line


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(sys.argv[2:] if argv is None else argv)
    try:
        check, models, meas, notes = run(args)
        doc = as_dict(check, models, meas, notes)
        if args.out:
            write_output(args.out, yaml.safe_dump(doc, sort_keys=False), force=args.force)
    except InputError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    print(json.dumps(doc, allow_nan=False) if args.json else format_check(check, models, meas, notes))
    if args.out and not args.json:
        print(f"check written to {args.out}")
    return 3 if check.status == "fail" else 0
