"""The progress of a run as the operator sees it: a bar that fits the terminal, or a line every few seconds.

Progress is counted in the plan's own seconds: each step weighs what the plan says it takes (the move from the
step before, the settling and the samples; a continuous sweep its move to the start, the sweep and the streams'
slack), so a long sweep moves the bar further than a short step. The remaining time is the planned seconds left
divided by the pace so far (planned seconds done per second of wall-clock time): it starts at the plan's own
estimate and does not jump when a short step follows a long one. Times are wall-clock; a simulated run (mock
devices on their virtual clock) adds its simulated time, labelled as such.

On a terminal the bar is drawn by tqdm (chosen over rich: no dependencies of its own and a fast import; it reads
the terminal's width at each redraw and never draws a line wider); while a step runs (a continuous sweep takes
tens of seconds) it advances with the clock, never beyond the step's planned share. Without a terminal, a plain
line at the first step, every :data:`LINE_PERIOD` seconds of wall-clock time (during a long step too) and at the
last step. Every step is logged either way; ``quiet`` only silences the display.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
import time
from collections.abc import Callable
from typing import IO, TYPE_CHECKING, Any

import numpy as np

from common.fit_width import wrap
from common.units import hms
from drivers.motion import motion_time
from session.plan import Plan, Step

if TYPE_CHECKING:
    from acquire.running.orchestrator import Progress

log = logging.getLogger("acquire")

LINE_PERIOD = 5.0  # s of wall-clock time between two progress lines without a terminal
REFRESH_PERIOD = 0.5  # s between redraws while a step runs
STREAM_SLACK = 0.5  # s the streams run before and after a continuous sweep (acquire/running/stream_loop.py)
BAR_FORMAT = "{desc} {percentage:3.0f}%|{bar}| {elapsed}<{remaining}{postfix}"
BAR_FIXED = 21  # characters of BAR_FORMAT besides the label, the bar and the postfix text (" 100%|| 00:02<00:00, ")
MIN_BAR = 10  # the bar keeps at least this many characters before the label drops the step's kind


def step_durations(plan: Plan, measure_time: float) -> dict[int, float]:
    """Planned seconds of each step of ``plan`` (by index), from home in plan order: the move from the step
    before at the plan's speeds, then the settle time and the samples (``measure_time`` s each); a continuous
    sweep (kind ``stream``): the move to its start, the sweep at its own speed and the streams' slack."""
    here = np.asarray(plan.home, dtype=float)
    speed, acc = np.asarray(plan.speed, dtype=float), np.asarray(plan.acceleration, dtype=float)
    out = {}
    for s in plan.steps:
        if s.kind == "stream" and s.start is not None and s.speed is not None and s.acceleration is not None:
            start = np.asarray(s.start, dtype=float)
            seconds = float(motion_time(start - here, speed, acc).max())
            seconds += float(motion_time(s.q[s.joint - 1] - start[s.joint - 1], s.speed, s.acceleration))
            seconds += 2 * STREAM_SLACK
        else:
            seconds = float(motion_time(np.asarray(s.q) - here, speed, acc).max())
            seconds += plan.settle_time + plan.samples_per_step * measure_time
        out[s.index] = seconds
        here = np.asarray(s.q, dtype=float)
    return out


def what(step: Step) -> str:
    """A step in a few words: ``joint 3 sweep``, ``joint 3 continuous sweep``, ``free``, ``check``."""
    if step.kind == "sweep":
        return f"joint {step.joint} sweep"
    if step.kind == "stream":
        return f"joint {step.joint} continuous sweep"
    return step.kind


