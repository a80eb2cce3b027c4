"""Converter: the Leica tracker poses of the right arm of CTU's Yaskawa Motoman dual-arm robot (set
``ctu_motoman``).

Source: github.com/ctu-vras/multirobot-calibration, file
``UserData/Robots/Motoman/Dataset/leica_dataset/updated_leica_dataset.mat`` (the data of K. Stepanova et al.,
"Automatic self-contained calibration of an industrial dual-arm robot with cameras using self-contact, planar
constraints, and self-observation", Robotics and Computer-Integrated Manufacturing 73 (2022) 102250; toolbox:
J. Rozlivek et al., Humanoids 2021). The repository states no licence, so the file is not in ours: put it in
``DATA/ctu_motoman/``.

What the file holds (``leica_dataset_description.txt`` beside it), and what this converter assumes:
- a MATLAB matrix ``dataset``, one record a row, 26 columns: pose id, face id, arm, camera, marker u, v (px), the
  torso axis E, the right arm's S, L, U, R, B, T, the left arm's six (rad), the Leica reflector's X, Y, Z (m, the
  tracker's frame) and four uncertainties (m; not said to be one standard deviation, so not used: the product
  estimates the noise);
- as the repository's loader (``loadNewLeicaDataset.m``) does: the first record of every pose id, the poses the
  tracker logged (X not NaN), and its 13th such pose removed (it misses the nominal by 22 mm where the others
  miss by 3 mm RMS); 586 poses. The reflector is on the right arm (its end effector ``LR1``). The torso axis E
  reads within 0.17 mrad of 0 (median 0.04 mrad; refused beyond 1 mrad), so it is taken as 0 and the torso row
  belongs to the base: the arm is converted as ``RRRRRR`` with the readings S..T. What that costs, measured with
  the loader's torso row on the nominal: the reflector moves by 0.04 mm (median) and at most 0.20 mm between E
  read and E = 0, an error no model here can absorb;
- every pose is a free pose; split (fixed): every fourth pose held out; region splits: S (then B) above its
  median held out. One session: the other ``leica_*`` files hold small local grids of the same arm with other
  reflector holders, which the source does not relate to this one's;
- nominal: ``bench/realdata/robots/motoman_right_arm.yaml`` (the loader's table ``loadMotomanLeica.m``). With
  only a base and a tool fitted it misses the poses by 3.0 mm RMS (2.5 mm mean): plausible for a 2 m arm's CAD
  table.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.io

from bench.realdata.common import Converted, DataError, Source, free_poses, require

NAME = "ctu_motoman"
FILE = "updated_leica_dataset.mat"
DROPPED = 12  # 0-based index, among the logged poses, that the source's loader removes
TORSO_LIMIT = 1e-3  # rad: the torso axis E must read this close to 0


def load(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """Right-arm readings S..T (rad) and reflector positions (m) of the logged poses, as the source's loader keeps."""
    path = require(Path(folder) / FILE)
    try:
        data = np.asarray(scipy.io.loadmat(path)["dataset"], dtype=float)
    except (ValueError, KeyError, OSError) as exc:
        raise DataError(f"{path}: not the MATLAB file with a 'dataset' matrix this converter reads ({exc})") from None
    if data.ndim != 2 or data.shape[1] != 26:
        raise DataError(f"{path}: 'dataset' is {data.shape}, expected 26 columns (see leica_dataset_description.txt)")
    _, first = np.unique(data[:, 0], return_index=True)
    rows = data[np.sort(first)]
    rows = np.delete(rows[~np.isnan(rows[:, 19])], DROPPED, axis=0)
    torso = np.abs(rows[:, 6]).max()
    if torso > TORSO_LIMIT:
        raise DataError(f"{path}: the torso axis E moves by {torso:.2e} rad; this converter handles E = 0 only")
    return rows[:, 7:13], rows[:, 19:22]


def convert(folder: Path) -> Converted:
    q, points = load(folder)
    return free_poses("RRRRRR", q, points, "CTU Motoman right arm, Leica (ctu-vras/multirobot-calibration "
                                           f"{FILE}), converted by bench.realdata.ctu_motoman")


SOURCE = Source(NAME, NAME, convert, nominal=Path(__file__).with_name("robots") / "motoman_right_arm.yaml",
                regions=(1, 5))
