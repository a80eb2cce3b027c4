"""The ``acquire`` command line: its options, subcommands and exit codes (``acquire --help``).

Light on purpose: the entry point (acquire/commands/launch.py) parses the command line with this parser before anything
heavy is imported, so ``--help``, ``--version`` and a mistyped option answer at once.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from common.arguments import OneLineParser, VersionAction, size
from common.help_text import Formatter as HelpFormatter
from common.units import Typed, positive_duration, positive_length

DESCRIPTION = "Plan, move, measure and record a calibration session, then identify the robot from it."

EPILOG = """\
examples:
  acquire --robot mock:ur5e --tracker mock     a rehearsal, all simulated
  acquire --robot ur5e --tracker mock --dry-run
      the plan, its duration and accuracy; nothing moves
  acquire --dry-run --target-accuracy 0.02mm --max-robot-time 2min
      the quickest plan predicted to reach 0.02 mm
  acquire --robot ur5e@192.168.1.10 --tracker serial:/dev/ttyUSB0 \\
      --config site.yaml                       a real arm and tracker
  acquire --robot ur5e@192.168.1.10 --tracker emscon:192.168.0.1 \\
      --config site.yaml                       a Leica tracker's emScon server
  acquire --robot ur5e@192.168.1.10 --tracker emscon:192.168.0.1 \\
      --mode continuous                        its continuous measurement
  acquire --robot ur5e@192.168.1.10 --tracker none
      the plan's motion at 25 % speed, measuring nothing
  acquire --resume SESSION                     continue an interrupted session
  acquire --tracker 'serial:/dev/ttyUSB0?protocol=polled-xyz' --probe
      check the tracker on site

subcommands (each has its own --help):
  export SESSION --csv OUT.csv     the session's measurements as a CSV
  backup SESSION COPY              a safe copy, even of a session being written
  verify --result RESULT           ISO 9283-style accuracy, before and after
                                   compensation
  calibrate-camera IMAGES --out F  a camera's intrinsics from ChArUco views
  print-board --out F              a marker or board to print at true scale

exit codes:
  0    complete (the identification passes, or passes with warnings)
  1    the run failed: robot fault, lost connection, timeout (resumable)
  2    bad input, or a plan that breaks a limit or comes too close to the cell
       (one line)
  3    complete, but the identification fails its verdict (do not use the
       model)
  130  stopped by Ctrl-C, SIGTERM or SIGHUP: the motion stops, the run is
       recorded as aborted (resumable)
