"""Several tracked points through acquisition: the simulated rig's reflectors (``points=``, ``occlusion=``), real
session files, the real ``acquire export`` command, per-point averaging, resume and the records' checks."""

from __future__ import annotations

import sqlite3
import threading
from dataclasses import replace
from itertools import combinations
from pathlib import Path

import numpy as np
import pytest

from acquire.commands.cli import main
from acquire.planning.plan import build_plan
from acquire.running.orchestrator import Orchestrator
from acquire.running.session import Session
from config.robots import load_robot
from config.site import SiteConfig
from drivers.base import TrackerReading
from drivers.clock import VirtualClock
from drivers.errors import SpecError
from drivers.sim.rig import SimulatedRig
from drivers.sim.robot import SimulatedRobot
from drivers.sim.tracker import SimulatedTracker
from drivers.spec import RobotSpec
from identify.io.csvio import read_measurements
from kinematics.dh import points_from_joints
from session.records import PointRecord, StepRecord

NOISE = 2e-5  # m per axis
SAMPLES = 3
ROBOT = "mock:ur10e?seed=5&points=3"
TRACKER = f"mock?seed=5&noise={NOISE:g}&occlusion=0.15"


def record_session(path: Path, robot: str, tracker: str, *, steps: int = 8, free: int = 2,
                   samples: int = SAMPLES, rig: SimulatedRig | None = None) -> SimulatedRig:
    """A real session file of the default plan (``steps`` per sweep) recorded on the simulated rig."""
    model = load_robot(RobotSpec.parse(robot).model)
    site = SiteConfig.default().with_overrides(steps_per_sweep=steps, samples_per_step=samples, free_poses=free)
    plan = build_plan(model, site)
    rig = rig or SimulatedRig.from_spec(robot, tracker, VirtualClock())
    arm, tracker_dev = SimulatedRobot(rig), SimulatedTracker(rig)
    arm.connect(1.0)
    tracker_dev.connect(1.0)
    config = {"robot_spec": robot, "tracker_spec": tracker, "site": site.as_dict()}
    with Session.create(path, plan, config, arm.identity(), tracker_dev.identity(), model.coupling) as session:
        result = Orchestrator(arm, tracker_dev, session, rig.clock).run()
    assert result.outcome in ("complete", "failed"), result
    return rig


@pytest.fixture(scope="module")
def points_session(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, SimulatedRig]:
    path = tmp_path_factory.mktemp("points") / "p.session"
    return path, record_session(path, ROBOT, TRACKER)


def test_every_point_is_recorded_and_exported(points_session: tuple[Path, SimulatedRig], tmp_path: Path) -> None:
    path, rig = points_session
    csv = tmp_path / "p.csv"
    assert main(["export", str(path), "--csv", str(csv)]) == 0
    assert csv.read_text().splitlines()[7].endswith(",tp")
    meas = read_measurements(csv).measurements
    assert meas.tp_ids == [1, 2, 3]
    poses: dict[tuple, dict[int, np.ndarray]] = {}
    for k in range(len(meas)):
        key = (int(meas.sweep[k]), int(meas.joint[k]), *meas.q[k])
        assert int(meas.tp[k]) not in poses.get(key, {})  # one row per point and pose
        poses.setdefault(key, {})[int(meas.tp[k])] = meas.points[k]
    # the reflectors, 150-250 mm apart, as seen at every pose (noise 0.012 mm per averaged axis)
    gaps = [np.linalg.norm(seen[a] - seen[b]) for seen in poses.values() for a, b in combinations(sorted(seen), 2)]
    assert min(gaps) > 0.15 - 1e-3 and max(gaps) < 0.25 + 1e-3
    # occlusion 0.15 per point and step (61 poses: 27 +- 5 of 183 points hidden; all three seen at 61 % of them)
    hidden = sum(3 - len(seen) for seen in poses.values())
    assert 0.07 * 3 * len(poses) < hidden < 0.25 * 3 * len(poses)
    assert sum(len(seen) == 3 for seen in poses.values()) > 0.4 * len(poses)
    # each point where the truth puts it, with its own noise: sigma / sqrt(samples) per axis
    truth = np.stack([points_from_joints(replace(rig.truth, tool=rig.tools[t - 1]), meas.q[k][None])[0]
                      for k, t in enumerate(meas.tp)])
    err = meas.points - truth
    sigma = NOISE / np.sqrt(SAMPLES)
    assert 0.8 < np.sqrt(np.mean(err**2)) / sigma < 1.2
    assert np.abs(err).max() < 6 * sigma
    kept = (NOISE / meas.sigma) ** 2  # the device's sigma over the root of the readings kept
    np.testing.assert_allclose(kept, np.round(kept), atol=1e-9)
    assert set(np.round(kept)) <= {1, 2, 3} and np.mean(np.round(kept) == 3) > 0.8


