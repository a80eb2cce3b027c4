"""Plan building, checking, duration and accuracy prediction (acquire/planning/plan.py)."""

from __future__ import annotations

import math
import re
import time
from dataclasses import replace

import numpy as np
import pytest

from acquire.planning import plan as plan_module
from acquire.planning.design import greedy_design
from acquire.planning.plan import (
    HOME_SWEEP,
    PlanError,
    axis_distances_many,
    build_plan,
    check_plan,
    estimate_duration,
    sweep_values,
    tp_model,
)
from acquire.planning.plan_report import format_plan, predicted_accuracy, prediction_bound
from config.robots import load_robot
from config.site import SiteConfig
from drivers.motion import motion_time
from identify.estimator.bounds import prediction_rms_bound
from identify.simulators.simulate import random_poses
from kinematics.truth import axis_distances
from session.plan import Plan, Step

ROBOTS = ["ur5e", "scara", "gantry", "track_ur5e"]
SITE = SiteConfig.default()


@pytest.fixture(scope="module")
def plans() -> dict[str, Plan]:
    return {name: build_plan(load_robot(name), SITE) for name in ROBOTS}


@pytest.mark.parametrize("name", ROBOTS)
def test_default_plan_structure(plans: dict[str, Plan], name: str) -> None:
    robot, plan = load_robot(name), plans[name]
    n = robot.n_joints
    assert plan.robot == name and plan.joint_types == robot.joint_types
    np.testing.assert_array_equal(plan.home, robot.home)
    assert [s.index for s in plan.steps] == list(range(len(plan.steps)))

    sweeps = [s for s in plan.steps if s.kind == "sweep"]
    order = list(dict.fromkeys((s.sweep, s.joint) for s in sweeps))
    assert order == [(k, n + 1 - k) for k in range(1, n + 1)]  # sweep 1 moves the last joint
    for k, j in order:
        steps = [s for s in sweeps if s.sweep == k]
        assert len(steps) == SITE.steps_per_sweep
        q = np.array([s.q for s in steps])
        others = np.delete(np.arange(n), j - 1)
        np.testing.assert_array_equal(q[:, others], np.tile(robot.home[others], (len(q), 1)))
        assert np.all(np.diff(q[:, j - 1]) > 0)

    free = [s for s in plan.steps if s.kind == "free"]
    assert sum(s.role == "fit" for s in free) == SITE.free_poses
    assert sum(s.role == "check" for s in free) == SITE.check_poses
    assert all(s.joint == 0 for s in free)
    assert sorted(s.sweep for s in free) == list(range(n + 1, n + 1 + len(free)))
    assert all(s.role == "fit" for s in sweeps)

    homes = [s for s in plan.steps if s.kind == "home"]
    measured = len(sweeps) + len(free)
    # plus one home step before each move that would come too close to the cell when made directly
    via_home = sum(int(note.split()[0]) for note in plan.notes if "go through home" in note)
    assert len(homes) == 2 + (measured - 1) // SITE.home_check_every + via_home
    assert plan.steps[0].kind == "home" and plan.steps[-1].kind == "home"
    assert all(s.q == plan.home and s.joint == 0 and s.sweep == HOME_SWEEP for s in homes)
    between = [len(list(g)) for g in "".join("h" if s.kind == "home" else "m" for s in plan.steps).split("h") if g]
    assert max(between) == SITE.home_check_every

    np.testing.assert_allclose(plan.speed, robot.default_speed)
    np.testing.assert_allclose(plan.acceleration, robot.default_acceleration)
    assert (plan.samples_per_step, plan.settle_time) == (SITE.samples_per_step, SITE.settle_time)


@pytest.mark.parametrize("name", ROBOTS)
def test_default_plan_inside_limits(plans: dict[str, Plan], name: str) -> None:
    robot, plan = load_robot(name), plans[name]
    assert check_plan(plan, robot) == []
    q = np.array([s.q for s in plan.steps])
    assert np.all(q >= robot.limits[:, 0]) and np.all(q <= robot.limits[:, 1])


@pytest.mark.parametrize("name", ROBOTS)
def test_tp_guess_off_every_axis(plans: dict[str, Plan], name: str) -> None:
    robot, plan = load_robot(name), plans[name]
    model = tp_model(robot, SITE.tp_guess)
    for step in plan.steps:
        distances = axis_distances(model, np.array(step.q))
        assert np.all(distances >= SITE.min_axis_distance), (step.index, distances)


