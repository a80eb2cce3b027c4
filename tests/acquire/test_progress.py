"""The progress of a run (acquire/running/progress.py): counted in the plan's seconds, in wall-clock time, an estimate
that does not jump, a line every few seconds without a terminal, and a bar that fits a real 80-column terminal."""

from __future__ import annotations

import fcntl
import io
import itertools
import os
import pty
import re
import select
import struct
import sys
import termios
from pathlib import Path

import pytest

from acquire.planning.plan import estimate_duration
from acquire.planning.plan_continuous import estimate_continuous_duration
from acquire.planning.plan_modes import build_mode_plan, mode_site
from acquire.running.orchestrator import Progress
from acquire.running.progress import LINE_PERIOD, ProgressDisplay, step_durations
from config.robots import load_robot
from config.site import SiteConfig

ROBOT = load_robot("ur5e")
SITE = SiteConfig.default().with_overrides(steps_per_sweep=8, free_poses=4)


class Wall:
    """A wall clock the test moves (s)."""

    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture(scope="module")
def plans():
    step = build_mode_plan("step", ROBOT, SITE)
    continuous = build_mode_plan("continuous", ROBOT, mode_site(SITE, "continuous", None))
    return step, continuous


def test_the_steps_planned_seconds_add_up_to_the_dry_runs_estimate(plans):
    step, continuous = plans
    assert sum(step_durations(step, SITE.measure_time).values()) == pytest.approx(
        estimate_duration(step, ROBOT, SITE.measure_time), rel=1e-12)
    assert sum(step_durations(continuous, SITE.measure_time).values()) == pytest.approx(
        estimate_continuous_duration(continuous, SITE.measure_time), rel=1e-12)


def _run(display: ProgressDisplay, wall: Wall, plan, pace: float, check=None) -> None:
    """Every step of ``plan`` taking ``pace`` times its planned seconds of wall-clock time."""
    durations = step_durations(plan, SITE.measure_time)
    display.plan_steps(list(plan.steps))
    n = len(plan.steps)
    for k, step in enumerate(plan.steps, 1):
        display.start(step, k, n)
        wall.t += pace * durations[step.index]
        display.done(Progress(step, k, n, 0.0, 0.0, 3, "ok", None))
        if check is not None:
            check(k, durations)


@pytest.mark.parametrize("which", [0, 1])
def test_the_remaining_time_follows_the_plan_and_does_not_jump(plans, which):
    """Steps of very different lengths (a 30 s sweep after 2 s steps) at a steady 1.3x the plan's pace: after
    every step the estimate is the true remaining time, so it only falls. Counting steps instead (the old
    estimate) would jump at every long step."""
    plan = plans[which]
    wall = Wall()
    display = ProgressDisplay(plan, SITE.measure_time, quiet=True, wall=wall)
    steps = plan.steps
    seen = []

    def check(k, durations):
        true_left = 1.3 * sum(durations[s.index] for s in steps[k:])
        seen.append(display.remaining())
        assert display.remaining() == pytest.approx(true_left, rel=1e-9, abs=1e-9)

    _run(display, wall, plan, 1.3, check)
    assert all(b <= a + 1e-9 for a, b in itertools.pairwise(seen))


def test_without_a_terminal_one_line_every_few_seconds_of_wall_time(plans):
    """A line at the first step, then one whenever LINE_PERIOD s of wall-clock time have passed, and the last; a
    long step (a continuous sweep) is reported while it runs."""
    plan = plans[1]
    out, wall = io.StringIO(), Wall()
    display = ProgressDisplay(plan, SITE.measure_time, stream=out, tty=False, wall=wall)
    printed = []
    display._line = lambda line, _orig=display._line: (printed.append(wall.t), _orig(line))  # when each came
    _run(display, wall, plan, 1.0)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("step 1/") and lines[-1].startswith(f"step {len(plan.steps)}/{len(plan.steps)}")
    gaps = [b - a for a, b in itertools.pairwise(printed[1:-1])]
    assert gaps and min(gaps) >= LINE_PERIOD
    total = sum(step_durations(plan, SITE.measure_time).values())
    assert len(lines) <= total / LINE_PERIOD + 2
    # during a long sweep: a line while it runs, saying how long it has run of its planned seconds
    sweep = next(s for s in plan.steps if s.kind == "stream")
    display = ProgressDisplay(plan, SITE.measure_time, stream=(out := io.StringIO()), tty=False, wall=wall)
    display.plan_steps(list(plan.steps))
    display.start(sweep, 3, 23)
    display.last_line = wall.t
    wall.t += LINE_PERIOD + 7
    display.tick()
    assert re.search(r"step 3/23 \(joint \d continuous sweep\): running for 12 s \(planned \d+ s\)", out.getvalue())


