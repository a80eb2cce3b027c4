"""Converter: three Franka Emika Panda arms measured at KETI (sets ``keti_panda_left``, ``keti_panda_right``,
``keti_panda_top``).

Source: github.com/psh117/kinematics_calibration, files ``data/KETI/panda_left.txt``, ``panda_right.txt`` and
``panda_top.txt`` (read by the repository's ``src/main_KETI.cpp``). The repository states no licence, so the
files are not in ours: put the three in ``DATA/keti_panda/``.

What the files hold, and what this converter assumes:
- whitespace-separated numbers, one pose a line, 10 columns: the seven joint readings (degrees: ``main_KETI.cpp``
  divides them by 180 and multiplies by pi) and the measured position X, Y, Z (m; the repository names neither the
  instrument nor the frame, and fits a base and a tool with the arm); 58-59 poses per arm;
- every pose is a free pose; split (fixed): every fourth pose held out; region split: J1 above its median held
  out. One session per arm;
- nominal: ``bench/realdata/robots/franka_panda.yaml`` (Franka's modified DH, as the repository's model uses).
  With only a base and a tool fitted it misses by 2.9 (left), 5.0 (right) and 3.3 mm RMS (top): large, and what
  the source's calibration starts from too.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.realdata.common import Converted, DataError, Source, free_poses, require

FOLDER = "keti_panda"
ARMS = ("left", "right", "top")
NOMINAL = Path(__file__).with_name("robots") / "franka_panda.yaml"


def load(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Readings (rad) and points (m) of one arm's file."""
    require(path)
    try:
        data = np.loadtxt(path, ndmin=2)
    except ValueError as exc:
        raise DataError(f"{path}: not a table of numbers ({exc})") from None
    if data.shape[1] != 10 or not np.all(np.isfinite(data)):
        raise DataError(f"{path}: {data.shape[1]} columns, expected 10 finite ones (7 joints in deg, X Y Z in m)")
    return np.radians(data[:, :7]), data[:, 7:]


def converter(arm: str):
    def convert(folder: Path) -> Converted:
        q, points = load(Path(folder) / f"panda_{arm}.txt")
        return free_poses("RRRRRRR", q, points, f"KETI Panda {arm} (psh117/kinematics_calibration data/KETI), "
                                                "converted by bench.realdata.keti_panda")
    return convert


SOURCES = [Source(f"keti_panda_{arm}", FOLDER, converter(arm), nominal=NOMINAL, regions=(1,)) for arm in ARMS]
