"""ASCII tracker profiles (``config/trackers/*.yaml``, schema 1): how a line-oriented device talks, and the
parser of its replies. A user adds a device by writing a profile, not code.

A profile holds (keys of :data:`KEYS`; see the bundled files for commented examples)::

    schema: 1                       # file-format version
    name: polled-xyz                # how ``protocol=NAME`` finds it (the file stem must match)
    description: ...
    serial: {baud: 9600, parity: N, bytesize: 8, stopbits: 1}   # defaults; the spec's options override them
    line_ending: "\\r\\n"            # appended to every command sent (replies may end in \\r, \\n or \\r\\n)
    init: ["UNITS MM", {send: "MODE 1", expect: "^OK$"}]        # after connect and after a device reset
    identify: {send: "*IDN?", pattern: "(?P<model>...),(?P<serial>...),(?P<firmware>...)"}
    mode: polled                    # polled: ``trigger`` per reading; streaming: the device sends freely
    trigger: "MEAS?"                # polled only
    start: "STREAM ON"              # streaming only, optional: sent after init
    stop: "STREAM OFF"              # streaming only, optional: sent before close
    period: 0.002                   # streaming only, optional: s between streamed lines on the device's clock
    response:                       # either a regular expression with named groups x, y, z and optional
      pattern: '^(?P<x>\\S+) (?P<y>\\S+) (?P<z>\\S+)$'   # status, sigma, checksum, payload, tp ...
      # ... or a delimiter (null: white space) and the field order (x, y, z, status, sigma, checksum, tp, t, seq,
      # or null for a field to skip):   delimiter: ",",  fields: [null, x, y, z, status, checksum]
      # t: the device's time of the reading (s, its own clock); seq: the line's sequence number (integer): a
      # streaming profile with t can stream with device timestamps (drivers/trackers/serial_stream.py)
    points: 3                       # optional (default 1), polled only: the trigger is answered by this many
                                    # lines, one per tracked point in id order; the response needs a ``tp``
                                    # field (the line's id, checked); a point out of sight answers with a
                                    # target-lost status (its id is read too) or error reply
    units: mm                       # mm, m or inch (x, y, z and sigma)
    max_abs: 100.0                  # metres; a coordinate beyond it is out of range (BadReading)
    sigma: 1.5e-5                   # metres per axis, the device's stated uncertainty (optional)
    checksum: {algorithm: xor, covers: payload}   # xor | sum8, two hex digits; covers: the ``payload`` group,
                                    # or (default) everything in the line before the checksum field
    status: {ok: ["OK"], target_lost: ["TL", "LOST"]}   # values of the status field; others: BadReading
    errors: [{pattern: "^E01", kind: target_lost}, {pattern: "^E\\\\d+", kind: error}]
    reset: "^ACME .* READY$"        # a line the device prints after (re)booting: the driver re-initialises
    simulation: {...}               # optional: how tests/tracker_devices.py formats this device's replies

Parsing (:class:`LineSplitter`, :func:`parse_line`): bytes are split at ``\\r``, ``\\n`` or ``\\r\\n``; bytes
outside printable ASCII are dropped; empty lines are skipped; a line longer than :data:`MAX_LINE` is dropped
as garbage. A line gives a :class:`ParsedLine` or raises BadReading (unparseable, out of range, checksum
mismatch, unknown status, error reply), TargetLost (status or error reply saying so) or :class:`DeviceReset`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from config.files import ConfigError, check_schema, config_file, got, read_yaml
from drivers.errors import BadReading, MeasurementError, TargetLost

SCHEMA_VERSION = 1
TRACKERS_DIR = Path(__file__).resolve().parents[2] / "config" / "trackers"
KEYS = ("schema", "name", "description", "serial", "line_ending", "init", "identify", "mode", "trigger", "start",
        "stop", "period", "response", "points", "units", "max_abs", "sigma", "checksum", "status", "errors", "reset",
        "simulation")
UNITS = {"mm": 1e-3, "m": 1.0, "inch": 0.0254}
FIELDS = ("x", "y", "z", "status", "sigma", "checksum", "tp", "t", "seq")
SERIAL_KEYS = ("baud", "parity", "bytesize", "stopbits")
MAX_LINE = 512  # characters; a longer run without a line ending is garbage
_PRINTABLE = bytes(range(32, 127)) + b"\t"
_DROP = bytes(b for b in range(256) if b not in _PRINTABLE)
_LINE_BREAK = re.compile(rb"\r\n|\r|\n")


class DeviceReset(MeasurementError):
    """The device printed its start-up banner: it was reset and must be initialised again."""


class PointLost(TargetLost):
    """A reply whose status says target lost, with the id ``tp`` of the tracked point it is about."""

    def __init__(self, message: str, tp: int) -> None:
        super().__init__(message)
        self.tp = tp


@dataclass(frozen=True)
class InitCommand:
    send: str
    expect: re.Pattern[str] | None = None


@dataclass(frozen=True)
class Profile:
    """A validated profile (see the module docstring). ``scale`` converts device units to metres."""

    name: str
    description: str
    path: str
    mode: str
    line_ending: str
    serial: dict[str, Any]
    init: tuple[InitCommand, ...]
    identify: tuple[str, re.Pattern[str]] | None
    trigger: str | None
    start: str | None
    stop: str | None
    pattern: re.Pattern[str] | None
    delimiter: str | None
    fields: tuple[str | None, ...]
    scale: float
    units: str
    max_abs: float
    sigma: float | None
    checksum: str | None
    checksum_covers: str
    status_ok: frozenset[str]
    status_lost: frozenset[str]
    errors: tuple[tuple[re.Pattern[str], str], ...]
    reset: re.Pattern[str] | None
    simulation: dict[str, Any] = field(default_factory=dict)
    points: int = 1
    period: float | None = None  # s between streamed lines (device clock), when the profile states it

    def has_field(self, name: str) -> bool:
        """True if replies carry field ``name`` (a ``fields`` entry or a named group of the pattern)."""
        return name in self.fields or (self.pattern is not None and name in self.pattern.groupindex)

    @property
    def has_status(self) -> bool:
        return "status" in self.fields or (self.pattern is not None and "status" in self.pattern.groupindex)


@dataclass(frozen=True)
class ParsedLine:
    """One parsed reading: ``position`` (x, y, z) in metres, ``status`` word, ``sigma`` metres or None, ``tp`` the
    tracked point's id when the reply has a ``tp`` field (else None), ``t`` the device's time of the reading (s
    on its own clock) and ``seq`` the line's sequence number when the reply has them (else None)."""

    position: tuple[float, float, float]
    status: str = "ok"
    sigma: float | None = None
    tp: int | None = None
    t: float | None = None
    seq: int | None = None


