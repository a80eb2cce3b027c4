"""The continuous plan's visiting order and its check poses (issue 26): as many check poses as the held-out figure
needs, sweeps and poses in a short tour, every move of it checked against the cell (pure, no devices)."""

from __future__ import annotations

import functools
import itertools

import numpy as np
import pytest

from acquire.planning.plan import plan_clearance, tp_model
from acquire.planning.plan_continuous import (
    _via_home,
    build_continuous_plan,
    estimate_continuous_duration,
    validation_poses,
)
from acquire.planning.plan_modes import mode_site
from acquire.planning.plan_order import Visit, order_visits, tour_time
from config.cell import cell_from_config, first_contact
from config.robots import load_robot
from config.site import SiteConfig
from drivers.motion import motion_time
from kinematics.dh import points_from_joints
from session.plan import Plan

UR5E = load_robot("ur5e")
SITE = mode_site(SiteConfig.default(), "continuous", None)


def _transfer(plan: Plan) -> float:
    """Seconds of the plan's moves between its visits (to each pose, to each stream's start; not the streams)."""
    here, total = np.asarray(plan.home), 0.0
    for s in plan.steps:
        target = np.asarray(s.start if s.kind == "stream" else s.q)
        total += float(motion_time(target - here, np.asarray(plan.speed), np.asarray(plan.acceleration)).max())
        here = np.asarray(s.q)
    return total


def test_check_pose_count_gives_the_held_out_rms_to_20_percent() -> None:
    assert validation_poses() == 5 and validation_poses(tracked_points=3) == 2 and validation_poses(2, 0.1) == 9
    # the rule's premise, by simulation: the RMS of 5 poses x 3 Gaussian components has a relative standard
    # error of sqrt(1/30) = 0.18 (20,000 draws: the estimate's own standard error is about 0.001)
    rms = np.sqrt(np.mean(np.random.default_rng(0).normal(size=(20_000, 5 * 3)) ** 2, axis=1))
    assert np.std(rms) / np.mean(rms) == pytest.approx(np.sqrt(1 / 30), abs=0.006)
    assert np.std(rms) / np.mean(rms) <= 0.2
    four = np.sqrt(np.mean(np.random.default_rng(1).normal(size=(20_000, 4 * 3)) ** 2, axis=1))
    assert np.std(four) / np.mean(four) > 0.2  # one pose fewer would miss it
    plan = build_continuous_plan(UR5E, SITE)
    assert sum(s.role == "check" for s in plan.steps) == 5  # the site's 8 were visited before
    assert sum(s.role == "check" for s in build_continuous_plan(UR5E, SITE.with_overrides(check_poses=2)).steps) == 2


def test_default_plan_travels_less_and_every_move_is_clear() -> None:
    plan = build_continuous_plan(UR5E, SITE)
    assert sorted(s.joint for s in plan.steps if s.kind == "stream") == [1, 2, 3, 4, 5, 6]
    # before: joints 6..1, each from its nearer end, home after the sweeps, 8 check poses: 53.9 s of moves
    # (45.0 s with 5 check poses) and 106.0 s in all; now 32.5 s and 81.6 s
    assert _transfer(plan) < 0.75 * 45.0
    assert estimate_continuous_duration(plan, SITE.measure_time) < 85.0  # 1/6 of stop-and-go's ~510 s
    kinds = [s.kind for s in plan.steps]
    assert kinds[0] == kinds[-1] == "home" and "home" not in kinds[1:-1]  # no move in this cell needs home
    clearance = plan_clearance(plan, UR5E, SITE)
    assert clearance is not None and clearance.slack >= clearance.guard  # every move, streams included


def test_a_move_that_would_come_too_close_goes_through_home() -> None:
    """A 2 cm post where the TP passes halfway between two poses, each reached from home clear of it: the plan's
    check finds the direct move and routes it through home."""
    home = np.asarray(UR5E.home, dtype=float)
    a, b = home.copy(), home.copy()
    a[0], b[1], b[2] = 0.8, -0.9, 0.95
    mid = points_from_joints(tp_model(UR5E, SITE.tp_guess), ((a + b) / 2)[None])[0]
    cell = cell_from_config(UR5E, SITE.with_overrides(boxes=({"name": "post", "min": list(mid - 0.01),
                                                               "max": list(mid + 0.01)},)))
    assert cell is not None and first_contact(cell, a, b) is not None
    assert first_contact(cell, home, a) is None and first_contact(cell, home, b) is None
    h = tuple(home)
    poses = [("home", 0, h, "fit", None, None), ("free", 0, tuple(a), "check", None, None),
             ("free", 0, tuple(b), "check", None, None), ("home", 0, h, "fit", None, None)]
    out, added = _via_home(cell, poses)
    assert added == 1 and [p[0] for p in out] == ["home", "free", "home", "free", "home"]
    assert _via_home(cell_from_config(UR5E, SITE), poses) == (poses, 0)  # without the post: direct


def test_order_visits_finds_the_shortest_tour_of_small_problems() -> None:
    """On random small problems (3 sweeps, 2 poses, 3 joints, one speed per joint) the tour is the exhaustive
    optimum (or within 5 % of it) and never longer than visiting in the given order from the nearer ends."""
    rng = np.random.default_rng(7)
    speed, acc = np.array([1.0, 1.0, 1.0]), np.array([2.0, 2.0, 2.0])

    @functools.cache
    def between(a: tuple[float, ...], b: tuple[float, ...]) -> float:
        return float(motion_time(np.subtract(b, a), speed, acc).max())

    def move(a: np.ndarray, b: np.ndarray) -> float:  # the exhaustive search meets each pair of ends many times
        return between(tuple(np.asarray(a, dtype=float)), tuple(np.asarray(b, dtype=float)))

    optimal = 0
    for _ in range(20):
        home = np.zeros(3)
        sweeps = []
        for j in range(3):
            start, end = home.copy(), home.copy()
            start[j], end[j] = rng.uniform(-3, -1), rng.uniform(1, 3)
            sweeps.append((start, end))
        poses = list(rng.uniform(-2, 2, size=(2, 3)))
        tour = order_visits(home, sweeps, poses, move)
        assert sorted((v.sweep, v.item) for v in tour) == [(False, 0), (False, 1), (True, 0), (True, 1), (True, 2)]
        t = tour_time(tour, home, sweeps, poses, move)
        items = [Visit(True, i) for i in range(3)] + [Visit(False, i) for i in range(2)]
        best = min(tour_time([Visit(v.sweep, v.item, v.sweep and bool(f >> v.item & 1)) for v in order], home,
                             sweeps, poses, move)
                   for order in itertools.permutations(items) for f in range(8))
        assert t <= 1.05 * best
        optimal += t <= best + 1e-9
        given = tour_time(items, home, sweeps, poses, move)
        assert t <= given + 1e-9
    assert optimal >= 16
