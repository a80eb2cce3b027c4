"""Device strings (drivers/spec.py) and the backend registry (drivers/registry.py)."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from drivers import registry, spec
from drivers.errors import BackendUnavailable, SpecError
from drivers.spec import FaultSpec, RobotSpec, TrackerSpec

ROOT = Path(__file__).resolve().parents[2]

# (text, backend, model, host, port, options)
ROBOTS = [
    ("ur5e", "ur", "ur5e", None, None, {}),
    ("ur5e@192.168.1.10", "ur", "ur5e", "192.168.1.10", None, {}),
    ("ur5e@192.168.1.10:30004", "ur", "ur5e", "192.168.1.10", 30004, {}),
    ("UR10e@robot-2.cell.local", "ur", "UR10e", "robot-2.cell.local", None, {}),
    ("ur5e@[fe80::1]:30004", "ur", "ur5e", "fe80::1", 30004, {}),
    ("ur5e@10.0.0.5?speed_scale=0.5&payload=1.2", "ur", "ur5e", "10.0.0.5", None,
     {"speed_scale": "0.5", "payload": "1.2"}),
    ("mock:ur5e", "mock", "ur5e", None, None, {}),
    ("mock:scara", "mock", "scara", None, None, {}),
    ("mock:ur5e?seed=3&fault=protective_stop@40", "mock", "ur5e", None, None,
     {"seed": "3", "fault": "protective_stop@40"}),
    ("mock:track_ur5e?ring=0&repeatability=1e-7&ring_tau=0.2&fault=slow@3x2,disconnect@9", "mock", "track_ur5e",
     None, None, {"ring": "0", "repeatability": "1e-7", "ring_tau": "0.2", "fault": "slow@3x2,disconnect@9"}),
]

# (text, backend, target, options)
TRACKERS = [
    ("serial:/dev/ttyUSB0?baud=115200&protocol=NAME", "serial", "/dev/ttyUSB0",
     {"baud": "115200", "protocol": "NAME"}),
    ("serial:COM3", "serial", "COM3", {}),
    ("serial:socket://192.168.0.7:4001?protocol=faro", "serial", "socket://192.168.0.7:4001", {"protocol": "faro"}),
    ("ipp://host:1294", "ipp", "host:1294", {}),
    ("ipp://10.1.2.3", "ipp", "10.1.2.3", {}),
    ("emscon:192.168.0.1", "emscon", "192.168.0.1", {}),
    ("emscon:at960.local:7000?reflector=2&meas_time=0.5", "emscon", "at960.local:7000",
     {"reflector": "2", "meas_time": "0.5"}),
    ("aruco:0?marker=7&size=0.05&camera=cam.yaml", "aruco", "0", {"marker": "7", "size": "0.05", "camera": "cam.yaml"}),
    ("aruco:/data/run1/*.png?marker=3", "aruco", "/data/run1/*.png", {"marker": "3"}),
    ("aruco:video.mp4", "aruco", "video.mp4", {}),
    ("mock", "mock", "", {}),
    ("mock?noise=5e-5&latency=0.01&dropout=0.02&seed=1&fault=target_lost@10", "mock", "",
     {"noise": "5e-5", "latency": "0.01", "dropout": "0.02", "seed": "1", "fault": "target_lost@10"}),
]

BAD_ROBOTS = ["", "   ", "sim:ur5e", "mock:", "mock:ur5e@10.0.0.1", "ur5e@", "ur5e@host:0", "ur5e@host:70000",
              "ur5e@host:abc", "ur 5e", "mock:arm#2.yaml", "ur5e?", "ur5e?speed", "ur5e?a=1&a=2", "ur5e?a=1&",
              "ur5e?=1",
              "ur5e@[fe80::1", "ur5e@ho st", "mock:ur5e?colour=red", "mock:ur5e?seed=-1", "mock:ur5e?seed=1.5",
              "mock:ur5e?ring=-1e-5", "mock:ur5e?ring_tau=nan", "mock:ur5e?fault=explode@3",
              "mock:ur5e?fault=protective_stop@3x2", "mock:ur5e?fault=slow@0", "mock:ur5e?fault=target_lost@3",
              "mock:ur5e?fault=slow@", "a:b:ur5e"]
BAD_TRACKERS = ["", "seriall:/dev/ttyUSB0", "serial", "serial:", "ipp:host", "ipp://", "ipp://host:99999",
                "ipp://bad host", "emscon:", "emscon", "emscon:host:0", "emscon://host", "aruco:", "mock:x", "mock?",
                "mock?nois=1", "mock?dropout=1", "mock?dropout=-0.1",
                "mock?noise=abc", "mock?latency=inf", "mock?seed=x", "mock?fault=protective_stop",
                "mock?fault=target_lost@2x0", "camera:0", "serial:/dev/ttyUSB0?baud", "serial:/dev/tty USB0"]


@pytest.mark.parametrize(("text", "backend", "model", "host", "port", "options"), ROBOTS)
def test_robot_spec_fields_and_round_trip(text: str, backend: str, model: str, host: str | None, port: int | None,
                                          options: dict[str, str]) -> None:
    parsed = RobotSpec.parse(text)
    assert (parsed.backend, parsed.model, parsed.host, parsed.port, parsed.options) == (backend, model, host, port,
                                                                                          options)
    assert str(parsed) == text
    assert list(parsed.options) == list(options)  # order kept
    assert RobotSpec.parse(str(parsed)) == parsed
    assert RobotSpec(backend, model, host, port, options) == parsed
    assert parsed.is_mock == (backend == "mock")


@pytest.mark.parametrize(("text", "backend", "target", "options"), TRACKERS)
def test_tracker_spec_fields_and_round_trip(text: str, backend: str, target: str, options: dict[str, str]) -> None:
    parsed = TrackerSpec.parse(text)
    assert (parsed.backend, parsed.target, parsed.options) == (backend, target, options)
    assert str(parsed) == text
    assert TrackerSpec.parse(str(parsed)) == parsed
    assert TrackerSpec(backend, target, options) == parsed


def test_equivalent_robot_forms_print_canonically() -> None:
    assert str(RobotSpec.parse("ur:ur5e@h:1")) == "ur5e@h:1"
    assert str(RobotSpec.parse("  mock:ur5e  ")) == "mock:ur5e"
    assert RobotSpec.parse("ur5e").with_host("10.0.0.2", 30004) == RobotSpec.parse("ur5e@10.0.0.2:30004")
    assert TrackerSpec.parse("ipp://cmm:1294").address == ("cmm", 1294)
    assert TrackerSpec.parse("ipp://cmm").address == ("cmm", None)


def test_specs_are_hashable_and_frozen() -> None:
    a, b = RobotSpec.parse("mock:ur5e?seed=1&ring=0"), RobotSpec.parse("mock:ur5e?seed=1&ring=0")
    assert hash(a) == hash(b) and len({a, b, TrackerSpec.parse("mock")}) == 2
    with pytest.raises(AttributeError):
        a.model = "ur10"  # type: ignore[misc]


@pytest.mark.parametrize("text", BAD_ROBOTS)
def test_malformed_robot_spec_repeats_input_and_shows_forms(text: str) -> None:
    with pytest.raises(SpecError) as info:
        RobotSpec.parse(text)
    message = str(info.value)
    assert "\n" not in message
    assert repr(text.strip()) in message
    assert "expected MODEL, MODEL@HOST[:PORT] or mock:MODEL" in message
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize("text", BAD_TRACKERS)
def test_malformed_tracker_spec_repeats_input_and_shows_forms(text: str) -> None:
    with pytest.raises(SpecError) as info:
        TrackerSpec.parse(text)
    message = str(info.value)
    assert "\n" not in message
    assert repr(text.strip()) in message
    assert message.endswith("expected " + spec.TRACKER_FORMS)


def test_unknown_backend_messages() -> None:
    with pytest.raises(SpecError) as info:
        TrackerSpec.parse("seriall:/dev/ttyUSB0")
    assert str(info.value) == ("unknown tracker backend 'seriall' (did you mean 'serial'?) in 'seriall:/dev/ttyUSB0'; "
                               "expected serial:PORT[?opts], ipp://HOST[:PORT], emscon:HOST[:PORT][?opts], "
                               "aruco:SOURCE[?opts], aruco:http://HOST[:PORT]/PATH[?QUERY][#opts] or mock[?opts]")
    with pytest.raises(SpecError, match=r"^unknown robot backend 'sim' in 'sim:ur5e'; expected MODEL"):
        RobotSpec.parse("sim:ur5e")


def test_unknown_mock_options_rejected_with_the_known_ones() -> None:
    with pytest.raises(SpecError) as info:
        RobotSpec.parse("mock:ur5e?sed=1")
    assert "unknown option 'sed' (did you mean 'seed'?)" in str(info.value)
    assert "known: seed, fault, repeatability, ring, ring_tau" in str(info.value)
    with pytest.raises(SpecError, match="known: noise, latency, dropout, seed, fault"):
        TrackerSpec.parse("mock?jitter=1")
    with pytest.raises(SpecError, match="known: protective_stop, emergency_stop, disconnect, slow, unsettled"):
        RobotSpec.parse("mock:ur5e?fault=explode")
    # Real backends' options are checked by their own modules.
    assert TrackerSpec.parse("serial:/dev/ttyUSB0?jitter=1").options == {"jitter": "1"}
    assert RobotSpec.parse("ur5e?anything=1").options == {"anything": "1"}


def test_direct_construction_is_validated() -> None:
    with pytest.raises(SpecError, match="a mock robot has no host"):
        RobotSpec("mock", "ur5e", host="h")
    with pytest.raises(SpecError, match="bad port"):
        RobotSpec("ur", "ur5e", port=30004)  # a port needs a host
    with pytest.raises(SpecError, match="unknown option 'x'"):
        TrackerSpec("mock", options={"x": "1"})
    with pytest.raises(SpecError, match="a port is missing"):
        TrackerSpec("serial")


def test_mock_settings_are_typed_with_defaults() -> None:
    robot = RobotSpec.parse("mock:ur5e?seed=3&fault=protective_stop@40,slow@5x2,unsettled").mock_settings()
    assert robot == {"seed": 3, "repeatability": 2e-6, "ring": 1e-5, "ring_tau": 0.1,
                     "fault": (FaultSpec("protective_stop", 40), FaultSpec("slow", 5, 2), FaultSpec("unsettled")),
                     "scale": 0.0, "eccentricity": 0.0, "compliance": 0.0, "backlash": 0.0, "arm": None, "points": 1,
                     "occlusion": 0.0, "rate": 500.0, "drop": 0.0}
    tracker = TrackerSpec.parse("mock?noise=1e-4&dropout=0.02&fault=target_lost@10x3&turned=0,-90,1e1"
                                ).mock_settings()
    assert tracker == {"noise": 1e-4, "latency": 0.002, "dropout": 0.02, "seed": None,
                       "fault": (FaultSpec("target_lost", 10, 3),), "points": None, "moved": (0.0, 0.0, 0.0),
                       "turned": (0.0, -90.0, 10.0), "occlusion": None,
                       "rate": 250.0, "clock_offset": 0.0, "drift": 0.0, "stamp_jitter": 0.0, "lost": (0.0, 2.0),
                       "orientation": 0.0}
    for bad in ("1,2", "1,2,x", "1,2,nan", "1,2,3,4"):
        with pytest.raises(SpecError, match="must be X,Y,Z: three finite numbers"):
            TrackerSpec.parse(f"mock?moved={bad}").mock_settings()
    assert str(FaultSpec("target_lost", 10, 3)) == "target_lost@10x3"
    assert str(FaultSpec("slow")) == "slow"


# --- registry ----------------------------------------------------------------------------------------------


def test_registry_tables_match_the_spec_backends() -> None:
    assert tuple(registry.ROBOT_BACKENDS) == spec.ROBOT_BACKENDS
    assert tuple(registry.TRACKER_BACKENDS) == spec.TRACKER_BACKENDS
    assert registry.ROBOT_BACKENDS["mock"] == "drivers.sim.robot:open_robot"
    assert registry.TRACKER_BACKENDS["mock"] == "drivers.sim.tracker:open_tracker"


def test_registry_rejects_unknown_backends() -> None:
    with pytest.raises(SpecError, match="unknown robot backend 'sim'"):
        registry.open_robot("sim:ur5e")
    with pytest.raises(SpecError, match="unknown tracker backend 'seriall'"):
        registry.open_tracker("seriall:/dev/ttyUSB0")
    with pytest.raises(BackendUnavailable,
                       match="unknown tracker backend 'laser'; known: serial, ipp, emscon, aruco, mock"):
        registry.load_factory("tracker", "laser")


def test_missing_backend_module_says_what_is_missing(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(registry.ROBOT_BACKENDS, "ur", "drivers.no_such_backend:open_robot")
    with pytest.raises(BackendUnavailable) as info:
        registry.open_robot("ur5e@10.0.0.1")
    assert str(info.value) == ("the 'ur' robot backend is not available in this installation "
                               "(drivers/no_such_backend.py is not implemented yet)")


@pytest.mark.parametrize(("package", "extra"), [("rtde_control", "ur"), ("serial", "serial"), ("cv2", "vision"),
                                                ("some_vendor_sdk", None)])
def test_missing_third_party_package_says_what_to_install(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                          package: str, extra: str | None) -> None:
    monkeypatch.setitem(sys.modules, package, None)  # import fails as if not installed, installed or not
    name = f"fake_backend_{package}"
    (tmp_path / f"{name}.py").write_text(f"import {package}\n\ndef open_robot(spec): ...\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(registry.ROBOT_BACKENDS, "ur", f"{name}:open_robot")
    with pytest.raises(BackendUnavailable) as info:
        registry.open_robot("ur5e")
    message = str(info.value)
    assert message.startswith(f"the 'ur' robot backend needs the Python module {package!r}, which is not installed")
    if extra:
        assert message.endswith(f"(the {extra} extra)") and "pip install '" in message
    else:
        assert message.endswith(f"install the package that provides {package!r}")


def test_backend_module_without_factory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "fake_backend_empty.py").write_text("X = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(registry.TRACKER_BACKENDS, "ipp", "fake_backend_empty:open_tracker")
    with pytest.raises(BackendUnavailable, match=r"fake_backend_empty\.py has no open_tracker\(\)"):
        registry.open_tracker("ipp://cmm")


def test_registry_opens_mock_devices_and_passes_kwargs() -> None:
    from drivers.base import Robot, Tracker
    from drivers.sim.rig import SimulatedRig

    rig = SimulatedRig.from_spec("mock:ur5e?seed=2", "mock?noise=1e-4")
    robot = registry.open_robot("mock:ur5e?seed=2", rig=rig, site=object())  # every factory takes rig and site
    tracker = registry.open_tracker(TrackerSpec.parse("mock?noise=1e-4"), rig=rig, site=None)
    assert isinstance(robot, Robot) and isinstance(tracker, Tracker)
    assert robot.rig is rig and tracker.rig is rig  # type: ignore[attr-defined]
    with pytest.raises(TypeError):
        registry.open_robot("mock:ur5e", bogus=1)


def test_importing_the_registry_imports_no_backend() -> None:
    code = textwrap.dedent("""
        import sys
        import drivers.registry
        from drivers.spec import RobotSpec, TrackerSpec
        RobotSpec.parse("mock:ur5e?seed=1"); TrackerSpec.parse("serial:/dev/ttyUSB0?baud=9600")
        heavy = ["drivers.sim", "drivers.ur", "drivers.trackers.serial_tracker", "drivers.trackers.ipp",
                 "drivers.camera.tracker", "cv2", "serial", "rtde_control", "rtde_receive", "numpy", "identify",
                 "config.robots"]
        print(",".join(name for name in heavy if name in sys.modules))
    """)
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert done.stdout.strip() == ""
    code_mock = "import sys, drivers.registry as r; r.open_robot('mock:ur5e'); print('drivers.sim' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code_mock], cwd=ROOT, capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "True"
