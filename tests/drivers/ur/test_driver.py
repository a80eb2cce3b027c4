"""The UR driver (drivers/ur/driver.py) with the real ur_rtde client against the controller emulator
(tests/ur_emulator/).

Each test gets its own emulator process on its own loopback address (the UR ports are fixed).
"""

from __future__ import annotations

import importlib.metadata
import json
import sys
import threading
import time

import numpy as np
import pytest

pytest.importorskip("rtde_control", reason="ur_rtde is not installed (pip install 'ur-rtde==1.6.5', the ur extra)")
pytest.importorskip("rtde_receive", reason="ur_rtde is not installed (pip install 'ur-rtde==1.6.5', the ur extra)")

from config.robots import load_robot
from drivers.base import Robot, RobotState
from drivers.errors import (
    BackendUnavailable,
    ConnectionFailed,
    DeviceTimeout,
    EmergencyStop,
    ProtectiveStop,
    RobotFault,
    SpecError,
)
from drivers.motion import leading_joint_limits, motion_time
from drivers.registry import open_robot
from drivers.sim.rig import SimulatedRig
from drivers.spec import parse_faults
from tests.ur_emulator import CMD_MOVEJ, CMD_STOPJ, EmulatorProcess, ScaledClock, free_loopback_address
from tests.ur_emulator import connected_robot as connected

PINNED_UR_RTDE = "1.6.5"  # the version whose handshake the emulator follows
HOME = np.array(load_robot("ur5e").home, dtype=float)
SPEED, ACC = [0.8] * 6, [1.5] * 6
SCALE = 10.0  # emulated time runs this much faster than the wall clock
LONG = HOME + np.array([3.0, 0, 0, 0, 0, 0])  # a move of about 10 emulated s at 0.3 rad/s: cut short by the tests
SLOW, SLOW_ACC = [0.3] * 6, [1.0] * 6


@pytest.fixture
def emulator():
    with EmulatorProcess(time_scale=SCALE) as emu:
        yield emu