def test_sweep_ranges_full_turn_and_clipping() -> None:
    ur = load_robot("ur5e")
    plan = build_plan(ur, replace(SITE, free_poses=0, check_poses=0))
    q1 = np.array([s.q[0] for s in plan.steps if s.kind == "sweep" and s.joint == 1])
    # a full turn about home in 10° steps, home included, -180° ... +170°: no angle twice
    np.testing.assert_allclose(np.degrees(q1 - ur.home[0]), np.arange(-180, 180, 10), atol=1e-9)
    # limits narrower than a turn: as far as the limits allow, both ends included
    values = sweep_values("R", 0.5, (-2.0, 2.0), 5)
    np.testing.assert_allclose(values, [-2.0, -1.0, 0.0, 1.0, 2.0])
    np.testing.assert_allclose(sweep_values("R", 0.0, (-1.0, 3.0), 3), [-1.0, 1.0, 3.0])
    np.testing.assert_allclose(sweep_values("P", 0.1, (0.0, 0.2), 3), [0.0, 0.1, 0.2])
    np.testing.assert_allclose(sweep_values("R", 0.0, (-9, 9), 4, (-1.0, 1.0)), np.linspace(-1, 1, 4))
    np.testing.assert_allclose(sweep_values("R", 0.0, (-9, 9), 4, (0.0, 2 * np.pi)), np.arange(4) * np.pi / 2)


def test_site_range_outside_limits_is_reported() -> None:
    # without collision geometry: folded back past its limit the arm would touch the column, and the collision
    # check would refuse the range before the limit check could report it (tests/acquire/test_safety.py covers that)
    scara = replace(load_robot("scara"), geometry=None)
    site = replace(SITE, sweep_ranges=(None, (-2.8, 1.0), None, None), free_poses=0, check_poses=0)
    plan = build_plan(scara, site)
    problems = check_plan(plan, scara)
    assert problems, "a sweep beyond the limits must be refused"
    assert all("joint 2 = -" in line and "outside its limits" in line for line in problems)
    first = next(s for s in plan.steps if s.kind == "sweep" and s.joint == 2)
    assert f"step {first.index} " in problems[0]
    assert "joint 2 = -2.8000 rad (-160.43°)" in problems[0]
    assert "[-2.6180 rad (-150.00°), 2.6180 rad (150.00°)]" in problems[0]
    # only the values beyond the limit are reported: -2.8 + 3.8 k / 35 < -2.618 for k = 0, 1
    assert len(problems) == 2
    assert "joint 2 = -2.6914 rad" in problems[1]


def test_check_plan_speed_joint_count_and_fields() -> None:
    ur = load_robot("ur5e")
    plan = build_plan(ur, replace(SITE, speed_fraction=7.0, free_poses=0, check_poses=0, home_check_every=0))
    problems = check_plan(plan, ur)
    assert len(problems) == 6
    assert problems[0] == "speed of joint 1 = 3.5000 rad/s above its max_speed 3.1416"
    bad = replace(plan, speed=tuple(ur.default_speed), home=plan.home[:5],
                  steps=(replace(plan.steps[0], q=plan.steps[0].q[:5]), replace(plan.steps[1], kind="jump"),
                         replace(plan.steps[2], q=(math.nan, *plan.steps[2].q[1:]))))
    problems = check_plan(bad, ur)
    assert "home: 5 joint values, ur5e has 6 joints" in problems
    assert "step 0 (sweep, sweep 1, joint 6): 5 joint values, ur5e has 6 joints" in problems
    assert any(line.startswith("step 1 ") and "kind 'jump'" in line for line in problems)
    assert any(line.startswith("step 2 ") and "joint 1 = nan" in line for line in problems)
    assert check_plan(replace(plan, robot="ur10e", speed=()), ur)[:2] == [
        "plan is for robot 'ur10e', the model is 'ur5e'", "speed: 0 values, ur5e has 6 joints"]


def test_sweep_joints_subset_and_speed_override() -> None:
    ur = load_robot("ur5e")
    site = replace(SITE, sweep_joints=(2, 5), free_poses=3, check_poses=1, home_check_every=0,
                   speed=(0.2, 0.2, 0.2, 0.4, 0.4, 0.4), speed_fraction=0.5, acceleration_fraction=2.0)
    plan = build_plan(ur, site)
    assert [s.joint for s in plan.steps if s.kind == "sweep"][:: SITE.steps_per_sweep] == [5, 2]
    assert plan.speed == (0.1, 0.1, 0.1, 0.2, 0.2, 0.2)
    np.testing.assert_allclose(plan.acceleration, 2 * ur.default_acceleration)
    assert not any(s.kind == "home" for s in plan.steps)
    with pytest.raises(PlanError, match=r"plan\.joints lists joint 7"):
        build_plan(ur, replace(SITE, sweep_joints=(7,)))
    with pytest.raises(PlanError, match=r"robot\.speed has 2 values for the 6 joints of ur5e"):
        build_plan(ur, replace(SITE, speed=(0.1, 0.1)))
    with pytest.raises(PlanError, match="sweep_ranges has 2 entries for the 6 joints"):
        build_plan(ur, replace(SITE, sweep_ranges=(None, None)))


