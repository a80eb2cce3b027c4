"""Converter: HUST's Leica AT960 measurements of a six-axis industrial robot (set ``hust2022``).

Source: github.com/ZhangTeng-Hust/ASTL, folder ``Data/`` (published as "HUST_NC_Robot", Mendeley Data,
doi:10.17632/srxktn4752.1); data of T. Zhang et al., "An active semi-supervised transfer learning method for
robot pose error prediction and compensation", Engineering Applications of Artificial Intelligence (2023). The
repository reserves reproduction ("No reproduction without permission"), so nothing of it is in ours: put its
folders ``Calibration/``, ``POINTS/`` and ``CURVE/`` (each ``Leica.csv`` and ``theta.xlsx``) in ``DATA/hust2022/``.

What the files hold, and what this converter assumes:
- ``Leica.csv``: one measured pose a line, a header row, then X, Y, Z (mm, the tracker's frame; the T-Mac
  probe's reference point), U(95) overall and per axis (mm), tilt, the probe's quaternion, image RMS, target,
  temperature, pressure, humidity, time stamp, ...; only X, Y, Z and the per-axis U(95) are used;
- ``theta.xlsx``: the six joint readings J1..J6 of the same poses, degrees, one header row (read with the
  standard library: an .xlsx file is a zip of XML);
- every pose is a free pose (``joint`` 0: several joints moved); ``sigma`` = the RMS of the per-axis U(95)
  divided by 1.96 (m);
- sessions: ``Calibration`` (40 poses, 11 Oct 2022), ``POINTS`` (300 poses, 20 Oct 2022, nine days later) and
  ``CURVE`` (500 poses along a path at one tool orientation, 8 Nov 2022, 28 days later); the dates are the
  tracker's time stamps. Fixed split: Calibration's every fourth pose (0-based index 3, 7, ...) is held out
  (``role`` check), the other 30 fit; ``POINTS`` and ``CURVE`` are later sessions, written as separate CSVs of
  check rows and scored after re-fitting the tracker's pose and the probe's offset on their even rows (either
  folder may be absent): the T-Mac's offset from the flange moved by about 0.9 mm between the sessions (the
  nominal placed on each session alone puts it at (-31.9, -18.4, 99.2) mm, then (-32.7, -18.9, 99.1) mm), which
  a rigid re-registration cannot absorb (it left every model at 0.89-0.91 mm on POINTS). ``LINE`` and
  ``SURFACE`` (same arm, 8 and 16-17 Nov) are not used;
- region splits: Calibration's poses with J1 (then J5) above its median are held out, the rest fit;
- nominal model: the source names neither the robot nor its kinematics. Its renders show a Staubli TX2 arm, and of
  the TX2-90, TX2-90L, TX2-90XL and TX60L nominals of robotkinematicscatalogue 1.1.2 only the TX2-90L's fits the
  Calibration poses with only a base and a tool fitted (0.42 mm RMS; POINTS 0.17 mm; the others 107-122 mm RMS;
  the TX90L, its predecessor, has the same table), so the bench starts from
  ``bench/realdata/robots/staubli_tx2_90l.yaml`` (robotkinematicscatalogue 1.1.2's modified DH table, converted
  exactly). A ``robot.yaml`` in the set's folder replaces it.
"""

from __future__ import annotations

import csv
import re
import zipfile
from pathlib import Path
from xml.etree import ElementTree

import numpy as np

from bench.realdata.common import Converted, DataError, Source, require

NAME = "hust2022"
JOINTS = "RRRRRR"
FIT_SESSION, LATER_SESSIONS = "Calibration", ("POINTS", "CURVE")
HOLD_EVERY = 4
U95_TO_SIGMA = 1.0 / 1.96
_NS = {"x": "http://schemas.openxmlformats.org/spreadsheetml/2006/main"}
_CELL = re.compile(r"^([A-Z]+)(\d+)$")


