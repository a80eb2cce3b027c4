"""The dry run plans with what the named tracker can do (issue 39, item 8): a polled serial profile cannot stream
(no continuous plan is offered or chosen, ``--mode continuous`` is refused in one line) and its data sheet's noise
is the one planned with, unless ``--noise`` or the site file says otherwise; a streaming device's rate caps the
stream rate asked for."""

from __future__ import annotations

import pytest

from acquire.commands.options import build_parser
from acquire.commands.prepare import UsageError, tracker_site
from config.site import SiteConfig
from drivers.spec import TrackerSpec

POLLED = "serial:/dev/ttyUSB0"  # the default profile, polled-xyz: sigma 0.02 mm, polled


def _site(argv: list[str], tracker: str):
    return tracker_site(SiteConfig.default(), build_parser().parse_args(argv), TrackerSpec.parse(tracker))


def test_a_polled_profile_plans_its_own_noise_and_no_stream():
    site, why = _site([], POLLED)
    assert site.tracker_noise == pytest.approx(2e-5) and "cannot stream" in why and "polled-xyz" in why
    assert _site(["--noise", "0.03mm"], POLLED)[0].tracker_noise == pytest.approx(5e-5)  # --noise is applied later
    with pytest.raises(UsageError, match="--mode continuous: serial:/dev/ttyUSB0 cannot stream"):
        _site(["--mode", "continuous"], POLLED)


def test_the_site_file_wins_over_the_data_sheet_and_streams_are_capped_by_the_device(tmp_path):
    site_file = tmp_path / "site.yaml"
    site_file.write_text("schema: 1\ntracker: {noise: 3.0e-5}\n")
    args = ["--config", str(site_file)]
    assert _site(args, POLLED)[0].tracker_noise == pytest.approx(SiteConfig.default().tracker_noise)
    streaming, why = _site([], "serial:/dev/ttyUSB0?protocol=stream-csv")  # 500 Hz, sigma 0.05 mm
    assert why == "" and streaming.stream_rate == pytest.approx(250.0)
    assert _site([], "mock?rate=100")[0].stream_rate == pytest.approx(100.0)


def test_target_planning_with_a_polled_tracker_chooses_among_stop_and_go_plans(capsys):
    from acquire.commands.cli import main

    assert main(["--robot", "ur5e", "--tracker", POLLED, "--dry-run", "--target-accuracy", "0.02mm",
                 "--steps", "12", "--free-poses", "0"]) == 0
    out = capsys.readouterr().out
    assert "<- chosen" in out and "continuous" not in out.split("plans considered")[1].split("range:")[0]
