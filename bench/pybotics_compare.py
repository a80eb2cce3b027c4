"""pybotics side by side: the same simulated UR5e data identified by this project and by pybotics.

    .venv/bin/python -m bench.pybotics_compare [--draws 2] [--pybotics-python /tmp/pyb-venv/bin/python]

pybotics is not a dependency: it lives in a throwaway venv (``python3 -m venv /tmp/pyb-venv &&
/tmp/pyb-venv/bin/pip install pybotics``) and runs in a subprocess (``bench/_pybotics_worker.py``, which
documents the DH -> MDH conversion and what pybotics fits). pybotics needs a starting model close to the
truth, including the tracker <- base transform; it is given the nominal DH table with this project's
geometric-step base and tool (what a user would have after registering the base), so its fit time excludes
that step. Accuracy: RMS 3D error at 200 held-out poses vs the truth, over ``--draws`` noise draws, and the
Cramér-Rao bound. Time: wall time of ``identify()`` in-process vs pybotics' ``least_squares`` call.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from config.robots import load_robot
from identify.estimator.bounds import prediction_rms_bound
from identify.results.pipeline import identify
from identify.simulators.simulate import random_poses, simulate
from kinematics.dh import DHModel, points_from_joints
from kinematics.truth import random_truth

SEED = 20240604
NOISE = 5e-5
WORKER = Path(__file__).with_name("_pybotics_worker.py")


def run_pybotics(python: str, start: DHModel, q_fit: np.ndarray, p_fit: np.ndarray, q_check: np.ndarray,
                 fit: bool = True) -> dict[str, np.ndarray]:
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        np.savez(src, types=start.joint_types, theta=start.theta, d=start.d, a=start.a, alpha=start.alpha,
                 base=start.base, tool=start.tool, q_fit=q_fit, p_fit=p_fit, q_check=q_check, fit=fit)
        subprocess.run([python, str(WORKER), str(src), str(dst)], check=True, timeout=600)
        with np.load(dst) as out:
            return {k: out[k] for k in out.files}


def rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.pybotics_compare", description=__doc__.split("\n")[0])
    parser.add_argument("--draws", type=int, default=2, help="noise draws (default 2; pybotics takes minutes each)")
    parser.add_argument("--pybotics-python", default="/tmp/pyb-venv/bin/python")
    args = parser.parse_args(argv)
    if not Path(args.pybotics_python).exists():
        print(f"{args.pybotics_python} not found: create it with python3 -m venv /tmp/pyb-venv && "
              "/tmp/pyb-venv/bin/pip install pybotics")
        return 2
    ask = "import importlib.metadata as m; print(m.version('pybotics'))"
    version = subprocess.run([args.pybotics_python, "-c", ask], capture_output=True, text=True, check=True)
    version = version.stdout.strip()
    robot = load_robot("ur5e")
    rng = np.random.default_rng(SEED)
    truth = random_truth(robot.nominal, robot.home, rng)
    q_check = random_poses(robot.limits, 200, rng)
    p_check = points_from_joints(truth, q_check)
    # the conversion to pybotics' modified DH must reproduce the forward model exactly
    same = run_pybotics(args.pybotics_python, truth, q_check[:1], p_check[:1], q_check, fit=False)
    conversion = rms(same["predicted"], p_check)
    print(f"pybotics {version} vs this project on simulated UR5e data: full sweeps (36 samples per joint), "
          f"noise {NOISE * 1e3:g} mm, 200 held-out poses, seed {SEED}")
    print(f"forward-model conversion check (truth through pybotics vs kinematics.dh): RMS {conversion:.2e} m")
    print()
    header = (f"{'draw':>4} {'bound mm':>9} {'ours mm':>9} {'geo mm':>9} {'pybotics mm':>11} {'ours ms':>8} "
              f"{'pybotics ms':>11} {'nfev':>5} {'fit ours mm':>11} {'fit pyb mm':>10}")
    print(header)
    print("-" * len(header))
    rows = []
    for k in range(args.draws):
        meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=NOISE)
        identify(meas, nominal=robot.nominal)  # warm-up, as the speed benchmark does
        start = time.perf_counter()
        ident = identify(meas, nominal=robot.nominal)
        ours_s = time.perf_counter() - start
        geo = ident.geometric.model
        begin = DHModel(robot.nominal.joint_types, robot.nominal.theta, robot.nominal.d, robot.nominal.a,
                        robot.nominal.alpha, geo.base, geo.tool)
        out = run_pybotics(args.pybotics_python, begin, meas.q, meas.points, q_check)
        bound = prediction_rms_bound(truth, meas.q, q_check, NOISE)
        row = (bound, rms(points_from_joints(ident.model, q_check), p_check), rms(points_from_joints(geo, q_check),
               p_check), rms(out["predicted"], p_check), ours_s, float(out["seconds"]), int(out["nfev"]),
               rms(points_from_joints(ident.model, meas.q), meas.points), float(out["fitted_rms"]))
        rows.append(row)
        print(f"{k:>4} {row[0] * 1e3:>9.5f} {row[1] * 1e3:>9.5f} {row[2] * 1e3:>9.5f} {row[3] * 1e3:>11.5f} "
              f"{row[4] * 1e3:>8.1f} {row[5] * 1e3:>11.1f} {row[6]:>5} {row[7] * 1e3:>11.6f} {row[8] * 1e3:>10.6f}")
    arr = np.array(rows)
    bound = np.sqrt(np.mean(arr[:, 0] ** 2))
    print()
    print(f"sqrt(mean RMS²)/bound: ours {np.sqrt(np.mean(arr[:, 1] ** 2)) / bound:.3f}, geometric step "
          f"{np.sqrt(np.mean(arr[:, 2] ** 2)) / bound:.3f}, pybotics {np.sqrt(np.mean(arr[:, 3] ** 2)) / bound:.3f}")
    print("ours/geo/pybotics mm: RMS 3D error at the held-out poses vs the truth; fit mm: RMS 3D residual of the")
    print("fitted samples (both minimise the same sum of squares; a lower one is a better optimum of it).")
    print(f"median time: ours {np.median(arr[:, 4]) * 1e3:.1f} ms (whole identification), pybotics "
          f"{np.median(arr[:, 5]) * 1e3:.1f} ms (least_squares only, started from our geometric base and tool)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
