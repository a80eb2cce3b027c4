"""The continuous dry run says what the plan does: sweeps numbered 1..n, the stop-and-go poses at the sweeps'
starts counted apart from fitted free poses, the sweeps' own speed and an acceleration with its unit."""

from __future__ import annotations

import re

from acquire.planning.plan_modes import build_mode_plan, mode_site
from acquire.planning.plan_report import format_plan
from config.robots import load_robot
from config.site import SiteConfig


def test_the_continuous_plan_is_described_as_it_runs():
    robot = load_robot("ur5e")
    plan = build_mode_plan("continuous", robot, mode_site(SiteConfig.default(), "continuous", None))
    text = format_plan(plan, robot, 0.0, None)
    numbers = [int(m.group(1)) for m in re.finditer(r"^\s+(\d+)\s+\d\s+.*cont\.$", text, re.M)]
    assert numbers == [1, 2, 3, 4, 5, 6]
    assert "free poses: 0 fitted + 5 held out for checking; 6 stop-and-go poses at the continuous sweeps' starts" \
        in text
    # transfers run at the sweeps' own speed cap (1 rad/s on a UR5e, issue 26), the sweeps at theirs
    assert "speed between steps: 57.3°/s" in text and "(each continuous sweep at its own speed: notes)" in text
    assert re.search(r"one continuous sweep at 57\.3°/s \(acceleration 57\.3°/s²\)", text)
