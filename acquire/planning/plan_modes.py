"""The three acquisition modes (``acquire --mode step | continuous | both``): the plan of each, the mode of a plan,
and the dry run's side-by-side comparison (pure, no devices).

- ``step``: stop-and-go sweeps and free poses (:func:`acquire.planning.plan.build_plan`);
- ``continuous``: one constant-speed sweep per joint while both devices stream, plus a short stop-and-go part
  (:func:`acquire.planning.plan_continuous.build_continuous_plan`);
- ``both`` (:func:`build_both_plan`): per joint, last to first, the stop-and-go sweep of that joint, then its
  continuous sweep over the same range (the stop-and-go pose at the range start, then the stream), then a home
  check; the check poses (and the fitted free poses, when asked for) last, in the continuous plan's order. The
  stop-and-go sweeps need no clock: they fix the geometry on their own, so the joint fit of the clock offset and
  drift (identify/estimator/sync.py) is anchored by samples whose timing cannot be wrong, and the session can be
  identified from its stop-and-go rows or from its streams alone to check the streams' timing independently (README,
  "Continuous motion"). It costs the robot time of both. Every move between two joints' blocks goes through home:
  a single-joint move inside a range checked clear of the cell, so clear by construction (and
  :func:`acquire.planning.plan.plan_clearance` checks every move again).

Continuous and both plans fit no free poses unless ``--free-poses`` asks for them (:func:`mode_site`): the streams
carry the fit.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from acquire.planning.plan import HOME_SWEEP, build_plan, estimate_duration
from acquire.planning.plan_continuous import (
    build_continuous_plan,
    estimate_continuous_duration,
    predicted_accuracy_continuous,
)
from acquire.planning.plan_report import predicted_accuracy
from common.units import hms
from config.cell import cell_from_config, first_contact
from config.robots import RobotModel
from config.site import SiteConfig
from session.plan import Plan, Step

MODES = ("step", "continuous", "both")


def plan_mode(plan: Plan) -> str:
    """``step`` (no stream step), ``continuous`` (stream steps and no stop-and-go sweep) or ``both``."""
    kinds = {s.kind for s in plan.steps}
    if "stream" not in kinds:
        return "step"
    return "both" if "sweep" in kinds else "continuous"


def mode_site(site: SiteConfig, mode: str | None, free_poses: int | None) -> SiteConfig:
    """``site`` as ``mode`` plans it: continuous and both fit no free poses unless ``free_poses`` (the
    ``--free-poses`` option) asks for some; step mode (``None`` too) keeps the site's."""
    if mode in ("continuous", "both") and free_poses is None:
        return site.with_overrides(free_poses=0)
    return site


def build_mode_plan(mode: str | None, robot: RobotModel, site: SiteConfig, rng_seed: int = 0) -> Plan:
    """The plan of ``mode`` (None: step) for ``robot`` under ``site`` (already :func:`mode_site`'s). Raises
    PlanError as :func:`acquire.planning.plan.build_plan` does."""
    if mode == "continuous":
        return build_continuous_plan(robot, site, rng_seed)
    if mode == "both":
        return build_both_plan(robot, site, rng_seed)
    return build_plan(robot, site, rng_seed)


