"""Mistakes an operator makes, refused in one line before any fitting: an impossible --parallel-tol or
--max-offset, a file compared with itself, a semicolon-separated CSV (with the hint it needs)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from identify.commands.cli import main

SAMPLE = Path(__file__).resolve().parents[2] / "identify" / "data" / "sample_ur5e.csv"


def _one_line(capsys, *words: str) -> None:
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1, err
    for word in words:
        assert word in err, err


@pytest.mark.parametrize(("option", "value"), [("--parallel-tol", "-1"), ("--parallel-tol", "2"),
                                               ("--max-offset", "-5mm")])
def test_impossible_tolerances_are_refused(option, value, capsys):
    assert main([str(SAMPLE), f"{option}={value}"]) == 2
    _one_line(capsys, option)


def test_a_file_compared_with_itself_is_refused(tmp_path, capsys):
    result = tmp_path / "a.yaml"
    result.write_text("{}")
    assert main(["compare", str(result), str(tmp_path / ".." / tmp_path.name / "a.yaml")]) == 2
    _one_line(capsys, "the same file")


def test_a_semicolon_separated_csv_gets_the_hint_it_needs(tmp_path, capsys):
    lines = SAMPLE.read_text().splitlines()
    header = next(k for k, line in enumerate(lines) if not line.startswith("#"))
    path = tmp_path / "semi.csv"
    path.write_text("\n".join(lines[:header] + [line.replace(",", ";") for line in lines[header:header + 5]]) + "\n")
    assert main([str(path)]) == 2
    _one_line(capsys, str(path), "missing column(s)", "semicolons", "comma-separated")


def _in_degrees(tmp_path: Path) -> Path:
    """The sample with every joint reading in degrees (the contract says radians)."""
    lines = SAMPLE.read_text().splitlines()
    header = next(k for k, line in enumerate(lines) if not line.startswith("#"))
    names = lines[header].split(",")
    out = lines[:header + 1]
    for line in lines[header + 1:]:
        fields = line.split(",")
        out.append(",".join(str(math.degrees(float(v))) if n.startswith("q") and v else v
                            for n, v in zip(names, fields, strict=True)))
    path = tmp_path / "degrees.csv"
    path.write_text("\n".join(out) + "\n")
    return path


@pytest.mark.parametrize("robot", [[], ["--robot", "ur5e"]])
def test_readings_in_degrees_are_refused_with_or_without_a_robot_model(tmp_path, capsys, robot):
    """Before, --robot turned the check into a warning and fitted from the nominal model."""
    assert main([str(_in_degrees(tmp_path)), *robot]) == 2
    _one_line(capsys, "degrees", "radians")


@pytest.mark.parametrize("option", ["--report", "--out"])
def test_an_output_no_file_can_be_written_to_is_refused_before_fitting(monkeypatch, capsys, option):
    """/proc is a folder, but no file can be made in it: before, the refusal came after the fit."""
    import identify.commands.cli

    def no_fit(*args, **kwargs):
        raise AssertionError("fitted before refusing the output")

    monkeypatch.setattr(identify.commands.cli, "identify", no_fit)
    assert main([str(SAMPLE), option, f"/proc/out-{option[2:]}"]) == 2
    _one_line(capsys, option, "no file can be written in /proc")