def wait_for(condition, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "condition not reached"
        time.sleep(0.005)


def once_moving(emu: EmulatorProcess, action, start: float = HOME[0], by: float = 0.05) -> threading.Thread:
    """Run ``action`` in a thread as soon as the emulated joint 1 has moved ``by`` rad from ``start``: a fault
    injected mid-move at a position, not after a wall-clock delay, so a loaded machine cannot shift it."""
    def run() -> None:
        wait_for(lambda: abs(emu.actual_q()[0] - start) > by, timeout=30.0)
        action()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def test_pinned_ur_rtde_version_and_handshake(emulator: EmulatorProcess) -> None:
    """Fails loudly when ur_rtde changes: a new version needs the emulator's handshake checked again."""
    assert importlib.metadata.version("ur_rtde") == PINNED_UR_RTDE
    robot = connected(emulator)
    try:
        robot.move_joints(HOME + np.array([0.05, 0, 0, 0, 0, 0]), SPEED, ACC, timeout=10.0)
        robot.stop()
    finally:
        robot.close()
    log = emulator.get("log")
    assert log.unknown_variables == []
    assert any("def rtde_control" in script for script in log.scripts)
    assert log.commands[:2] == [CMD_MOVEJ, CMD_STOPJ]
    assert "PolyscopeVersion" in log.dashboard and "get robot model" in log.dashboard


def test_connect_move_read_settle_stop(emulator: EmulatorProcess) -> None:
    robot = connected(emulator)
    try:
        assert isinstance(robot, Robot) and robot.joint_types == "RRRRRR"
        identity = robot.identity()
        assert identity.model == "ur5e" and identity.serial and identity.firmware.startswith("5.")
        assert robot.state() is RobotState.READY
        np.testing.assert_allclose(robot.read_joints(), HOME, atol=1e-4)
        target = HOME + np.array([0.3, -0.1, 0.1, 0.0, 0.2, -0.2])
        robot.move_joints(target, SPEED, ACC, timeout=10.0)
        robot.wait_until_still(0.05, 5.0)
        np.testing.assert_allclose(robot.read_joints(), target, atol=1e-3)
        np.testing.assert_allclose(robot.read_joints(), emulator.actual_q(), atol=1e-4)  # the encoder values
        assert robot.state() is RobotState.READY
        robot.move_joints(HOME, SPEED, ACC, timeout=10.0)
        np.testing.assert_allclose(robot.read_joints(), HOME, atol=1e-3)
        # one joint moving: at its own speed, not at the slowest joint's (the controller's move duration says)
        robot.move_joints(HOME + np.array([0.4, 0, 0, 0, 0, 0]), [0.8] + [0.2] * 5, ACC, timeout=10.0)
        assert emulator.last_motion()[1] == pytest.approx(float(motion_time(0.4, 0.8, ACC[0])), rel=1e-6)
        robot.stop()  # nothing moving: harmless, never raises
    finally:
        robot.close()
    assert robot.state() is RobotState.DISCONNECTED
    assert robot.reconnections == 0


def test_factory_calibration_is_read_and_recorded(emulator: EmulatorProcess) -> None:
    robot = connected(emulator)
    robot.close()
    calibration = robot.factory_calibration
    assert calibration is not None and set(calibration) >= {"theta", "a", "d", "alpha"}
    truth = emulator.truth()
    for key in ("theta", "a", "d", "alpha"):  # the emulated controller's calibration is its true robot
        np.testing.assert_allclose(calibration[key], getattr(truth, key), rtol=0, atol=1e-12)
    assert json.loads(robot.identity().details["factory_calibration"]) == calibration


def test_robot_without_calibration_still_works() -> None:
    with EmulatorProcess(kinematics=False, time_scale=SCALE) as emu:
        robot = connected(emu)
        try:
            assert robot.factory_calibration is None
            assert robot.identity().details["factory_calibration"].startswith("unavailable (the controller sends no")
            robot.move_joints(HOME + np.array([0.05, 0, 0, 0, 0, 0]), SPEED, ACC, timeout=10.0)
        finally:
            robot.close()


def test_stop_cuts_a_move_short(emulator: EmulatorProcess) -> None:
    robot = connected(emulator)
    try:
        once_moving(emulator, robot.stop)
        with pytest.raises(RobotFault, match="stopped"):
            robot.move_joints(LONG, SLOW, SLOW_ACC, timeout=60.0)
        robot.wait_until_still(0.05, 5.0)
        q = robot.read_joints()
        assert HOME[0] + 0.01 < q[0] < LONG[0] - 1.0  # stopped on the way
        assert CMD_STOPJ in emulator.get("log").commands
        robot.move_joints(HOME, SPEED, ACC, timeout=10.0)  # the next move works
        np.testing.assert_allclose(robot.read_joints(), HOME, atol=1e-3)
    finally:
        robot.close()


def test_protective_stop_mid_move_then_resume(emulator: EmulatorProcess) -> None:
    robot = connected(emulator)
    try:
        once_moving(emulator, emulator.protective_stop)
        with pytest.raises(ProtectiveStop, match="teach pendant") as info:
            robot.move_joints(LONG, SLOW, SLOW_ACC, timeout=60.0)
        assert "\n" not in str(info.value)
        assert robot.state() is RobotState.PROTECTIVE_STOP
        with pytest.raises(ProtectiveStop):
            robot.move_joints(HOME, SPEED, ACC, timeout=10.0)
        emulator.clear_stop()  # the operator unlocks it on the pendant
        wait_for(lambda: robot.state() is RobotState.READY)
        robot.move_joints(HOME, SPEED, ACC, timeout=10.0)  # the control script is uploaded again
        np.testing.assert_allclose(robot.read_joints(), HOME, atol=1e-3)
    finally:
        robot.close()


def test_rig_scheduled_protective_stop_stops_the_move_halfway() -> None:
    rig = SimulatedRig("ur5e", clock=ScaledClock(SCALE), robot_faults=parse_faults("protective_stop@2", "robot"))
    with EmulatorProcess(rig=rig) as emu:
        robot = connected(emu)
        try:
            step = np.array([0.2, 0, 0, 0, 0, 0])
            robot.move_joints(HOME + step, SPEED, ACC, timeout=10.0)
            with pytest.raises(ProtectiveStop):
                robot.move_joints(HOME + 2 * step, SPEED, ACC, timeout=10.0)
            np.testing.assert_allclose(robot.read_joints(), HOME + 1.5 * step, atol=1e-3)  # stopped halfway
        finally:
            robot.close()


def test_emergency_stop(emulator: EmulatorProcess) -> None:
    robot = connected(emulator)
    try:
        once_moving(emulator, emulator.emergency_stop)
        with pytest.raises(EmergencyStop, match="emergency-stop button"):
            robot.move_joints(LONG, SLOW, SLOW_ACC, timeout=60.0)
        assert robot.state() is RobotState.EMERGENCY_STOP
    finally:
        robot.close()


def test_a_move_that_never_finishes_times_out_and_stops() -> None:
    with EmulatorProcess(stall=True, time_scale=SCALE) as emu:
        robot = connected(emu)
        try:
            with pytest.raises(DeviceTimeout, match="stopped"):
                robot.move_joints(HOME + np.array([0.2, 0, 0, 0, 0, 0]), SPEED, ACC, timeout=0.5)
        finally:
            robot.close()
        assert CMD_STOPJ in emu.get("log").commands


def test_unreachable_host_fails_with_one_line() -> None:
    robot = open_robot(f"ur5e@{free_loopback_address()}")  # nobody listens there
    with pytest.raises(ConnectionFailed, match="cannot reach") as info:
        robot.connect(10.0)
    assert "\n" not in str(info.value)


def test_model_mismatch_is_refused() -> None:
    with EmulatorProcess(model="ur10e") as emu:
        robot = open_robot(f"ur5e@{emu.host}")
        with pytest.raises(ConnectionFailed, match=r"UR10.*ur5e"):
            robot.connect(5.0)
        robot = open_robot(f"ur10e@{emu.host}")
        robot.connect(5.0)
        robot.close()


def test_cb3_controller_is_told_apart_from_e_series() -> None:
    with EmulatorProcess(model="ur5", version=(3, 15, 7, 106331), time_scale=SCALE) as emu:
        with pytest.raises(ConnectionFailed, match=r"UR5 \(CB3\).*ur5e"):
            open_robot(f"ur5e@{emu.host}").connect(5.0)
        robot = connected(emu, "ur5")
        try:
            assert robot.identity().firmware.startswith("3.15")
            target = robot.read_joints() + np.array([0.1, 0, 0, 0, 0, 0])
            robot.move_joints(target, SPEED, ACC, timeout=10.0)
            np.testing.assert_allclose(robot.read_joints(), target, atol=1e-3)
        finally:
            robot.close()


def test_controller_not_in_remote_control_is_refused() -> None:
    with EmulatorProcess(remote_control=False) as emu, pytest.raises(ConnectionFailed, match="Remote Control"):
        open_robot(f"ur5e@{emu.host}").connect(5.0)


def test_move_j_gets_the_leading_joints_speed_within_every_joints_own() -> None:
    """UR's moveJ takes one speed (the leading joint's): a move of one joint runs at that joint's speed whatever the
    others' (a continuous sweep); in a move of several, none exceeds its own."""
    home = np.zeros(6)
    one = home + np.array([0, 0, 0, 0, 0, 2.0])
    assert leading_joint_limits(home, one, [0.5] * 5 + [1.0], [1.0] * 5 + [2.0]) == (1.0, 2.0)
    two = home + np.array([1.0, 0.5, 0, 0, 0, 0])  # joint 1 leads; joint 2 goes half as fast
    v, a = leading_joint_limits(home, two, [0.8, 0.3, 1, 1, 1, 1], [2.0, 0.6, 1, 1, 1, 1])
    assert (v, a) == pytest.approx((0.6, 1.2))  # joint 2 at its own 0.3 rad/s and 0.6 rad/s²
    assert leading_joint_limits(home, home, [0.8, 0.3, 1, 1, 1, 1], [2.0] * 6) == (0.3, 2.0)  # nothing moves


def test_spec_checks() -> None:
    with pytest.raises(SpecError, match="unknown option"):
        open_robot("ur5e@127.0.0.1?speed=3")
    with pytest.raises(SpecError, match="no address"):
        open_robot("ur5e")
    with pytest.raises(SpecError, match="port"):
        open_robot("ur5e@127.0.0.1:30004")
    with pytest.raises(SpecError, match="stream_timeout"):
        open_robot("ur5e@127.0.0.1?stream_timeout=-1")
    robot = open_robot("ur5e@127.0.0.1?max_speed=0.5")
    with pytest.raises(ValueError, match="max_speed"):
        robot.move_joints(HOME, [0.8] * 6, ACC, timeout=1.0)
    with pytest.raises(ConnectionFailed, match="not connected"):
        robot.read_joints()


def test_missing_ur_rtde_says_how_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "rtde_control", None)  # import fails
    with pytest.raises(BackendUnavailable, match=r"pip install 'ur-rtde==1.6.5' \(the ur extra\)"):
        open_robot("ur5e@127.0.0.1")