"""


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="acquire", description=DESCRIPTION, formatter_class=HelpFormatter,
                epilog=EPILOG)
    p.add_argument("--robot", help="robot spec: ur5e, ur5e@HOST, mock:ur5e; the model may be a robot YAML file: "
                   "mock:my_arm.yaml, my_arm.yaml@HOST (mock:ur5e; on --resume: the session's, whose address may "
                   "change)")
    p.add_argument("--tracker", help="tracker spec: serial:PORT?..., ipp://HOST, emscon:HOST[:PORT]?... (a Leica "
                   "laser tracker's emScon server, port 700: stationary points, and for continuous sweeps its "
                   "continuous measurement by time stamped with the tracker's clock; ?probe=6dof: a 6-DoF probe's "
                   "full poses; emscon:sim with a mock robot), "
                   "aruco:... (a camera in the cell: aruco:0?..., aruco:/dev/video0?..., a network camera "
                   "aruco:http://HOST:PORT/PATH#... (an MJPEG stream or a snapshot URL; its options after '#'); "
                   "aruco:...&mount=flange: a camera on the flange seeing a fixed board: jog the arm where it sees "
                   "the whole board; a checked, confirmed locate phase of small wrist turns measures its mount and "
                   "the board, then stop-and-go views that keep it in sight are planned and shown; &square_sigma=M: "
                   "the board measured; &flatness=M&lens_sigma=K&focal_sigma=F&centre_sigma=PX: the board's shape, "
                   "the lens's residual k1, k2, focal length (relative) and principal point estimated from the views; "
                   "&latency=S: s from a frame's exposure to its delivery, a reading skips "
                   "the frames delivered within it of its request (default 0, a network camera's measured one); "
                   "aruco:sim's dk1, dfocal, dcx, shutter, exposure, gain, gradient, glare, bow: a real "
                   "camera's errors, drivers/camera/imperfections.py), mock, or none (motion "
                   "rehearsal) (mock; on --resume: the session's, whose port or "
                   "host may change)")
    p.add_argument("--config", type=Path, help="site YAML (hosts, tracker, sweep ranges, timeouts)")
    p.add_argument("--session", type=Path, help="session file to create (default sessions/<robot>-<time>.session)")
    p.add_argument("--resume", type=Path, metavar="SESSION", help="continue this session where it stopped")
    p.add_argument("--remeasure-missing", action="store_true",
                   help="with --resume: measure a complete session's missing steps again (the first attempt is kept)")
    p.add_argument("--force", action="store_true",
                   help="replace an existing result or report beside a new session")
    p.add_argument("--dry-run", action="store_true", help="print the plan and what it will reach; move nothing")
    p.add_argument("--yes", action="store_true", help="do not ask before moving a real robot")
    p.add_argument("--realtime", action="store_true", help="mock mode at the speed of a real run")
    p.add_argument("--quiet", action="store_true", help="no progress display")
    p.add_argument("--log", type=Path, metavar="FILE", help="log every step and event to FILE")
    p.add_argument("--steps", type=size("steps"), help="steps per sweep (site default 36)")
    p.add_argument("--samples", type=size("samples"), help="tracker samples per step (site default)")
    p.add_argument("--free-poses", type=size("free_poses"), help="free poses added for the fit and validation")
    p.add_argument("--noise", action=Typed, convert=positive_length, metavar="LENGTH",
                   help="tracker noise per axis (1 sigma) for the predicted accuracy, e.g. 0.05mm or 50um (a bare "
                        "number is metres)")
    p.add_argument("--target-accuracy", action=Typed, convert=positive_length, metavar="LENGTH",
                   help="plan for this predicted held-out accuracy (RMS TP error, e.g. 0.02mm) in the least robot "
                        "time: candidate sweep ranges, speeds, steps and free poses, and the dry run prints their "
                        "robot time against predicted accuracy (with --mode: that mode's only)")
    p.add_argument("--max-robot-time", action=Typed, convert=positive_duration, metavar="TIME",
                   help="the longest robot time a planned session may take, e.g. 90s or 2min (a bare number is "
                        "seconds); alone: the most accurate candidate plan within it")
    p.add_argument("--probe", action="store_true",
                   help="open the tracker, take --count readings, print them with their spread, and exit")
    p.add_argument("--count", type=size("count"), default=10, help="readings taken by --probe (10)")
    p.add_argument("--json", action="store_true",
                   help="with --probe: one JSON object per reading; with --dry-run: the plan as one JSON object")
    p.add_argument("--speed-fraction", type=float, metavar="F",
                   help="joint speeds and accelerations as this fraction of the model's defaults (site "
                        "robot.speed_fraction; 0.25 with --tracker none)")
    p.add_argument("--mode", choices=("step", "continuous", "both"), default=None,
                   help="step: stop-and-go sweeps (the default); continuous: each sweep one constant-speed move while "
                        "robot and tracker stream (both must stream); both: per joint the stop-and-go sweep and the "
                        "continuous one (the stop-and-go sweeps need no clock: they anchor the streams' timing and can "
                        "check it; --steps sets their size); the dry run compares the three")
    p.add_argument("--trace-io", type=Path, metavar="FILE",
                   help="log every byte to and from the tracker (serial, I++ and emScon trackers)")
    p.add_argument("--camera-mount", metavar="X,Y,Z,RX,RY,RZ",
                   help="a flange camera's rough pose on the flange (flange <- camera, OpenCV's camera frame: z along "
                   "the line of sight; m, and a rotation vector in degrees), e.g. from the bracket's drawing; the "
                   "locate phase measures it (default 0,0,0.05,0,0,0 known to 100 mm and any turn)")
    p.add_argument("--camera-mount-tolerance", metavar="MM,DEG",
                   help="how far --camera-mount may be off (20,10): a located mount farther off is refused; the "
                   "camera's body is grown by it in the locate moves' collision check")
    p.add_argument("--version", action=VersionAction)
    return p
