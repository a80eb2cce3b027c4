"""ISO 9283 beyond AP/RP in ``acquire verify``: do the stated uncertainties match the spread, and is vAP found?

    .venv/bin/python -m bench.verify_iso [--draws 50] [--cycles 6] [--backlash 2e-4]

One calibration of the simulated UR5e with three reflectors (``acquire --robot mock:ur5e?points=3 --tracker mock``,
the default plan, 0.05 mm tracker noise). Then, per draw, the real ``acquire verify`` command (in process, virtual
clock) on the same arm with ``backlash`` rad of play in every joint (``mock:ur5e?points=3&backlash=B``), the tracker's
noise seeded by the draw: every figure (AP, RP, AD, RD, dAP, dRP, vAP, orientation AP and RP, before and after) and
the standard uncertainty it states.

1. **Uncertainty against spread**: per figure, the standard deviation of its value over the draws against the mean
   of the uncertainties stated, pooled per kind of figure (AP, RP, ... over the poses and both runs) as
   sqrt(mean u²) / sqrt(mean spread²). Target: every kind within ±20 % (the pooled spread of 10 figures over 50
   draws is known to about 3 %; a single figure's to 10 %, so single ratios scatter more).
2. **vAP found**: the vAP the truth implies (the backlash replayed over the joints read at every step) against the
   measured one, per pose, run and draw. Target: every measured vAP within 4 stated uncertainties (plus 5 µm) of the
   truth's, and every truth's vAP above 4 stated uncertainties (the direction-dependent error is seen, not noise).

Exit status 1 when a target is missed.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import contextlib
import io
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from acquire.commands.cli import main as acquire
from acquire.running.session import Session
from drivers.sim.rig import SimulatedRig
from drivers.sim.world import backlash_play
from kinematics.dh import points_from_joints

ROBOT = "mock:ur5e?points=3"
TOLERANCE = 0.2  # stated / spread, pooled per kind of figure


def _quiet(args: list[str]) -> int:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return acquire(args)


def _truth_vap(session: Path, rig: SimulatedRig, lash: float) -> dict[str, np.ndarray]:
    """Per run, the vAP (5,) of each pose on the rig's truth for the joints the session read, through the
    calibration's base: the backlash replayed from home over every step in order."""
    with Session.open(session) as s:
        info, steps = s.header["config"]["verification"], s.steps()
    base = np.array(info["base"])
    lash_now, last = np.zeros(rig.model.n_joints), np.array(rig.model.home, dtype=float)
    reached: dict[tuple[str, int, int], list[np.ndarray]] = {}
    for record in steps:
        q = np.array(record.q_act)
        lash_now, last = backlash_play(lash_now, q - last, lash), q
        label = info["steps"][record.plan_index]
        if label[0] in ("before", "after"):
            point = points_from_joints(replace(rig.truth, tool=rig.tools[0]), (q + lash_now)[None])[0]
            reached.setdefault((label[0], label[2], label[3]), []).append((point - base[:3, 3]) @ base[:3, :3])
    out = {}
    for mode in ("before", "after"):
        vap = []
        for k in range(1, 6):
            bary = [np.mean(reached[(mode, k, h)], axis=0) for h in (1, 2, 3)]
            vap.append(max(np.linalg.norm(a - b) for a in bary for b in bary))
        out[mode] = np.array(vap)
    return out


