"""Device strings (``--robot``, ``--tracker``) parsed into small typed objects that print back to the string.

Robot specs::

    ur5e                      a real UR robot; its host comes from the site configuration
    ur5e@192.168.1.10[:PORT]  a real UR robot at that host (IPv6 in brackets: ur5e@[fe80::1])
    mock:ur5e                 the simulated robot of that model (drivers/sim/)
    mock:arms/cell7.yaml      the model may be a path to a robot YAML file (validated as the bundled ones are),
    arms/cell7.yaml@HOST      in every form: a separator or a .yaml/.yml ending makes it a path (no '@', '?',
                              '#', '&' or white space in it)
    ...?key=value&key=value   options; ``ur:ur5e`` is accepted as the explicit form of ``ur5e``

Tracker specs::

    serial:PORT[?opts]        PORT: /dev/ttyUSB0, COM3, socket://host:port, rfc2217://host:port, ...
                              e.g. serial:/dev/ttyUSB0?baud=115200&protocol=NAME
    ipp://HOST[:PORT][?opts]  an I++ DME server (port as given; the backend picks its default, 1294)
    emscon:HOST[:PORT][?opts] a Leica emScon server (laser tracker; the backend's default port: 700)
    aruco:SOURCE[?opts]       camera index, video/image path or glob; e.g. aruco:0?marker=7&size=0.05
    mock[?opts]               the simulated tracker (drivers/sim/)

Option values are raw text (no percent-decoding): they must not contain ``& = ? #`` or white space; their
order is kept so that ``str(spec)`` gives back the string that was parsed. Options of the mock backends are
checked here (:data:`MOCK_ROBOT_OPTIONS`, :data:`MOCK_TRACKER_OPTIONS`); options of real backends are checked
by their own modules when they are opened. Every error is a :class:`~drivers.errors.SpecError` whose one-line
message repeats the input and shows the expected forms.

Simulated faults (the ``fault`` option of both mock backends) are ``NAME[@N][xK]`` separated by commas: the
fault happens at move (robot) or measurement (tracker) number ``N`` (1-based, counted from the rig's
creation; without ``@N``: the first one) and, for the transient faults, lasts ``K`` moves / measurements.
"""

from __future__ import annotations

import difflib
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from config.model_path import names_a_file
from drivers.errors import SpecError

ROBOT_BACKENDS = ("ur", "mock")
TRACKER_BACKENDS = ("serial", "ipp", "emscon", "aruco", "mock")
ROBOT_FORMS = "MODEL, MODEL@HOST[:PORT] or mock:MODEL (e.g. ur5e, ur5e@192.168.1.10, mock:ur5e, mock:my_arm.yaml; " \
              "MODEL: a bundled name or a path to a robot YAML file), each with optional ?key=value&..."
TRACKER_FORMS = ("serial:PORT[?opts], ipp://HOST[:PORT], emscon:HOST[:PORT][?opts], aruco:SOURCE[?opts], "
                 "aruco:http://HOST[:PORT]/PATH[?QUERY][#opts] or mock[?opts]")

#: Faults of the simulated robot: at move N (see drivers/sim/rig.py for what each does).
ROBOT_FAULTS = ("protective_stop", "emergency_stop", "disconnect", "slow", "unsettled")
#: Faults of the simulated tracker: at measurement N (one ``measure`` call).
TRACKER_FAULTS = ("target_lost", "bad_reading", "disconnect", "slow")
#: Faults that last until cleared (stops: ``rig.clear_faults()``; disconnect: ``connect()``); no ``xK``.
PERSISTENT_FAULTS = ("protective_stop", "emergency_stop", "disconnect")

#: Most tracked points (reflectors) the simulated rig puts on the flange (all 150-250 mm apart on a plate).
MAX_POINTS = 4
_POINTS = f"tracked points (reflectors) on the flange, 1..{MAX_POINTS}, 150-250 mm apart"
_OCCLUSION = "probability that a tracked point is out of sight at a measurement (line of sight blocked)"