def profile_names() -> list[str]:
    """Names of the bundled profiles (file stems in ``config/trackers/``), sorted."""
    return sorted(p.stem for p in TRACKERS_DIR.glob("*.yaml"))


def load_profile(name_or_path: str | Path) -> Profile:
    """A bundled profile by name, or a YAML file by path; ConfigError (one line: file, key, expected)."""
    path = config_file(name_or_path, TRACKERS_DIR, "tracker profile", profile_names)
    return profile_from_dict(read_yaml(path), path)


def _regex(src: Any, key: str, value: Any) -> re.Pattern[str]:
    if not isinstance(value, str) or not value:
        raise ConfigError(src, key, "a regular expression (string)", got(value))
    try:
        return re.compile(value)
    except re.error as exc:
        raise ConfigError(src, key, f"a valid regular expression ({exc})", got(value)) from None


def _text(src: Any, key: str, value: Any, optional: bool = True) -> str | None:
    if value is None and optional:
        return None
    if not isinstance(value, str) or not value.strip() or any(c in value for c in "\r\n"):
        raise ConfigError(src, key, "a non-empty one-line string" + (" (or null)" if optional else ""), got(value))
    return value


def _strings(src: Any, key: str, value: Any) -> frozenset[str]:
    if value is None:
        return frozenset()
    if not isinstance(value, list) or not all(isinstance(v, str | int) and not isinstance(v, bool) for v in value):
        raise ConfigError(src, key, "a list of status values (strings)", got(value))
    return frozenset(str(v) for v in value)