def test_tp_on_an_axis_is_refused_or_dropped() -> None:
    ur = load_robot("ur5e")
    with pytest.raises(PlanError, match=r"0\.0000 m from the axis of joint 6 at home"):
        build_plan(ur, replace(SITE, tp_guess=(0.0, 0.0, 0.1)))
    site = replace(SITE, tp_guess=(0.0, 0.1, 0.0), free_poses=0, check_poses=0)
    plan = build_plan(replace(ur, geometry=None), site)  # the full turn: no collision clipping
    model = tp_model(ur, site.tp_guess)
    joint5 = [s for s in plan.steps if s.joint == 5]
    assert len(joint5) == SITE.steps_per_sweep - 6
    assert "joint 5 sweep: 6 of 36 poses dropped (TP within 20 mm of the axis of joint 4)" in plan.notes
    assert all(np.all(axis_distances(model, np.array(s.q)) >= 0.02) for s in plan.steps)


def test_vectorised_axis_distances_match() -> None:
    ur = load_robot("track_ur5e")
    model = tp_model(ur, SITE.tp_guess)
    q = random_poses(ur.limits, 20, np.random.default_rng(3))
    expected = np.array([axis_distances(model, row) for row in q])
    np.testing.assert_allclose(axis_distances_many(model, q), expected, rtol=1e-12, atol=1e-12)


def test_prediction_bound_matches_identify_bounds() -> None:
    ur = load_robot("ur5e")
    model = tp_model(ur, SITE.tp_guess)
    rng = np.random.default_rng(4)
    q_fit = random_poses(ur.limits, 40, rng)
    q_eval = random_poses(ur.limits, 30, rng)
    expected = prediction_rms_bound(model, q_fit, q_eval, 1e-4)
    assert prediction_bound(model, q_fit, q_eval, 1e-4) == pytest.approx(expected, rel=1e-6)
    # one sweep alone cannot determine the model: the bound says so instead of a finite number
    sweep = np.tile(ur.home, (10, 1))
    sweep[:, 5] = np.linspace(-1, 1, 10)
    assert prediction_bound(model, sweep, q_eval, 1e-4) == math.inf


@pytest.mark.parametrize("name", ["ur5e", "scara"])
def test_greedy_free_poses_beat_random_ones(name: str) -> None:
    robot = load_robot(name)
    count = 12
    site = replace(SITE, free_poses=count, check_poses=0)
    plan = build_plan(robot, site, rng_seed=7)
    model = tp_model(robot, site.tp_guess)
    sweeps = np.array([s.q for s in plan.steps if s.kind == "sweep"])
    designed = np.array([s.q for s in plan.steps if s.kind == "free"])
    assert len(designed) == count
    # judged on held-out poses the design never saw
    q_eval = random_poses(robot.limits, 300, np.random.default_rng(11))
    greedy = prediction_bound(model, np.vstack([sweeps, designed]), q_eval, 1.0)
    box = plan_module._joint_box(robot, site)
    for seed in range(5):
        pool = random_poses(box, 200, np.random.default_rng(100 + seed), plan_module.FREE_MARGIN)
        pool = pool[np.all(axis_distances_many(model, pool) >= site.min_axis_distance, axis=1)][:count]
        random_bound = prediction_bound(model, np.vstack([sweeps, pool]), q_eval, 1.0)
        assert greedy < 0.95 * random_bound, (seed, greedy, random_bound)
    assert greedy < prediction_bound(model, sweeps, q_eval, 1.0)


def test_greedy_design_is_fast_and_picks_distinct_poses() -> None:
    ur = load_robot("ur5e")
    model = tp_model(ur, SITE.tp_guess)
    plan = build_plan(ur, replace(SITE, free_poses=0, check_poses=0))
    sweeps = np.array([s.q for s in plan.steps if s.kind == "sweep"])
    rng = np.random.default_rng(0)
    pool = random_poses(ur.limits, plan_module.CANDIDATES, rng)
    q_eval = random_poses(ur.limits, plan_module.EVAL_POSES, rng)
    start = time.perf_counter()
    chosen = greedy_design(model, sweeps, pool, q_eval, 30)
    elapsed = time.perf_counter() - start
    assert len(set(chosen.tolist())) == 30
    assert elapsed < 2.0  # about 0.2 s here; generous for a loaded test machine
    # the greedy criterion decreases the design's own objective at every pose added
    bounds = [prediction_bound(model, np.vstack([sweeps, pool[chosen[:k]]]), q_eval, 1.0) for k in (0, 10, 20, 30)]
    assert bounds == sorted(bounds, reverse=True) and bounds[-1] < 0.7 * bounds[0]


