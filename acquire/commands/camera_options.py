"""The options and help of ``acquire``'s camera tools (``calibrate-camera``, ``print-board``): light on purpose, so
that the entry point (acquire/commands/launch.py) answers ``--help`` and usage errors before OpenCV and numpy are
imported (acquire/commands/camera_cli.py does the work)."""

from __future__ import annotations

import argparse
from pathlib import Path

from common.arguments import OneLineParser, size
from common.help_text import Formatter as HelpFormatter
from common.units import positive_length

HELP = """Camera tools of ``acquire``: calibrate a camera from ChArUco views, print a marker or board at true scale.

    acquire calibrate-camera views/ --cols 7 --rows 5 --square 0.03 --size 0.022 --out cam.yaml
    acquire calibrate-camera --live 0 --views 25 --cols 7 --rows 5 --square 0.03 --size 0.022 --out cam.yaml
    acquire print-board --marker 7 --size 0.05 --out marker7.pdf
    acquire print-board --board charuco --cols 7 --rows 5 --square 0.03 --size 0.022 --out board.png --dpi 600

The calibration writes OpenCV FileStorage YAML (camera_matrix, distortion_coefficients, image_width,
image_height, avg_reprojection_error), the file the ``aruco:`` tracker reads with ``camera=``. Views with
fewer than ``--min-corners`` ChArUco corners or collinear ones are skipped; after a first fit, views whose
RMS reprojection error exceeds 3x the median are dropped and the camera is fitted again.
Exit codes: 0 done, 2 bad input (one line).
"""


def _parser(prog: str, description: str) -> argparse.ArgumentParser:
    p = OneLineParser(prog=prog, description=description, formatter_class=HelpFormatter,
                epilog=HELP.split("\n\n", 1)[1].replace("``", ""))
    p.add_argument("--dict", default="4X4_50", help="ArUco dictionary (4X4_50)")
    p.add_argument("--cols", type=int, help="board columns (markers of a grid, squares of a ChArUco)")
    p.add_argument("--rows", type=int, help="board rows")
    p.add_argument("--square", type=positive_length, metavar="LENGTH",
                   help="ChArUco square side, e.g. 30mm (a bare number is metres)")
    p.add_argument("--size", type=positive_length, metavar="LENGTH",
                   help="marker side, e.g. 22mm (a bare number is metres)")
    p.add_argument("--first", type=int, default=0, help="id of the board's first marker (0)")
    return p


def calibrate_parser() -> argparse.ArgumentParser:
    """The parser of ``acquire calibrate-camera``."""
    p = _parser("acquire calibrate-camera", "Calibrate a camera from ChArUco board views; write its intrinsics.")
    p.add_argument("images", nargs="?", help="folder or glob of board images")
    p.add_argument("--live", metavar="CAMERA", help="grab the views from this camera (index or device) instead")
    p.add_argument("--views", type=size("views"), default=25, help="views to grab with --live (25), one a second")
    p.add_argument("--min-corners", type=int, default=8, help="least ChArUco corners in a usable view (8)")
    p.add_argument("--out", type=Path, required=True, help="intrinsics file to write (.yaml)")
    p.add_argument("--force", action="store_true", help="replace --out if it exists")
    return p


def print_parser() -> argparse.ArgumentParser:
    """The parser of ``acquire print-board``."""
    p = _parser("acquire print-board", "Write a marker or board at true scale: PNG (with its DPI) or PDF.")
    p.add_argument("--marker", type=int, help="a single marker of this id (with --size)")
    p.add_argument("--board", choices=("grid", "charuco"), help="a board (with --cols, --rows, --size ...)")
    p.add_argument("--gap", type=positive_length, metavar="LENGTH",
                   help="grid board: gap between markers, e.g. 5mm (a bare number is metres; size/5)")
    p.add_argument("--dpi", type=int, default=600, help="print resolution, dots per inch (600)")
    p.add_argument("--out", type=Path, required=True, help="output file: .png or .pdf")
    p.add_argument("--force", action="store_true", help="replace --out if it exists")
    return p
