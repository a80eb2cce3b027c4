"""Tracker profiles: the loader's one-line errors and the line parser (with hypothesis fuzzing)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from config.robots import ConfigError
from drivers.errors import BadReading, TargetLost
from drivers.trackers.ascii_profile import (
    DeviceReset,
    LineSplitter,
    ParsedLine,
    checksum_of,
    load_profile,
    parse_line,
    profile_from_dict,
    profile_names,
)

BUNDLED = ("polled-xyz", "stream-csv", "tracker-checksum")


def test_bundled_profiles_load() -> None:
    assert set(BUNDLED) <= set(profile_names())
    for name in BUNDLED:
        profile = load_profile(name)
        assert profile.name == name and profile.scale > 0


def _base() -> dict:
    return yaml.safe_load(Path(load_profile("polled-xyz").path).read_text())


@pytest.mark.parametrize(("change", "key", "words"), [
    ({"units": "furlong"}, "units", "mm, m, inch"),
    ({"mode": "sometimes"}, "mode", "polled or streaming"),
    ({"schema": 9}, "schema", "schema version <= 1"),
    ({"colour": "red"}, "colour", "unknown key"),
    ({"response": {"pattern": "(?P<x>.*) (?P<y>.*)"}}, "response.pattern", "no group 'z'"),
    ({"response": {"pattern": "(?P<x>"}}, "response.pattern", "valid regular expression"),
    ({"response": {"fields": ["x", "y", "y"]}}, "response.fields", "distinct"),
    ({"trigger": None}, "trigger", "mode polled"),
    ({"checksum": {"algorithm": "crc99"}}, "checksum.algorithm", "xor or sum8"),
    ({"max_abs": -1}, "max_abs", "> 0"),
    ({"errors": [{"pattern": "E", "kind": "explode"}]}, "errors[0].kind", "error or target_lost"),
    ({"serial": {"parity": "Q"}}, "serial.parity", "N, E, O"),
])
def test_loader_errors_are_one_line_with_file_key_and_expected(change: dict, key: str, words: str) -> None:
    data = {**_base(), **change}
    with pytest.raises(ConfigError) as info:
        profile_from_dict(data, "my.yaml")
    text = str(info.value)
    assert "\n" not in text and text.startswith("my.yaml") and f"'{key}'" in text and words in text


def test_loader_error_for_missing_file_and_unknown_name(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such file"):
        load_profile(tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match="bundled tracker profile"):
        load_profile("nonesuch")
    bad = tmp_path / "bad.yaml"
    bad.write_text("schema: 1\nname: [unclosed\n")
    with pytest.raises(ConfigError, match="line"):
        load_profile(bad)


def test_user_profile_by_path(tmp_path: Path) -> None:
    path = tmp_path / "mine.yaml"
    path.write_text("schema: 1\nname: mine\nmode: polled\ntrigger: GO\nunits: m\n"
                    "response: {delimiter: ';', fields: [null, x, y, z]}\n")
    profile = load_profile(path)
    assert parse_line(profile, "P7;1;2;3").position == (1.0, 2.0, 3.0)


def test_units_are_converted_to_metres() -> None:
    assert parse_line(load_profile("polled-xyz"), "1000 -2000 500").position == pytest.approx((1.0, -2.0, 0.5))
    assert parse_line(load_profile("stream-csv"), "P,1.5,2,3").position == pytest.approx((1.5, 2, 3))
    line = _checksummed("PTS,100.0,0,-10,OK")
    assert parse_line(load_profile("tracker-checksum"), line).position == pytest.approx((2.54, 0, -0.254))


def _checksummed(payload: str, algorithm: str = "xor") -> str:
    return f"${payload}*{checksum_of(payload, algorithm)}"


def test_checksum_status_and_errors() -> None:
    p = load_profile("tracker-checksum")
    good = _checksummed("PTS,1,2,3,OK")
    with pytest.raises(BadReading, match="checksum mismatch"):
        parse_line(p, good[:-2] + ("00" if good[-2:] != "00" else "01"))
    with pytest.raises(TargetLost):
        parse_line(p, _checksummed("PTS,1,2,3,TL"))
    with pytest.raises(BadReading, match="unknown status"):
        parse_line(p, _checksummed("PTS,1,2,3,WARM"))
    with pytest.raises(BadReading, match="out of range"):
        parse_line(p, _checksummed("PTS,1e6,2,3,OK"))
    with pytest.raises(BadReading, match="error"):
        parse_line(p, "$ERR,12")
    with pytest.raises(DeviceReset):
        parse_line(p, "$BOOT*00")
    assert checksum_of("A", "sum8") == "41" and checksum_of("AB", "xor") == "03"


def test_polled_device_errors() -> None:
    p = load_profile("polled-xyz")
    with pytest.raises(TargetLost):
        parse_line(p, "E01 TARGET LOST")
    with pytest.raises(BadReading):
        parse_line(p, "E07 NOT INITIALISED")
    with pytest.raises(BadReading, match="fields"):
        parse_line(p, "1 2")
    with pytest.raises(BadReading, match="unparseable"):
        parse_line(p, "1 2 nan")


def test_sum8_checksum_in_delimited_profile() -> None:
    data = {"schema": 1, "name": "d", "mode": "streaming", "units": "mm", "checksum": {"algorithm": "sum8"},
            "response": {"delimiter": ",", "fields": ["x", "y", "z", "checksum"]}}
    p = profile_from_dict(data)
    good = "1,2,3," + checksum_of("1,2,3,", "sum8")
    assert parse_line(p, good).position == pytest.approx((1e-3, 2e-3, 3e-3))
    with pytest.raises(BadReading):
        parse_line(p, "1,2,4," + checksum_of("1,2,3,", "sum8"))


def test_splitter_partial_lines_noise_and_mixed_endings() -> None:
    s = LineSplitter()
    assert s.feed(b"1 2") == []
    assert s.feed(b" 3\r") == ["1 2 3"]
    assert s.feed(b"\n4 5 6\n\x00\xff7 8 9\r\r\n") == ["4 5 6", "7 8 9"]
    s.resync()
    assert s.feed(b".5 6\r\n1 1 1\n") == ["1 1 1"]
    assert s.feed(b"x" * 2000) == [] and s.feed(b"\n1 2 3\n") == ["1 2 3"]


def _outcome(profile_name: str, data: bytes, chunk: int) -> list[object]:
    profile, splitter, out = load_profile(profile_name), LineSplitter(), []
    for i in range(0, len(data), max(chunk, 1)):
        for line in splitter.feed(data[i:i + max(chunk, 1)]):
            try:
                out.append(parse_line(profile, line))
            except (BadReading, TargetLost, DeviceReset) as exc:
                out.append(type(exc))
    return out


@settings(max_examples=300, deadline=None)  # what parses, not how fast on a loaded host
@given(st.sampled_from(BUNDLED), st.binary(max_size=2000), st.integers(1, 64))
def test_fuzz_random_bytes_give_readings_or_measurement_errors(name: str, data: bytes, chunk: int) -> None:
    for item in _outcome(name, data, chunk):
        if isinstance(item, ParsedLine):
            assert all(math.isfinite(v) for v in item.position)
        else:
            assert item in (BadReading, TargetLost, DeviceReset)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.floats(-5000, 5000), st.floats(-5000, 5000), st.floats(-5000, 5000)), max_size=20),
       st.lists(st.sampled_from([b"\r\n", b"\n", b"\r"]), min_size=20, max_size=20), st.integers(1, 17))
def test_fuzz_valid_lines_split_anywhere_parse_back(points: list, endings: list, chunk: int) -> None:
    data = b"".join(f"{x:.4f} {y:.4f} {z:.4f}".encode() + eol for (x, y, z), eol in zip(points, endings, strict=False))
    got = _outcome("polled-xyz", data, chunk)
    assert len(got) == len(points)
    for item, (x, y, z) in zip(got, points, strict=True):
        assert isinstance(item, ParsedLine)
        assert item.position == pytest.approx((x / 1000, y / 1000, z / 1000), abs=1e-7)