def build_both_plan(robot: RobotModel, site: SiteConfig, rng_seed: int = 0) -> Plan:
    """The plan holding the stop-and-go sweeps of :func:`acquire.planning.plan.build_plan` and the continuous sweeps of
    :func:`acquire.planning.plan_continuous.build_continuous_plan` for ``robot`` under ``site`` (module docstring).
    Sweep ids: one per stop-and-go sweep, one per stop-and-go pose and per stream (home checks ``HOME_SWEEP``)."""
    step = build_plan(robot, site, rng_seed)
    cont = build_continuous_plan(robot, site, rng_seed)
    home = tuple(cont.home)
    sweeps: dict[int, list[Step]] = {}
    for s in step.steps:
        if s.kind == "sweep":
            sweeps.setdefault(s.joint, []).append(s)
    streams: dict[int, list[Step]] = {}  # joint -> [its range-start pose, its stream]
    for k, s in enumerate(cont.steps):
        if s.kind == "stream":
            streams[s.joint] = [cont.steps[k - 1], s]
    starts = {id(pair[0]) for pair in streams.values()}
    # the check (and fitted free) poses, in the continuous plan's order, from home after the last block
    tail = [s for s in cont.steps if s.kind == "free" and id(s) not in starts]
    ordered: list[Step] = [Step(0, "home", HOME_SWEEP, 0, home)]
    for j in sorted(set(sweeps) | set(streams), reverse=True):
        ordered += sweeps.get(j, []) + streams.get(j, [])
        ordered.append(Step(0, "home", HOME_SWEEP, 0, home))
    cell, here = cell_from_config(robot, site), np.asarray(home)
    for s in tail:  # every move of the tail checked; through home where the direct move would come too close
        if cell is not None and first_contact(cell, here, np.asarray(s.q)) is not None:
            ordered.append(Step(0, "home", HOME_SWEEP, 0, home))
        ordered.append(s)
        here = np.asarray(s.q)
    if ordered[-1].kind != "home":
        ordered.append(Step(0, "home", HOME_SWEEP, 0, home))
    steps: list[Step] = []
    ids: dict[tuple[str, int], int] = {}
    for s in ordered:
        if s.kind == "home":
            sweep = HOME_SWEEP
        elif s.kind == "sweep":  # the steps of one stop-and-go sweep share its id
            sweep = ids.setdefault(("sweep", s.sweep), len(ids) + 1)
        else:
            sweep = ids.setdefault((s.kind, s.index), len(ids) + 1)
        steps.append(replace(s, index=len(steps), sweep=sweep))
    notes = [n for n in step.notes if n.startswith("joint") and "sweep" in n and "continuous" not in n]
    notes += [n for n in cont.notes if n not in notes]
    notes.insert(0, "both modes: per joint the stop-and-go sweep, then the continuous sweep of the same range, then "
                    "home; the stop-and-go sweeps need no clock and check the streams' timing "
                    "(acquire/planning/plan_modes.py)")
    return replace(cont, steps=tuple(steps), notes=tuple(notes), speed=step.speed)  # stop-and-go sweeps' speed


def format_modes(robot: RobotModel, site: SiteConfig, shown: Plan, free_poses: int | None = None,
                 no_stream: str = "") -> str:
    """The dry run's comparison of the three modes for ``robot`` under ``site`` (before :func:`mode_site`;
    ``free_poses`` the ``--free-poses`` option): robot time (the duration estimate), tracker samples and predicted
    accuracy (Cramér-Rao bound of the held-out RMS TP error, timing error excluded) of each mode's plan
    (``shown`` is one of them). ``no_stream``: why the tracker cannot stream (then only the step mode is shown)."""
    if no_stream:
        return f"\nmodes: step only: {no_stream}; continuous and both need a streaming tracker"
    rows = []
    for mode in MODES:
        plan = shown if plan_mode(shown) == mode else build_mode_plan(mode, robot, mode_site(site, mode, free_poses))
        stop_and_go = sum(1 for s in plan.steps if s.kind != "stream") * plan.samples_per_step
        if mode == "step":
            seconds = estimate_duration(plan, robot, site.measure_time)
            accuracy, samples = predicted_accuracy(plan, robot, site.tp_guess, site.tracker_noise)["with_free"], 0.0
        else:
            seconds = estimate_continuous_duration(plan, site.measure_time)
            acc = predicted_accuracy_continuous(plan, robot, site.tp_guess, site.tracker_noise, site.stream_rate)
            accuracy, samples = acc["with_free"], acc["samples"]
        rows.append((mode, seconds, int(samples) + stop_and_go, accuracy))
    step_time = rows[0][1]
    lines = ["", "modes (--mode step | continuous | both):", f"  {'mode':<11} {'robot time':>10} {'x step':>7} "
             f"{'samples':>8} {'predicted accuracy (RMS, held out)':>36}"]
    for mode, seconds, samples, accuracy in rows:
        shown_accuracy = f"{accuracy * 1e3:.4f} mm" if math.isfinite(accuracy) else "undetermined"
        lines.append(f"  {mode:<11} {hms(seconds):>10} {seconds / step_time:>7.2f} {samples:>8} "
                     f"{shown_accuracy:>36}")
    lines.append(f"  streams at {site.stream_rate:g} Hz, every sample with the tracker noise; the bounds leave out the "
                 "timing error, which the identification estimates (both: the stop-and-go sweeps need no clock)")
    return "\n".join(lines)