#: Options of ``mock:MODEL``: name -> (kind, default, meaning).
MOCK_ROBOT_OPTIONS: dict[str, tuple[str, object, str]] = {
    "seed": ("int", 0, "seed of the true robot and of the robot's random errors"),
    "fault": ("faults", (), "simulated faults, " + "|".join(ROBOT_FAULTS) + "[@MOVE][xCOUNT],..."),
    "repeatability": ("float", 2e-6, "standard deviation of the reached joint position, rad (m)"),
    "ring": ("float", 1e-5, "amplitude of the oscillation after a move, rad (m)"),
    "ring_tau": ("float", 0.1, "decay time of that oscillation, s"),
    "scale": ("float", 0.0, "joint reading scale error (gear ratio): per joint this times a seeded random sign"),
    "eccentricity": ("float", 0.0, "once-per-turn joint error amplitude, degrees (revolute joints; seeded "
                     "random phase per joint)"),
    "compliance": ("float", 0.0, "joint compliance under gravity, rad/(N m) (m/N), every joint; needs the "
                   "model's dynamics"),
    "backlash": ("float", 0.0, "lost motion at a reversal, rad (m), every joint: a joint rests half of it short of "
                 "its target, behind it in the direction of the move"),
    "arm": ("int", None, "seed of the true arm's DH errors alone (default: seed): another arm of the same model at "
            "the same placement, with the same reflectors"),
    "points": ("points", 1, _POINTS),
    "occlusion": ("probability", 0.0, _OCCLUSION),
    "rate": ("rate", 500.0, "joint stream rate, Hz (continuous motion; drivers/sim/stream.py)"),
    "drop": ("probability", 0.0, "probability that a joint-stream packet is lost (a gap in the stream)"),
}
#: Options of ``mock``: name -> (kind, default, meaning).
MOCK_TRACKER_OPTIONS: dict[str, tuple[str, object, str]] = {
    "noise": ("float", 5e-5, "isotropic Gaussian noise, m per axis"),
    "latency": ("float", 0.002, "time per reading, s"),
    "dropout": ("probability", 0.0, "probability that a reading is lost (TargetLost)"),
    "seed": ("int", None, "seed of the tracker's noise and dropouts (default: the robot's seed)"),
    "fault": ("faults", (), "simulated faults, " + "|".join(TRACKER_FAULTS) + "[@MEASUREMENT][xCOUNT],..."),
    "points": ("points", None, _POINTS + " (default: the robot spec's, 1)"),
    "moved": ("vector", (0.0, 0.0, 0.0), "the tracker stands elsewhere: what it sees is shifted by X,Y,Z m "
              "(after turned)"),
    "turned": ("vector", (0.0, 0.0, 0.0), "the tracker stands turned: what it sees is rotated by the rotation "
               "vector X,Y,Z, degrees (its length is the angle)"),
    "occlusion": ("probability", None, _OCCLUSION + " (default: the robot spec's, 0)"),
    "orientation": ("float", 0.0, "6-DoF mode (a 6-DoF probe on each tracked point): every reading also gives the "
                    "target frame's orientation, with isotropic noise of this many rad per axis (0: positions only)"),
    "rate": ("rate", 250.0, "stream rate, Hz (continuous motion; drivers/sim/stream.py)"),
    "clock_offset": ("signed", 0.0, "the tracker clock's offset from the robot's, s"),
    "drift": ("drift", 0.0, "the tracker clock's rate error, a fraction in [-0.01, 0.01] (1e-3: 0.1 %)"),
    "stamp_jitter": ("float", 0.0, "standard deviation of a streamed sample's timestamp, s"),
    "lost": ("interval", (0.0, 2.0), "the target is out of sight for DURATION s from START s (default 2) into "
             "every stream: DURATION[@START]"),
}

