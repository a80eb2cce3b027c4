"""I++ DME: averaged readings (server property found at session start, or client-side averaging) and error
severities (warnings recorded, errors cleared), against the simulated server on loopback."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.errors import BadReading, ConnectionFailed
from drivers.registry import open_tracker
from drivers.sim.rig import SimulatedRig
from tests.tracker_devices import IppServer
from tests.tracker_devices import open_ipp as _open

NOISE = 1e-4  # m per axis, large against the 1 nm resolution of the server's replies


@pytest.fixture
def rig() -> SimulatedRig:
    return SimulatedRig("ur5e", seed=5)


def _spread(readings) -> float:
    """RMS per-axis standard deviation of the readings' positions, m."""
    pts = np.array([r.position for r in readings])
    return float(np.sqrt(np.mean(np.var(pts, axis=0, ddof=1))))


def test_server_averaging_property_is_found_set_and_used(rig: SimulatedRig) -> None:
    with IppServer(rig, noise=NOISE, averaging="XX.Average") as server:
        tracker = _open(server, average="16")
        readings = tracker.measure(16, 5.0)
        ident = tracker.identity()
        tracker.close()
    assert tracker.server_average == "Tool.XX.Average" and tracker.server_count == 16
    assert server.properties["XX.Average"] == 16 and server.gets == 16  # one Get per reading
    assert "server: Tool.XX.Average = 16" in ident.details["averaging"]
    assert all(r.sigma is None for r in readings)  # the standard has no field for a point's uncertainty
    # each reading is the mean of 16 points: its spread is NOISE/4 (sample std of 16: within 0.5x..1.6x)
    assert 0.5 * NOISE / 4 < _spread(readings) < 1.6 * NOISE / 4
    assert np.allclose(np.mean([r.position for r in readings], axis=0), rig.true_point(), atol=5 * NOISE / 16)


def test_server_clamps_the_count_with_warning_0504_and_the_client_goes_on(rig: SimulatedRig) -> None:
    with IppServer(rig, averaging="XX.Average", max_average=32) as server:
        tracker = _open(server, average="100")
        assert len(tracker.measure(2, 2.0)) == 2
        tracker.close()
    assert tracker.server_count == 32
    assert [(w.severity, w.code, w.command) for w in tracker.warnings] == [(1, "0504", "SetProp(Tool.XX.Average(100))")]
    assert not any(c.endswith("ClearAllErrors()") for c in server.commands)


@pytest.mark.parametrize("enum_props", [True, False])
def test_client_averages_when_the_server_cannot(enum_props: bool, rig: SimulatedRig) -> None:
    with IppServer(rig, noise=NOISE, enum_props=enum_props) as server:
        tracker = _open(server, average="9")
        readings = tracker.measure(12, 5.0)
        ident = tracker.identity()
        tracker.close()
    assert tracker.server_average is None and server.gets == 9 * 12
    assert ident.details["averaging"] == "client: 9 point(s) per reading"
    if not enum_props:  # EnumAllProp(Tool()) was refused (error 0501), cleared, and the session went on
        assert any(c.endswith("ClearAllErrors()") for c in server.commands)
    sigmas = np.array([r.sigma for r in readings])
    # sigma = spread of 9 points / 3: NOISE/3 (sample std of 9: within 0.4x..1.7x)
    assert np.all((sigmas > 0.4 * NOISE / 3) & (sigmas < 1.7 * NOISE / 3))
    assert 0.5 * NOISE / 3 < _spread(readings) < 1.6 * NOISE / 3
    assert np.abs(np.array([r.position for r in readings]) - rig.true_point()).max() < 5 * NOISE / 3


def test_client_averaging_rejects_an_outlier(rig: SimulatedRig) -> None:
    with IppServer(rig, noise=NOISE) as server:
        tracker = _open(server, average="9", averaging="client")
        server.inject("outlier")
        reading = tracker.measure(1, 3.0)[0]
        tracker.close()
    assert not any("EnumAllProp" in c for c in server.commands)
    assert reading.status == "ok, 1 of 9 points rejected"
    assert np.abs(reading.position - rig.true_point()).max() < 5 * NOISE / np.sqrt(8)


def test_a_named_averaging_property_the_server_lacks_fails_at_connect(rig: SimulatedRig) -> None:
    with IppServer(rig) as server:
        tracker = open_tracker(f"ipp://{server.host}:{server.port}?averaging=Tool.XX.Average&average=4")
        with pytest.raises(ConnectionFailed) as info:
            tracker.connect(2.0)
        tracker.close()
    assert "Tool.XX.Average" in str(info.value) and "0510" in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize(("fault", "severity", "code", "command"), [
    ("warning", 1, "1009", "Get(X(), Y(), Z())"),
    ("info", 0, "0000", "Get(X(), Y(), Z())"),
    ("event_warning", 1, "8001", ""),
])
def test_warnings_and_infos_are_recorded_and_do_not_stop_the_reading(fault: str, severity: int, code: str,
                                                                     command: str, rig: SimulatedRig) -> None:
    with IppServer(rig) as server:
        tracker = _open(server, retries="0")
        server.inject(fault)
        readings = tracker.measure(2, 3.0)
        tracker.close()
    assert [(w.severity, w.code, w.command) for w in tracker.warnings] == [(severity, code, command)]
    assert code in readings[0].status and readings[1].status == "ok"  # kept with the reading it came with
    assert all(np.allclose(r.position, rig.true_point(), atol=2e-4) for r in readings)
    assert server.gets == 2 and not any(c.endswith("ClearAllErrors()") for c in server.commands)


@pytest.mark.parametrize(("fault", "severity", "code"), [("error", 2, "0511"), ("fatal", 9, "0503")])
def test_errors_are_cleared_then_retried_or_reported_in_one_line(fault: str, severity: int, code: str,
                                                                 rig: SimulatedRig) -> None:
    with IppServer(rig) as server:
        tracker = _open(server, retries="2")
        server.inject(fault)
        assert len(tracker.measure(1, 3.0)) == 1  # cleared and retried
        assert sum(c.endswith("ClearAllErrors()") for c in server.commands) == 1
        server.inject(fault, 3)
        with pytest.raises(BadReading) as info:
            tracker.measure(1, 3.0)
        assert f"error {code} (severity {severity}" in str(info.value) and "3 attempts" in str(info.value)
        assert "\n" not in str(info.value) and info.value.severity == severity
        assert len(tracker.measure(1, 2.0)) == 1 and not server.in_error
        tracker.close()
    assert tracker.warnings == []