def _kind(name: str) -> str:
    return name.split(" ")[0]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.verify_iso", description=__doc__.split("\n")[0])
    parser.add_argument("--draws", type=int, default=50)
    parser.add_argument("--cycles", type=int, default=6)
    parser.add_argument("--backlash", type=float, default=2e-4, help="rad, every joint (default 0.2 mrad)")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    print(f"python {sys.version.split()[0]}, numpy {np.__version__}, {time.strftime('%Y-%m-%d')}; {args.draws} draws, "
          f"{args.cycles} cycles, UR5e with 3 reflectors, backlash {args.backlash * 1e3:.2f} mrad, 0.05 mm noise")
    robot = f"{ROBOT}&backlash={args.backlash}"
    rig = SimulatedRig.from_spec(ROBOT, "mock")
    values: dict[str, list[float]] = {}
    stated: dict[str, list[float]] = {}
    vap_rows = []  # (measured, truth, stated) per pose, run and draw
    codes, ratios = [], []  # verify's exit codes; registered residuals over what the result predicts
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        cal = folder / "cal.session"
        if _quiet(["--robot", ROBOT, "--tracker", "mock", "--session", str(cal), "--quiet"]) != 0:
            print("the calibration failed")
            return 1
        result = cal.with_suffix(".result.yaml")
        for k in range(args.draws):
            session = folder / f"v{k}.session"
            codes.append(_quiet(["verify", "--result", str(result), "--robot", robot, "--tracker",
                                 f"mock?seed={k + 1}", "--session", str(session), "--cycles", str(args.cycles),
                                 "--quiet"]))
            summary = yaml.safe_load(session.with_suffix(".verify.yaml").read_text())
            ratios.append(summary["registration"]["ratio"])
            truth = _truth_vap(session, rig, args.backlash)
            for mode in ("before", "after"):
                run = summary["runs"][mode]
                for name, value in run["figures"].items():
                    values.setdefault(f"{name} {mode}", []).append(value)
                    stated.setdefault(f"{name} {mode}", []).append(run["uncertainty"][name])
                vap_rows += [(run["figures"][f"vap P{p}"], truth[mode][p - 1], run["uncertainty"][f"vap P{p}"])
                             for p in range(1, 6)]
    print(f"verify exit codes: {', '.join(f'{c}: {codes.count(c)}' for c in sorted(set(codes)))}; registered residuals"
          f" / predicted: median {np.median(ratios):.2f}, largest {max(ratios):.2f} (3: fail, another arm or tool)")
    kinds: dict[str, list[tuple[float, float]]] = {}
    for name, v in values.items():
        if len(v) == args.draws:
            kinds.setdefault(_kind(name), []).append((float(np.std(v, ddof=1)), float(np.sqrt(np.mean(np.square(
                stated[name]))))))
    print(f"{'figure':8} {'n':>3} {'spread':>10} {'stated':>10} {'pooled':>7} {'single ratios':>15}  "
          "(spread and stated: RMS over the figures; mm, or mrad for orientation)")
    met = True
    for kind, rows in sorted(kinds.items()):
        spread, claim = np.array(rows).T
        pooled = float(np.sqrt(np.mean(claim**2)) / np.sqrt(np.mean(spread**2)))
        single = claim / spread
        met &= abs(pooled - 1.0) <= TOLERANCE
        rms_spread, rms_claim = np.sqrt(np.mean(spread**2)) * 1e3, np.sqrt(np.mean(claim**2)) * 1e3
        print(f"{kind:8} {len(rows):3d} {rms_spread:10.4f} {rms_claim:10.4f}"
              f" {pooled:7.3f} {single.min():7.2f}-{single.max():.2f}")
    vap = np.array(vap_rows)
    within = int(np.sum(np.abs(vap[:, 0] - vap[:, 1]) <= 4 * vap[:, 2] + 5e-6))
    seen = int(np.sum(vap[:, 1] > 4 * vap[:, 2]))
    print(f"vAP (backlash {args.backlash * 1e3:.2f} mrad): truth's {vap[:, 1].min() * 1e3:.4f}-"
          f"{vap[:, 1].max() * 1e3:.4f}"
          f" mm; |measured - truth's| median {np.median(np.abs(vap[:, 0] - vap[:, 1])) * 1e3:.4f} mm, within 4 stated "
          f"uncertainties in {within}/{len(vap)}; truth's above 4 stated uncertainties (median "
          f"{np.median(vap[:, 2]) * 1e3:.4f} mm) in {seen}/{len(vap)}")
    met &= within == len(vap) and seen == len(vap)
    print(f"wall time {time.perf_counter() - t0:.0f} s")
    print("targets: " + ("met" if met else "MISSED"))
    return 0 if met else 1


if __name__ == "__main__":
    sys.exit(main())
