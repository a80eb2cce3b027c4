"""Plans designed for a target accuracy (acquire/planning/plan_target.py, ``acquire --target-accuracy``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from acquire.commands.cli import main
from acquire.planning.plan_continuous import (
    STREAM_START_SLACK,
    estimate_continuous_duration,
    predicted_accuracy_continuous,
    stream_poses,
)
from acquire.planning.plan_target import Candidate, TargetError, candidates, choose, clear_ranges, format_tradeoff
from config.robots import load_robot
from config.site import SiteConfig
from drivers.motion import motion_time


@pytest.fixture(scope="module")
def continuous():
    """The continuous candidates of a UR5e in the default cell (nine plans, a few seconds)."""
    return candidates(("continuous",), load_robot("ur5e"), SiteConfig.default())


def _fake(seconds: float, accuracy: float) -> Candidate:
    site = SiteConfig.default()
    return Candidate("continuous", 1.0, None, None, 0, site, None, seconds, accuracy)  # type: ignore[arg-type]


def test_the_quickest_candidate_that_reaches_the_target_is_chosen():
    found = [_fake(60, 3e-5), _fake(80, 1.9e-5), _fake(90, 1e-5), _fake(200, 5e-6)]
    assert choose(found, 2e-5, None) is found[1]
    assert choose(found, 1e-5, 120) is found[2]
    assert choose(found, None, 100) is found[2]  # the time alone: the most accurate within it
    with pytest.raises(TargetError, match=r"no plan considered reaches 0.005 mm within 0:01:40: the best predicts "
                                          r"0.0100 mm in 0:01:30"):
        choose(found, 5e-6, 100)
    with pytest.raises(TargetError, match="the quickest considered takes 0:01:00"):
        choose(found, 2e-5, 30)


def test_every_candidate_carries_its_own_duration_and_bound_and_slower_or_wider_predicts_better(continuous):
    robot, site = load_robot("ur5e"), SiteConfig.default()
    assert [c.seconds for c in continuous] == sorted(c.seconds for c in continuous)
    assert len(continuous) == 9
    for c in continuous:  # the table's numbers are those of the dry run for the same plan
        assert c.seconds == pytest.approx(estimate_continuous_duration(c.plan, site.measure_time), rel=1e-9)
        bound = predicted_accuracy_continuous(c.plan, robot, site.tp_guess, site.tracker_noise, site.stream_rate)
        assert c.accuracy == pytest.approx(bound["with_free"], rel=1e-9)
    by = {(c.range_fraction, c.speed_cap): c for c in continuous}
    for cap in (None, 0.5, 0.25):  # a wider range: more information, more time
        assert by[1.0, cap].accuracy < by[0.75, cap].accuracy < by[0.5, cap].accuracy
        assert by[1.0, cap].seconds > by[0.5, cap].seconds
    for fraction in (1.0, 0.75, 0.5):  # slower sweeps: more samples per radian
        assert by[fraction, 0.25].accuracy < by[fraction, 0.5].accuracy < by[fraction, None].accuracy
        assert by[fraction, 0.25].seconds > by[fraction, None].seconds


def test_a_shrunk_range_stays_inside_the_clear_one_about_home(continuous):
    full = next(c for c in continuous if c.range_fraction == 1.0 and c.speed_cap is None).plan
    robot = load_robot("ur5e")
    wide, half = clear_ranges(full, robot, 1.0), clear_ranges(full, robot, 0.5)
    for j, (w, h) in enumerate(zip(wide, half, strict=True)):
        assert w is not None and h is not None
        assert w[0] <= h[0] <= full.home[j] <= h[1] <= w[1]
        assert h[1] - h[0] == pytest.approx(0.5 * (w[1] - w[0]), rel=1e-12)


def test_the_trade_off_table_fits_80_columns_and_marks_the_choice(continuous):
    chosen = choose(continuous, 2e-5, 120)
    text = format_tradeoff(continuous, chosen, 2e-5, 120)
    assert max(len(line) for line in text.splitlines()) <= 80
    assert sum("<- chosen" in line for line in text.splitlines()) == 1
    assert "plans considered for 0.02 mm in at most 0:02:00 (" in text


def test_the_dry_run_plans_for_the_target_and_a_step_plan_keeps_the_operators_steps(capsys):
    code = main(["--robot", "mock:ur5e", "--tracker", "mock", "--dry-run", "--mode", "step", "--steps", "12",
                 "--target-accuracy", "0.03mm"])
    out = capsys.readouterr().out
    assert code == 0
    rows = [line for line in out.splitlines() if line.startswith("  step ")]
    assert len(rows) == 2 and all(line.split()[3] == "12" for line in rows)  # free poses 0 and the site's
    chosen = next(line for line in rows if "<- chosen" in line)
    assert float(chosen.split()[6]) <= 0.03
    assert "modes (--mode step | continuous | both)" not in out  # the trade-off table replaces the mode table


@pytest.mark.slow
@pytest.mark.parametrize(("extra", "message"), [
    (["--target-accuracy", "0.001mm", "--mode", "step", "--steps", "12"], "no plan considered reaches 0.001 mm"),
    (["--max-robot-time", "10s", "--mode", "step", "--steps", "12"], "no plan fits in 0:00:10"),
    (["--target-accuracy", "0.02mm", "--mode", "both"], "not both"),
    (["--target-accuracy", "0.02mm", "--tracker", "none"], "--tracker none measures nothing"),
])
def test_an_unreachable_or_misplaced_target_is_refused_in_one_line(capsys, extra, message):
    argv = ["--robot", "mock:ur5e", "--tracker", "mock", "--dry-run", *extra]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and message in err and "Traceback" not in err


@pytest.mark.slow
def test_the_chosen_plan_is_the_one_the_session_gets(capsys, continuous):
    """The plan acquire goes on with (its JSON) is the chosen candidate's: its ranges and speeds, not the
    default plan's."""
    chosen = choose(continuous, 2e-5, None)
    default = next(c for c in continuous if c.range_fraction == 1.0 and c.speed_cap is None)
    assert chosen is not default  # else this test could not tell them apart
    assert main(["--robot", "mock:ur5e", "--tracker", "mock", "--dry-run", "--json", "--mode", "continuous",
                 "--target-accuracy", "0.02mm"]) == 0
    steps = json.loads(capsys.readouterr().out)["steps"]
    streams = [(s["start"], s["q"], s["speed"]) for s in steps if s["kind"] == "stream"]
    expected = [(list(s.start), list(s.q), s.speed) for s in chosen.plan.steps if s.kind == "stream"]
    assert len(streams) == len(expected) == 6
    for (start, end, speed), (start0, end0, speed0) in zip(streams, expected, strict=True):
        np.testing.assert_allclose(start + end + [speed], start0 + end0 + [speed0], atol=1e-12)


