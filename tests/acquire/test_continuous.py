"""Continuous-motion acquisition on the simulated rig: the plan, the stream loop, the session's stream tables, faults
mid-sweep, crash and resume, the export and the command line (real SQLite files, real CLI runs)."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest

from acquire.commands.cli import main
from acquire.planning.plan import build_plan, check_plan, plan_clearance, tp_model
from acquire.planning.plan_continuous import (
    STREAM_SPEED_CAP,
    build_continuous_plan,
    deflection_limits,
    estimate_continuous_duration,
    stream_speed,
)
from acquire.planning.plan_modes import build_both_plan
from acquire.running.orchestrator import Orchestrator, StopRequest, Timeouts
from acquire.running.session import Session
from acquire.running.stream_loop import COMMIT_PERIOD
from config.cell import cell_from_config
from config.robots import load_robot
from config.site import SiteConfig
from drivers.base import DeviceIdentity
from drivers.clock import VirtualClock
from drivers.errors import DeviceTimeout
from drivers.motion import motion_time
from drivers.sim.rig import SimulatedRig
from drivers.sim.robot import open_robot
from drivers.sim.tracker import open_tracker
from identify.io.csvio import read_measurements
from kinematics.collision import moves_samples
from kinematics.dh import points_from_joints
from session.plan import Plan

UR5E = load_robot("ur5e")
#: a small continuous plan: two wrist sweeps, two check poses, no fitted free poses
SMALL = SiteConfig.default().with_overrides(sweep_joints=(6, 5), free_poses=0, check_poses=2)


def _session(tmp_path: Path, robot: str, tracker: str, site: SiteConfig = SMALL, name: str = "c.session"):
    plan = build_continuous_plan(UR5E, site)
    rig = SimulatedRig.from_spec(robot, tracker, VirtualClock())
    arm, sensor = open_robot(robot, rig=rig), open_tracker(tracker, rig=rig)
    arm.connect(1.0)
    sensor.connect(1.0)
    session = Session.create(tmp_path / name, plan, {"robot_spec": robot, "tracker_spec": tracker,
                                                     "site": site.as_dict()},
                             DeviceIdentity("robot", "sim"), DeviceIdentity("tracker", "sim"))
    return session, arm, sensor, rig


def _run(session: Session, arm, sensor, rig) -> object:
    return Orchestrator(arm, sensor, session, rig.clock, Timeouts(60.0, 10.0, 10.0)).run()


# --- the plan ------------------------------------------------------------------------------------------------


def test_continuous_plan_is_checked_and_respects_its_speed_caps() -> None:
    site = SiteConfig.default().with_overrides(free_poses=0, stream_speed=0.7)
    plan = build_continuous_plan(UR5E, site)
    streams = [s for s in plan.steps if s.kind == "stream"]
    assert sorted(s.joint for s in streams) == [1, 2, 3, 4, 5, 6]  # each joint once, in the order of least travel
    assert check_plan(plan, UR5E) == []
    model = tp_model(UR5E, site.tp_guess)
    for s in streams:
        cap = min(0.7, STREAM_SPEED_CAP, UR5E.max_speed[s.joint - 1], deflection_limits(UR5E, model, s.joint,
                                                                                         site.tracker_noise)[0])
        assert 0 < s.speed <= cap + 1e-12
        assert s.acceleration <= UR5E.default_acceleration[s.joint - 1] + 1e-12
        moved = [k for k in range(6) if abs(s.q[k] - s.start[k]) > 1e-12]
        assert moved == [s.joint - 1]  # one joint, from its start to its end
        prev = plan.steps[s.index - 1]
        assert prev.kind == "free" and prev.q == s.start  # a stop-and-go pose at the range start
    # the ranges are the stop-and-go plan's (limits and the cell's clipping)
    step_plan = build_plan(UR5E, site)
    for s in streams:
        values = [t.q[s.joint - 1] for t in step_plan.steps if t.kind == "sweep" and t.joint == s.joint]
        lo, hi = sorted((s.start[s.joint - 1], s.q[s.joint - 1]))  # either way: from the end nearer the arm
        assert min(values) - 1e-9 <= lo < hi <= max(values) + 1e-9
    # every move, the streamed ones included, is checked at fine interpolation and clear
    clearance = plan_clearance(plan, UR5E, site)
    assert clearance is not None and clearance.slack >= clearance.guard
    cell = cell_from_config(UR5E, site)
    s = streams[0]
    samples, _owner = moves_samples(cell, np.array([s.start, s.q]))
    span = abs(s.q[5] - s.start[5])
    assert len(samples) >= span * 0.1 / 0.01  # the TP, >= 0.1 m off the axis, moves <= 1 cm between checks
    # a deflection-limited joint: the shoulder's inertia makes its limit the binding one
    v2, _a2 = deflection_limits(UR5E, model, 2, site.tracker_noise)
    assert stream_speed(UR5E, SiteConfig.default(), step_plan, 2)[0] == pytest.approx(min(v2, STREAM_SPEED_CAP))
    assert v2 < UR5E.max_speed[1]


def test_plan_json_of_stop_and_go_plans_is_unchanged_and_continuous_plans_round_trip() -> None:
    step = build_plan(UR5E, SMALL)
    assert '"start"' not in step.to_json() and '"speed": null' not in step.to_json()
    assert Plan.from_json(step.to_json()) == step
    plan = build_continuous_plan(UR5E, SMALL)
    assert plan.continuous and not step.continuous
    assert Plan.from_json(plan.to_json()) == plan


def test_a_stream_step_without_its_speed_is_refused() -> None:
    plan = build_continuous_plan(UR5E, SMALL)
    s = next(s for s in plan.steps if s.kind == "stream")
    from dataclasses import replace

    bad = replace(plan, steps=tuple(replace(t, speed=None) if t is s else t for t in plan.steps))
    assert any("stream step needs" in line for line in check_plan(bad, UR5E))
    fast = replace(plan, steps=tuple(replace(t, speed=10.0) if t is s else t for t in plan.steps))
    assert any("above the max_speed" in line for line in check_plan(fast, UR5E))


# --- the stream loop, the session and faults -------------------------------------------------------------------


def _streams(path: Path) -> list[tuple]:
    with sqlite3.connect(path) as db:
        return db.execute("SELECT id, plan_index, attempt, status, superseded FROM streams ORDER BY id").fetchall()


def test_streamed_session_commits_every_half_second_and_exports_rows(tmp_path: Path) -> None:
    session, arm, sensor, rig = _session(tmp_path, "mock:ur5e", "mock?latency=0.02")
    with session:
        result = _run(session, arm, sensor, rig)
        assert result.outcome == "complete"
        meas = session.to_measurements()
    path = tmp_path / "c.session"
    with sqlite3.connect(path) as db:
        assert db.execute("PRAGMA user_version").fetchone()[0] == 3
        for stream, started in db.execute("SELECT id, started FROM streams"):
            times = [started] + [t for (t,) in db.execute("SELECT t FROM stream_batches WHERE stream = ? ORDER BY t",
                                                          (stream,))]
            # batches at least every second on the rig's clock (every COMMIT_PERIOD = 0.5 s + one poll)
            assert max(np.diff(times)) <= 1.0
            assert max(np.diff(times[1:-1])) <= COMMIT_PERIOD + 0.021
        joint_rows = db.execute("SELECT count(*) FROM joint_samples").fetchone()[0]
        tracker_rows = db.execute("SELECT count(*) FROM tracker_samples").fetchone()[0]
    assert [s[3] for s in _streams(path)] == ["complete", "complete"]
    streamed = meas.streamed
    assert streamed.sum() > 0.9 * tracker_rows and joint_rows > 1.9 * tracker_rows
    assert set(meas.joint[streamed]) == {5, 6}
    assert not np.isnan(meas.t[streamed]).any() and np.isnan(meas.t[~streamed]).all()
    # the coarse offset finds the configured latency (tracker stamps 20 ms after the robot's)
    assert meas.clock_offset == pytest.approx(-0.02, abs=3e-3)
    # the rows' joints are where the arm was when the tracker saw the TP: the true model puts the TP at the
    # measured point within the noise (0.087 mm RMS in 3D) and the coarse timing's error
    miss = meas.points[streamed] - points_from_joints(rig.truth, meas.q[streamed])
    assert np.sqrt(np.mean(np.sum(miss**2, axis=1))) < 0.12e-3
    # export -> CSV -> read: t, streamed and the offset survive
    csv = tmp_path / "c.csv"
    with Session.open(path) as s:
        rows = s.export_csv(csv)
    back = read_measurements(csv).measurements
    assert rows == len(meas) == len(back)
    assert np.array_equal(back.streamed, meas.streamed)
    assert back.clock_offset == pytest.approx(meas.clock_offset)
    assert np.allclose(back.t[streamed], meas.t[streamed], rtol=0, atol=1e-6)
    assert np.allclose(back.q, meas.q, atol=1e-9) and np.allclose(back.points, meas.points, atol=1e-9)


def test_target_lost_and_dropped_packets_are_gaps_and_nothing_is_fitted_across_them(tmp_path: Path) -> None:
    session, arm, sensor, rig = _session(tmp_path, "mock:ur5e?drop=0.01", "mock?lost=0.5@1.5")
    with session:
        assert _run(session, arm, sensor, rig).outcome == "complete"
        meas = session.to_measurements()
    with sqlite3.connect(tmp_path / "c.session") as db:
        tracker_gaps = db.execute("SELECT t_start, t_end FROM stream_gaps WHERE device = 'tracker'").fetchall()
        robot_gaps = db.execute("SELECT t_start, t_end FROM stream_gaps WHERE device = 'robot'").fetchall()
    assert len(tracker_gaps) == 2 and all(b - a == pytest.approx(0.5, abs=1e-6) for a, b in tracker_gaps)
    assert len(robot_gaps) > 10
    t = meas.t[meas.streamed]
    for a, b in tracker_gaps:  # no tracker sample inside the lost stretch
        assert not np.any((t > a + 1e-6) & (t < b - 1e-6))
    robot_time = t + meas.clock_offset
    for a, b in robot_gaps:  # no row interpolated across a lost packet (one period either side)
        assert not np.any((robot_time >= a - 0.002) & (robot_time <= b + 0.002))


def test_protective_stop_mid_sweep_interrupts_it_and_the_resume_redoes_it(tmp_path: Path) -> None:
    # moves: 1 home, 2 the first range start, 3 the stream step's move to its start (already there), 4 the sweep
    session, arm, sensor, rig = _session(tmp_path, "mock:ur5e?fault=protective_stop@4", "mock")
    with session:
        result = _run(session, arm, sensor, rig)
        assert result.outcome == "failed" and "protective stop" in result.reason
    path = tmp_path / "c.session"
    first = _streams(path)
    assert len(first) == 1 and first[0][3] == "interrupted"
    with sqlite3.connect(path) as db:
        partial = db.execute("SELECT count(*) FROM tracker_samples").fetchone()[0]
    assert partial > 0  # kept, but superseded by the redo
    rig = SimulatedRig.from_spec("mock:ur5e", "mock", VirtualClock())  # recovered: the faults are cleared
    arm, sensor = open_robot("mock:ur5e", rig=rig), open_tracker("mock", rig=rig)
    arm.connect(1.0)
    sensor.connect(1.0)
    with Session.open(path, write=True) as session:
        assert _run(session, arm, sensor, rig).outcome == "complete"
        meas = session.to_measurements()
    streams = _streams(path)
    assert [(s[2], s[3], s[4]) for s in streams if s[1] == first[0][1]] == [(1, "interrupted", 1), (2, "complete", 0)]
    with sqlite3.connect(path) as db:
        redo = db.execute("SELECT count(*) FROM tracker_samples WHERE stream = ?", (streams[1][0],)).fetchone()[0]
        current = db.execute("SELECT count(*) FROM tracker_samples t JOIN streams s ON s.id = t.stream "
                             "WHERE s.superseded = 0").fetchone()[0]
    assert meas.streamed.sum() <= current and redo > partial
    assert meas.streamed.sum() > current - 10  # only a handful outside the joint stream


def test_a_sweep_longer_than_the_move_timeout_runs_to_its_end(tmp_path: Path) -> None:
    """The move timeout is the slack a move gets beyond its own duration: a constant-speed sweep longer than it
    runs to its end, and the robot's own bound (given to ``start_move``) is as long as the loop's."""
    site = SMALL.with_overrides(speed_fraction=2.0, acceleration_fraction=2.0)
    session, arm, sensor, rig = _session(tmp_path, "mock:ur5e", "mock", site)
    plan = session.plan
    sweeps = [float(motion_time(s.q[s.joint - 1] - s.start[s.joint - 1], s.speed, s.acceleration))
              for s in plan.steps if s.kind == "stream"]
    timeout = 5.0
    assert max(sweeps) > timeout + 1.0  # the joint 6 sweep: 7.1 s
    with session:
        result = Orchestrator(arm, sensor, session, rig.clock, Timeouts(timeout, 10.0, 10.0)).run()
        assert result.outcome == "complete", result.reason
    assert [s[3] for s in _streams(tmp_path / "c.session")] == ["complete", "complete"]
    # the simulated robot keeps a streamed move's timeout as a blocking move does: stopped where it was then
    arm.start_move(np.add(plan.home, [1.0, 0, 0, 0, 0, 0]), plan.speed, plan.acceleration, 0.5)  # 1.5 s
    rig.clock.sleep(0.6)
    with pytest.raises(DeviceTimeout, match=r"timeout of 0\.5 s"):
        arm.motion_done()
    move = rig._path
    assert not rig._moving and move.t_end == pytest.approx(move.t0 + 0.5)


class _Crash(BaseException):
    """Stands for the process dying (kill -9): not an error any layer handles."""


def test_a_crash_mid_sweep_loses_at_most_a_second_and_the_resume_redoes_the_sweep(tmp_path: Path) -> None:
    session, arm, sensor, rig = _session(tmp_path, "mock:ur5e", "mock")
    read = sensor.read_stream
    crash_at: list[float] = []

    def dying() -> object:
        if arm.rig._path is not None and rig.clock.now() > arm.rig._path.t0 + 3.0:
            crash_at.append(rig.clock.now())
            raise _Crash
        return read()

    sensor.read_stream = dying
    with pytest.raises(_Crash), session:
        _run(session, arm, sensor, rig)
    path = tmp_path / "c.session"
    (_stream, index, _attempt, status, _superseded), = _streams(path)
    assert status == "recording"  # the process died while recording
    with sqlite3.connect(path) as db:
        last = db.execute("SELECT max(t) FROM tracker_samples").fetchone()[0]
    # tracker stamps run 2 ms (the default latency) after the rig's clock: at most one second was lost
    assert crash_at[0] - (last - 0.002) <= 1.0
    rig = SimulatedRig.from_spec("mock:ur5e", "mock", VirtualClock())
    arm, sensor = open_robot("mock:ur5e", rig=rig), open_tracker("mock", rig=rig)
    arm.connect(1.0)
    sensor.connect(1.0)
    with Session.open(path, write=True) as session:
        assert _run(session, arm, sensor, rig).outcome == "complete"
        assert session.to_measurements().streamed.sum() > 1000
    redo = [s for s in _streams(path) if s[1] == index]
    assert [(s[2], s[3], s[4]) for s in redo] == [(1, "interrupted", 1), (2, "complete", 0)]


# --- the command line ------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_cli_continuous_session_end_to_end_and_export(tmp_path: Path, capsys) -> None:
    site = tmp_path / "site.yaml"
    site.write_text("schema: 1\nplan:\n  check_poses: 4\n  stream_speed: 0.8\n")
    path = tmp_path / "c.session"
    code = main(["--robot", "mock:ur5e", "--tracker", "mock?rate=50&latency=0.01&drift=0.0005", "--mode", "continuous",
                 "--config", str(site), "--session", str(path), "--quiet"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "holdout" in out and "cont." in out
    # the robot is released, and the time it was held printed, before the identification starts
    released = next(line for line in out.splitlines() if line.startswith("robot released: held "))
    assert out.index(released) < out.index("result written to")
    with Session.open(path) as session:
        steps = session.steps()
    recorded = max(s.t_end for s in steps) - min(s.t_start for s in steps)  # s of the run's (virtual) clock
    held = float(released.split()[3])
    assert recorded <= held + 0.05 < recorded + 5.0, (held, recorded)
    assert " s simulated (" in released and " s wall)" in released  # a mock run says its time is virtual
    csv = tmp_path / "c.csv"
    assert main(["export", str(path), "--csv", str(csv)]) == 0
    out = capsys.readouterr().out
    assert "coarse clock offset" in out and "streamed rows" in out
    back = read_measurements(csv).measurements
    assert back.has_streams and back.streamed.sum() > 1000
    assert main(["export", str(path), "--csv", str(csv)]) == 2  # no overwrite without --force
    with Session.open(path) as session:
        assert session.plan.continuous and session.header["schema"] == 3


def test_cli_dry_run_compares_the_modes_and_bad_combinations_are_one_line(tmp_path: Path, capsys) -> None:
    assert main(["--robot", "ur5e", "--tracker", "mock", "--dry-run", "--mode", "continuous"]) == 0
    out = capsys.readouterr().out
    assert "modes (--mode step | continuous | both)" in out
    step_line = next(line for line in out.splitlines() if line.strip().startswith("step "))
    cont_line = next(line for line in out.splitlines() if line.strip().startswith("continuous "))
    h, m, s = (int(v) for v in step_line.split()[1].split(":"))
    h2, m2, s2 = (int(v) for v in cont_line.split()[1].split(":"))
    assert (h2 * 3600 + m2 * 60 + s2) < 0.35 * (h * 3600 + m * 60 + s)
    assert main(["--robot", "mock:ur5e", "--tracker", "none", "--mode", "continuous"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--mode step" in err
    with pytest.raises(SystemExit) as info:
        main(["--robot", "mock:ur5e", "--mode", "sideways"])
    assert info.value.code == 2


def test_ctrl_c_mid_sweep_stops_the_motion_and_the_run_is_aborted(tmp_path: Path) -> None:
    session, arm, sensor, rig = _session(tmp_path, "mock:ur5e", "mock")
    stop = StopRequest()
    read = sensor.read_stream

    def pressed() -> object:
        move = arm.rig._path
        if move is not None and not stop.requested and rig.clock.now() > move.t0 + 2.0:
            stop.request()  # what the SIGINT handler does
        return read()

    sensor.read_stream = pressed
    with session:
        result = Orchestrator(arm, sensor, session, rig.clock, Timeouts(60.0, 10.0, 10.0), stop=stop).run()
        assert result.outcome == "aborted"
        assert session.recorded_indices() == {0, 1}  # home and the range start; the sweep is not recorded
    move = rig._path
    assert not rig._moving and move.t_stop < move.t0 + move.duration  # stopped short of the range end
    assert [s[3] for s in _streams(tmp_path / "c.session")] == ["interrupted"]


def test_moves_between_sweeps_go_at_the_sweeps_speed() -> None:
    """Between the sweeps the arm moves at the sweeps' own cap (1 rad/s on a UR5e, not the stop-and-go plan's
    0.5 rad/s) unless the site sets robot.speed; that makes the plan shorter, the swept ranges and the stop-and-go
    sweeps of --mode both unchanged (the order and direction of the sweeps: tests/acquire/test_plan_order.py)."""
    site = SiteConfig.default().with_overrides(free_poses=0)
    plan, step = build_continuous_plan(UR5E, site), build_plan(UR5E, site)
    assert plan.speed == (1.0,) * 6 and step.speed == (0.5,) * 6
    slow = build_continuous_plan(UR5E, site.with_overrides(speed=(0.5,) * 6))
    assert slow.speed == (0.5,) * 6
    assert check_plan(plan, UR5E) == []
    # 81.6 s against 96.2 s: the moves between the visits are about a third of the plan at 1 rad/s
    assert estimate_continuous_duration(plan, site.measure_time) < 0.9 * estimate_continuous_duration(
        slow, site.measure_time)
    assert build_both_plan(UR5E, site).speed == step.speed
