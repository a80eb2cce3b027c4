"""The ``identify`` command line: its options, subcommands and exit codes (``identify --help``).

Light on purpose: the entry point (identify/commands/launch.py) parses with this parser before the estimator is
imported, so ``--help``, ``--version`` and a mistyped option answer at once. The defaults below are the estimator's own
(:data:`identify.estimator.cpa.DEFAULT_PARALLEL_TOL`, :data:`identify.io.csvio.UNITS`), repeated here so that printing
help imports none of it; a test keeps them equal.
"""

from __future__ import annotations

import argparse

from common.arguments import OneLineParser, VersionAction
from common.help_text import Formatter as HelpFormatter
from common.units import Typed, length, positive_length

DEFAULT_PARALLEL_TOL = 0.01  # rad: identify.estimator.cpa.DEFAULT_PARALLEL_TOL
UNITS = ("m", "mm")  # identify.io.csvio.UNITS
SUBCOMMANDS = ("compensate", "compare", "check")  # identify/commands/compensate_cli.py, compare_cli.py, check_cli.py

DESCRIPTION = ("Identify a robot's DH parameters, base and tracked point from a measurement CSV (sweeps of one "
               "joint at a time; the format is in README.md) or an acquisition session.")

EPILOG = """\
examples:
  identify measurements.csv --robot ur5e --out cal.yaml --report report.html
  identify sessions/ur5e-20261122-101500.session --noise 0.02mm
  identify measurements.csv --json
  identify flange.csv --robot ur5e --out cal.yaml
                         a camera on the flange ('# sensor: flange' rows: the
                         board's pose in the camera frame): the arm, the
                         camera's mount and the board's place in one fit; its
                         scale from '# scale_sigma:' or the robot's lengths

subcommands (each has its own --help):
  compare A B [C ...]    has the robot changed between calibrations (results
                         or sessions)?
  compensate RESULT --targets F --out F
                         joint values that bring the real arm to given targets
                         (or --program F: a robot program filtered)
  check RESULT DATA      does a calibration still hold on new data of the arm?

exit codes:
  0    a result that passes its verdict, or passes with warnings
  1    the identification failed (a numerical failure, one line)
  2    bad input or usage (one line)
  3    a result that fails its verdict (still written, for diagnosis: do not use the model)
  130  stopped by Ctrl-C
"""


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="identify", description=DESCRIPTION, epilog=EPILOG,
                     formatter_class=HelpFormatter)
    parser.add_argument("input", help="measurement CSV (sweep,joint,q1..qN,x,y,z) or an acquisition session file")
    parser.add_argument("--out", metavar="FILE", help="write the result YAML to FILE (README.md: File contracts)")
    parser.add_argument("--json", action="store_true", help="print the full result as JSON instead of a table")
    parser.add_argument("--report", metavar="FILE", help="write a self-contained HTML report (needs matplotlib)")
    parser.add_argument("--verification", metavar="FILE",
                        help="with --report: show this acquire verify run (its .verify.yaml) in the headline")
    parser.add_argument("--urdf", metavar="FILE", help="write the identified robot as URDF")
    parser.add_argument("--ur-calibration", metavar="FILE",
                        help="write the UR ROS driver's kinematics calibration YAML (6R UR arms)")
    parser.add_argument("--rtb", metavar="FILE", help="write a Robotics Toolbox for Python script (DHRobot)")
    parser.add_argument("--json-out", metavar="FILE", help="write the full result as JSON")
    parser.add_argument("--csv", metavar="FILE", help="write the measurements as the CSV contract (e.g. of a session)")
    parser.add_argument("--joints", metavar="TYPES", help="joint types base to tip, e.g. RRPR (overrides the file)")
    parser.add_argument("--units", choices=UNITS, help="unit of x, y, z and sigma (default: file or m)")
    parser.add_argument("--robot", metavar="MODEL",
                        help="nominal model for comparison (e.g. ur5e, or a YAML path; a session: its robot)")
    parser.add_argument("--holdout", type=float, default=0.3, metavar="FRACTION",
                        help="share of free poses held out for validation when there is no role column (0.3)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the hold-out draw (0)")
    parser.add_argument("--parallel-tol", type=float, default=DEFAULT_PARALLEL_TOL, metavar="RAD",
                        help=f"axes closer than this are treated as parallel ({DEFAULT_PARALLEL_TOL} rad)")
    parser.add_argument("--max-offset", action=Typed, convert=length, default=None, metavar="LENGTH",
                        help="where the data resolve a near-parallel pair's misalignment, keep the parallel-axis "
                        "convention instead of exact DH if exact DH would move d more than LENGTH (e.g. 500mm; a "
                        "bare number is metres; 'inf': exact DH always; default: the robot's size, the farthest "
                        "measured point from joint 1's axis). The verdict's dh_table check says what the "
                        "convention costs; the URDF and UR calibration exports carry the exact axes whatever "
                        "the cap")
    parser.add_argument("--no-robust", action="store_true", help="plain least squares, no outlier rejection")
    parser.add_argument("--noise", action=Typed, convert=positive_length, metavar="LENGTH",
                        help="the tracker's noise per axis (1 sigma) to judge the fit by, e.g. 0.05mm or 50um (a bare "
                        "number is metres; a sigma column wins)")
    parser.add_argument("--coupling", metavar="FILE",
                        help="YAML with the readings' coupling, DH values = matrix . readings + offset: a row-major "
                        "n x n list, or {matrix: ..., offset: [...]} (wins over '# coupling:' and the robot model's)")
    parser.add_argument("--extensions", choices=("auto", "none"), default="auto",
                        help="joint errors beyond DH (reading scale, once-per-turn, compliance with --robot "
                        "dynamics): selected where the data support them (auto, default) or never (none)")
    parser.add_argument("--rows", choices=("all", "step", "streamed"), default="all",
                        help="fit only the stop-and-go rows or only the streamed ones (held-out rows validate either); "
                        "two such results of one session, compared with identify compare, check the streams' timing")
    parser.add_argument("--force", action="store_true", help="replace output files that already exist")
    parser.add_argument("--version", action=VersionAction)
    return parser