def test_points_are_averaged_apart_and_the_file_is_schema_2(points_session: tuple[Path, SimulatedRig]) -> None:
    path, _ = points_session
    with Session.open(path) as session:
        steps = session.steps()
        assert session.header["schema"] == 2 and session.outcome() == "complete"
        drift = session.drift()
    several = [s for s in steps if s.points]
    assert len(several) == sum(s.status == "ok" for s in steps)
    for step in several:
        assert [p.samples + p.rejected for p in step.points] == [SAMPLES] * len(step.points)
        assert step.position == step.points[0].position
        for p in step.points:  # each point's average is the mean of its own kept readings
            mine = [r.position for r, u in zip(step.readings, step.used, strict=True) if r.tp == p.tp and u]
            np.testing.assert_allclose(p.position, np.mean(mine, axis=0), atol=1e-15)
    assert len(drift) > 1 and max(d for _, d in drift) < 1e-4
    with sqlite3.connect(path) as db:
        assert db.execute("PRAGMA user_version").fetchone()[0] == 2
        assert db.execute("SELECT count(DISTINCT tp) FROM readings").fetchone()[0] == 3


def test_a_stopped_points_session_resumes_and_reads_back_equal(tmp_path: Path) -> None:
    path = tmp_path / "r.session"
    robot = "mock:ur5e?seed=2&points=2&fault=protective_stop@12"
    rig = record_session(path, robot, "mock?occlusion=0.2", steps=6, free=0)
    with Session.open(path) as session:
        before = session.steps()
        assert session.outcome() == "failed" and session.header["schema"] == 2
    rig.clear_faults()
    arm, tracker = SimulatedRobot(rig), SimulatedTracker(rig)
    with Session.open(path, write=True) as session:
        assert Orchestrator(arm, tracker, session, rig.clock).run().outcome == "complete"
        after = session.steps()
    assert after[: len(before)] == before  # records read back equal the ones written, points included
    assert {p.tp for s in after for p in s.points} == {1, 2}


def test_records_check_their_points() -> None:
    reading = TrackerReading(np.zeros(3), 0.0, 1e-5, tp=2)
    point = PointRecord(2, (0.0, 0.0, 0.0), 1e-5, 1, 0)
    base = dict(plan_index=0, kind="free", sweep=1, joint=0, role="fit", q_cmd=(0.0,), q_act=(0.0,),
                position=(0.0, 0.0, 0.0), sigma=1e-5, samples=1, rejected=0, status="ok", reason="", t_start=0.0,
                t_end=1.0, readings=(reading,), used=(True,))
    assert StepRecord(**base, points=(point,)).positions() == {2: ((0.0, 0.0, 0.0), 1e-5)}
    with pytest.raises(ValueError, match="need their averages"):
        StepRecord(**base)  # readings of point 2 without its average
    with pytest.raises(ValueError, match="tracked point 2 has samples 2"):
        StepRecord(**base, points=(replace(point, samples=2),))
    with pytest.raises(ValueError, match="first tracked point"):
        StepRecord(**{**base, "position": (1.0, 0.0, 0.0)}, points=(point,))


def test_points_options_are_checked() -> None:
    with pytest.raises(SpecError, match=r"points=5 must be an integer in 1\.\.4"):
        RobotSpec.parse("mock:ur5e?points=5")
    with pytest.raises(SpecError, match=r"points= is 3 in .* but 2 in"):
        SimulatedRig.from_spec("mock:ur5e?points=3", "mock?points=2")
    rig = SimulatedRig.from_spec("mock:ur5e", "mock?points=3")  # the tracker's spec may say it too
    assert rig.points == 3 and np.array_equal(rig.tools[0], rig.truth.tool)
    plain = SimulatedRig.from_spec("mock:ur5e", "mock")
    assert np.array_equal(plain.truth.base, rig.truth.base)  # the reflectors leave the rest of the world alone


def test_settling_ends_on_a_clock_of_epoch_size() -> None:
    """A settle time that is no multiple of the polling period ends (its last sliver of time is below what a clock
    near 1.8e9 s resolves; it once looped for ever)."""
    rig = SimulatedRig("ur5e", clock=VirtualClock(1.8e9 + 0.123))
    arm = SimulatedRobot(rig)
    arm.connect(1.0)
    waited: list[float] = []

    def settle_all() -> None:
        for settle in (0.1, 0.37, 0.5):
            start = rig.clock.now()
            arm.wait_until_still(settle, 5.0)
            waited.append(rig.clock.now() - start)

    worker = threading.Thread(target=settle_all, daemon=True)
    worker.start()
    worker.join(10.0)
    assert len(waited) == 3 and np.allclose(waited, [0.1, 0.37, 0.5], atol=1e-5)
