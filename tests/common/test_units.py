"""Lengths and durations on the command line (common/units.py): a number with its unit; a bare number in metres
or seconds."""

from __future__ import annotations

import argparse

import pytest

from common.units import length, parse_duration, parse_length, positive_duration, positive_length


@pytest.mark.parametrize(("text", "metres"), [
    ("0.05mm", 5e-5), ("50um", 5e-5), ("50µm", 5e-5), ("50μm", 5e-5), ("5e-5", 5e-5), ("5e-5m", 5e-5),
    (" 2 cm ", 0.02), (".5mm", 5e-4), ("1in", 0.0254), ("-3mm", -3e-3), ("+1.5E-3 m", 1.5e-3)])
def test_a_length_is_a_number_with_a_unit_and_a_bare_number_is_metres(text, metres):
    assert parse_length(text) == pytest.approx(metres, rel=1e-12)


@pytest.mark.parametrize("text", ["0.05xx", "mm", "", "inf", "nan", "1e400", "5 m m", "0.05 mm2", "1,5mm", "--1"])
def test_anything_else_is_refused_in_one_line_naming_the_units(text):
    with pytest.raises(ValueError) as info:
        parse_length(text)
    assert "\n" not in str(info.value)
    with pytest.raises(argparse.ArgumentTypeError):
        length(text)


def test_a_positive_length_refuses_zero_and_negatives():
    assert positive_length("50um") == pytest.approx(5e-5)
    for text in ("0", "0mm", "-1mm"):
        with pytest.raises(argparse.ArgumentTypeError, match="positive"):
            positive_length(text)


def test_every_length_option_of_the_commands_takes_units():
    from acquire.commands.cli import build_parser as acquire_parser
    from identify.commands.cli import build_parser as identify_parser

    got = identify_parser().parse_args(["x.csv", "--noise", "50um", "--max-offset", "5cm"])
    assert (got.noise, got.max_offset) == pytest.approx((5e-5, 0.05), rel=1e-12)
    assert acquire_parser().parse_args(["--noise", "0.05mm"]).noise == pytest.approx(5e-5, rel=1e-12)


@pytest.mark.parametrize(("text", "seconds"), [("90s", 90.0), ("1.5min", 90.0), ("2h", 7200.0), ("90", 90.0),
                                               (" 30 s ", 30.0)])
def test_a_duration_is_a_number_with_a_unit_and_a_bare_number_is_seconds(text, seconds):
    assert parse_duration(text) == pytest.approx(seconds, rel=1e-12)
    assert positive_duration(text) == pytest.approx(seconds, rel=1e-12)


@pytest.mark.parametrize("text", ["90mm", "s", "", "inf", "1m", "0", "-5s"])
def test_a_positive_duration_refuses_other_units_zero_and_negatives(text):
    with pytest.raises(argparse.ArgumentTypeError) as info:
        positive_duration(text)
    assert "\n" not in str(info.value)


def test_a_negative_length_with_its_unit_is_refused_for_its_sign_not_as_a_missing_argument(capsys):
    from acquire.commands.options import build_parser as acquire_parser
    from identify.commands.check_cli import build_parser as check_parser

    for parser, argv in ((acquire_parser(), ["--noise", "-0.05mm"]), (check_parser(), ["r.yaml", "d.csv", "--noise",
                                                                                        "-50 um"])):
        with pytest.raises(SystemExit) as info:
            parser.parse_args(argv)
        assert info.value.code == 2
        err = capsys.readouterr().err
        assert len(err.splitlines()) == 1 and "must be a positive length" in err and "expected one argument" not in err


def test_the_text_as_typed_is_kept_and_the_slip_hint_repeats_it():
    from acquire.commands.options import build_parser as acquire_parser
    from common.units import as_typed, slip_hint

    args = acquire_parser().parse_args(["--noise", "50mm", "--target-accuracy", "0.02"])
    assert args.noise == pytest.approx(0.05) and as_typed(args, "noise") == "50mm"
    hint = slip_hint("--noise", as_typed(args, "noise"), args.noise)
    assert hint == "--noise 50mm is read as 50 mm; did you mean 50um?"
    assert slip_hint("--target-accuracy", "0.02", 0.02).endswith("did you mean 0.02mm?")
    assert slip_hint("--noise", "2 m", 2.0).endswith("did you mean 2mm?")
    assert slip_hint("--noise", "0.05um", 5e-8, too_large=False).endswith("did you mean 0.05mm?")
    assert "give the unit" in slip_hint("--noise", "1in", 0.0254)
    assert as_typed(acquire_parser().parse_args([]), "noise") is None


def test_identify_check_noise_takes_units():
    from identify.commands.check_cli import build_parser as check_parser

    assert check_parser().parse_args(["r.yaml", "d.csv", "--noise", "50um"]).noise == pytest.approx(5e-5, rel=1e-12)


def test_the_tool_option_takes_lengths_with_units():
    from common.arguments import comma_numbers
    from common.errors import InputError

    assert comma_numbers("0,0,100mm", "--tool", (3, 6), lengths=3) == pytest.approx([0.0, 0.0, 0.1], rel=1e-12)
    assert comma_numbers("1cm,0,0.1,0,0,1.5", "--tool", (3, 6), lengths=3)[::5] == pytest.approx([0.01, 1.5])
    with pytest.raises(InputError, match="0,0,100mm"):
        comma_numbers("0,0,100mm,0,0,1rad", "--tool", (3, 6), lengths=3)  # rotations are radians, bare
