"""The options and help of ``identify``'s subcommands (``check``, ``compare``, ``compensate``): light on purpose,
so that the entry point (identify/commands/launch.py) answers ``--help`` and usage errors before the subcommand's
own imports (the estimator, scipy). The defaults repeated here are the subcommands' own; a test keeps them equal."""

from __future__ import annotations

import argparse

from common.arguments import OneLineParser, size
from common.help_text import Formatter as HelpFormatter
from common.help_text import description as _description
from common.units import Typed, positive_length

UNITS = ("m", "mm")  # identify.io.csvio.UNITS
ALPHA = 0.01  # identify.applications.compare.ALPHA
POSES = 500  # identify.applications.compare.POSES

CHECK_HELP = """``identify check RESULT DATA``: does a calibration still hold on new data?

RESULT is a result YAML (identify --out); DATA a measurement CSV or an
acquisition session of the same arm, taken with the tracker wherever it stands
now. The tracker frame is registered anew (a rigid 6-DoF fit, robust to a few
gross errors), then each model of the result predicts every row: the plain DH
table and, when the result selected joint errors, the extended model. The
figure that decides is cross-validated (each of 5 blocks of poses is predicted
from a registration fitted on the others) and compared with the error the
result expects there (tracker noise, model uncertainty, model error): up to
1.5x it holds (pass), beyond 3x it does not (fail), in between: warn.

--refit-tool also refits each tracked point's position on the flange (3
numbers per point): use it when the reflector was re-mounted. The check then
cannot see a changed tool, nor a change of the arm that looks like one.

Exit codes: 0 pass or warn, 3 fail (another arm, another tool, or the arm
changed), 2 bad input (one line).
"""

COMPARE_HELP = """\
``identify compare A B [C ...]``: has the robot changed between calibrations? (the edge where files are read)

Each input is a result YAML (``identify --out``, with its covariance) or an acquisition session (identified here
against its robot's nominal model), oldest first. Results of different robots or joint types are refused. Prints
one verdict line, then per consecutive pair the test of every DH parameter and the predicted TP displacement
(see identify/applications/compare.py); ``--html FILE`` writes the trend of every significant parameter over the inputs.

Exit codes: 0 no significant change, 3 a significant change, 2 bad input (one line).
"""

COMPENSATE_HELP = """\
``identify compensate RESULT --targets FILE --out FILE``: joint values (or controller poses) that bring the real
arm to given targets with its identified model (the edge where files are read and written).

Targets (CSV, one header row, ``#`` comment lines; metres and radians):

- ``--frame tracker`` (default): ``x,y,z`` the TP in the tracker (cell) frame;
- ``--frame base``: ``x,y,z`` and optionally ``rx,ry,rz`` (UR axis-angle) of the tool centre point (``--tool``,
  default the identified TP) in the robot's base frame (DH frame 0); with ``rx,ry,rz`` the orientation counts;
- ``--joints-from nominal``: ``q1..qN`` planned with the nominal model: the targets are where the nominal model
  puts the tool there (position and, for six joints or more, orientation; base frame).

Joint values (``q1..qN`` seeds, rows of ``--joints-from nominal``, and the output) are the controller's readings
(for a coupled robot, as its controller reports them). Optional ``q1..qN`` columns seed the solution (default:
the robot's home); an ``id`` column is copied through.
Each target is solved with the controller's model first and the identified model from there (the branch of the
seed). ``--as controller-pose`` also writes the pose the controller must be given so that the real arm reaches
the target, as UR's ``p[x, y, z, rx, ry, rz]``. The controller's model ("before", what the arm runs today) is
its factory calibration when the result records one (``controller:``), else the nominal model of ``--robot``.

``--program FILE`` filters a robot program instead (URScript): every target of ``movej``, ``movel``, ``movep``
and ``servoj`` (joint lists, rad; ``p[x, y, z, rx, ry, rz]`` poses, m and axis-angle rad, base frame; named
poses assigned once) is rewritten so that the real arm goes where the program meant on the controller's model,
each changed line commented with its change in mm and mrad; everything else is kept byte for byte, and what
cannot be rewritten (targets computed at run time, pose_trans chains, values read from the controller) is listed
line by line. The TCP: ``--tool``, else the program's one literal ``set_tcp(p[...])``, else the identified TP.
Pose targets are solved from the previous target's joints (the first from home), as the controller runs them.
The compensated joints are checked against the joint limits and the cell of ``--config SITE`` (default: the robot
alone on its mounting surface); a target that fails is kept as written and listed.

Another robot model than the result's is refused; a result that records none (identified without --robot) is
compared with --robot's nominal by its geometry, and another model's is refused. Exit codes: 0 every target
reached (with --program: every target rewritten and every motion line understood), 3 some not (each row or
listed line says why), 2 bad input (one line).
"""


