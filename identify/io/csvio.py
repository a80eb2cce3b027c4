"""Measurement CSV (README.md, File contracts): read (with one-line errors for bad input) and write.

Format: UTF-8, comma separated, one header row; ``#`` lines are comments, ``# joints: RRRRRR`` and
``# units: m, rad`` (or ``mm``) and ``# coupling: [[...]]`` (row-major n x n, DH values = C · readings) carry
metadata. Columns ``sweep,joint,q1..qN,x,y,z`` plus optional ``sigma``, ``role`` (fit/check) and ``tp``
(tracked point id); ``t`` (the sample's time, s) is kept; any other column (``step``...) is ignored.
Full pose (optional): ``rx,ry,rz`` the measured target frame's orientation in the device frame (rotation vector,
rad; x, y, z is then the frame's origin) and ``sigma_r`` its standard uncertainty per axis (rad); rows without an
orientation leave the four empty.
The device: ``# sensor: fixed | flange`` (``flange``: an eye-in-hand camera, the rows are the fixed board's pose in
its frame; identify/sensors/flange.py) and ``# scale_sigma: U | unknown`` (the relative standard uncertainty of the
device's length scale; identify/sensors/scale.py).
Continuous motion: ``# streamed: 3, 4`` lists the sweeps recorded while the robot moved (their joint values
interpolated from the joint stream at robot time ``t + clock_offset``), ``# clock_offset: 0.0123`` (s).
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from common.errors import InputError
from identify.estimator.measurements import Measurements, looks_like_millimetres
from identify.sensors.metadata import format_scale_sigma, parse_scale_sigma, parse_sensor
from kinematics.dh import check_joint_types
from kinematics.joint_errors import Coupling

UNITS = {"m": 1.0, "mm": 1e-3}
ROTATION_COLUMNS = ("rx", "ry", "rz")
_Q_COLUMN = re.compile(r"^q(\d+)$")


@dataclass
class CsvContent:
    """A parsed file: measurements plus the comment metadata (``key: value`` lines) and notes."""

    measurements: Measurements
    metadata: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def read_measurements(path: str | Path, joints: str | None = None, units: str | None = None) -> CsvContent:
    """Read a measurement CSV. ``joints`` (e.g. ``RRPR``) overrides the file's ``# joints:`` line;
    ``units`` (``m`` or ``mm``) gives the unit of x, y, z and sigma. Raises InputError (one line)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror})") from None
    if not raw.strip():
        raise InputError(f"{path}: the file is empty")
    if b"\x00" in raw:
        raise InputError(f"{path}: binary data, not a measurement CSV")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not UTF-8 text (byte {exc.start}); not a measurement CSV") from None
    what = _other_file(text)
    if what is not None:
        raise InputError(f"{path}: {what}")
    try:
        return parse_measurements(text.splitlines(), joints, units)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None


