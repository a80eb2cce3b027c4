"""`acquire --probe`: the operator's first check of a tracker, over a real pseudo-terminal."""

from __future__ import annotations

import json

import numpy as np
import pytest

from acquire.commands.cli import main

pytest.importorskip("serial")
from tests.tracker_devices import AsciiDevice


def test_probe_over_a_pty_prints_readings_spread_and_traces_the_bytes(tmp_path, capsys):
    trace = tmp_path / "io.log"
    with AsciiDevice("polled-xyz", noise=2e-5) as device:
        spec = f"serial:{device.port}?protocol=polled-xyz&timeout=0.5"
        assert main(["--tracker", spec, "--probe", "--count", "5", "--json", "--trace-io", str(trace)]) == 0
        truth = device.rig.true_point()
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(rows) == 5 and set(rows[0]) >= {"x", "y", "z", "timestamp", "sigma", "status"}
    pts = np.array([[r["x"], r["y"], r["z"]] for r in rows])
    assert np.abs(pts.mean(axis=0) - truth).max() < 5 * 2e-5  # metres, tracker frame, within noise
    assert trace.stat().st_size > 0


def test_probe_reports_each_failed_reading_in_one_line_and_exits_1(capsys):
    with AsciiDevice("polled-xyz") as device:
        device.inject("target_lost", count=2)
        code = main(["--tracker", f"serial:{device.port}?protocol=polled-xyz&timeout=0.5&retries=0", "--probe",
                     "--count", "4"])
    assert code == 1
    out, err = capsys.readouterr()
    assert out.count("reading ") == 2 and "2 of 4 readings" in out
    failures = [line for line in err.splitlines() if line]
    assert len(failures) == 2 and all("TargetLost" in line for line in failures)


def test_trace_io_is_refused_for_trackers_without_a_byte_stream(capsys):
    assert main(["--tracker", "mock", "--probe", "--trace-io", "x.log"]) == 2
    assert "serial, I++ and emScon" in capsys.readouterr().err


@pytest.mark.parametrize(("spec", "words"), [
    ("serial:/dev/does-not-exist-7?protocol=polled-xyz", "cannot open serial port '/dev/does-not-exist-7'"),
    ("serial:/dev/ttyS0?protocol=nonesuch", "nonesuch"),
    ("ipp://127.0.0.1:1?timeout=0.5", "cannot connect to the I++ server ipp://127.0.0.1:1"),
])
def test_probe_of_a_missing_device_is_one_line_and_exit_2(spec, words, capsys):
    assert main(["--tracker", spec, "--probe"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err and "Traceback" not in err
