"""Motion rehearsal (``acquire --tracker none``): the whole plan at a reduced speed, nothing measured or recorded;
against the UR controller emulator with the real ur_rtde client (as tests/acquire/test_ur_session.py), and on the
simulated robot."""

from __future__ import annotations

import numpy as np
import pytest

from acquire.commands.cli import main as acquire
from acquire.planning.plan import build_plan
from config.robots import load_robot
from config.site import load_site
from drivers.motion import motion_time

SCALE = 100.0  # emulated seconds per wall second
SITE = """schema: 1
plan: {settle_time: 0.02, steps_per_sweep: 4, free_poses: 3, check_poses: 1, home_check_every: 10}
timeouts: {connect: 10.0, move: 60.0, settle: 10.0, measure: 5.0}
"""


def _plan(site_path, fraction: float):
    site = load_site(site_path).with_overrides(speed_fraction=fraction, acceleration_fraction=fraction)
    return build_plan(load_robot("ur5e"), site)


@pytest.mark.slow
def test_rehearsal_against_the_emulator_moves_through_the_plan_at_a_quarter_speed(tmp_path, monkeypatch,
                                                                                   capsys) -> None:
    pytest.importorskip("rtde_control", reason="ur_rtde is not installed (pip install 'ur-rtde==1.6.5', the ur extra)")
    from tests.ur_emulator import CMD_MOVEJ, EmulatorProcess

    monkeypatch.chdir(tmp_path)
    site = tmp_path / "site.yaml"
    site.write_text(SITE)
    with EmulatorProcess(time_scale=SCALE) as emu:
        code = acquire(["--robot", f"ur5e@{emu.host}", "--tracker", "none", "--yes", "--config", str(site),
                        "--quiet"])
        out, err = capsys.readouterr()
        assert code == 0, err
        moves = emu.get("log").commands.count(CMD_MOVEJ)
        _, duration = emu.last_motion()
        replies = emu.tracker_replies()
        final = np.asarray(emu.actual_q())
    robot = load_robot("ur5e")
    plan = _plan(site, 0.25)
    assert moves == len(plan.steps)  # every step, one moveJ each
    np.testing.assert_allclose(final, plan.steps[-1].q, atol=1e-3)
    # the last move at a quarter of the default speed and acceleration (moveJ leads with the smallest of the
    # per-joint values): its duration on the emulator's clock is the trapezoid of that speed and acceleration
    # (d / v + v / a: here 3.7x the full-speed one)
    distance = np.abs(np.subtract(plan.steps[-1].q, plan.steps[-2].q))
    speed, acceleration = 0.25 * robot.default_speed.min(), 0.25 * robot.default_acceleration.min()
    assert duration == pytest.approx(motion_time(distance, speed, acceleration).max(), rel=1e-6)
    assert duration > 3 * motion_time(distance, 4 * speed, 4 * acceleration).max()
    assert replies == 0 and not list(tmp_path.rglob("*.session")) and not (tmp_path / "sessions").exists()
    assert f"rehearsal complete: {len(plan.steps)} steps reached, nothing measured or recorded" in out
    assert "clearance: closest approach" in out and "predicted accuracy" not in out


def test_rehearsal_on_the_simulated_robot_and_its_speed_fraction(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    site = tmp_path / "site.yaml"
    site.write_text(SITE)
    args = ["--robot", "mock:ur5e", "--tracker", "none", "--config", str(site)]
    assert acquire([*args, "--speed-fraction", "0.5"]) == 0
    out = capsys.readouterr().out
    assert "speed: 14.3°/s" in out  # half the UR5e's default 0.5 rad/s
    assert acquire(args) == 0
    out = capsys.readouterr().out
    assert "speed: 7.2°/s" in out and "rehearsal complete" in out and not (tmp_path / "sessions").exists()
    assert acquire([*args, "--speed-fraction", "1.5"]) == 2
    assert "--speed-fraction must be in (0, 1], got 1.5" in capsys.readouterr().err


def test_ctrl_c_stops_a_rehearsal_and_a_fault_fails_it() -> None:
    """The rehearsal loop: Ctrl-C (the stop request) stops the arm and ends the run as aborted; a robot fault
    stops it and ends it as failed; nothing else happens between moves."""
    from acquire.running.orchestrator import StopRequest
    from acquire.running.rehearsal import rehearse
    from drivers.base import RobotState
    from drivers.errors import ProtectiveStop

    plan = build_plan(load_robot("ur5e"), load_site_text(SITE))

    class Arm:
        def __init__(self, fault_at: int | None = None) -> None:
            self.moves, self.stops, self.fault_at = [], 0, fault_at

        def state(self):
            return RobotState.READY

        def move_joints(self, q, speed, acceleration, timeout):
            if len(self.moves) == self.fault_at:
                raise ProtectiveStop("protective stop")
            self.moves.append((tuple(q), tuple(speed), timeout))

        def stop(self):
            self.stops += 1

    arm, stop = Arm(), StopRequest()
    result = rehearse(arm, plan, 60.0, stop, lambda step, done, total: stop.request() if done == 5 else None)
    assert (result.outcome, result.recorded, len(arm.moves), arm.stops) == ("aborted", 5, 5, 1)
    assert all(m == (s.q, plan.speed, 60.0) for m, s in zip(arm.moves, plan.steps, strict=False))
    arm = Arm(fault_at=7)
    result = rehearse(arm, plan, 60.0, StopRequest())
    assert (result.outcome, result.recorded, arm.stops) == ("failed", 7, 1) and "protective stop" in result.reason


def load_site_text(text: str):
    import yaml

    from config.site import site_from_dict

    return site_from_dict(yaml.safe_load(text), "test")
