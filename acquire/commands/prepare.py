"""What the ``acquire`` commands share before anything moves: the site with the command line's overrides, the
operator's confirmation, the devices opened (mock mode's simulated rig behind them), and the check of the move from
where the arm stands to the plan's first step. ``UsageError``: bad input, one line and exit code 2."""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

from config.site import SiteConfig, load_site
from drivers.clock import Clock, VirtualClock, WallClock
from drivers.spec import RobotSpec, TrackerSpec

if TYPE_CHECKING:
    from acquire.running.session import Session
    from config.cell import Clearance
    from config.robots import RobotModel
    from drivers.base import Robot, Tracker
    from drivers.sim.rig import SimulatedRig
    from session.plan import Plan

Spec = TypeVar("Spec", RobotSpec, TrackerSpec)


class UsageError(Exception):
    """Bad input: one line, exit code 2."""


REHEARSAL_SPEED = 0.25  # --tracker none: the share of the model's default speeds and accelerations


def site_from_args(args: argparse.Namespace) -> SiteConfig:
    """The site file (``--config``; default the built-in site) with the command line's overrides; ``--tracker
    none`` (a rehearsal) moves at :data:`REHEARSAL_SPEED` unless ``--speed-fraction`` says otherwise."""
    site = load_site(args.config) if args.config else SiteConfig.default()
    fraction = args.speed_fraction
    if fraction is None and getattr(args, "tracker", None) == "none":
        fraction = REHEARSAL_SPEED
    if fraction is not None and not 0 < fraction <= 1:
        raise UsageError(f"--speed-fraction must be in (0, 1], got {fraction}")
    return site.with_overrides(steps_per_sweep=args.steps, samples_per_step=args.samples,
                               free_poses=args.free_poses, tracker_noise=args.noise, speed_fraction=fraction,
                               acceleration_fraction=fraction)


UNIT_SLIP = 10.0  # a noise this many times off the tracker's stated one: a unit slip, not the tracker
NOISE_MAX = 0.01  # m: a noise (per axis) or a target accuracy above 1 cm calibrates nothing
TARGET_SLIP = 100.0  # a target accuracy this many times the tracker's noise is met by any plan: a unit slip


def stated_noise(tracker: TrackerSpec | None) -> float | None:
    """The noise per axis (m) the named tracker states: a mock tracker's ``noise`` option (or its default), a
    serial profile's data-sheet ``sigma``; None when it states none (or it cannot be read: said elsewhere)."""
    return tracker_states(tracker)[0]


def tracker_states(tracker: TrackerSpec | None) -> tuple[float | None, float | None, str]:
    """What the named tracker states before it is opened: its noise per axis (m; None: unknown), its stream rate
    (Hz; 0: it cannot stream, a polled device; None: unknown) and what says so (``profile polled-xyz``)."""
    if tracker is None:
        return None, None, ""
    if tracker.backend == "mock":
        from drivers.spec import MOCK_TRACKER_OPTIONS

        try:
            return (float(tracker.options.get("noise", MOCK_TRACKER_OPTIONS["noise"][1])),
                    float(tracker.options.get("rate", MOCK_TRACKER_OPTIONS["rate"][1])), "the mock tracker's options")
        except ValueError:
            return None, None, ""
    if tracker.backend == "serial":
        from drivers.trackers.ascii_profile import load_profile

        try:
            profile = load_profile(tracker.options.get("protocol", "polled-xyz"))
        except Exception:  # an unreadable profile is refused by the tracker's own checks, in its words
            return None, None, ""
        rate = 0.0 if profile.mode == "polled" else (1.0 / profile.period if profile.period else None)
        return profile.sigma, rate, f"profile {profile.name}"
    if tracker.backend == "emscon":  # continuous by time: one point per millisecond at most (the TPI's least step)
        noise = None
        if tracker.target == "sim":
            try:
                noise = float(tracker.options.get("noise", 5e-5))
            except ValueError:
                noise = None
            noise = noise if noise is not None and 0 < noise < math.inf else None  # else refused by the tracker
        return noise, 1000.0, "the emScon TPI"
    return None, None, ""