def profile_from_dict(data: Any, source: str | Path = "<dict>") -> Profile:
    """Validate a profile mapping; ConfigError naming ``source`` and the key."""
    src = source
    if not isinstance(data, dict):
        raise ConfigError(src, None, "a mapping (a tracker profile)", got(data))
    for key in data:
        if key not in KEYS:
            raise ConfigError(src, str(key), f"only the keys {', '.join(KEYS)}", "an unknown key")
    for key in ("schema", "name", "mode", "response", "units"):
        if key not in data:
            raise ConfigError(src, key, "this key (required)", "nothing (missing key)")
    check_schema(src, data["schema"], SCHEMA_VERSION)
    name = _text(src, "name", data["name"], optional=False) or ""
    if isinstance(source, Path) and source.stem.lower() != name.lower():
        raise ConfigError(src, "name", f"the file's stem {source.stem!r}", got(name))
    mode = data["mode"]
    if mode not in ("polled", "streaming"):
        raise ConfigError(src, "mode", "polled or streaming", got(mode))
    trigger = _text(src, "trigger", data.get("trigger"))
    if mode == "polled" and trigger is None:
        raise ConfigError(src, "trigger", "the command that triggers one measurement (mode polled)", "nothing")
    if mode == "streaming" and trigger is not None:
        raise ConfigError(src, "trigger", "no trigger in mode streaming (use start/stop)", got(trigger))
    eol = data.get("line_ending", "\r\n")
    if eol not in ("\r\n", "\n", "\r"):
        raise ConfigError(src, "line_ending", "one of \"\\r\\n\", \"\\n\", \"\\r\"", got(eol))
    serial = data.get("serial") or {}
    if not isinstance(serial, dict):
        raise ConfigError(src, "serial", f"a mapping with the keys {', '.join(SERIAL_KEYS)}", got(serial))
    for key, value in serial.items():
        if key not in SERIAL_KEYS:
            raise ConfigError(src, f"serial.{key}", f"only the keys {', '.join(SERIAL_KEYS)}", "an unknown key")
        if key == "parity" and value not in ("N", "E", "O", "M", "S"):
            raise ConfigError(src, "serial.parity", "N, E, O, M or S", got(value))
        if key != "parity" and (isinstance(value, bool) or not isinstance(value, int | float) or value <= 0):
            raise ConfigError(src, f"serial.{key}", "a number > 0", got(value))
    init = []
    raw_init = data.get("init") or []
    if not isinstance(raw_init, list):
        raise ConfigError(src, "init", "a list of commands (strings or {send, expect})", got(raw_init))
    for i, item in enumerate(raw_init):
        if isinstance(item, dict):
            extra = set(item) - {"send", "expect"}
            if extra or "send" not in item:
                raise ConfigError(src, f"init[{i}]", "a string or a mapping {send, expect}", got(item))
            expect = None if item.get("expect") is None else _regex(src, f"init[{i}].expect", item["expect"])
            init.append(InitCommand(_text(src, f"init[{i}].send", item["send"], False) or "", expect))
        else:
            init.append(InitCommand(_text(src, f"init[{i}]", item, False) or ""))
    identify = None
    if data.get("identify") is not None:
        ident = data["identify"]
        if not isinstance(ident, dict) or set(ident) != {"send", "pattern"}:
            raise ConfigError(src, "identify", "a mapping {send, pattern} (pattern groups model, serial, firmware)",
                              got(ident))
        identify = (_text(src, "identify.send", ident["send"], False) or "",
                    _regex(src, "identify.pattern", ident["pattern"]))
    response = data["response"]
    pattern, delimiter, fields = None, None, ()
    if not isinstance(response, dict) or set(response) not in ({"pattern"}, {"fields"}, {"fields", "delimiter"}):
        raise ConfigError(src, "response", "a mapping {pattern} or {delimiter, fields}", got(response))
    if "pattern" in response:
        pattern = _regex(src, "response.pattern", response["pattern"])
        missing = [g for g in ("x", "y", "z") if g not in pattern.groupindex]
        if missing:
            raise ConfigError(src, "response.pattern", "named groups x, y and z", f"no group {missing[0]!r}")
        names = tuple(pattern.groupindex)
    else:
        delimiter = response.get("delimiter")
        if delimiter is not None and (not isinstance(delimiter, str) or not delimiter):
            raise ConfigError(src, "response.delimiter", "a non-empty string (or null: white space)", got(delimiter))
        fields = response["fields"]
        ok = isinstance(fields, list) and all(f is None or f in FIELDS for f in fields)
        named = [f for f in fields if f is not None] if ok else []
        if not ok or len(named) != len(set(named)) or not {"x", "y", "z"} <= set(named):
            raise ConfigError(src, "response.fields", f"a list of distinct field names ({', '.join(FIELDS)}) or "
                              "null, with x, y and z", got(fields))
        fields, names = tuple(fields), tuple(named)
    points = data.get("points", 1)
    if isinstance(points, bool) or not isinstance(points, int) or points < 1:
        raise ConfigError(src, "points", "an integer >= 1 (tracked points per trigger)", got(points))
    if points > 1 and mode != "polled":
        raise ConfigError(src, "points", "1 in mode streaming (several points per reply need a trigger)", got(points))
    if points > 1 and "tp" not in names:
        raise ConfigError(src, "response", "a tp field (the tracked point's id) with points > 1", "none")
    units = data["units"]
    if units not in UNITS:
        raise ConfigError(src, "units", f"one of {', '.join(UNITS)}", got(units))
    max_abs = data.get("max_abs", 1000.0)
    if isinstance(max_abs, bool) or not isinstance(max_abs, int | float) or not 0 < max_abs < math.inf:
        raise ConfigError(src, "max_abs", "a number > 0 (m)", got(max_abs))
    sigma = data.get("sigma")
    if sigma is not None and (isinstance(sigma, bool) or not isinstance(sigma, int | float) or not sigma > 0):
        raise ConfigError(src, "sigma", "a number > 0 (m per axis) or null", got(sigma))
    checksum, covers = None, "line"
    if data.get("checksum") is not None:
        cs = data["checksum"]
        if not isinstance(cs, dict) or "algorithm" not in cs or set(cs) - {"algorithm", "covers"}:
            raise ConfigError(src, "checksum", "a mapping {algorithm: xor|sum8, covers: payload|line}", got(cs))
        checksum, covers = cs["algorithm"], cs.get("covers", "line")
        if checksum not in ("xor", "sum8"):
            raise ConfigError(src, "checksum.algorithm", "xor or sum8", got(checksum))
        if covers not in ("payload", "line"):
            raise ConfigError(src, "checksum.covers", "payload or line", got(covers))
        if "checksum" not in names:
            raise ConfigError(src, "response", "a checksum field (the profile has a checksum)", "none")
        if covers == "payload" and (pattern is None or "payload" not in pattern.groupindex):
            raise ConfigError(src, "checksum.covers", "a response pattern with a group 'payload'", "none")
    elif "checksum" in names:
        raise ConfigError(src, "checksum", "a checksum algorithm (the response has a checksum field)", "nothing")
    status = data.get("status") or {}
    if not isinstance(status, dict) or set(status) - {"ok", "target_lost"}:
        raise ConfigError(src, "status", "a mapping {ok: [...], target_lost: [...]}", got(status))
    if ("status" in names) != bool(status.get("ok")):
        raise ConfigError(src, "status.ok", "the ok values of the response's status field (both or neither)",
                          got(status.get("ok")))
    errors = []
    raw_errors = data.get("errors") or []
    if not isinstance(raw_errors, list):
        raise ConfigError(src, "errors", "a list of {pattern, kind: error|target_lost}", got(raw_errors))
    for i, item in enumerate(raw_errors):
        if not isinstance(item, dict) or set(item) - {"pattern", "kind"} or "pattern" not in item:
            raise ConfigError(src, f"errors[{i}]", "a mapping {pattern, kind: error|target_lost}", got(item))
        kind = item.get("kind", "error")
        if kind not in ("error", "target_lost"):
            raise ConfigError(src, f"errors[{i}].kind", "error or target_lost", got(kind))
        errors.append((_regex(src, f"errors[{i}].pattern", item["pattern"]), kind))
    reset = None if data.get("reset") is None else _regex(src, "reset", data["reset"])
    period = data.get("period")
    if period is not None and (isinstance(period, bool) or not isinstance(period, int | float) or not period > 0
                               or mode != "streaming"):
        raise ConfigError(src, "period", "a number > 0 (s between streamed lines; mode streaming only)", got(period))
    simulation = data.get("simulation") or {}
    if not isinstance(simulation, dict):
        raise ConfigError(src, "simulation", "a mapping (how the simulated device formats replies)", got(simulation))
    return Profile(
        name=name, description=str(data.get("description") or ""), path=str(source), mode=mode, line_ending=eol,
        serial=dict(serial), init=tuple(init), identify=identify, trigger=trigger,
        start=_text(src, "start", data.get("start")), stop=_text(src, "stop", data.get("stop")),
        pattern=pattern, delimiter=delimiter, fields=fields, scale=UNITS[units], units=units,
        max_abs=float(max_abs), sigma=None if sigma is None else float(sigma), checksum=checksum,
        checksum_covers=covers, status_ok=_strings(src, "status.ok", status.get("ok")),
        status_lost=_strings(src, "status.target_lost", status.get("target_lost")), errors=tuple(errors),
        reset=reset, simulation=dict(simulation), points=points, period=None if period is None else float(period))