_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*\Z")
_MODEL_PATH = re.compile(r"[^\s?#@&]+\Z")  # a model given as a file (config.model_path.names_a_file)
_HOST = re.compile(r"(?:[A-Za-z0-9_][A-Za-z0-9_.-]*|\[[0-9A-Fa-f:.]+\])\Z")
_KEY = re.compile(r"[A-Za-z][A-Za-z0-9_]*\Z")
_VALUE = re.compile(r"[^&=?#\s]+\Z")
_FAULT = re.compile(r"([a-z_]+)(?:@([0-9]+))?(?:x([0-9]+))?\Z")


@dataclass(frozen=True)
class FaultSpec:
    """A simulated fault: ``name`` at move / measurement ``at`` (1-based; None: the next one), lasting
    ``count`` moves / measurements (transient faults only)."""

    name: str
    at: int | None = None
    count: int = 1

    def __str__(self) -> str:
        return self.name + ("" if self.at is None else f"@{self.at}") + ("" if self.count == 1 else f"x{self.count}")


def _fail(problem: str, text: str, forms: str) -> SpecError:
    return SpecError(" ".join(f"{problem} in {text!r}; expected {forms}".split()))


def _suggest(word: str, choices: tuple[str, ...] | list[str]) -> str:
    close = difflib.get_close_matches(word, list(choices), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _split_options(text: str, forms: str, separator: str = "?") -> tuple[str, dict[str, str]]:
    """``head?k=v&k=v`` -> (head, {k: v}) with syntax checks; order kept. A network camera's URL keeps its own
    ``?``: its options follow ``separator`` ``#``."""
    head, sep, query = text.partition(separator)
    options: dict[str, str] = {}
    if not sep:
        return head, options
    if not query:
        raise _fail(f"empty option list after {separator!r}", text, forms)
    for item in query.split("&"):
        key, eq, value = item.partition("=")
        if not eq or not _KEY.match(key) or not _VALUE.match(value):
            raise _fail(f"malformed option {item!r} (options are key=value joined by '&')", text, forms)
        if key in options:
            raise _fail(f"option {key!r} given twice", text, forms)
        options[key] = value
    return head, options


def _query(options: dict[str, str], separator: str = "?") -> str:
    return separator + "&".join(f"{k}={v}" for k, v in options.items()) if options else ""


def _is_url_source(text: str) -> bool:
    """An ``aruco:http://...`` (or https) camera: its options follow ``#``, its URL may hold a ``?``."""
    return text.startswith(("aruco:http://", "aruco:https://"))


def parse_faults(value: str, device: str) -> tuple[FaultSpec, ...]:
    """``NAME[@N][xK],...`` -> faults of ``device`` ("robot" or "tracker"); ValueError with a one-line reason."""
    known = ROBOT_FAULTS if device == "robot" else TRACKER_FAULTS
    faults = []
    for item in value.split(","):
        match = _FAULT.match(item)
        if not match:
            raise ValueError(f"malformed fault {item!r} (NAME[@N][xCOUNT])")
        name, at, count = match.group(1), match.group(2), match.group(3)
        if name not in known:
            raise ValueError(f"unknown {device} fault {name!r}{_suggest(name, known)} (known: {', '.join(known)})")
        fault = FaultSpec(name, None if at is None else int(at), 1 if count is None else int(count))
        if fault.at == 0 or fault.count == 0:
            raise ValueError(f"fault {item!r}: numbers start at 1")
        if fault.count != 1 and name in PERSISTENT_FAULTS:
            raise ValueError(f"fault {item!r}: {name} lasts until cleared and takes no xCOUNT")
        faults.append(fault)
    return tuple(faults)


def parse_interval(key: str, value: str) -> tuple[float, float]:
    """``DURATION[@START]`` (s; START default 2) of option ``key`` -> (duration, start); ValueError in one line."""
    duration, _, start = value.partition("@")
    try:
        out = (float(duration), float(start or 2.0))
    except ValueError:
        out = (math.nan, math.nan)
    if not all(math.isfinite(v) and v >= 0 for v in out):
        raise ValueError(f"option {key}={value} must be DURATION[@START], seconds >= 0")
    return out


def parse_vector(key: str, value: str) -> tuple[float, float, float]:
    """``X,Y,Z`` (three finite numbers) of option ``key``; ValueError in one line."""
    try:
        out = tuple(float(v) for v in value.split(","))
    except ValueError:
        out = ()
    if len(out) != 3 or not all(math.isfinite(v) for v in out):
        raise ValueError(f"option {key}={value} must be X,Y,Z: three finite numbers")
    return out  # type: ignore[return-value]


def _typed(kind: str, key: str, value: str, device: str) -> object:
    """Convert one mock option value; ValueError with a one-line reason."""
    if kind == "faults":
        return parse_faults(value, device)
    if kind == "int":
        if not value.isdigit():
            raise ValueError(f"option {key}={value} must be a non-negative integer")
        return int(value)
    if kind == "interval":
        return parse_interval(key, value)
    if kind == "vector":
        return parse_vector(key, value)
    if kind == "points":
        if not value.isdigit() or not 1 <= int(value) <= MAX_POINTS:
            raise ValueError(f"option {key}={value} must be an integer in 1..{MAX_POINTS}")
        return int(value)
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if kind == "signed" and math.isfinite(number):
        return number
    if kind == "drift" and math.isfinite(number) and abs(number) <= 0.01:
        return number
    if kind == "rate" and not (math.isfinite(number) and 0 < number <= 10000):
        raise ValueError(f"option {key}={value} must be a rate in (0, 10000] Hz")
    if kind == "drift" or not math.isfinite(number) or number < 0 or (kind == "probability" and number >= 1):
        expected = {"probability": "a probability in [0, 1)", "drift": "a fraction in [-0.01, 0.01]",
                    "signed": "a finite number"}.get(kind, "a finite number >= 0")
        raise ValueError(f"option {key}={value} must be {expected}")
    return number


def _mock_settings(options: dict[str, str], table: dict[str, tuple[str, object, str]], device: str,
                   text: str, forms: str) -> dict[str, Any]:
    """All settings of a mock backend (defaults filled in), typed; SpecError naming the input."""
    settings: dict[str, Any] = {key: default for key, (_, default, _) in table.items()}
    for key, value in options.items():
        if key not in table:
            known = ", ".join(table)
            raise _fail(f"unknown option {key!r}{_suggest(key, list(table))} of the mock {device} "
                        f"(known: {known})", text, forms)
        try:
            settings[key] = _typed(table[key][0], key, value, device)
        except ValueError as exc:
            raise _fail(str(exc), text, forms) from None
    return settings


@dataclass(frozen=True)
class RobotSpec:
    """A parsed ``--robot`` string. ``backend`` "ur" or "mock"; ``model`` a robot model name (syntax only is
    checked here); ``host`` (None: from the site configuration) and ``port`` (None: the backend's default)
    for real robots; ``options`` as given, in order."""

    backend: str
    model: str
    host: str | None = None
    port: int | None = None
    options: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "options", dict(self.options))
        self._check(str(self))

    @classmethod
    def parse(cls, text: str) -> RobotSpec:
        """Parse a robot spec; raises SpecError (one line: the input and the expected forms)."""
        if not isinstance(text, str):
            raise SpecError(f"a robot spec must be a string, got {text!r}; expected {ROBOT_FORMS}")
        text = text.strip()
        if not text:
            raise _fail("empty robot spec", text, ROBOT_FORMS)
        head, options = _split_options(text, ROBOT_FORMS)
        model_part, at, address = head.partition("@")
        backend, colon, model = model_part.partition(":")
        if not colon or (backend not in ROBOT_BACKENDS and names_a_file(model_part)):  # C:\arms\x.yaml
            backend, model = "ur", model_part
        elif backend not in ROBOT_BACKENDS:
            raise _fail(f"unknown robot backend {backend!r}{_suggest(backend, ROBOT_BACKENDS)}", text, ROBOT_FORMS)
        host: str | None = None
        port: int | None = None
        if at:
            host, port = _host_port(address, text, ROBOT_FORMS)
        spec = cls.__new__(cls)
        for name, value in (("backend", backend), ("model", model), ("host", host), ("port", port),
                            ("options", options)):
            object.__setattr__(spec, name, value)
        spec._check(text)
        return spec

    def _check(self, text: str) -> None:
        if self.backend not in ROBOT_BACKENDS:
            raise _fail(f"unknown robot backend {self.backend!r}", text, ROBOT_FORMS)
        if not isinstance(self.model, str) or not (
                _NAME.match(self.model) or (names_a_file(self.model) and _MODEL_PATH.match(self.model))):
            raise _fail(f"bad robot model {self.model!r} (a bundled name: letters, digits, '_' and '-'; or a path "
                        "to a robot YAML file)", text, ROBOT_FORMS)
        if self.backend == "mock" and (self.host is not None or self.port is not None):
            raise _fail("a mock robot has no host", text, ROBOT_FORMS)
        if self.host is not None and not _HOST.match(self.host if ":" not in self.host else f"[{self.host}]"):
            raise _fail(f"bad host {self.host!r}", text, ROBOT_FORMS)
        if self.port is not None and (self.host is None or not 0 < self.port < 65536):
            raise _fail(f"bad port {self.port!r} (1..65535, after a host)", text, ROBOT_FORMS)
        if self.backend == "mock":
            self.mock_settings(text)

    def mock_settings(self, text: str | None = None) -> dict[str, Any]:
        """Typed options of a mock robot with defaults filled in (see :data:`MOCK_ROBOT_OPTIONS`)."""
        return _mock_settings(self.options, MOCK_ROBOT_OPTIONS, "robot", text or str(self), ROBOT_FORMS)

    @property
    def is_mock(self) -> bool:
        return self.backend == "mock"

    @property
    def model_is_file(self) -> bool:
        """True when the model is a path to a robot YAML file, not a bundled name."""
        return names_a_file(self.model)

    def resolved(self) -> RobotSpec:
        """The same spec with a model file's path made absolute (what a session records: a resume from another
        folder finds the same file); a bundled name as it is."""
        if not self.model_is_file:
            return self
        return RobotSpec(self.backend, str(Path(self.model).resolve()), self.host, self.port, self.options)

    def with_host(self, host: str, port: int | None = None) -> RobotSpec:
        """The same spec at ``host`` (e.g. from the site configuration)."""
        return RobotSpec(self.backend, self.model, host, port, self.options)

    def __str__(self) -> str:
        if self.backend == "mock":
            head = f"mock:{self.model}"
        else:
            head = self.model
            if self.host is not None:
                head += "@" + (f"[{self.host}]" if ":" in self.host else self.host)
                head += "" if self.port is None else f":{self.port}"
        return head + _query(self.options)

    def __hash__(self) -> int:
        return hash((self.backend, self.model, self.host, self.port, tuple(self.options.items())))


