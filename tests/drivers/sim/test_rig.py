"""The simulated rig (drivers/sim/): physics, timing, faults."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from config.robots import load_robot
from drivers.base import Robot, RobotState, Tracker
from drivers.clock import VirtualClock, WallClock
from drivers.errors import (
    BadReading,
    ConnectionFailed,
    DeviceTimeout,
    EmergencyStop,
    ProtectiveStop,
    RobotFault,
    SpecError,
    TargetLost,
)
from drivers.motion import move_duration
from drivers.registry import open_robot, open_tracker
from drivers.sim.rig import SimulatedRig
from drivers.sim.robot import SimulatedRobot
from drivers.sim.tracker import SimulatedTracker
from kinematics.dh import points_from_joints
from kinematics.truth import random_truth

T0 = 1000.0  # start of the virtual clock, s
UR5E = load_robot("ur5e")
SPEED, ACC = np.array(UR5E.default_speed), np.array(UR5E.default_acceleration)  # 0.5 rad/s, 1.0 rad/s²


def make(robot: str = "mock:ur5e?seed=1", tracker: str = "mock",
         clock: VirtualClock | WallClock | None = None) -> tuple[SimulatedRig, SimulatedRobot, SimulatedTracker]:
    rig = SimulatedRig.from_spec(robot, tracker, VirtualClock(T0) if clock is None else clock)
    robot_dev, tracker_dev = open_robot(robot, rig=rig), open_tracker(tracker, rig=rig)
    robot_dev.connect(1.0)
    tracker_dev.connect(1.0)
    return rig, robot_dev, tracker_dev  # type: ignore[return-value]


def home() -> np.ndarray:
    return np.array(UR5E.home, dtype=float)


def pose(**moves: float) -> np.ndarray:
    """Home with joint j{i} (1-based) moved by the given rad."""
    q = home()
    for name, delta in moves.items():
        q[int(name[1:]) - 1] += delta
    return q


def test_devices_implement_the_protocols_and_identify_themselves() -> None:
    _, robot, tracker = make("mock:ur5e?seed=7")
    assert isinstance(robot, Robot) and isinstance(tracker, Tracker)
    assert robot.joint_types == "RRRRRR"
    assert robot.identity().model == "simulated ur5e" and robot.identity().serial == "SIM-R7"
    assert robot.identity().kind == "robot"
    assert tracker.identity().model == "simulated tracker" and tracker.identity().serial == "SIM-T7"
    assert tracker.identity().kind == "tracker" and tracker.identity().details["noise"] == "5e-05"


def test_truth_is_the_seeded_random_truth_of_the_nominal_model() -> None:
    rig, _, _ = make("mock:ur5e?seed=4")
    expected = random_truth(UR5E.nominal, home(), np.random.default_rng(4))
    np.testing.assert_array_equal(rig.truth.dh_table(), expected.dh_table())
    np.testing.assert_array_equal(rig.truth.base, expected.base)
    np.testing.assert_array_equal(rig.truth.tool, expected.tool)
    assert np.abs(rig.truth.dh_table() - UR5E.nominal.dh_table()).max() > 1e-5  # perturbed
    other, _, _ = make("mock:ur5e?seed=5")
    assert not np.allclose(other.truth.base, rig.truth.base)


def test_tracker_sees_the_true_tp_within_noise() -> None:
    rig, robot, tracker = make("mock:ur5e?seed=2", "mock?noise=5e-5&latency=0.002")
    target = pose(j1=0.4, j3=-0.3, j6=1.0)
    robot.move_joints(target, SPEED, ACC, timeout=30)
    robot.wait_until_still(0.5, timeout=10)
    q = robot.read_joints()
    t_start = rig.clock.now()
    readings = tracker.measure(200, timeout=5)
    assert rig.clock.now() - t_start == pytest.approx(200 * 0.002)
    points = np.array([r.position for r in readings])
    truth = points_from_joints(rig.truth, q)[0]
    sigma = 5e-5
    assert np.all(np.abs(points.mean(axis=0) - truth) < 4 * sigma / math.sqrt(200))
    assert np.all((0.8 * sigma < points.std(axis=0)) & (points.std(axis=0) < 1.2 * sigma))
    assert all(r.sigma == sigma and r.status == "ok" for r in readings)
    stamps = np.array([r.timestamp for r in readings])
    np.testing.assert_allclose(np.diff(stamps), 0.002)
    assert stamps[0] == pytest.approx(t_start)
    # The truth moves with the robot: another pose gives another point, metres away from the nominal model's.
    assert np.linalg.norm(truth - points_from_joints(rig.truth, home())[0]) > 0.05


def test_move_time_follows_the_trapezoidal_profile_of_the_slowest_joint() -> None:
    rig, robot, _ = make("mock:ur5e?repeatability=0")  # every move starts exactly at the last target
    # Joint 1 by 1 rad at 0.5 rad/s, 1 rad/s²: cruise, 1/0.5 + 0.5/1 = 2.5 s; joint 2 by 0.1 rad is faster.
    t = rig.clock.now()
    robot.move_joints(pose(j1=1.0, j2=0.1), SPEED, ACC, timeout=30)
    assert rig.clock.now() - t == pytest.approx(2.5, abs=1e-9)
    # Joint 6 by 0.1 rad: never reaches 0.5 rad/s (0.1 < 0.5²/1): triangular, 2·sqrt(0.1/1) s.
    t = rig.clock.now()
    robot.move_joints(pose(j1=1.0, j2=0.1, j6=-0.1), SPEED, ACC, timeout=30)
    assert rig.clock.now() - t == pytest.approx(2 * math.sqrt(0.1), abs=1e-9)
    # Faster limits, shorter move: 2 rad at 2 rad/s, 4 rad/s²: 2/2 + 2/4 = 1.5 s.
    t = rig.clock.now()
    robot.move_joints(pose(j1=3.0, j2=0.1, j6=-0.1), SPEED * 4, ACC * 4, timeout=30)
    assert rig.clock.now() - t == pytest.approx(1.5, abs=1e-9)
    assert move_duration([0, 0], [1.0, 0.1], [0.5, 0.5], [1.0, 1.0]) == pytest.approx(2.5)
    assert move_duration([0.0], [0.0], [0.5], [1.0]) == 0.0


def test_readings_ring_after_a_move_and_settle_within_repeatability() -> None:
    rig, robot, _ = make()
    target = pose(j2=0.3, j5=-0.2)
    robot.move_joints(target, SPEED, ACC, timeout=30)
    right_after = robot.read_joints()
    rest = rig.rest_joints
    assert np.abs(right_after - rest).max() > 4e-6  # ringing, amplitude 0.5..1 × 1e-5 rad
    assert np.abs(right_after - target).max() > 1e-6
    t = rig.clock.now()
    robot.wait_until_still(0.5, timeout=5)
    waited = rig.clock.now() - t
    assert 0.5 < waited < 1.5
    settled = robot.read_joints()
    assert np.abs(settled - rest).max() < 1e-6
    error = settled - target  # the repeatability error, N(0, 2e-6) per joint
    assert 0 < np.abs(error).max() < 5 * 2e-6
    # The readings are the actual values: they differ from the command by the repeatability error.
    assert not np.array_equal(settled, target)


def test_without_repeatability_error_the_settled_reading_is_the_command() -> None:
    _, robot, _ = make("mock:ur5e?repeatability=0")
    target = pose(j1=-0.5, j4=0.25)
    robot.move_joints(target, SPEED, ACC, timeout=30)
    assert np.abs(robot.read_joints() - target).max() > 1e-6
    robot.wait_until_still(0.3, timeout=5)
    assert np.abs(robot.read_joints() - target).max() < 1e-6


def test_moves_are_checked_against_limits_and_speeds() -> None:
    scara = load_robot("scara")
    rig, robot, _ = make("mock:scara")
    outside = np.array(scara.home, dtype=float)
    outside[0] = scara.limits[0, 1] + 0.01
    t = rig.clock.now()
    with pytest.raises(ValueError, match=r"joint 1 target .* is outside its limits"):
        robot.move_joints(outside, scara.default_speed, scara.default_acceleration, timeout=30)
    too_fast = np.array(scara.max_speed) * 1.5
    with pytest.raises(ValueError, match="speed"):
        robot.move_joints(scara.home, too_fast, scara.default_acceleration, timeout=30)
    with pytest.raises(ValueError, match="must be 4 finite numbers"):
        robot.move_joints([0.0, 0.0], scara.default_speed, scara.default_acceleration, timeout=30)
    assert rig.clock.now() == t and rig.moves == 0
    np.testing.assert_array_equal(rig.rest_joints, scara.home)


def test_devices_must_be_connected() -> None:
    rig = SimulatedRig.from_spec("mock:ur5e", "mock", VirtualClock(T0))
    robot, tracker = open_robot("mock:ur5e", rig=rig), open_tracker("mock", rig=rig)
    assert robot.state() is RobotState.DISCONNECTED
    with pytest.raises(ConnectionFailed, match="not connected"):
        robot.read_joints()
    with pytest.raises(ConnectionFailed, match="not connected"):
        tracker.measure(1, 1.0)
    robot.connect(1.0)
    assert robot.state() is RobotState.READY
    robot.close()
    assert robot.state() is RobotState.DISCONNECTED


# --- faults ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("fault", "error", "state"), [
    ("protective_stop", ProtectiveStop, RobotState.PROTECTIVE_STOP),
    ("emergency_stop", EmergencyStop, RobotState.EMERGENCY_STOP),
])
def test_stop_faults_latch_until_cleared(fault: str, error: type[Exception], state: RobotState) -> None:
    rig, robot, _ = make(f"mock:ur5e?fault={fault}@2")
    robot.move_joints(pose(j1=0.2), SPEED, ACC, timeout=30)
    assert rig.pending_faults() == [f"robot: {fault}@2"]
    start = robot.read_joints()
    target = pose(j1=1.2)  # 1 rad: 2.5 s, stopped halfway (1.25 s, 0.5 rad)
    t = rig.clock.now()
    with pytest.raises(error, match="during move 2"):
        robot.move_joints(target, SPEED, ACC, timeout=30)
    assert rig.clock.now() - t == pytest.approx(1.25)
    assert robot.state() is state
    assert rig.rest_joints[0] == pytest.approx(start[0] + 0.5, abs=1e-4)
    with pytest.raises(error):
        robot.move_joints(target, SPEED, ACC, timeout=30)
    rig.clear_faults()
    assert robot.state() is RobotState.READY
    robot.move_joints(target, SPEED, ACC, timeout=30)
    robot.wait_until_still(0.5, timeout=5)
    assert np.abs(robot.read_joints() - target).max() < 1e-5
    assert rig.moves == 3  # the rejected call in the stop state is not a move


def test_programmatic_protective_stop() -> None:
    rig, robot, _ = make()
    rig.inject("protective_stop", at_move=3)
    for k in range(2):
        robot.move_joints(pose(j6=0.1 * (k + 1)), SPEED, ACC, timeout=30)
    with pytest.raises(ProtectiveStop):
        robot.move_joints(pose(j6=0.3), SPEED, ACC, timeout=30)
    assert robot.state() is RobotState.PROTECTIVE_STOP
    robot.stop()  # never raises
    robot.wait_until_still(0.2, timeout=5)  # the arm is still, in protective stop
    rig.clear_faults()
    robot.move_joints(pose(j6=0.3), SPEED, ACC, timeout=30)
    assert robot.state() is RobotState.READY


def test_robot_disconnect_until_reconnect() -> None:
    rig, robot, tracker = make("mock:ur5e?fault=disconnect@1")
    before = rig.rest_joints
    with pytest.raises(ConnectionFailed, match="move 1"):
        robot.move_joints(pose(j1=0.5), SPEED, ACC, timeout=30)
    assert robot.state() is RobotState.DISCONNECTED
    np.testing.assert_array_equal(rig.rest_joints, before)  # the command never arrived
    for call in (robot.read_joints, lambda: robot.wait_until_still(0.1, 1.0),
                 lambda: robot.move_joints(pose(j1=0.5), SPEED, ACC, 30)):
        with pytest.raises(ConnectionFailed):
            call()
    robot.stop()
    rig.clear_faults()
    assert robot.state() is RobotState.DISCONNECTED  # a lost link needs connect()
    assert len(tracker.measure(2, 1.0)) == 2  # the tracker still sees the arm
    robot.connect(1.0)
    assert robot.state() is RobotState.READY
    robot.move_joints(pose(j1=0.5), SPEED, ACC, timeout=30)
    assert robot.read_joints()[0] == pytest.approx(0.5, abs=1e-4)


def test_slow_robot_move_times_out_on_the_clock() -> None:
    rig, robot, _ = make("mock:ur5e?fault=slow@1")
    t, wall = rig.clock.now(), time.perf_counter()
    with pytest.raises(DeviceTimeout, match="did not finish within its timeout of 20 s"):
        robot.move_joints(pose(j1=0.5), SPEED, ACC, timeout=20)
    assert rig.clock.now() - t == pytest.approx(20)
    assert time.perf_counter() - wall < 0.5
    np.testing.assert_array_equal(rig.rest_joints, home())  # stuck
    assert robot.state() is RobotState.READY
    robot.move_joints(pose(j1=0.5), SPEED, ACC, timeout=20)  # the next move works


def test_move_longer_than_its_timeout() -> None:
    rig, robot, _ = make()
    t = rig.clock.now()
    with pytest.raises(DeviceTimeout, match=r"needs 2\.500 s, more than its timeout of 1 s"):
        robot.move_joints(pose(j1=1.0), SPEED, ACC, timeout=1.0)
    assert rig.clock.now() - t == pytest.approx(1.0)
    assert 0.1 < rig.rest_joints[0] < 0.5  # stopped on the way (0.375 rad after 1 s)
    assert robot.state() is RobotState.READY


def test_unsettled_arm_makes_wait_until_still_time_out() -> None:
    rig, robot, _ = make("mock:ur5e?fault=unsettled@1")
    robot.move_joints(pose(j2=0.2), SPEED, ACC, timeout=30)
    t = rig.clock.now()
    with pytest.raises(DeviceTimeout, match="did not settle"):
        robot.wait_until_still(0.5, timeout=3.0)
    assert rig.clock.now() - t == pytest.approx(3.0)
    rig.clear_faults()
    robot.wait_until_still(0.5, timeout=3.0)
    assert np.abs(robot.read_joints() - rig.rest_joints).max() < 1e-6


def test_target_lost_for_k_measurements() -> None:
    rig, _, tracker = make("mock:ur5e", "mock?fault=target_lost@2x3")
    assert len(tracker.measure(5, 1.0)) == 5
    for number in (2, 3, 4):
        with pytest.raises(TargetLost, match=f"measurement {number}"):
            tracker.measure(5, 1.0)
    assert len(tracker.measure(5, 1.0)) == 5
    assert rig.measurements == 5


def test_clear_faults_ends_a_running_fault_but_keeps_scheduled_ones() -> None:
    rig, _, tracker = make()
    rig.inject("target_lost", count=10)
    rig.inject("bad_reading", at_measure=5)
    with pytest.raises(TargetLost):
        tracker.measure(1, 1.0)
    rig.clear_faults()
    assert rig.pending_faults() == ["tracker: bad_reading@5"]
    assert len(tracker.measure(1, 1.0)) == 1
    tracker.measure(1, 1.0)
    tracker.measure(1, 1.0)
    with pytest.raises(BadReading, match="garbage at measurement 5"):
        tracker.measure(1, 1.0)
    rig.inject("slow", at_move=9)
    rig.clear_faults(pending=True)
    assert rig.pending_faults() == []


def test_tracker_disconnect_and_slow() -> None:
    rig, _, tracker = make("mock:ur5e", "mock?fault=disconnect@1,slow@2")
    with pytest.raises(ConnectionFailed, match="measurement 1"):
        tracker.measure(1, 1.0)
    with pytest.raises(ConnectionFailed):
        tracker.measure(1, 1.0)  # still down: not counted as a measurement
    tracker.connect(1.0)
    t = rig.clock.now()
    with pytest.raises(DeviceTimeout, match="measurement 2"):
        tracker.measure(3, 0.75)
    assert rig.clock.now() - t == pytest.approx(0.75)
    t = rig.clock.now()
    with pytest.raises(DeviceTimeout):
        tracker.measure(1000, 1.0)  # 1000 × 2 ms > 1 s
    assert rig.clock.now() - t == pytest.approx(1.0)
    assert len(tracker.measure(3, 1.0)) == 3


def test_dropouts_are_seeded_and_at_the_given_rate() -> None:
    def outcomes(seed: int) -> list[bool]:
        _, _, tracker = make(f"mock:ur5e?seed={seed}", "mock?dropout=0.3")
        result = []
        for _ in range(400):
            try:
                tracker.measure(1, 1.0)
                result.append(True)
            except TargetLost:
                result.append(False)
        return result

    first = outcomes(1)
    assert first == outcomes(1)
    assert first != outcomes(2)
    assert 0.22 < 1 - np.mean(first) < 0.38


def test_inject_rejects_bad_requests() -> None:
    rig, robot, _ = make()
    robot.move_joints(pose(j1=0.1), SPEED, ACC, timeout=30)
    with pytest.raises(ValueError, match="robot move 1 has already happened"):
        rig.inject("protective_stop", at_move=1)
    with pytest.raises(ValueError, match="unknown robot fault 'explode'"):
        rig.inject("explode", at_move=5)
    with pytest.raises(ValueError, match="both devices"):
        rig.inject("disconnect")
    with pytest.raises(ValueError, match="count"):
        rig.inject("emergency_stop", count=2)
    with pytest.raises(ValueError, match="unknown robot fault 'target_lost'"):
        rig.inject("target_lost", at_move=4)
    with pytest.raises(ValueError, match="at_move is for the robot"):
        rig.inject("target_lost", at_move=4, device="tracker")
    rig.inject("slow", device="tracker")
    assert rig.pending_faults() == ["tracker: slow@1"]


def test_stop_and_ctrl_c_leave_the_arm_where_it_is() -> None:
    class StoppingClock(VirtualClock):
        robot: SimulatedRobot | None = None

        def sleep(self, seconds: float) -> None:
            super().sleep(seconds)
            if self.robot is not None:
                self.robot.stop()  # as from another thread during the move

    clock = StoppingClock(T0)
    rig, robot, _ = make(clock=clock)
    clock.robot = robot
    with pytest.raises(RobotFault, match="stopped"):
        robot.move_joints(pose(j1=1.0), SPEED, ACC, timeout=30)
    assert robot.state() is RobotState.READY
    assert 0 < rig.rest_joints[0] < 0.01  # 50 ms into the move
    clock.robot = None
    for later in (clock.now(), clock.now() + 1.0):  # a time given, as the UR emulator's reader gives it: not the
        assert 0 < rig.actual_joints(later)[0] < 0.01  # planned profile's (it stopped there)

    class InterruptedClock(VirtualClock):
        armed = False

        def sleep(self, seconds: float) -> None:
            super().sleep(seconds)
            if self.armed:
                raise KeyboardInterrupt

    clock2 = InterruptedClock(T0)
    rig2, robot2, _ = make(clock=clock2)
    clock2.armed = True
    with pytest.raises(KeyboardInterrupt):
        robot2.move_joints(pose(j1=1.0), SPEED, ACC, timeout=30)
    clock2.armed = False
    assert robot2.state() is RobotState.READY
    assert 0 < rig2.rest_joints[0] < 0.01


def test_open_checks_the_spec_against_the_rig() -> None:
    rig = SimulatedRig.from_spec("mock:ur5e?seed=3", "mock?noise=1e-4")
    with pytest.raises(ValueError, match="disagrees with the simulated rig on seed"):
        open_robot("mock:ur5e", rig=rig)
    with pytest.raises(ValueError, match="names model 'ur10'"):
        open_robot("mock:ur10?seed=3", rig=rig)
    with pytest.raises(ValueError, match="disagrees with the simulated rig on noise"):
        open_tracker("mock", rig=rig)
    with pytest.raises(ValueError, match="needs the simulated robot"):
        open_tracker("mock?noise=1e-4")
    with pytest.raises(SpecError, match="needs mock devices"):
        SimulatedRig.from_spec("ur5e@10.0.0.1", "mock")
    with pytest.raises(SpecError, match="needs mock devices"):
        SimulatedRig.from_spec("mock:ur5e", "serial:/dev/ttyUSB0")
    with pytest.raises(SpecError, match=r"'mock:ur55'.*bundled robot name"):
        SimulatedRig.from_spec("mock:ur55", "mock")
    alone = open_robot("mock:scara?seed=2")  # a private rig with a virtual clock
    assert isinstance(alone.rig.clock, VirtualClock) and alone.joint_types == "RRPR"


def test_two_hundred_moves_on_the_virtual_clock_do_not_wait() -> None:
    """The virtual clock advances without sleeping: 200 moves, settles and measurements (over 100 s of robot time)
    take a small share of that in wall time, however loaded the host."""
    rig, robot, tracker = make()
    t_virtual, t_wall = rig.clock.now(), time.perf_counter()
    for k in range(200):
        robot.move_joints(pose(j6=0.2 * (k % 10), j2=0.05 * (k % 3)), SPEED, ACC, timeout=30)
        robot.wait_until_still(0.5, timeout=5)
        assert len(tracker.measure(5, 1.0)) == 5
    virtual = rig.clock.now() - t_virtual
    assert virtual > 200 * 0.5  # at least the settle times passed on the virtual clock
    assert time.perf_counter() - t_wall < 0.02 * virtual  # idle: under 0.3 s; a clock that slept: all of it


def test_wall_clock_plays_at_real_speed() -> None:
    _, robot, tracker = make(clock=WallClock())
    t = time.perf_counter()
    robot.move_joints(pose(j6=0.004), SPEED, ACC, timeout=5)  # triangular: 2·sqrt(0.004) = 0.126 s
    assert 0.12 < time.perf_counter() - t < 1.0
    assert len(tracker.measure(3, 1.0)) == 3


def test_rig_swaps_the_arm_and_moves_the_tracker() -> None:
    """arm=N: another DH table of the model, at the same placement with the same TP; moved/turned: the tracker
    sees every point through the rigid move (rotation vector in degrees, then the shift), nothing else changes."""
    from scipy.spatial.transform import Rotation

    first = SimulatedRig.from_spec("mock:ur5e", "mock").truth
    other = SimulatedRig.from_spec("mock:ur5e?arm=7", "mock").truth
    np.testing.assert_array_equal(other.base, first.base)
    np.testing.assert_array_equal(other.tool, first.tool)
    assert np.max(np.abs(other.a - first.a)) > 1e-4  # another arm: its lengths differ by a tenth of a mm or more
    moved = SimulatedRig.from_spec("mock:ur5e", "mock?moved=1.2,-1.5,0.4&turned=100,0,-40")
    move = np.eye(4)
    move[:3, :3] = Rotation.from_rotvec(np.radians([100.0, 0.0, -40.0])).as_matrix()
    move[:3, 3] = [1.2, -1.5, 0.4]
    np.testing.assert_allclose(moved.truth.base, move @ first.base, atol=1e-15)
    np.testing.assert_array_equal(moved.truth.a, first.a)
    with pytest.raises(ValueError, match="disagrees with the simulated rig on moved, turned"):
        open_tracker("mock", rig=moved)


def test_backlash_leaves_a_joint_behind_its_target_in_the_direction_of_the_move() -> None:
    """``backlash=B``: the readings reach the command, the joint rests B/2 short of it, behind in the direction it
    came from; the same command reached from the other side lands B further on (where vAP comes from)."""
    lash = 2e-3
    rig, robot, _ = make(f"mock:ur5e?repeatability=0&ring=0&backlash={lash}")
    assert np.array_equal(rig.true_joints(), rig.readings_of(home()))  # not moved yet: no lost motion
    target = pose(j2=0.1)
    robot.move_joints(pose(j2=0.3), SPEED, ACC, timeout=30)
    robot.move_joints(target, SPEED, ACC, timeout=30)  # joint 2 comes down to the target; the others stay
    robot.wait_until_still(0.3, timeout=5)
    from_above = rig.true_joints() - target
    assert np.abs(robot.read_joints() - target).max() < 1e-9
    np.testing.assert_allclose(from_above, [0, lash / 2, 0, 0, 0, 0], atol=1e-9)
    robot.move_joints(pose(j2=-0.1), SPEED, ACC, timeout=30)
    robot.move_joints(target, SPEED, ACC, timeout=30)  # up to the same target
    robot.wait_until_still(0.3, timeout=5)
    np.testing.assert_allclose(rig.true_joints() - target, [0, -lash / 2, 0, 0, 0, 0], atol=1e-9)
    # a reversal shorter than the gap (a quarter of it, back down) leaves the joint where it was: the motor only
    # crosses the gap
    robot.move_joints(target - np.array([0, lash / 4, 0, 0, 0, 0]), SPEED, ACC, timeout=30)
    robot.wait_until_still(0.3, timeout=5)
    np.testing.assert_allclose(rig.true_joints() - target, [0, -lash / 2, 0, 0, 0, 0], atol=1e-9)
