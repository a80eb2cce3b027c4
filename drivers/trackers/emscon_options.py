"""The options of an ``emscon:`` tracker (drivers/trackers/emscon.py), checked without connecting, and what the
tracker will be asked to do, said before anything connects (``acquire --dry-run``).

Options (spec ``?key=value&...`` or the site file's ``tracker.settings``; the spec wins): ``timeout`` (s per
answer, default 3), ``init_timeout`` (s, default 120), ``retries`` (default 2), ``meas_time`` (s per stationary
measurement, default 1), ``reflector`` (name or id), ``initialize`` (``auto`` or ``always``), ``probe`` (``none``
or ``6dof``: a 6-DoF probe's full poses), ``temperature`` (°C), ``pressure`` (mbar), ``humidity`` (%RH): all three or
none, ``trace`` (a file). ``emscon:sim`` also takes ``noise`` (m per axis, default 5e-5), ``angle_noise`` (rad per
axis of the probe's orientation, default 2e-5), ``seed`` (default the robot's) and ``fault``
(drivers/trackers/emscon_sim.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from drivers.errors import SpecError
from drivers.spec import TrackerSpec

DEFAULT_PORT = 700
OPTIONS = ("timeout", "init_timeout", "retries", "meas_time", "reflector", "initialize", "probe", "temperature",
           "pressure", "humidity", "trace")
SIM_OPTIONS = ("noise", "angle_noise", "seed", "fault")  # emscon:sim only
FORM = ("emscon:HOST[:PORT][?timeout=S&init_timeout=S&retries=N&meas_time=S&reflector=NAME|ID&initialize=auto|always"
        "&probe=none|6dof&temperature=C&pressure=MBAR&humidity=PERCENT&trace=FILE]")
PROBES = ("none", "6dof")
#: plausible environment parameters (°C, mbar, %RH): the server refuses others (meteo data out of range)
ENVIRONMENT_RANGE = {"temperature": (-20.0, 60.0), "pressure": (500.0, 1200.0), "humidity": (0.0, 100.0)}
_SECONDS = {"timeout": 3600.0, "init_timeout": 3600.0, "meas_time": 600.0}  # upper limits, s


@dataclass(frozen=True)
class EmsconSettings:
    """The checked options of one ``emscon:`` spec (units in the module doc); ``simulated`` for ``emscon:sim``."""

    host: str
    port: int
    timeout: float = 3.0
    init_timeout: float = 120.0
    retries: int = 2
    meas_time: float = 1.0
    reflector: str | None = None
    initialize: str = "auto"
    probe: bool = False  # probe=6dof: a 6-DoF probe's full poses
    environment: tuple[float, float, float] | None = None
    trace: str | None = None
    simulated: bool = False
    sim: tuple[tuple[str, Any], ...] = ()  # emscon:sim's own options as given

    def simulator(self, spec: TrackerSpec, rig: Any) -> Callable[[], Any]:
        """What starts the simulated server of ``emscon:sim`` on ``rig`` (the mock robot's: required)."""
        if rig is None:
            raise SpecError(f"tracker spec {str(spec)!r}: emscon:sim measures a simulated robot: use it with "
                            "--robot mock:MODEL")
        raw = dict(self.sim)
        try:
            noise = float(raw.get("noise", 5e-5))
            angle_noise = float(raw.get("angle_noise", 2e-5))
            seed = int(str(raw.get("seed", rig.tracker_seed)))
            from drivers.trackers.emscon_server import parse_faults
            from drivers.trackers.emscon_sim import EmsconSimServer

            faults = parse_faults(str(raw["fault"])) if "fault" in raw else ()
            if not (math.isfinite(noise) and noise >= 0 and seed >= 0 and 0 <= angle_noise < 0.1):
                raise ValueError(f"noise={raw.get('noise')} must be >= 0 m, angle_noise={raw.get('angle_noise')} in "
                                 f"[0, 0.1) rad and seed={raw.get('seed')} an integer >= 0")
        except ValueError as exc:
            raise SpecError(f"tracker spec {str(spec)!r}: {' '.join(str(exc).split())}; expected {FORM}") from None
        return lambda: EmsconSimServer(rig, noise=noise, seed=seed, faults=faults, angle_noise=angle_noise)


def parse_settings(spec: TrackerSpec, site: Any = None) -> EmsconSettings:
    """The settings of ``spec`` with the site file's ``tracker.settings`` as defaults; SpecError in one line."""
    if spec.backend != "emscon":
        raise SpecError(f"drivers.trackers.emscon opens emscon:HOST[:PORT] trackers, got {str(spec)!r}; "
                        f"expected {FORM}")
    raw: dict[str, Any] = {k: v for k, v in dict(getattr(site, "tracker_settings", None) or {}).items()
                           if v is not None}
    raw.update(spec.options)
    simulated = spec.target == "sim"
    known = OPTIONS + (SIM_OPTIONS if simulated else ())
    for key in raw:
        if key not in known:
            extra = " (only for emscon:sim)" if key in SIM_OPTIONS else ""
            raise SpecError(f"tracker spec {str(spec)!r}: unknown option {key!r}{extra} (known: {', '.join(known)}); "
                            f"expected {FORM}")

    def bad(key: str, need: str) -> SpecError:
        return SpecError(f"tracker spec {str(spec)!r}: option {key}={raw[key]} must be {need}; expected {FORM}")

    values: dict[str, Any] = {}
    for key, high in _SECONDS.items():
        if key in raw:
            number = _number(raw[key])
            if not 0.0 < number <= high:
                raise bad(key, f"a number of seconds in (0, {high:g}]")
            values[key] = number
    if "retries" in raw:
        if not str(raw["retries"]).isdigit():
            raise bad("retries", "an integer >= 0")
        values["retries"] = int(str(raw["retries"]))
    given = [key for key in ENVIRONMENT_RANGE if key in raw]
    if given and len(given) != 3:
        raise SpecError(f"tracker spec {str(spec)!r}: temperature, pressure and humidity go together (got only "
                        f"{', '.join(given)}); expected {FORM}")
    if given:
        env = []
        for key, (low, high) in ENVIRONMENT_RANGE.items():
            number = _number(raw[key])
            if not low <= number <= high:
                raise bad(key, f"a number in [{low:g}, {high:g}]")
            env.append(number)
        values["environment"] = (env[0], env[1], env[2])
    initialize = str(raw.get("initialize", "auto"))
    if initialize not in ("auto", "always"):
        raise bad("initialize", "auto or always")
    probe = str(raw.get("probe", "none")).lower()
    if probe not in PROBES:
        raise bad("probe", " or ".join(PROBES))
    host, port = ("127.0.0.1", 0) if simulated else spec.address
    return EmsconSettings(host, port or DEFAULT_PORT, initialize=initialize, probe=probe == "6dof",
                          reflector=None if raw.get("reflector") is None else str(raw["reflector"]),
                          trace=None if raw.get("trace") is None else str(raw["trace"]), simulated=simulated,
                          sim=tuple((k, raw[k]) for k in SIM_OPTIONS if k in raw), **values)


def _number(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def describe(spec: TrackerSpec, site: Any, samples_per_step: int, steps: int, sweeps: int = 0,
             stream_rate: float = 0.0) -> list[str]:
    """What the tracker will be asked to do, for the dry run: one line each, no connection made. ``steps``: the
    plan's stationary steps (``samples_per_step`` measurements each); ``sweeps``: its continuous sweeps, streamed
    at ``stream_rate`` Hz asked."""
    s = parse_settings(spec, site)
    where = "a simulated emScon server on the mock robot (loopback)" if s.simulated else f"{s.host}:{s.port}"
    env = ("set to {:g} degC, {:g} mbar, {:g} %RH".format(*s.environment) if s.environment
           else "read from the server (its weather station or last values) and recorded")
    reflector = (f"{s.reflector!r} (by name or id), recorded" if s.reflector
                 else "the one selected on the tracker, recorded")
    readings = samples_per_step * steps
    step_time = samples_per_step * (s.meas_time + 0.05)  # s a step's readings take, with some room for the link
    limit = float(getattr(site, "measure_timeout", math.inf))
    late = ([f"  warning: {samples_per_step} measurements of {s.meas_time:g} s take about {step_time:.1f} s, more "
             f"than the site's measure timeout ({limit:g} s): raise timeouts.measure or lower meas_time"]
            if steps and step_time > limit else [])
    lines = [f"tracker: Leica emScon TPI at {where}; at connect and at every reconnect it is asked to:",
             "  initialise " + ("at every connect" if s.initialize == "always" else "only if it says it is not")
             + f" (within {s.init_timeout:g} s)",
             "  use metres, radians, degC, mbar, %RH and right-handed rectangular coordinates in its own frame "
             "(no transformation, no station orientation)",
             f"  environment: {env}",
             f"  reflector: {reflector}"]
    if s.probe:
        lines.append("  measure a 6-DoF probe (T-Mac class): each reading the tip's position and the probe's "
                     "orientation, with their deviations, recorded as full poses")
    what = "6-DoF poses" if s.probe else "points"
    if steps:
        lines.append(f"  measure stationary {what} of {s.meas_time:g} s: {samples_per_step} per step, {readings} in "
                     f"all ({readings * s.meas_time / 60:.1f} min of measuring)")
    if sweeps:
        separation = continuous_separation(stream_rate)
        lines += [f"  measure continuously by time during each of the {sweeps} sweeps: a point every {separation} ms "
                  f"({1000 / separation:g} per second), each stamped with the tracker's own clock (the session fits "
                  "its offset and drift to the robot's)"
                  + ("; 6-DoF points, of which the sweep records the tip's position (streamed rows have no "
                     "orientation)" if s.probe else ""),
                  "  in a sweep, a broken beam or lost reflector, flagged points, a dropped, garbled or silent link: "
                  "a gap, and the measurement started again (every 0.2 s until the beam is back; on a new link)"]
    lines.append(f"  faults: a broken beam or lost reflector, warming up or not ready: retried by the run; a dropped, "
                 f"garbled or silent link: read again on a new link ({s.retries} retries, {s.timeout:g} s per answer)")
    return lines + late


def continuous_separation(rate: float) -> int:
    """The time separation (ms, whole, at least 1) of a continuous measurement asked ``rate`` points per second."""
    return max(1, round(1000.0 / rate))
