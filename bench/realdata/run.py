"""Real-data benchmark (issue 27): every public robot-calibration set the data folder holds, one table per set.

    .venv/bin/python -m bench.realdata DATA [--set boby2021 ...] [--out DIR] [--pybotics-python PATH]
    make bench-realdata DATA=folder

``DATA`` holds one sub-folder per set, named as the set (``DATA/boby2021/``, ``DATA/hust2022/``,
``DATA/zhang2016/``; what each must hold: ``bench/realdata/README.md``). Nothing is downloaded. Per set present:
the converter writes the measurement CSV (and the second session's, where the set has one) into ``--out``
(default: a temporary folder); the product identifies it as a user would (``identify CSV --out result.yaml``,
in-process, timed, with ``--robot DATA/<set>/robot.yaml`` when the folder has a nominal model, else the set's
own in ``bench/realdata/robots/``); the written result's plain and extended models are read back and scored on
the check rows by this package's own forward model (:mod:`bench.realdata.score`), and on the second session
after a rigid re-registration of the tracker (fitted on its even rows, scored on its odd ones). A DH-only
least-squares baseline (:mod:`bench.realdata.baseline`) and, where its venv exists, pybotics are fitted to the
same fit rows from the product's plain model and scored the same way.

Targets (exit status 1 when one is missed): the plain model's check RMS <= 1.02x the baseline's; the extended
model no worse than the plain one on the second session; no model the verdict passes whose independently scored
check RMS exceeds what the file states for it (its expected RMS) by more than 2 %.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from scipy.stats import chi2

from bench.realdata import baseline, boby2021, hust2022, score, zhang2016
from bench.realdata.common import Converted, DataError, rigid_fit, rms

SETS = {module.NAME: module for module in (boby2021, hust2022, zhang2016)}
BASELINE_TARGET = 1.02
FALSE_ALARM = 1e-3  # a stated figure is missed when the check RMS exceeds it beyond its chi-square spread at this rate


def stated_limit(poses: int) -> float:
    """How far above its stated expectation an RMS over ``poses`` 3D errors may land by chance (ratio)."""
    k = 3 * max(poses, 1)
    return float(np.sqrt(chi2.isf(FALSE_ALARM, k) / k))


@dataclass
class Row:
    """One model's scores (m): check rows of the fit session, second session (re-registered); fit time (s)."""

    model: str
    check: float = float("nan")
    second: float = float("nan")
    stated: float = float("nan")
    seconds: float = float("nan")
    note: str = ""


@dataclass
class SetResult:
    name: str
    rows: list[Row] = field(default_factory=list)
    verdict: str = ""
    missed: list[str] = field(default_factory=list)
    skipped: str = ""


def second_session_rms(model: score.Model, second: Converted) -> float:
    """RMS (m) on the odd rows of the second session after a rigid registration fitted on its even rows."""
    predicted = model.predict(second.q, second.tp)
    even = np.arange(len(second.q)) % 2 == 0
    rotation, shift = rigid_fit(predicted[even], second.points[even])
    moved = predicted[~even] @ rotation.T + shift
    return rms(moved - second.points[~even])


def identify_in_process(csv: Path, result: Path, robot: Path | None) -> tuple[int, float, str]:
    """Run ``identify`` as its command does; exit code, wall time (s) and what it printed."""
    from identify.commands.cli import main

    argv = [str(csv), "--out", str(result), "--force"] + (["--robot", str(robot)] if robot else [])
    text = io.StringIO()
    began = time.perf_counter()
    with contextlib.redirect_stdout(text), contextlib.redirect_stderr(text):
        code = main(argv)
    return code, time.perf_counter() - began, text.getvalue()


def pybotics_row(python: str, start: score.Model, data: Converted, second: Converted | None) -> Row:
    """pybotics' calibration (its own venv, ``bench._pybotics_worker``) on the first tracked point's fit rows,
    started from ``start``, scored like the others on that point's check rows (and the second session's)."""
    from bench.pybotics_compare import run_pybotics
    from kinematics.dh import DHModel

    first = int(data.tp.min())
    one = data.tp == first
    model = DHModel(start.types, *start.table.T, base=start.base, tool=start.tools[first])
    fit, check = one & ~data.check, one & data.check
    q_check = data.dh_values()[check]
    if second is not None:
        q_check = np.vstack([q_check, second.dh_values()[second.tp == first]])
    out = run_pybotics(python, model, data.dh_values()[fit], data.points[fit], q_check)
    n = int(check.sum())
    row = Row(f"pybotics (point {first} only)", seconds=float(out["seconds"]),
              check=rms(out["predicted"][:n] - data.points[check]))
    if second is not None:
        mine = second.tp == first
        predicted, measured = out["predicted"][n:], second.points[mine]
        even = np.arange(len(measured)) % 2 == 0
        rotation, shift = rigid_fit(predicted[even], measured[even])
        row.second = rms(predicted[~even] @ rotation.T + shift - measured[~even])
    return row


