"""Plans designed for a target accuracy (``acquire --target-accuracy 0.02mm [--max-robot-time 90s]``; pure).

The planner builds a small family of candidate plans, predicts each one's robot time (the dry run's duration
estimate) and held-out accuracy (the Cramér-Rao bound of the RMS TP error at random poses within the limits, from
the same Fisher information as the dry run's "predicted accuracy" and the result's uncertainty:
:func:`acquire.planning.plan_report.predicted_accuracy`,
:func:`acquire.planning.plan_continuous.predicted_accuracy_continuous`), and keeps the quickest one whose prediction
reaches the target within the time allowed. The candidates vary:

- continuous plans: the sweep ranges, the clear range of every swept joint (the default plan's) or that range
  shrunk towards home to :data:`RANGE_FRACTIONS` of it (a shrunk range stays inside the clear one, so it is
  clear too); and the sweep speed, the plan's own (deflection-capped) speed or a cap of :data:`SLOW_SPEEDS`
  rad/s (slower: more samples per radian; a cap no slower than the plan's fastest sweep is not considered);
  no fitted free poses (the streams carry the fit);
- stop-and-go plans: the steps per sweep (:data:`STEP_COUNTS`) and the fitted free poses (none or the site's),
  over the clear ranges.

Each candidate costs a plan (its collision checks) and a bound: about half a second; the fifteen of both modes
take some seconds, which only ``--target-accuracy`` and ``--max-robot-time`` spend.

An option the operator gave (``--steps``, ``--free-poses``) is kept in every candidate. The continuous bound
leaves out the streams' timing error, which the identification estimates (as the dry run's mode table says).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from itertools import product

from acquire.planning.plan import estimate_duration
from acquire.planning.plan_continuous import estimate_continuous_duration, predicted_accuracy_continuous
from acquire.planning.plan_modes import build_mode_plan, plan_mode
from acquire.planning.plan_report import predicted_accuracy
from common.units import hms
from config.robots import RobotModel
from config.site import SiteConfig
from session.plan import Plan

RANGE_FRACTIONS = (1.0, 0.75, 0.5)  # continuous sweep ranges considered, as fractions of the clear range about home
SLOW_SPEEDS = (0.5, 0.25)  # rad/s (m/s): the slower sweep speeds a continuous candidate may cap its sweeps at
STEP_COUNTS = (12, 24, 36)  # steps per stop-and-go sweep considered


class TargetError(Exception):
    """No candidate reaches the target within the time allowed (one line)."""


@dataclass(frozen=True)
class Candidate:
    """One plan considered: its knobs, robot time (s) and predicted held-out RMS TP error (m)."""

    mode: str
    range_fraction: float
    speed_cap: float | None  # rad/s, continuous sweeps' cap (None: the plan's own speed); None in step mode
    steps: int | None  # steps per stop-and-go sweep (None in continuous mode)
    free: int  # fitted free poses
    site: SiteConfig  # the site as this candidate plans it
    plan: Plan
    seconds: float
    accuracy: float


def clear_ranges(plan: Plan, robot: RobotModel, fraction: float) -> tuple[tuple[float, float] | None, ...]:
    """Per joint, the range the sweeps of ``plan`` cover (the clear range about home), shrunk towards home to
    ``fraction`` of it (None for a joint ``plan`` does not sweep)."""
    ranges: list[tuple[float, float] | None] = [None] * robot.n_joints
    for s in plan.steps:
        if s.kind not in ("sweep", "stream"):
            continue
        j = s.joint - 1
        values = [s.q[j]] + ([s.start[j]] if s.start is not None else [])
        lo, hi = ranges[j] or (math.inf, -math.inf)
        ranges[j] = (min(lo, *values), max(hi, *values))
    home = plan.home
    return tuple(None if r is None else (home[j] + fraction * (r[0] - home[j]), home[j] + fraction * (r[1] - home[j]))
                 for j, r in enumerate(ranges))


def _evaluate(mode: str, robot: RobotModel, site: SiteConfig) -> tuple[Plan, float, float]:
    plan = build_mode_plan(mode, robot, site)
    if mode == "step":
        return (plan, estimate_duration(plan, robot, site.measure_time),
                predicted_accuracy(plan, robot, site.tp_guess, site.tracker_noise)["with_free"])
    accuracy = predicted_accuracy_continuous(plan, robot, site.tp_guess, site.tracker_noise, site.stream_rate)
    return plan, estimate_continuous_duration(plan, site.measure_time), accuracy["with_free"]


def candidates(modes: tuple[str, ...], robot: RobotModel, site: SiteConfig, steps: int | None = None,
               free: int | None = None) -> list[Candidate]:
    """Every candidate plan of ``modes`` (``step``, ``continuous``) for ``robot`` under ``site``, sorted by robot
    time; ``steps`` and ``free`` (``--steps``, ``--free-poses``) fix those knobs when given. Raises PlanError as
    :func:`acquire.planning.plan.build_plan` does."""
    out: list[Candidate] = []
    for mode in modes:
        frees = (free,) if free is not None else ((0,) if mode == "continuous" else (0, site.free_poses))
        base = build_mode_plan(mode, robot, site.with_overrides(free_poses=0))
        for fraction in RANGE_FRACTIONS if mode == "continuous" else (1.0,):
            ranged = site if fraction == 1.0 else site.with_overrides(sweep_ranges=clear_ranges(base, robot,
                                                                                                 fraction))
            if mode == "continuous":
                knobs = [(cap, None, f) for cap, f in product((None, *SLOW_SPEEDS), dict.fromkeys(frees))]
            else:
                knobs = [(None, n, f) for n, f in product((steps,) if steps else STEP_COUNTS, dict.fromkeys(frees))]
            fastest = math.inf  # the uncapped plan's fastest sweep: a cap at or above it changes nothing
            for cap, n, f in knobs:
                if cap is not None and cap >= fastest:
                    continue
                chosen = ranged.with_overrides(free_poses=f, steps_per_sweep=n)
                if cap is not None:
                    chosen = chosen.with_overrides(stream_speed=min(cap, site.stream_speed or math.inf))
                plan, seconds, accuracy = _evaluate(mode, robot, chosen)
                if cap is None and mode == "continuous":
                    fastest = max((s.speed or 0.0 for s in plan.steps if s.kind == "stream"), default=0.0)
                out.append(Candidate(mode, fraction, cap, n, f, chosen, plan, seconds, accuracy))
    return sorted(out, key=lambda c: (c.seconds, c.accuracy))


def choose(found: list[Candidate], target: float | None, max_seconds: float | None) -> Candidate:
    """The quickest candidate whose prediction reaches ``target`` (m; None: the most accurate within the time)
    within ``max_seconds`` (None: no limit). Raises :class:`TargetError` (one line) when none does."""
    within = [c for c in found if max_seconds is None or c.seconds <= max_seconds]
    if not within:
        quickest = min(found, key=lambda c: c.seconds)
        raise TargetError(f"no plan fits in {_clock(max_seconds or 0.0)}: the quickest considered takes "
                          f"{_clock(quickest.seconds)} (raise --max-robot-time)")
    if target is None:
        return min(within, key=lambda c: (c.accuracy, c.seconds))
    reaching = [c for c in within if c.accuracy <= target]
    if not reaching:
        best = min(within, key=lambda c: c.accuracy)
        limit = "" if max_seconds is None else f" within {_clock(max_seconds)}"
        raise TargetError(f"no plan considered reaches {target * 1e3:.4g} mm{limit}: the best predicts "
                          f"{best.accuracy * 1e3:.4f} mm in {_clock(best.seconds)} (a quieter tracker, "
                          "a longer time or a looser target)")
    return min(reaching, key=lambda c: (c.seconds, c.accuracy))


def format_tradeoff(found: list[Candidate], chosen: Candidate | None, target: float | None,
                    max_seconds: float | None) -> str:
    """The dry run's trade-off table: every candidate's robot time and predicted accuracy, ``chosen`` marked (None:
    none reached the goal), 80 columns."""
    goal = [f"{target * 1e3:.4g} mm" if target is not None else "the best accuracy"]
    if max_seconds is not None:
        goal.append(f"in at most {_clock(max_seconds)}")
    lines = ["", f"plans considered for {' '.join(goal)} (robot time, accuracy):",
             f"  {'mode':<10} {'range':>5} {'sweep speed':>11} {'steps':>5} {'free':>4} {'robot time':>10} "
             f"{'predicted':>12}"]
    for c in found:
        speed = "-" if c.mode == "step" else ("plan's" if c.speed_cap is None else
                                             f"≤ {math.degrees(c.speed_cap):.0f}°/s")
        accuracy = f"{c.accuracy * 1e3:.4f} mm" if math.isfinite(c.accuracy) else "undetermined"
        over = max_seconds is not None and c.seconds > max_seconds
        misses = target is not None and not c.accuracy <= target
        mark = "<- chosen" if c is chosen else ("too long" if over else ("misses" if misses else ""))
        lines.append(f"  {c.mode:<10} {c.range_fraction * 100:>4.0f}% {speed:>11} {c.steps or '-':>5} {c.free:>4} "
                     f"{_clock(c.seconds):>10} {accuracy:>12} {mark}".rstrip())
    lines += ["  range: share of each joint's clear range about home; predicted: RMS TP error",
              "  at random held-out poses (Cramér-Rao bound; continuous: timing error left out)"]
    return "\n".join(lines)


def _clock(seconds: float) -> str:
    """h:mm:ss, rounded up (a plan shown at the limit fits in it)."""
    return hms(math.ceil(seconds - 1e-9))


def replan_for_rate(plan: Plan, robot: RobotModel, site: SiteConfig, rate: float, target: float | None,
                    resumed: bool) -> tuple[Plan, str, bool]:
    """The plan to run when the tracker streams at ``rate`` Hz instead of the site's ``stream_rate`` (an I++ server
    that refused the rate asked and took the standard's 10 reports/s): one line saying what changed, and whether to
    refuse the run (before anything moves).

    A new session's continuous ``plan`` is built again at ``rate`` (sweeps at most :data:`DEFAULT_STREAM_SPEED`
    at :data:`SPARSE_STREAM_RATE` or less, acquire/planning/plan_continuous.py): the same poses and the same joint-space
    paths, the checks of the shown plan hold, only slower. A plan that would differ in a pose, or that misses
    ``target`` (m) at the new rate, is refused with what to do; a resumed session keeps its plan (only the
    prediction line)."""
    before = predicted_accuracy_continuous(plan, robot, site.tp_guess, site.tracker_noise, site.stream_rate)
    slower = plan
    if not resumed:
        slower = build_mode_plan(plan_mode(plan), robot, site.with_overrides(stream_rate=rate))
        if [(s.kind, s.joint, s.q, s.start) for s in slower.steps] != [(s.kind, s.joint, s.q, s.start)
                                                                      for s in plan.steps]:
            return plan, (f"at {rate:g} samples/s the plan would change its poses; set plan: "
                          f"{{stream_rate: {rate:g}}} in the site file and check it with --dry-run"), True
    after = predicted_accuracy_continuous(slower, robot, site.tp_guess, site.tracker_noise, rate)
    line = (f"at {rate:g} samples/s the plan predicts {after['with_free'] * 1e3:.4g} mm held-out "
            f"({before['with_free'] * 1e3:.4g} mm planned at {site.stream_rate:g})")
    if slower is not plan:
        fastest = max((s for s in slower.steps if s.kind == "stream" and s.speed is not None), key=lambda s: s.speed)
        unit = "rad/s" if robot.joint_types[fastest.joint - 1] == "R" else "m/s"
        line += (f"; sweeps slowed to {fastest.speed:.3g} {unit} at most, same poses and paths: robot time "
                 f"{_clock(estimate_continuous_duration(plan, site.measure_time))} -> "
                 f"{_clock(estimate_continuous_duration(slower, site.measure_time))}")
    missed = target is not None and after["with_free"] > target
    if missed:
        line += (f"; the target {target * 1e3:g} mm is out of reach: set plan: {{stream_rate: {rate:g}}} in the "
                 "site file and plan again (--dry-run shows the plan it chooses)")
    return slower, line, missed