class ProgressDisplay:
    """The display of one run (see the module docstring). The orchestrator calls :meth:`start` before each
    step and :meth:`done` after it; :meth:`close` at the end. ``simulated``: the run's clock is virtual (its
    ``elapsed`` is shown as simulated time). ``stream`` (stderr), ``tty`` (whether it is a terminal) and ``wall``
    (the wall clock, s) are the display's edges, given by tests."""

    def __init__(self, plan: Plan, measure_time: float, quiet: bool = False, simulated: bool = False,
                 stream: IO[str] | None = None, tty: bool | None = None,
                 wall: Callable[[], float] = time.monotonic) -> None:
        self.durations = step_durations(plan, measure_time)
        self.quiet, self.simulated, self.wall = quiet, simulated, wall
        self.stream = sys.stderr if stream is None else stream
        self.tty = bool(tty if tty is not None else _isatty(self.stream))
        self.planned = 0.0  # planned seconds of the steps this run will do (grows with retakes)
        self.done_planned = 0.0
        self.started = wall()
        self.step: Step | None = None  # the step running now (None between steps)
        self.shown: Step | None = None  # the step the bar names: the running one, or the last one
        self.step_started = self.started
        self.count = self.total = 0
        self.again = False  # the pass of steps measured again (recorded missing), counted on its own
        self.simulated_elapsed = 0.0
        self.last_line = -float("inf")
        self._lock = threading.Lock()
        self._bar: Any = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # --- what the orchestrator calls -----------------------------------------------------------------------

    def plan_steps(self, steps: list[Step]) -> None:
        """The steps this run will do, in order (called once, before the first)."""
        self.planned += sum(self.durations.get(s.index, 0.0) for s in steps)

    def start(self, step: Step, count: int, total: int, again: bool = False) -> None:
        """Step number ``count`` of ``total`` in this run starts (``again``: of the steps measured again)."""
        with self._lock:
            self.step, self.shown, self.count, self.total, self.again = step, step, count, total, again
            self.step_started = self.wall()
        if self.quiet:
            return
        if self._thread is None:
            if self.tty:
                self._open_bar()
            self._thread = threading.Thread(target=self._tick, daemon=True, name="acquire-progress")
            self._thread.start()
        self._draw()

    def done(self, p: Progress) -> None:
        """A step ended (:class:`acquire.running.orchestrator.Progress`: its status, samples, the sweep's residual so
        far and the run's own clock, simulated or not)."""
        with self._lock:
            if p.status == "missing" and not p.again:  # measured once more at the end of the run: more time, the
                self.planned += self.durations.get(p.step.index, 0.0)  # same step count (a pass of its own)
            self.done_planned += self.durations.get(p.step.index, 0.0)
            self.step, self.count, self.total, self.again = None, p.done, p.total, p.again
            self.simulated_elapsed = p.elapsed
        extra = f", sweep residual {p.residual * 1e3:.3f} mm" if p.residual is not None else ""
        outcome = f"{p.samples} samples, {p.status}" if p.samples else p.status  # a rehearsal measures nothing
        line = f"{self._label()} ({what(p.step)}): {outcome}; {self._times()}{extra}"
        log.info(line)
        if self.quiet:
            return
        if self.tty:
            self._draw()
        elif p.done in (1, p.total) or self.wall() - self.last_line >= LINE_PERIOD:
            self._line(line)

    def _label(self) -> str:
        """``step 12/256``, or ``again 3/119`` in the pass of steps measured again."""
        return f"{'again' if self.again else 'step'} {self.count}/{self.total}"

    def close(self) -> None:
        """End the display (the bar stays on screen, with a newline after it)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2 * REFRESH_PERIOD)
        if self._bar is not None:
            with self._lock, contextlib.suppress(OSError, ValueError):
                self._bar.close()
            self._bar = None

    # --- the estimate ----------------------------------------------------------------------------------------

    def progress(self) -> float:
        """Planned seconds done, the running step's share included (never beyond its planned duration)."""
        if self.step is None:
            return self.done_planned
        share = self.durations.get(self.step.index, 0.0)
        return self.done_planned + min(max(self.wall() - self.step_started, 0.0), 0.95 * share)

    def remaining(self) -> float:
        """Wall-clock seconds left: the planned seconds left at the pace so far (the plan's own figure before
        anything is done)."""
        done = self.progress()
        left = max(self.planned - done, 0.0)
        elapsed = self.wall() - self.started
        return left if done <= 0 or elapsed <= 0 else left * elapsed / done

    def _times(self) -> str:
        text = f"elapsed {hms(self.wall() - self.started)}, remaining about {hms(self.remaining())}"
        return text + (f" (simulated time {hms(self.simulated_elapsed)})" if self.simulated else "")

    # --- drawing ---------------------------------------------------------------------------------------------

    def _open_bar(self) -> None:
        from tqdm import tqdm

        tqdm.monitor_interval = 0  # no monitor thread: this display redraws itself
        self._bar = tqdm(total=max(self.planned, 1e-9), file=self.stream, dynamic_ncols=True, smoothing=0.0,
                         bar_format=BAR_FORMAT, mininterval=0.0, leave=True)

    def _draw(self) -> None:
        """Redraw the bar (terminal) from the current state."""
        if self._bar is None:
            return
        with self._lock:
            label = self._label()
            sim = f"simulated {hms(self.simulated_elapsed)}" if self.simulated else ""
            room = _columns(self.stream) - len(label) - len(sim) - BAR_FIXED  # for the bar
            if self.shown is not None and room - len(what(self.shown)) - 1 >= MIN_BAR:  # the step's kind: if it fits
                label += f" {what(self.shown)}"
            elif room < 3:
                sim = ""
            with contextlib.suppress(OSError, ValueError):  # a closed terminal (SIGHUP) ends the display only
                self._bar.total = max(self.planned, 1e-9)
                self._bar.n = min(self.progress(), self._bar.total)
                self._bar.set_description_str(label, refresh=False)
                self._bar.set_postfix_str(sim, refresh=False)
                self._bar.refresh()

    def _line(self, line: str) -> None:
        """A progress line without a terminal: wrapped to ``COLUMNS`` when set (common/fit_width.py), else whole (a
        log keeps one line per item)."""
        self.last_line = self.wall()
        with self._lock, contextlib.suppress(OSError, ValueError):
            print("\n".join(wrap(line)), file=self.stream, flush=True)

    def _tick(self) -> None:
        while not self._stop.wait(REFRESH_PERIOD):
            self.tick()

    def tick(self) -> None:
        """While a step runs (every REFRESH_PERIOD s): advance the bar, or, without a terminal, say what runs once
        LINE_PERIOD s have passed since the last line."""
        if self.quiet:
            return
        step = self.step
        if self.tty:
            self._draw()
        elif step is not None and self.wall() - self.last_line >= LINE_PERIOD:
            running = self.wall() - self.step_started
            self._line(f"{self._label()} ({what(step)}): running for {running:.0f} s (planned "
                       f"{self.durations.get(step.index, 0.0):.0f} s); {self._times()}")


def _columns(stream: IO[str]) -> int:
    """The width of the terminal ``stream`` writes to (80 when it cannot be told)."""
    try:
        return os.get_terminal_size(stream.fileno()).columns
    except (AttributeError, OSError, ValueError):
        return 80


def _isatty(stream: IO[str]) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False
