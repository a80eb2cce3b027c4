"""Do two versions of the estimator identify the same parameters? The speed benchmark's data sets, compared in σ.

    .venv/bin/python -m bench.same_results --out new.json
    PYTHONPATH=OLD_TREE .venv/bin/python bench/same_results.py --out old.json    # another commit's checkout
    .venv/bin/python -m bench.same_results --compare old.json new.json

``--out`` identifies the data sets of :mod:`bench.speed` (UR5e 6 × 36 × 5 sets, 6 × 100 × 3, 6 × 300 × 2, iiwa7
7 × 1000 × 2; each with and without the nominal: 24 identifications) and writes every written model's full parameter
vector (base translation, tool, DH table; m, rad), its standard uncertainties, the base rotation, the verdict, the
rejected rows and the chosen start. ``--compare`` prints, per identification, the largest change of a free
parameter in units of its own σ (the base rotation's change against its smallest σ) and any other difference; exit 1
when a change reaches ``--limit`` σ (default 0.01) or a verdict or rejected row differs. A different start label is
printed, not counted: when both starts converge to one solution their costs tie, and rounding picks the label.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from config.robots import load_robot
from identify.results.pipeline import identify
from identify.simulators.simulate import simulate
from kinematics.truth import random_truth

SEED, NOISE = 20240602, 5e-5  # as bench.speed
CASES = ([("ur5e", 36, k) for k in range(5)] + [("ur5e", 100, k) for k in range(3)]
         + [("ur5e", 300, k) for k in range(2)] + [("iiwa7", 1000, k) for k in range(2)])


def identified() -> dict[str, dict]:
    """Every case's written models and verdict, keyed ``robot/steps/set/nominal``."""
    out = {}
    for name, steps, index in CASES:
        robot = load_robot(name)
        rng = np.random.default_rng((SEED, steps, index))
        truth = random_truth(robot.nominal, robot.home, rng)
        meas, _ = simulate(truth, robot.home, robot.limits, rng, noise=NOISE, steps=steps)
        for with_nominal in (True, False):
            result = identify(meas, nominal=robot.nominal if with_nominal else None)
            models = {
                key: {"vector": [*m.model.base[:3, 3], *m.tools[0], *m.model.dh_table().ravel()],
                      "std": list(m.std[3:]), "rotation": m.model.base[:3, :3].tolist(),
                      "rotation_std": float(np.min(m.std[:3][m.std[:3] > 0], initial=np.inf))}
                for key, m in result.models.items()}
            out[f"{name}/{steps}/{index}/{with_nominal}"] = {
                "models": models, "verdict": [[c.name, c.status] for c in result.verdict.checks],
                "rejected": result.rejected_rows, "start": result.start}
    return out


def compare(old: dict, new: dict, limit: float) -> bool:
    """Print the differences of ``new`` from ``old``; True when every change is below ``limit`` σ."""
    ok, worst = True, 0.0
    for key, a in old.items():
        b = new[key]
        notes = [f"{field} differs" for field in ("verdict", "rejected") if a[field] != b[field]]
        ok &= not notes
        if a["start"] != b["start"]:  # starts converged to one solution tie: rounding picks the label
            notes.append(f"start {a['start']!r} -> {b['start']!r}")
        if set(a["models"]) != set(b["models"]):
            notes.append("models differ")
            ok = False
        for name in set(a["models"]) & set(b["models"]):
            ma, mb = a["models"][name], b["models"][name]
            std = np.array(ma["std"])
            free = std > 0
            change = np.abs(np.subtract(ma["vector"], mb["vector"]))[free] / std[free]
            turn = np.subtract(np.array(ma["rotation"]).T @ np.array(mb["rotation"]), np.eye(3))
            z = max(float(np.max(change, initial=0.0)), float(np.linalg.norm(turn - turn.T) / 2 / ma["rotation_std"]))
            worst = max(worst, z)
            notes.append(f"{name}: largest change {z:.2e} sigma")
        print(f"{key:24s} " + "; ".join(notes))
    print(f"largest change over every case: {worst:.2e} sigma (limit {limit:g})")
    return ok and worst < limit


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.same_results", description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, help="write this version's results here (JSON)")
    parser.add_argument("--compare", type=Path, nargs=2, metavar=("OLD", "NEW"), help="compare two result files")
    parser.add_argument("--limit", type=float, default=0.01, help="largest change allowed, in sigma (default 0.01)")
    args = parser.parse_args(argv)
    if args.out is not None:
        if args.out.exists():
            print(f"{args.out} exists; remove it first", file=sys.stderr)
            return 2
        args.out.write_text(json.dumps(identified()))
        print(f"wrote {args.out}")
    if args.compare is not None:
        old, new = (json.loads(p.read_text()) for p in args.compare)
        return 0 if compare(old, new, args.limit) else 1
    return 0 if args.out is not None else 2


if __name__ == "__main__":
    sys.exit(main())
