"""Verification that registers first: does ``acquire verify`` see through a moved tracker and catch another arm?

    .venv/bin/python -m bench.verify_registration [--draws 50] [--cycles 3]

One calibration of the simulated UR5e of ``mock:ur5e`` (seed 0: sweeps, 20 free poses, 0.05 mm tracker noise,
identified against the nominal, written and read back). Then, in process (the real ``acquire verify`` command on
the mock rig, virtual clock), per draw:

1. ``moved``: the tracker put back elsewhere (a uniformly random rotation, any angle, and a shift of 0.5-2 m in a
   random direction; its own noise seed): the verdict, exit code, how far the registration says the tracker moved
   and turned against the truth, and the largest difference over the five poses and both runs between the measured
   AP and the AP the simulated truth implies for the recorded commands (what the test would measure with a perfect
   registration and no noise);
2. ``another arm``: the same model with other DH errors (``arm=`` seed) where the calibrated arm stood, tracker
   not moved: the verdict and exit code, and the registered residuals over what the result predicts.

Targets: every ``moved`` draw passes (exit 0) with every AP within 0.2 mm of the truth's (the tolerance of
tests/acquire/test_verify.py: barycentre noise at chi-square 1e-4 plus the registration's allowance) and every
``another arm`` draw fails with exit 3. Exit status 1 when a target is missed.
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
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from acquire.commands.cli import main as acquire
from acquire.running.session import Session
from config.robots import load_robot
from drivers.sim.rig import SimulatedRig
from identify.io.result_io import result_to_dict
from identify.results.pipeline import identify
from identify.simulators.simulate import simulate
from kinematics.dh import points_from_joints

NOISE = 5e-5
AP_TOLERANCE = 2e-4  # m: measured AP against the truth's, every pose and run
ROBOT = load_robot("ur5e")


def _calibrate(folder: Path) -> tuple[Path, object]:
    truth = SimulatedRig("ur5e", seed=0).truth
    meas, _ = simulate(truth, ROBOT.home, ROBOT.limits, np.random.default_rng(4), noise=NOISE, free_poses=20,
                       check_poses=10)
    path = folder / "cal.result.yaml"
    path.write_text(yaml.safe_dump(result_to_dict(identify(meas, ROBOT.nominal), ROBOT.nominal, "ur5e")))
    return path, truth


def _verify(result: Path, session: Path, robot: str, tracker: str, cycles: int) -> tuple[int, dict]:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        code = acquire(["verify", "--result", str(result), "--robot", robot, "--tracker", tracker, "--session",
                        str(session), "--cycles", str(cycles), "--quiet"])
    return code, yaml.safe_load(session.with_suffix(".verify.yaml").read_text())


def _ap_error(session: Path, summary: dict, truth) -> float:
    """Largest |measured AP - AP the truth implies for the recorded commands| over poses and runs, m."""
    with Session.open(session) as s:
        info = s.header["config"]["verification"]
    base, targets, worst = np.array(info["base"]), np.array(info["targets"]), 0.0
    for mode in ("before", "after"):
        reached = (points_from_joints(truth, np.array(info["q"][mode])) - base[:3, 3]) @ base[:3, :3]
        implied = np.linalg.norm(reached - targets, axis=1)
        measured = np.array([p["ap"] for p in summary["runs"][mode]["poses"]])
        worst = max(worst, float(np.max(np.abs(measured - implied))))
    return worst


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.verify_registration", description=__doc__.split("\n")[0])
    parser.add_argument("--draws", type=int, default=50)
    parser.add_argument("--cycles", type=int, default=3)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(2026)
    t0 = time.perf_counter()
    print(f"python {sys.version.split()[0]}, numpy {np.__version__}, {time.strftime('%Y-%m-%d')}; {args.draws} draws "
          f"per case, {args.cycles} cycles, UR5e, {NOISE * 1e3:.2f} mm noise")
    moved_rows, arm_rows = [], []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        result, truth = _calibrate(folder)
        for k in range(args.draws):
            turn = np.degrees(Rotation.random(random_state=rng.integers(2**31)).as_rotvec())
            direction = rng.normal(size=3)
            shift = rng.uniform(0.5, 2.0) * direction / np.linalg.norm(direction)
            tracker = (f"mock?seed={k + 1}&moved={','.join(f'{v:.6f}' for v in shift)}"
                       f"&turned={','.join(f'{v:.6f}' for v in turn)}")
            session = folder / f"m{k}.session"
            code, summary = _verify(result, session, "mock:ur5e", tracker, args.cycles)
            reg = summary["registration"]
            moved_rows.append((code, summary["verdict"]["status"], abs(reg["moved"] - np.linalg.norm(shift)),
                               abs(reg["turned_deg"] - np.linalg.norm(turn)), _ap_error(session, summary, truth),
                               reg["ratio"]))
            session = folder / f"a{k}.session"
            code, summary = _verify(result, session, f"mock:ur5e?arm={k + 100}", f"mock?seed={k + 1}", args.cycles)
            arm_rows.append((code, summary["verdict"]["status"], summary["registration"]["ratio"],
                             summary["registration"]["heldout_rms"]))
    m = np.array([r[2:] for r in moved_rows], dtype=float)
    a = np.array([r[2:] for r in arm_rows], dtype=float)
    moved_ok = sum(r[0] == 0 for r in moved_rows)
    arm_fail = sum(r[0] == 3 for r in arm_rows)
    ap_ok = int(np.sum(m[:, 2] <= AP_TOLERANCE))
    print(f"moved tracker (any rotation, 0.5-2 m): exit 0 in {moved_ok}/{args.draws} "
          f"(verdicts: {', '.join(sorted({r[1] for r in moved_rows}))}); |AP - truth's| max over poses and runs: "
          f"median {np.median(m[:, 2]) * 1e3:.4f} mm, largest {m[:, 2].max() * 1e3:.4f} mm "
          f"({ap_ok}/{args.draws} within {AP_TOLERANCE * 1e3:.1f} mm)")
    print(f"  registration: moved off by median {np.median(m[:, 0]) * 1e3:.3f} mm, largest {m[:, 0].max() * 1e3:.3f}"
          f" mm; turned off by median {np.median(m[:, 1]):.4f} deg, largest {m[:, 1].max():.4f} deg; residuals / "
          f"predicted: median {np.median(m[:, 3]):.2f}, largest {m[:, 3].max():.2f}")
    print(f"another arm (same model, other DH errors): exit 3 in {arm_fail}/{args.draws}; registered residuals / "
          f"predicted: smallest {a[:, 0].min():.1f}, median {np.median(a[:, 0]):.1f} (RMS median "
          f"{np.median(a[:, 1]) * 1e3:.3f} mm)")
    print(f"wall time {time.perf_counter() - t0:.0f} s")
    met = moved_ok == args.draws and ap_ok == args.draws and arm_fail == args.draws
    print("targets: " + ("met" if met else "MISSED"))
    return 0 if met else 1


if __name__ == "__main__":
    sys.exit(main())
