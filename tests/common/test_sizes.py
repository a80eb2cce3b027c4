"""Size options are bounded (issue 39, item 7): ``--steps 100000000`` ran ten minutes to 6.5 GB before anything was
said. Every size option (command line or site file) beyond what can finish is refused at once in one line that
says the bound and why; the bounds themselves are accepted."""

from __future__ import annotations

import pytest

from common.arguments import SIZES


def _refused(parser, argv, capsys) -> str:
    with pytest.raises(SystemExit) as info:
        parser.parse_args(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1, err
    return err


@pytest.mark.parametrize(("option", "name"), [("--steps", "steps"), ("--samples", "samples"),
                                              ("--free-poses", "free_poses"), ("--count", "count")])
def test_acquire_size_options_beyond_their_bound_are_refused(option, name, capsys):
    from acquire.commands.options import build_parser

    high = SIZES[name][1]
    assert getattr(build_parser().parse_args([option, str(high)]), name) == high
    err = _refused(build_parser(), [option, "100000000"], capsys)
    assert f"{option}: 100000000 is more than {high}" in err


def test_verify_compare_and_camera_sizes_are_bounded(capsys):
    from acquire.commands.camera_cli import calibrate_main
    from acquire.commands.verify_options import build_parser as verify_parser
    from identify.commands.compare_cli import build_parser as compare_parser

    assert "ISO 9283 asks for 30" in _refused(verify_parser(), ["--cycles", "5000"], capsys)
    assert "--poses" in _refused(compare_parser(), ["a", "b", "--poses", "10000000"], capsys)
    with pytest.raises(SystemExit):
        calibrate_main(["imgs", "--out", "x.yaml", "--views", "99999"])
    assert "--views: 99999 is more than 1000" in capsys.readouterr().err


def test_the_site_file_is_bounded_as_the_command_line_is():
    from config.files import ConfigError
    from config.site import SiteConfig

    site = SiteConfig.default()
    assert site.with_overrides(steps_per_sweep=1000).steps_per_sweep == 1000
    with pytest.raises(ConfigError, match=r"steps_per_sweep.*from 3 to 1000"):
        site.with_overrides(steps_per_sweep=100_000_000)
    with pytest.raises(ConfigError, match=r"verify\.cycles"):
        site.with_overrides(verify_cycles=5000)