def checksum_of(text: str, algorithm: str) -> str:
    """Two upper-case hex digits: XOR, or sum mod 256, of the ASCII codes of ``text``."""
    data = text.encode("latin-1", "replace")
    value = 0
    if algorithm == "xor":
        for b in data:
            value ^= b
    else:
        value = sum(data) & 0xFF
    return f"{value:02X}"


class LineSplitter:
    """Bytes in, complete lines out (str, printable ASCII only, non-empty). Robust to partial lines (kept until
    their end arrives), noise bytes (dropped), mixed line endings and over-long runs (dropped, counted).

    ``resync()`` drops everything up to the next line ending: after flushing a stream, the first fragment
    is the tail of a line and must not be read as one.
    """

    def __init__(self, max_line: int = MAX_LINE) -> None:
        self.max_line = max_line
        self._buffer = b""
        self._skip = False
        self.dropped = 0  # over-long or resync fragments thrown away

    def resync(self) -> None:
        self._buffer, self._skip = b"", True

    def clear(self) -> None:
        self._buffer, self._skip = b"", False

    def feed(self, data: bytes) -> list[str]:
        parts = _LINE_BREAK.split(self._buffer + data)
        self._buffer = parts.pop()
        if len(self._buffer) > self.max_line:
            self._buffer, self._skip = b"", True
            self.dropped += 1
        lines = []
        for raw in parts:
            if self._skip:
                self._skip = False
                self.dropped += 1
                continue
            if len(raw) > self.max_line:
                self.dropped += 1
                continue
            text = raw.translate(None, _DROP).decode("ascii").strip()
            if text:
                lines.append(text)
        return lines


