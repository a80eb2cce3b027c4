"""The UR driver's link to the controller: ur_rtde runs in a worker process, so a crashed or hung worker, a
dropped or frozen connection and Ctrl-C are handled in the acquisition process (tests/ur_emulator)."""

from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest

pytest.importorskip("rtde_control", reason="ur_rtde is not installed (pip install 'ur-rtde==1.6.5', the ur extra)")

from acquire.running.orchestrator import StopRequest
from config.robots import load_robot
from drivers.errors import ConnectionFailed, RobotFault
from drivers.sim.rig import SimulatedRig
from drivers.spec import parse_faults
from tests.ur_emulator import CMD_STOPJ, EmulatorProcess, ScaledClock
from tests.ur_emulator import connected_robot as connected

HOME = np.array(load_robot("ur5e").home, dtype=float)
SPEED, ACC = [0.8] * 6, [1.5] * 6
SCALE = 10.0
STEP = np.array([0.2, 0, 0, 0, 0, 0])


@pytest.fixture
def emulator():
    with EmulatorProcess(time_scale=SCALE) as emu:
        yield emu


def test_a_killed_worker_is_replaced_and_the_run_goes_on(emulator: EmulatorProcess) -> None:
    robot = connected(emulator)
    try:
        first = robot._worker.pid
        os.kill(first, signal.SIGKILL)  # what a segfault in ur_rtde does to the worker
        np.testing.assert_allclose(robot.read_joints(), HOME, atol=1e-4)
        assert robot.reconnections == 1 and robot._worker.pid != first
        robot.move_joints(HOME + STEP, SPEED, ACC, timeout=10.0)
        np.testing.assert_allclose(robot.read_joints(), HOME + STEP, atol=1e-3)
    finally:
        robot.close()


def test_a_hung_worker_is_killed_and_replaced(emulator: EmulatorProcess) -> None:
    robot = connected(emulator)
    robot.call_timeout = 0.5  # s; a request normally takes well under a millisecond
    try:
        hung = robot._worker.pid
        os.kill(hung, signal.SIGSTOP)
        np.testing.assert_allclose(robot.read_joints(), HOME, atol=1e-4)
        assert robot.reconnections == 1
        with pytest.raises(ProcessLookupError):  # the hung worker was killed, not left behind
            for _ in range(100):
                os.kill(hung, 0)
                time.sleep(0.01)
    finally:
        robot.close()


def test_dropped_connections_mid_move_are_reconnected_and_the_move_completes() -> None:
    """The controller's network drops at move 2 (before it starts); the driver reconnects with a fresh worker
    and commands the same target again."""
    rig = SimulatedRig("ur5e", clock=ScaledClock(SCALE), robot_faults=parse_faults("disconnect@2", "robot"))
    with EmulatorProcess(rig=rig) as emu:
        robot = connected(emu)
        try:
            robot.move_joints(HOME + STEP, SPEED, ACC, timeout=10.0)
            robot.move_joints(HOME + 2 * STEP, SPEED, ACC, timeout=10.0)
            np.testing.assert_allclose(robot.read_joints(), HOME + 2 * STEP, atol=1e-3)
            assert robot.reconnections >= 1
        finally:
            robot.close()


def test_connection_drop_while_idle_recovers(emulator: EmulatorProcess) -> None:
    """ur_rtde 1.6.5's own reconnect thread can crash its process after a drop: here it is the worker's."""
    robot = connected(emulator)
    try:
        emulator.drop_connections()
        robot.move_joints(HOME + STEP, SPEED, ACC, timeout=10.0)
        np.testing.assert_allclose(robot.read_joints(), HOME + STEP, atol=1e-3)
    finally:
        robot.close()


def test_a_controller_gone_for_good_ends_in_connection_failed() -> None:
    emu = EmulatorProcess(time_scale=SCALE)
    robot = connected(emu, options="reconnects=2")
    try:
        emu.close()  # the controller is switched off
        with pytest.raises(ConnectionFailed, match="2 reconnection attempt") as info:
            robot.read_joints()
        assert "\n" not in str(info.value)
        with pytest.raises(ConnectionFailed, match="not connected"):
            robot.move_joints(HOME, SPEED, ACC, timeout=5.0)
    finally:
        robot.close()


def test_a_frozen_state_stream_is_a_lost_link(emulator: EmulatorProcess) -> None:
    robot = connected(emulator, options="stream_timeout=0.3&reconnects=0")  # a fresh worker would wait for the stream
    try:
        robot.wait_until_still(0.05, 5.0)
        emulator.freeze_stream()  # links up, packages keep coming, the timestamp stands still
        with pytest.raises(ConnectionFailed, match="state stream") as info:
            robot.wait_until_still(10.0, 20.0)  # would take 10 s with a live stream
        assert "0 reconnection attempt" in str(info.value) and "\n" not in str(info.value)
        emulator.freeze_stream(False)
        robot.connect(5.0)  # the operator resumes once the controller streams again
        robot.move_joints(HOME + STEP, SPEED, ACC, timeout=10.0)
        np.testing.assert_allclose(robot.read_joints(), HOME + STEP, atol=1e-3)
    finally:
        robot.close()


def test_ctrl_c_stops_the_arm_through_the_worker(emulator: EmulatorProcess) -> None:
    """Ctrl-C reaches the driver's process and its worker (one process group); the worker ignores it, the
    orchestrator's handler calls stop(), and stopJ reaches the controller."""
    robot = connected(emulator)
    stop = StopRequest()
    stop.on_request = robot.stop
    worker = robot._worker.pid

    def ctrl_c() -> None:
        deadline = time.monotonic() + 30.0
        while abs(emulator.actual_q()[0] - HOME[0]) < 0.05 and time.monotonic() < deadline:
            time.sleep(0.005)
        os.kill(worker, signal.SIGINT)
        os.kill(os.getpid(), signal.SIGINT)

    try:
        threading.Thread(target=ctrl_c, daemon=True).start()
        with stop.installed(), pytest.raises(RobotFault, match="stopped"):
            robot.move_joints(HOME + np.array([3.0, 0, 0, 0, 0, 0]), [0.3] * 6, [1.0] * 6, timeout=60.0)
        assert stop.requested
        assert CMD_STOPJ in emulator.get("log").commands
        assert robot._worker.pid == worker and robot.reconnections == 0  # the worker survived Ctrl-C
        robot.wait_until_still(0.05, 5.0)
        assert HOME[0] + 0.01 < robot.read_joints()[0] < HOME[0] + 2.0  # stopped on the way
    finally:
        robot.close()