def _host_port(address: str, text: str, forms: str) -> tuple[str, int | None]:
    """``host``, ``host:port``, ``[v6]`` or ``[v6]:port`` -> (host without brackets, port or None)."""
    if address.startswith("["):
        inside, bracket, rest = address[1:].partition("]")
        host, port_text = inside, rest[1:] if rest.startswith(":") else None
        if not bracket or (rest and port_text is None) or not _HOST.match(f"[{inside}]"):
            raise _fail(f"bad host {address!r}", text, forms)
    else:
        host, colon, port_text_ = address.partition(":")
        port_text = port_text_ if colon else None
        if not _HOST.match(host):
            raise _fail(f"bad host {host!r}", text, forms)
    if port_text is None:
        return host, None
    if not port_text.isdigit() or not 0 < int(port_text) < 65536:
        raise _fail(f"bad port {port_text!r} (1..65535)", text, forms)
    return host, int(port_text)


@dataclass(frozen=True)
class TrackerSpec:
    """A parsed ``--tracker`` string. ``backend`` one of :data:`TRACKER_BACKENDS`; ``target`` the port, address
    or source after the backend ("" for mock); ``options`` as given, in order."""

    backend: str
    target: str = ""
    options: dict[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "options", dict(self.options))
        self._check(str(self))

    @classmethod
    def parse(cls, text: str) -> TrackerSpec:
        """Parse a tracker spec; raises SpecError (one line: the input and the expected forms)."""
        if not isinstance(text, str):
            raise SpecError(f"a tracker spec must be a string, got {text!r}; expected {TRACKER_FORMS}")
        text = text.strip()
        if not text:
            raise _fail("empty tracker spec", text, TRACKER_FORMS)
        head, options = _split_options(text, TRACKER_FORMS, "#" if _is_url_source(text) else "?")
        backend, colon, target = head.partition(":")
        if backend not in TRACKER_BACKENDS:
            raise _fail(f"unknown tracker backend {backend!r}{_suggest(backend, TRACKER_BACKENDS)}", text,
                        TRACKER_FORMS)
        if backend == "ipp":
            if not target.startswith("//"):
                raise _fail("an I++ address is written ipp://HOST[:PORT]", text, TRACKER_FORMS)
            target = target[2:]
        elif backend == "mock" and colon:
            raise _fail("the mock tracker takes no target (write mock or mock?key=value)", text, TRACKER_FORMS)
        spec = cls.__new__(cls)
        for name, value in (("backend", backend), ("target", target), ("options", options)):
            object.__setattr__(spec, name, value)
        spec._check(text)
        return spec

    def _check(self, text: str) -> None:
        if self.backend not in TRACKER_BACKENDS:
            raise _fail(f"unknown tracker backend {self.backend!r}", text, TRACKER_FORMS)
        url = isinstance(self.target, str) and _is_url_source(f"{self.backend}:{self.target}")
        if not isinstance(self.target, str) or any(c.isspace() or c in ("#" if url else "?#") for c in self.target):
            raise _fail(f"bad target {self.target!r}", text, TRACKER_FORMS)
        if self.backend == "mock":
            if self.target:
                raise _fail("the mock tracker takes no target", text, TRACKER_FORMS)
            self.mock_settings(text)
        elif not self.target:
            what = {"serial": "a port", "ipp": "a host", "emscon": "a host", "aruco": "a camera source"}[self.backend]
            prefix = "ipp://" if self.backend == "ipp" else f"{self.backend}:"
            raise _fail(f"{what} is missing after {prefix!r}", text, TRACKER_FORMS)
        elif self.backend in ("ipp", "emscon"):
            _host_port(self.target, text, TRACKER_FORMS)

    def mock_settings(self, text: str | None = None) -> dict[str, Any]:
        """Typed options of the mock tracker with defaults filled in (see :data:`MOCK_TRACKER_OPTIONS`)."""
        return _mock_settings(self.options, MOCK_TRACKER_OPTIONS, "tracker", text or str(self), TRACKER_FORMS)

    @property
    def is_mock(self) -> bool:
        return self.backend == "mock"

    @property
    def address(self) -> tuple[str, int | None]:
        """(host, port or None) of an ``ipp`` or ``emscon`` spec."""
        if self.backend not in ("ipp", "emscon"):
            raise ValueError(f"{self} has no network address")
        return _host_port(self.target, str(self), TRACKER_FORMS)

    def __str__(self) -> str:
        head = {"mock": "mock", "ipp": f"ipp://{self.target}"}.get(self.backend, f"{self.backend}:{self.target}")
        return head + _query(self.options, "#" if _is_url_source(head) else "?")

    def __hash__(self) -> int:
        return hash((self.backend, self.target, tuple(self.options.items())))
