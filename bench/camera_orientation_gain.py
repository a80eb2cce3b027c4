"""A camera session identified with the board's orientations vs the same session as positions only (issue 35).

    PYTHONPATH=. .venv/bin/python -m bench.camera_orientation_gain SESSION OUTDIR

SESSION: a finished ``acquire`` session of a mock robot measured by ``aruco:sim`` (the simulated truth is known).
Its CSV (``identify SESSION --csv``) is identified as it is and with its ``rx,ry,rz,sigma_r`` columns removed; each
result's TP is compared with the simulated truth at 200 random poses inside the result's domain (RMS, mm), beside
its held-out figure, its verdict and, with orientations, its held-out orientations. Files go to OUTDIR.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from acquire.running.session import Session
from drivers.clock import VirtualClock
from drivers.sim.rig import SimulatedRig
from drivers.spec import RobotSpec, TrackerSpec
from identify.io.result_io import load_result
from kinematics.dh import points_from_joints

ORIENTATION = ("rx", "ry", "rz", "sigma_r")
POSES = 200


def positions_only(text: str) -> str:
    """The CSV ``text`` without its orientation columns (comment lines kept)."""
    lines = text.splitlines()
    head = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    columns = lines[head].split(",")
    keep = [i for i, c in enumerate(columns) if c not in ORIENTATION]
    return "\n".join(lines[:head] + [",".join(row.split(",")[i] for i in keep) for row in lines[head:]]) + "\n"


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    session, out = Path(args[0]), Path(args[1])
    out.mkdir(parents=True, exist_ok=True)
    identify = str(Path(sys.executable).with_name("identify"))
    subprocess.run([identify, str(session), "--csv", str(out / "six.csv"), "--out", str(out / "session.yaml"),
                    "--force"], check=False, capture_output=True)
    (out / "pos.csv").write_text(positions_only((out / "six.csv").read_text()))
    with Session.open(session) as s:
        config = s.header["config"]
    rig = SimulatedRig.from_spec(RobotSpec.parse(config["robot_spec"]), TrackerSpec.parse(config["tracker_spec"]),
                                 VirtualClock())
    rng = np.random.default_rng(0)
    for name in ("six", "pos"):
        subprocess.run([identify, str(out / f"{name}.csv"), "--robot", rig.model.name, "--out",
                        str(out / f"{name}.yaml"), "--force"], check=False, capture_output=True)
        model, doc = load_result(str(out / f"{name}.yaml"))
        domain = np.array(doc["domain"]["joints"])
        q = rng.uniform(domain[:, 0], domain[:, 1], (POSES, len(domain)))
        err = np.linalg.norm(model.points(q) - points_from_joints(rig.truth, q), axis=1)
        v = doc["validation"][doc["validation"]["use"]]
        label = "with orientations" if name == "six" else "positions only"
        print(f"{label:>18}: TP vs truth at {POSES} poses {np.sqrt(np.mean(err**2)) * 1e3:.4f} mm RMS; held-out "
              f"{v['samples']} poses {v['rms'] * 1e3:.4f} mm (expected {v['expected_rms'] * 1e3:.4f}); verdict "
              f"{doc['verdict']['status']}")
        if "orientation" in v:
            o = v["orientation"]
            print(f"{'':>18}  held-out orientations {o['samples']}: {o['rms_rad'] * 1e3:.3f} mrad RMS (expected "
                  f"{o['expected_rms_rad'] * 1e3:.3f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
