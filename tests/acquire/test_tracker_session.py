"""A full acquisition with real tracker drivers: the orchestrator moves the simulated robot while the serial
driver (over a pseudo-terminal), the I++ client or the emScon client (over loopback TCP) measures a simulated device
that answers from the same rig's true TP; the session file is identified end to end. A device reset (serial) or a
server restart (I++, emScon) is injected mid-session, with other faults; no step may be lost or duplicated.

The CLI keeps refusing a simulated robot with a real tracker (``SimulatedRig.from_spec``): a real tracker
cannot see a simulated arm. Here the devices are assembled by hand, so the simulated device and robot share
one rig."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("serial")

from acquire.planning.plan import build_plan
from acquire.running.orchestrator import Orchestrator, Progress, Timeouts
from acquire.running.session import Session
from config.robots import load_robot
from config.site import SiteConfig
from drivers.base import Tracker
from drivers.clock import VirtualClock
from drivers.registry import open_tracker
from drivers.sim.rig import SimulatedRig
from drivers.sim.robot import SimulatedRobot
from identify.estimator.bounds import prediction_covariances, prediction_rms_bound
from identify.results.pipeline import identify
from identify.simulators.simulate import random_poses
from kinematics.dh import points_from_joints
from tests.emscon_device import EmsconServer
from tests.tracker_devices import AsciiDevice, IppServer

MODEL = "ur5e"
NOISE = 2e-5  # m per axis per reading, the simulated devices' noise
SAMPLES = 3  # readings per step
STEP_SIGMA = NOISE / np.sqrt(SAMPLES)  # per-axis noise of a recorded step


def _run(rig: SimulatedRig, tracker: Tracker, path: Path, faults: dict[int, Callable[[], None]]):
    """Plan, record and identify a session; ``faults[k]()`` runs after step k (1-based) is recorded."""
    robot_model = load_robot(MODEL)
    site = SiteConfig.default().with_overrides(steps_per_sweep=8, samples_per_step=SAMPLES, free_poses=8)
    plan = build_plan(robot_model, site)
    robot = SimulatedRobot(rig)
    robot.connect(1.0)
    tracker.connect(3.0)

    def on_progress(p: Progress) -> None:
        if p.done in faults:
            faults[p.done]()

    try:
        with Session.create(path, plan, {"robot_spec": f"mock:{MODEL}", "tracker_spec": "test"}, robot.identity(),
                            tracker.identity()) as session:
            result = Orchestrator(robot, tracker, session, rig.clock, Timeouts(measure=5.0), retries=3,
                                  on_progress=on_progress).run()
    finally:
        tracker.close()
        robot.close()
    with Session.open(path) as session:
        steps, meas = session.steps(), session.to_measurements()
        events = session.events()
    return plan, result, steps, meas, events, identify(meas, robot_model.nominal)


def _check_complete(plan, result, steps) -> None:
    assert result.outcome == "complete" and result.missing == 0
    indices = [s.plan_index for s in steps]
    assert sorted(indices) == list(range(len(plan.steps)))  # none lost, none twice
    assert all(s.status == "ok" and s.samples + s.rejected == SAMPLES for s in steps)


def _check_identified(rig: SimulatedRig, meas, ident) -> None:
    """The identified model predicts the true TP within what the device noise allows (Cramér-Rao bound)
    and within what the result says about itself (its covariance, with the noise its residuals imply)."""
    fit_q = meas.q[~meas.check]
    q_check = random_poses(load_robot(MODEL).limits, 200, np.random.default_rng(0))
    err = points_from_joints(ident.model, q_check) - points_from_joints(rig.truth, q_check)
    rms = float(np.sqrt(np.mean(np.sum(err**2, axis=1))))
    bound = prediction_rms_bound(rig.truth, fit_q, q_check, STEP_SIGMA)
    own = float(np.sqrt(np.mean(np.trace(prediction_covariances(ident.model, fit_q, q_check,
                                                                 ident.refinement.noise), axis1=1, axis2=2))))
    assert rms < 3.0 * bound, (rms, bound)
    assert rms < 3.0 * own, (rms, own)
    assert 0.5 * STEP_SIGMA < ident.refinement.noise < 2.0 * STEP_SIGMA  # the residuals agree with the device


@pytest.fixture
def rig() -> SimulatedRig:
    return SimulatedRig(MODEL, clock=VirtualClock(), seed=3)


def test_serial_tracker_session_with_a_device_reset(rig: SimulatedRig, tmp_path: Path) -> None:
    with AsciiDevice("polled-xyz", rig, noise=NOISE, seed=1) as device:
        tracker = open_tracker(f"serial:{device.port}?protocol=polled-xyz&timeout=0.5&retries=2")
        faults = {20: lambda: device.inject("reset"), 35: lambda: device.inject("garbage"),
                  45: lambda: device.inject("target_lost", 3)}
        plan, result, steps, meas, events, ident = _run(rig, tracker, tmp_path / "serial.session", faults)
        resets, inits = tracker.resets, device.commands.count("UNITS MM")
    _check_complete(plan, result, steps)
    assert resets == 1 and inits == 2  # initialised again after the reset, and only then
    assert sum(e[2] == "retry" for e in events) == 1  # target lost 3 times: 1 orchestrator retry
    _check_identified(rig, meas, ident)


def test_ipp_tracker_session_with_a_server_restart(rig: SimulatedRig, tmp_path: Path) -> None:
    with IppServer(rig, noise=NOISE, seed=1) as server:
        tracker = open_tracker(f"ipp://{server.host}:{server.port}?timeout=0.5")
        faults = {20: lambda: server.inject("drop"), 30: lambda: server.inject("warning"),
                  40: lambda: server.inject("error")}
        plan, result, steps, meas, events, ident = _run(rig, tracker, tmp_path / "ipp.session", faults)
        sessions = sum(c.endswith("StartSession()") for c in server.commands)
    _check_complete(plan, result, steps)
    assert tracker.reconnects == 1 and sessions == 2  # the client opened a new session after the restart
    assert not any(e[2] == "retry" for e in events)  # the error was cleared and retried inside the driver
    warned = [r.status for s in steps for r in s.readings if r.status != "ok"]
    assert len(warned) == 1 and "warning 1009" in warned[0]  # the warning is kept in the session file
    # I++ gives no sigma: each step's is the spread of its 3 readings (6 dof: a factor 2 either way; none for a step
    # of 2 kept), and the identification takes the pooled spread instead (identify/io/session_measurements.py)
    recorded = np.array([np.nan if s.sigma is None else s.sigma for s in steps])
    assert np.nanmax(recorded) > 2 * np.nanmin(recorded)
    kept = np.array([s.samples for s in steps], dtype=float)
    assert meas.sigma is not None and len(meas.sigma) == len(steps)
    assert np.all(np.abs(meas.sigma * np.sqrt(kept) / NOISE - 1) < 0.15), meas.sigma  # the device's noise
    _check_identified(rig, meas, ident)


def test_emscon_tracker_session_with_faults(rig: SimulatedRig, tmp_path: Path) -> None:
    with EmsconServer(rig, noise=NOISE, seed=1) as server:
        tracker = open_tracker(f"emscon:{server.host}:{server.port}?timeout=0.3&meas_time=0.001")
        faults = {10: lambda: server.inject("beam_broken", 3), 20: lambda: server.inject("drop"),
                  30: lambda: server.inject("garbage"), 40: lambda: server.inject("silence"),
                  50: lambda: server.inject("warming_up")}
        plan, result, steps, meas, events, ident = _run(rig, tracker, tmp_path / "emscon.session", faults)
        reconnects, connections = tracker.reconnects, server.connections
    _check_complete(plan, result, steps)
    assert reconnects == 3 and connections == 4  # drop, garbage and silence: each read again on a new link
    retries = [e[3] for e in events if e[2] == "retry"]
    assert len(retries) == 4  # the beam broken for 3 attempts of one step (the 4th measures), one warm-up refusal
    assert len({r.partition(",")[0] for r in retries[:3]}) == 1  # "step N, attempt k: ...": one step
    assert all("BeamLost" in r and "10004" in r and "\n" not in r for r in retries[:3])
    assert "TrackerNotReady" in retries[3] and "10012" in retries[3]
    _check_identified(rig, meas, ident)
