"""identify's report and identify compare's verdict fit an 80-column terminal (COLUMNS=80); without a terminal
they are left unwrapped (one line per check, for logs)."""

from __future__ import annotations

from pathlib import Path

import pytest

from identify.commands.cli import main

SAMPLE = Path(__file__).resolve().parents[2] / "identify" / "data" / "sample_ur5e.csv"


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """Two identifications of the sample (other held-out draws) and the 80-column report of the first."""
    folder = tmp_path_factory.mktemp("fit")
    mp = pytest.MonkeyPatch()
    mp.setenv("COLUMNS", "80")
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main([str(SAMPLE), "--robot", "ur5e", "--out", str(folder / "a.yaml")]) == 0
        assert main([str(SAMPLE), "--robot", "ur5e", "--seed", "1", "--out", str(folder / "b.yaml")]) == 0
    mp.undo()
    return folder, out.getvalue()


@pytest.mark.slow
def test_the_report_fits_80_columns_with_the_dh_table_whole(results):
    _, text = results
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= 80, max(lines, key=len)
    assert any(line.split() == ["theta", "[deg]", "d", "[mm]", "a", "[mm]", "alpha", "[deg]"] for line in lines)
    assert sum(line.startswith("J1 R") for line in lines) == 4  # two tables of two blocks: DH, then its deltas


def test_without_a_terminal_the_report_is_not_wrapped(results, capsys, monkeypatch):
    monkeypatch.delenv("COLUMNS", raising=False)
    folder, _ = results
    assert main(["compare", str(folder / "a.yaml"), str(folder / "b.yaml")]) == 0
    out = capsys.readouterr().out
    assert any(line.startswith("verdict: no significant change") and "largest TP displacement" in line
               for line in out.splitlines())


def test_the_compare_verdict_is_printed_once_within_80_columns(results, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    folder, _ = results
    assert main(["compare", str(folder / "a.yaml"), str(folder / "b.yaml")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert max(len(line) for line in lines) <= 80, max(lines, key=len)
    assert sum(line.startswith("verdict:") for line in lines) == 1