def check_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="identify check", description="Does a calibration still hold on new data of the arm?",
                formatter_class=HelpFormatter, epilog="\n".join(CHECK_HELP.splitlines()[2:]))
    p.add_argument("result", metavar="RESULT", help="result YAML of the calibration (identify --out)")
    p.add_argument("data", metavar="DATA", help="measurement CSV or acquisition session of the arm today")
    p.add_argument("--refit-tool", action="store_true",
                   help="also refit each tracked point on the flange (a re-mounted reflector)")
    p.add_argument("--noise", action=Typed, convert=positive_length, metavar="LENGTH",
                   help="today's tracker noise per axis (1 sigma), e.g. 0.05mm or 50um (a bare number is metres; "
                   "default: the calibration's)")
    p.add_argument("--joints", metavar="TYPES", help="joint types of a CSV without '# joints:', e.g. RRRRRR")
    p.add_argument("--units", choices=sorted(UNITS), help="unit of x, y, z in the CSV (default: file or m)")
    p.add_argument("--json", action="store_true", help="print the check as one JSON object")
    p.add_argument("--out", metavar="FILE", help="write the check as YAML")
    p.add_argument("--force", action="store_true", help="replace --out if it exists")
    return p


def compare_parser() -> argparse.ArgumentParser:
    first, rest = COMPARE_HELP.split("\n\n", 1)
    p = OneLineParser(prog="identify compare", description=_description(first),
                formatter_class=HelpFormatter, epilog=rest.replace("``", ""))
    p.add_argument("inputs", nargs="+", metavar="RESULT_OR_SESSION", help="two or more, oldest first")
    p.add_argument("--robot", metavar="MODEL", help="nominal model (joint limits of the displacement poses; default: "
                   "the inputs')")
    p.add_argument("--alpha", type=float, default=ALPHA, help=f"family-wise false-alarm rate ({ALPHA})")
    p.add_argument("--poses", type=size("poses"), default=POSES, help=f"random poses for the TP displacement ({POSES})")
    p.add_argument("--seed", type=int, default=0, help="seed of those poses (0)")
    p.add_argument("--html", metavar="FILE", help="write the trend page (needs matplotlib)")
    p.add_argument("--json", action="store_true", help="print the comparison as one JSON object")
    p.add_argument("--force", action="store_true", help="replace --html if it exists")
    return p


def compensate_parser() -> argparse.ArgumentParser:
    first, rest = COMPENSATE_HELP.split("\n\n", 1)  # the first paragraph (two lines) is the description
    p = OneLineParser(prog="identify compensate", description=_description(first),
                formatter_class=HelpFormatter, epilog=rest.replace("``", ""))
    p.add_argument("result", help="result YAML of identify --out (with its covariance)")
    given = p.add_mutually_exclusive_group(required=True)
    given.add_argument("--targets", metavar="FILE", help="targets CSV (see above)")
    given.add_argument("--program", metavar="FILE",
                       help="robot program to filter (URScript: movej/movel/movep/servoj targets; see below)")
    p.add_argument("--out", required=True, metavar="FILE", help="output CSV (with --program: the filtered program)")
    p.add_argument("--frame", choices=("tracker", "base"), default="tracker",
                   help="frame of x,y,z targets: tracker (the TP) or base (the tool, robot frame 0)")
    p.add_argument("--joints-from", choices=("nominal",), dest="joints_from",
                   help="targets are joint values planned with the nominal model")
    p.add_argument("--as", choices=("joints", "controller-pose"), default="joints", dest="output",
                   help="write joint values (default) or also the controller's pose (UR p[...])")
    p.add_argument("--robot", metavar="MODEL",
                   help="nominal model (limits, home, the controller's model); default: the result's")
    p.add_argument("--tool", metavar="X,Y,Z[,RX,RY,RZ]",
                   help="tool centre point in the flange frame: X,Y,Z lengths (e.g. 0,0,100mm; a bare number is "
                   "metres), UR axis-angle rad (default: the identified TP)")
    p.add_argument("--language", choices=("urscript",), default="urscript", help="language of --program")
    p.add_argument("--config", metavar="SITE",
                   help="site file whose cell the compensated program targets are checked against (default: the "
                        "robot alone on its mounting surface)")
    p.add_argument("--force", action="store_true", help="replace --out if it exists")
    p.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    return p