def test_predicted_accuracy_ballpark(plans: dict[str, Plan]) -> None:
    ur = load_robot("ur5e")
    acc = predicted_accuracy(plans["ur5e"], ur, SITE.tp_guess, 5e-5)
    step = acc["step_noise"]
    assert step == pytest.approx(5e-5 / math.sqrt(SITE.samples_per_step))
    # full sweeps only: about 1x the per-step noise (0.96 measured); ±20° sweeps about 18x (18.5 measured)
    assert 0.5 < acc["sweeps_only"] / step < 3.5
    assert 10 < acc["partial"] / step < 40
    assert acc["partial"] / acc["sweeps_only"] > 8
    # the free poses buy a clear improvement, and rescue short arcs
    assert acc["with_free"] < 0.75 * acc["sweeps_only"]
    assert acc["partial_with_free"] < 0.15 * acc["partial"]
    # bounds scale with the noise
    acc2 = predicted_accuracy(plans["ur5e"], ur, SITE.tp_guess, 1e-4)
    assert acc2["with_free"] == pytest.approx(2 * acc["with_free"], rel=1e-9)


def test_motion_time_profiles() -> None:
    # trapezoid: 1 rad at 0.5 rad/s, 1 rad/s²: 0.5 s up, 1.5 s cruise, 0.5 s down
    assert motion_time(1.0, 0.5, 1.0) == pytest.approx(2.5)
    # triangle: 0.01 rad never reaches 0.5 rad/s: 2·sqrt(0.01/1)
    assert motion_time(0.01, 0.5, 1.0) == pytest.approx(0.2)
    assert motion_time(0.0, 0.5, 1.0) == 0.0


def test_duration_of_a_two_step_plan() -> None:
    ur = load_robot("ur5e")
    home = tuple(float(x) for x in ur.home)
    q1 = (home[0] + 1.0, *home[1:])
    q2 = (home[0] + 1.0, home[1] - 0.01, *home[2:])
    plan = Plan("ur5e", "RRRRRR", home, (Step(0, "sweep", 1, 1, q1), Step(1, "sweep", 1, 2, q2)),
                samples_per_step=5, settle_time=0.5, speed=(0.5,) * 6, acceleration=(1.0,) * 6)
    # moves: 1 rad (2.5 s), then 0.01 rad (0.2 s); per step 0.5 s settle + 5 x 0.1 s sampling
    assert estimate_duration(plan, ur, 0.1) == pytest.approx(2.5 + 0.2 + 2 * (0.5 + 0.5))
    slow = replace(plan, speed=(0.25, *(0.5,) * 5))  # the slowest joint sets the move time
    assert estimate_duration(slow, ur, 0.1) == pytest.approx(1.0 / 0.25 + 0.25 + 0.2 + 2.0)
    assert estimate_duration(replace(plan, steps=()), ur, 0.1) == 0.0


def test_plan_json_round_trip(plans: dict[str, Plan]) -> None:
    for plan in plans.values():
        again = Plan.from_json(plan.to_json())
        assert again == plan
        assert isinstance(again.steps[5].q, tuple)


def test_format_plan(plans: dict[str, Plan]) -> None:
    ur = load_robot("ur5e")
    plan = plans["ur5e"]
    duration = estimate_duration(plan, ur, 0.02)
    acc = predicted_accuracy(plan, ur, SITE.tp_guess, 5e-5)
    text = format_plan(plan, ur, duration, acc)
    lines = text.splitlines()
    sweep_lines = [line for line in lines if re.match(r"^\s+\d+\s+\d+\s+-?\d", line)]
    assert len(sweep_lines) == 6
    assert sweep_lines[0].split() == ["1", "6", "-180.0°", "170.0°", "36"]
    homes = sum(s.kind == "home" for s in plan.steps)  # 8 checks + the moves that go through home
    assert f"free poses: 24 fitted + 8 held out for checking; home checks: {homes}" in text
    assert f"total: {len(plan.steps)} steps x 5 samples = {5 * len(plan.steps)} samples" in text
    hours, rest = divmod(round(duration), 3600)
    assert f"estimated duration: {hours}:{rest // 60:02d}:{rest % 60:02d}" in text
    assert f"this plan                    {acc['with_free'] * 1e3:.4f} mm" in text
    assert f"without its free poses       {acc['sweeps_only'] * 1e3:.4f} mm" in text
    assert "speed: 28.6°/s" in text
    assert all(f"  - {note}" in text for note in plan.notes)
    gantry = load_robot("gantry")
    text = format_plan(plans["gantry"], gantry, 0.0, None)
    assert "0.0 mm   1000.0 mm" in text and "predicted accuracy" not in text
