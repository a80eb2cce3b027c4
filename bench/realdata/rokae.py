"""Converters: two Rokae six-axis arms measured by a laser tracker, from two repositories of one author (sets
``rokae_lm`` and ``rokae_dho``).

Sources (neither states a licence, so neither is in ours):
- ``rokae_lm``: github.com/dongjy-s/LM_PyTorch, files ``data/joint_angle.csv`` and ``data/laser_pos.csv``; put
  both in ``DATA/rokae_lm/``. ``joint_angle.csv`` is the controller's export, one ``jointtarget`` a line,
  ``j:{J1,...,J6,0}`` in degrees; ``laser_pos.csv`` the tracker software's export, one pose a line: its name,
  then a nominal pose X, Y, Z (mm), Rx, Ry, Rz (deg), the measured pose in the same layout, and two residuals
  (the header, absent here, is in the other repository's ``data/pos.txt``: "Name Nominal X ... Measure X ...
  Residuals Pos Residuals Ori"). Only the measured X, Y, Z are used (the repository's loader reads columns 7-9
  too). 30 poses. Nominal: ``bench/realdata/robots/rokae_lm_pytorch.yaml`` (its ``data/dh.csv``); with only a
  base and a tool fitted it misses by 2.1 mm RMS.
- ``rokae_dho``: github.com/dongjy-s/dh_optimize, file ``data/data.txt``; put it in ``DATA/rokae_dho/``. Three
  blocks separated by ``--------`` lines: ``#angle`` (J1..J6, deg), ``#location`` (X, Y, Z, mm), ``#pos``
  (quaternions, unused). 30 poses. Nominal: ``bench/realdata/robots/rokae_dh_optimize.yaml`` (its
  ``optimize/forward_kinematics.py``); with only a base and a tool fitted it misses by 0.64 mm RMS, and the
  fitted tool (1.5, 0.8, 97.8 mm) is the repository's own (1.1, 1.1, 97.2 mm), which confirms units and joint
  order. Published (``result/error_comparison.txt``): mean error 1.920 mm before and 0.134 mm after its
  calibration, in-sample over all 30 poses (not a held-out figure).

Both: every pose is a free pose; split (fixed): every fourth pose held out; region split: J1 above its median
held out. One session each.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from bench.realdata.common import Converted, DataError, Source, free_poses, require

ROBOTS = Path(__file__).with_name("robots")
_TARGET = re.compile(r"j:\{([^}]*)\}")


def _numbers(text: str, path: Path) -> list[float]:
    try:
        return [float(v) for v in re.split(r"[,\s]+", text.strip()) if v]
    except ValueError:
        raise DataError(f"{path}: a line of numbers holds text: {text.strip()[:60]!r}") from None


def load_lm(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """Readings (rad) and measured points (m) of ``rokae_lm``."""
    joints_path, laser_path = require(Path(folder) / "joint_angle.csv"), require(Path(folder) / "laser_pos.csv")
    targets = [_TARGET.search(line) for line in joints_path.read_text(encoding="utf-8").splitlines()]
    q = [_numbers(t.group(1), joints_path)[:6] for t in targets if t]
    rows = [line.split() for line in laser_path.read_text(encoding="utf-8").splitlines() if line.strip()]
    measured = [_numbers(" ".join(r[7:10]), laser_path) for r in rows if len(r) >= 13]
    if not q or len(q) != len(measured) or any(len(v) != 6 for v in q) or len(rows) != len(measured):
        raise DataError(f"{folder}: {len(q)} joint targets and {len(measured)} of {len(rows)} tracker lines "
                        "(expected one 'j:{J1..J6,..}' per pose and lines of a name and 14 numbers)")
    return np.radians(q), np.array(measured) * 1e-3


def load_dho(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """Readings (rad) and measured points (m) of ``rokae_dho``."""
    path = require(Path(folder) / "data.txt")
    blocks = re.split(r"^-{4,}\s*$", path.read_text(encoding="utf-8"), flags=re.MULTILINE)
    tables = {}
    for block in blocks:
        lines = [ln for ln in block.strip().splitlines() if ln.strip()]
        if lines and lines[0].startswith("#"):
            tables[lines[0][1:].split(":")[0].strip()] = [_numbers(ln, path) for ln in lines[1:]]
    angle, location = tables.get("angle", []), tables.get("location", [])
    if not angle or len(angle) != len(location) or {len(r) for r in angle} != {6} or {len(r) for r in location} != {3}:
        raise DataError(f"{path}: expected '#angle' rows of 6 and as many '#location' rows of 3, separated by "
                        "'--------' lines")
    return np.radians(angle), np.array(location) * 1e-3


def convert_lm(folder: Path) -> Converted:
    q, points = load_lm(folder)
    return free_poses("RRRRRR", q, points, "Rokae arm (dongjy-s/LM_PyTorch), converted by bench.realdata.rokae")


def convert_dho(folder: Path) -> Converted:
    q, points = load_dho(folder)
    return free_poses("RRRRRR", q, points, "Rokae arm (dongjy-s/dh_optimize), converted by bench.realdata.rokae")


SOURCES = [
    Source("rokae_lm", "rokae_lm", convert_lm, nominal=ROBOTS / "rokae_lm_pytorch.yaml", regions=(1,)),
    Source("rokae_dho", "rokae_dho", convert_dho, nominal=ROBOTS / "rokae_dh_optimize.yaml", regions=(1,),
           published={"fixed": "mean 0.134 mm (1.920 mm before), in-sample over all 30 poses "
                               "(result/error_comparison.txt): not a held-out figure"}),
]
