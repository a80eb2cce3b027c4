"""Terminal text within the terminal's width (common/fit_width.py)."""

from __future__ import annotations

from common.fit_width import table, width, wrap, wrap_lines


def test_a_long_line_wraps_under_its_own_indentation_and_keeps_long_words_whole():
    line = "  pass  model_fit: " + "residuals 0.0525 mm per axis, " * 5 + "/a/very/long/path/" * 6
    out = wrap(line, 60)
    assert all(len(x) <= 60 for x in out[:-1]) and out[-1].strip() == "/a/very/long/path/" * 6
    assert out[0].startswith("  pass") and all(x.startswith("      ") for x in out[1:])
    assert " ".join(" ".join(out).split()) == " ".join(line.split())  # the words, all of them, in order
    assert wrap_lines(["short", "a\nb"], 60) == ["short", "a", "b"]


def test_a_table_too_wide_splits_into_blocks_that_repeat_its_key_column():
    header = ["", "theta", "d", "a", "alpha"]
    rows = [["J1 R", "0.0000 fixed", "162.5000 ± 0.0065", "-425.1060 ± 0.0045", "90.0226 ± 0.0006"]]
    wide = table(header, rows, 200)
    assert len(wide) == 2 and wide[1].split()[:2] == ["J1", "R"]
    narrow = table(header, rows, 50)
    assert max(map(len, narrow)) <= 50 and "" in narrow
    assert sum(line.startswith("J1 R") for line in narrow) == len(narrow) // 3 + 1  # one row per block


def test_without_a_terminal_or_columns_nothing_is_wrapped(monkeypatch):
    monkeypatch.delenv("COLUMNS", raising=False)
    assert width() is None  # pytest's stdout is not a terminal
    assert wrap("x " * 200) == ["x " * 200]
    monkeypatch.setenv("COLUMNS", "80")
    assert width() == 80
