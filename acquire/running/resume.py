"""What ``acquire --resume`` may change: connection details yes, the plan never.

A session stores the device specs and the resolved site configuration it was created with (and, after a resume
that changed them, the latest connection details under the ``connection`` header key). On a resume the operator
may give a new robot address (``--robot ur5e@NEW``), a new tracker port or host (``--tracker ...`` of the same
backend) or a site file with new hosts, tracker settings, timeouts or retries: these are connection details,
used from then on and listed so that the session can record them as an event. Anything that would change the
plan (the robot model or backend, a simulated device's world, the steps, samples, sweep ranges, free poses,
speeds...) is refused with one line naming the option; so is a site file that cannot be read. The robot model
is the one the session records (a model file of the operator's, moved or edited since, cannot change the plan).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from config.files import read_yaml
from config.robots import ConfigError, RobotModel, load_robot, robot_from_document
from config.site import FIELDS, SiteConfig, load_site
from drivers.spec import RobotSpec, TrackerSpec

#: Site fields that only say how to reach and wait for the devices; every other field shapes the plan.
CONNECTION_FIELDS = frozenset({"host", "hosts", "tracker", "tracker_settings", "tracker_noise", "measure_time",
                               "connect_timeout", "move_timeout", "settle_timeout", "measure_timeout", "retries",
                               "robot_model"})
#: Command-line options that shape the plan -> their site field.
PLAN_OPTIONS = {"--steps": "steps_per_sweep", "--samples": "samples_per_step", "--free-poses": "free_poses"}


class ResumeRefused(ValueError):
    """A resume that would change the plan or cannot read its settings; one line naming the option."""


@dataclass(frozen=True)
class ResumeSettings:
    """The specs and site configuration a resumed run uses, and what changed (one line each, for the event)."""

    robot: RobotSpec
    tracker: TrackerSpec
    site: SiteConfig
    changes: tuple[str, ...]

    def connection(self) -> dict[str, Any]:
        """The ``connection`` header value that a later resume starts from."""
        return {"robot_spec": str(self.robot), "tracker_spec": str(self.tracker), "site": self.site.as_dict()}


def resume_settings(header: dict[str, Any], robot: str | None = None, tracker: str | None = None,
                    config: Path | None = None, options: dict[str, Any] | None = None) -> ResumeSettings:
    """Merge what the operator gave on a resume into what the session ``header`` recorded.

    ``robot``/``tracker``: the ``--robot``/``--tracker`` strings or None; ``config``: a site file or None;
    ``options``: plan options as given on the command line (``{"--steps": 12}``, None when not given).
    Raises ResumeRefused (plan changes), SpecError (bad specs) or ConfigError (an unreadable site file).
    """
    stored = header.get("connection") or header["config"]
    old_robot, old_tracker = RobotSpec.parse(stored["robot_spec"]), TrackerSpec.parse(stored["tracker_spec"])
    old_site = SiteConfig.from_dict(stored["site"])
    changes: list[str] = []
    new_robot = old_robot if robot is None else _robot(old_robot, RobotSpec.parse(robot), robot)
    new_tracker = old_tracker if tracker is None else _tracker(old_tracker, TrackerSpec.parse(tracker), tracker)
    for label, old, new in (("robot", old_robot, new_robot), ("tracker", old_tracker, new_tracker)):
        if str(old) != str(new):
            changes.append(f"{label}: {old} -> {new}")
    site = old_site
    if config is not None:
        site = _site(old_site, Path(config), old_robot.model)
        for name in sorted(CONNECTION_FIELDS):
            if getattr(site, name) != getattr(old_site, name):
                section, key = FIELDS[name]
                changes.append(f"{key if section is None else f'{section}.{key}'}: {getattr(old_site, name)!r} -> "
                               f"{getattr(site, name)!r} ({config})")
    for option, value in (options or {}).items():
        name = PLAN_OPTIONS.get(option)
        if value is not None and name is not None and value != getattr(old_site, name):
            raise ResumeRefused(f"{option} {value}: the session's plan has {getattr(old_site, name)}; a resume "
                                "cannot change the plan (start a new session for another plan)")
    return ResumeSettings(new_robot, new_tracker, replace(site, source=f"{old_site.source} + resume"), tuple(changes))


def session_model(header: dict[str, Any], spec: RobotSpec) -> tuple[RobotModel, str]:
    """The robot model a resumed session plans and moves with, and one line saying why it is not the file's ('' when
    it is). A bundled model (``spec.model`` a name) is loaded by name; a model file's session records the model itself
    (``config.robot_model``): that record is used when the file has moved or changed since. ConfigError when the
    session records no model and the file cannot be read."""
    recorded = (header.get("config") or {}).get("robot_model")
    if not spec.model_is_file or not isinstance(recorded, dict):
        return load_robot(spec.model), ""
    try:
        current = load_robot(spec.model)
    except ConfigError:
        current = None
    if current is not None and current.document == recorded:
        return current, ""
    what = "is not there" if not Path(spec.model).exists() else "has changed since the session was planned"
    model = robot_from_document(recorded, spec.model)  # the file's path: the spec still names the same model
    return model, f"robot: {spec.model} {what}; the resume uses the model the session records ({model.name})"


def _robot(old: RobotSpec, new: RobotSpec, text: str) -> RobotSpec:
    new = new.resolved()  # a model file named from another folder is the same file
    if (new.backend, new.model) != (old.backend, old.resolved().model):
        raise ResumeRefused(f"--robot {text}: the session was measured with {old}; a resume may change the robot's "
                            f"address, not the robot ({old.backend}:{old.model})")
    if new.backend == "mock" and _world(new.options) != _world(old.options):
        raise ResumeRefused(f"--robot {text}: the simulated robot of the session is {old}; a resume cannot change "
                            "its options (other than fault)")
    return new


def _tracker(old: TrackerSpec, new: TrackerSpec, text: str) -> TrackerSpec:
    if new.backend != old.backend:
        raise ResumeRefused(f"--tracker {text}: the session was measured with {old}; a resume may change the "
                            f"tracker's port, host or options, not its kind ({old.backend})")
    if new.backend == "mock" and _world(new.options) != _world(old.options):
        raise ResumeRefused(f"--tracker {text}: the simulated tracker of the session is {old}; a resume cannot "
                            "change its options (other than fault)")
    return new


def _world(options: dict[str, str]) -> dict[str, str]:
    """A simulated device's options that define its world (all but the injected faults)."""
    return {k: v for k, v in options.items() if k != "fault"}


def _site(old: SiteConfig, path: Path, model: str) -> SiteConfig:
    """``old`` with the connection fields the file at ``path`` sets; ResumeRefused if it sets a plan field to
    another value. Keys the file leaves out keep the session's values (a site file of hosts only is enough)."""
    new = load_site(path)
    raw = read_yaml(path)
    updates: dict[str, Any] = {}
    for name, (section, key) in FIELDS.items():
        mapping = raw if section is None else (raw.get(section) or {})
        if key not in mapping:
            continue
        value = getattr(new, name)
        if name == "robot_model":
            if value is not None and value.strip().lower() != model.lower():
                raise ResumeRefused(f"--config {path}: robot.model is {value}; the session's robot is {model}")
            continue
        if name in CONNECTION_FIELDS:
            updates[name] = value
        elif value != getattr(old, name):
            dotted = key if section is None else f"{section}.{key}"
            raise ResumeRefused(f"--config {path}: {dotted} is {_show(value)}, the session's plan has "
                                f"{_show(getattr(old, name))}; a resume cannot change the plan")
    return replace(old, **updates)


def _show(value: Any) -> str:
    return "null" if value is None else str(list(value) if isinstance(value, tuple) else value)