def test_a_plan_just_over_the_limit_is_not_shown_at_the_limit():
    found = [_fake(90.4, 1e-5), _fake(80, 1.5e-5)]
    text = format_tradeoff(found, found[1], 2e-5, 90)
    assert "0:01:31    0.0100 mm too long" in text and "0:01:20    0.0150 mm <- chosen" in text


def test_a_speed_cap_that_slows_no_sweep_is_not_a_candidate():
    """A SCARA without link masses sweeps at 0.25 rad/s already: capping it at 0.5 or 0.25 rad/s changes nothing,
    so each sweep range is one candidate, not three equal ones."""
    found = candidates(("continuous",), load_robot("scara"), SiteConfig.default())
    assert [c.speed_cap for c in found] == [None, None, None]
    assert len({round(c.seconds, 6) for c in found}) == 3


def test_the_bound_counts_the_samples_the_streams_take_at_rest_at_the_range_ends(continuous):
    """The streams run 0.5 s before and after each move (the arm at rest at the range ends), and the session keeps
    those samples: the bound counts them at the ends (the dry run once expected 8,400 samples where sessions kept
    9,900)."""
    site = SiteConfig.default()
    plan = next(c for c in continuous if c.range_fraction == 1.0 and c.speed_cap is None).plan
    q, weight = stream_poses(plan, site.stream_rate)
    streams = [s for s in plan.steps if s.kind == "stream"]
    moving = sum(int(site.stream_rate * float(motion_time(s.q[s.joint - 1] - s.start[s.joint - 1], s.speed,
                                                                s.acceleration))) for s in streams)
    rest = site.stream_rate * STREAM_START_SLACK
    assert weight.sum() == pytest.approx(moving + 2 * rest * len(streams), rel=1e-9)
    ends = np.array([s.start for s in streams] + [s.q for s in streams])
    at_ends = np.array([np.any(np.all(np.isclose(row, ends), axis=1)) for row in q])
    assert np.all(weight[at_ends] > rest)
