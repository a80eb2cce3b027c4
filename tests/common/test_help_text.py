"""Every ``--help`` fits an 80-column terminal (issue 39, item 9): argparse wraps its own parts; the hand-laid
description and epilog are fitted too (common/help_text.py): blocks that fit are kept, prose is refilled, a table
row hangs at its second column, a long command is continued with a backslash. ``identify --help`` lists every
subcommand."""

from __future__ import annotations

import pytest

from common.help_text import fit


def _parsers():
    from acquire.commands.camera_options import calibrate_parser, print_parser
    from acquire.commands.options import build_parser as acquire_parser
    from acquire.commands.verify_options import build_parser as verify_parser
    from identify.commands import sub_options
    from identify.commands.options import build_parser as identify_parser

    return [acquire_parser, verify_parser, calibrate_parser, print_parser, identify_parser, sub_options.check_parser,
            sub_options.compare_parser, sub_options.compensate_parser]


@pytest.mark.parametrize("columns", [80, 60])
def test_every_help_fits_the_terminal(columns, monkeypatch):
    monkeypatch.setenv("COLUMNS", str(columns))
    for build in _parsers():
        text = build().format_help()
        wide = [line for line in text.splitlines() if len(line) > columns]
        assert not wide, (build().prog, wide)


def test_identify_help_lists_every_subcommand():
    from identify.commands.options import SUBCOMMANDS, build_parser

    text = build_parser().format_help()
    assert all(f"\n  {name} " in text for name in SUBCOMMANDS)


def test_fit_keeps_what_fits_refills_prose_and_hangs_rows():
    text = ("A short block stays.\n\n"
            + "word " * 30 + "\nand its next line\n\n"
            "  0    fine\n  130  stopped by Ctrl-C, SIGTERM or SIGHUP: the motion stops, the run is recorded\n\n"
            "  acquire --robot ur5e@192.168.1.10 --tracker serial:/dev/ttyUSB0 --config site.yaml --yes")
    out = fit(text, 60).split("\n")
    assert out[0] == "A short block stays." and all(len(line) <= 60 for line in out)
    assert "  0    fine" in out and "       stops, the run is recorded" in out  # hung at the second column
    assert "word word word and its next line" in " ".join(out)  # the paragraph refilled
    commands = [line for line in out if "acquire" in line or "--yes" in line]
    assert commands[0].endswith(" \\") and commands[-1].endswith("--yes")