def _other_file(text: str) -> str | None:
    """What a YAML file of the product's given as measurements is, and where it goes (None: not one of them)."""
    first = next((line for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")), "")
    if not re.match(r"[A-Za-z_][\w-]*:(\s|$)", first):  # a CSV header row, not a YAML mapping
        return None
    import yaml

    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError:
        return None
    if not isinstance(doc, dict):
        return None
    if "joints" in doc and ("verdict" in doc or "base" in doc):
        return ("this is a result (a calibration, identify --out), not measurements: identify reads a measurement "
                "CSV or a session; a result goes to identify compensate, check or compare, or acquire verify")
    if "runs" in doc and "verdict" in doc:
        return "this is a verification summary (acquire verify), not measurements: show it with identify --verification"
    if "dh" in doc and "joints" in doc:
        return "this is a robot model, not measurements: give it with --robot"
    return "a YAML file, not a measurement CSV (sweep,joint,q1..qN,x,y,z; README.md, File contracts)"


def parse_measurements(lines: Iterable[str], joints: str | None = None, units: str | None = None) -> CsvContent:
    """Parse CSV lines (see :func:`read_measurements`); errors name the line number."""
    metadata: dict[str, str] = {}
    numbered: list[tuple[int, str]] = []
    for number, line in enumerate(lines, start=1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            key, sep, value = stripped.lstrip("#").partition(":")
            if sep:
                metadata[key.strip().lower()] = value.strip()
            continue
        numbered.append((number, line))
    if not numbered:
        raise InputError("no header row and no data")
    notes: list[str] = []
    types = _joint_types(joints, metadata, notes)
    scale = _unit_scale(units, metadata)
    header_line, header = numbered[0][0], [h.strip() for h in next(csv.reader([numbered[0][1]]))]
    columns = _columns(header, types, header_line, notes)
    rows = list(csv.reader([text for _, text in numbered[1:]]))
    if not rows:
        raise InputError("the header has no data rows below it")
    n = len(types)
    m = len(rows)
    q = np.empty((m, n))
    points = np.empty((m, 3))
    sweep = np.empty(m, dtype=np.int64)
    joint = np.empty(m, dtype=np.int64)
    sigma = np.empty(m) if "sigma" in columns else None
    check = np.zeros(m, dtype=bool)
    tp = np.ones(m, dtype=np.int64)
    t = np.full(m, np.nan) if "t" in columns else None
    rotvec = np.full((m, 3), np.nan) if "rx" in columns else None
    sigma_r = np.full(m, np.nan) if "sigma_r" in columns else None
    line_numbers = np.array([number for number, _ in numbered[1:]], dtype=np.int64)
    fast = _parse_fast(rows, header, columns, n)
    if fast is not None:  # every field well formed: vectorised (the loop below names the first bad field)
        sweep, joint, q, points, fast_sigma, fast_tp, t, fast_check, rotvec, sigma_r = fast
        points = points * scale
        sigma = None if fast_sigma is None else fast_sigma * scale
        tp = np.ones(m, dtype=np.int64) if fast_tp is None else fast_tp
        check = np.zeros(m, dtype=bool) if fast_check is None else fast_check
        rows = []  # nothing left for the checking loop
    for k, fields in enumerate(rows):
        line = int(line_numbers[k])
        if len(fields) != len(header):
            raise InputError(f"line {line}: {len(fields)} fields, the header has {len(header)}")
        sweep[k] = _integer(fields, columns["sweep"], "sweep", line)
        joint[k] = _integer(fields, columns["joint"], "joint", line)
        for j in range(n):
            q[k, j] = _number(fields, columns[f"q{j + 1}"], f"q{j + 1}", line, allow_empty=True)
        for axis, name in enumerate("xyz"):
            points[k, axis] = _number(fields, columns[name], name, line) * scale
        if sigma is not None:
            sigma[k] = _number(fields, columns["sigma"], "sigma", line) * scale
        if "role" in columns:
            role = fields[columns["role"]].strip().lower()
            if role not in ("fit", "check"):
                raise InputError(f"line {line}: role must be 'fit' or 'check', got {role!r}")
            check[k] = role == "check"
        if t is not None:
            t[k] = _number(fields, columns["t"], "t", line, allow_empty=True)
        if "tp" in columns:
            tp[k] = _integer(fields, columns["tp"], "tp", line)
            if tp[k] < 1:
                raise InputError(f"line {line}: tp must be a positive integer (the tracked point's id), got {tp[k]}")
        if rotvec is not None:
            for axis, name in enumerate(ROTATION_COLUMNS):
                rotvec[k, axis] = _number(fields, columns[name], name, line, allow_empty=True)
        if sigma_r is not None:
            sigma_r[k] = _number(fields, columns["sigma_r"], "sigma_r", line, allow_empty=True)
    if scale == 1.0 and looks_like_millimetres(points):
        peak = float(np.max(np.abs(points)))
        raise InputError(f"x, y, z reach {peak:g}: these look like millimetres; pass --units mm "
                         "(the CSV contract uses metres)")
    coupling = parse_coupling(metadata["coupling"], n) if "coupling" in metadata else None
    streamed, offset = _streams(metadata, sweep, t)
    sensor = parse_sensor(metadata["sensor"]) if "sensor" in metadata else "fixed"
    scale = parse_scale_sigma(metadata["scale_sigma"]) if "scale_sigma" in metadata else None
    meas = Measurements(types, q, points, sweep, joint, sigma, check, line_numbers, has_role="role" in columns,
                        tp=tp, coupling=coupling, t=t, streamed=streamed, clock_offset=offset, rotvec=rotvec,
                        sigma_r=sigma_r, sensor=sensor, scale_sigma=scale)
    return CsvContent(meas, metadata, notes)


def _parse_fast(rows: list[list[str]], header: list[str], columns: dict[str, int], n: int) -> tuple | None:
    """The numeric columns of ``rows`` parsed at once, or None when any field would need a message (a
    missing or malformed value, an empty reading, a bad role or tp): then the per-row loop reports it."""
    if any(len(fields) != len(header) for fields in rows):
        return None

    def floats(name: str) -> np.ndarray:
        index = columns[name]
        values = np.array([fields[index] for fields in rows], dtype=float)
        if not np.all(np.isfinite(values)):
            raise ValueError(name)
        return values

    def optional(name: str) -> np.ndarray:  # empty fields are NaN; a written "nan" or "inf" is refused
        texts = [fields[columns[name]].strip() for fields in rows]
        values = np.array([text or "nan" for text in texts], dtype=float)
        given = np.array([bool(text) for text in texts])
        if not np.all(np.isfinite(values[given])):
            raise ValueError(name)
        return values

    def integers(name: str) -> np.ndarray:
        index = columns[name]
        return np.array([int(fields[index]) for fields in rows], dtype=np.int64)

    try:
        sweep, joint = integers("sweep"), integers("joint")
        q = np.column_stack([floats(f"q{j}") for j in range(1, n + 1)])
        points = np.column_stack([floats(axis) for axis in "xyz"])
        sigma = floats("sigma") if "sigma" in columns else None
        tp = integers("tp") if "tp" in columns else None
        t = None
        if "t" in columns:  # a row without a time (a stop-and-go step of an old session) is NaN
            texts = [fields[columns["t"]].strip() for fields in rows]
            given = np.array([bool(text) for text in texts])
            t = np.array([text or "nan" for text in texts], dtype=float)
            if not np.all(np.isfinite(t[given])):  # a written "nan" or "inf" is refused, as by the loop
                return None
    except ValueError:
        return None
    if tp is not None and np.any(tp < 1):
        return None
    rotvec = np.column_stack([optional(name) for name in ROTATION_COLUMNS]) if "rx" in columns else None
    sigma_r = optional("sigma_r") if "sigma_r" in columns else None
    check = None
    if "role" in columns:
        roles = np.array([fields[columns["role"]].strip().lower() for fields in rows])
        if not set(roles.tolist()) <= {"fit", "check"}:
            return None
        check = roles == "check"
    return sweep, joint, q, points, sigma, tp, t, check, rotvec, sigma_r


def _streams(metadata: dict[str, str], sweep: np.ndarray, t: np.ndarray | None) -> tuple[np.ndarray, float]:
    """Rows of the ``# streamed:`` sweeps, and the ``# clock_offset:`` (s)."""
    streamed = np.zeros(len(sweep), dtype=bool)
    text = metadata.get("streamed", "").strip()
    if text:
        try:
            ids = [int(part) for part in text.replace(",", " ").split()]
        except ValueError:
            raise InputError(f"'# streamed:' must list sweep ids like '3, 4', got {text!r}") from None
        unknown = sorted(set(ids) - set(sweep.tolist()))
        if unknown:
            raise InputError(f"'# streamed:' names sweep(s) {unknown} that have no rows")
        if t is None:
            raise InputError("'# streamed:' sweeps need a t column (the sample's time, s)")
        streamed = np.isin(sweep, ids)
        if np.any(np.isnan(t[streamed])):
            raise InputError("every row of a '# streamed:' sweep needs its time t (s)")
    try:
        offset = float(metadata.get("clock_offset", "0").split()[0])
    except (ValueError, IndexError):
        raise InputError(f"'# clock_offset:' must be a number of seconds, got {metadata['clock_offset']!r}") from None
    if not math.isfinite(offset):
        raise InputError("'# clock_offset:' must be a finite number of seconds")
    return streamed, offset


def parse_coupling(text: str, n: int) -> Coupling:
    """The ``# coupling:`` metadata: a row-major n x n matrix ``[[...], ...]`` (DH values = C · readings)."""
    try:
        value = yaml.safe_load(text)
        matrix = np.array(value, dtype=float)
    except (yaml.YAMLError, TypeError, ValueError):
        raise InputError(f"'# coupling:' must be a row-major {n}x{n} matrix like [[1, 0], [0, 1]], "
                         f"got {text!r}") from None
    if matrix.shape != (n, n):
        raise InputError(f"'# coupling:' must be a {n}x{n} matrix for {n} joints, got shape {matrix.shape}")
    try:
        return Coupling(matrix, np.zeros(n))
    except ValueError as exc:
        raise InputError(f"'# coupling:' {exc}") from None


def _joint_types(joints: str | None, metadata: dict[str, str], notes: list[str]) -> str:
    declared = metadata.get("joints")
    try:
        from_file = check_joint_types(declared) if declared else None
        given = check_joint_types(joints) if joints else None
    except ValueError as exc:
        raise InputError(str(exc)) from None
    if given and from_file and given != from_file:
        notes.append(f"--joints {given} overrides the file's '# joints: {from_file}'")
    types = given or from_file
    if not types:
        raise InputError("joint types unknown: add a '# joints: RRRRRR' comment line or pass --joints")
    return types


def _unit_scale(units: str | None, metadata: dict[str, str]) -> float:
    declared = metadata.get("units", "")
    name = units or declared.split(",")[0].strip().lower() or "m"
    if name not in UNITS:
        raise InputError(f"unknown position unit {name!r}; expected one of {', '.join(UNITS)}")
    return UNITS[name]


def _columns(header: list[str], types: str, line: int, notes: list[str]) -> dict[str, int]:
    n = len(types)
    seen: dict[str, int] = {}
    for index, name in enumerate(header):
        if name in seen:
            raise InputError(f"line {line}: column {name!r} appears twice")
        seen[name] = index
    q_numbers = sorted(int(m.group(1)) for name in header if (m := _Q_COLUMN.match(name)))
    if q_numbers and q_numbers != list(range(1, len(q_numbers) + 1)):
        raise InputError(f"line {line}: joint columns must be q1..qN without gaps, got "
                         f"{', '.join(f'q{k}' for k in q_numbers)}")
    if q_numbers and len(q_numbers) != n:
        raise InputError(f"inconsistent joint counts: joint types {types} give {n} joints but the header has "
                         f"q1..q{len(q_numbers)}")
    required = ["sweep", "joint", *(f"q{j}" for j in range(1, n + 1)), "x", "y", "z"]
    missing = [name for name in required if name not in seen]
    if missing:
        separator = next((c for c in (";", "\t") if any(c in name for name in header)), None)
        hint = (f" (the header is separated by {'semicolons' if separator == ';' else 'tabs'}: the file must be "
                "comma-separated, with a decimal point)" if separator else "")
        raise InputError(f"line {line}: missing column(s) {', '.join(missing)}; expected "
                         f"sweep,joint,q1..q{n},x,y,z{hint}")
    rotation = [name for name in (*ROTATION_COLUMNS, "sigma_r") if name in seen]
    if rotation and not set(ROTATION_COLUMNS) <= set(rotation):
        raise InputError(f"line {line}: an orientation needs the columns rx, ry, rz together (and sigma_r), got "
                         f"{', '.join(rotation)}")
    ignored = [name for name in header if name not in (*required, "sigma", "role", "tp", "t", *rotation)]
    if ignored:
        notes.append(f"ignored column(s): {', '.join(ignored)}")
    return seen


def _number(fields: list[str], index: int, name: str, line: int, allow_empty: bool = False) -> float:
    text = fields[index].strip()
    if not text:
        if allow_empty:
            return math.nan
        raise InputError(f"line {line}: column {name} is empty")
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"line {line}: column {name}: {text!r} is not a number") from None
    if not math.isfinite(value):
        raise InputError(f"line {line}: column {name}: {text!r} is not a finite number")
    return value


def _integer(fields: list[str], index: int, name: str, line: int) -> int:
    text = fields[index].strip()
    try:
        return int(text)
    except ValueError:
        raise InputError(f"line {line}: column {name}: {text!r} is not an integer") from None


def format_measurements(meas: Measurements, metadata: dict[str, str] | None = None) -> str:
    """The CSV text of ``meas`` (metres, radians), with ``# joints:``/``# units:`` and ``metadata``."""
    out = io.StringIO()
    out.write(f"# joints: {meas.joint_types}\n# units: m, rad\n")
    if meas.coupling is not None and not meas.coupling.is_identity:
        if np.any(meas.coupling.offset):
            raise ValueError("the CSV coupling has no offset: add it to the readings before writing")
        out.write(f"# coupling: {meas.coupling.matrix.tolist()}\n")
    if meas.has_streams:
        out.write(f"# streamed: {', '.join(str(s) for s in np.unique(meas.sweep[meas.streamed]))}\n")
        out.write(f"# clock_offset: {meas.clock_offset!r}\n")
    if meas.sensor != "fixed":
        out.write(f"# sensor: {meas.sensor}\n")
    if meas.scale_sigma is not None:
        out.write(f"# scale_sigma: {format_scale_sigma(meas.scale_sigma)}\n")
    for key, value in (metadata or {}).items():
        if key not in ("coupling", "streamed", "clock_offset", "sensor", "scale_sigma"):
            out.write(f"# {key}: {value}\n")
    n = meas.n_joints
    header = ["sweep", "joint", *(f"q{j}" for j in range(1, n + 1)), "x", "y", "z"]
    if meas.sigma is not None:
        header.append("sigma")
    if meas.has_role or np.any(meas.check):
        header.append("role")
    several = bool(np.any(meas.tp != 1))
    if several:
        header.append("tp")
    if meas.t is not None:
        header.append("t")
    oriented = meas.rotvec is not None and bool(np.any(meas.oriented))
    if oriented:
        header += [*ROTATION_COLUMNS, "sigma_r"]
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(header)
    for k in range(len(meas)):
        row = [str(int(meas.sweep[k])), str(int(meas.joint[k]))]
        row += ["" if math.isnan(v) else repr(float(v)) for v in meas.q[k]]
        row += [repr(float(v)) for v in meas.points[k]]
        if meas.sigma is not None:
            row.append(repr(float(meas.sigma[k])))
        if "role" in header:
            row.append("check" if meas.check[k] else "fit")
        if several:
            row.append(str(int(meas.tp[k])))
        if meas.t is not None:
            row.append("" if math.isnan(meas.t[k]) else repr(float(meas.t[k])))
        if oriented:
            given = bool(meas.oriented[k])
            row += [repr(float(v)) if given else "" for v in meas.rotvec[k]]
            row.append(repr(float(meas.sigma_r[k])) if given else "")
        writer.writerow(row)
    return out.getvalue()