def read_xlsx(path: Path) -> np.ndarray:
    """The numeric cells of the first worksheet of ``path`` (rows x columns); text cells (the header) are skipped."""
    try:
        with zipfile.ZipFile(require(path)) as book:
            names = sorted(n for n in book.namelist() if re.fullmatch(r"xl/worksheets/sheet\d+\.xml", n))
            if not names:
                raise DataError(f"{path}: no worksheet in the workbook")
            root = ElementTree.fromstring(book.read(names[0]))
    except (zipfile.BadZipFile, ElementTree.ParseError) as exc:
        raise DataError(f"{path}: not an .xlsx workbook ({exc})") from None
    rows = []
    for row in root.iterfind("x:sheetData/x:row", _NS):
        values = {}
        for cell in row.iterfind("x:c", _NS):
            ref, value = _CELL.match(cell.get("r", "")), cell.find("x:v", _NS)
            if ref and value is not None and cell.get("t") in (None, "n"):
                values[ref.group(1)] = float(value.text)
        if values:
            rows.append([values[k] for k in sorted(values, key=lambda c: (len(c), c))])
    if not rows or len({len(r) for r in rows}) != 1:
        raise DataError(f"{path}: expected a rectangular block of numbers under one header row")
    return np.array(rows)


def read_leica(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Points (m) and per-axis sigma (m) of a tracker export ``Leica.csv`` (Latin-1: its header has a degree sign)."""
    with require(path).open(encoding="latin-1", newline="") as handle:
        rows = list(csv.reader(handle))
    header = [h.strip() for h in rows[0]]
    try:
        columns = [header.index(name) for name in ("X  [mm]", "Y  [mm]", "Z  [mm]",
                                                   "U(95) X  [mm]", "U(95) Y  [mm]", "U(95) Z  [mm]")]
        data = np.array([[float(r[c]) for c in columns] for r in rows[1:] if r], dtype=float)
    except (ValueError, IndexError) as exc:
        raise DataError(f"{path}: not the tracker export this converter reads ({exc})") from None
    sigma = np.sqrt(np.mean(np.square(data[:, 3:]), axis=1)) * U95_TO_SIGMA * 1e-3
    return data[:, :3] * 1e-3, sigma


def session(folder: Path, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Readings (rad), points (m) and sigma (m) of one session folder."""
    points, sigma = read_leica(Path(folder) / name / "Leica.csv")
    degrees = read_xlsx(Path(folder) / name / "theta.xlsx")
    if degrees.shape != (len(points), 6):
        raise DataError(f"{Path(folder) / name}: theta.xlsx has {degrees.shape} readings for {len(points)} "
                        "measured points (expected one row of six per point)")
    return np.radians(degrees), points, sigma


def _free(q: np.ndarray, points: np.ndarray, sigma: np.ndarray, check: np.ndarray, source: str) -> Converted:
    m = len(q)
    return Converted(JOINTS, q, points, np.arange(1, m + 1), np.zeros(m, dtype=np.int64), check,
                     np.ones(m, dtype=np.int64), sigma=sigma,
                     metadata={"source": f"HUST_NC_Robot {source} (ZhangTeng-Hust/ASTL), converted by "
                                         "bench.realdata.hust2022"})


def convert(folder: Path) -> Converted:
    """The first session in the CSV contract: 30 fit poses, 10 held out (see the module docstring)."""
    q, points, sigma = session(folder, FIT_SESSION)
    check = np.arange(len(q)) % HOLD_EVERY == HOLD_EVERY - 1
    return _free(q, points, sigma, check, FIT_SESSION)


def sessions(folder: Path) -> dict[str, Converted]:
    """The later sessions the folder holds (all rows check), by name."""
    out = {}
    for name in LATER_SESSIONS:
        if (Path(folder) / name).is_dir():
            q, points, sigma = session(folder, name)
            out[name] = _free(q, points, sigma, np.ones(len(q), dtype=bool), name)
    return out


SOURCE = Source(NAME, NAME, convert, sessions, nominal=Path(__file__).with_name("robots") / "staubli_tx2_90l.yaml",
                regions=(1, 5), retool=True)
