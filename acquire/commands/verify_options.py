"""``acquire verify --result RESULT``: measure how accurate the arm is before and after compensation (ISO 9283-style).

    acquire verify --result cal.result.yaml --robot mock:ur5e --tracker mock     rehearsal on the simulated rig
    acquire verify --result cal.result.yaml --robot ur5e@192.168.1.10 --tracker serial:/dev/ttyUSB0 --config site.yaml
    acquire verify --result cal.result.yaml --robot ur5e --dry-run             the test's poses and moves, nothing moved
    acquire verify --resume sessions/ur5e-verify-20261122-101500.session      continue an interrupted test

The test (acquire/verification/verify.py) registers the tracker first, on 8 poses of its own (trackers move between
sessions), and says how far it moved; each pose is visited from three directions (an approach pose along the base's +x,
+y, +z first) for ISO 9283's vAP, and its orientation is measured where the result knows three or more tracked points;
every figure is shown with its uncertainty (Monte-Carlo over the cycles). The test is planned before anything moves
and checked like an acquisition plan (joint limits, the cell); a real robot moves only after the operator has read
it and typed ``yes`` (or passed ``--yes``); Ctrl-C stops the motion; every wait has a timeout. The session is a
session file like an acquisition's (durable, resumable; its header holds the test), and ``SESSION.verify.yaml`` and
``SESSION.report.html`` are written beside it. Exit codes: 0 complete (verdict pass or warn), 3 complete but
compensation fails the test or the registered residuals say another arm or another tool, 1 the run failed or left
poses unmeasured (resumable), 2 bad input or a test that cannot be planned, 130 stopped by the operator.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from common.arguments import OneLineParser, size
from common.help_text import Formatter as HelpFormatter
from common.help_text import description as _description


def build_parser() -> argparse.ArgumentParser:
    assert __doc__ is not None
    first, rest = __doc__.split("\n\n", 1)
    p = OneLineParser(prog="acquire verify", description=_description(first),
                formatter_class=HelpFormatter, epilog=rest.replace("``", ""))
    p.add_argument("--result", type=Path, help="the calibration to verify (result YAML, with its covariance)")
    p.add_argument("--robot", help="robot spec (default: mock:<the result's robot>, the simulated rig)")
    p.add_argument("--tracker", help="tracker spec (default mock)")
    p.add_argument("--config", type=Path, help="site YAML (cell, timeouts, verify: cube_centre, cube_edge, cycles)")
    p.add_argument("--session", type=Path,
                   help="session file to create (default sessions/<robot>-verify-<time>.session)")
    p.add_argument("--resume", type=Path, metavar="SESSION", help="continue this verification session")
    p.add_argument("--cycles", type=size("cycles"),
                   help="visits of each pose per run (site verify.cycles; default 30, as ISO 9283 asks; fewer for a "
                   "quicker test: the dry run shows the duration)")
    p.add_argument("--samples", type=size("samples"), help="tracker samples per visit (site default)")
    p.add_argument("--dry-run", action="store_true", help="print the test and its checks; move nothing")
    p.add_argument("--yes", action="store_true", help="do not ask before moving a real robot")
    p.add_argument("--realtime", action="store_true", help="mock mode at the speed of a real run")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.add_argument("--force", action="store_true",
                   help="replace an existing .verify.yaml or report beside a new session")
    for name in ("noise", "steps", "free_poses", "speed_fraction", "log", "trace_io"):  # what prepare.py reads
        p.set_defaults(**{name: None})
    return p