def tracker_site(site: SiteConfig, args: argparse.Namespace, tracker: TrackerSpec | None) -> tuple[SiteConfig, str]:
    """The site planned with what the named tracker states (:func:`tracker_states`): its noise unless ``--noise``
    or the site file gives one, its stream rate unless the site file gives one. Returns the site and, for a tracker
    that cannot stream, why (else ""); ``--mode continuous`` or ``both`` with it is a UsageError."""
    noise, rate, said = tracker_states(tracker)
    given = _site_keys(args.config)
    if noise is not None and args.noise is None and ("tracker", "noise") not in given:
        site = site.with_overrides(tracker_noise=noise)
    if rate == 0.0:
        why = f"{tracker} cannot stream ({said}: polled)"
        if getattr(args, "mode", None) in ("continuous", "both"):
            raise UsageError(f"--mode {args.mode}: {why}; use --mode step")
        return site, why
    if rate is not None and ("plan", "stream_rate") not in given:
        site = site.with_overrides(stream_rate=min(rate, site.stream_rate))
    return site, ""


def _site_keys(path: Path | None) -> set[tuple[str, str]]:
    """The (section, key) pairs the site file at ``path`` sets (none without a file)."""
    if path is None:
        return set()
    from config.files import read_yaml

    data = read_yaml(Path(path))
    return {(section, key) for section, values in data.items() if isinstance(values, dict) for key in values}


def check_units(args: argparse.Namespace, site: SiteConfig, tracker: TrackerSpec | None) -> None:
    """UsageError (one line, repeating what was typed) for a ``--noise`` or ``--target-accuracy`` that looks
    1000x off: a noise above :data:`NOISE_MAX` or :data:`UNIT_SLIP` times off the tracker's stated noise, a target
    above :data:`NOISE_MAX` or :data:`TARGET_SLIP` times the noise planned with (``site.tracker_noise``, m)."""
    from common.units import as_typed, mm, slip_hint

    stated = stated_noise(tracker)
    noise = args.noise
    if noise is not None:
        what = f"the tracker states {mm(stated)} per axis" if stated else f"no tracker is noisier than {mm(NOISE_MAX)}"
        if noise > NOISE_MAX or (stated and noise > UNIT_SLIP * stated):
            raise UsageError(f"{slip_hint('--noise', as_typed(args, 'noise'), noise)} ({what})")
        if stated and noise * UNIT_SLIP < stated:
            raise UsageError(f"{slip_hint('--noise', as_typed(args, 'noise'), noise, too_large=False)} ({what}; "
                             "a tracker is not tenfold better than its data sheet)")
    target = args.target_accuracy
    if target is not None and (target > NOISE_MAX or target > TARGET_SLIP * site.tracker_noise):
        raise UsageError(f"{slip_hint('--target-accuracy', as_typed(args, 'target_accuracy'), target)} "
                         f"({target / site.tracker_noise:.0f}x the tracker noise {mm(site.tracker_noise)} per axis: "
                         "any plan reaches it)")


def without_faults(spec: Spec) -> Spec:
    """``spec`` without a mock backend's ``fault`` option."""
    if spec.backend != "mock" or "fault" not in spec.options:
        return spec
    return replace(spec, options={k: v for k, v in spec.options.items() if k != "fault"})


def confirm(robot_spec: RobotSpec, args: argparse.Namespace, plan: Plan, question: str | None = None) -> None:
    """A real robot moves only after the operator has seen the plan and said yes (or passed --yes)."""
    if robot_spec.backend == "mock" or args.yes:
        return
    if not sys.stdin.isatty():
        raise UsageError("a real robot needs confirmation: run in a terminal or pass --yes after reading the plan")
    question = question or f"Move {robot_spec} through these {len(plan.steps)} steps? Type 'yes' to start: "
    answer = input(question).strip()
    if answer.lower() != "yes":
        raise UsageError("not confirmed; nothing moved")


TRACED_BACKENDS = ("serial", "ipp", "emscon")  # trackers whose byte stream --trace-io can log


