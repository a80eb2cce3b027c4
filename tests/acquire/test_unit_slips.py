"""``acquire --noise`` and ``--target-accuracy`` 1000x off (a bare number meant in mm, or the wrong unit) are
refused before anything is planned, in one line that repeats what was typed and says what to write instead;
sensible values pass (issue 39, item 2)."""

from __future__ import annotations

import pytest

from acquire.commands.cli import main


@pytest.mark.parametrize(("argv", "words"), [
    (["--noise", "0.05"], "--noise 0.05 is read as 50 mm; did you mean 0.05mm?"),
    (["--noise", "50mm"], "--noise 50mm is read as 50 mm; did you mean 50um?"),
    (["--noise", "0.005"], "--noise 0.005 is read as 5 mm; did you mean 0.005mm?"),  # 100x the mock's 0.05 mm
    (["--noise", "0.05um"], "did you mean 0.05mm?"),  # 1000x below what the tracker states
    (["--target-accuracy", "0.02"], "--target-accuracy 0.02 is read as 20 mm; did you mean 0.02mm?"),
    (["--target-accuracy", "2mm"], "did you mean 2um?"),  # 40x the noise: allowed; 2 mm with 0.01 mm noise is not
    (["--tracker", "serial:/dev/ttyUSB0?protocol=polled-xyz", "--noise", "0.5mm"], "states 0.02 mm"),
])
def test_a_unit_slip_is_refused_in_one_line_repeating_what_was_typed(argv, words, capsys):
    if argv[:2] == ["--target-accuracy", "2mm"]:
        argv = [*argv, "--noise", "0.01mm", "--tracker", "mock?noise=1e-5"]
    assert main(["--robot", "mock:ur5e", "--dry-run", *argv]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and words in err, err


def test_noise_and_target_in_their_units_pass_the_check(capsys):
    from acquire.commands.options import build_parser
    from acquire.commands.prepare import check_units
    from config.site import SiteConfig
    from drivers.spec import TrackerSpec

    for argv, tracker in ((["--noise", "0.05mm", "--target-accuracy", "0.02mm"], "mock"),
                          (["--noise", "20um"], "serial:/dev/ttyUSB0"), (["--noise", "1mm"], "ipp://tracker"),
                          (["--target-accuracy", "1mm"], "mock")):
        args = build_parser().parse_args(argv)
        check_units(args, SiteConfig.default().with_overrides(tracker_noise=args.noise), TrackerSpec.parse(tracker))