def test_without_a_terminal_lines_fit_columns_when_set(plans, monkeypatch):
    """``COLUMNS=80 acquire ... | cat``: the progress lines (99 columns before, issue 39 item 10) fit; without
    COLUMNS a log keeps one line per item."""
    plan = plans[1]
    for columns, most in (("80", 80), (None, 10**6)):
        if columns is None:
            monkeypatch.delenv("COLUMNS", raising=False)
        else:
            monkeypatch.setenv("COLUMNS", columns)
        out, wall = io.StringIO(), Wall()
        display = ProgressDisplay(plan, SITE.measure_time, stream=out, tty=False, simulated=True, wall=wall)
        _run(display, wall, plan, 1.0)
        lines = out.getvalue().splitlines()
        assert lines and max(map(len, lines)) <= most
        assert (columns is None) == all(line.startswith("step ") for line in lines)  # wrapped: continuations


def _pty_run(argv: list[str], cols: int, cwd: Path | None = None) -> str:
    """The command's terminal output at ``cols`` columns (a real pseudo-terminal), escape sequences removed."""
    pid, fd = pty.fork()
    if pid == 0:  # the child: the command on the terminal
        if cwd is not None:
            os.chdir(cwd)
        os.execv(argv[0], argv)
    fcntl.ioctl(fd, termios.TIOCSWINSZ, struct.pack("HHHH", 24, cols, 0, 0))
    out = b""
    while select.select([fd], [], [], 120)[0]:
        try:
            chunk = os.read(fd, 65536)
        except OSError:  # the child closed the terminal
            break
        if not chunk:
            break
        out += chunk
    os.waitpid(pid, 0)
    return re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", out.decode(errors="replace"))


def _assert_bar(text: str, cols: int) -> None:
    """The progress bar of a 6-step mock session on a ``cols``-column terminal: redrawn in place, never wider, done in
    seconds of wall-clock time (and, at 80 columns, minutes of simulated time, labelled; narrower: the label and
    the bar keep the room)."""
    bars = [line for line in re.split(r"[\r\n]", text) if "%|" in line]
    assert len(bars) > 10
    assert max(len(b) for b in bars) <= cols
    last = bars[-1]
    assert re.search(r"100%\|█+\| 00:0\d<00:00", last)
    if cols >= 80:
        assert re.search(r"simulated 0:0[1-9]:\d\d", last) and "joint 3 sweep" in text


@pytest.mark.slow
def test_the_bar_fits_a_narrow_terminal_and_shows_wall_clock_time(tmp_path):
    """50 columns (80: the session below, on the same command)."""
    acquire = str(Path(sys.executable).with_name("acquire"))
    _assert_bar(_pty_run([acquire, "--robot", "mock:ur5e", "--tracker", "mock", "--steps", "6", "--samples", "2",
                          "--free-poses", "4", "--session", str(tmp_path / "s.session")], 50), 50)


@pytest.mark.slow
def test_a_session_and_its_verification_fit_an_80_column_terminal(tmp_path):
    """What ``make demo`` prints (plan, progress, identification, verification), on a real 80-column terminal:
    no line wider, the progress bar in wall-clock and simulated time, the DH table's four columns side by side."""
    bin_ = Path(sys.executable).parent
    text = _pty_run([str(bin_ / "acquire"), "--robot", "mock:ur5e", "--tracker", "mock", "--steps", "6",
                     "--samples", "2", "--free-poses", "4", "--session", "s.session"], 80, tmp_path)
    _assert_bar(text, 80)
    text += _pty_run([str(bin_ / "acquire"), "verify", "--result", "s.result.yaml", "--robot", "mock:ur5e",
                      "--tracker", "mock", "--cycles", "2", "--session", "v.session"], 80, tmp_path)
    lines = re.split(r"[\r\n]", text)
    assert "verification written to" in text and "Traceback" not in text
    assert max(len(line) for line in lines) <= 80, max(lines, key=len)
    assert any(re.search(r"theta \[deg\] +d \[mm\] +a \[mm\] +alpha \[deg\]", line) for line in lines)


def test_a_motion_rehearsal_shows_the_same_progress(capsys):
    """--tracker none: the same display (without a terminal: the first and the last step), in wall-clock time with
    the simulated time labelled; nothing measured, so no sample counts."""
    from acquire.commands.cli import main

    assert main(["--robot", "mock:ur5e", "--tracker", "none", "--steps", "6", "--free-poses", "4"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and err[0].startswith("step 1/") and re.match(r"step (\d+)/\1 \(home\): reached;", err[1])
    assert re.search(r"elapsed 0:00:0\d, .*\(simulated time 0:[01]\d:\d\d\)", err[1])