def _number(profile: Profile, line: str, name: str, text: str | None) -> float:
    try:
        value = float(text) if text is not None else math.nan
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise BadReading(f"{profile.name}: unparseable {name} value {text!r} in reply {_short(line)}")
    return value


def _short(line: str) -> str:
    return repr(line if len(line) <= 60 else line[:57] + "...")


def classify(profile: Profile, line: str) -> None:
    """Raise DeviceReset / TargetLost / BadReading if ``line`` is the reset banner or an error reply."""
    if profile.reset is not None and profile.reset.search(line):
        raise DeviceReset(f"{profile.name}: the device was reset (it sent {_short(line)})")
    for pattern, kind in profile.errors:
        if pattern.search(line):
            if kind == "target_lost":
                raise TargetLost(f"{profile.name}: target lost (device reply {_short(line)})")
            raise BadReading(f"{profile.name}: the device replied with an error: {_short(line)}")


def parse_line(profile: Profile, line: str) -> ParsedLine:
    """One reply line -> ParsedLine (metres); raises BadReading, TargetLost or DeviceReset (see module doc)."""
    classify(profile, line)
    if profile.pattern is not None:
        match = profile.pattern.search(line)
        if match is None:
            raise BadReading(f"{profile.name}: reply {_short(line)} does not match the response pattern")
        values = match.groupdict()
        covered = None
        if profile.checksum is not None:
            covered = match.group("payload") if profile.checksum_covers == "payload" else \
                line[:match.start("checksum")]
    else:
        parts = line.split(profile.delimiter) if profile.delimiter is not None else line.split()
        if len(parts) != len(profile.fields):
            raise BadReading(f"{profile.name}: reply {_short(line)} has {len(parts)} fields, expected "
                             f"{len(profile.fields)}")
        values = {f: p.strip() for f, p in zip(profile.fields, parts, strict=True) if f is not None}
        covered = None
        if profile.checksum is not None:
            index = profile.fields.index("checksum")
            sep = profile.delimiter if profile.delimiter is not None else " "
            covered = sep.join(parts[:index]) + (sep if index else "")
    if profile.checksum is not None:
        given = (values.get("checksum") or "").upper()
        expected = checksum_of(covered or "", profile.checksum)
        if given != expected:
            raise BadReading(f"{profile.name}: checksum mismatch in reply {_short(line)} (got {given!r}, computed "
                             f"{expected!r})")
    status = "ok"
    tp = None
    if values.get("tp") is not None:
        text = values["tp"].strip()
        if not text.isdigit() or int(text) < 1:
            raise BadReading(f"{profile.name}: bad tracked point id {text!r} in reply {_short(line)}")
        tp = int(text)
    if profile.has_status:
        word = values.get("status")
        if word in profile.status_lost:
            if tp is not None:
                raise PointLost(f"{profile.name}: tracked point {tp} out of sight (status {word!r})", tp)
            raise TargetLost(f"{profile.name}: target lost (status {word!r})")
        if word not in profile.status_ok:
            raise BadReading(f"{profile.name}: unknown status {word!r} in reply {_short(line)}")
    xyz = [_number(profile, line, k, values.get(k)) * profile.scale for k in ("x", "y", "z")]
    if max(abs(v) for v in xyz) > profile.max_abs:
        raise BadReading(f"{profile.name}: reply {_short(line)} is out of range (|coordinate| > "
                         f"{profile.max_abs:g} m)")
    sigma = profile.sigma
    if values.get("sigma") is not None:
        sigma = _number(profile, line, "sigma", values["sigma"]) * profile.scale
        if sigma < 0:
            raise BadReading(f"{profile.name}: negative sigma in reply {_short(line)}")
    t = None if values.get("t") is None else _number(profile, line, "t", values["t"])
    seq = None
    if values.get("seq") is not None:
        if not values["seq"].strip().isdigit():
            raise BadReading(f"{profile.name}: bad sequence number {values['seq']!r} in reply {_short(line)}")
        seq = int(values["seq"])
    return ParsedLine((xyz[0], xyz[1], xyz[2]), status, sigma, tp, t, seq)