def run_set(name: str, folder: Path, out: Path, pybotics: str | None = None) -> SetResult:
    module = SETS[name]
    result = SetResult(name)
    data = module.convert(folder)
    second = module.convert_second(folder) if hasattr(module, "convert_second") else None
    csv = data.write(out / f"{name}.csv")
    if second is not None:
        second.write(out / f"{name}.second.csv")
    robot = folder / "robot.yaml"
    robot = robot if robot.is_file() else getattr(module, "NOMINAL", None)
    if data.joint.max() == 0 and robot is None:
        result.skipped = f"free poses only and no nominal model ({folder / 'robot.yaml'} missing)"
        return result
    code, seconds, printed = identify_in_process(csv, out / f"{name}.result.yaml", robot)
    if code not in (0, 3):
        result.skipped = f"identify exited {code}: {printed.strip().splitlines()[-1] if printed.strip() else ''}"
        return result
    doc = yaml.safe_load((out / f"{name}.result.yaml").read_text(encoding="utf-8"))
    result.verdict = doc["verdict"]["status"]
    fit, check = ~data.check, data.check
    written = score.models(doc)
    stated = score.stated(doc)
    for label, model in written.items():
        row = Row(f"product {label}", seconds=seconds, stated=stated.get(label, float("nan")))
        if not model.scorable:
            row.note = "holds compliance terms: not scored"
        else:
            row.check = rms(model.predict(data.q[check], data.tp[check]) - data.points[check])
            if second is not None:
                row.second = second_session_rms(model, second)
        result.rows.append(row)
    if "extended" not in written and (doc.get("extensions") or {}).get("terms"):
        result.rows.append(Row("product extended", note="joint errors without extensions.model: no DH reader "
                                                        "can use them (file predates issue 23)"))
    start = written["plain"]
    fitted, fit_seconds = baseline.fit(start, data.q[fit], data.points[fit], data.tp[fit])
    base = Row("DH-only least squares", seconds=fit_seconds,
               check=rms(fitted.predict(data.q[check], data.tp[check]) - data.points[check]))
    if second is not None:
        base.second = second_session_rms(fitted, second)
    result.rows.append(base)
    if pybotics:
        result.rows.append(pybotics_row(pybotics, start, data, second))
    result.rows.append(Row("published", note=getattr(module, "PUBLISHED", None) or "none for this split"))
    result.missed = targets(result.rows, result.verdict, int(np.sum(check)), doc.get("use", "plain"))
    return result


def targets(rows: list[Row], verdict: str, poses: int, use: str = "plain") -> list[str]:
    """The issue's targets missed by these rows (``poses``: check rows behind each check RMS; ``use``: the model
    the result says to use)."""
    by = {r.model: r for r in rows}
    missed = []
    plain, ext, base = by.get("product plain"), by.get("product extended"), by["DH-only least squares"]
    if plain and plain.check > BASELINE_TARGET * base.check:
        missed.append(f"plain {plain.check * 1e3:.3f} mm > {BASELINE_TARGET}x baseline {base.check * 1e3:.3f} mm")
    if plain and ext and np.isfinite(ext.second) and ext.second > plain.second:
        missed.append(f"extended {ext.second * 1e3:.3f} mm worse than plain {plain.second * 1e3:.3f} mm "
                      "on the second session")
    for row in (plain, ext):
        # the model the result says to use is vouched for by a pass or a warn; the other one only by a pass (the
        # holdout check turns the verdict to warn, naming it, when that model misses its own expectation)
        used = row is not None and row.model == f"product {use}"
        vouched = row and verdict in (("pass", "warn") if used else ("pass",)) and np.isfinite(row.stated)
        if vouched and row.check > stated_limit(poses) * row.stated:
            missed.append(f"{row.model} passes its verdict ({verdict}) but predicts {row.check * 1e3:.3f} mm "
                          f"where it states {row.stated * 1e3:.3f} mm (beyond the {stated_limit(poses):.3f}x "
                          f"chance allows over {poses} rows)")
    return missed


def _mm(value: float) -> str:
    return "-" if not np.isfinite(value) else f"{value * 1e3:.3f}"


def table(result: SetResult) -> str:
    """The set's Markdown table."""
    if result.skipped:
        return f"### {result.name}\n\nnot run: {result.skipped}\n"
    lines = [f"### {result.name} (verdict: {result.verdict})", "",
             "| model | check RMS (mm) | second session RMS (mm) | stated (mm) | time (s) | note |",
             "|---|---|---|---|---|---|"]
    for r in result.rows:
        time_text = "-" if not np.isfinite(r.seconds) else f"{r.seconds:.2f}"
        lines.append(f"| {r.model} | {_mm(r.check)} | {_mm(r.second)} | {_mm(r.stated)} | {time_text} | {r.note} |")
    lines += [""] + [f"- target missed: {m}" for m in result.missed]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.realdata", description=__doc__.split("\n")[0])
    parser.add_argument("data", type=Path, help="folder with one sub-folder per set (see bench/realdata/README.md)")
    parser.add_argument("--set", action="append", choices=sorted(SETS), help="only these sets (default: all present)")
    parser.add_argument("--out", type=Path, help="folder for the converted CSVs and results (default: temporary)")
    parser.add_argument("--pybotics-python", default="/tmp/pyb-venv/bin/python",
                        help="python of a venv with pybotics (see bench/pybotics_compare.py); skipped if absent")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        print(f"bench.realdata: error: {args.data}: not a folder", file=sys.stderr)
        return 2
    names = args.set or sorted(SETS)
    present = [n for n in names if (args.data / n).is_dir()]
    if not present:
        print(f"bench.realdata: error: {args.data} holds none of {', '.join(names)}", file=sys.stderr)
        return 2
    pybotics = args.pybotics_python if Path(args.pybotics_python).exists() else None
    if pybotics is None:
        print(f"pybotics: {args.pybotics_python} not found, its rows are left out")
    status = 0
    with tempfile.TemporaryDirectory() as scratch:
        out = args.out or Path(scratch)
        out.mkdir(parents=True, exist_ok=True)
        for name in present:
            try:
                result = run_set(name, args.data / name, out, pybotics)
            except DataError as exc:
                print(f"bench.realdata: error: {name}: {exc}", file=sys.stderr)
                return 2
            print(table(result))
            status |= bool(result.missed)
    for name in sorted(set(names) - set(present)):
        print(f"{name}: not in {args.data}")
    return int(status)


if __name__ == "__main__":
    sys.exit(main())
