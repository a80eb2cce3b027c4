"""Converter: Boby & Klimchik's laser-tracker sweeps of a six-axis industrial robot (set ``boby2021``).

Source: github.com/RABKKK/LaserTrackerPoseData4KinIdent, file ``N1N2N3Jval.csv``; data of R. A. Boby,
A. Klimchik, "Combination of geometric and parametric approaches for kinematic identification of an industrial
robot", Robotics and Computer-Integrated Manufacturing (2021). The repository states no licence, so the file is
not in ours: put it in ``DATA/boby2021/``.

What the file holds, and what this converter assumes:
- whitespace-separated numbers, one pose a line, 21 columns: three spherically mounted reflectors (SMR) on the
  end effector, x, y, z each (columns 1-9, mm, the laser tracker's frame), then 12 columns of which the last
  six are the controller's joint readings J1..J6 (degrees) and the six before them are zero (refused if not);
- the poses are sweeps of one joint each from one home pose (J1; J2 with J3 = -J2; J3; J4; J5; J6). J2 and J3
  are coupled as on FANUC-style controllers: the DH value of joint 3 is J2 + J3, so the second sweep, which
  moves J2 and J3 by opposite angles, turns DH joint 2 alone (the reflectors' triangle turns by the sweep's
  80 deg, which rules out the uncoupled reading). The CSV carries this as ``# coupling:``;
- rows: one per reflector and pose (``tp`` 1, 2, 3 = the file's column triples); the converter finds the sweeps
  from the readings (consecutive poses that differ in one DH joint);
- split (fixed): the middle pose of every sweep (index ``len // 2``) is held out (``role`` check, all three
  reflectors); the rest fit. The set is one session: no second one. No region split: every sweep starts from
  one home pose, so each joint other than the swept one has one value, and holding out one side of a joint
  removes most of its sweep (the product then has no circle to start from). The paper's figures are for its
  own split and model: none is printed.
- nominal model: none is needed (the sweeps identify the arm from scratch); the set's repository does not
  name the robot model, so no data sheet is cited.
- noise: not given by the set; the product estimates it from the residuals.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.realdata.common import Converted, DataError, Source, require

NAME = "boby2021"
FILE = "N1N2N3Jval.csv"
JOINTS = "RRRRRR"
COUPLING = np.eye(6)
COUPLING[2, 1] = 1.0  # DH joint 3 = J2 + J3


def load(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """Reflector positions (poses x 3 x 3, m) and joint readings (poses x 6, rad) of ``folder/N1N2N3Jval.csv``."""
    path = require(Path(folder) / FILE)
    try:
        data = np.loadtxt(path, ndmin=2)
    except ValueError as exc:
        raise DataError(f"{path}: not a table of numbers ({exc})") from None
    if data.shape[1] != 21:
        raise DataError(f"{path}: {data.shape[1]} columns, expected 21 (3 reflectors x 3, then 12 joint columns)")
    if not np.all(np.isfinite(data)):
        raise DataError(f"{path}: non-finite values")
    if np.any(data[:, 9:15] != 0.0):
        raise DataError(f"{path}: columns 10-15 are expected to be zero (the readings are the last six)")
    return data[:, :9].reshape(-1, 3, 3) * 1e-3, np.radians(data[:, 15:])


def sweeps(dh: np.ndarray, tol: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Sweep id (from 1) and swept DH joint (1-based) of every pose: runs of consecutive poses that differ from
    the pose before them in one and the same DH joint."""
    groups: list[list[int]] = [[0]]
    moved: list[int] = [0]
    for k in range(1, len(dh)):
        changed = np.flatnonzero(np.abs(dh[k] - dh[k - 1]) > tol)
        if len(changed) == 1 and moved[-1] in (0, changed[0] + 1):
            groups[-1].append(k)
            moved[-1] = int(changed[0]) + 1
        else:
            groups.append([k])
            moved.append(0)
    alone = [g[0] for g, j in zip(groups, moved, strict=True) if j == 0]
    if alone:
        raise DataError(f"pose(s) {alone} (0-based) belong to no sweep of one joint")
    sweep = np.concatenate([np.full(len(g), s + 1) for s, g in enumerate(groups)])
    joint = np.concatenate([np.full(len(g), j) for g, j in zip(groups, moved, strict=True)])
    return sweep.astype(np.int64), joint.astype(np.int64)


def convert(folder: Path) -> Converted:
    """The set in the CSV contract (see the module docstring for the assumptions)."""
    smr, readings = load(folder)
    dh = readings @ COUPLING.T
    sweep, joint = sweeps(dh)
    check = np.zeros(len(readings), dtype=bool)
    for s in np.unique(sweep):
        rows = np.flatnonzero(sweep == s)
        check[rows[len(rows) // 2]] = True
    n_tp = smr.shape[1]
    return Converted(
        joints=JOINTS,
        q=np.repeat(readings, n_tp, axis=0),
        points=smr.reshape(-1, 3),
        sweep=np.repeat(sweep, n_tp),
        joint=np.repeat(joint, n_tp),
        check=np.repeat(check, n_tp),
        tp=np.tile(np.arange(1, n_tp + 1), len(readings)),
        coupling=COUPLING,
        metadata={"source": "Boby & Klimchik laser-tracker sweeps (RABKKK/LaserTrackerPoseData4KinIdent), "
                            "converted by bench.realdata.boby2021"},
    )


SOURCE = Source(NAME, NAME, convert)
