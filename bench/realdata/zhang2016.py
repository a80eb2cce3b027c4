"""Converter: a KUKA LBR iiwa 7 moved over a grid of its first two joints, measured by an external tracker with
no payload and with 5 kg (set ``zhang2016``).

Source: github.com/Zhangzhongqiu/new-calibration, files ``0kg/20161216_run1_0kg.csv`` and
``5kg/20161216_run4_5kg.csv`` (in the repository's history, commit 381b14f; removed from its newest tree). The
repository states no licence, so the files are not in ours: put them in ``DATA/zhang2016/`` under these names
(``20161216_run1_0kg.csv`` required, ``20161216_run4_5kg.csv`` optional).

What the files hold, and what this converter assumes:
- comma-separated, one header row (``number, theta_1..theta_7, tau_1..tau_7, m_00..m_33``), one pose a line:
  the seven joint readings (rad), the seven joint torques (N m, unused here) and the tracked body's pose as a
  row-major 4x4 matrix whose translation ``m_03, m_13, m_23`` is in mm, in the tracker's frame (the repository
  does not name the tracker; its code divides the translation by 1000 and uses it as the measured point);
- the grid moves A1 and A2 only; A3..A7 stay within 0.2 mrad of their reading 0 (checked: refused beyond
  1 mrad, except the first row, the home pose, which is dropped). The arm is therefore converted as a two-joint
  arm (``RR``, readings A1 and A2): the links beyond A2 are rigid and belong to the tool;
- sweeps: the grid has one row per (A1 level, A2 level). The rows at the A1 level nearest 0 form the sweep of
  joint 2; the other rows at the A2 level nearest 45 deg form the sweep of joint 1; every other row is a free
  pose (``joint`` 0). (Cutting the whole grid into sweeps, one per A1 level for joint 2 and one per A2 level
  for joint 1, is as valid a reading of the CSV contract, but the product's start cannot use sweeps of one
  joint taken at different values of the others: see bench/realdata/README.md, "Findings".)
- split (fixed): every fourth free pose (0-based index 3, 7, ... among them) is held out (``role`` check);
  region splits: the rows with A1 (then A2) above its median are held out, the rest fit;
- second session: the 5 kg run (same day, same grid, payload added), scored after a rigid re-registration; it
  measures what a payload does to a model fitted without one, not a tracker move;
- nominal model: ``bench/realdata/robots/iiwa7_a1a2.yaml`` (A2 0.340 m above the base, perpendicular to A1,
  after KUKA's iiwa 7 R800 specification; the rest of the arm is the tool). Noise: not given; the product
  estimates it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.realdata.common import Converted, DataError, Source, require

NAME = "zhang2016"
FIT_FILE, SECOND_FILE = "20161216_run1_0kg.csv", "20161216_run4_5kg.csv"
JOINTS = "RR"
FROZEN_LIMIT = 1e-3  # rad: A3..A7 must stay this close to 0
LEVEL_TOL = np.radians(0.5)  # rad: readings closer than this are one grid level
HOLD_EVERY = 4
NOMINAL = Path(__file__).with_name("robots") / "iiwa7_a1a2.yaml"


def load(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Readings of A1, A2 (rad) and tracked points (m) of one run, the home row dropped."""
    require(path)
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except ValueError as exc:
        raise DataError(f"{path}: not the comma-separated run this converter reads ({exc})") from None
    if data.shape[1] != 31:
        raise DataError(f"{path}: {data.shape[1]} columns, expected 31 (number, 7 joints, 7 torques, 4x4 pose)")
    q, pose = data[1:, 1:8], data[1:, 15:31].reshape(-1, 4, 4)
    frozen = np.abs(q[:, 2:]).max()
    if frozen > FROZEN_LIMIT:
        raise DataError(f"{path}: A3..A7 move by {frozen:.4f} rad; this converter handles the A1/A2 grid only")
    return q[:, :2], pose[:, :3, 3] * 1e-3


def levels(values: np.ndarray) -> np.ndarray:
    """Grid level index (0, 1, ... in increasing value) of every reading."""
    order = np.sort(values)
    starts = order[np.concatenate([[True], np.diff(order) > LEVEL_TOL])]
    return np.searchsorted(starts, values + LEVEL_TOL, side="right") - 1


def sweeps(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sweep id and swept joint of every row: one sweep of joint 2, one of joint 1, the rest free poses (one
    sweep id each, joint 0); see the module docstring."""
    level1, level2 = levels(q[:, 0]), levels(q[:, 1])
    nearest1 = level1[np.argmin(np.abs(q[:, 0]))]
    nearest2 = level2[np.argmin(np.abs(q[:, 1] - np.radians(45.0)))]
    joint = np.zeros(len(q), dtype=np.int64)
    joint[level1 == nearest1] = 2
    joint[(level2 == nearest2) & (joint == 0)] = 1
    sweep = np.arange(3, len(q) + 3, dtype=np.int64)
    sweep[joint == 2], sweep[joint == 1] = 1, 2
    return sweep, joint


def _converted(q: np.ndarray, points: np.ndarray, sweep: np.ndarray, joint: np.ndarray, check: np.ndarray,
               source: str) -> Converted:
    return Converted(JOINTS, q, points, sweep, joint, check, np.ones(len(q), dtype=np.int64),
                     metadata={"source": f"KUKA LBR iiwa 7 A1/A2 grid, {source} (Zhangzhongqiu/new-calibration), "
                                         "converted by bench.realdata.zhang2016"})


def convert(folder: Path) -> Converted:
    """The no-payload run in the CSV contract."""
    q, points = load(Path(folder) / FIT_FILE)
    sweep, joint = sweeps(q)
    check = np.zeros(len(q), dtype=bool)
    free = np.flatnonzero(joint == 0)
    check[free[HOLD_EVERY - 1::HOLD_EVERY]] = True
    return _converted(q, points, sweep, joint, check, FIT_FILE)


def sessions(folder: Path) -> dict[str, Converted]:
    """The 5 kg run (all rows check, free poses), when the folder holds it."""
    path = Path(folder) / SECOND_FILE
    if not path.is_file():
        return {}
    q, points = load(path)
    m = len(q)
    return {"5 kg": _converted(q, points, np.arange(1, m + 1), np.zeros(m, dtype=np.int64), np.ones(m, dtype=bool),
                               SECOND_FILE)}


SOURCE = Source(NAME, NAME, convert, sessions, nominal=NOMINAL, regions=(1, 2))