def open_traced_tracker(tracker_spec: TrackerSpec, rig: SimulatedRig | None, site: SiteConfig,
                        trace_io: Path | None) -> Tracker:
    """The tracker opened (not yet connected), logging its bytes to ``trace_io`` when given (serial, I++ and emScon
    only: UsageError otherwise)."""
    from drivers.registry import open_tracker

    if trace_io is not None and tracker_spec.backend not in TRACED_BACKENDS:
        raise UsageError(f"--trace-io logs the bytes of serial, I++ and emScon trackers, not of "
                         f"{tracker_spec.backend!r}")
    extra = {"trace_io": trace_io} if trace_io is not None else {}
    return open_tracker(tracker_spec, rig=rig, site=site, **extra)


def open_devices(robot_spec: RobotSpec, tracker_spec: TrackerSpec, realtime: bool, site: SiteConfig,
                 trace_io: Path | None = None, model: RobotModel | None = None) -> tuple[Robot, Tracker, Clock]:
    """The robot and tracker opened and connected (within the site's connect timeout, s), and the run's clock:
    mock mode's simulated rig behind mock devices, on a virtual clock unless ``realtime``. ``model``: the robot
    model to drive (a resumed session's recorded one), None for the one ``robot_spec`` names."""
    from drivers.registry import open_robot

    clock = WallClock() if realtime or robot_spec.backend != "mock" else VirtualClock()
    rig = None
    if robot_spec.backend == "mock" or tracker_spec.backend == "mock":
        from drivers.sim.rig import SimulatedRig

        rig = SimulatedRig.from_spec(robot_spec, tracker_spec, clock, model)
    robot = open_robot(robot_spec, rig=rig, site=site, model=model)
    tracker = open_traced_tracker(tracker_spec, rig, site, trace_io)
    robot.connect(site.timeouts.connect)
    tracker.connect(site.timeouts.connect)
    return robot, tracker, clock


def check_start(robot: Robot, plan: Plan, robot_model: RobotModel, site: SiteConfig, index: int,
                session: Session | None = None) -> None:
    """The plan is checked from home; the arm may stand elsewhere (jogged, or stopped mid-move before a
    resume). UsageError unless the move from where it stands to step ``index`` is clear too. The robot's
    readings give DH values through the session's coupling (a new session: the model's)."""
    import numpy as np

    from config.cell import cell_from_config, first_contact

    cell = cell_from_config(robot_model, site)
    if cell is None or not plan.steps:
        return
    here = np.asarray(robot.read_joints(), dtype=float)
    coupling = robot_model.coupling if session is None else session.coupling
    if coupling is not None:
        here = coupling.dh_from_readings(here[None, :])[0]
    step = plan.steps[index]
    contact = first_contact(cell, here, np.asarray(step.start if step.start is not None else step.q))
    if contact is not None:
        home = ", ".join(f"{np.degrees(v):.1f}" if t == "R" else f"{v:.3f}"
                         for v, t in zip(plan.home, plan.joint_types, strict=True))
        raise UsageError(f"the move from the arm's current pose to step {index} would come too close: {contact.what} "
                         f"{contact.distance * 1e3:.1f} mm apart (needs {contact.required * 1e3:.0f} mm); jog the "
                         f"arm to home ({home}; deg / m) first")


def motion_problems(plan: Plan, robot: RobotModel, robot_spec: RobotSpec, clearance: Clearance | None,
                    site: SiteConfig) -> list[str]:
    """Why the plan's motion may not run: a step or move that comes too close to the cell, or no geometry to
    check it with on a real robot."""
    if clearance is None:
        if robot_spec.backend == "mock":
            return []
        return [f"{robot.name} has no collision geometry ('collision:' in {robot.path.name}): the plan cannot be "
                "checked against the cell and the arm itself"]
    if clearance.slack >= clearance.guard:
        return []
    step = plan.steps[clearance.slack_move]
    needs = clearance.slack_distance - clearance.slack + clearance.guard
    return [f"the move to step {step.index} ({step.kind}) comes too close: {clearance.slack_what} "
            f"{clearance.slack_distance * 1e3:.1f} mm apart at a checked sample (needs {needs * 1e3:.0f} mm with "
            f"{clearance.guard * 1e3:g} mm for the motion between samples)"]
